"""Plausibility of a CLS scene (issue 39): values each well-formed that move the shell through its
base or past its pillars, or ask for more samples than any machine we run on holds.

:func:`problems` refuses (``mlsim check`` and every load, through the kind's ``check``), naming the
field, the value, the limit and the fix:

- a motion that takes a mount of the shell's underside (an LED, a pillar's top) down to the base:
  at the shell origin's height ``gap - compression`` and a rotation ``rx`` about x through it, a
  mount at (y, z) in the shell frame sits at ``gap - compression + y sin(rx) + z cos(rx)`` above the
  base (:func:`other_sensors.cls.shell.pillar_strains`' kinematics). The foam cannot be crushed to
  nothing and an LED cannot pass through the LTV board; the existing rules already keep the
  compression alone under the pillars' height and the estimator's 15 mm floor, so this one names
  the rotation that tips the outermost mount through;
- a shear whose pillar offset passes ``MAX_PILLAR_SHEAR_STRAIN`` of the pillars' height;
- signals, estimates or a calibration whose memory (sample count x the bytes a sample takes,
  measured) passes :data:`mlsim.plausibility.MAX_RUN_MEMORY_GB`.

The amplitudes judged are those the run moves: the calibration (``cls_calibrate``, which every
``cls_estimate`` needs) always runs the general motion with all three, a ``cls_signals`` run alone
only its ``shape``'s. The general motion's sines (:func:`other_sensors.cls.shell.trajectory`) are
bounded by the amplitudes and may reach them together, so its corners are judged.

:func:`warnings` lists the work that is plausible but expensive, with its estimate; :func:`stage_cost`
prices each stage for ``mlsim run --dry-run`` (the kind's ``cost`` hook), from the same measurements.
"""

from __future__ import annotations

import math

import numpy as np

from mlsim.cost_model import GB, StageCost
from mlsim.plausibility import MAX_RUN_MEMORY_GB, cost_warnings, memory_problem

__all__ = ["MAX_PILLAR_SHEAR_STRAIN", "SIGNAL_BYTES_PER_SAMPLE_PAIR", "CALIBRATION_BYTES_PER_POSE_PAIR", "SIGNAL_SECONDS_PER_SAMPLE",
           "ESTIMATE_SECONDS_PER_SAMPLE", "CALIBRATION_SECONDS_PER_POSE", "problems", "warnings", "lowest_mount_mm",
           "max_rotation_deg", "moved_amplitudes", "run_cost", "stage_cost", "SIGNALS_STAGE_BYTES_PER_SAMPLE_PAIR",
           "ESTIMATE_STAGE_BYTES_PER_SAMPLE_PAIR", "SIGNALS_STAGE_FIXED_S", "ESTIMATE_STAGE_FIXED_S", "ESTIMATE_STAGE_SECONDS_PER_SAMPLE",
           "CALIBRATE_STAGE_SECONDS_PER_POSE"]

# A pillar's top offset sideways by its own height: a pillar that kept its length would lie flat on
# the base. The model's linear shear law and its neglect of the pillars' bending (shell.py) hold for
# offsets well under it; the shipped shear is 6 mm on 38.1 mm pillars (0.16).
MAX_PILLAR_SHEAR_STRAIN = 1.0
# Measured (tracemalloc peak, this machine, scenes/cls/general.toml at 4,000 and 16,000 samples of
# 5 pairs, the optical truth): cls_signals 561 B and cls_estimate 436 B a sample, held together (the
# estimate reads the signals): about 200 B a sample and pair.
SIGNAL_BYTES_PER_SAMPLE_PAIR = 200.0
# the same two measurements per stage (5 pairs): cls_signals 561 / 5, cls_estimate 436 / 5
SIGNALS_STAGE_BYTES_PER_SAMPLE_PAIR = 561.0 / 5
ESTIMATE_STAGE_BYTES_PER_SAMPLE_PAIR = 436.0 / 5
# Measured the same way: cls_calibrate 4,183-4,320 B a reference pose of 5 pairs (its LM's Jacobian
# rows and the optical voltages): about 860 B a pose and pair.
CALIBRATION_BYTES_PER_POSE_PAIR = 860.0
# Measured (wall, 2 shared cores, 5 pairs): 12.5 us a sample for the signals, 65-75 us for the LM
# estimates (warm start), and 2 ms a pose for the calibration at 2,960 poses (37 s at 80 Hz: 5.8 s)
SIGNAL_SECONDS_PER_SAMPLE = 12.5e-6
ESTIMATE_SECONDS_PER_SAMPLE = 75e-6
CALIBRATION_SECONDS_PER_POSE = 2e-3
# Per stage for the dry run's estimate (wall, 2 shared cores, 2026-11-27, general.toml at 4,000 and 16,000
# samples, numba's kernels compiled): cls_signals 0.73 and 0.93 s, a fixed 0.6 s (the optics' set-up)
# then SIGNAL_SECONDS_PER_SAMPLE; cls_estimate 0.17 and 0.27 s, 0.15 s then 10 us a sample (the
# 75 us above, an LM solve a sample, stays the warnings' bound); cls_calibrate 2.1-3.3 s at 2,960 poses
# and 6.8 s at 5,920: 0.7-1.15 ms a pose, the larger rounded up (the 2 ms above stays the warnings' bound)
SIGNALS_STAGE_FIXED_S = 0.6
ESTIMATE_STAGE_FIXED_S = 0.15
ESTIMATE_STAGE_SECONDS_PER_SAMPLE = 10e-6
CALIBRATE_STAGE_SECONDS_PER_POSE = 1.2e-3


