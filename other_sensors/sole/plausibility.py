"""Plausibility of a plantar-sole scene (issue 39): values each well-formed that put a foot where the
contact model does not reach, a robot whose legs cannot span its feet, or a balance study longer
than any machine we run on holds.

:func:`problems` refuses (``mlsim check`` and every load, through the kind's ``check``), naming the
field, the value, the limit and the fix:

- a foot the run places (:func:`feet`) with no terrain under any of its cells (the contact stage has nothing to stand on);
- a foot that sinks further than the skin is thick (``SKIN_THICKNESS_MM``): the Winkler layer
  (:mod:`other_sensors.sole.contact`) is springs only as deep as the skin; past it the foot's
  bottom meets the terrain, which the model does not cover. A foot held at ``height_mm`` is judged
  by its deepest overlap (first contact less the height); one placed by ``load_n`` (or the robot's
  weight in the balance loop, which stands on one sole) by the least sink that load can have, the
  whole sole's ``F / (k A_cells)``: a load that could be valid is never refused;
- two feet (double support, or the landing's step) further apart than two legs reach: a leg is
  shorter than the CoM's height (the hips lie below the CoM), so the feet are at most
  ``2 z_com`` apart;
- a balance study whose memory (ticks x pushes x the bytes a tick takes, measured) passes
  :data:`mlsim.plausibility.MAX_RUN_MEMORY_GB`.

:func:`warnings` lists the balance runs that are plausible but expensive, with their estimate;
:func:`stage_cost` prices the balance stages for ``mlsim run --dry-run`` (the kind's ``cost`` hook),
from the same measurements (the contact stages, milliseconds a foot, are not modelled).
"""

from __future__ import annotations

import math

import numpy as np

from mlsim.cost_model import GB, StageCost
from mlsim.plausibility import MAX_RUN_MEMORY_GB, cost_warnings, memory_problem

from .estimators import G
from .schema import FOUNDATION_STIFFNESS_N_M3

__all__ = ["SKIN_THICKNESS_MM", "BYTES_PER_TICK", "SECONDS_PER_TICK", "problems", "warnings", "least_sink_mm", "feet", "balance_runs",
           "balance_ticks", "stage_cost"]

# The skin's depth (cells, force sensors' foam, cover). A choice consistent with the foundation: a thin
# layer's Winkler modulus is about E / h (Johnson, Contact Mechanics, 1985, sec. 5.9), and the default
# 1e8 N/m^3 over 5 mm is a 0.5 MPa elastomer, a soft cover's; the schema's "few-millimetre skin".
SKIN_THICKNESS_MM = 5.0
# Measured (scenes/sole/balance_push.toml at 250 and 1,000 ticks, this machine): the balance loop holds
# 425 B a tick (tracemalloc peak: its histories and the tick's pressure field) and takes 290 us a tick
# on 2 shared cores (the fixed cost of the first 250 ticks excluded).
BYTES_PER_TICK = 425.0
SECONDS_PER_TICK = 290e-6
BALANCE_OUTPUTS = ("sole_balance", "sole_balance_sweep")


def feet(scene) -> list[tuple[str, object, object]]:
    """(dotted field prefix, foot, terrain) of every foot the run places: the foot for the contact
    (and the feasibility that reads it) and double support, the second foot for double support, each
    obstacle case's for the obstacle table."""
    s, wanted = scene.sensor, set(scene.outputs)
    out = []
    if wanted & {"sole_contact", "sole_feasibility", "sole_double_support"}:
        out.append(("sensor.foot", s.foot, s.terrain))
    if "sole_double_support" in wanted and s.second_foot is not None:
        out.append(("sensor.second_foot", s.second_foot, s.terrain))
    if "sole_obstacle_table" in wanted:
        out += [(f"sensor.obstacles[{i}].foot", c.foot, c.terrain) for i, c in enumerate(s.obstacles)]
    return out


