"""A sweep's cost before it runs (issue 39 item 2, :mod:`mlsim.sweep.cost`): ``mlsim sweep --dry-run``
prints per variant and load the time and peak memory of the stages the sweep runs, the nonlinear
tier's solve "if escalated" (its steps those of the escalated scene) and which variants are likely
to escalate, and the total on the workers. Nothing is solved: dry runs and the cost model only."""

from __future__ import annotations

import math
import re
from pathlib import Path

import pytest

from fem.finite_strain import dynamics_substeps
from mlsim.cli import main
from mlsim.scene import load_scene
from mlsim.sweep import cost
from mlsim.sweep.run import read_load

ROOT = Path(__file__).resolve().parents[1]
DEFAULT = str(ROOT / "scenes" / "mavig_default.toml")
SWIPE = read_load(ROOT / "scenes" / "swipe.toml")
PRESS = read_load(ROOT / "scenes" / "press.toml")


def _dry_run(capsys, tmp_path, *extra) -> str:
    code = main(["sweep", DEFAULT, "--vary", "sensor.rod.height_mm=9,10.5", "--out", str(tmp_path / "sweep"), "--cache",
                 str(tmp_path / "cache"), "--workers", "2", "--dry-run", *extra])
    assert code == 0
    assert not (tmp_path / "sweep").exists()  # a dry run writes nothing
    return capsys.readouterr().out


def _blocks(out: str) -> dict[str, list[str]]:
    """The dry run's lines under each variant, by the varied height."""
    blocks, current = {}, None
    for line in out.splitlines():
        m = re.match(r"  v\d{3}_\w{8}  height_mm=(\S+)", line)
        if m:
            current = m.group(1)
            blocks[current] = [line]
        elif current and line.startswith("      "):
            blocks[current].append(line)
    return blocks


def test_sweep_dry_run_prices_every_variant_and_load(tmp_path, capsys):
    out = _dry_run(capsys, tmp_path)
    blocks = _blocks(out)
    assert set(blocks) == {"9", "10.5"}
    duration = r"[\d.]+ (s|min|h)"
    memory = r"[\d.]+ (MB|GB)"
    for height, lines in blocks.items():
        assert re.search(rf"to run; {duration}, {memory} peak$", lines[0]), lines[0]
        for part in ("press", "swipe", "separation", "direction (3 angles)"):
            row = next(line for line in lines if line.strip().startswith(part))
            assert re.search(rf"{duration} +{memory}", row), row
        # the mesh is priced with the variant's first load only: its other runs load it from the cache
        assert "mesh" in next(line for line in lines if line.strip().startswith("press"))
        assert "mesh" not in next(line for line in lines if line.strip().startswith("swipe"))
        assert sum("if escalated:" in line for line in lines) == 2  # one per load
    assert re.search(rf"total: {duration} of work, {duration} on 2 worker\(s\), {memory} peak", out)
    assert "with the 1 flagged load(s) escalated" in out and "estimate" in out


@pytest.mark.parametrize("height", [9.0, 10.5])
def test_escalated_estimate_has_the_escalated_scenes_steps(height, tmp_path, capsys):
    lines = _blocks(_dry_run(capsys, tmp_path))[f"{height:g}"]
    swipe = lines[[i for i, line in enumerate(lines) if line.strip().startswith("swipe")][0] + 1]
    m = re.search(r"if escalated: \+.*\(nonlinear, backward Euler, (\d+) substeps: (\d+) steps", swipe)
    assert m, swipe
    # independently: the swipe under the variant, its frames by hand (the load's duration rounded up to a
    # frame, the first frame and one after: fem.trajectory.time_grid), the dynamics' substeps from the rods
    scene = SWIPE.apply(load_scene(DEFAULT).with_values({"sensor.rod.height_mm": height}), ("solve", "camera"))
    frames = math.ceil(scene.load.duration_s * scene.camera.fps - 1e-9) + 2
    substeps = max(scene.fidelity.solve.substeps, dynamics_substeps(scene))
    assert (int(m.group(1)), int(m.group(2))) == (substeps, 1 + (frames - 1) * substeps)
    if height == 10.5:
        # 0.3 mm at 10 mm/s, 14.4 mm at 200 mm/s, 1 mm at 10 mm/s: 0.202 s, 9 frames at 30 FPS; the swipe's own
        # 48 substeps (the dynamics ask 32 for 10.5 mm rods: docs/uses/sweeps.md)
        assert (substeps, frames) == (48, 9) and dynamics_substeps(scene) == 32 and "LIKELY to escalate" in swipe
    else:
        assert "not expected to escalate" in swipe


def test_no_escalation_estimate_when_the_sweep_does_not_escalate(tmp_path, capsys):
    out = _dry_run(capsys, tmp_path, "--escalate-tier", "none", "--metrics", "tear")
    assert "if escalated" not in out and "flagged" not in out
    assert "separation" not in out and "direction" not in out  # only the metrics asked for are priced


@pytest.mark.parametrize("height, diameter, risk", [(9.0, 5.0, ""), (9.5, 5.0, "possible"), (10.5, 5.0, "likely"),
                                                    (9.0, 4.0, "likely"), (6.0, 4.0, "")])
def test_escalation_proxy_is_the_rods_slenderness_against_the_measured_swipes(height, diameter, risk):
    scene = load_scene(DEFAULT).with_values({"sensor.rod.height_mm": height, "sensor.rod.diameter_mm": diameter})
    assert cost.escalation_risk(SWIPE.apply(scene, ("solve",))) == risk
    assert cost.escalation_risk(PRESS.apply(scene, ("solve",))) == ""  # no slide: not flagged


def test_sweep_wall_time_on_workers():
    assert cost.sweep_wall_s([10.0, 10.0, 10.0, 10.0], 2) == 20.0
    assert cost.sweep_wall_s([30.0, 10.0, 10.0, 10.0], 2) == 30.0  # the longest variant bounds it
    assert cost.sweep_wall_s([5.0], 4) == 5.0
