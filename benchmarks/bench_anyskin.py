"""How much faster than real time the AnySkin helmet's estimator runs (SPEC 2: 20 channels x 3 axes at 150 Hz).

The whole estimator of :class:`other_sensors.anyskin.estimate.Estimator` with the shipped trained
files (``scenes/anyskin/headon_push.toml``): the stream's checks, the initial baseline, the median
and low-pass filters, the 50-sample slope windows, the causal CNN (batched over a chunk's time
windows: each window holds only past slopes, so batching keeps causality; a channel that commits a
new offset mid-chunk has the rest of its chunk redone), the contact state machine, dynamic
re-baselining and the LSTM-MLP force map, on a simulated recording of the scene (drift on, so that
it re-baselines). Prints the median wall time over repeats, per recording and per sample, and the
real-time factor (the recording's duration over the median time), with and without
re-baselining. Torch, BLAS and OpenMP run on one thread, and the process is pinned to one core
where the OS allows it (SPEC 2's rate on one core). The first run (oneDNN's set-up) is not timed.
Not a test. Usage:

    .venv/bin/python benchmarks/bench_anyskin.py [--seconds 60] [--repeats 7]
"""

from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"  # before NumPy and torch load: one core

import argparse
import platform
import statistics
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import torch  # noqa: E402

from mlsim.scene import load_scene  # noqa: E402
from other_sensors.anyskin.estimate import make_estimator  # noqa: E402
from other_sensors.anyskin.signals import simulate_helmet  # noqa: E402


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="recording length (s)")
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "anyskin" / "headon_push.toml"))
    args = ap.parse_args(argv)
    if hasattr(os, "sched_setaffinity"):
        os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
    torch.set_num_threads(1)
    sensor = load_scene(args.scene).sensor
    sensor = sensor.model_copy(update={"trajectory": sensor.trajectory.model_copy(update={"duration_s": args.seconds})})
    sig = simulate_helmet(sensor, 0)
    readings = sig.readings.reshape(len(sig.t), -1, 3)
    est = make_estimator(sensor)
    n, duration = len(sig.t), len(sig.t) / sensor.magnetometers.rate_hz
    print(f"AnySkin estimator ({est.name}): {readings.shape[1]} channels x 3 axes, {n} samples = {duration:g} s at "
          f"{sensor.magnetometers.rate_hz:g} Hz; {platform.processor() or platform.machine()}, torch {torch.__version__}, 1 thread")
    for rebaseline in (True, False):
        est.run(readings, sig.t, rebaseline=rebaseline)  # warm-up
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            out = est.run(readings, sig.t, rebaseline=rebaseline)
            times.append(time.perf_counter() - t0)
        med = statistics.median(times)
        label = "with re-baselining" if rebaseline else "static baseline   "
        print(f"{label}: median {1e3 * med:8.1f} ms per recording ({1e6 * med / n:6.1f} us per sample), "
              f"{duration / med:7.1f} x real time; {int(out.track.rebaselines.sum())} re-baselines; "
              f"min {1e3 * min(times):.1f} ms, max {1e3 * max(times):.1f} ms over {args.repeats}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
