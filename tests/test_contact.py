"""Frictional contact: the Coulomb return map, and a flat probe sliding over one rod (issue #3)."""

from __future__ import annotations

import numpy as np
import pytest
import skfem

from fem.contact import ContactHistory, FlatProbe, coulomb_traction, solve_contact_increment
from fem.cylinder import Cylinder
from fem.elasticity import assemble, discretise, facet_indices, skfem_mesh
from fem.geometry import FaceTag
from fem.materials.linear_elastic import lame_parameters
from fem.mesh import MeshParams, build_mesh


def _points(n=6, seed=0):
    rng = np.random.default_rng(seed)
    X = np.zeros((3, 1, n))
    X[:2] = rng.uniform(-1e-3, 1e-3, (2, 1, n))
    X[2] = 1e-3
    return X, rng


def test_return_map_stick_slip_and_separation():
    X, rng = _points()
    probe = FlatProbe(height_m=1e-3 - 1e-5, offset_m=(2e-6, 0.0), friction=0.5, eps_n=1e10, eps_t=1e9)
    hist = ContactHistory.zero((1, 6))
    u = np.zeros((3, 1, 6))
    t, _, p, stick = coulomb_traction(X, u, probe, hist)
    np.testing.assert_allclose(p, 1e10 * 1e-5)  # penetration 10 um
    np.testing.assert_allclose(t[2], -p)
    assert stick.all()  # trial 1e9 * 2e-6 = 2 kPa < mu p = 50 kPa
    np.testing.assert_allclose(t[0], 2e3)  # friction drags the body along the probe's motion
    far = FlatProbe(height_m=1e-3 - 1e-5, offset_m=(1e-3, 0.0), friction=0.5, eps_n=1e10, eps_t=1e9)
    t, _, p, stick = coulomb_traction(X, u, far, hist)
    assert not stick.any()
    np.testing.assert_allclose(np.hypot(t[0], t[1]), 0.5 * p)  # slip: |t_T| = mu p exactly
    above = FlatProbe(height_m=1.1e-3, offset_m=(1e-3, 0.0))
    t, D, p, stick = coulomb_traction(X, u, above, hist)
    assert np.all(t == 0) and np.all(D == 0) and np.all(p == 0)


@pytest.mark.parametrize("offset", [2e-7, 1e-4], ids=["stick", "slip"])
def test_traction_tangent_matches_finite_differences(offset):
    X, rng = _points(seed=1)
    probe = FlatProbe(height_m=1e-3 - 1e-5, offset_m=(offset, 0.3 * offset), friction=0.5, eps_n=1e10, eps_t=1e9)
    hist = ContactHistory.zero((1, 6))
    u = rng.normal(size=(3, 1, 6)) * 1e-7
    _, D, _, stick = coulomb_traction(X, u, probe, hist)
    assert stick.all() if offset < 1e-6 else not stick.any()
    h = 1e-12
    for j in range(3):
        du = np.zeros_like(u)
        du[j] = h
        tp, *_ = coulomb_traction(X, u + du, probe, hist)
        tm, *_ = coulomb_traction(X, u - du, probe, hist)
        np.testing.assert_allclose((tp - tm) / (2 * h), D[:, j], rtol=1e-5, atol=1e-6 * np.abs(D).max())


def test_flat_probe_sliding_over_a_rod_sticks_then_slips_at_mu_n():
    """Press a flat probe 0.1 mm into the tip of a clamped 5 mm x 9 mm rod, then slide it sideways.

    While the tip sticks, the friction force grows with the slide (the rod bends); once the whole
    contact slips, the tangential force equals mu times the normal force."""
    radius, length, young, mu_friction = 2.5e-3, 9e-3, 1.5e6, 0.3
    mesh, _ = build_mesh(Cylinder(radius, length), MeshParams(edge_length_m=2.0e-3, envelope_m=5e-5), progress=False)
    sk = skfem_mesh(mesh.points, mesh.tets, mesh.edge_nodes, mesh.tet_edges)
    tip = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.ROD_TIP])
    root = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM])
    d = discretise(sk, "P2P1")
    lam, mu = lame_parameters(young, 0.49)
    K = assemble(d, lam, mu)
    fb = skfem.FacetBasis(sk, d.u.elem, facets=tip, intorder=4)
    fixed = d.u.get_dofs(facets=root).all()
    eps_n = 100 * young / 2.0e-3  # 100 E / h, h the mesh edge
    hist = ContactHistory.zero(np.asarray(fb.global_coordinates())[0].shape)
    x = np.zeros(d.n_dofs)
    height = length - 0.1e-3
    x, hist, pressed = solve_contact_increment(K, d.n_u, fb, fixed, x, FlatProbe(height, (0.0, 0.0), mu_friction, eps_n, eps_n / 10), hist)
    assert pressed["normal_n"] > 0.1 and abs(pressed["tangential_n"][0]) < 0.01 * pressed["normal_n"]
    ratios, stick = [], []
    for k in range(1, 5):
        probe = FlatProbe(height, (0.15e-3 * k, 0.0), mu_friction, eps_n, eps_n / 10)
        x, hist, f = solve_contact_increment(K, d.n_u, fb, fixed, x, probe, hist, case=f"slide step {k}")
        ratios.append(f["tangential_n"][0] / f["normal_n"])
        stick.append(f["stick_fraction"])
        assert np.all(np.isfinite(x))
    assert stick[0] > 0.05 and ratios[0] < 0.9 * mu_friction  # stick (partial): below the Coulomb limit
    assert ratios[0] < ratios[1] <= ratios[2] * (1 + 1e-9)  # the friction force builds up
    for r, s in zip(ratios[2:], stick[2:]):  # gross slip: T = mu N
        assert s == 0.0
        assert r == pytest.approx(mu_friction, rel=0.02)
