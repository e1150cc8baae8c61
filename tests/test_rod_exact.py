"""Geometrically exact rod kinematics of the linear tiers (fem.rod_exact, rod_kinematics = "cosserat"):
the layered section, the roots' motion, q's order at small load, the P-delta moment, the option's
plumbing, and the tiny scene's press and slide against the nonlinear tier (the reference of the
accuracy claims, in the default suite)."""

from __future__ import annotations


import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from fem import condensed
from fem import cosserat_rod as cr
from fem import quasistatic as qs
from fem import rod_error
from fem import rod_exact as rx
from fem import rod_kinematics as rk


@pytest.fixture(scope="module")
def body(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    lame, rho, _ = qs.layer_materials(scene)
    return qs.LinearBody(mesh, lame, rho, "P2P1", gravity=True)


@pytest.fixture(scope="module")
def rod0(tiny_mesh, body):
    """Rod 0's contact points (tip face and sides), its Cosserat kinematics on the body's root motion (its
    root at rest without contact), and a unit load pattern: 0.05 N along x over the tip face by area."""
    scene, _, mesh, _ = tiny_mesh
    tip_z = qs.tip_height_m(mesh)
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, 2e-3))
    points = points.subset(np.flatnonzero(points.rod == 0))
    sections = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], scene.sensor.base.thickness_mm * 1e-3, tip_z)
    O = qs._on_dofs(rx.root_observation(mesh.points, sections), body)
    C, A = qs.compliance(body, points.W, observe=O)
    kin = rx.CosseratKinematics(sections, qs._rod_section(scene), A, np.zeros(A.shape[0]), points.X, points.rod)
    tip = points.X[:, 2] >= tip_z - 1e-9
    f = np.zeros((points.m, 3))
    f[tip, 0] = 0.05 * points.area_m2[tip] / points.area_m2[tip].sum()
    return kin, points, C, f


def test_a_layered_section_of_one_material_is_the_solid_section():
    """Three layers of one material sum to the solid round section (Cowper's coefficient of its nu)."""
    solid = cr.RodSection.circular(0.009, 2.5e-3, 1.5e6, 0.45)
    layered = rx.layered_section(2.5e-3, 0.009, [1.5e6] * 3, [0.45] * 3, [0.2e-3, 0.5e-3])
    for name in ("axial_n", "shear_n", "bending_n_m2", "torsion_n_m2"):
        np.testing.assert_allclose(getattr(layered, name), getattr(solid, name), rtol=1e-12)
    # a stiff skin dominates bending more than stretch (its fourth-power lever)
    stiff = rx.layered_section(2.5e-3, 0.009, [15e6, 1.5e6, 1.5e6], [0.45] * 3, [0.2e-3, 0.5e-3])
    assert stiff.bending_n_m2[0] / solid.bending_n_m2[0] > stiff.axial_n / solid.axial_n > 1.0
    with pytest.raises(ValueError, match="one thickness per layer"):
        rx.layered_section(2.5e-3, 0.009, [1.5e6] * 3, [0.45] * 3, [0.2e-3])


def test_the_root_rotation_is_the_exponential_map():
    theta = np.array([[0.3, -0.2, 0.1], [0.0, 0.0, 0.0], [1e-14, 0.0, 0.0]])
    q = rx._rotation_quaternion(theta)
    np.testing.assert_allclose(cr.rotation_matrix(q), Rotation.from_rotvec(theta).as_matrix(), atol=1e-14)


def test_attachments_put_points_on_their_segment():
    X = np.array([[0.1e-3, 0.0, 0.0], [0.0, 0.2e-3, 4.5e-3], [0.3e-3, 0.0, 9e-3], [0.0, 0.0, 9.5e-3]])
    seg, along, off = rx.attachments(X, np.zeros(2), 0.0, 9e-3, 8)
    assert seg.tolist() == [0, 4, 7, 7]
    np.testing.assert_allclose(along, [0.0, 0.0, 1.0, 1.0], atol=1e-12)
    np.testing.assert_allclose(off[:, :2], X[:, :2])
    assert np.all(off[:, 2] == 0)


def test_the_straight_rods_unit_responses_are_its_gradients_solve(rod0):
    """The rounds' linear rod (CosseratKinematics._linear_dofs, precomputed responses to unit loads) is the
    straight rod's Hessian solve of the loads' gradient, for any forces on rod 0's points and tip loads."""
    kin, points, _, _ = rod0
    rng = np.random.default_rng(3)
    f, F, M = rng.normal(size=(points.m, 3)), rng.normal(size=3), 1e-3 * rng.normal(size=3)
    g0, _ = cr.gradient_and_hessian(kin._straight, kin.section, np.array([1.0, 0.0, 0.0, 0.0]), F, M,
                                    loads=cr.PointLoads(*kin._attach[0], f), hessian=False)
    expected = -cr._cho_solve(kin._H0_factor, g0)
    np.testing.assert_allclose(kin._linear_dofs(0, f, F, M), expected, rtol=0, atol=1e-12 * np.abs(expected).max())


