"""The time-stepped linear solve with contact on condensed compliance (fem.quasistatic, fem.condensed),
on the 2 x 2 tiny sensor: equilibrium, linearity, symmetry, friction, and finiteness."""

from __future__ import annotations

import numpy as np
import pytest

from fem import quasistatic as qs
from mlsim.scene import scene_from_dict


def _scene(tiny_scene, segments, friction=0.0, gravity=False, substeps=1, diameter_mm=40.0):
    data = tiny_scene.model_dump(mode="json", exclude_none=True)
    data["load"] = {
        "indenter": {"shape": "flat", "diameter_mm": diameter_mm},
        "start_xy_mm": [0.0, 0.0],
        "start_gap_mm": 0.5,
        "friction_coefficient": friction,
        "segments": segments,
    }
    data["fidelity"]["solve"] = {"tier": "linear", "substeps": substeps, "gravity": gravity}
    return scene_from_dict(data)


@pytest.fixture(scope="module")
def body(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    lame, rho, _ = qs.layer_materials(scene)
    return qs.LinearBody(mesh, lame, rho, "P2P1", gravity=False)


def test_frictionless_press_equilibrium_symmetry_linearity(tiny_mesh, body):
    scene0, _, mesh, _ = tiny_mesh
    press = [{"kind": "press", "depth_mm": 0.6, "speed_mm_s": 6.0}, {"kind": "press", "depth_mm": 0.1, "speed_mm_s": 1.0}]
    scene = _scene(scene0, press)
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))
    # no gravity: the clamp's reaction balances the contact force
    np.testing.assert_allclose(ep.reaction_n + ep.contact_force_n, 0.0, atol=1e-8 * np.abs(ep.contact_force_n).max())
    # the flat punch covers all four rods: equal shares (the mesh is not symmetric: 5 %)
    last = ep.rod_force_n[-1, :, 2]
    assert np.all(last < 0)
    np.testing.assert_allclose(last, last.mean(), rtol=0.05)
    # frictionless flat punch on fully covered tips: force proportional to indentation
    t = ep.t_s
    depth = np.interp(t, [0, 0.1, 0.2], [-0.5, 0.1, 0.2])  # mm below the tips
    f = ep.normal_force_n
    i1, i2 = np.argmin(abs(depth - 0.1)), np.argmin(abs(depth - 0.2))
    assert f[i2] / f[i1] == pytest.approx(depth[i2] / depth[i1], rel=0.02)
    # stress: the rods are in compression, finite everywhere
    assert np.all(np.isfinite(ep.stress)) and np.all(np.isfinite(ep.displacement))
    assert ep.von_mises[-1].max() > 0


def test_friction_stick_then_slip(tiny_mesh, body):
    """A flat probe pressed on the four tips, then slid 8 mm: the tangential force starts well below
    mu N while the tips stick and bend the rods, and ends at mu N (within 2 %) in gross slip."""
    scene0, _, mesh, _ = tiny_mesh
    mu = 0.5
    segs = [{"kind": "press", "depth_mm": 0.7, "speed_mm_s": 7.0},
            {"kind": "slide", "distance_mm": 8.0, "speed_mm_s": 20.0}]
    scene = _scene(scene0, segs, friction=mu, substeps=4)
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False, substeps=4))
    ratio = np.hypot(ep.contact_force_n[:, 0], ep.contact_force_n[:, 1]) / np.maximum(ep.normal_force_n, 1e-12)
    first = np.flatnonzero(ep.t_s > 0.1 + 1e-9)[0]
    assert ratio[first] < 0.5 * mu  # stick: friction not yet mobilised
    assert ep.stick_fraction[first] > 0.2
    end_of_slide = np.argmin(abs(ep.t_s - 0.5))
    assert ratio[end_of_slide] == pytest.approx(mu, rel=0.02)  # gross slip: T = mu N
    assert ep.stick_fraction[end_of_slide] == 0.0
    assert ep.contact_force_n[end_of_slide, 0] > 0  # the probe drags the tips along +x
    assert np.all(np.isfinite(ep.stress))


