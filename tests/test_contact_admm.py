"""The ADMM contact solver on the Delassus operator (fem.contact_admm): the cone projection, closed-form
single-point answers (penalty press, stick, slip), the grouped (Woodbury) operator against the dense
one, bounded work with its residual reported, warm starts, and a whole episode against the Newton
solver."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fem import contact_admm as ca
from fem import quasistatic as qs

MU = 0.8


def _project_cone_numpy(v, n, mu):
    """The cone projection in numpy (the reference of the compiled fem.admm_kernels.project_cones)."""
    vn = np.einsum("ij,ij->i", v, n)
    vt = v - vn[:, None] * n
    t = np.linalg.norm(vt, axis=1)
    a = (vn + mu * t) / (1.0 + mu * mu)  # the normal part of the projection onto the cone's surface
    scale = np.divide(mu * a, t, out=np.zeros_like(t), where=t > 0)
    out = a[:, None] * n + scale[:, None] * vt
    out[t <= mu * vn] = v[t <= mu * vn]  # inside
    out[mu * t <= -vn] = 0.0  # in the polar cone: the apex
    return out


def _de_saxce_numpy(sigma, n, mu):
    sn = np.einsum("ij,ij->i", sigma, n)
    return (mu * np.linalg.norm(sigma - sn[:, None] * n, axis=1))[:, None] * n


def _normals(m, rng):
    n = rng.standard_normal((m, 3))
    return n / np.linalg.norm(n, axis=1, keepdims=True)


# ------------------------------------------------------------------------------ the cone projection
def test_projection_onto_the_cone_is_a_projection():
    rng = np.random.default_rng(0)
    v, n = rng.standard_normal((2000, 3)), _normals(2000, rng)
    p = ca.project_cone(v, n, MU)
    pn = np.einsum("ij,ij->i", p, n)
    pt = np.linalg.norm(p - pn[:, None] * n, axis=1)
    assert np.all(pt <= MU * pn + 1e-12)  # in the cone
    np.testing.assert_allclose(ca.project_cone(p, n, MU), p, atol=1e-12)  # idempotent
    # Moreau: v - P v is orthogonal to P v and lies in the polar cone (-K*)
    r = v - p
    np.testing.assert_allclose(np.einsum("ij,ij->i", r, p), 0.0, atol=1e-12)
    rn = np.einsum("ij,ij->i", r, n)
    rt = np.linalg.norm(r - rn[:, None] * n, axis=1)
    assert np.all(MU * rt <= -rn + 1e-12)
    # the projection is the nearest point of the cone: no sampled cone point is nearer
    t = rng.standard_normal((2000, 3))
    q = ca.project_cone(t, n, MU)
    assert np.all(np.linalg.norm(v - p, axis=1) <= np.linalg.norm(v - q, axis=1) + 1e-12)
    # the compiled projection is the numpy formula's, to rounding (inside, apex and surface cases)
    np.testing.assert_allclose(p, _project_cone_numpy(v, n, MU), rtol=1e-12, atol=1e-15)
    assert ca.project_cone(np.zeros((0, 3)), np.zeros((0, 3)), MU).shape == (0, 3)


def test_de_saxce_correction_is_mu_times_the_tangential_size_along_n():
    rng = np.random.default_rng(1)
    s, n = rng.standard_normal((50, 3)), _normals(50, rng)
    g = ca.de_saxce(s, n, MU)
    np.testing.assert_allclose(g, _de_saxce_numpy(s, n, MU), atol=1e-15)


# -------------------------------------------------------------------------- closed-form single points
def _one_point(c_m_n=2e-4, k_n_m=1e5):
    return ca.DenseDelassus(np.eye(3) * c_m_n, np.array([k_n_m]))


@pytest.mark.parametrize("penetration_m", [1e-6, 1e-4])
def test_a_pressed_point_carries_the_force_of_its_springs_in_series(penetration_m):
    """Body compliance c and penalty 1/k in series, pushed a distance delta into a flat indenter:
    f_n = delta / (c + 1/k)."""
    G = _one_point()
    n = np.array([[0.0, 0.0, 1.0]])
    b = np.array([[0.0, 0.0, -penetration_m]])
    f, *_ = ca.admm_contact(G, b, n, MU, rtol=1e-10, max_iterations=5000)
    np.testing.assert_allclose(f[0], [0.0, 0.0, penetration_m / (2e-4 + 1e-5)], rtol=1e-8)


@pytest.mark.parametrize("drag_m, sticks", [(1e-6, True), (1e-3, False)])
def test_a_dragged_point_sticks_or_slips_by_coulomb(drag_m, sticks):
    """Pressed by delta and dragged sideways by d: sticking needs the force d / (c + 1/k) <= mu f_n,
    else the point slips with |f_T| = mu f_n against the drag."""
    G = _one_point()
    n = np.array([[0.0, 0.0, 1.0]])
    delta = 2e-5
    b = np.array([[drag_m, 0.0, -delta]])  # sigma = G f + b: the drag is the body's slip without force
    f, *_ = ca.admm_contact(G, b, n, MU, rtol=1e-10, max_iterations=5000)
    fn = delta / 2.1e-4
    assert f[0, 2] == pytest.approx(fn, rel=1e-8)
    if sticks:
        assert f[0, 0] == pytest.approx(-drag_m / 2.1e-4, rel=1e-8)
        assert abs(f[0, 0]) < MU * fn
    else:
        assert f[0, 0] == pytest.approx(-MU * fn, rel=1e-8)
    assert abs(f[0, 1]) < 1e-12 * fn


def test_a_point_away_from_the_indenter_carries_nothing():
    G = _one_point()
    f, *_ = ca.admm_contact(G, np.array([[1e-5, 0.0, 1e-6]]), np.array([[0.0, 0.0, 1.0]]), MU, rtol=1e-10, max_iterations=5000)
    np.testing.assert_allclose(f, 0.0, atol=1e-9)


# ----------------------------------------------------------------------------------- coupled points
def _random_compliance(m, rng, scale=1e-4):
    A = rng.standard_normal((3 * m, 3 * m))
    return scale * (A @ A.T / (3 * m) + 0.1 * np.eye(3 * m))


def _random_problem(seed, m=30):
    """A random coupled problem: 30 points under a flat face, some pressed into it, some not."""
    rng = np.random.default_rng(seed)
    G = ca.DenseDelassus(_random_compliance(m, rng), np.full(m, 1e5))
    n = np.tile([0.0, 0.0, 1.0], (m, 1))
    return G, 1e-5 * rng.standard_normal((m, 3)) - np.array([0.0, 0.0, 1e-5]), n


def test_coupled_points_satisfy_the_friction_problem():
    """A random coupled problem: the answer is in the cones, sigma + Gamma(sigma) in the dual cones,
    and complementary, to the tolerance."""
    G, b, n = _random_problem(2)
    m = len(b)
    f, z, rung, it, res, tol = ca.admm_contact(G, b, n, MU, rtol=1e-9, max_iterations=20000)
    assert res <= tol and it < 20000
    sigma = G.apply(f) + b
    s = sigma + ca.de_saxce(sigma, n, MU)
    assert np.all(np.linalg.norm(f[:, :2], axis=1) <= MU * f[:, 2] * (1 + 1e-9) + 1e-12)
    assert np.all(MU * np.linalg.norm(s[:, :2], axis=1) <= s[:, 2] + 1e-6 * np.abs(sigma).max())
    assert abs(np.sum(f * s)) <= 1e-7 * np.abs(f).max() * np.abs(sigma).max() * m
    assert f[:, 2].max() > 0 and (f[:, 2] == 0).any()  # some points touch, some do not


def _rod_block_problem(seed, sizes=(4, 7, 5, 1)):
    """A random compliance of points on len(sizes) rods, its rod-block operator and the dense
    operator of the same elastic part (blocks plus resultant coupling)."""
    rng = np.random.default_rng(seed)
    rod = np.repeat(np.arange(len(sizes)), sizes)
    m = len(rod)
    C = _random_compliance(m, rng)
    H = ca.rod_resultant_coupling(C, rod, rng.uniform(0.5, 1.5, m))
    r3 = np.repeat(rod, 3)
    blocks = [C[np.ix_(r3 == a, r3 == a)] for a in range(len(sizes))]
    k = rng.uniform(5e4, 2e5, m)
    return ca.RodBlockDelassus(blocks, H, rod, k), ca.DenseDelassus(ca.rod_block_compliance(blocks, H, rod), k), C, rod, rng


def test_the_rod_block_operator_is_the_dense_one_of_its_compliance():
    """Each rod's points with their own compliance, the rods coupled through their resultants: the
    per-rod solves with Woodbury on the resultants, and the product, equal the dense operator's; the
    coupling of two rods is the mean of their points' mutual compliance (areas as weights)."""
    rods, dense, C, rod, rng = _rod_block_problem(3)
    r = rng.standard_normal((len(rod), 3))
    np.testing.assert_allclose(rods.apply(r), dense.apply(r), rtol=1e-12)
    for rho in (1e-6, 1e-4, 1e-2):
        np.testing.assert_allclose(rods._solve(rods._factorise(rho), r, rho), dense._solve(dense._factorise(rho), r, rho), rtol=1e-9)
    assert rods.lambda_min() == pytest.approx(dense.lambda_min())
    # equal weights: H_ab is the plain mean of C's (a, b) block per axis pair, and zero for a = b
    H = ca.rod_resultant_coupling(C, rod, np.ones(len(rod)))
    r3 = np.repeat(rod, 3)
    block = C[np.ix_(r3 == 0, r3 == 2)]
    np.testing.assert_allclose(H[0:3, 6:9], [[block[i::3, j::3].mean() for j in range(3)] for i in range(3)], rtol=1e-12)
    np.testing.assert_array_equal(H[3:6, 3:6], 0.0)
    with pytest.raises(ValueError, match="rod by rod"):
        ca.RodBlockDelassus(rods.blocks, rods.H, rod[::-1], 1.0 / rods.inv_k)