def test_q_vanishes_without_force_and_is_quadratic_at_small_force(rod0):
    """q is the rod's nonlinear part: zero at zero force, second order in it (q(2 f) = 4 q(f) to 3 %
    at 1 % of the unit pattern), and at the unit pattern the tip's drop, the largest term, is
    downward (a bent rod's tip comes down)."""
    kin, points, _, f = rod0
    q0, load0 = kin.q_and_load(np.zeros_like(f))
    assert not q0.any() and not load0.any()
    q1 = kin.q(0.01 * f)
    q2 = kin.q(0.02 * f)
    assert np.abs(q1).max() > 0
    np.testing.assert_allclose(q2, 4.0 * q1, rtol=0, atol=0.03 * 4.0 * np.abs(q1).max())
    q = kin.q(f)
    assert q[:, 2].mean() < 0
    # the rounds' batch over the loaded rods (padded points) is the per-rod rule, point by point
    (j, state, u_r, th_r, _, d_lin, _), = kin._answers(f)
    np.testing.assert_allclose(q[kin._points[j]], kin._nonlinear_part(j, state, u_r, th_r, d_lin, kin.X[kin._points[j]]),
                               rtol=0, atol=1e-12 * np.abs(q).max())
    # each rod's largest axial contact load since it was cleared (fem.quasistatic._collapse_refused judges a failed step by it)
    kin.axial_peak_n[:] = 0.0
    press = f.copy()
    press[:, 2] = -np.abs(f[:, 0])  # 0.05 N down on the tip face
    kin.q(press)
    kin.q(0.5 * press)
    assert kin.axial_peak_n[j] == pytest.approx(0.05, rel=1e-12) and not np.delete(kin.axial_peak_n, j).any()


def test_the_pdelta_load_carries_the_bent_rods_extra_root_moment(rod0):
    """Under a compressive tip load P with a sideways push H, the P-delta load's moment about the root is
    the bent rod's extra root moment: P times the tip face's sideways travel d_x plus H times its
    (negative) vertical travel d_z, to 2 % (the face's points move a little differently from its centre)."""
    kin, points, _, f = rod0
    tip = points.X[:, 2] >= points.X[:, 2].max() - 1e-9
    push = f.copy()
    push[tip, 2] = -0.1 * points.area_m2[tip] / points.area_m2[tip].sum()
    _, load = kin.q_and_load(push)
    (state, loads, u_r, _, _), = kin.solve_rods(push).values()
    travel = (loads.positions(state) - points.X)[tip].mean(axis=0) - u_r
    lever = points.X[tip, 2] - kin.root_X[0, 2]
    moment_y = float(np.sum(lever * load[tip, 0]))
    assert travel[2] < 0 < travel[0]
    assert moment_y == pytest.approx(0.1 * travel[0] + 0.05 * travel[2], rel=0.02)


def test_the_error_estimate_is_first_order_in_the_load_and_sees_no_release(rod0):
    """The tier's own estimate (:func:`fem.rod_error.force_error_estimate`) is of terms quadratic in
    the load (the rod's end turned with its tip, the section's mismatch times the nonlinear part), so relative to the
    force it is first order: a tenth of the load, a tenth of the estimate (to the rotation's next order). Without the
    body's local compliance it is NaN; a rod that stays loaded is no release."""
    kin, points, C, f = rod0
    assert np.isnan(rod_error.force_error_estimate(kin, f[None], np.ones(1)).force)
    cols = lambda p: (3 * np.asarray(p)[:, None] + np.arange(3)).ravel()  # noqa: E731
    kin.local_compliance = lambda p: C[np.ix_(cols(p), cols(p))]
    try:
        big, small = (rod_error.force_error_estimate(kin, s * f[None], np.ones(1)) for s in (2.0, 0.2))
        assert big.force > 0.0 and abs(small.force / big.force - 0.1) <= 0.005, (small, big)  # measured 0.1003
        both = rod_error.force_error_estimate(kin, np.stack([2.0 * f, 1.5 * f]), np.ones(2))
        assert both.releases == []
        # let go after a bend of 1.6 % of the rod's length: no release below RELEASE_SIDEWAYS; 10 x the load, one
        let_go = rod_error.force_error_estimate(kin, np.stack([20.0 * f, np.zeros_like(f)]), np.ones(2))
        assert let_go.releases == [(1, int(kin.sections.rods[0]))], let_go
        assert rod_error.force_error_estimate(kin, np.stack([2.0 * f, np.zeros_like(f)]), np.ones(2)).releases == []
    finally:
        kin.local_compliance = None


