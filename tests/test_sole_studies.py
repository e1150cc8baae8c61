"""The plantar sole's studies (issue 21, SPEC 4): the balance study to a 10 cm ZMP excursion, the
double-support polygon against its analytic area, and the obstacle table against the single-obstacle
scenes, each through ``mlsim run``."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest

import other_sensors.sole.kind  # noqa: F401  (registers the plantar_sole kind)
from mlsim.cli import main
from mlsim.scene import SceneError, load_scene
from other_sensors.sole import estimators as est
from other_sensors.sole.balance import ZMP_EDGE_MARGIN_M, simulate_balance, zmp_limit
from other_sensors.sole.cells import sole_layout
from other_sensors.sole.stages import assessment_of, contact_of_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes" / "sole"
LAYOUT = sole_layout()
K = 1.0e8


def _run(scene: str, tmp_path: Path) -> Path:
    out = tmp_path / scene
    assert main(["run", str(SCENES / f"{scene}.toml"), "--out", str(out), "--cache", str(tmp_path / "cache"), "--quiet"]) == 0
    return out


def test_the_zmp_reaches_the_sole_outline_less_its_margin():
    normals, offsets = zmp_limit(LAYOUT)
    outline = LAYOUT.outline()
    # every outline vertex is margin outside the limit's nearest edge; the front limit along +x is 10 mm inside the toe
    assert np.allclose((normals @ outline.T).max(axis=1) - offsets, ZMP_EDGE_MARGIN_M)
    toe = LAYOUT.corners[..., 0].max()
    front = min(o / n[0] for n, o in zip(normals, offsets) if n[0] > 1e-9 and abs(n[1]) < 1e-9)
    assert front == pytest.approx(toe - 0.01, abs=1e-12)
    with pytest.raises(ValueError, match="margin"):
        zmp_limit(LAYOUT, 0.2)


def test_a_push_that_moves_the_zmp_10_cm_keeps_the_lipm_upright_with_the_skin_zmp_within_1_cm(tmp_path):
    out = _run("balance_push_10cm", tmp_path)
    s = json.loads((out / "summary.json").read_text())["stages"]["sole_balance"]["summary"]
    # SPEC 4: pushes moved the ZMP up to 10 cm; the skin ZMP stayed within about 1 cm of the F/T ZMP
    assert 100.0 <= s["zmp_excursion_mm"] < 101.7  # 10 cm, short of the ZMP's reach (toe - 10 mm)
    assert s["skin_ft_zmp_gap_mm"] < 10.0 and s["upright"] and s["fall_time_s"] is None
    assert abs(s["final_com_mm"][0]) < 1.0
    # the ZMP peaks while the push lasts (0.5 s to 0.7 s), balancing F z_com / (m g) = 99.6 mm of it, and comes back
    rows = np.loadtxt(out / "sole_balance.csv", delimiter=",", skiprows=1)
    peak = rows[np.argmax(rows[:, 10]), 0]
    assert 0.5 <= peak < 0.7 and abs(rows[-1, 10]) < 1e-3


def test_the_balance_study_table(tmp_path):
    out = _run("balance_sweep", tmp_path)
    with open(out / "sole_balance_sweep.csv") as fh:
        rows = list(csv.DictReader(fh))
    push = np.array([float(r["push_n"]) for r in rows])
    excursion = np.array([float(r["zmp_excursion_mm"]) for r in rows])
    gap = np.array([float(r["skin_ft_gap_mm"]) for r in rows])
    upright = np.array([r["upright"] == "yes" for r in rows])
    b = load_scene(SCENES / "balance_sweep.toml").sensor.balance
    np.testing.assert_array_equal(push, [20, 40, 60, 80, 100, 105, 150, 200, 250, 300])
    # the ZMP's reach along +x: the toe less the margin (the sole's outline, zmp_limit)
    normals, offsets = zmp_limit(LAYOUT)
    reach = min(o / n[0] for n, o in zip(normals, offsets) if n[0] > 1e-9 and abs(n[1]) < 1e-9)
    # below the reach the ZMP excursion is the LIPM's static balance of the push, F z_com / (m g), linear in F
    # (a lagged velocity loop overshoots it by a few per cent)
    small = push * b.z_com_m / (b.mass_kg * 9.81) < 0.8 * reach
    np.testing.assert_allclose(excursion[small], push[small] * b.z_com_m / (b.mass_kg * 9.81) * 1e3, rtol=0.05)
    assert np.all(np.diff(excursion) >= -1e-6) and excursion.max() == pytest.approx(1e3 * reach, abs=1e-3)  # held at its reach (CSV: 6 digits)
    # the capture point's closed form with the ZMP at its reach from the push's start (the best any
    # regulator can do): xi(tau) = p_eff (1 - e^{omega tau}), p_eff = reach - F z / (m g), so a push
    # above F* = m omega^2 reach / (1 - e^{-omega tau}) ends with xi past the reach: it must fall
    omega = np.sqrt(9.81 / b.z_com_m)
    f_star = b.mass_kg * omega**2 * reach / (1 - np.exp(-omega * b.push_duration_s))
    assert not upright[push > f_star].any() and (push > f_star).any()
    # a push the ZMP balances without reaching the edge leaves it upright, the skin within 1 cm of the F/T (SPEC 4)
    assert upright[small].all() and gap.max() < 10.0
    # standing is monotone in the push: one threshold, between the pushes that stood and F*
    assert list(upright) == sorted(upright, reverse=True)
    md = (out / "sole_balance_sweep.md").read_text()
    assert "no (fell at" in md and (out / "sole_balance_sweep.png").stat().st_size > 0


def test_a_fall_ends_the_run_and_is_not_upright():
    scene = load_scene(SCENES / "balance_push_10cm.toml")
    run = simulate_balance(LAYOUT, scene.sensor.balance.model_copy(update={"push_n": 400.0}), K, np.random.default_rng(0))
    assert 0.5 < run.fall_time_s < 0.7 and not run.upright()
    after = run.t > run.fall_time_s
    assert np.all(run.com[after] == run.com[after][0])  # held at the fall
    normals, offsets = zmp_limit(LAYOUT)
    assert (normals @ run.xi[~after][-1] > offsets).any()


def test_double_support_polygon_and_combined_cop_of_the_scene(tmp_path):
    out = _run("double_support", tmp_path)
    s = json.loads((out / "sole_double_support.json").read_text())
    # both soles flat, all 42 cells active each; the hull of a convex sole K and K + d is
    # A(K) + |d| w(K), w the width of K across d: d = (50, 200) mm
    assert s["active_cells"] == [42, 42]
    d = np.array([0.05, 0.2])
    across = np.array([-d[1], d[0]]) / np.linalg.norm(d)
    width = np.ptp(LAYOUT.outline() @ across)
    assert s["polygon_area_cm2"] == pytest.approx(1e4 * (LAYOUT.sole_area() + np.linalg.norm(d) * width), rel=1e-9)
    # the combined CoP is the loads' weighted mean of the ankles (each sole's CoP over its ankle on flat ground)
    expected = (500 * np.array([50.0, 100.0]) + 344 * np.array([0.0, -100.0])) / 844
    np.testing.assert_allclose(s["cop_ft_mm"], expected, atol=1e-6)
    np.testing.assert_allclose(s["cop_mm"], expected, atol=0.2)  # the skin: 0.02 N of noise per sensor
    polygon = np.loadtxt(out / "sole_double_support_polygon.csv", delimiter=",", skiprows=1)
    assert est.polygon_area(polygon * 1e-3) == pytest.approx(s["polygon_area_cm2"] * 1e-4, rel=1e-5)


def test_the_obstacle_table_matches_the_single_obstacle_scenes(tmp_path):
    out = _run("obstacles", tmp_path)
    with open(out / "sole_obstacles.csv") as fh:
        table = {r["obstacle"]: r for r in csv.DictReader(fh)}
    assert list(table) == ["large_flat", "small_flat_border", "small_flat_ankle", "three_spheres"]
    study = load_scene(SCENES / "obstacles.toml")
    cases = {c.name: c for c in study.sensor.obstacles}
    for name, row in table.items():
        single = load_scene(SCENES / f"{name}.toml")
        assert cases[name].terrain == single.sensor.terrain and cases[name].foot == single.sensor.foot  # the same obstacle
        # the table's row is the single scene's with the study's landing (and robot)
        landed = single.sensor.model_copy(update={"landing": study.sensor.landing, "balance": study.sensor.balance})
        contact = contact_of_scene(landed, single.seed)
        a = assessment_of(landed, contact)
        assert row["ft_rule"] == ("re-plan" if a.ft_replan else "keep") and row["skin_rule"] == ("re-plan" if a.skin_replan else "keep")
        assert float(row["ankle_moment_nm"]) == pytest.approx(a.ankle_moment, rel=1e-3, abs=1e-3)
        assert float(row["area_ratio"]) == pytest.approx(a.area_ratio, rel=1e-3)
        assert float(row["fz_n"]) == pytest.approx(contact.wrench[2], rel=1e-3)
        # a landing is harder than the static placement: the impact's force exceeds the load taken over
        assert contact.wrench[2] > single.sensor.foot.load_n
        assert (out / f"sole_obstacle_{name}.png").stat().st_size > 0
    # SPEC 4's point: the skin rule sees every small obstacle wherever it is
    assert all(table[n]["skin_rule"] == "re-plan" for n in ("small_flat_border", "small_flat_ankle", "three_spheres"))
    assert table["large_flat"]["skin_rule"] == "keep"
    assert "at the landing's impact" in (out / "sole_obstacles.md").read_text()
    assert (out / "sole_obstacles.png").stat().st_size > 0


def test_a_study_without_its_section_is_refused_naming_it(tmp_path):
    base = (SCENES / "balance_push_10cm.toml").read_text()
    for output, field in (("sole_double_support", "sensor.second_foot"), ("sole_obstacle_table", "sensor.obstacles")):
        path = tmp_path / "bad.toml"
        path.write_text(base.replace('outputs = ["sole_balance"]', f'outputs = ["{output}"]'))
        with pytest.raises(SceneError, match=field.replace(".", r"\.")):
            load_scene(path)
    text = (SCENES / "obstacles.toml").read_text().replace('name = "three_spheres"', 'name = "large_flat"')
    (tmp_path / "twice.toml").write_text(text)
    with pytest.raises(SceneError, match="sensor.obstacles"):
        load_scene(tmp_path / "twice.toml")