def test_loose_solves_stream_the_rod_blocks_in_single_precision(monkeypatch):
    """At rtol >= SINGLE_PRECISION_RTOL the compiled iterations take the rod blocks' inverses in
    float32: the solve is float64's to float32 rounding (not exactly: the copy is used), and the
    contact forces agree with a float64 solve within the tolerance. Tighter solves keep float64."""
    from fem import admm_kernels as ak

    rods, _, _, rod, rng = _rod_block_problem(41, sizes=(9, 12, 6, 8))
    m = len(rod)
    for rung in (-2, 0, 3):
        single, double = rods.kernel_operator(rung, single=True), rods.kernel_operator(rung)
        assert single[1].dtype == np.float32 and double[1].dtype == np.float64
        r = rng.standard_normal((m, 3))
        x32, x64 = ak.solve(*single, r), ak.solve(*double, r)
        err = np.abs(x32 - x64).max() / np.abs(x64).max()
        assert 0.0 < err < 1e-5
    n = np.tile([0.0, 0.0, 1.0], (m, 1))
    b = 1e-6 * rng.standard_normal((m, 3))
    b[:, 2] = -1e-5 * rng.uniform(0.5, 1.5, m)
    rtol = 1e-5
    assert rtol >= ca.SINGLE_PRECISION_RTOL
    f32, *_, res32, tol32 = ca.admm_contact(rods, b, n, MU, rtol=rtol, max_iterations=20000)
    monkeypatch.setattr(ca, "SINGLE_PRECISION_RTOL", np.inf)  # every solve in float64
    f64, *_, res64, tol64 = ca.admm_contact(rods, b, n, MU, rtol=rtol, max_iterations=20000)
    assert res32 <= tol32 and res64 <= tol64
    np.testing.assert_allclose(f32, f64, atol=20 * tol64)