def test_the_error_estimate_does_not_hold_for_a_rod_dragged_over_near_buckling(rod0):
    """A rod whose tip moved sideways past a tenth of its length under more than half its free Euler load along its
    axis, sliding (its sideways force at the friction limit), is dragged over near buckling (fem.rod_error.BENT_AXIAL):
    its tip goes where the friction limit over its near-buckling lateral stiffness puts it (the swipe over 12 x 5 mm
    rods: estimated 8-15 %, measured 23-28 % in force), so the estimate says it does not hold there, naming the first
    step and the rod. Held by friction below its limit (the direction test's pushed rod: 1.1 % off), bent as far under
    a small axial load, or pressed as hard straight, it holds."""
    from fem.elastica import euler_load_clamped_free_n

    kin, points, C, f = rod0
    cols = lambda p: (3 * np.asarray(p)[:, None] + np.arange(3)).ravel()  # noqa: E731
    kin.local_compliance = lambda p: C[np.ix_(cols(p), cols(p))]
    tip = np.flatnonzero(f[:, 0] > 0.0)
    down = np.zeros_like(f)
    down[tip, 2] = -points.area_m2[tip] / points.area_m2[tip].sum()  # 1 N down over the tip face by area
    sec = kin.section
    euler_n = euler_load_clamped_free_n(min(sec.bending_n_m2), sec.length_m)

    def sideways(load):
        (_, state, *_), = [a for a in kin._answers(load) if a[0] == 0]
        return float(np.linalg.norm(state.x[-1, :2] - kin.root_X[0, :2])) / sec.length_m

    def estimate(loads, friction):
        return rod_error.force_error_estimate(kin, np.stack(loads), np.ones(len(loads)), friction=friction)

    try:
        near, far = 0.55 * euler_n * down, 0.2 * euler_n * down
        dragged = 3.0 * f + near  # 0.15 N sideways at 0.55 x the free Euler load: 0.28 L
        assert sideways(dragged) > rod_error.RELEASE_SIDEWAYS
        limit = 0.15 / (0.55 * euler_n)  # the friction coefficient it slides at
        est = estimate([near, dragged], limit)
        assert est.bent == [(1, int(kin.sections.rods[0]))] and est.releases == [], est
        # held by friction below its limit, or with no friction given: not dragged over
        assert estimate([near, dragged], 1.5 * limit).bent == [] and estimate([near, dragged], None).bent == []
        # as far sideways under a fifth of the load (0.24 L), and pressed straight (0.03 L, the tip face's eccentricity)
        light = 5.0 * f + far
        assert sideways(light) > rod_error.RELEASE_SIDEWAYS
        assert estimate([light], 0.25 / (0.2 * euler_n)).bent == []
        assert sideways(near) < 0.05 and estimate([near], 0.0).bent == []  # frictionless: sliding, but straight
    finally:
        kin.local_compliance = None


def test_the_section_identified_from_the_meshs_rod_gives_the_straight_rod_its_lateral_tip_compliance(rod0, tiny_mesh, monkeypatch):
    """The tiny mesh's rod is stiffer sideways than the layered section (fTetWild's faceted circle, the P2
    elements): the identified bending and shear stiffnesses give the straight Cosserat rod exactly the mesh's lateral
    tip compliance on average (both scale the straight rod's compliance by the same factor). Rods that scatter about
    the section within their spread keep it; a systematic offset is identified."""
    kin, points, C, f = rod0
    scene = tiny_mesh[0]
    cols = lambda p: (3 * np.asarray(p)[:, None] + np.arange(3)).ravel()  # noqa: E731
    local = lambda p: C[np.ix_(cols(p), cols(p))]  # noqa: E731
    kin.local_compliance = local
    try:
        ratio = rod_error.lateral_compliance_ratio(kin, 0)
        assert np.all((ratio > 0.9) & (ratio < 0.98)), ratio  # measured 0.962 and 0.960 on the shipped mesh
        scale = 1.0 / ratio.mean()  # one rod, two directions: their spread 0.1 % against a 4 % offset
        assert rod_error.identified_stiffness_scale(kin) == pytest.approx(scale, rel=1e-12)
        identified = rx.CosseratKinematics(kin.sections, rx.stiffened(kin.section, scale), kin.A, kin.obs_0, points.X, points.rod)
        identified.local_compliance = local
        assert rod_error.lateral_compliance_ratio(identified, 0).mean() == pytest.approx(1.0, abs=1e-9)
        assert identified.section.axial_n == kin.section.axial_n and identified.section.torsion_n_m2 == kin.section.torsion_n_m2
    finally:
        kin.local_compliance = None
    # the rule, on ratios given: a scatter about 1 keeps the section, an offset beyond two standard errors does not
    for ratios, expected in (([1.02, 0.98, 1.03, 0.97], 1.0), ([0.95, 0.94, 0.96, 0.95], 1.0 / 0.95), ([1.0], 1.0)):
        # rods 0..n-1 with a tip face and these ratios, one more without (it is left out)
        monkeypatch.setattr(rod_error, "lateral_compliance_ratio", lambda kin, j, r=ratios: np.array([r[j]]) if j < len(r) else None)
        fake = type("K", (), {"sections": type("S", (), {"rods": np.arange(len(ratios) + 1)})()})()
        assert rod_error.identified_stiffness_scale(fake) == pytest.approx(expected, rel=1e-12), ratios


