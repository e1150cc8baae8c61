"""Plausibility of an AnySkin helmet scene (issue 39): values each well-formed that push the pads
through the helmet, or ask for more magnetometer samples than any machine we run on holds.

:func:`problems` refuses (``mlsim check`` and every load, through the kind's ``check``), naming the
field, the value, the limit and the fix:

- a push that drives the pads further back than the face stands ahead of the head's centre: the
  plate's force shared by all four pads (:func:`other_sensors.anyskin.helmet.plate_forces`: each
  a ``pad_stiffness_n_mm`` spring) moves each at least ``F / (4 k)``; past ``face_forward_mm`` the
  pads would be inside the head. The least travel is judged, so a load that could be valid is never
  refused. The skin itself is never pushed through its thickness: the point-dipole truth saturates
  at ``max_strain`` < 1 by construction, and the magnet-volume truth's inversion is refused by the
  kind's check already (``truth.worst_stretch``);
- a trace whose memory, samples x the skin's grid x grid dipole columns x the bytes one column
  takes per sample (measured), passes :data:`mlsim.plausibility.MAX_RUN_MEMORY_GB`.

:func:`warnings` lists the run that is plausible but expensive (the studies re-simulate the trace
once per face pitch, per drift factor and per truth), with its estimate; :func:`stage_cost` prices each
stage that simulates traces for ``mlsim run --dry-run`` (the kind's ``cost`` hook), from the same
measurements (the contact estimator and the bench's training are not measured: not modelled).
"""

from __future__ import annotations

from mlsim.cost_model import GB, StageCost
from mlsim.plausibility import MAX_RUN_MEMORY_GB, cost_warnings, memory_problem

from .schema import RATE_HZ, SKIN_GRID

__all__ = ["N_PADS", "BYTES_PER_SAMPLE_COLUMN", "SECONDS_PER_SAMPLE_COLUMN", "SHIPPED_DURATION_S", "problems", "warnings",
           "least_pad_travel_mm", "simulations", "traces_held", "run_cost", "stage_cost", "traces_of_stage",
           "STAGE_SECONDS_PER_SAMPLE_COLUMN"]

N_PADS = 4  # SPEC 2: four skins in an X, each on its pad
# Measured (tracemalloc peak of anyskin_signals, this machine, scenes/anyskin/push_study.toml at 750-3,000
# samples): the point-dipole truth 617-633 B a sample and dipole column at grids 7, 14, 28; the
# magnet-volume truth 415-713 at grids 7 and 14: the larger, rounded up.
BYTES_PER_SAMPLE_COLUMN = 720.0
# Measured the same way (wall, 2 shared cores): 4.5-14 us a sample and column over both truths and
# grids 7-28 (the small grids carry a fixed cost per sample): the larger.
SECONDS_PER_SAMPLE_COLUMN = 14e-6
# Per truth for the dry run's estimate (wall of anyskin_signals, headon_push.toml's 1,800 samples, 2 shared
# cores, 2026-11-27): the point dipoles 4.5, 3.7 and 4.1 us a sample and column at grids 7, 14 and 28; the
# magnet volume 9.8 and 7.4 at grids 7 and 14: the larger of each (SECONDS_PER_SAMPLE_COLUMN, the larger
# of both, stays the warnings' bound)
STAGE_SECONDS_PER_SAMPLE_COLUMN = {"point_dipole": 4.5e-6, "magnet_volume": 10e-6}
# The shipped head-on push's trace (scenes/anyskin/headon_push.toml): the reference the field
# named in a refusal is measured against (see _largest_factor)
SHIPPED_DURATION_S = 12.0


def least_pad_travel_mm(sensor) -> float:
    """The least travel (mm) of the pads under the heaviest push: shared by all four."""
    heaviest = sensor.push.peak_n * (1 + sensor.push.jitter)
    return heaviest / (N_PADS * sensor.helmet.pad_stiffness_n_mm)


def simulations(scene) -> int:
    """How many times the run simulates the helmet's trace: once for anyskin_signals (which
    anyskin_contact reads), and per study once a face pitch, a drift factor, a truth (anyskin.study)."""
    from .study import PITCHES_DEG, SWEEP_FACTORS, TRUTHS

    wanted = set(scene.outputs)
    studies = {"anyskin_pitch": len(PITCHES_DEG), "anyskin_drift": len(SWEEP_FACTORS), "anyskin_bench": len(TRUTHS)}
    n = (1 if wanted & {"anyskin_signals", "anyskin_contact"} else 0) + sum(v for k, v in studies.items() if k in wanted)
    return max(n, 1)


def traces_held(scene) -> int:
    """How many traces the run holds at once: a study's beside the cached anyskin_signals one."""
    return 2 if simulations(scene) > 1 else 1


