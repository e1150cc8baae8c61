"""A dataset worker's start-up: what its first episode costs beyond the ones after it.

    .venv/bin/python benchmarks/bench_worker_startup.py [--spec scenes/interactions/paper.toml] [--runs 3] [--profile]

Each run is a fresh process set up as a spawned dataset worker is (one thread for every numerical
library), which plans the spec's episodes, then runs two of them through
:func:`mlsim.dataset.generate.run_episode_job` with the sensor's precomputes from the cache (built
first, and not timed, where missing). Prints per run the CPU seconds (``time.process_time``) of the
imports and plan, of the first episode and of the second, and which heavy modules the worker imported
(Mitsuba should not be: the deformed tier reads its cached parts). The medians over the runs last.
``--profile``: cProfile of one run's first episode, the 40 costliest functions by cumulative time.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HEAVY = ("mitsuba", "drjit", "torch", "colour", "pandas", "scipy.integrate", "cv2")

_CHILD = """
import json, sys, time
sys.path[:0] = [sys.argv[1], sys.argv[1] + "/benchmarks"]
c0 = time.process_time()
from bench_episode_stages import _jobs, _one_thread
_one_thread()  # a worker's thread limits, before numpy loads
from mlsim.dataset import generate as gen
jobs = _jobs(sys.argv[2], 2)
c1 = time.process_time()
prof = None
if sys.argv[3] == "1":
    import cProfile
    prof = cProfile.Profile()
    prof.enable()
first = gen.run_episode_job(jobs[0])
c2 = time.process_time()
if prof is not None:
    prof.disable()
second = gen.run_episode_job(jobs[1])
c3 = time.process_time()
if prof is not None:
    import pstats
    pstats.Stats(prof, stream=sys.stderr).sort_stats("cumulative").print_stats(40)
print(json.dumps({"imports_and_plan_s": c1 - c0, "first_s": c2 - c1, "second_s": c3 - c2, "frames": [first["attrs"]["n_frames"], second["attrs"]["n_frames"]],
                  "heavy": [m for m in json.loads(sys.argv[4]) if m in sys.modules]}))
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--spec", default=str(ROOT / "scenes" / "interactions" / "paper.toml"))
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--profile", action="store_true")
    args = ap.parse_args()
    import numpy as np

    rows = []
    for run in range(args.runs + 1):  # run 0 builds what the cache lacks (and loads numba's caches into the OS's): not counted
        profile = args.profile and run == 1
        done = subprocess.run([sys.executable, "-c", _CHILD, str(ROOT), args.spec, "1" if profile else "0", json.dumps(HEAVY)],
                              capture_output=True, text=True, env=os.environ.copy())
        if done.returncode != 0:
            sys.exit(done.stderr)
        if profile:
            print(done.stderr)
        row = json.loads(done.stdout.strip().splitlines()[-1])
        if run:
            rows.append(row)
            print(f"run {run}: imports and plan {row['imports_and_plan_s']:.2f} s, first episode {row['first_s']:.2f} s, second "
                  f"{row['second_s']:.2f} s CPU ({row['frames'][0]}, {row['frames'][1]} frames); heavy modules: {', '.join(row['heavy']) or 'none'}")
    med = {k: float(np.median([r[k] for r in rows])) for k in ("imports_and_plan_s", "first_s", "second_s")}
    import platform

    print(f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}")
    print(f"median of {len(rows)}: imports and plan {med['imports_and_plan_s']:.2f} s, first episode {med['first_s']:.2f} s, second "
          f"{med['second_s']:.2f} s: start-up about {med['imports_and_plan_s'] + med['first_s'] - med['second_s']:.2f} s of CPU per worker")


if __name__ == "__main__":
    main()