@pytest.mark.parametrize("case, segs, friction", [
    ("zero load", [{"kind": "hold", "duration_s": 0.1}], 0.8),
    # 2 mm per frame diagonally; mu 0.3 keeps the stick drag (about mu x 17 x 0.3 mm for these rods,
    # axially 17x stiffer than in bending) inside small strain: at mu 0.8 the guard refuses it
    ("2 mm per frame", [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0},
                        {"kind": "slide", "distance_mm": 8.0, "speed_mm_s": 60.0, "direction_deg": 45.0}], 0.3),
    ("deep press", [{"kind": "press", "depth_mm": 3.5, "speed_mm_s": 35.0}], 0.8),
])
def test_extreme_loads_converge_and_stay_finite(tiny_mesh, body, case, segs, friction):
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, segs, friction=friction, diameter_mm=12.0)
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))
    for name in ("stress", "von_mises", "sed", "displacement", "rod_force_n", "reaction_n"):
        assert np.all(np.isfinite(getattr(ep, name))), f"{case}: {name} has NaN or Inf"
    np.testing.assert_allclose(ep.reaction_n + ep.contact_force_n, 0.0, atol=1e-8 * max(np.abs(ep.contact_force_n).max(), 1e-12))
    if case == "zero load":
        assert np.all(ep.contact_force_n == 0) and np.all(ep.stress == 0)
    else:
        assert ep.normal_force_n.max() > 0


def test_ten_times_the_largest_design_load_is_refused_clearly_not_nan(tiny_mesh, body):
    """160 N (10 x the 16 N top of SPEC 1.3's force range) on four rods would shorten them by more
    than half their height: the force-controlled solve must stop with a SolverError that names the
    step and the limit, not return garbage."""
    from fem.nonlinear import SolverError

    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "force_n": 160.0, "duration_s": 0.2}], friction=0.5, diameter_mm=12.0)
    with pytest.raises(SolverError, match=r"step \d+ \(t = .* ms\).*small_strain_limit"):
        qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))


def test_force_controlled_press_reaches_the_ramp(tiny_mesh, body):
    scene0, _, mesh, _ = tiny_mesh
    segs = [{"kind": "press", "force_n": 3.0, "duration_s": 0.1}, {"kind": "hold", "duration_s": 0.05}]
    scene = _scene(scene0, segs, friction=0.5)
    ep = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))
    target = np.minimum(ep.t_s / 0.1, 1.0) * 3.0
    on = ep.t_s > 0
    np.testing.assert_allclose(ep.normal_force_n[on], target[on], rtol=1e-5)
    np.testing.assert_allclose(ep.force_target_n[on], target[on], rtol=1e-12)
    # the punch sinks as the force grows, and holds its height while the force is held (to 1 nm: the
    # height is found again at each step from an iterative contact solve with a force tolerance)
    z = ep.pose[:, 2]
    assert np.all(np.diff(z[on]) <= 1e-9)
    assert np.ptp(z[ep.t_s > 0.1 + 1e-9]) < 1e-9


def _penalty_force(k_n_per_m, z_touch, z_pass=None, seen=None):
    """F(z) = k (z_touch - z)_+ of a penalty contact, zero again below ``z_pass`` (the indenter has
    passed the points); the heights asked for are appended to ``seen``."""

    def at_z(z):
        if seen is not None:
            seen.append(z)
        f = k_n_per_m * max(z_touch - z, 0.0)
        return (0.0 if z_pass is not None and z < z_pass else f), z

    return at_z


@pytest.mark.parametrize("z_guess", [10.9e-3, 10.5e-3, 8.2e-3, 6.0e-3])
def test_the_force_search_finds_the_penalty_height_from_any_first_guess(z_guess):
    """Above contact, just past the answer or deep below it: the height k (z_touch - z) = F to 1e-6."""
    from fem.condensed import solve_points_at_force

    seen = []
    k, z_touch, target = 2000.0, 10.0e-3, 3.0  # 2 N/mm: the answer 1.5 mm below the touch
    z, payload, n = solve_points_at_force(target, z_guess, _penalty_force(k, z_touch, seen=seen), 11.0e-3, z_min=8.0e-3)
    assert z == pytest.approx(z_touch - target / k, abs=1e-9) and payload == z and n == len(seen) <= 60
    assert min(seen) >= 8.0e-3  # never below the floor, even from a first guess under it