def run_cost(scene) -> tuple[float, float, float]:
    """(samples of one trace, bytes held, seconds of the whole run)."""
    s = scene.sensor
    n = s.trajectory.duration_s * s.magnetometers.rate_hz
    columns = s.skin.grid * s.skin.grid
    return n, n * columns * BYTES_PER_SAMPLE_COLUMN * traces_held(scene), n * columns * SECONDS_PER_SAMPLE_COLUMN * simulations(scene)


def traces_of_stage(stage: str) -> int:
    """How many helmet traces ``stage`` simulates (0: it simulates none)."""
    from .study import PITCHES_DEG, SWEEP_FACTORS, TRUTHS

    return {"anyskin_signals": 1, "anyskin_pitch": len(PITCHES_DEG), "anyskin_drift": len(SWEEP_FACTORS),
            "anyskin_bench": len(TRUTHS)}.get(stage, 0)


def stage_cost(scene, stage: str) -> StageCost | None:
    """The expected cost of running ``stage`` (the kind's ``cost`` hook, :func:`mlsim.cost_model.stage_cost`):
    its traces x samples x the skin's dipole columns x the bytes and seconds a sample and column takes
    (measured, above); a study holds one trace at a time, beside the cached anyskin_signals one."""
    traces = traces_of_stage(stage)
    if traces == 0:
        return None
    s = scene.sensor
    n, columns = s.trajectory.duration_s * s.magnetometers.rate_hz, s.skin.grid * s.skin.grid
    trace = n * columns * BYTES_PER_SAMPLE_COLUMN
    kept, transient = (trace, 0.0) if stage == "anyskin_signals" else (0.0, trace)  # a study keeps its table only
    per_s = STAGE_SECONDS_PER_SAMPLE_COLUMN.get(s.skin.truth, SECONDS_PER_SAMPLE_COLUMN)
    return StageCost(stage, kept, traces * n * columns * per_s, transient_bytes=transient,
                     note=f"{traces} trace(s) of {n:.4g} samples, grid {s.skin.grid}, {s.skin.truth}")


def _largest_factor(sensor) -> tuple[str, float]:
    """The field of the trace's size furthest above its shipped value (what made the trace large)."""
    s = sensor
    factors = {"sensor.trajectory.duration_s": (s.trajectory.duration_s / SHIPPED_DURATION_S, s.trajectory.duration_s),
               "sensor.magnetometers.rate_hz": (s.magnetometers.rate_hz / RATE_HZ, s.magnetometers.rate_hz),
               "sensor.skin.grid": ((s.skin.grid / SKIN_GRID) ** 2, s.skin.grid)}
    field = max(factors, key=lambda k: factors[k][0])
    return field, factors[field][1]


def problems(scene) -> list[tuple]:
    """What refuses the AnySkin scene: ``[(field, value, reason)]`` (module docstring)."""
    s = scene.sensor
    out = []
    travel = least_pad_travel_mm(s)
    if travel >= s.helmet.face_forward_mm:
        most = N_PADS * s.helmet.pad_stiffness_n_mm * s.helmet.face_forward_mm / (1 + s.push.jitter)
        out.append(("sensor.push.peak_n", s.push.peak_n,
                    f"a {s.push.peak_n * (1 + s.push.jitter):.4g} N push (peak x (1 + jitter)) moves even {N_PADS} pads sharing it "
                    f"{travel:.4g} mm back, past the face's {s.helmet.face_forward_mm:g} mm ahead of the head's centre (into the head); "
                    f"use peak_n < {most:.4g} or stiffer pads (sensor.helmet.pad_stiffness_n_mm)"))
    n, held, _ = run_cost(scene)
    columns = s.skin.grid * s.skin.grid
    most = MAX_RUN_MEMORY_GB * GB / (columns * BYTES_PER_SAMPLE_COLUMN * traces_held(scene))
    field, value = _largest_factor(s)
    p = memory_problem(field, value, f"{n:.4g} samples ({s.trajectory.duration_s:g} s at {s.magnetometers.rate_hz:g} Hz) of "
                       f"{columns} dipole columns (grid {s.skin.grid})", held,
                       f"keep duration_s x rate_hz under {most:.3g} samples at this grid (e.g. duration_s <= "
                       f"{most / s.magnetometers.rate_hz:.4g} at {s.magnetometers.rate_hz:g} Hz), or a coarser sensor.skin.grid")
    return out + ([p] if p else [])


def warnings(scene) -> list[str]:
    """The AnySkin run's plausible but expensive work, with its estimate."""
    if problems(scene):
        return []
    n, held, seconds = run_cost(scene)
    return cost_warnings(f"the helmet's traces ({simulations(scene)} of {n:.4g} samples, grid {scene.sensor.skin.grid})", held, seconds)