def test_the_solve_on_the_touching_rods_is_the_solve_on_all():
    """Rods none of whose points reach the indenter unloaded are left out of the ADMM and checked
    after; one that the others' loads pull into contact (through the coupling) is added. The forces
    equal those of the solve on every point, and the left-out rods carry none."""
    added = 0
    for seed in range(8):
        rods, _, _, rod, rng = _rod_block_problem(20 + seed, sizes=(6, 5, 7, 4))
        m = len(rod)
        n = np.tile([0.0, 0.0, 1.0], (m, 1))
        b = 1e-6 * rng.standard_normal((m, 3))
        b[:, 2] = np.where(rod < 2, -1e-5 * rng.uniform(0.5, 1.5, m), 1e-9)  # rods 0, 1 pressed; 2, 3 a hair away
        f_all, *_, res_all, tol_all = ca.admm_contact(rods, b, n, MU, rtol=1e-10, max_iterations=50000)
        f, z, rung, it, res, tol = ca.admm_on_touching_rods(rods, b, n, MU, rtol=1e-10, max_iterations=50000)
        assert res <= tol and res_all <= tol_all
        np.testing.assert_allclose(f, f_all, atol=1e-6 * np.abs(f_all).max())
        pulled = np.abs(f[rod >= 2]).max() > 0
        added += pulled
        sigma = rods.apply(f) + b
        assert np.all(sigma[rod >= 2, 2][f[rod >= 2, 2] == 0] >= -1e-9 * np.abs(b).max())  # no left-out point inside
    assert added > 0  # some seed's coupling pulled a left-out rod into contact: the add path ran