def moved_amplitudes(scene) -> set[str]:
    """The trajectory's amplitudes (``compression_mm``, ``shear_mm``, ``rotation_deg``) that the run moves."""
    shape = scene.sensor.trajectory.shape
    if calibrates(scene) or shape == "general":
        return {"compression_mm", "shear_mm", "rotation_deg"}
    return {"compression": {"compression_mm"}, "shear": {"shear_mm"}, "rotation": {"rotation_deg"}}.get(shape, set())


def calibrates(scene) -> bool:
    """Whether the run calibrates (``cls_calibrate`` asked for, or needed by ``cls_estimate``)."""
    return bool({"cls_calibrate", "cls_estimate"} & set(scene.outputs))


def _mounts_mm(sensor) -> np.ndarray:
    """(M, 2) the shell's underside mounts (y, z) mm in the shell frame: the LEDs (z = 0) and the
    pillars' tops (``gap - height`` below the origin, as :func:`other_sensors.cls.shell.pillar_strains`)."""
    p, f = sensor.pairs, sensor.foam
    y = (np.arange(p.n) - (p.n - 1) / 2) * p.pitch_mm
    leds = y + np.where(np.arange(p.n) % 2 == 0, 1.0, -1.0) * p.stagger_mm  # ltv.default_layout's stagger
    tops = np.asarray(f.pillar_y_mm, float)
    return np.concatenate([np.stack([leds, np.zeros(p.n)], 1), np.stack([tops, np.full(3, f.height_mm - p.gap_mm)], 1)])


def lowest_mount_mm(sensor, compression_mm: float, rotation_deg: float) -> float:
    """The lowest mount's height over the base (mm) with the shell pressed ``compression_mm`` and
    turned by +-``rotation_deg`` about x (module docstring)."""
    m = _mounts_mm(sensor)
    rx = math.radians(rotation_deg)
    z0 = sensor.pairs.gap_mm - compression_mm
    return float(np.min(z0 - math.sin(rx) * np.abs(m[:, 0]) + math.cos(rx) * m[:, 1]))


def max_rotation_deg(sensor, compression_mm: float) -> float:
    """The largest rotation (deg) that keeps every mount above the base at ``compression_mm``
    (bisection: the lowest mount falls monotonically with the rotation up to 90 deg)."""
    lo, hi = 0.0, 90.0
    if lowest_mount_mm(sensor, compression_mm, lo) <= 0:
        return 0.0
    for _ in range(60):
        mid = (lo + hi) / 2
        lo, hi = (mid, hi) if lowest_mount_mm(sensor, compression_mm, mid) > 0 else (lo, mid)
    return lo


def _motion_problems(scene) -> list[tuple]:
    s = scene.sensor
    tr = s.trajectory
    moved = moved_amplitudes(scene)
    compression = tr.compression_mm if "compression_mm" in moved else 0.0
    out = []
    where = "the calibration's general motion" if calibrates(scene) else f"the {tr.shape} trajectory"
    if "rotation_deg" in moved and tr.rotation_deg > 0:
        low = lowest_mount_mm(s, compression, tr.rotation_deg)
        if low <= 0:
            room = max_rotation_deg(s, compression)
            out.append(("sensor.trajectory.rotation_deg", tr.rotation_deg,
                        f"{where} tips the shell {tr.rotation_deg:g} deg at {compression:g} mm of compression: its outermost mount "
                        f"(an LED or a pillar's top) reaches {low:.3g} mm, through the base; the limit at this compression is "
                        f"{room:.3g} deg: use rotation_deg < {room:.3g}, less compression_mm or a narrower sensor.pairs.pitch_mm"))
    if "shear_mm" in moved:
        limit = MAX_PILLAR_SHEAR_STRAIN * s.foam.height_mm
        if tr.shear_mm > limit:
            out.append(("sensor.trajectory.shear_mm", tr.shear_mm,
                        f"{where} offsets the pillars' tops by {tr.shear_mm:g} mm, more than {MAX_PILLAR_SHEAR_STRAIN:g} x their "
                        f"{s.foam.height_mm:g} mm height (a pillar that kept its length would lie on the base): use shear_mm <= {limit:.4g}"))
    return out