def test_the_force_search_stays_above_its_floor_and_says_why_it_stops():
    """A target beyond the force the points can give (the indenter passes them at z_pass): a clear
    SolverError, every height asked for finite and at or above z_min; before, the march doubled its
    step 60 times and stopped at z = -1.6e18 mm."""
    from fem.condensed import solve_points_at_force
    from fem.nonlinear import SolverError

    seen = []
    with pytest.raises(SolverError, match=r"step 5: cannot reach 30 N: 10 N at z = 8\.0000 mm, the lowest height the search allows"):
        solve_points_at_force(30.0, 10.9e-3, _penalty_force(5000.0, 10.0e-3, seen=seen), 11.0e-3, case="step 5", z_min=8.0e-3)
    assert np.all(np.isfinite(seen)) and min(seen) == 8.0e-3 and len(seen) < 10
    # the force falls as the indenter goes deeper (it passed the points between two trials): refused,
    # not marched on
    seen.clear()
    with pytest.raises(SolverError, match=r"the normal force falls from 0\.2 N at z = 9\.9000 mm to 0 N .* not monotone"):
        solve_points_at_force(3.0, 9.9e-3, _penalty_force(2000.0, 10.0e-3, z_pass=9.8e-3, seen=seen), 11.0e-3, z_min=5.0e-3)
    assert min(seen) >= 5.0e-3
    with pytest.raises(ValueError, match="z_min .* must be below z_free"):
        solve_points_at_force(3.0, 9.9e-3, _penalty_force(2000.0, 10.0e-3), 11.0e-3, z_min=11.0e-3)


def test_reduced_tier_agrees_with_linear_on_a_uniform_press(tiny_mesh, body):
    """The reduced tier carries a flat punch's uniform press as the linear tier does: total force and
    volume-mean von Mises within 1 %, its 95th percentile within 2 % (the peak, at the punch's rim,
    depends on the mesh: fTetWild is not deterministic)."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0}])
    lin = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))
    red = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="reduced", gravity=False))
    assert red.normal_force_n[-1] == pytest.approx(lin.normal_force_n[-1], rel=0.01)
    w = mesh.volumes()
    assert np.sum(red.von_mises[-1] * w) == pytest.approx(np.sum(lin.von_mises[-1] * w), rel=0.01)
    assert np.percentile(red.von_mises[-1], 95) == pytest.approx(np.percentile(lin.von_mises[-1], 95), rel=0.02)
    np.testing.assert_allclose(red.reaction_n + red.contact_force_n, 0.0, atol=1e-6 * np.abs(red.contact_force_n).max())


@pytest.mark.parametrize("tier", ["linear", "reduced"])
def test_the_newton_contact_solver_gives_the_admm_answer(tiny_mesh, body, tier):
    """The two contact solvers of the linear tiers solve one contact law: a press and a slide with
    friction (stick, then slip), per-rod contact force within 0.5 % of the largest."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0},
                            {"kind": "slide", "distance_mm": 0.6, "speed_mm_s": 6.0, "direction_deg": 30.0}], friction=0.5)
    eps = {solver: qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier=tier, gravity=False, contact_solver=solver))
           for solver in ("admm", "newton")}
    ref = eps["admm"].rod_force_n
    assert np.abs(ref).max() > 0.05
    assert np.abs(eps["newton"].rod_force_n - ref).max() <= 5e-3 * np.abs(ref).max()


def _stiff_case(case: str) -> dict:
    from mlsim.materials import SHIPPED_MATERIALS

    young = SHIPPED_MATERIALS["SC37"].young_modulus_pa.value
    return {
        "nu 0.4999": {"materials": {"SC37": {"poisson_ratio": 0.4999}}},
        "1000x stiffer absorber": {"materials": {"STIFF": {"description": "1000 x SC37", "young_modulus_pa": 1000.0 * young,
                                                           "poisson_ratio": 0.45, "density_kg_m3": 1000.0}},
                                   "sensor.materials.absorber": "STIFF"},
        "0.1 mm ML layer": {"sensor.layers.ml_mm": 0.1},
    }[case]


_STIFF_CASES = ("nu 0.4999", "1000x stiffer absorber", "0.1 mm ML layer")