def least_sink_mm(sensor, load_n: float) -> float:
    """The least a sole can sink under ``load_n`` (mm): the whole sole's cells carrying it."""
    layout = sensor.cells.layout()
    return 1e3 * load_n / (sensor.foundation.stiffness_n_m3 * layout.n_cells * layout.cell_area)


def _most_load_n(sensor) -> float:
    layout = sensor.cells.layout()
    return SKIN_THICKNESS_MM * 1e-3 * sensor.foundation.stiffness_n_m3 * layout.n_cells * layout.cell_area


def _sink_fix(sensor, field: str) -> str:
    return (f"use {field} < {_most_load_n(sensor):.4g} N, or a stiffer foundation (sensor.foundation.stiffness_n_m3, "
            f"{FOUNDATION_STIFFNESS_N_M3:g} by default)")


def _foot_problems(scene) -> list[tuple]:
    from .landing import first_contact_height

    sensor = scene.sensor
    layout, n = sensor.cells.layout(), sensor.cells.quadrature
    out = []
    for prefix, foot, terrain in feet(scene):
        try:
            # a primitive 1e300 mm away overflows its distance to inf, which reads (rightly) as no terrain there
            with np.errstate(over="ignore", invalid="ignore"):
                touch_mm = 1e3 * first_contact_height(layout, foot.pose(), terrain.to_terrain(), n)
        except ValueError:
            out.append((f"{prefix}.x_mm", foot.x_mm, f"no terrain lies under any cell of the sole at ({foot.x_mm:g}, {foot.y_mm:g}) mm; "
                                                     "move the foot over the terrain's primitives or add a flat ground"))
            continue
        if foot.height_mm is not None:
            depth = touch_mm - foot.height_mm
            if depth > SKIN_THICKNESS_MM:
                out.append((f"{prefix}.height_mm", foot.height_mm,
                            f"the sole's lowest point overlaps the terrain by {depth:.4g} mm (first contact at {touch_mm:.4g} mm), "
                            f"deeper than the {SKIN_THICKNESS_MM:g} mm skin (other_sensors.sole.plausibility.SKIN_THICKNESS_MM): "
                            f"use height_mm > {touch_mm - SKIN_THICKNESS_MM:.4g}"))
        else:
            sink = least_sink_mm(sensor, foot.load_n)
            if sink > SKIN_THICKNESS_MM:
                out.append((f"{prefix}.load_n", foot.load_n,
                            f"even the whole sole carrying it sinks {sink:.4g} mm, deeper than the {SKIN_THICKNESS_MM:g} mm skin "
                            f"(other_sensors.sole.plausibility.SKIN_THICKNESS_MM): {_sink_fix(sensor, 'load_n')}"))
    return out


def _span_problems(sensor) -> list[tuple]:
    reach_mm = 2 * sensor.balance.z_com_m * 1e3
    why = f"two legs, each shorter than the CoM's {sensor.balance.z_com_m:g} m height, span at most {reach_mm:.4g} mm"
    out = []
    if sensor.second_foot is not None:
        dx, dy = sensor.second_foot.x_mm - sensor.foot.x_mm, sensor.second_foot.y_mm - sensor.foot.y_mm
        if math.hypot(dx, dy) > reach_mm:
            axis = "x_mm" if abs(dx) >= abs(dy) else "y_mm"
            out.append((f"sensor.second_foot.{axis}", getattr(sensor.second_foot, axis),
                        f"the feet are {math.hypot(dx, dy):.4g} mm apart; {why} (sensor.balance.z_com_m): bring the second foot "
                        f"within {reach_mm:.4g} mm of the first"))
    landing = sensor.landing
    if landing is not None and math.hypot(landing.step_length_mm, landing.step_width_mm) > reach_mm:
        axis = "step_length_mm" if landing.step_length_mm >= landing.step_width_mm else "step_width_mm"
        out.append((f"sensor.landing.{axis}", getattr(landing, axis),
                    f"a step {landing.step_length_mm:g} mm long and {landing.step_width_mm:g} mm wide puts the feet "
                    f"{math.hypot(landing.step_length_mm, landing.step_width_mm):.4g} mm apart; {why}: shorten the step"))
    return out


