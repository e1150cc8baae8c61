"""Nonlinear tier: mixed neo-Hookean with Newton, on the clamped 5 mm x 9 mm rod (issue #3)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import skfem
from skfem import FacetBasis, LinearForm

from fem.cylinder import Cylinder
from fem.elasticity import assemble, discretise, facet_indices, skfem_mesh, solve_static, split
from fem.geometry import FaceTag
from fem.materials.linear_elastic import lame_parameters
from fem.mesh import MeshParams, build_mesh
from fem.nonlinear import SolverError, residual_and_tangent, solve_nonlinear

RADIUS, LENGTH = 2.5e-3, 9e-3
LAM, MU = lame_parameters(1.5e6, 0.49)


@pytest.fixture(scope="module")
def rod():
    mesh, _ = build_mesh(Cylinder(RADIUS, LENGTH), MeshParams(edge_length_m=1.5e-3, envelope_m=3.75e-5), progress=False)
    sk = skfem_mesh(mesh.points, mesh.tets, mesh.edge_nodes, mesh.tet_edges)
    tip = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.ROD_TIP])
    root = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM])
    d = discretise(sk, "P2P1")
    tip_basis = FacetBasis(sk, d.u.elem, facets=tip, intorder=4)
    area = math.pi * RADIUS**2

    @LinearForm
    def unit_lateral(v, w):  # 1 N in +x spread evenly over the tip (dead load)
        return v[0] / area

    unit = np.concatenate([skfem.asm(unit_lateral, tip_basis), np.zeros(d.p.N)])
    fixed = d.u.get_dofs(facets=root).all()

    def tip_deflection(x):
        u, _ = split(d, x)
        return skfem.Functional(lambda w: w.u[0]).assemble(tip_basis, u=tip_basis.interpolate(u)) / area

    linear = solve_static(assemble(d, LAM, MU), unit, fixed)
    force_half = 0.5 * LENGTH / tip_deflection(linear)  # linear estimate of the force for L / 2
    return d, unit, fixed, tip_deflection, linear, force_half


def test_tangent_at_rest_is_the_linear_mixed_operator(rod):
    d, *_ = rod
    r, k = residual_and_tangent(d, np.zeros(d.n_dofs), LAM, MU)
    assert np.abs(r).max() == 0.0
    linear = assemble(d, LAM, MU)
    assert abs(k - linear).max() <= 1e-12 * abs(linear).max()


def test_tangent_is_the_derivative_of_the_residual(rod):
    d, *_ = rod
    rng = np.random.default_rng(4)
    x = 1e-6 * rng.normal(size=d.n_dofs)
    dx = 1e-9 * rng.normal(size=d.n_dofs)
    _, k = residual_and_tangent(d, x, LAM, MU)
    r_plus, _ = residual_and_tangent(d, x + dx, LAM, MU, with_tangent=False)
    r_minus, _ = residual_and_tangent(d, x - dx, LAM, MU, with_tangent=False)
    central = 0.5 * (r_plus - r_minus)
    assert np.linalg.norm(central - k @ dx) <= 1e-6 * np.linalg.norm(k @ dx)


def test_compiled_residual_equals_the_numpy_evaluation(rod, monkeypatch):
    """fem.residual_kernels (one fused loop) against fem.nonlinear's batched evaluation, at a strained
    state with pressure and per-element moduli (a stiffness contrast of 100); an inverted element is
    refused by both."""
    import fem.nonlinear as nl

    d, *_ = rod
    rng = np.random.default_rng(11)
    # a smooth large deformation (bending, twist and stretch, strains of order 10 %: random nodal noise
    # inverts the mesh's thin boundary elements) with a random pressure
    X, Y, Z = d.u.doflocs
    comp = np.arange(d.n_u) % 3  # the vector basis interleaves components (dof 3 i + a)
    field = np.where(comp == 0, 0.3 * Z**2 / LENGTH - 0.1 * Y * Z / LENGTH, np.where(comp == 1, 0.1 * X * Z / LENGTH, 0.05 * Z))
    x = np.concatenate([field, 0.3 * rng.standard_normal(d.p.N)])
    lam = LAM * rng.uniform(0.01, 1.0, d.u.mesh.nelements)
    mu = MU * rng.uniform(0.01, 1.0, d.u.mesh.nelements)
    ours, _ = residual_and_tangent(d, x, lam, mu, with_tangent=False)
    monkeypatch.setattr(nl, "COMPILED_RESIDUAL", False)
    ref, _ = residual_and_tangent(d, x, lam, mu, with_tangent=False)
    assert np.abs(ref[: d.n_u]).max() > 0 and np.abs(ref[d.n_u :]).max() > 0
    np.testing.assert_allclose(ours, ref, rtol=0, atol=1e-12 * np.abs(ref).max())
    monkeypatch.setattr(nl, "COMPILED_RESIDUAL", True)
    crushed = x.copy()
    crushed[: d.n_u] = -2.0 * d.u.doflocs[comp, np.arange(d.n_u)]  # u = -2 X: F = -I, every point through the origin
    with pytest.raises(FloatingPointError, match="det F <= 0"):
        residual_and_tangent(d, crushed, LAM, MU, with_tangent=False)


def test_vectorised_tangent_equals_scikit_fem_form_assembly(rod):
    """fem.nonlinear.tangent_uu (two batched products) and residual_u (one) against scikit-fem
    assembling the same weak forms pair by pair, at a strained state with pressure."""
    from skfem.helpers import det, inv

    from fem.elasticity import _per_qp
    from fem.nonlinear import _identity_like, _tangent_uu, tangent_uu

    d, *_ = rod
    d.pressure_scale = float(MU)
    rng = np.random.default_rng(7)
    x = np.concatenate([1e-4 * rng.standard_normal(d.n_u), 0.1 * rng.standard_normal(d.p.N)])
    prev = d.u.interpolate(x[: d.n_u])
    F = _identity_like(prev.grad) + prev.grad
    Finv = inv(F)
    mu_q = np.asarray(_per_qp(np.full(d.u.mesh.nelements, MU), d.u))
    p_q = np.asarray(d.p.interpolate(x[d.n_u :]))
    ours = tangent_uu(d.u, mu_q, p_q, d.pressure_scale, np.asarray(Finv))
    ref = skfem.asm(_tangent_uu, d.u, F=F, J=det(F), Finv=Finv, p=p_q, mu=mu_q, s=d.pressure_scale)
    assert abs(ours - ref).max() <= 1e-13 * abs(ref).max()
    # the residual likewise: one batched product against the form assembled per vector function
    from fem.nonlinear import _residual_u, residual_u

    r = residual_u(d.u, mu_q, p_q, d.pressure_scale, np.asarray(F), np.asarray(Finv))
    r_ref = skfem.asm(_residual_u, d.u, F=F, J=det(F), Finv=Finv, p=p_q, mu=mu_q, s=d.pressure_scale)
    np.testing.assert_allclose(r, r_ref, rtol=0, atol=1e-13 * np.abs(r_ref).max())
    # and the displacement-pressure block: one batched product against the pairwise form
    from fem.nonlinear import _tangent_up, tangent_up

    kup = tangent_up(d.u, d.p, d.pressure_scale, np.asarray(Finv))
    kup_ref = skfem.asm(_tangent_up, d.p, d.u, F=F, J=det(F), Finv=Finv, s=d.pressure_scale)
    assert kup.shape == kup_ref.shape
    assert abs(kup - kup_ref).max() <= 1e-13 * abs(kup_ref).max()


def test_small_load_agrees_with_the_linear_tier(rod):
    d, unit, fixed, tip_deflection, linear, force_half = rod
    load = 0.01 * 1.25 * force_half  # 1 % of the large-deflection load below
    x, report = solve_nonlinear(d, LAM, MU, lambda t: t * load * unit, fixed, increments=1)
    assert tip_deflection(x) == pytest.approx(load * tip_deflection(linear), rel=0.02)
    assert report.residuals[-1][-1] <= 1e-8 * report.residuals[-1][0]


def test_large_deflection_of_half_the_rod_height_converges(rod):
    d, unit, fixed, tip_deflection, _, force_half = rod
    load = 1.25 * force_half  # a dead lateral load stiffens the rod: 1.25x the linear estimate
    x, report = solve_nonlinear(d, LAM, MU, lambda t: t * load * unit, fixed, increments=8)
    assert tip_deflection(x) >= 0.5 * LENGTH
    assert np.all(np.isfinite(x))
    for history in report.residuals:  # every increment: residual reduced by 1e-8 or more
        assert history[-1] <= 1e-8 * history[0]
    last = report.residuals[-1]
    assert len(last) >= 3 and last[-1] <= 1e-3 * last[-2]  # Newton's quadratic tail


def test_zero_load_gives_zero_state_without_iterations(rod):
    d, unit, fixed, *_ = rod
    x, report = solve_nonlinear(d, LAM, MU, lambda t: 0.0 * unit, fixed, increments=2)
    assert np.abs(x).max() == 0.0 and report.total_iterations == 0


def test_impossible_load_raises_a_clear_solver_error(rod):
    d, unit, fixed, *_ = rod
    with pytest.raises(SolverError, match=r"rod under an absurd load: Newton did not converge at load factor"):
        solve_nonlinear(d, LAM, MU, lambda t: t * 1e6 * unit, fixed, increments=1, max_iterations=4,
                        min_increment=0.2, case="rod under an absurd load")
