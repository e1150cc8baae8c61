"""The pipeline's solve stage: VTU time series, forces CSV, summary, cache, and the small-strain guard."""

from __future__ import annotations

import csv
import xml.etree.ElementTree as ET
from pathlib import Path

import meshio
import numpy as np
import pytest

from fem.nonlinear import SolverError
from fem.quasistatic import Episode
from mlsim import pipeline
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenes" / "mavig_tiny.toml"


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, cache, tiny_mesh):
    scene = load_scene(TINY).with_values({"outputs": ["solve"]})
    out = tmp_path_factory.mktemp("solve")
    res = pipeline.run(scene, out_dir=out, cache=cache, progress=False, log=lambda m: None)
    return scene, out, res


def test_vtu_series_holds_the_episode_fields_in_paraview_order(tiny_run):
    scene, out, res = tiny_run
    ep: Episode = res.results["solve"]
    pvd = ET.parse(out / "solve" / "solve.pvd").getroot()
    sets = pvd.findall("./Collection/DataSet")
    assert len(sets) == ep.n_frames
    np.testing.assert_allclose([float(d.get("timestep")) for d in sets], ep.t_s[ep.frame_step], rtol=1e-8)
    i = ep.n_frames - 1
    m = meshio.read(out / "solve" / sets[i].get("file"))
    np.testing.assert_allclose(m.points, ep.mesh_points, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.point_data["displacement_m"], ep.frames("displacement")[i], rtol=1e-6, atol=1e-12)
    s = m.cell_data["stress_pa"][0]
    ours = ep.frames("stress")[i]  # (6, T): xx, yy, zz, yz, xz, xy
    # ParaView's symmetric tensor order: xx, yy, zz, xy, yz, xz
    for pv, k in enumerate((0, 1, 2, 5, 3, 4)):
        np.testing.assert_allclose(s[:, pv], ours[k], rtol=1e-6, atol=1e-3)
    np.testing.assert_allclose(m.cell_data["von_mises_pa"][0], ep.frames("von_mises")[i], rtol=1e-6)
    # the stored rate is the backward difference of the stored frames
    prev = meshio.read(out / "solve" / sets[i - 1].get("file"))
    dt = ep.t_s[ep.frame_step[i]] - ep.t_s[ep.frame_step[i - 1]]
    np.testing.assert_allclose(m.cell_data["von_mises_rate_pa_s"][0], (m.cell_data["von_mises_pa"][0] - prev.cell_data["von_mises_pa"][0]) / dt,
                               rtol=1e-4, atol=1e-2 / dt)


def test_forces_csv_is_in_equilibrium_and_summary_peaks_match_the_fields(tiny_run):
    scene, out, res = tiny_run
    ep: Episode = res.results["solve"]
    rows = list(csv.DictReader(open(out / "solve_forces.csv")))
    assert len(rows) == ep.n_frames
    weight_n = float(rows[0]["reaction_z_n"])  # frame 0 has no contact: the clamp carries the weight alone
    assert float(rows[0]["normal_force_n"]) == 0.0 and weight_n > 0
    for r in rows:
        contact = np.array([float(r[f"contact_f{c}_n"]) for c in "xyz"])
        reaction = np.array([float(r[f"reaction_{c}_n"]) for c in "xyz"])
        rods = sum(float(v) for k, v in r.items() if k.startswith("rod") and k.endswith("normal_force_n"))
        # contact + clamp reaction + weight (vertical) = 0
        np.testing.assert_allclose(contact + reaction, [0.0, 0.0, weight_n], atol=1e-6 * max(1.0, abs(contact).max()))
        assert rods == pytest.approx(float(r["normal_force_n"]), rel=1e-7, abs=1e-9)
    summary = res.summary["stages"]["solve"]["summary"]
    peaks = summary["per_rod_peak"]
    assert len(peaks["von_mises_kpa"]) == 4
    for rod in range(4):
        on = ep.tet_rod == rod
        assert peaks["von_mises_kpa"][rod] == pytest.approx(ep.von_mises[:, on].max() / 1e3, rel=1e-6)
        assert peaks["ml_von_mises_kpa"][rod] <= peaks["von_mises_kpa"][rod] + 1e-9
    assert summary["peak_normal_force_n"] == pytest.approx(ep.normal_force_n.max())
    assert summary["peak_normal_force_n"] > 0.1  # the sphere does press the rods
    assert (out / "solve_forces.png").stat().st_size > 10_000


def test_second_run_loads_the_episode_from_the_cache(tiny_run, cache):
    scene, out, res = tiny_run
    again = pipeline.run(scene, out_dir=None, cache=cache, progress=False, log=lambda m: None)
    assert [s.action for s in again.steps] == ["load"]
    a, b = res.results["solve"], again.results["solve"]
    np.testing.assert_array_equal(a.stress, b.stress)
    # a camera change that the solve does not read keeps the key; a friction change does not
    assert pipeline.stage_key(scene.with_values({"camera.gain_db": 6.0}), "solve") == again.steps[0].key
    assert pipeline.stage_key(scene.with_values({"load.friction_coefficient": 0.3}), "solve") != again.steps[0].key


def test_reduced_precompute_is_cached_across_loads(tmp_path, tiny_mesh):
    cache = pipeline.Cache(tmp_path)
    scene = load_scene(TINY).with_values({"outputs": ["solve"], "fidelity.solve.tier": "reduced"})
    logs: list[str] = []
    pipeline.run(scene, out_dir=None, cache=cache, progress=False, log=logs.append)
    assert any("precomputing" in m for m in logs)
    logs.clear()
    other = scene.with_values({"load.friction_coefficient": 0.2})
    res = pipeline.run(other, out_dir=None, cache=cache, progress=False, log=logs.append)
    assert not any("precomputing" in m for m in logs)
    assert res.results["solve"].tier == "reduced"
    assert len(list((tmp_path / "reduced_model").iterdir())) == 1


def test_a_punch_pushed_into_a_rod_from_the_side_is_refused_by_name(tiny_mesh):
    """A 2 mm thick wall lowered 1.5 mm below the tips at the array's edge, then slid 5 mm into a rod:
    a linear rod cannot bend under it, so its tip is pushed the whole way (4.9 mm, 54 % of its
    height); the solver names the limit instead of returning that. (With one step per frame the
    wall moves 1.7 mm per step: the tunnelling guard must cut the steps, or the rod tip would pass
    through the wall and the limit never be reached.)"""
    from fem import quasistatic as qs

    scene, _, mesh, _ = tiny_mesh
    scene = scene.with_values({"load": {"start_xy_mm": [7.2, 3.6], "friction_coefficient": 0.8,
                                        "indenter": {"shape": "box", "size_mm": [2.0, 8.0, 5.0]},
                                        "segments": [{"kind": "press", "depth_mm": 2.0, "speed_mm_s": 20.0},
                                                     {"kind": "slide", "distance_mm": 5.0, "speed_mm_s": 50.0, "direction_deg": 180.0}]}})
    with pytest.raises(SolverError, match=r"rod 3 moves .* mm, .* of the 9\.0 mm rod height, beyond fidelity\.solve\.small_strain_limit = 0\.3"):
        qs.run_episode(scene, mesh, settings=qs.SolveSettings(tier="linear", gravity=False, small_strain_limit=0.3))
