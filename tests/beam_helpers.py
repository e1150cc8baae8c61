"""A clamped square beam of tetrahedra for the nonlinear and dynamic tiers' closed-form checks
(tests/test_nonlinear_large_deflection.py, tests/test_dynamics.py)."""

from __future__ import annotations

import numpy as np
import scipy.sparse.linalg as spla
import skfem
from skfem import FacetBasis, LinearForm

from fem.elastica import euler_load_clamped_free_n
from fem.elasticity import assemble, discretise, solve_static, split
from fem.nonlinear import residual_and_tangent


def square_beam(side_m: float, length_m: float, across: int, along: int):
    """A clamped square beam of tetrahedra along z: the discretisation, its clamp's DOFs, the tip's facet
    basis and unit end loads (1 N spread evenly over the tip, along +x and along -z), and a function
    giving the tip's mean displacement (3,) m."""
    edge = np.linspace(-side_m / 2, side_m / 2, across + 1)
    mesh = skfem.MeshTet.init_tensor(edge, edge, np.linspace(0.0, length_m, along + 1))
    d = discretise(mesh, "P2P1")
    tip = FacetBasis(mesh, d.u.elem, facets=mesh.facets_satisfying(lambda x: np.isclose(x[2], length_m)), intorder=4)
    area = side_m**2

    def load(component: int, sign: float) -> np.ndarray:
        form = LinearForm(lambda v, w: sign * v[component] / area)
        return np.concatenate([skfem.asm(form, tip), np.zeros(d.p.N)])

    def tip_displacement(x: np.ndarray) -> np.ndarray:
        u = tip.interpolate(split(d, x)[0])
        return np.array([skfem.Functional(lambda w, c=c: w.u[c]).assemble(tip, u=u) / area for c in range(3)])

    fixed = d.u.get_dofs(facets=mesh.facets_satisfying(lambda x: np.isclose(x[2], 0.0))).all()
    return d, fixed, load(0, 1.0), load(2, -1.0), tip_displacement


def buckling_load(d, fixed, axial, ei, length_m, lam, mu):
    """The smallest load factor of the linearised buckling problem (K_0 + mu K_G) phi = 0 about a state
    compressed by 1e-3 of the Euler load, K_G from the tangent's change there; returns N and the two
    lowest factors (the square's two bending planes)."""
    free = np.setdiff1d(np.arange(d.n_dofs), fixed)
    K0 = assemble(d, lam, mu)
    p0 = 1e-3 * euler_load_clamped_free_n(ei, length_m)
    _, KT = residual_and_tangent(d, solve_static(K0, p0 * axial, fixed), lam, mu)
    K0f = K0[free][:, free].tocsc()
    geometric = -(KT - K0)[free][:, free].tocsc()  # K_G for the load p0
    lu = spla.splu(K0f)
    op = spla.LinearOperator(K0f.shape, matvec=lambda v: lu.solve(geometric @ v), dtype=float)
    values = spla.eigs(op, k=4, which="LM", return_eigenvectors=False, v0=np.ones(len(free)))
    factors = np.sort(1.0 / values.real)
    factors = factors[factors > 0]
    return factors[0] * p0, factors[:2]
