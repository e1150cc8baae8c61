"""Plausibility of the sibling kinds' scenes (issue 39, item 1): values each well-formed that move the
CLS shell through its base, push the AnySkin pads into the head, put a sole where the Winkler layer
does not reach, or ask for more memory than any machine holds, are refused by ``mlsim check`` (exit 2)
naming the field, the value, the limit and the fix; every shipped sibling scene passes, without a
warning. Each limit here is worked out from the geometry or the stated constants by hand, not read
back from the code's message.
"""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from mlsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
SIBLING_SCENES = sorted(str(p.relative_to(ROOT)) for d in ("cls", "anyskin", "sole") for p in (ROOT / "scenes" / d).glob("*.toml"))
GIB = 1024**3


def check(scene: str, capsys, *changes: str) -> tuple[int, str, str]:
    argv = ["check", str(ROOT / scene)]
    for c in changes:
        argv += ["--set", c]
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in err
    return code, out, err


def refused(scene: str, capsys, field: str, *changes: str) -> str:
    """The problem line naming ``field`` of a scene that must be refused with exit 2."""
    code, _, err = check(scene, capsys, *changes)
    assert code == 2, err
    lines = [line.strip() for line in err.splitlines() if line.strip().startswith(field + " = ")]
    assert lines, err
    return lines[0]


@pytest.mark.parametrize("scene", SIBLING_SCENES)
def test_every_shipped_sibling_scene_passes_check_without_a_warning(scene, capsys):
    code, out, err = check(scene, capsys)
    assert code == 0, err
    assert "warning:" not in out


# ------------------------------------------------------------------------------------------- CLS
def test_cls_rotation_that_tips_a_pillar_through_the_base_is_refused_with_the_largest_rotation(capsys):
    # general.toml: 5 pairs at 20 mm pitch (LEDs out to 40 + 6 mm), pillars at +-45 mm whose tops sit
    # 40 - 38.1 = 1.9 mm under the shell origin, 18 mm of compression: the origin 22 mm up. The pillar
    # top (45, -1.9) reaches the base at 45 sin r + 1.9 cos r = 22, before the LED (46 sin r = 22, 28.6 deg).
    z0, y, z = 40.0 - 18.0, 45.0, 1.9
    limit = math.degrees(math.asin(z0 / math.hypot(y, z)) - math.atan2(z, y))
    assert 26.5 < limit < 27.0
    line = refused("scenes/cls/general.toml", capsys, "sensor.trajectory.rotation_deg", "sensor.trajectory.rotation_deg=30")
    assert "30" in line and "through the base" in line and f"use rotation_deg < {limit:.3g}" in line
    code, _, err = check("scenes/cls/general.toml", capsys, f"sensor.trajectory.rotation_deg={limit - 0.05:.3f}")
    assert code == 0, err


def test_cls_rotation_is_judged_only_where_the_run_moves_it(capsys):
    # cls_signals alone on the compression trajectory never rotates the shell: 30 deg is not refused
    code, _, err = check("scenes/cls/general.toml", capsys, "outputs=['cls_signals']", "sensor.trajectory.shape='compression'",
                         "sensor.trajectory.rotation_deg=30")
    assert code == 0, err


def test_cls_shear_past_the_pillars_height_is_refused(capsys):
    line = refused("scenes/cls/shear.toml", capsys, "sensor.trajectory.shear_mm", "sensor.trajectory.shear_mm=40")
    assert "38.1" in line and "use shear_mm <= 38.1" in line  # SPEC 3: 1.5 in pillars
    code, _, err = check("scenes/cls/shear.toml", capsys, "sensor.trajectory.shear_mm=38")
    assert code == 0, err


def test_cls_calibration_too_large_for_memory_is_refused_with_the_most_poses(capsys):
    from other_sensors.cls.plausibility import CALIBRATION_BYTES_PER_POSE_PAIR

    # 3600 s at 100 kHz: 3.6e8 poses of 5 pairs; the limit is 64 GiB over the bytes of a pose's 5 pairs
    most = 64 * GIB / (5 * CALIBRATION_BYTES_PER_POSE_PAIR)
    line = refused("scenes/cls/general.toml", capsys, "sensor.calibration.rate_hz", "sensor.calibration.rate_hz=100000",
                   "sensor.calibration.duration_s=3600")
    assert "3.6e+08 reference poses" in line and "64 GB" in line and f"rate_hz <= {most / 3600:.4g}" in line


def test_cls_signals_too_large_for_memory_are_refused_and_a_large_run_is_warned(capsys):
    line = refused("scenes/cls/general.toml", capsys, "sensor.trajectory.rate_hz", "sensor.trajectory.rate_hz=100000",
                   "sensor.trajectory.duration_s=600", "sensor.pairs.n=16")
    assert "6e+07 samples" in line and "16 pairs" in line
    # the same with SPEC 3's 5 pairs fits (6e7 x 5 x 200 B = 56 GiB) but is worth a warning
    code, out, err = check("scenes/cls/general.toml", capsys, "sensor.trajectory.rate_hz=100000", "sensor.trajectory.duration_s=600")
    assert code == 0, err
    assert f"about {6e7 * 5 * 200 / GIB:.3g} GB expected" in out