def test_the_section_identified_from_the_couple_and_the_force_gives_the_straight_rod_both_tip_compliances(rod0, tiny_mesh):
    """A flat face guides a rod, whose deflection is the friction's cantilever deflection less the face's moment's: the
    section must answer a couple on the tip face as the mesh's rod does, not only a sideways force. The tiny mesh's
    rod answers a couple less than the layered section (ratio below 1, measured 0.70 and 0.74 here) and a force 4 %
    less; the identified bending and shear stiffnesses (E I from the couple, kappa G A from the force) give the straight
    Cosserat rod the mesh's couple compliance to round-off and its force compliance to 1e-3 (measured 8e-4: the
    identification splits the force compliance as the continuous cantilever's, L^3 / 3 E I + L / kappa G A, where the
    8-segment rod's split differs slightly)."""
    kin, points, C, f = rod0
    cols = lambda p: (3 * np.asarray(p)[:, None] + np.arange(3)).ravel()  # noqa: E731
    kin.local_compliance = lambda p: C[np.ix_(cols(p), cols(p))]
    try:
        couple, force = rod_error.couple_compliance_ratio(kin, 0), rod_error.lateral_compliance_ratio(kin, 0)
        assert np.all((couple > 0.5) & (couple < 0.95)) and np.all(force < 0.98), (couple, force)
        bending, shear = rod_error.identified_section_scales(kin)
        assert bending == pytest.approx(1.0 / couple.mean(), rel=1e-12)
        identified = rx.CosseratKinematics(kin.sections, rx.stiffened(kin.section, bending, shear), kin.A, kin.obs_0, points.X, points.rod)
        identified.local_compliance = kin.local_compliance
        assert rod_error.couple_compliance_ratio(identified, 0).mean() == pytest.approx(1.0, abs=1e-9)
        assert rod_error.lateral_compliance_ratio(identified, 0).mean() == pytest.approx(1.0, abs=1e-3)
        assert identified.section.axial_n == kin.section.axial_n and identified.section.torsion_n_m2 == kin.section.torsion_n_m2
    finally:
        kin.local_compliance = None