def test_a_sub_operator_on_some_points_is_the_dense_principal_sub_operator():
    """The operator on a subset of points (some rods cut to a few of their points, others whole) is
    the dense operator's principal sub-block: its product and its (G + rho I)^-1."""
    rods, dense, _, rod, rng = _rod_block_problem(5, sizes=(6, 5, 7, 4))
    keep = np.flatnonzero((rod == 1) | np.isin(np.arange(len(rod)), [0, 2, 11, 14, 15]))  # rod 1 whole, 0 and 2 cut, 3 out
    sub = rods.restrict_points(keep)
    assert sub is rods.restrict_points(keep)  # kept, with its rho ladder
    sel = (3 * keep[:, None] + np.arange(3)).ravel()
    G = dense.C[np.ix_(sel, sel)] + np.diag(np.repeat(dense.inv_k[keep], 3))
    r = rng.standard_normal((len(keep), 3))
    np.testing.assert_allclose(sub.apply(r).ravel(), G @ r.ravel(), rtol=1e-12)
    for rho in (1e-6, 1e-4, 1e-2):
        np.testing.assert_allclose(sub._solve(sub._factorise(rho), r, rho).ravel(), np.linalg.solve(G + rho * np.eye(len(G)), r.ravel()), rtol=1e-9)


def test_a_rod_with_few_touching_points_takes_part_with_those_alone():
    """On a rod where a few of its points reach the indenter unloaded, only those take part; the
    others are checked after and added where the loaded ones pull them in (through the rod's own
    compliance). The forces equal the solve on every point."""
    added = 0
    for seed in range(8):
        rods, _, _, rod, rng = _rod_block_problem(40 + seed, sizes=(8, 9, 7))
        m = len(rod)
        n = np.tile([0.0, 0.0, 1.0], (m, 1))
        b = 1e-6 * rng.standard_normal((m, 3))
        first = np.r_[0, np.cumsum(np.bincount(rod))[:-1]]
        b[:, 2] = 1e-9  # a hair away ...
        b[first, 2] = b[first + 1, 2] = -1e-5  # ... but for two points of each rod: fewer than WHOLE_ROD_FRACTION
        f_all, *_, res_all, tol_all = ca.admm_contact(rods, b, n, MU, rtol=1e-10, max_iterations=50000)
        f, z, rung, it, res, tol = ca.admm_on_touching_rods(rods, b, n, MU, rtol=1e-10, max_iterations=50000)
        assert res <= tol and res_all <= tol_all
        np.testing.assert_allclose(f, f_all, atol=1e-6 * np.abs(f_all).max())
        first_problem = next(iter(rods._restricted.values()))
        assert len(first_problem.points) == 2 * len(first)  # the pressed points alone
        loaded = np.flatnonzero(f[:, 2] != 0)
        added += len(set(loaded) - set(first) - set(first + 1)) > 0
        sigma = rods.apply(f) + b
        assert np.all(sigma[f[:, 2] == 0, 2] >= -1e-9 * np.abs(b).max())  # no left-out point inside
    assert added > 0  # some seed pulled a left-out point into contact: the add path ran


# ---------------------------------------------------------------------------------- bounded work
def test_the_iteration_bound_holds_and_the_residual_is_reported():
    rng = np.random.default_rng(4)
    m = 30
    G = ca.DenseDelassus(_random_compliance(m, rng, 1e-2), np.full(m, 1e7))  # badly conditioned
    n = np.tile([0.0, 0.0, 1.0], (m, 1))
    b = 1e-4 * rng.standard_normal((m, 3))
    f, z, rung, it, res, tol = ca.admm_contact(G, b, n, MU, rtol=1e-12, max_iterations=7)
    assert it == 7 and res > tol  # stopped at the bound and said so
    assert np.all(np.isfinite(f))