@pytest.mark.parametrize("case", _STIFF_CASES)
def test_stiff_sensors_in_a_frictional_episode_converge_finite_and_in_equilibrium(tiny_mesh, cache, case):
    """Stiff variants of the tiny sensor under a press and a slide with friction: each converges (or
    would raise a SolverError naming the step), with no NaN or Inf anywhere and the clamp balancing
    the contact force; a stiffer sensor needs more force for the same indentation."""
    from mlsim import pipeline

    scene0, _, mesh0, _ = tiny_mesh
    segs = [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0}, {"kind": "slide", "distance_mm": 2.0, "speed_mm_s": 20.0}]
    base = _scene(scene0, segs, friction=0.5, diameter_mm=12.0)
    scene = base.with_values(_stiff_case(case))
    mesh = mesh0 if case != "0.1 mm ML layer" else pipeline.run(scene, out_dir=None, cache=cache, outputs=("mesh",), progress=False,
                                                               log=lambda m: None).results["mesh"][0]
    ep = qs.run_episode(scene, mesh, settings=qs.SolveSettings.from_scene(scene))
    for name in qs._EPISODE_ARRAYS:
        a = getattr(ep, name)
        if a.dtype.kind == "f" and name not in ("force_target_n", "stick_fraction"):
            assert np.all(np.isfinite(a)), f"{case}: {name}"
    np.testing.assert_allclose(ep.reaction_n + ep.contact_force_n, 0.0, atol=1e-7 * np.abs(ep.contact_force_n).max())
    ref = qs.run_episode(base, mesh0, settings=qs.SolveSettings.from_scene(base))
    ratio = ep.normal_force_n.max() / ref.normal_force_n.max()
    if case == "1000x stiffer absorber":
        assert ratio > 1.5  # a rigid cap on each rod: the rods can no longer bulge at the tip
    elif case == "nu 0.4999":
        assert ratio == pytest.approx(1.0, abs=0.1)  # nearly the same material: P2P1 does not lock
    else:
        # all three layers are SC37 here, so only the mesh differs (the punch's rim crosses the
        # coarse tips: mesh-sensitive); the thin layer itself must not upset the solve
        assert ratio == pytest.approx(1.0, abs=0.2)


def test_the_far_field_basis_keeps_the_low_rank_response_off_each_rods_own_rows():
    """fem.quasistatic.far_field_basis: per rod, the response off its own rows to the tolerance in
    the Frobenius norm, zero on its own rows, with the rank of the far field (three here, under a
    tail of 1e-5), and each basis vector weighting its own rod's columns only."""
    rng = np.random.default_rng(3)
    n, patch_rod = 400, np.repeat([0, 1, 2], [4, 2, 3])
    cols = {a: (3 * np.flatnonzero(patch_rod == a)[:, None] + np.arange(3)).ravel() for a in range(3)}
    own = {0: np.arange(0, 30), 1: np.arange(30, 80), 2: np.arange(80, 100)}
    response = np.zeros((n, 3 * len(patch_rod)))
    for a, c in cols.items():
        response[:, c] = rng.standard_normal((n, 3)) @ rng.standard_normal((3, len(c))) + 1e-6 * rng.standard_normal((n, len(c)))
        response[np.ix_(own[a], c)] = rng.standard_normal((len(own[a]), len(c)))  # full rank on its own rows
    basis, coeff = qs.far_field_basis(response.astype(np.float32), patch_rod, own, rtol=1e-4)
    assert basis.shape == (9, n) and coeff.shape == (9, 3 * len(patch_rod)) and basis.dtype == np.float32
    approx = basis.T.astype(float) @ coeff
    for a, c in cols.items():
        far = response[:, c].copy()
        far[own[a]] = 0.0
        assert np.linalg.norm(approx[:, c] - far) <= 1e-4 * np.linalg.norm(far)
        np.testing.assert_array_equal(approx[np.ix_(own[a], c)], 0.0)
        rows = slice(3 * a, 3 * a + 3)  # the rods' bases one after the other
        np.testing.assert_array_equal(np.delete(coeff[rows], c, axis=1), 0.0)


def test_the_far_field_basis_is_the_same_bits_on_any_number_of_blas_threads():
    """far_field_basis's SVDs run on one BLAS thread: a process on two threads (the dataset driver,
    ``mlsim run``) makes the bits that one on one thread makes (on main this fails: two threads' SVD
    of a tall response rounds differently), and the cached model does not depend on the machine's
    thread count."""
    from threadpoolctl import threadpool_limits

    rng = np.random.default_rng(5)
    n, patch_rod = 30000, np.repeat([0, 1, 2], [7, 5, 6])  # tall and thin, as the sensors' responses
    response = (rng.standard_normal((n, 6)) @ rng.standard_normal((6, 3 * len(patch_rod)))
                + 1e-3 * rng.standard_normal((n, 3 * len(patch_rod)))).astype(np.float32)
    own = {0: np.arange(0, 300), 1: np.arange(300, 800), 2: np.arange(800, 1000)}
    made = []
    for threads in (1, 2):
        with threadpool_limits(threads, user_api="blas"):
            made.append(qs.far_field_basis(response, patch_rod, own))
    np.testing.assert_array_equal(made[0][0], made[1][0])
    np.testing.assert_array_equal(made[0][1], made[1][1])