def run_cost(scene) -> dict[str, tuple[float, float, float]]:
    """Per stage the run computes: (sample count, bytes, seconds) from the measured constants."""
    s = scene.sensor
    pairs = s.pairs.n
    out = {}
    if set(scene.outputs) & {"cls_signals", "cls_estimate"}:
        n = s.trajectory.duration_s * s.trajectory.rate_hz
        seconds = n * (SIGNAL_SECONDS_PER_SAMPLE + (ESTIMATE_SECONDS_PER_SAMPLE if "cls_estimate" in scene.outputs else 0.0))
        out["signals"] = (n, n * pairs * SIGNAL_BYTES_PER_SAMPLE_PAIR, seconds)
    if calibrates(scene):
        n = s.calibration.duration_s * s.calibration.rate_hz
        out["calibration"] = (n, n * pairs * CALIBRATION_BYTES_PER_POSE_PAIR, n * CALIBRATION_SECONDS_PER_POSE)
    return out


def stage_cost(scene, stage: str) -> StageCost | None:
    """The expected cost of running ``stage`` (the kind's ``cost`` hook, :func:`mlsim.cost_model.stage_cost`):
    its samples (trajectory or calibration poses) x the bytes and seconds one takes (measured, above)."""
    s = scene.sensor
    pairs = s.pairs.n
    if stage in ("cls_signals", "cls_estimate"):
        n = s.trajectory.duration_s * s.trajectory.rate_hz
        per_bytes, fixed_s, per_s = ((SIGNALS_STAGE_BYTES_PER_SAMPLE_PAIR, SIGNALS_STAGE_FIXED_S, SIGNAL_SECONDS_PER_SAMPLE)
                                     if stage == "cls_signals" else
                                     (ESTIMATE_STAGE_BYTES_PER_SAMPLE_PAIR, ESTIMATE_STAGE_FIXED_S, ESTIMATE_STAGE_SECONDS_PER_SAMPLE))
        return StageCost(stage, n * pairs * per_bytes, fixed_s + n * per_s, note=f"{n:.4g} samples of {pairs} pairs")
    if stage == "cls_calibrate":
        n = s.calibration.duration_s * s.calibration.rate_hz
        return StageCost(stage, n * pairs * CALIBRATION_BYTES_PER_POSE_PAIR, n * CALIBRATE_STAGE_SECONDS_PER_POSE,
                         note=f"{n:.4g} reference poses of {pairs} pairs")
    return None


def _size_problems(scene) -> list[tuple]:
    s = scene.sensor
    costs = run_cost(scene)
    out = []
    if "signals" in costs:
        n, nbytes, _ = costs["signals"]
        tr = s.trajectory
        most = _most_samples(s.pairs.n, SIGNAL_BYTES_PER_SAMPLE_PAIR)
        field, value = (("sensor.trajectory.rate_hz", tr.rate_hz) if tr.rate_hz > 2000.0  # SPEC 3's rate
                        else ("sensor.trajectory.duration_s", tr.duration_s))
        p = memory_problem(field, value, f"{n:.4g} samples ({tr.duration_s:g} s at {tr.rate_hz:g} Hz) of {s.pairs.n} pairs", nbytes,
                           f"keep duration_s x rate_hz under {most:.3g} samples: rate_hz <= {most / tr.duration_s:.4g} or "
                           f"duration_s <= {most / tr.rate_hz:.4g}")
        out += [p] if p else []
    if "calibration" in costs:
        n, nbytes, _ = costs["calibration"]
        cal = s.calibration
        most = _most_samples(s.pairs.n, CALIBRATION_BYTES_PER_POSE_PAIR)
        field, value = (("sensor.calibration.rate_hz", cal.rate_hz) if cal.rate_hz > 80.0  # SPEC 3's reference rate
                        else ("sensor.calibration.duration_s", cal.duration_s))
        p = memory_problem(field, value, f"the calibration's {n:.4g} reference poses ({cal.duration_s:g} s at {cal.rate_hz:g} Hz) of "
                           f"{s.pairs.n} pairs", nbytes, f"keep duration_s x rate_hz under {most:.3g} poses: rate_hz <= "
                           f"{most / cal.duration_s:.4g} or duration_s <= {most / cal.rate_hz:.4g}")
        out += [p] if p else []
    return out


def _most_samples(pairs: int, bytes_per_sample_pair: float) -> float:
    """The most samples of ``pairs`` pairs that fit in ``MAX_RUN_MEMORY_GB``."""
    return MAX_RUN_MEMORY_GB * GB / (pairs * bytes_per_sample_pair)


def problems(scene) -> list[tuple]:
    """What refuses the CLS scene: ``[(field, value, reason)]`` (module docstring)."""
    return _motion_problems(scene) + _size_problems(scene)


def warnings(scene) -> list[str]:
    """The CLS run's plausible but expensive work, with its estimate."""
    if problems(scene):
        return []
    out = []
    for name, (n, nbytes, seconds) in run_cost(scene).items():
        what = f"the signals and their estimates ({n:.4g} samples)" if name == "signals" else f"the calibration ({n:.4g} reference poses)"
        out += cost_warnings(what, nbytes, seconds)
    return out