def test_the_compiled_iteration_is_the_numpy_one():
    """One ADMM map of fem.admm_kernels against the module docstring's formulas in numpy (De Saxce's
    correction, the cone projection, the multiplier update), dense and rod by rod."""
    from fem import admm_kernels as ak

    G, b, n = _random_problem(7)
    n = _normals(len(b), np.random.default_rng(8))
    rng = np.random.default_rng(9)
    y, z, s = (1e-3 * rng.standard_normal(b.shape) for _ in range(3))
    G_rods = _rod_block_problem(10, sizes=(9, 12, 1, 8))[0]
    for G, rung in ((G, -1), (G, 2), (G_rods, -1), (G_rods, 2)):
        rho = G.rho(rung)
        rhs = rho * y - z - b - s
        x = G.solve(rhs, rung)
        s_ref = _de_saxce_numpy(rhs - rho * x + b, n, MU)
        y_ref = _project_cone_numpy(x + z / rho, n, MU)
        z_ref = z + rho * (x - y_ref)
        y2, z2, s2 = np.empty_like(y), np.empty_like(z), np.empty_like(s)
        primal, dual, y_max = ak._step(*G.kernel_operator(rung), rho, b, n, MU, y, z, s, y2, z2, s2)
        np.testing.assert_allclose(y2, y_ref, rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(z2, z_ref, rtol=1e-12, atol=1e-18)
        np.testing.assert_allclose(s2, s_ref, rtol=1e-12, atol=1e-18)
        assert primal == pytest.approx(np.abs(x - y_ref).max(), rel=1e-12)
        assert dual == pytest.approx(np.abs(y_ref - y).max(), rel=1e-12)


def test_anderson_acceleration_reaches_the_plain_answer_in_fewer_iterations(monkeypatch):
    """The accelerated iterations solve the same problem: forces agree to the tolerance; on a coupled
    problem they take fewer iterations than plain ADMM."""
    G, b, n = _random_problem(2, m=60)
    f_aa, _, _, it_aa, res_aa, tol_aa = ca.admm_contact(G, b, n, MU, rtol=1e-8, max_iterations=20000)
    assert G.anderson_memory > 0
    monkeypatch.setattr(G, "anderson_memory", 0)
    f, _, _, it, res, tol = ca.admm_contact(G, b, n, MU, rtol=1e-8, max_iterations=20000)
    assert res <= tol and res_aa <= tol_aa
    assert it_aa < 0.8 * it
    np.testing.assert_allclose(f_aa, f, atol=20 * tol)
    pn = f_aa[:, 2]
    assert np.all(np.linalg.norm(f_aa[:, :2], axis=1) <= MU * pn * (1 + 1e-12) + 1e-15)  # in the cones


def test_a_warm_start_from_the_answer_converges_at_once():
    G, b, n = _random_problem(5)
    f, z, rung, it, res, tol = ca.admm_contact(G, b, n, MU, rtol=1e-8, max_iterations=20000)
    f2, z2, _, it2, res2, tol2 = ca.admm_contact(G, b, n, MU, f, z, rung, rtol=1e-8, max_iterations=20000)
    assert it > 10 and it2 <= 2
    np.testing.assert_allclose(f2, f, atol=tol)


# --------------------------------------------------------------------------------- whole episodes
# the tiny sensor under a flat punch, and its linear body: as tests/test_quasistatic's
from test_quasistatic import _scene, body  # noqa: E402,F401  (body is a pytest fixture)


PRESS_HOLD = [{"kind": "press", "depth_mm": 0.7, "speed_mm_s": 7.0}, {"kind": "hold", "duration_s": 0.1}]


def test_frictionless_press_admm_agrees_with_newton(tiny_mesh, body):
    """Frictionless punch on the four tips: both solvers solve the same penalty problem (Newton's
    smoothing length, 1e-7 h, is far below the penetration here), so forces agree to 0.5 %; the
    ADMM steps stay within their bound; no gravity: the clamp balances the contact force."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, PRESS_HOLD, 0.0)
    st = qs.SolveSettings(tier="linear", gravity=False)
    newton = qs.run_episode(scene, mesh, body=body, settings=st)
    admm = qs.run_episode(scene, mesh, body=body, settings=dataclasses.replace(st, contact_solver="admm"))
    on = newton.normal_force_n > 0.05 * newton.normal_force_n.max()
    assert on.sum() >= 4
    np.testing.assert_allclose(admm.normal_force_n[on], newton.normal_force_n[on], rtol=5e-3)
    np.testing.assert_allclose(admm.rod_force_n[on], newton.rod_force_n[on], atol=5e-3 * np.abs(newton.rod_force_n).max())
    assert admm.iterations.max() <= st.contact_max_iterations * 6  # the bound: iterations x linearisations
    np.testing.assert_allclose(admm.reaction_n + admm.contact_force_n, 0.0, atol=1e-8 * admm.normal_force_n.max())


def test_hold_steps_reuse_their_answer(tiny_mesh, body, monkeypatch):
    """With friction, a hold repeats the last step's problem, whose answer is its own fixed point: the
    hold steps reuse it (no iterations, the same fields). Solved anyway, from the warm start, they
    converge in a few iterations to the same forces."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, PRESS_HOLD, 0.5)
    st = qs.SolveSettings(tier="linear", gravity=False, contact_solver="admm")
    ep = qs.run_episode(scene, mesh, body=body, settings=st)
    hold = np.flatnonzero(np.diff(ep.pose[:, 2]) == 0) + 1
    assert len(hold) >= 3
    assert np.all(ep.iterations[hold] == 0) and ep.iterations[: hold[0]].max() > 20
    assert np.array_equal(ep.stress[hold], np.broadcast_to(ep.stress[hold[0] - 1], ep.stress[hold].shape))
    monkeypatch.setattr(qs, "REUSE_HOLDS", False)
    solved = qs.run_episode(scene, mesh, body=body, settings=st)
    assert np.all(solved.iterations[hold[1:]] <= 10)
    np.testing.assert_allclose(ep.rod_force_n, solved.rod_force_n, atol=1e-3 * np.abs(solved.rod_force_n).max())


def test_a_slide_sticks_then_slips_by_coulomb(tiny_mesh, body):
    """tests/test_quasistatic's slide with the ADMM solver: pressed, then slid 8 mm; the friction force
    is below mu N while the tips stick and bend the rods, and ends at mu N in gross slip (the return
    map's slip force exactly, to the solver's tolerance) with no point sticking."""
    scene0, _, mesh, _ = tiny_mesh
    mu = 0.5
    segs = [{"kind": "press", "depth_mm": 0.7, "speed_mm_s": 7.0}, {"kind": "slide", "distance_mm": 8.0, "speed_mm_s": 20.0}]
    scene = _scene(scene0, segs, friction=mu, substeps=4)
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False, substeps=4, contact_solver="admm"))
    ratio = np.hypot(ep.contact_force_n[:, 0], ep.contact_force_n[:, 1]) / np.maximum(ep.normal_force_n, 1e-12)
    first = np.flatnonzero(ep.t_s > 0.1 + 1e-9)[0]
    assert ratio[first] < 0.5 * mu and ep.stick_fraction[first] > 0.2
    end_of_slide = np.argmin(abs(ep.t_s - 0.5))
    assert ratio[end_of_slide] == pytest.approx(mu, rel=1e-3)
    assert ep.stick_fraction[end_of_slide] == 0.0
    assert ep.contact_force_n[end_of_slide, 0] > 0  # the probe drags the tips along +x


