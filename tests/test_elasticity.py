"""Elasticity: material laws, the patch test and manufactured-solution convergence for every element."""

from __future__ import annotations

import numpy as np
import pytest
import skfem
from skfem import Functional

from fem.elasticity import (ELEMENTS, _per_qp, assemble, body_force, deviatoric_form, deviatoric_matrix, discretise, dof_components, element_lame,
                            solve_static, split)
from fem.materials import material_model
from fem.materials import linear_elastic as le
from fem.materials import neo_hookean as nh


# ------------------------------------------------------------------------------------ materials
def test_lame_parameters_reference_values():
    lam, mu = le.lame_parameters(1.0e6, 0.25)
    assert lam == pytest.approx(4e5) and mu == pytest.approx(4e5)  # E nu / ((1+nu)(1-2nu)), E / (2(1+nu))
    assert le.bulk_modulus(lam, mu) == pytest.approx(1e6 / (3 * (1 - 2 * 0.25)))
    for bad in [(0.0, 0.3), (1e6, 0.5), (1e6, -1.0), (float("nan"), 0.3)]:
        with pytest.raises(ValueError):
            le.lame_parameters(*bad)


def test_linear_stress_energy_and_von_mises():
    lam, mu = le.lame_parameters(2.0e6, 0.3)
    eps = np.array([[1e-3, 2e-4, 0], [2e-4, -5e-4, 0], [0, 0, 3e-4]])
    sig = le.stress(eps, lam, mu)
    assert 0.5 * np.sum(sig * eps) == pytest.approx(le.strain_energy_density(eps, lam, mu), rel=1e-12)
    uniaxial = np.zeros((3, 3))
    uniaxial[0, 0] = 5e5
    assert le.von_mises(uniaxial) == pytest.approx(5e5)  # uniaxial: sigma_vm = |sigma_xx|
    shear = np.zeros((3, 3))
    shear[0, 1] = shear[1, 0] = 1e5
    assert le.von_mises(shear) == pytest.approx(np.sqrt(3) * 1e5)  # pure shear: sqrt(3) tau
    assert le.von_mises(np.eye(3) * 7e5) == pytest.approx(0.0, abs=1e-9)  # hydrostatic: zero


def test_neo_hookean_derivatives_match_finite_differences():
    rng = np.random.default_rng(1)
    lam, mu = le.lame_parameters(1.5e6, 0.45)
    F = np.eye(3) + 0.15 * rng.normal(size=(4, 3, 3))
    P = nh.first_piola(F, lam, mu)
    A = nh.first_elasticity(F, lam, mu)
    h = 1e-7
    for i in range(3):
        for j in range(3):
            Fp, Fm = F.copy(), F.copy()
            Fp[:, i, j] += h
            Fm[:, i, j] -= h
            dW = (nh.strain_energy_density(Fp, lam, mu) - nh.strain_energy_density(Fm, lam, mu)) / (2 * h)
            np.testing.assert_allclose(P[:, i, j], dW, rtol=1e-6, atol=1e-6 * np.abs(P).max())
            dP = (nh.first_piola(Fp, lam, mu) - nh.first_piola(Fm, lam, mu)) / (2 * h)
            np.testing.assert_allclose(A[:, :, :, i, j], dP, rtol=1e-6, atol=1e-6 * np.abs(A).max())


def test_neo_hookean_reduces_to_linear_at_small_strain_and_is_objective():
    lam, mu = le.lame_parameters(1.5e6, 0.49)
    rng = np.random.default_rng(2)
    eps = rng.normal(size=(3, 3)) * 1e-7
    eps = 0.5 * (eps + eps.T)
    np.testing.assert_allclose(nh.cauchy_stress(np.eye(3) + eps, lam, mu), le.stress(eps, lam, mu), rtol=1e-5, atol=1e-3)
    assert nh.strain_energy_density(np.eye(3), lam, mu) == 0.0
    # Rotating the deformed body rotates the Cauchy stress and keeps the energy.
    F = np.eye(3) + 0.2 * rng.normal(size=(3, 3))
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    assert nh.strain_energy_density(q @ F, lam, mu) == pytest.approx(nh.strain_energy_density(F, lam, mu), rel=1e-12)
    np.testing.assert_allclose(nh.cauchy_stress(q @ F, lam, mu), q @ nh.cauchy_stress(F, lam, mu) @ q.T, rtol=1e-10, atol=1e-6)
    with pytest.raises(FloatingPointError, match="inverts"):
        nh.first_piola(np.diag([1.0, 1.0, -1.0]), lam, mu)


def test_material_registry_lists_valid_names():
    assert material_model("neo_hookean") is nh
    with pytest.raises(ValueError, match="choose one of: linear_elastic, neo_hookean"):
        material_model("mooney")


def test_element_lame_is_fraction_weighted():
    frac = np.array([[1, 0, 0], [0.25, 0.25, 0.5]])
    lam, mu = element_lame(frac, [(1.0, 10.0), (2.0, 20.0), (4.0, 40.0)])
    np.testing.assert_allclose(lam, [1.0, 0.25 + 0.5 + 2.0])
    np.testing.assert_allclose(mu, [10.0, 2.5 + 5 + 20])