def balance_runs(scene) -> int:
    """How many balance loops the run simulates: one for sole_balance, one a push for sole_balance_sweep."""
    return (("sole_balance" in scene.outputs) + len(scene.sensor.balance_sweep.push_n) * ("sole_balance_sweep" in scene.outputs))


def balance_ticks(scene) -> float:
    """The control ticks the balance stages run in all."""
    return balance_runs(scene) * scene.sensor.balance.duration_s * scene.sensor.balance.rate_hz


def stage_cost(scene, stage: str) -> StageCost | None:
    """The expected cost of running ``stage`` (the kind's ``cost`` hook, :func:`mlsim.cost_model.stage_cost`):
    the balance loop's ticks (one run for sole_balance, one a push for sole_balance_sweep) x the bytes
    and seconds a tick takes (measured, above); None for the other stages."""
    runs = {"sole_balance": 1, "sole_balance_sweep": len(scene.sensor.balance_sweep.push_n)}.get(stage)
    if runs is None:
        return None
    b = scene.sensor.balance
    ticks = runs * b.duration_s * b.rate_hz
    return StageCost(stage, ticks * BYTES_PER_TICK, ticks * SECONDS_PER_TICK,
                     note=f"{runs} run(s) of {b.duration_s * b.rate_hz:.4g} ticks ({b.duration_s:g} s at {b.rate_hz:g} Hz)")


def _balance_problems(scene) -> list[tuple]:
    s = scene.sensor
    if not set(BALANCE_OUTPUTS) & set(scene.outputs):
        return []
    out = []
    weight = s.balance.mass_kg * G
    if least_sink_mm(s, weight) > SKIN_THICKNESS_MM:
        out.append(("sensor.balance.mass_kg", s.balance.mass_kg,
                    f"standing on one sole, the robot's {weight:.4g} N sink even the whole sole {least_sink_mm(s, weight):.4g} mm, "
                    f"deeper than the {SKIN_THICKNESS_MM:g} mm skin (other_sensors.sole.plausibility.SKIN_THICKNESS_MM): use mass_kg < "
                    f"{_most_load_n(s) / G:.4g}, or a stiffer foundation (sensor.foundation.stiffness_n_m3)"))
    ticks, b = balance_ticks(scene), s.balance
    most = MAX_RUN_MEMORY_GB * GB / BYTES_PER_TICK
    field, value = ("sensor.balance.rate_hz", b.rate_hz) if b.rate_hz > 250.0 else ("sensor.balance.duration_s", b.duration_s)  # SPEC 4's 250 Hz
    p = memory_problem(field, value, f"{ticks:.4g} balance ticks ({balance_runs(scene)} run(s) of {b.duration_s:g} s at {b.rate_hz:g} Hz)",
                       ticks * BYTES_PER_TICK, f"keep the runs x duration_s x rate_hz under {most:.3g} ticks: fewer "
                                               "sensor.balance_sweep.push_n, a shorter duration_s or a lower rate_hz")
    return out + ([p] if p else [])


def problems(scene) -> list[tuple]:
    """What refuses the plantar-sole scene: ``[(field, value, reason)]`` (module docstring)."""
    s = scene.sensor
    return _foot_problems(scene) + _span_problems(s) + _balance_problems(scene)


def warnings(scene) -> list[str]:
    """The balance runs' plausible but expensive work, with its estimate."""
    if problems(scene):
        return []
    ticks = balance_ticks(scene)
    return cost_warnings(f"the balance loop ({ticks:.4g} ticks)", ticks * BYTES_PER_TICK, ticks * SECONDS_PER_TICK)
