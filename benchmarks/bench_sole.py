"""How much faster than real time the plantar skin's estimators run (SPEC 4: cells read at up to 250 Hz).

One control tick, for both soles (double support, 0.2 m apart, each sole on a different obstacle so
that the polygons are not trivial): from the 42 x 3 force readings and the 42 proximity gaps of
each sole, the CoP (force sensors and cell centres), the active cells (eps_F), the contact area, the
support and pre-touch polygons and their areas, the obstacle's bounding box and sidestep, both
feasibility rules, then the double-support hull in the world and the combined CoP. Readings differ
every tick (fresh noise), drawn before the timing. Prints the median time per tick over repeats and
the real-time factor (1 / 250 s divided by it), for the compiled path (:mod:`other_sensors.sole.tick`,
one call per sole and one for the double support, as a controller would call it each tick), for
the same path over a whole recording at once (:func:`other_sensors.sole.tick.estimate_series`,
both soles, vectorised over time) and for the reference (:mod:`other_sensors.sole.estimators`).
The process is pinned to one core and numba / BLAS / OpenMP to one thread (SPEC 4's rate on one
core); the compiled functions are compiled (or loaded from numba's cache) before the timing, and
the compiled path's results are checked against the reference's before it is timed. Not a test. Usage:

    .venv/bin/python benchmarks/bench_sole.py [--ticks 2000] [--repeats 5]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMBA_NUM_THREADS"):
    os.environ[_var] = "1"  # before NumPy and numba load: one core

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
from other_sensors.sole.tick import SkinEstimator, double_support, estimate_series  # noqa: E402

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


def fast_tick(estimator, readings, poses):
    left, right = (estimator(forces, gaps, wrench) for forces, gaps, wrench in readings)
    return double_support(left, poses[0], right, poses[1])


def timed(run, ticks, repeats) -> tuple[float, float]:
    """(median, fastest) seconds per tick of ``run(readings)`` over the ticks, ``repeats`` times (the
    fastest repeat is the one least disturbed by other processes on a shared core)."""
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        for readings in ticks:
            run(readings)
        times.append((time.perf_counter() - start) / len(ticks))
    return statistics.median(times), min(times)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--ticks", type=int, default=2000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args(argv)
    os.sched_setaffinity(0, {min(os.sched_getaffinity(0))})  # one core
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
    estimator = SkinEstimator(layout, 0.15 * est.G, 0.01, EPS_TORQUE_NM, EPS_AREA, 0.03)
    for readings in ticks[:50]:  # compile, and check against the reference
        ref, (poly, cop) = one_tick(layout, sole_area, readings, poses, 0.15 * est.G, 0.01, 0.03), fast_tick(estimator, readings, poses)
        actives = [est.active_cells(f.sum(axis=1), 0.15 * est.G) for f, _, _ in readings]
        ref_poly = est.double_support_polygon(layout.corners, actives[0], poses[0], layout.corners, actives[1], poses[1])
        if not (np.allclose(cop, ref, rtol=1e-12, atol=1e-15) and np.isclose(est.polygon_area(poly), est.polygon_area(ref_poly), rtol=1e-12)):
            raise SystemExit(f"compiled path disagrees with the reference: CoP {cop} vs {ref}")
    series = [(np.stack([t[s][0] for t in ticks]), np.stack([t[s][1] for t in ticks]), np.stack([t[s][2] for t in ticks])) for s in (0, 1)]
    for s in series:
        estimate_series(estimator, *(a[:2] for a in s))

    def whole(_):
        for s in series:
            estimate_series(estimator, *s)

    results = {
        "compiled, tick by tick": timed(lambda r: fast_tick(estimator, r, poses), ticks, args.repeats),
        "compiled, whole recording": tuple(v / len(ticks) for v in timed(whole, [None], args.repeats)),
        "reference (estimators.py)": timed(lambda r: one_tick(layout, sole_area, r, poses, 0.15 * est.G, 0.01, 0.03), ticks, args.repeats),
    }
    print(f"machine: {platform.processor() or platform.machine()}, python {platform.python_version()}, numpy {np.__version__}; "
          f"pinned to core {sorted(os.sched_getaffinity(0))}, 1 thread")
    print(f"estimators, both soles, one {RATE_HZ:.0f} Hz tick ({args.repeats} repeats x {args.ticks} ticks): median (fastest repeat)")
    for name, (per_tick, best) in results.items():
        print(f"  {name:28s} {per_tick * 1e6:8.1f} us ({best * 1e6:6.1f})   {1.0 / RATE_HZ / per_tick:7.0f} x faster than real time "
              f"({1.0 / RATE_HZ / best:.0f} x)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
