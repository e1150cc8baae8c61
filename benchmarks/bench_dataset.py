"""The paper-sized interaction dataset on this machine: wall time and episodes/s, then training time.

    .venv/bin/python benchmarks/bench_dataset.py [--spec scenes/interactions/paper.toml] [--workers 2]
        [--executor local|ray] [--out out/bench_dataset] [--keep]

Generates the spec's dataset from scratch (8 actions x 100 samples by 10 people for the paper
spec) with the sensor's precomputes taken from the cache (their one-off cost is printed apart), then
trains and evaluates the 8- and 4-class CNNs on a held-out split of people. Prints the medians
and totals; the acceptance targets (ISSUE 6): generation under 15 min on 2 cores, training under
2 min on CPU. Writes ``bench_dataset.json`` in the output directory.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "scenes" / "interactions" / "paper.toml"))
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--executor", default="local", choices=["local", "ray"])
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_dataset"))
    ap.add_argument("--keep", action="store_true", help="keep an existing dataset in --out (resume) instead of starting afresh")
    args = ap.parse_args(argv)

    from classifiers.train import heldout_experiment
    from mlsim.dataset.generate import generate
    from mlsim.dataset.reader import load_episodes
    from mlsim.dataset.spec import load_dataset_spec

    spec, base = load_dataset_spec(args.spec)
    out = Path(args.out)
    if out.exists() and not args.keep:
        shutil.rmtree(out)
    t0 = time.perf_counter()
    summary = generate(spec, base, out, workers=args.workers, executor=args.executor, progress=True, log=print)
    total = time.perf_counter() - t0
    episodes = load_episodes(out)
    train = {}
    for n in (8, 4):
        exp = heldout_experiment(episodes, n_classes=n, seed=0)
        train[n] = {"train_s": round(exp.result.train_seconds, 2), "accuracy_heldout_people": round(exp.metrics.accuracy, 4),
                    "test_people": [int(p) for p in exp.test_people]}
    report = {
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}",
        "episodes": summary["episodes_stored"], "workers": args.workers, "executor": args.executor,
        "precompute_s": summary["precompute_s"], "episodes_wall_s": summary["episodes_wall_s"], "total_wall_s": round(total, 1),
        "episodes_per_s": summary["episodes_per_s"], "worker_s_per_episode_median": summary["worker_s_per_episode_median"],
        "train": train,
    }
    print(json.dumps(report, indent=2))
    (out / "bench_dataset.json").write_text(json.dumps(report, indent=2))
    print(f"generation: {summary['episodes_run_now']} episodes in {summary['episodes_wall_s']:.0f} s "
          f"({summary['episodes_per_s']} episodes/s; precompute {summary['precompute_s']} s; target < 900 s)")
    for n in (8, 4):
        print(f"training {n} classes: {train[n]['train_s']} s (target < 120 s); held-out people {train[n]['test_people']}: "
              f"accuracy {train[n]['accuracy_heldout_people']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
