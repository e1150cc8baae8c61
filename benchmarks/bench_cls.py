"""CLS pose estimation speed on 2 kHz data (SPEC 3 reference: 7.02 iterations on average, ~0.125 ms per
estimate in C on a 2.5 GHz laptop CPU). Not a test: prints figures.

    OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 .venv/bin/python benchmarks/bench_cls.py [--seconds 10] [--shape general]

Prints, for the warm start of SPEC 3 (each estimate starts from the previous one) and for a cold start
(each from the rest pose: the fairer comparison with the SPEC's 7.02 iterations, which at 2 kHz with
a warm start would be surprising; the SPEC does not say how its iterations were counted):
(1) the whole series through :func:`estimate_poses` (compiled loop: motion detection + LM), as time
per LM estimate (best of 5) with the mean iteration count, and (2) for the warm start, the median of
single estimates timed one by one from Python (this adds numba's dispatch overhead of a few
microseconds). ``--six-dof`` runs the 6-DoF estimator on a ring of 6 pairs instead.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from other_sensors.cls.estimator import AT_REST, LmSettings, _args, _lm, estimate_poses, estimate_poses6, usable  # noqa: E402
from other_sensors.cls.ltv import default_layout, ring_layout  # noqa: E402
from other_sensors.cls.shell import ADC_RANGE_V, measure, measure6, trajectory, trajectory6  # noqa: E402


def _series(volts, layout, settings, n_rest, estimate, repeats=5):
    """Best-of-``repeats`` time per LM estimate (ms), the estimates, and the mean iterations."""
    estimate(volts[:n_rest + 50], layout, settings, n_rest, ADC_RANGE_V)  # compile
    runs = []
    for _ in range(repeats):
        start = time.perf_counter()
        est = estimate(volts, layout, settings, n_rest, ADC_RANGE_V)
        runs.append(time.perf_counter() - start)
    fitted = est.status != AT_REST
    return 1e3 * min(runs) / max(int(fitted.sum()), 1), est, float(est.iterations[fitted].mean()), fitted


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0)
    parser.add_argument("--shape", default="general")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--six-dof", action="store_true", help="the 6-DoF estimator on a ring of 6 pairs")
    args = parser.parse_args(argv)
    if args.six_dof:
        return _six_dof(args)

    rate, rest_s = 2000.0, 0.25
    layout, settings = default_layout(), LmSettings()
    t = np.arange(int(args.seconds * rate)) / rate
    poses = trajectory(args.shape, t, rest_s, layout.rest_p[2], 10.0, 6.0, 6.0, 0.5, np.random.default_rng([args.seed, 0]))
    volts, _ = measure(poses, layout, 0.7, np.random.default_rng([args.seed, 1]))
    n_rest = int(rest_s * rate)

    per_estimate_ms, est, mean_it, fitted = _series(volts, layout, settings, n_rest, estimate_poses)
    cold_ms, cold, cold_it, _ = _series(volts, layout, LmSettings(warm_start=False), n_rest, estimate_poses)
    n_fit = int(fitted.sum())

    # single estimates, each warm-started from the previous sample's estimate, timed one by one
    ok = usable(volts, ADC_RANGE_V)
    extra = _args(layout, settings)
    out = np.empty(3)
    idx = np.flatnonzero(fitted)
    times, iters = np.empty(len(idx)), np.empty(len(idx))
    for j, s in enumerate(idx):
        mu0 = est.poses[s - 1] if s > 0 and np.all(np.isfinite(est.poses[s - 1])) else np.array([0.0, layout.rest_p[2], 0.0])
        vm, okk = np.where(ok[s], volts[s], 0.0), ok[s]
        start = time.perf_counter_ns()
        it, _ = _lm(vm, okk, mu0, *extra, out)
        times[j] = (time.perf_counter_ns() - start) * 1e-6
        iters[j] = it
    err = est.poses[fitted] - poses[fitted]
    print(f"CLS estimator, {args.shape} trajectory, {args.seconds:g} s at {rate:g} Hz, {layout.n_pairs} pairs, noise 0.7 mV RMS")
    print(f"  LM estimates: {n_fit} of {len(t)} samples (the rest were at rest: no estimate)")
    print(f"  warm start (SPEC 3), series (compiled loop): {per_estimate_ms:.4f} ms per estimate (best of 5), "
          f"mean iterations {mean_it:.2f} (max {est.iterations.max()})")
    print(f"  cold start (from rest), series (compiled loop): {cold_ms:.4f} ms per estimate (best of 5), "
          f"mean iterations {cold_it:.2f} (max {cold.iterations.max()})")
    print(f"  warm start, single calls from Python: median {np.median(times):.4f} ms per estimate (p90 {np.percentile(times, 90):.4f} ms)")
    print("  SPEC 3 reference: 7.02 iterations, ~0.125 ms per estimate (C, 2.5 GHz laptop CPU)")
    print(f"  RMS error: y {np.sqrt(np.mean(err[:, 0] ** 2)):.4f} mm, z {np.sqrt(np.mean(err[:, 1] ** 2)):.4f} mm, "
          f"rx {np.degrees(np.sqrt(np.mean(err[:, 2] ** 2))):.4f} deg")
    return 0


def _six_dof(args) -> int:
    rate, rest_s = 2000.0, 0.25
    layout = ring_layout()
    t = np.arange(int(args.seconds * rate)) / rate
    poses = trajectory6(args.shape, t, rest_s, layout.rest_p[2], 10.0, 6.0, 6.0, 0.5, np.random.default_rng([args.seed, 0]))
    volts, _ = measure6(poses, layout, 0.7, np.random.default_rng([args.seed, 1]))
    n_rest = int(rest_s * rate)
    print(f"CLS 6-DoF estimator, {args.shape} trajectory, {args.seconds:g} s at {rate:g} Hz, ring of {layout.n_pairs} pairs, noise 0.7 mV RMS")
    for name, settings in (("warm start", LmSettings()), ("cold start (from rest)", LmSettings(warm_start=False))):
        ms, est, mean_it, fitted = _series(volts, layout, settings, n_rest, estimate_poses6)
        err = est.poses[fitted] - poses[fitted]
        print(f"  {name}: {ms:.4f} ms per estimate (best of 5), mean iterations {mean_it:.2f}; RMS error "
              f"{np.sqrt(np.mean(np.sum(err[:, :3] ** 2, 1))):.4f} mm, {np.degrees(np.sqrt(np.mean(np.sum(err[:, 3:] ** 2, 1)))):.4f} deg")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
