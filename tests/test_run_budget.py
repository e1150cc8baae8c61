"""The cost estimate before a run and its budget (issue 39): ``--dry-run`` prints each stage's frames,
steps, tets, memory and time; a run past ``--max-memory-gb`` or ``--max-frames`` is refused before
anything runs unless ``--over-budget``; only the stages a plan runs are priced."""

from __future__ import annotations

from pathlib import Path

import pytest

from mlsim import cost_model, pipeline, run_budget
from mlsim.cli import main
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = str(ROOT / "scenes" / "mavig_default.toml")
TINY = str(ROOT / "scenes" / "mavig_tiny.toml")


def test_dry_run_prints_each_stage_cost(tmp_path, capsys):
    assert main(["run", DEFAULT, "--dry-run", "--cache", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("estimate:") == 1
    rows = {line.split()[0]: line.split() for line in out.splitlines() if line.startswith("  ") and len(line.split()) > 3}
    # the demo's load lasts 0.65 s: 22 frames at 30 FPS (fem.trajectory.time_grid), one solve step each;
    # the camera adds 1 s of idle frames (30) for the DLLM's thresholds
    assert rows["solve"][1:3] == ["22", "22"] and rows["camera"][1] == "52"
    assert "mesh" in rows and "no cost model" in " ".join(rows["geometry"])


def test_only_the_stages_to_run_are_priced(cache):
    scene = load_scene(TINY)
    est = run_budget.estimate(scene, pipeline.plan(scene, cache, ("mesh",)))  # the shipped mesh is cached
    assert est.rows == () and est.memory_bytes == run_budget.BASE_BYTES
    est = run_budget.estimate(scene, pipeline.plan(scene, None, ("mesh",)))  # no cache: geometry and mesh run
    assert [name for name, _ in est.rows] == ["geometry", "mesh"]
    assert est.seconds == pytest.approx(cost_model.stage_cost(scene, "mesh").seconds)


def test_a_cached_reduced_model_is_not_priced(tmp_path):
    """The reduced tier's precompute (the sensor's model, cached apart from the solve, keyed on mesh and body) is
    priced only where the cache lacks it: with it cached the solve costs the rest, and the table says why."""
    from fem.stages import REDUCED_MODEL, reduced_model_payload
    from mlsim.stage import precompute_key

    scene = load_scene(DEFAULT)
    assert scene.fidelity.solve.tier == "reduced"
    full = cost_model.stage_cost(scene, "solve")
    cached = cost_model.stage_cost(scene, "solve", precompute_cached=True)
    assert cached.seconds == pytest.approx(full.seconds - 1.2 * cost_model.BODY_S_PER_TET * cost_model.estimated_tets(scene))
    assert cached.note == "reduced (its precompute cached)" and full.note == "reduced"
    key = precompute_key(reduced_model_payload(scene))
    asked = []

    class Holding:  # a cache that holds the sensor's reduced model and nothing else
        def has(self, stage, k):
            asked.append((stage, k))
            return (stage, k) == (REDUCED_MODEL.name, key)

    plan = pipeline.plan(scene, None, ("solve",))
    solve = dict(run_budget.estimate(scene, plan, Holding()).rows)["solve"]
    assert solve.seconds == pytest.approx(cached.seconds) and asked == [(REDUCED_MODEL.name, key)]
    assert dict(run_budget.estimate(scene, plan, pipeline.Cache(tmp_path)).rows)["solve"].seconds == pytest.approx(full.seconds)
    # another tier has no such model: priced as before, the cache not asked
    linear = scene.with_values({"fidelity.solve.tier": "linear"})
    asked.clear()
    assert dict(run_budget.estimate(linear, plan, Holding()).rows)["solve"].seconds == pytest.approx(cost_model.stage_cost(linear, "solve").seconds)
    assert asked == []


def test_a_cached_render_matrix_is_not_priced(tmp_path):
    """The render's matrix (the deformed tier's bounces, the transport tier's light transport; cached on the sensor and
    view, not the load) is priced only where the cache lacks it: with it cached the render costs its frames and the
    matrix's load (make demo: 90 s priced where the stage took 0.74 s), and the table says why. The path tier has none."""
    from mlsim.render.stage import TRANSPORT, transport_payload
    from mlsim.stage import precompute_key

    scene = load_scene(DEFAULT)
    assert scene.fidelity.render.tier == "deformed"
    full, cached = (cost_model.stage_cost(scene, "render", precompute_cached=c) for c in (False, True))
    frames = cost_model.episode_frames(scene.load.duration_s, scene.camera.fps)
    assert cached.seconds == pytest.approx(cost_model.RENDER_CACHED_MATRIX_S + frames * cost_model.RENDER_FRAME_S["deformed"])
    assert full.seconds > 50 * cached.seconds and cached.note == "deformed (its matrix cached)" and full.note == "deformed"
    key = precompute_key(transport_payload(scene, bounces=True))
    assert key != precompute_key(transport_payload(scene))  # the transport tier's matrix is another
    assert key == precompute_key(transport_payload(scene.with_values({"load.friction_coefficient": 0.5}), bounces=True))  # not the load's

    class Holding:  # a cache that holds the sensor's bounces and nothing else
        def has(self, stage, k):
            return (stage, k) == (TRANSPORT.name, key)

    plan = pipeline.plan(scene, None, ("render",))
    assert dict(run_budget.estimate(scene, plan, Holding()).rows)["render"].seconds == pytest.approx(cached.seconds)
    assert dict(run_budget.estimate(scene, plan, pipeline.Cache(tmp_path)).rows)["render"].seconds == pytest.approx(full.seconds)
    path = scene.with_values({"fidelity.render.tier": "path"})
    assert dict(run_budget.estimate(path, plan, Holding()).rows)["render"].seconds == pytest.approx(cost_model.stage_cost(path, "render").seconds)


def test_run_past_the_memory_budget_is_refused_before_it_starts(tmp_path, capsys):
    out = tmp_path / "out"
    code = main(["run", TINY, "--outputs", "geometry", "--max-memory-gb", "0.01", "--cache", str(tmp_path / "c"), "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "--max-memory-gb = 0.01" in err and "--over-budget" in err and "Traceback" not in err
    assert not out.exists() and not (tmp_path / "c").exists()  # nothing ran, nothing was cached


def test_run_past_the_frame_budget_is_refused(tmp_path, capsys):
    # the tiny scene's load: 0.1 s press and 0.08 s slide, 8 frames at 30 FPS
    code = main(["run", TINY, "--outputs", "solve", "--max-frames", "7", "--cache", str(tmp_path), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "--max-frames = 7" in err and "8 frames" in err


def test_over_budget_runs_anyway_and_the_log_starts_with_the_estimate(tmp_path, capsys):
    code = main(["run", TINY, "--outputs", "geometry", "--max-memory-gb", "0.01", "--over-budget", "--cache", str(tmp_path / "c"),
                 "--out", str(tmp_path / "o")])
    assert code == 0
    assert capsys.readouterr().err.splitlines()[0].startswith("estimate: ")


@pytest.mark.parametrize("flag, value", [("--max-memory-gb", "0"), ("--max-memory-gb", "-2"), ("--max-frames", "0")])
def test_budget_flags_must_be_positive(flag, value, tmp_path, capsys):
    assert main(["run", TINY, "--outputs", "geometry", flag, value, "--cache", str(tmp_path)]) == 2
    assert f"{flag} = " in capsys.readouterr().err


def test_default_memory_budget_is_a_fraction_of_the_machine():
    assert run_budget.default_max_memory_gb() == pytest.approx(run_budget.MEMORY_FRACTION * run_budget.machine_memory_bytes() / 1024**3)
    assert 0 < run_budget.default_max_memory_gb() < run_budget.machine_memory_bytes() / 1024**3
