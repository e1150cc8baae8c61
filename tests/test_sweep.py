"""mlsim sweep: the variants, the metrics against closed forms, the shared cache, kill-and-resume, the report."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from fem.finite_strain import rod_first_mode_rad_s
from mlsim.scene import SceneError, load_scene
from mlsim.sweep import metrics
from mlsim.sweep.report import pareto_front
from mlsim.sweep.run import read_load, stored_records, sweep
from mlsim.sweep.variants import parse_vary, variants
from process_helpers import kill_when

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenes" / "mavig_tiny.toml"
DEFAULT = ROOT / "scenes" / "mavig_default.toml"


# ------------------------------------------------------------------------------------ variants
def test_vary_values_are_toml_and_bare_words_are_strings():
    (h,), (m,) = parse_vary(["sensor.rod.height_mm=6,7.5, 9"]), parse_vary(["sensor.materials.core=SC37,PDMS"])
    assert h.values == (6, 7.5, 9) and h.name == "height_mm"
    assert m.values == ("SC37", "PDMS")


@pytest.mark.parametrize("bad", [["sensor.rod.height_mm"], ["=1,2"], ["sensor.rod.height_mm="], ["a.b=1", "a.b=2"]])
def test_malformed_vary_is_refused_with_the_flag(bad):
    with pytest.raises(SceneError, match="--vary"):
        parse_vary(bad)


def test_grid_is_the_product_and_zip_pairs_values():
    base = load_scene(DEFAULT)
    varies = parse_vary(["sensor.rod.height_mm=6,9,12", "sensor.rod.diameter_mm=4,5"])
    grid = variants(base, varies, "grid")
    assert len(grid) == 6 and len({v.variant_id for v in grid}) == 6
    assert [v.scene.sensor.rod.height_mm for v in grid] == [6, 6, 9, 9, 12, 12]
    assert [v.scene.sensor.rod.diameter_mm for v in grid] == [4, 5] * 3
    with pytest.raises(SceneError, match="same number of values"):
        variants(base, varies, "zip")
    zipped = variants(base, parse_vary(["sensor.rod.height_mm=6,12", "sensor.rod.diameter_mm=4,5"]), "zip")
    assert [(v.scene.sensor.rod.height_mm, v.scene.sensor.rod.diameter_mm) for v in zipped] == [(6, 4), (12, 5)]
    # the id follows the values, not the run: the same values give the same id
    assert variants(base, varies, "grid")[3].variant_id == grid[3].variant_id


def test_unbuildable_variants_carry_the_reason_and_unknown_fields_stop_the_sweep():
    base = load_scene(DEFAULT)
    vs = variants(base, parse_vary(["sensor.rod.diameter_mm=5,7.5", "sensor.layers.ml_mm=0.5,2.4"]))
    reasons = {(v.values["sensor.rod.diameter_mm"], v.values["sensor.layers.ml_mm"]): v.reason for v in vs}
    assert reasons[(5, 0.5)] is None
    assert "rods overlap" in reasons[(7.5, 0.5)] and "sensor.rod.diameter_mm" in reasons[(7.5, 0.5)]
    assert "thinner than the rod radius" in reasons[(5, 2.4)]
    with pytest.raises(SceneError, match="no such field"):
        variants(base, parse_vary(["sensor.rod.length_mm=6,9"]))
    (bad,) = variants(base, parse_vary(["sensor.materials.core=NOPE"]))
    assert bad.scene is None and "unknown material" in bad.reason and "SC37" in bad.reason


# ------------------------------------------------------------------------------------- metrics
def _rotation(rng):
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q * np.sign(np.linalg.det(q))


def _voigt(t):
    return np.array([t[0, 0], t[1, 1], t[2, 2], t[1, 2], t[0, 2], t[0, 1]])


def test_principal_values_are_rotation_invariant_and_match_hookes_law():
    rng = np.random.default_rng(0)
    E, nu, s = 2.0e6, 0.45, 3.0e5
    uniaxial = np.diag([s, 0.0, 0.0])
    for _ in range(5):
        R = _rotation(rng)
        v = _voigt(R @ uniaxial @ R.T)
        np.testing.assert_allclose(metrics.principal_stress(v), [0, 0, s], atol=1e-6 * s)
        # uniaxial tension: axial strain s / E, lateral -nu s / E
        np.testing.assert_allclose(metrics.principal_strain(v, E, nu), [-nu * s / E, -nu * s / E, s / E], rtol=1e-9, atol=1e-12)
    # a general tensor: the strain's principal values are the eigenvalues of the compliance times sigma
    t = rng.normal(size=(3, 3)) * 1e5
    t = t + t.T
    eps = ((1 + nu) * t - nu * np.trace(t) * np.eye(3)) / E
    np.testing.assert_allclose(metrics.principal_strain(_voigt(t), E, nu), np.linalg.eigvalsh(eps), rtol=1e-9, atol=1e-15)


def test_tear_risk_safety_factors_are_the_table_over_the_peak():
    scene = load_scene(DEFAULT).with_values({"sensor.materials.core": "PDMS"})
    pdms, sc37 = scene.material("core"), scene.material("ml_layer")
    s = 1.0e5
    stress = np.zeros((2, 6, 3), np.float32)
    stress[1, 0, 0] = s  # uniaxial in the core tet (rod 4), at the second step
    stress[1, 2, 1] = 0.5 * s  # smaller, in an ML tet
    episode = SimpleNamespace(stress=stress, layer_fraction=np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0]], float),
                              tet_rod=np.array([4, 2, -1]), normal_force_n=np.array([0.0, 3.0]))
    r = metrics.tear_risk(episode, scene)
    strain = s / pdms.young_modulus_pa.value
    assert r["peak_principal_stress_kpa"] == pytest.approx(100.0)
    assert r["peak_principal_strain_pct"] == pytest.approx(100 * strain, rel=1e-6)
    assert r["peak_stress_rod"] == 4 and r["material_of_peak"] == "PDMS"
    assert r["safety_factor_stress"] == pytest.approx(pdms.tensile_strength_pa.value / s, rel=1e-6)
    assert r["safety_factor_strain"] == pytest.approx(pdms.elongation_at_break.value / strain, rel=1e-6)
    assert not r["tears"] and r["peak_normal_force_n"] == 3.0
    # the same stress in a material past its elongation at break tears
    stress[1, 0, 0] = 1.2 * pdms.elongation_at_break.value * pdms.young_modulus_pa.value
    assert metrics.tear_risk(episode, scene)["tears"]
    assert sc37.name == "SC37"


def test_separation_is_one_for_black_gaps_and_zero_for_merged_disks():
    rows, cols, pitch, radius = 2, 3, 40.0, 12.0
    yy, xx = np.mgrid[0:100, 0:140]
    centres = np.array([[30 + pitch * j, 30 + pitch * i] for i in range(rows) for j in range(cols)], float)
    disks = np.zeros((100, 140))
    for cx, cy in centres:
        disks[(xx - cx) ** 2 + (yy - cy) ** 2 <= radius**2] = 200
    r = metrics.separation(disks.astype(np.uint8), centres, radius, rows, cols)
    assert r["min_valley"] == pytest.approx(1.0) and r["min_rim_gap_px"] == pytest.approx(pitch - 2 * radius)
    flat = np.full((100, 140), 150, np.uint8)
    assert metrics.separation(flat, centres, radius, rows, cols)["min_valley"] == pytest.approx(0.0)
    half = np.where(disks > 0, 200, 100).astype(np.uint8)  # a grey gap at half the disks' level
    assert metrics.separation(half, centres, radius, rows, cols)["min_valley"] == pytest.approx(0.5)


def test_beam_sensitivity_is_spec_1_3():
    E = 1.5e6
    s = metrics.beam_strain_per_newton(9.0, 5.0, E)
    assert s == pytest.approx(4 * 9e-3 / (np.pi * 2.5e-3**3 * E))
    assert metrics.beam_strain_per_newton(18.0, 5.0, E) == pytest.approx(2 * s)
    assert metrics.beam_strain_per_newton(9.0, 10.0, E) == pytest.approx(s / 8)


def test_brightness_counts_photons_and_the_brightest_rods_counts():
    cam = SimpleNamespace(rod_photons=np.array([[1.0, 2.0], [3.0, 0.0]]), rod_signal_e=np.array([[5.0, 1.0], [2.0, 7.0]]))
    frames = np.zeros((3, 4, 4), np.uint8)
    frames[:, :2] = 10
    frames[1, :2] = 40  # rod 0's disk (top half) 30 above its darkest frame in frame 1
    masks = np.zeros((2, 4, 4), bool)
    masks[0, :2], masks[1, 2:] = True, True
    b = metrics.brightness(cam, frames, masks)
    assert b["total_photons"] == 6.0 and b["per_rod_photons"] == [4.0, 2.0] and b["peak_rod_signal_e"] == 7.0
    assert b["peak_rod_dn"] == pytest.approx(30.0)


def test_pareto_front():
    pts = [(0.1, 5.0), (0.2, 4.0), (0.3, 9.0), (0.05, 1.0), (0.3, 8.0)]
    assert pareto_front(pts) == [True, False, True, True, False]


def test_load_files_carry_their_stepping():
    swipe = read_load(ROOT / "scenes" / "swipe.toml")
    assert swipe.name == "swipe" and swipe.solve == {"substeps": 48, "rod_kinematics": "cosserat", "rod_coupling": "held"}
    assert swipe.load["segments"][1]["speed_mm_s"] == 200.0  # SPEC 1.5: 200 mm/s
    press = read_load(ROOT / "scenes" / "press.toml")
    assert press.solve == {} and press.load["segments"][0]["force_n"] == 5.0
    first_order = load_scene(DEFAULT).with_values({"fidelity.solve.rod_kinematics": "first_order"})
    scene = swipe.apply(first_order, ("solve",))
    assert scene.fidelity.solve.substeps == 48 and scene.load.indenter.tip_area_mm2 == 500.0 and scene.outputs == ("solve",)
    assert scene.fidelity.solve.rod_kinematics == "cosserat" and scene.fidelity.solve.rod_coupling == "held"  # with its coupling
    # what the load needs at the least: a variant that steps finer or with rod kinematics as rich keeps its own (and its coupling)
    finer = swipe.apply(load_scene(DEFAULT).with_values({"fidelity.solve.rod_kinematics": "cosserat", "fidelity.solve.rod_coupling": "dead",
                                                         "fidelity.solve.substeps": 96}), ("solve",))
    assert finer.fidelity.solve.rod_kinematics == "cosserat" and finer.fidelity.solve.substeps == 96 and finer.fidelity.solve.rod_coupling == "dead"
    demo = swipe.apply(load_scene(DEFAULT), ("solve",))
    assert demo.fidelity.solve.rod_kinematics == "cosserat" and demo.fidelity.solve.rod_coupling == "held"  # the demo's own
    assert demo.fidelity.solve.substeps == 48
    with pytest.raises(SceneError, match="no \\[load\\]"):
        read_load(ROOT / "scenes" / "verify_fem_s2.toml")


# ------------------------------------------------------------------------ the driver and cache
def _tiny_sweep(out: Path, cache_dir, values: str = "SC37,PDMS", **kw):
    # the tiny load's first-order answer estimates itself 175 % off, which the default escalation hands to the
    # nonlinear tier (22 s a variant); these tests are of the sweep's driver and cache, not of that tier
    kw.setdefault("escalate_to", None)
    base = load_scene(TINY)
    return sweep(base, parse_vary([f"sensor.materials.core={values}"]), out, loads=[read_load(TINY)], wanted=("tear",),
                 cache_dir=cache_dir, progress=False, log=lambda m: None, **kw)


def test_a_stage_the_variant_does_not_change_is_loaded_from_the_cache(tmp_path, cache):
    """Two materials: the second variant's mesh (which reads no material) is loaded, its solve runs;
    the report has one row per variant with its safety factors."""
    summary = _tiny_sweep(tmp_path / "sw", cache.root)
    assert summary["complete"] and summary["run_now"] == 2
    recs = {r["values"]["sensor.materials.core"]: r for r in stored_records(tmp_path / "sw").values()}
    pdms = recs["PDMS"]["loads"]["mavig_tiny"]
    assert pdms["ok"], pdms.get("reason")
    assert pdms["actions"]["mesh"] == "load" and pdms["actions"]["solve"] == "run"
    # a softer core strains more under the same press (depth control: the same displacement)
    e = {k: r["loads"]["mavig_tiny"]["peak_principal_strain_pct"] for k, r in recs.items()}
    assert e["PDMS"] != e["SC37"]
    rows = (tmp_path / "sw" / "sweep.csv").read_text().splitlines()
    assert len(rows) == 3 and "mavig_tiny_sf_strain" in rows[0]
    assert (tmp_path / "sw" / "sweep_core.png").stat().st_size > 0
    # the same sweep again: nothing runs
    assert _tiny_sweep(tmp_path / "sw", cache.root)["run_now"] == 0


def test_a_different_sweep_into_the_same_folder_is_refused(tmp_path, cache):
    _tiny_sweep(tmp_path / "sw", cache.root, values="SC37", limit=0)
    with pytest.raises(SceneError, match="holds a different sweep"):
        _tiny_sweep(tmp_path / "sw", cache.root, values="SC37,EF30", limit=0)


def test_killed_sweep_resumes_without_rerunning_finished_variants(tmp_path, cache):
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "mlsim.cli", "sweep", str(TINY), "--load", str(TINY), "--vary", "sensor.materials.core=SC37,PDMS,DS30",
           "--metrics", "tear", "--escalate-tier", "none", "--out", str(out), "--cache", str(cache.root), "--quiet"]
    kill_when(cmd, lambda: bool(stored_records(out)), what="variant")
    before = {k: (tmp_path / "killed" / "variants" / f"{k}.json").read_bytes() for k in stored_records(out)}
    assert 1 <= len(before) < 3
    summary = _tiny_sweep(out, cache.root, values="SC37,PDMS,DS30")
    assert summary["complete"] and summary["run_now"] == 3 - len(before)
    for k, data in before.items():  # the finished variants' records are untouched
        assert (out / "variants" / f"{k}.json").read_bytes() == data
    assert len(json.loads((out / "summary.json").read_text())["files"]) >= 3


def test_a_variant_whose_stages_are_all_cached_still_reports_them(tmp_path, cache):
    """A second sweep of the same variant into a new folder loads every stage, the solve too (the
    planner leaves out the stages a cached camera result does not need unless they are asked for),
    and gives the same figures."""
    base = load_scene(TINY).with_values({"fidelity.render.transport_spp": 8})
    # not escalated (the tiny load's first-order answer would go to the nonlinear tier): a test of the cache
    kw = dict(loads=[read_load(TINY)], wanted=("brightness", "tear"), cache_dir=cache.root, progress=False, log=lambda m: None, escalate_to=None)
    varies = parse_vary(["sensor.rod.height_mm=9"])
    sweep(base, varies, tmp_path / "a", **kw)
    sweep(base, varies, tmp_path / "b", **kw)
    (a,), (b,) = stored_records(tmp_path / "a").values(), stored_records(tmp_path / "b").values()
    ra, rb = a["loads"]["mavig_tiny"], b["loads"]["mavig_tiny"]
    assert rb["ok"], rb.get("reason")
    assert set(rb["actions"].values()) <= {"load", "run"} and rb["actions"]["camera"] == "load" and rb["actions"]["solve"] == "load"
    assert rb["total_photons"] == ra["total_photons"] > 0
    assert rb["peak_principal_strain_pct"] == ra["peak_principal_strain_pct"]
    assert rb["photons_per_newton"] == pytest.approx(rb["total_photons"] / rb["peak_normal_force_n"])


def test_a_fast_answer_its_own_estimate_calls_no_answer_is_escalated():
    """The Cosserat tier answers rods past collapse without refusing them, and its estimate says how far off
    it is: above ESCALATE_ESTIMATE (20 %) the sweep hands the load to the nonlinear tier as it does a refusal.
    The sweep's own figures (2026-11-29): the 12 x 3 mm swipe 13608 % (escalated), the 9 x 3 mm press 5.3 %
    and swipe 8 % with 13 releases (kept, their estimate and releases in the report)."""
    from mlsim.sweep.run import ESCALATE_ESTIMATE, beyond_its_estimate

    assert ESCALATE_ESTIMATE == 0.2
    why = beyond_its_estimate({"tier": "reduced", "geometric_error_estimate": 136.08, "geometric_error_releases": [9, 12]})
    assert "13608%" in why and "above 20%" in why and "[9, 12]" in why and "ESCALATE_ESTIMATE" in why
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": 0.053, "geometric_error_releases": []}) is None
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": 0.08, "geometric_error_releases": [3] * 13}) is None
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": 0.2}) is None  # at the limit: kept
    assert "above 20%" in beyond_its_estimate({"tier": "linear", "geometric_error_estimate": 0.2001})
    assert "inf" in beyond_its_estimate({"tier": "linear", "geometric_error_estimate": float("inf")})
    # rods dragged over near buckling (fem.rod_error.BENT_AXIAL): the estimate does not hold, the answer is kept and
    # the report says so (escalating them would send most swipes over 9-12 mm rods to the nonlinear tier)
    assert beyond_its_estimate({"tier": "reduced", "geometric_error_estimate": 0.081, "geometric_error_bent": [[60, 13], [71, 8]]}) is None
    # no estimate made (second-order rod kinematics record NaN, the swipe load's least kinematics): an answer, not escalated
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": float("nan")}) is None
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": None}) is None
    assert beyond_its_estimate({"tier": "nonlinear", "geometric_error_estimate": 5.0}) is None  # the reference itself
    assert beyond_its_estimate({"tier": "linear", "geometric_error_estimate": 0.3}, limit=0.5) is None


def test_the_report_marks_an_estimate_that_does_not_hold():
    """A load's force error estimate in the Markdown table is marked where the tier says it does not hold: bent
    rods let go (``releases``) or rods dragged over near buckling (``bent``, fem.rod_error.BENT_AXIAL: the 12 x 5 mm
    swipe estimated 8 %, measured 28 % in force); the CSV keeps the number."""
    from mlsim.sweep.report import _cell

    row = {"swipe_force_err_est": 0.0812, "swipe_releases": 0, "swipe_bent": 4, "press_force_err_est": 0.031, "press_releases": 0,
           "press_bent": 0, "hold_force_err_est": 0.05, "hold_releases": 2}
    assert _cell(row, "swipe_force_err_est") == "0.0812 (does not hold)"
    assert _cell(row, "press_force_err_est") == "0.031" and _cell(row, "hold_force_err_est") == "0.05 (does not hold)"
    assert _cell(row, "swipe_bent") == "4" and _cell({}, "swipe_force_err_est") == "-"


def test_a_load_the_fast_tier_refuses_is_answered_by_the_nonlinear_tier(tmp_path, cache):
    """A variant whose linear tier refuses the load as beyond its model (here: small_strain_limit set
    to 0.1 % of the rod height, so a 0.1 mm press of one rod passes it) is solved by the nonlinear tier; the
    record and the report's tiers column say so, and the answer is the linear tier's own within 2 %
    at this small strain (0.9 %; at 2.7 % the two differ by 3.4 %: the neo-Hookean stiffening).
    With --escalate-tier none the refusal is recorded with its reason."""
    from mlsim.sweep.run import Load

    # one step per period of the rods' first mode (323 Hz) keeps the escalated dynamics cheap: 11 steps a frame
    base = load_scene(TINY).with_values({"fidelity.solve.small_strain_limit": 0.001, "fidelity.solve.gravity": False,
                                         "fidelity.solve.steps_per_period": 1.0})
    # a flat probe over one rod: every vertex of its tip touches (a small sphere can fall between the coarse
    # mesh's vertices), and few contact points make the nonlinear solve cheap
    press = Load("small_press", {"indenter": {"shape": "flat", "diameter_mm": 6.0}, "start_xy_mm": [3.6, 3.6], "start_gap_mm": 0.1,
                                 "segments": [{"kind": "press", "depth_mm": 0.2, "speed_mm_s": 20.0}]}, {})
    varies = parse_vary(["sensor.rod.height_mm=9"])
    kw = dict(loads=[press], wanted=("tear",), cache_dir=cache.root, progress=False, log=lambda m: None)
    # the limit as it is above and as it allows the linear tier's answer, in one sweep: one worker
    # process for both variants (a sweep per variant started one each, ~5 s of imports and set-up)
    sweep(base, parse_vary(["sensor.rod.height_mm=9", "fidelity.solve.small_strain_limit=0.001,0.5"]), tmp_path / "up", **kw)
    rec, lin = sorted(stored_records(tmp_path / "up").values(), key=lambda v: v["values"]["fidelity.solve.small_strain_limit"])
    assert rec["values"]["fidelity.solve.small_strain_limit"] == 0.001 and lin["values"]["fidelity.solve.small_strain_limit"] == 0.5
    r = rec["loads"]["small_press"]
    assert r["ok"], r.get("reason")
    assert r["solve_tier"] == "nonlinear" and r["escalated"]["from_tier"] == "linear"
    assert "OutOfRangeError" in r["escalated"]["reason"] and "small_strain_limit" in r["escalated"]["reason"]
    # stepped with backward-Euler dynamics at the least substeps that give the first bending mode a step per period
    period_s = 2.0 * np.pi / rod_first_mode_rad_s(base)
    esc = r["escalated"]
    assert esc["dynamics"] == "backward_euler" and esc["substeps"] == int(np.ceil(1.0 / (base.camera.fps * period_s)))
    assert "small_press: nonlinear+be<linear/" in (tmp_path / "up" / "sweep.csv").read_text()
    # the linear tier's answer where it is allowed to give one (escalation on, as above: not taken)
    ln = lin["loads"]["small_press"]
    assert ln["solve_tier"] == "linear" and ln["escalated"] is None
    assert r["peak_normal_force_n"] == pytest.approx(ln["peak_normal_force_n"], rel=0.02)
    # no escalation: the refusal is the record
    sweep(base, varies, tmp_path / "none", escalate_to=None, **kw)
    (no,) = stored_records(tmp_path / "none").values()
    assert not no["loads"]["small_press"]["ok"] and "small_strain_limit" in no["loads"]["small_press"]["reason"]