# -------------------------------------------------------------------------------- discretisation
def _distorted_cube(n: int, rng, element: str, vertex_jitter=0.04, edge_jitter=0.01):
    """Unit cube, n intervals a side, interior vertices moved and (for P2) interior edges curved."""
    m = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, n + 1)] * 3)
    h = 1.0 / n
    p = m.p.copy()
    inner = m.interior_nodes()
    p[:, inner] += rng.uniform(-vertex_jitter * h, vertex_jitter * h, (3, len(inner)))
    m = skfem.MeshTet(p, m.t)
    if element == "P1":
        return m
    m2 = skfem.MeshTet2.from_mesh(m)
    dl = m2.doflocs.copy()
    inner_edges = np.setdiff1d(np.arange(m2.edges.shape[1]), m2.boundary_edges())
    dl[:, m.p.shape[1] + inner_edges] += rng.uniform(-edge_jitter * h, edge_jitter * h, (3, len(inner_edges)))
    return skfem.MeshTet2(dl, m2.t, sort_t=False)


def _jacobian_sign_is_constant_per_element(d) -> bool:
    det = d.u.mapping.detDF(d.u.X)
    return bool(np.all((det > 0).all(axis=1) | (det < 0).all(axis=1)))


@pytest.mark.parametrize("element", ELEMENTS)
@pytest.mark.parametrize("nu", [0.3, 0.4999])
def test_patch_test_reproduces_linear_fields(element, nu):
    """Any linear displacement on the boundary of a distorted (curved, for P2) patch is reproduced
    inside to 1e-10, with the exact constant pressure lambda tr(A) for the mixed element."""
    rng = np.random.default_rng(3)
    d = discretise(_distorted_cube(3, rng, element), element)
    assert _jacobian_sign_is_constant_per_element(d)  # a valid (unfolded) patch
    a, b = rng.normal(size=(3, 3)), rng.normal(size=3)
    lam, mu = le.lame_parameters(1.0e6, nu)
    exact = (a @ d.u.doflocs + b[:, None])[dof_components(d.u), np.arange(d.u.N)]
    fixed = d.u.get_dofs().all()
    x = solve_static(assemble(d, lam, mu), np.zeros(d.n_dofs), fixed, exact[fixed])
    u, p = split(d, x)
    assert np.abs(u - exact).max() <= 1e-10 * np.abs(exact).max()
    if p is not None:
        np.testing.assert_allclose(p, lam * np.trace(a), rtol=1e-10)


@pytest.mark.parametrize("threads", [1, 2])
def test_deviatoric_matrix_is_scikit_fems_bit_for_bit(threads):
    """The mixed form's displacement block made from each function's symmetric gradient once, on the
    pairs i <= j, equals scikit-fem's assembly of the form in every bit (curved P2, mu per element),
    and is symmetric (to the round-off of summing an entry's elements in another order than its mirror's)."""
    rng = np.random.default_rng(5)
    d = discretise(_distorted_cube(2, rng, "P2P1"), "P2P1")
    mu_q = _per_qp(rng.uniform(1e5, 1e6, d.u.mesh.nelements), d.u)
    ours = deviatoric_matrix(d.u, mu_q, threads=threads)
    theirs = skfem.asm(deviatoric_form, d.u, mu=mu_q)
    for name in ("indptr", "indices", "data"):
        assert getattr(ours, name).tobytes() == getattr(theirs, name).tobytes(), name
    assert abs(ours - ours.T).max() <= 1e-14 * abs(ours).max()


# Manufactured solution on the unit cube: u = (sin pi y, sin pi z, sin pi x). It is divergence-free,
# so the pressure p = lambda div u is 0 and the solution is the same for every nu: the test then
# measures approximation, not the lambda / mu amplification of the pressure error that a
# compressible field would carry into nearly incompressible runs. Body force f = mu pi^2 u;
# Dirichlet data: the exact field at the boundary DOFs.
def _exact(x):
    return np.stack([np.sin(np.pi * x[1]), np.sin(np.pi * x[2]), np.sin(np.pi * x[0])])


def _l2_error(d, u) -> float:
    uh = d.u.interpolate(u)

    @Functional
    def err(w):
        e = w.uh - _exact(w.x)
        return e[0] ** 2 + e[1] ** 2 + e[2] ** 2

    return float(np.sqrt(err.assemble(d.u, uh=uh)))


CONVERGENCE = {  # element: (refinements, nu, theoretical L2 order)
    "P1": ((4, 8, 16), 0.3, 2.0),
    "P2": ((2, 4, 8), 0.3, 3.0),
    "P2P1": ((2, 4, 8), 0.4999, 3.0),
}


@pytest.mark.parametrize("element", ELEMENTS)
def test_manufactured_solution_converges_at_the_theoretical_order(element):
    sizes, nu, order = CONVERGENCE[element]
    lam, mu = le.lame_parameters(1.0, nu)
    errors = []
    for n in sizes:
        mesh = skfem.MeshTet.init_tensor(*[np.linspace(0, 1, n + 1)] * 3)
        if element != "P1":
            mesh = skfem.MeshTet2.from_mesh(mesh)
        d = discretise(mesh, element)
        fixed = d.u.get_dofs().all()
        boundary = _exact(d.u.doflocs)[dof_components(d.u), np.arange(d.u.N)][fixed]
        x = solve_static(assemble(d, lam, mu), body_force(d, lambda x: mu * np.pi**2 * _exact(x)), fixed, boundary)
        u, p = split(d, x)
        errors.append(_l2_error(d, u))
        if p is not None:  # the pressure of a divergence-free field is zero, in units of mu
            assert np.abs(p).max() < 0.5 * mu
    slope = np.polyfit(np.log(1.0 / np.array(sizes)), np.log(errors), 1)[0]
    assert abs(slope - order) <= 0.2, (errors, slope)
    assert np.all(np.isfinite(errors))