def test_a_rods_load_reaches_the_rest_of_the_sensor_as_its_resultant(tiny_mesh, body):
    """Saint-Venant on the reduced tier's precompute: away from its own tets a rod's patch loads act
    through about six far-field vectors (the rod's resultant force and moment: 5-7 to 1e-3 of their
    norm), however many patch columns it has."""
    scene, _, mesh, _ = tiny_mesh
    red = qs.build_reduced(scene, mesh, body, qs.SolveSettings(tier="reduced", gravity=False))
    per_rod = np.array([np.sum(np.any(red.stress_coeff[:, (3 * np.flatnonzero(red.rod == r)[:, None] + np.arange(3)).ravel()] != 0, axis=1))
                        for r in np.unique(red.rod)])
    assert per_rod.sum() == len(red.stress_coeff)  # each basis vector belongs to one rod
    assert np.all((per_rod >= 5) & (per_rod <= 7)), per_rod


def test_the_field_recovery_drops_only_the_far_fields_small_entries(tiny_mesh, body, monkeypatch, tmp_path):
    """ReducedModel.far_field_rows keeps each far-field basis vector's entries of at least
    FAR_FIELD_DROP of its largest, and reduced_fields_of then differs from the dense superposition
    (basis^T coeff, in float64) by at most the dropped entries' bound, sum_k |c_k| drop peak_k."""
    scene0, _, mesh, _ = tiny_mesh
    red = qs.build_reduced(scene0, mesh, body, qs.SolveSettings(tier="reduced", gravity=False))
    A = red.far_field_rows("stress").toarray()
    B = red.stress_basis.T.astype(float)
    peak = np.abs(B).max(axis=0)
    kept = np.abs(B) >= qs.FAR_FIELD_DROP * peak
    np.testing.assert_array_equal(A, np.where(kept, B, 0.0).astype(np.float32))
    assert 0.0 < kept.mean() < 0.5  # the basis vectors decay away from their rod

    rng = np.random.default_rng(0)
    keep = np.flatnonzero(red.point_rod == red.point_rod[0])  # one rod's points, loaded
    loads = rng.standard_normal((3, len(keep), 3))
    stress, _ = qs.reduced_fields_of(red, keep, red.point_rod[keep], loads)
    # the model read back from its file (the cache's) holds the same sparse rows and gives the same bits
    red.save(tmp_path / "reduced.npz")
    back = qs.ReducedModel.load(tmp_path / "reduced.npz")
    for which in ("stress", "displacement"):
        a, b = red.far_field_rows(which), back._far_rows[which]
        assert a.shape == b.shape and (a != b).nnz == 0 and b.dtype == np.float32
    np.testing.assert_array_equal(qs.reduced_fields_of(back, keep, back.point_rod[keep], loads)[0], stress)
    Fp = np.zeros((red.stress_coeff.shape[1], 3))
    np.add.at(Fp, (3 * red.point_patch[keep][:, None] + np.arange(3)).ravel(), loads.reshape(3, -1).T)
    c = red.stress_coeff @ Fp  # (K, U)
    rows_s, own_s, _, _ = red.local_responses()[int(red.point_rod[0])]
    dense = red.stress_gravity[:, None] + B @ c
    on = np.searchsorted(np.flatnonzero(red.point_rod == red.point_rod[0]), keep)
    f_r = np.zeros((len(on) * 3, 3))
    f_r[(3 * on[:, None] + np.arange(3)).ravel()] = loads.reshape(3, -1).T
    dense[rows_s] += own_s.astype(float) @ f_r
    bound = qs.FAR_FIELD_DROP * (np.abs(c) * peak[:, None]).sum(axis=0)  # (U,)
    err = np.abs(stress - dense)
    assert np.all(err <= bound[None, :] + 1e-5 * np.abs(dense).max()), (err.max(axis=0), bound)
    # and without the drop the recovery is the dense superposition, to float32 rounding
    monkeypatch.setattr(qs, "FAR_FIELD_DROP", 0.0)
    red._far_rows.clear()
    exact, _ = qs.reduced_fields_of(red, keep, red.point_rod[keep], loads)
    np.testing.assert_allclose(exact, dense, rtol=0, atol=1e-5 * np.abs(dense).max())