def test_a_bending_load_warns_with_its_estimated_error(tiny_mesh, body):
    """The tiny scene's own load (a sphere pressed between the rods and slid 4 mm) bends the rods far
    enough that the linear tier's small-strain kinematics are off (94 % on per-rod force against the
    nonlinear tier at 2 mm, P2): the run says so with its estimate from its own field
    (fem.rod_kinematics.first_order_force_error), which is large; a small press bends nothing and
    stays quiet."""
    from mlsim.scene import load_scene

    scene0, _, mesh, _ = tiny_mesh
    said = []
    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml").with_values({"fidelity.solve.gravity": False})
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False), log=said.append)
    assert ep.seconds["rod_bending_ratio"] > 0.1  # tips dragged over a millimetre on 9 mm rods
    assert ep.seconds["geometric_error_estimate"] > 0.3
    assert any("small-strain kinematics" in m and "nonlinear" in m and f"{ep.seconds['geometric_error_estimate']:.0%}" in m for m in said)
    said.clear()
    small = qs.run_episode(_scene(scene0, PRESS_HOLD, 0.5), mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False), log=said.append)
    assert small.seconds["geometric_error_estimate"] < 0.02 and not any("kinematics" in m for m in said)


def test_a_sub_operators_restrictions_are_its_roots():
    """Restricting a sub-operator restricts the operator it was cut from (one set of caches for all):
    the same object, and still the dense principal sub-block of the whole."""
    rods, dense, _, rod, rng = _rod_block_problem(6, sizes=(6, 5, 7, 4))
    path = np.flatnonzero(rod != 3)  # an episode's points
    sub = rods.restrict_points(path)
    touching = np.array([0, 1, 2, 7, 8, 12, 13])  # indices into the sub-operator's points
    inner = sub.restrict_points(touching)
    assert inner is rods.restrict_points(path[touching])
    sel = (3 * path[touching][:, None] + np.arange(3)).ravel()
    G = dense.C[np.ix_(sel, sel)] + np.diag(np.repeat(dense.inv_k[path[touching]], 3))
    r = rng.standard_normal((len(touching), 3))
    np.testing.assert_allclose(inner.apply(r).ravel(), G @ r.ravel(), rtol=1e-12)
    rho = inner.rho(2)
    np.testing.assert_allclose(inner.solve(r, 2).ravel(), np.linalg.solve(G + rho * np.eye(len(G)), r.ravel()), rtol=1e-9)


