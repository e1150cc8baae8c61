"""Plausibility checks of the scene model (issue 39): loads off the sensor or through its base, episodes
and runs past the stated limits are refused by ``mlsim check`` with the field named; the reproduced
cases of the issue each exit 2 without a traceback; the frame count the check uses is the solver's."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from mlsim import cost_model, plausibility
from mlsim.cli import main
from mlsim.errors import SceneError
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = str(ROOT / "scenes" / "mavig_default.toml")
TINY = ROOT / "scenes" / "mavig_tiny.toml"


def _refused(overrides: dict, scene=DEFAULT) -> list:
    with pytest.raises(SceneError) as err:
        load_scene(scene, overrides)
    return err.value.problems


# the four cases of the issue's "Why", each with the field its message must name
ISSUE_CASES = [
    ("load.segments.0.depth_mm=1e9", "load.segments[0].depth_mm", "the rods' height, 9 mm"),
    ("load.segments.0.depth_mm=100", "load.segments[0].depth_mm", "the rods' height, 9 mm"),
    ("load.segments.2.speed_mm_s=1e-9", "load.segments[2].speed_mm_s", f"the limit is {plausibility.MAX_EPISODE_FRAMES} frames"),
    # 18 mm to the edge plus the 5 cm^2 probe's radius, 12.6 mm
    ("load.segments.2.distance_mm=1e6", "load.segments[2].distance_mm", "the limit is 30.62 mm"),
]


@pytest.mark.parametrize("setting, field, limit", ISSUE_CASES)
def test_issue_cases_refused_by_check_and_run(setting, field, limit, capsys):
    for command in (["check", DEFAULT], ["run", DEFAULT, "--dry-run"], ["run", DEFAULT, "--outputs", "solve", "--out", "/nonexistent"]):
        assert main([*command, "--set", setting]) == 2
        err = capsys.readouterr().err
        assert field in err and limit in err and "Traceback" not in err
        assert len([line for line in err.splitlines() if line.startswith("  ")]) == 1  # the cause alone, not its consequences


def test_press_limit_is_the_rod_height_below_the_start_gap():
    # default demo: start gap 0.5 mm, rods 9 mm: the lowest point may go 9 mm below the tips, a 9.5 mm press
    load_scene(DEFAULT, {"load.segments.0.depth_mm": 9.49})
    (p,) = _refused({"load.segments.0.depth_mm": 9.51})
    assert p.path == "load.segments[0].depth_mm" and "use depth_mm < 9.5" in p.message
    # a release lifts it: the same depth after a 2 mm release and a second press is judged from there
    segs = [{"kind": "press", "depth_mm": 5.0, "speed_mm_s": 10.0}, {"kind": "release", "distance_mm": 2.0, "speed_mm_s": 10.0},
            {"kind": "press", "depth_mm": 6.4, "speed_mm_s": 10.0}]
    load_scene(DEFAULT, {"load.segments": segs})
    segs[2]["depth_mm"] = 6.6  # 0.5 gap: 5 - 2 + 6.6 - 0.5 = 9.1 mm below the tips
    (p,) = _refused({"load.segments": segs})
    assert p.path == "load.segments[2].depth_mm" and "9.1 mm below" in p.message


def test_force_ramp_counts_as_reaching_the_tips():
    segs = [{"kind": "press", "force_n": 5.0, "duration_s": 0.2}, {"kind": "press", "depth_mm": 8.9, "speed_mm_s": 10.0}]
    load_scene(DEFAULT, {"load.segments": segs})  # 8.9 mm below the tips at least: allowed
    segs[1]["depth_mm"] = 9.1
    (p,) = _refused({"load.segments": segs})
    assert p.path == "load.segments[1].depth_mm"


@pytest.mark.parametrize("x, y, deg, expected", [(0, 0, 0, 18), (0, 0, 90, 18), (0, 0, 45, 18 * math.sqrt(2)), (-7.2, 0, 0, 25.2),
                                                 (10, 5, 180, 28), (0, 0, 30, 18 / math.cos(math.radians(30))), (19, 0, 0, 0.0)])
def test_slide_limit_is_the_distance_to_the_surface_edge(x, y, deg, expected):
    assert plausibility.slide_limit_mm(x, y, deg, 18.0, 18.0) == pytest.approx(expected, rel=1e-12)


def test_slides_are_followed_from_segment_to_segment():
    # the default demo's 500 mm^2 punch reaches sqrt(500 / pi) = 12.616 mm from its axis: it leaves
    # the 36 mm surface when its axis is 30.616 mm from the centre
    reach = math.sqrt(500.0 / math.pi)
    slide = {"kind": "slide", "speed_mm_s": 100.0}
    segs = [{"kind": "press", "depth_mm": 1.0, "speed_mm_s": 10.0}, {**slide, "distance_mm": 10.0, "direction_deg": 90.0},
            {**slide, "distance_mm": 8.0 + reach - 1e-6, "direction_deg": 90.0}]
    load_scene(DEFAULT, {"load.segments": segs})
    segs[2]["distance_mm"] = 8.0 + reach + 0.01
    (p,) = _refused({"load.segments": segs})
    assert p.path == "load.segments[2].distance_mm" and "(0, 10) to (0, 30.63)" in p.message and "limit is 20.62 mm" in p.message
    # a rotation never moves the reference point, however far it turns (fem.trajectory)
    load_scene(DEFAULT, {"load.segments": [*segs[:2], {"kind": "rotate", "angle_deg": 720.0, "rate_deg_s": 360.0}]})


def test_footprint_radius_of_each_indenter_shape():
    from mlsim.scene import LoadSpec

    def reach(indenter):
        load = LoadSpec.model_validate({"indenter": indenter, "segments": [{"kind": "hold", "duration_s": 0.1}]})
        return plausibility.footprint_radius_mm(load.indenter)

    assert reach({"shape": "flat", "diameter_mm": 10.0}) == 5.0
    assert reach({"shape": "flat", "tip_area_mm2": math.pi * 16.0}) == pytest.approx(4.0, rel=1e-12)
    assert reach({"shape": "sphere", "diameter_mm": 6.0}) == 3.0
    assert reach({"shape": "cylinder", "diameter_mm": 7.7, "length_mm": 160.0}) == pytest.approx(math.hypot(80.0, 3.85))
    assert reach({"shape": "box", "size_mm": [6.0, 8.0, 3.0]}) == 5.0


@pytest.mark.parametrize("duration, fps", [(0.1, 30.0), (1 / 30, 30.0), (0.5, 30.0), (0.21, 120.0), (1e-4, 30.0), (2.0, 7.0)])
def test_episode_frames_is_the_solvers_time_grid(duration, fps):
    from fem.trajectory import time_grid
    from mlsim.scene import LoadSpec

    load = LoadSpec.model_validate({"indenter": {"shape": "sphere", "diameter_mm": 4.0},
                                    "segments": [{"kind": "hold", "duration_s": duration}]})
    grid = time_grid(load, fps, substeps=3)
    assert cost_model.episode_frames(load.duration_s, fps) == grid.n_frames
    assert cost_model.solve_steps(grid.n_frames, 3) == len(grid.step_times_s)


def test_frame_and_step_limits_name_the_field_that_fixes_them():
    frames_s = plausibility.MAX_EPISODE_FRAMES / 30.0
    load_scene(DEFAULT, {"load.segments.1.duration_s": frames_s - 2.0})
    (p,) = _refused({"load.segments.1.duration_s": frames_s})
    assert p.path == "load.segments[1].duration_s"
    (p,) = _refused({"load.segments.3.rate_deg_s": 1e-6})
    assert p.path == "load.segments[3].rate_deg_s"
    # the default demo's 1.02 s load: 33 frames, 1 + 32 x substeps steps
    room = (plausibility.MAX_SOLVE_STEPS - 1) // 32
    load_scene(DEFAULT, {"fidelity.solve.substeps": min(room, 1000)})
    if room < 1000:
        (p,) = _refused({"fidelity.solve.substeps": room + 1})
        assert p.path == "fidelity.solve.substeps" and f"substeps <= {room}" in p.message


def test_camera_memory_past_the_limit_is_refused():
    # 8192 x 8192 RGB frames: 201 MB each; a 10.55 s load at 30 FPS keeps 319 frames plus 30 idle ones
    problems = _refused({"camera.width_px": 8192, "camera.height_px": 8192, "load.segments.1.duration_s": 10.0})
    (p,) = problems
    assert p.path == "camera.width_px" and f"the limit is {plausibility.MAX_RUN_MEMORY_GB:g} GB" in p.message
    cost = cost_model.stage_cost(load_scene(DEFAULT), "camera")
    assert cost.frames == 22 + 30 and cost.memory_bytes < 1e9  # 0.65 s: 22 frames and 1 s of idle ones


def test_expensive_but_plausible_scene_warns_with_the_estimate(capsys):
    assert plausibility.warnings(load_scene(DEFAULT)) == []
    # ten minutes of the default demo at the linear tier: allowed, and said to be large (every step's fields)
    scene = load_scene(DEFAULT, {"load.segments.1.duration_s": 590.0})
    assert any(w.startswith("the solve stage is expected to need about") and "17,719 frames" in w for w in plausibility.warnings(scene))
    assert main(["check", DEFAULT, "--set", "load.segments.1.duration_s=590.0"]) == 0
    assert "warning: the solve stage" in capsys.readouterr().out


def _is_dataset_spec(data: dict) -> bool:
    """A dataset spec names its base scene (``scene = ...``) and has a field only specs have; a scene
    overlay (issue 41's ``scene = "base.toml"``, what ``mlsim calibrate`` writes) has scene fields only."""
    from mlsim.dataset.spec import DatasetSpec
    from mlsim.scene import Scene

    spec_only = set(DatasetSpec.model_fields) - set(Scene.model_fields) - {"scene"}
    return isinstance(data.get("scene"), str) and bool(spec_only & set(data))


def test_shipped_scenes_stay_plausible():
    for path in [*ROOT.glob("scenes/*.toml"), *ROOT.glob("scenes/*/*.toml")]:
        # a dataset spec (paper.toml, issue 42's small.toml) names its base scene, which is checked here itself;
        # a scene overlay is checked merged over its base
        if not _is_dataset_spec(tomllib.loads(path.read_text())):
            assert plausibility.problems(load_scene(path)) == [], path


def test_a_scene_overlay_is_checked_over_its_base_not_skipped_as_a_dataset_spec(tmp_path):
    overlay = tmp_path / "sensor.toml"
    overlay.write_text(f'scene = "{TINY}"\n\n[camera]\nfocal_length_mm = 6.0\n')
    assert not _is_dataset_spec(tomllib.loads(overlay.read_text()))
    assert _is_dataset_spec(tomllib.loads((ROOT / "scenes" / "interactions" / "small.toml").read_text()))
    assert plausibility.problems(load_scene(overlay)) == []
    assert load_scene(overlay).camera.focal_length_mm == 6.0


def test_tet_estimate_within_a_factor_of_the_shipped_meshes(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    ratio = cost_model.estimated_tets(scene) / mesh.n_tets
    assert 0.5 < ratio < 2.0, ratio
    # the default demo's 2 mm mesh (16,848 tets, tests/data/meshes)
    assert 0.5 < cost_model.estimated_tets(load_scene(DEFAULT)) / 16848 < 2.0


def test_probe_that_never_nears_a_contact_point_is_an_empty_contact_set(cache):
    """A 1 mm sphere between the tiny scene's rods reaches no contact point (the kernel's empty
    operator was a numpy traceback): the episode is the sensor under gravity alone, the same fields
    as an indenter that passes near points and stays clear of them."""
    from mlsim import pipeline

    def solve(**values):
        scene = load_scene(TINY, values)
        return pipeline.run(scene, cache=cache, outputs=("solve",), progress=False, log=lambda m: None).results["solve"]

    empty = solve(**{"load.indenter.diameter_mm": 1.0, "load.segments.0.depth_mm": 0.1, "load.segments.1.distance_mm": 0.1})
    clear = solve(**{"load.start_gap_mm": 0.5, "load.segments.0.depth_mm": 0.2, "load.segments.1.distance_mm": 0.1})
    assert np.all(empty.normal_force_n == 0) and np.all(clear.normal_force_n == 0)
    np.testing.assert_allclose(empty.von_mises[-1], clear.von_mises[-1], rtol=1e-5, atol=1e-3 * float(clear.von_mises.max()))
    assert np.isfinite(empty.von_mises).all() and float(empty.von_mises.max()) > 0  # gravity's stress, not zeros


def test_empty_contact_operator_is_a_solver_error():
    from fem.contact_admm import DenseDelassus
    from mlsim.errors import SolverError

    with pytest.raises(SolverError, match="contact set is empty"):
        DenseDelassus(np.zeros((0, 0)), np.zeros(0))


def test_time_grid_refuses_a_load_past_the_step_limit_before_allocating():
    """A load built in code is not checked by the scene model: the grid itself refuses it (a slide at
    1e-9 mm/s asked numpy for 335 GiB), naming the steps and the limit."""
    from fem.trajectory import time_grid
    from mlsim.errors import SolverError
    from mlsim.scene import LoadSpec

    load = LoadSpec.model_validate({"indenter": {"shape": "sphere", "diameter_mm": 4.0},
                                    "segments": [{"kind": "slide", "distance_mm": 1.5, "speed_mm_s": 1e-9}]})
    with pytest.raises(SolverError, match=f"4.5e\\+10 frames at 30 FPS, .* past the limit of {plausibility.MAX_SOLVE_STEPS}"):
        time_grid(load, 30.0)
    load = LoadSpec.model_validate({"indenter": {"shape": "sphere", "diameter_mm": 4.0},
                                    "segments": [{"kind": "hold", "duration_s": 1e308}]})
    with pytest.raises(SolverError, match="inf frames"):
        time_grid(load, 1e3)
    assert time_grid(load.model_copy(update={"segments": (load.segments[0].model_copy(update={"duration_s": 1.0}),)}), 30.0).n_frames == 32
