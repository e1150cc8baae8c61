"""How much faster than real time the plantar skin's estimators run (SPEC 4: cells read at up to 250 Hz).

One control tick, for both soles (double support, 0.2 m apart, each sole on a different obstacle so
that the polygons are not trivial): from the 42 x 3 force readings and the 42 proximity gaps of
each sole, the CoP (force sensors and cell centres), the active cells (eps_F), the contact area, the
support and pre-touch polygons and their areas, the obstacle's bounding box and sidestep, both
feasibility rules, then the double-support hull in the world and the combined CoP. Readings differ
every tick (fresh noise), drawn before the timing. Prints the median time per tick over repeats and
the real-time factor (1 / 250 s divided by it). Not a test. Usage:

    OMP_NUM_THREADS=1 .venv/bin/python benchmarks/bench_sole.py [--ticks 2000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from other_sensors.sole import estimators as est  # noqa: E402
from other_sensors.sole.cells import sole_layout  # noqa: E402
from other_sensors.sole.contact import FootPose, height_for_load, sole_contact  # noqa: E402
from other_sensors.sole.feasibility import EPS_AREA, EPS_TORQUE_NM, ft_rule, skin_rule  # noqa: E402
from other_sensors.sole.terrain import Box, Flat, Sphere  # noqa: E402

RATE_HZ = 250.0


def one_tick(layout, sole_area, readings, poses, eps_force_n, range_m, clearance_m):
    cops, totals, actives = [], [], []
    for (forces, gaps, wrench), pose in zip(readings, poses):
        cells = forces.sum(axis=1)
        cop = est.sole_cop(layout, forces)
        est.sole_cop(layout, forces, by="cell")
        active = est.active_cells(cells, eps_force_n)
        est.contact_area(active, layout.cell_area)
        polygon = est.support_polygon(layout.corners, active)
        area = est.polygon_area(polygon)
        est.polygon_area(est.pretouch_polygon(layout.corners, gaps, range_m))
        ft, skin = ft_rule(float(np.hypot(wrench[3], wrench[4])), EPS_TORQUE_NM), skin_rule(area, sole_area, EPS_AREA)
        if ft or skin:
            est.sidestep(polygon, clearance_m)
        cops.append(pose.to_world(cop)[:2])
        totals.append(cells.sum())
        actives.append(active)
    est.double_support_polygon(layout.corners, actives[0], poses[0], layout.corners, actives[1], poses[1])
    return est.combined_cop(np.array(cops), np.array(totals))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    layout = sole_layout()
    sole_area = layout.sole_area()
    poses = [FootPose((0.0, 0.1, 0.0)), FootPose((0.0, -0.1, 0.0))]
    terrains = [[Flat(0.0), Box((0.0, 0.1), (0.04, 0.04), 0.02)],
                [Flat(0.0), Sphere((0.07, -0.06, 0.0), 0.02), Sphere((-0.08, -0.1, 0.0), 0.02)]]
    exact = []
    for pose, terrain in zip(poses, terrains):
        z = height_for_load(layout, pose, terrain, 1e8, 400.0)
        exact.append(sole_contact(layout, pose.with_height(z), terrain, 1e8))
    rng = np.random.default_rng(0)
    ticks = [[(c.sensor_forces + rng.normal(0.0, 0.02, c.sensor_forces.shape), c.gaps, c.wrench) for c in exact]
             for _ in range(args.ticks)]
    times = []
    for _ in range(args.repeats):
        start = time.perf_counter()
        for readings in ticks:
            one_tick(layout, sole_area, readings, poses, 0.15 * est.G, 0.01, 0.03)
        times.append((time.perf_counter() - start) / args.ticks)
    per_tick = statistics.median(times)
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, numpy {np.__version__}")
    print(f"estimators, both soles, one tick: {per_tick * 1e6:.0f} us (median of {args.repeats} x {args.ticks} ticks)")
    print(f"real-time factor at {RATE_HZ:.0f} Hz: {1.0 / RATE_HZ / per_tick:.1f} x faster than real time")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