def test_episodes_sharing_the_sensors_contact_operator_repeat_a_cold_episode_exactly(tiny_mesh, body):
    """The reduced tier's contact operator is the sensor's, kept with the reduced model and shared by
    its episodes (ReducedModel.contact_operator): an episode that finds its blocks, inverses and
    sub-operators made by an earlier one gives the answer of one that makes them (same scene, same
    output), and another load in between changes nothing."""
    scene0, _, mesh, _ = tiny_mesh
    press_slide = _scene(scene0, [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0},
                                  {"kind": "slide", "distance_mm": 0.6, "speed_mm_s": 6.0, "direction_deg": 30.0}], friction=0.5)
    other = _scene(scene0, [{"kind": "press", "depth_mm": 0.5, "speed_mm_s": 5.0}], friction=0.3)
    settings = qs.SolveSettings(tier="reduced", gravity=False)
    reduced = qs.build_reduced(press_slide, mesh, body, settings)
    cold = qs.run_episode(press_slide, mesh, body=body, settings=settings, reduced=reduced)
    assert cold.seconds["contact_factorisations"] > 0
    qs.run_episode(other, mesh, body=body, settings=settings, reduced=reduced)
    warm = qs.run_episode(press_slide, mesh, body=body, settings=settings, reduced=reduced)
    assert len(reduced._operators) == 1  # one operator for the sensor, not one per episode
    assert warm.seconds["contact_factorisations"] == 0  # every rung it needs was made by the first
    np.testing.assert_array_equal(warm.rod_force_n, cold.rod_force_n)
    np.testing.assert_array_equal(warm.von_mises, cold.von_mises)
    fresh = qs.run_episode(press_slide, mesh, body=body, settings=settings, reduced=qs.build_reduced(press_slide, mesh, body, settings))
    np.testing.assert_array_equal(fresh.rod_force_n, cold.rod_force_n)


def test_the_precomputed_responses_are_the_bodys_own_solves(tiny_mesh, body):
    """ReducedModel.build solves on the free DOFs only and forms the stress rows compiled (issue 40):
    a rod's point compliance block, its points' stress on its own tets and displacement at its own
    vertices are W^T K^-1 W, S K^-1 W and K^-1 W there, as LinearBody.solve, its stress operator and
    scipy give them (to 1e-12 of the largest; the model's float32 responses to their rounding)."""
    from fem import condensed

    scene, _, mesh, _ = tiny_mesh
    settings = qs.SolveSettings(tier="reduced", gravity=False)
    red = qs.build_reduced(scene, mesh, body, settings)
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, settings.contact_band_m))
    rod = int(red.local_sizes[0, 0])
    cols = (3 * np.flatnonzero(points.rod == rod)[:, None] + np.arange(3)).ravel()
    X = body.solve(points.W[:, cols].toarray())
    block = (points.W.T @ X)[cols]
    got = red.rod_blocks()[rod]
    np.testing.assert_allclose(got, 0.5 * (block + block.T), rtol=0, atol=1e-12 * np.abs(block).max())
    rows_s, stress, rows_d, disp = red.local_responses()[rod]
    want_s = (body.S @ X)[rows_s]
    want_d = X[body.vertex_dofs.ravel()][rows_d]
    np.testing.assert_allclose(stress, want_s, rtol=1e-6, atol=1e-6 * np.abs(want_s).max())
    np.testing.assert_allclose(disp, want_d, rtol=1e-6, atol=1e-6 * np.abs(want_d).max())
    assert np.abs(got).max() > 0 and np.abs(stress).max() > 0


def test_the_linear_tier_says_it_runs_quasi_static_when_dynamics_is_asked(tiny_mesh, body):
    """fidelity.solve.dynamics is the nonlinear tier's: the linear tier has no inertia. Asked for it, it
    solves the same equilibria (the same episode, bit for bit: its cache key leaves the field out, fem.stages)
    and says so in the run log rather than silently."""
    scene0, _, mesh, _ = tiny_mesh
    press = [{"kind": "press", "depth_mm": 0.8, "speed_mm_s": 8.0}]  # 0.3 mm past the tips (the start gap is 0.5 mm)
    scene = _scene(scene0, press)
    quasi = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False))
    lines = []
    dynamic = qs.run_episode(scene, mesh, body=body, settings=qs.SolveSettings(tier="linear", gravity=False, dynamics="backward_euler"),
                             log=lines.append)
    assert any('fidelity.solve.dynamics = "backward_euler"' in line and "no inertia" in line for line in lines)
    np.testing.assert_array_equal(dynamic.rod_force_n, quasi.rod_force_n)
    np.testing.assert_array_equal(dynamic.stress, quasi.stress)
    assert np.abs(quasi.rod_force_n).max() > 0.0  # the probe touched