def test_the_scene_switch_is_validated(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    cos = scene.with_values({"fidelity.solve.rod_kinematics": "cosserat", "fidelity.solve.contact_solver": "newton"})
    with pytest.raises(ValueError, match='rod_kinematics = "cosserat" needs fidelity.solve.contact_solver = "admm"'):
        qs.run_episode(cos, mesh)


def test_the_tiny_press_and_slide_within_5_percent_of_the_nonlinear_tier(tiny_mesh, body):
    """The tiny scene (a 6 mm sphere pressed 1 mm between four 2 x 2 rods, then slid 4 mm with mu 0.8:
    rods tilt 10-15 deg), linear tier, against the nonlinear tier on the same 2.5 mm mesh, relative
    Frobenius errors over frames and rods (mlsim.studies.accuracy): measured rod-base von Mises / per-rod
    contact force / tip displacement 2.5 / 4.4 / 4.0 % with Cosserat rods, 18.5 / 16.1 / 18.4 % with
    second-order kinematics, 52 / 93 / 48 % with first order; the reduced tier 2.5 / 4.2 / 3.8 % (with the
    neo-Hookean axial law of 2026-11-28: 2.5 / 4.5 / 3.9 % and 2.6 / 4.3 / 3.8 %; with the rounds tested on their
    residual, solve stage 18, on the shipped 2027-tet mesh: 2.0 / 2.3 / 2.0 % and 2.2 / 2.1 / 1.8 %, stage 17 there
    2.1 / 2.3 / 2.0 % and 2.2 / 2.1 / 1.9 %; with the section identified from the mesh's rods, stage 22: 2.8 / 1.5 /
    1.5 % and 3.0 / 1.4 / 1.5 %). About 25 s,
    the nonlinear tier most."""
    from mlsim.studies.accuracy import relative_error, rod_measures

    scene, _, mesh, _ = tiny_mesh
    base = scene.sensor.base.thickness_mm * 1e-3
    ref = rod_measures(qs.run_episode(scene.with_values({"fidelity.solve.tier": "nonlinear"}), mesh), base)
    cos = scene.with_values({"fidelity.solve.rod_kinematics": "cosserat"})
    errors, estimates = {}, {}
    for tier in ("linear", "reduced"):
        s = cos.with_values({"fidelity.solve.tier": tier})
        ep = qs.run_episode(s, mesh, body=body if tier == "linear" else None)
        m = rod_measures(ep, base)
        errors[tier] = {k: relative_error(m[k], ref[k]) for k in m}
        estimates[tier] = ep.summary()
    for tier, err in errors.items():
        assert err["rod_base_von_mises"] <= 0.05, (tier, err)
        assert err["rod_contact_force"] <= 0.05, (tier, err)
        assert err["tip_displacement"] <= 0.05, (tier, err)
        # the tier's own estimate (fem.rod_error.force_error_estimate) within a factor of 4 of the
        # measured force error (measured on the shipped mesh: 1.3-1.4 % estimated / 2.1-2.3 % measured), no bent rod let go
        est = estimates[tier]
        assert 0.25 * err["rod_contact_force"] <= est["geometric_error_estimate"] <= 4.0 * err["rod_contact_force"], (tier, est, err)
        assert est["geometric_error_releases"] == [], est
    # a reference that tells the kinematics apart: first order is far off it here
    first = rod_measures(qs.run_episode(scene.with_values({"fidelity.solve.tier": "linear"}), mesh, body=body), base)
    assert relative_error(first["rod_contact_force"], ref["rod_contact_force"]) > 0.3


def _flat_press(scene, depth_mm: float):
    """The default demo's load on the tiny scene: a flat face (500 mm^2) pressed depth_mm (from 0.5 mm above the
    tips) into the four rods, then slid 1.5 mm along x with mu 0.8."""
    return scene.with_values({"load.indenter.shape": "flat", "load.indenter.tip_area_mm2": 500.0, "load.indenter.diameter_mm": None,
                              "load.segments": [{"kind": "press", "depth_mm": depth_mm, "speed_mm_s": 10.0},
                                                {"kind": "slide", "distance_mm": 1.5, "speed_mm_s": 15.0, "direction_deg": 0.0}]})


def test_a_flat_press_at_the_free_euler_load_is_followed_by_held_rods(tiny_mesh, body):
    """A flat face pressed into the tiny scene's rods to about their free Euler load (1.38-1.44 N each against
    1.41 N) and slid: the face grips the tips, so the rods stand (clamped-guided: four times that load). The rods
    held by the contact in their solves (the Robin coupling) are within 5 % of the nonlinear tier:
    measured rod-base von Mises / per-rod force / tip displacement 1.4 / 1.5 / 1.6 % (``rod_coupling = "held"``,
    solve stage 22, the section identified from the mesh's rods; 1.9 / 1.4 / 1.5 % at stage 18; 1.4 / 1.3 / 3.4 % at stage 17, whose rounds stopped on the force a damped round moved; with
    the linear axial law 4.0 / 3.8 / 4.4 %). Under dead loads between
    rounds they buckled in their own solves (65 / 83 / 122 % with the buckling limit raised to 10) and are
    refused at the default limit, in the contact round, naming the field. The reduced tier (the default demo's)
    is held to the same."""
    from mlsim.studies.accuracy import relative_error, rod_measures

    scene, _, mesh, _ = tiny_mesh
    base = scene.sensor.base.thickness_mm * 1e-3
    press = _flat_press(scene, 0.9)
    ref = rod_measures(qs.run_episode(press.with_values({"fidelity.solve.tier": "nonlinear"}), mesh), base)
    assert 0.9 < np.abs(ref["rod_contact_force"][..., 2]).max() / qs._euler_load_n(scene) < 1.2
    cos = press.with_values({"fidelity.solve.rod_kinematics": "cosserat", "fidelity.solve.rod_coupling": "held"})
    said = []
    ep = qs.run_episode(cos, mesh, body=body, log=said.append)
    m = rod_measures(ep, base)
    err = {k: relative_error(m[k], ref[k]) for k in m}
    assert err["rod_base_von_mises"] <= 0.05 and err["rod_contact_force"] <= 0.05 and err["tip_displacement"] <= 0.05, err
    # the tier's own estimate, in the run log, within a factor of 4 of the measured force error (2.1 / 1.7 % on another mesh)
    est = ep.summary()["geometric_error_estimate"]
    assert 0.25 * err["rod_contact_force"] <= est <= 4.0 * err["rod_contact_force"], (est, err)
    assert any(f"estimated {est:.1%} off the nonlinear tier's" in line for line in said), said
    # the rounds tested on their residual, not on the force a round damped by round_relaxation moved (3.4 % before)
    assert err["tip_displacement"] <= 0.025, err
    # the default demo's own solve (scenes/mavig_default.toml: held rods on the reduced tier), the same checks:
    # measured 1.9 / 1.7 / 1.9 %, estimate 2.1 %, in about 1.5 s (2026-11-29)
    ep = qs.run_episode(cos.with_values({"fidelity.solve.tier": "reduced"}), mesh)
    m = rod_measures(ep, base)
    err = {k: relative_error(m[k], ref[k]) for k in m}
    assert err["rod_base_von_mises"] <= 0.05 and err["rod_contact_force"] <= 0.05 and err["tip_displacement"] <= 0.025, err
    est = ep.summary()["geometric_error_estimate"]
    assert 0.25 * err["rod_contact_force"] <= est <= 4.0 * err["rod_contact_force"], (est, err)


def test_dead_loads_past_the_buckling_limit_are_refused_in_the_contact_round(tiny_mesh, body):
    """Without the hold (dead loads between the contact's rounds, ``rod_coupling = "dead"``, the default) the
    rounds diverge past the rods' free Euler load to an answer with little force (the default demo's flat punch:
    2.8 N against 18.4 N), which a check after the step would pass. So the check runs in every round, before
    the rods are solved, and names the field."""
    scene, _, mesh, _ = tiny_mesh
    dead = _flat_press(scene, 0.9).with_values({"fidelity.solve.rod_kinematics": "cosserat"})
    with pytest.raises(qs.OutOfRangeError, match=r"a contact round: rod \d+ carries .* Cosserat rods under dead contact loads .*buckling_limit"):
        qs.run_episode(dead, mesh, body=body)


def test_a_held_rods_collapse_is_refused_with_its_load_and_a_solvers_failure_is_not():
    """A held rods' step that fails (a rod's Newton, force control) with a rod pressed past its free Euler load is a
    collapse the rounds do not follow: a RodCollapseError (an OutOfRangeError) carrying the step and the load the
    sensor carried at the last step that converged, which mlsim sweep records as the load's answer (the sweep's 5 N
    press on 12 x 3 mm rods, at 5 x, failed in a rod's Newton and was recorded as failed). Below that load the
    failure is the solver's and stays a SolverError; a refusal passes as it is; the peak is cleared for each step."""
    from types import SimpleNamespace

    from mlsim.errors import RodCollapseError

    kin = SimpleNamespace(axial_peak_n=np.array([0.3, 2.0]))
    newton = qs.SolverError("cosserat rod: Newton did not converge in 200 iterations at load step 1/16; unbalanced force 64 N")
    with pytest.raises(RodCollapseError) as caught:
        with qs._collapse_refused(kin, 0.1, "step 3 (t = 100.0 ms)", "reduced", 3, 3.258):
            kin.axial_peak_n[1] = 0.5  # the step's solves: rod 1 at 5 x its free Euler load of 0.1 N
            raise newton
    said = str(caught.value)
    assert said.startswith("step 3 (t = 100.0 ms): the rods collapse: after the last step that converged, at 3.258 N on the indenter, "
                           "this step's contact rounds loaded rod 1 with up to 0.5 N along its axis, 5.00 x its free Euler load 0.1 N (1.25 x"), said
    assert "unbalanced force 64 N" in said and 'fidelity.solve.dynamics = "backward_euler"' in said and caught.value.__cause__ is newton
    assert isinstance(caught.value, qs.OutOfRangeError) and caught.value.force_n == 3.258 and caught.value.step == 3
    assert kin.axial_peak_n[0] == 0.0  # the last step's peaks cleared on entry
    with pytest.raises(qs.SolverError) as caught:
        with qs._collapse_refused(kin, 0.1, "step 4", "reduced", 4, 3.3):
            kin.axial_peak_n[:] = 0.09
            raise newton
    assert caught.value is newton and not isinstance(caught.value, qs.OutOfRangeError)
    refusal = qs.OutOfRangeError("small_strain_limit")
    with pytest.raises(qs.OutOfRangeError) as caught:
        with qs._collapse_refused(kin, 0.1, "step 5", "reduced", 5, 3.3):
            kin.axial_peak_n[:] = 1.0
            raise refusal
    assert caught.value is refusal


def _tip_history(ep) -> np.ndarray:
    """The rods' tip-face centre displacement (S, R, 3) m at every step."""
    P, tets = ep.mesh_points, ep.mesh_tets
    out = []
    for r in range(ep.rod_force_n.shape[1]):
        verts = np.unique(tets[ep.tet_rod == r])
        top = verts[P[verts, 2] >= P[verts, 2].max() - 1e-9]
        out.append(ep.displacement[:, top].mean(axis=1))
    return np.stack(out, axis=1).astype(float)


def test_rods_released_from_a_drag_ring_as_the_nonlinear_tiers_dynamics(tiny_mesh, body):
    """The tiny scene's sphere pressed 1 mm, dragged 3 mm (two rods bent 1.2 mm) and lifted at 300 mm/s, under
    backward Euler dynamics at 300 frames/s (5 steps a frame: the rods' 323 Hz first mode at 4.6 steps a period,
    fidelity.solve.steps_per_period): released, the rods swing through straight to about a fifth of their bend and
    ring down. The linear tier's Cosserat rods with their inertia (fem.cosserat_dynamics) follow the nonlinear
    tier's dynamics: measured on the shipped mesh rod-base von Mises / per-rod force / tip displacement
    3.3 / 2.7 / 2.0 % over the frames, the tips' history after the release 9.9 % (the first overshoot 10 %
    short of the reference's 19 % of the bend); quasi-static, the rods stop dead at straight (100 % off after
    the release); with the roots clamped under the contact forces alone (not turning under the rods' inertial
    reaction), on another mesh of the scene, 19 %, the rods ringing about 6 % fast. About 10 s."""
    from mlsim.studies.accuracy import relative_error, rod_measures

    scene, _, mesh, _ = tiny_mesh
    lift = scene.with_values({
        "camera.fps": 300.0, "camera.exposure_ms": 3.0, "fidelity.solve.dynamics": "backward_euler", "fidelity.solve.substeps": 5,
        "load.segments": [{"kind": "press", "depth_mm": 1.0, "speed_mm_s": 50.0},
                          {"kind": "slide", "distance_mm": 3.0, "speed_mm_s": 100.0, "direction_deg": 90.0},
                          {"kind": "release", "distance_mm": 1.5, "speed_mm_s": 300.0}]})
    base = scene.sensor.base.thickness_mm * 1e-3
    ref_ep = qs.run_episode(lift.with_values({"fidelity.solve.tier": "nonlinear"}), mesh)
    said = []
    ep = qs.run_episode(lift.with_values({"fidelity.solve.rod_kinematics": "cosserat"}), mesh, body=body, log=said.append)
    assert any("Cosserat rods have their inertia" in line for line in said), said
    # the bent rods let go by the lift: the tier's own estimate says it does not hold there (fem.rod_exact), naming the steps
    releases = ep.summary()["geometric_error_releases"]
    assert releases and {r for _, r in releases} <= set(range(ep.rod_force_n.shape[1])), releases
    assert any("it does not hold here: bent rods are let go in steps" in line for line in said), said
    ref, m = rod_measures(ref_ep, base), rod_measures(ep, base)
    err = {k: relative_error(m[k], ref[k]) for k in m}
    assert err["rod_base_von_mises"] <= 0.05 and err["tip_displacement"] <= 0.05 and err["rod_contact_force"] <= 0.05, err
    # after the last step in contact: the swing through straight and its ringing, step by step
    normal = -ref_ep.rod_force_n[:, :, 2].sum(axis=1)
    after = slice(int(np.flatnonzero(normal > 1e-4).max()) + 1, None)
    tips_ref, tips = _tip_history(ref_ep)[after], _tip_history(ep)[after]
    bent = np.abs(_tip_history(ref_ep)[:, :, 1]).max()
    overshoot_ref, overshoot = tips_ref[:, :, 1].min(), tips[:, :, 1].min()
    assert overshoot_ref < -0.15 * bent  # a reference that swings: a quasi-static tier stops at straight
    assert abs(overshoot / overshoot_ref - 1.0) <= 0.15, (overshoot, overshoot_ref)
    assert np.linalg.norm(tips - tips_ref) / np.linalg.norm(tips_ref) <= 0.15


def test_rods_held_under_a_slid_probe_come_to_rest_under_inertia(tiny_mesh, body):
    """The tiny scene's rods under the swipe's flat probe (mu 0.3), pressed 0.1 mm, slid 2 mm at 200 mm/s and held
    20 ms, under dynamics at 300 frames/s: in the hold the rods ring down and rest. What each step's contact rounds
    leave unsettled the next step's inertial prediction carries on: at the statics' tolerance alone (1e-3 of the
    normal force) the held rods' forces alternated step by step and grew, from 0.2 to 2 mN of 353 (each 2 ms frame
    of a 480 frames/s hold lit up to 5.7 % of the press's brightest, the nonlinear tier's 1.4e-6); settled also to a
    tenth of the force the step moved (fem.rod_exact.CosseratKinematics.ROUND_STEP_FRACTION) they stay within
    0.002-0.008 mN (2.8e-4 of the press's brightest frame). About 11 s."""
    scene, _, mesh, _ = tiny_mesh
    held = scene.with_values({
        "load.indenter.shape": "flat", "load.indenter.tip_area_mm2": 500.0, "load.indenter.diameter_mm": None,
        "load.indenter.edge_radius_mm": 3.0, "load.friction_coefficient": 0.3, "load.start_gap_mm": 0.2, "load.start_xy_mm": [0.0, 0.0],
        "load.segments": [{"kind": "press", "depth_mm": 0.3, "speed_mm_s": 50.0},
                          {"kind": "slide", "distance_mm": 2.0, "speed_mm_s": 200.0, "direction_deg": 0.0},
                          {"kind": "hold", "duration_s": 0.02}],
        "camera.fps": 300.0, "camera.exposure_ms": 3.0, "fidelity.solve.dynamics": "backward_euler", "fidelity.solve.substeps": 5,
        "fidelity.solve.rod_kinematics": "cosserat", "fidelity.solve.rod_coupling": "held"})
    ep = qs.run_episode(held, mesh, body=body)
    force = ep.rod_force_n
    pressed = np.linalg.norm(force, axis=2).max()
    assert pressed > 0.3  # every rod under the face: 0.35 N each
    change = np.linalg.norm(np.diff(force, axis=0), axis=2).max(axis=1)  # (S - 1,) N, the largest rod's change a step
    hold = int(round(0.02 * 300.0 * 5))  # the hold's steps
    late = change[-hold // 2:]
    assert late.max() <= 3e-4 * pressed, (late.max(), pressed)
    # resting, not ringing on: the last steps move no more than the hold's middle ones, or than the rounds' own
    # tolerance (ROUND_RTOL_LEAST of the total normal force: with the section identified from the couple too, stage 25,
    # the hold's changes sit at 3-9e-6 N, 1.4e-5 N that tolerance)
    floor = rx.CosseratKinematics.ROUND_RTOL_LEAST * float(-force[-1, :, 2].sum())
    assert late[-5:].max() <= 2.0 * max(late[:5].max(), floor), late


def test_the_rods_inertia_is_refused_at_a_step_too_coarse_for_their_first_mode(tiny_mesh):
    """As the nonlinear tier's dynamics (the scene's check, on load): the Cosserat rods' inertia at the same steps;
    without Cosserat rods the fast tiers have no inertia and only say so in the run log (fem.quasistatic)."""
    from mlsim.errors import SceneError

    scene, _, _, _ = tiny_mesh
    coarse = {"camera.fps": 400.0, "camera.exposure_ms": 2.5, "fidelity.solve.dynamics": "backward_euler", "fidelity.solve.substeps": 2}
    with pytest.raises(SceneError, match=r"fidelity.solve.substeps = 2: a 1.25 ms step cannot resolve the rods' first bending mode"):
        scene.with_values({**coarse, "fidelity.solve.rod_kinematics": "cosserat"})
    assert scene.with_values(coarse).fidelity.solve.substeps == 2
    inertia = qs.rod_inertia(scene.with_values({**coarse, "fidelity.solve.substeps": 4, "fidelity.solve.rod_kinematics": "cosserat"}))
    assert inertia.time_step_s == pytest.approx(1.0 / 1600.0)
    # the nonlinear tier's damping ratio eta / 2 at the first mode: a_M = eta omega_1
    from fem.finite_strain import rod_first_mode_rad_s

    assert inertia.damping_per_s == pytest.approx(scene.fidelity.solve.loss_factor * rod_first_mode_rad_s(scene))


def test_rods_pressed_past_their_euler_load_stay_in_contact_as_the_slide_starts(tiny_mesh, cache):
    """The tiny sensor's rods made 12 mm tall, pressed 0.7 mm by the swipe's flat probe (mu 0.3) to 1.5 x their free
    Euler load, then slid 1 mm at 200 mm/s, under dynamics at 300 frames/s. With inertia the rods' nonlinear part
    carries their compression for a step, so a round that lets the contact go can find the rods out of the face
    while they spring back: the contact rounds also test the points the rods' new state carries into the face
    (fem.contact_admm.solve_step). Before, the steps from the slide's start alternated between no contact and
    1.3 N per rod; now within 3 % of the nonlinear tier (measured 2.9 / 2.0 / 0.8 %). About 25 s; the tall rods'
    mesh is shipped (tests/data/meshes: its fresh build took 19 s, and each build is another mesh)."""
    from mlsim.studies.accuracy import relative_error, rod_measures

    scene, _, _, _ = tiny_mesh
    tall = scene.with_values({
        "sensor.rod.height_mm": 12.0, "load.indenter.shape": "flat", "load.indenter.tip_area_mm2": 500.0, "load.indenter.diameter_mm": None,
        "load.indenter.edge_radius_mm": 3.0, "load.friction_coefficient": 0.3, "load.start_gap_mm": 0.2,
        "load.segments": [{"kind": "press", "depth_mm": 0.7, "speed_mm_s": 50.0},
                          {"kind": "slide", "distance_mm": 1.0, "speed_mm_s": 200.0, "direction_deg": 0.0}],
        "camera.fps": 300.0, "camera.exposure_ms": 3.0, "fidelity.solve.dynamics": "backward_euler", "fidelity.solve.substeps": 3})
    from mlsim import pipeline

    mesh, _ = pipeline.run(tall, out_dir=None, cache=cache, outputs=("mesh",), progress=False, log=lambda m: None).results["mesh"]
    base = tall.sensor.base.thickness_mm * 1e-3
    ref_ep = qs.run_episode(tall.with_values({"fidelity.solve.tier": "nonlinear"}), mesh)
    ep = qs.run_episode(tall.with_values({"fidelity.solve.rod_kinematics": "cosserat", "fidelity.solve.rod_coupling": "held"}), mesh)
    pressed = -ref_ep.rod_force_n[:, :, 2]
    assert pressed.max() > 1.4 * qs._euler_load_n(tall)
    touching = pressed > 0.5 * pressed.max()
    assert np.all(-ep.rod_force_n[:, :, 2][touching] > 0.5 * pressed.max())  # no step lets the rods go
    ref, m = rod_measures(ref_ep, base), rod_measures(ep, base)
    err = {k: relative_error(m[k], ref[k]) for k in m}
    assert all(e <= 0.05 for e in err.values()), err