def test_running_out_of_iterations_with_left_out_points_inside_is_reported():
    """When the iteration budget ends before the left-out points are checked in, the force those
    points lack (k |sigma_n| each) is part of the residual: the answer is never reported converged
    with points inside the indenter (it was, with 3-15 points inside, on 5 iterations)."""
    seen_inside = 0
    for seed in range(40, 48):
        rods, _, _, rod, rng = _rod_block_problem(seed, sizes=(8, 9, 7))
        m = len(rod)
        n = np.tile([0.0, 0.0, 1.0], (m, 1))
        b = 1e-6 * rng.standard_normal((m, 3))
        first = np.r_[0, np.cumsum(np.bincount(rod))[:-1]]
        b[:, 2] = 1e-9
        b[first, 2] = b[first + 1, 2] = -1e-5  # two pressed points per rod: the others left out at first
        for budget in (5, 20):
            f, z, rung, it, res, tol = ca.admm_on_touching_rods(rods, b, n, MU, rtol=1e-10, max_iterations=budget)
            assert it == budget
            sigma_n = (rods.apply(f) + b)[:, 2]
            inside = (f[:, 2] == 0) & (sigma_n < 0)
            if inside.any():
                seen_inside += 1
                assert res > tol
    assert seen_inside >= 8  # the case arose (at 5 iterations on every seed)


def test_the_rod_blocks_are_the_same_bits_on_any_number_of_blas_threads():
    """The rod blocks' eigendecompositions, their inverses per rho and so the ADMM answer are the
    same bits in a process on two BLAS threads as on one (a dataset worker's): on two threads the
    inverses' products rounded differently (the screw sensor's first factorisation: an ADMM solve at
    rtol 1e-7 took 93 iterations against one thread's 96), and on a loaded 2-core machine its 25
    eigendecompositions took 3.2 s against 28 ms. Their LAPACK calls run on one thread (on main
    this test fails: the inverses differ in their last bits)."""
    from threadpoolctl import threadpool_limits

    made, _, _, rod, rng = _rod_block_problem(7, sizes=(34, 30, 26))  # (its inputs on this process's threads)
    m = len(rod)
    n = np.tile([0.0, 0.0, 1.0], (m, 1))
    b = 1e-6 * rng.standard_normal((m, 3))
    b[:, 2] = -1e-5 * rng.uniform(0.0, 1.5, m)
    cut = np.flatnonzero(rng.uniform(size=m) < 0.3)  # every rod cut: their sub-blocks diagonalised
    answers = []
    for threads in (1, 2):
        with threadpool_limits(threads, user_api="blas"):
            rods = ca.RodBlockDelassus(made.blocks, made.H, rod, 1.0 / made.inv_k)
            f, *_ = ca.admm_contact(rods, b, n, MU, rtol=1e-9, max_iterations=20000)
            sub = rods.restrict_points(cut)
            answers.append([*rods._eig, *rods._Q, *sub._eig, *sub._Q, *rods.kernel_operator(0)[1:4], *rods.kernel_operator(3)[1:4], f])
    assert len(answers[0]) == len(answers[1])
    for one, two in zip(*answers):
        np.testing.assert_array_equal(one, two)