# --------------------------------------------------------------------------------------- AnySkin
def test_anyskin_push_that_drives_the_pads_into_the_head_is_refused(capsys):
    # headon_push: 5 N/mm pads, the face 150 mm ahead of the head's centre, +-20 % jitter. 5000 N shared
    # by all four pads still moves each 5000 x 1.2 / 20 = 300 mm; the limit is 4 x 5 x 150 / 1.2 = 2500 N.
    line = refused("scenes/anyskin/headon_push.toml", capsys, "sensor.push.peak_n", "sensor.push.peak_n=5000")
    assert "300 mm back" in line and "150 mm" in line and "use peak_n < 2500" in line
    code, _, err = check("scenes/anyskin/headon_push.toml", capsys, "sensor.push.peak_n=2400")
    assert code == 0, err


def test_anyskin_trace_too_large_for_memory_is_refused_naming_what_grew(capsys):
    from other_sensors.anyskin.plausibility import BYTES_PER_SAMPLE_COLUMN

    # push_study runs the studies: two traces of 14 x 14 dipole columns held at once
    most = 64 * GIB / (196 * BYTES_PER_SAMPLE_COLUMN * 2)
    line = refused("scenes/anyskin/push_study.toml", capsys, "sensor.magnetometers.rate_hz", "sensor.magnetometers.rate_hz=10000",
                   "sensor.trajectory.duration_s=600")
    assert "6e+06 samples" in line and f"under {most:.3g} samples" in line
    # a finer skin (60 / 14 squared: 18x the columns) on a 100 s trace (8.3x the shipped 12 s): the grid grew most
    assert 100 * 150 * 3600 * BYTES_PER_SAMPLE_COLUMN * 2 > 64 * GIB
    refused("scenes/anyskin/push_study.toml", capsys, "sensor.skin.grid", "sensor.skin.grid=60", "sensor.trajectory.duration_s=100")


# ------------------------------------------------------------------------------------------ sole
def test_sole_load_that_sinks_even_the_whole_sole_past_the_skin_is_refused(capsys):
    # 42 cells of 690 mm^2 on a 1e8 N/m^3 foundation carry at most 5 mm x k x A = 14,490 N within the skin
    most = 5e-3 * 1e8 * 42 * 690e-6
    line = refused("scenes/sole/large_flat.toml", capsys, "sensor.foot.load_n", "sensor.foot.load_n=1e5")
    assert f"sinks {1e5 / (1e8 * 42 * 690e-6) * 1e3:.4g} mm" in line and f"use load_n < {most:.4g} N" in line
    # a soft foundation refuses the shipped load and names the stiffness in the fix
    line = refused("scenes/sole/large_flat.toml", capsys, "sensor.foot.load_n", "sensor.foundation.stiffness_n_m3=1e5")
    assert "stiffness_n_m3" in line


def test_sole_foot_held_below_the_skin_is_refused(capsys):
    # large_flat: a 20 mm box under the whole sole: first contact at 20 mm; 10 mm overlaps 10 mm, the skin is 5
    line = refused("scenes/sole/large_flat.toml", capsys, "sensor.foot.height_mm", "sensor.foot.height_mm=10")
    assert "overlaps the terrain by 10 mm" in line and "use height_mm > 15" in line
    code, _, err = check("scenes/sole/large_flat.toml", capsys, "sensor.foot.height_mm=16")
    assert code == 0, err


def test_sole_foot_over_no_terrain_is_refused(capsys):
    line = refused("scenes/sole/small_flat_ankle.toml", capsys, "sensor.foot.x_mm",
                   "sensor.terrain.primitives=[{shape='box', center_mm=[0.0, 0.0], size_mm=[40.0, 40.0], top_mm=20.0}]",
                   "sensor.foot.x_mm=1000")
    assert "no terrain" in line


def test_sole_feet_further_apart_than_two_legs_are_refused(capsys):
    # z_com 0.8 m: two legs span at most 1600 mm; double_support's first foot is at (50, 100) mm
    line = refused("scenes/sole/double_support.toml", capsys, "sensor.second_foot.y_mm", "sensor.second_foot.y_mm=-2000")
    assert f"{math.hypot(50, 2100):.4g} mm apart" in line and "1600 mm" in line
    line = refused("scenes/sole/obstacles.toml", capsys, "sensor.landing.step_length_mm", "sensor.landing.step_length_mm=2000")
    assert f"{math.hypot(2000, 200):.4g} mm apart" in line


def test_sole_balance_on_a_foundation_too_soft_for_the_robot_is_refused(capsys):
    # 86 kg on one sole: 843.7 N; at 1e6 N/m^3 the whole sole sinks 843.7 / (1e6 x 0.02898) = 29 mm
    line = refused("scenes/sole/balance_push.toml", capsys, "sensor.balance.mass_kg", "sensor.foundation.stiffness_n_m3=1e6")
    assert f"{86 * 9.81 / (1e6 * 42 * 690e-6) * 1e3:.4g} mm" in line
    assert f"use mass_kg < {5e-3 * 1e6 * 42 * 690e-6 / 9.81:.4g}" in line


def test_sole_balance_sweep_too_large_for_memory_is_refused(capsys):
    from other_sensors.sole.plausibility import BYTES_PER_TICK

    # 300 pushes of 60 s at 10 kHz: 1.8e8 ticks
    pushes = "[" + ", ".join(f"{p:.1f}" for p in range(300)) + "]"
    assert 1.8e8 * BYTES_PER_TICK > 64 * GIB
    line = refused("scenes/sole/balance_sweep.toml", capsys, "sensor.balance.rate_hz", "sensor.balance.rate_hz=10000",
                   "sensor.balance.duration_s=60", f"sensor.balance_sweep.push_n={pushes}")
    assert "1.8e+08 balance ticks (300 run(s)" in line
