"""An interaction dataset on this machine: end-to-end frames/s, where each frame's time goes, training.

    .venv/bin/python benchmarks/bench_dataset.py [--spec scenes/interactions/paper.toml] [--workers 2]
        [--executor local|ray] [--out out/bench_dataset] [--keep] [--set samples_per_action=4]
        [--chain per_episode|batched] [--device auto|cpu|cuda] [--no-train] [--alone N]

Generates the spec's dataset from scratch (8 actions x 100 samples by 10 people for the paper
spec; ``--set samples_per_action=4 --set people=2`` for a few minutes' run) with the sensor's
precomputes taken from the cache (their one-off cost is printed apart), then trains and evaluates
the 8- and 4-class CNNs on a held-out split of people (``--no-train``: not).

Prints the per-stage table (ms per frame, medians over the episodes): each stage inside the
dataset (the store's ``stage_seconds`` of every episode: its workers share the cores with each
other and the driver) beside the same stage in one worker on its own (``--alone N``: N episodes
through :mod:`bench_episode_stages` in a subprocess, one thread: ``run_episode_job`` whole and
each stage's own ``run`` on its inputs), and what the dataset adds around the workers' stages
(plan, pickling, the store's writes, the driver). The acceptance targets: ISSUE 6, generation of
the paper's dataset under 15 min on 2 cores, training under 2 min on CPU; ISSUE 78, 300 frames/s
end to end on 2 cores. Writes ``bench_dataset.json`` in the output directory.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

#: The stages after the sensor's precomputes, in the order an episode runs them.
EPISODE_STAGES = ("solve", "emission", "render", "camera", "dllm")


def stage_table(episode_attrs: list[dict]) -> dict:
    """Per stage, the median over episodes of its ms per frame (``stage_seconds`` / ``n_frames``),
    and of the worker's whole episode (``seconds``: the pipeline's run, plan and cache look-ups included)."""
    import numpy as np

    def median_ms(values):
        return round(float(np.median(values)), 3) if values else None

    rows = {s: median_ms([1e3 * a["stage_seconds"][s] / a["n_frames"] for a in episode_attrs if s in a.get("stage_seconds", {})])
            for s in EPISODE_STAGES}
    rows["worker episode"] = median_ms([1e3 * a["seconds"] / a["n_frames"] for a in episode_attrs])
    return rows


def _cpu_s() -> dict:
    """CPU seconds (user + system) of this process and of its children that have ended (a local pool's workers, once shut down)."""
    import resource

    own, children = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return {"driver": own.ru_utime + own.ru_stime, "workers": children.ru_utime + children.ru_stime}


def _alone(spec: str, episodes: int) -> dict:
    """bench_episode_stages's figures for ``episodes`` episodes (one worker, one thread, in a subprocess)."""
    cmd = [sys.executable, str(ROOT / "benchmarks" / "bench_episode_stages.py"), "--json-only", "--spec", spec, "--episodes", str(episodes)]
    done = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=True, env=dict(os.environ, PYTHONPATH=str(ROOT)))
    return json.loads(done.stdout.strip().splitlines()[-1])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "scenes" / "interactions" / "paper.toml"))
    ap.add_argument("--workers", type=int, default=os.cpu_count() or 1)
    ap.add_argument("--executor", default="local", choices=["local", "ray"])
    ap.add_argument("--out", default=str(ROOT / "out" / "bench_dataset"))
    ap.add_argument("--keep", action="store_true", help="keep an existing dataset in --out (resume) instead of starting afresh")
    ap.add_argument("--set", action="append", default=[], metavar="FIELD=INT", help="a spec's integer field for this run (samples_per_action, people)")
    ap.add_argument("--chain", choices=["per_episode", "batched"], help="the spec's chain for this run")
    ap.add_argument("--device", choices=["auto", "cpu", "cuda"], help="the spec's device for this run (the batched chain's)")
    ap.add_argument("--no-train", action="store_true", help="generation only")
    ap.add_argument("--alone", type=int, default=0, metavar="N", help="also N episodes in one worker on its own, stage by stage")
    args = ap.parse_args(argv)

    from mlsim.dataset import store
    from mlsim.dataset.generate import generate
    from mlsim.dataset.spec import load_dataset_spec

    overrides = {k: int(v) for k, v in (s.split("=", 1) for s in args.set)}
    overrides |= {k: getattr(args, k) for k in ("chain", "device") if getattr(args, k)}
    spec, base = load_dataset_spec(args.spec, overrides)
    out = Path(args.out)
    if out.exists() and not args.keep:
        shutil.rmtree(out)
    t0 = time.perf_counter()
    cpu0 = _cpu_s()
    summary = generate(spec, base, out, workers=args.workers, executor=args.executor, progress=True, log=print)
    cpu = {k: v - cpu0[k] for k, v in _cpu_s().items()}
    total = time.perf_counter() - t0
    attrs = [store.read_episode(out, e, ()) for e in sorted(store.complete_episodes(out))]
    frames = sum(a["n_frames"] for a in attrs)
    inside = stage_table(attrs)
    # the dataset's wall time per frame, times its workers: what each frame cost a worker's core
    # slot, the driver's share and the pool's idle ends included
    per_frame_slot_ms = 1e3 * summary["episodes_wall_s"] * args.workers / frames if frames else None
    report = {
        "machine": f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}, load average {os.getloadavg()[0]:.1f}",
        "spec": Path(args.spec).name, "overrides": overrides,
        "episodes": summary["episodes_stored"], "frames": frames, "workers": args.workers, "executor": args.executor,
        "precompute_s": summary["precompute_s"], "episodes_wall_s": summary["episodes_wall_s"], "total_wall_s": round(total, 1),
        "episodes_per_s": summary["episodes_per_s"], "frames_per_s": summary["frames_per_s"],
        "worker_s_per_episode_median": summary["worker_s_per_episode_median"],
        "ms_per_frame_in_dataset": inside, "worker_slot_ms_per_frame": round(per_frame_slot_ms, 3) if per_frame_slot_ms else None,
        # CPU seconds of the driver and of its (reaped) local workers over the whole run, the driver's precompute episode included
        "cpu_s": {k: round(v, 2) for k, v in cpu.items()},
        "cpu_ms_per_frame": round(1e3 * (cpu["driver"] + cpu["workers"]) / frames, 3) if frames else None,
    }
    alone = None
    if args.alone:
        from bench_episode_stages import _per_frame_ms

        rows = _alone(args.spec, args.alone)["episodes"]
        alone = {s: (_per_frame_ms(rows, "dataset", s), _per_frame_ms(rows, "alone", s)) for s in EPISODE_STAGES}
        alone["worker episode"] = (stage_table([{"n_frames": r["frames"], "seconds": r["seconds"]} for r in rows])["worker episode"], None)
        report["ms_per_frame_one_worker"] = {s: {"run_episode_job": a, "stage_alone": b} for s, (a, b) in alone.items()}
    if not args.no_train:
        from classifiers.train import heldout_experiment
        from mlsim.dataset.reader import load_episodes

        episodes = load_episodes(out)
        train = {}
        for n in (8, 4):
            exp = heldout_experiment(episodes, n_classes=n, seed=0)
            train[n] = {"train_s": round(exp.result.train_seconds, 2), "accuracy_heldout_people": round(exp.metrics.accuracy, 4),
                        "test_people": [int(p) for p in exp.test_people]}
        report["train"] = train
    print(json.dumps(report, indent=2))
    (out / "bench_dataset.json").write_text(json.dumps(report, indent=2))

    def fmt(v):
        return "-" if v is None else f"{v:.2f}"

    print(f"\n{report['machine']}\n{len(attrs)} episodes of {report['spec']} {overrides or ''}, {frames} frames, {args.workers} {args.executor} "
          f"worker(s); ms per frame, medians over episodes")
    head = f"{'stage':16s} {'in the dataset':>15s}"
    if alone:
        head += f" {'one worker':>11s} {'stage alone':>12s}"
    print(head)
    for s in EPISODE_STAGES + ("worker episode",):
        line = f"{s:16s} {fmt(inside[s]):>15s}"
        if alone:
            line += f" {fmt(alone[s][0]):>11s} {fmt(alone[s][1]):>12s}"
        print(line)
    print(f"{'dataset wall x workers':16s} {fmt(report['worker_slot_ms_per_frame']):>15s}   (all a worker's core does per frame, the driver's share included)")
    if args.executor == "local" and report["cpu_ms_per_frame"]:
        # on a shared machine the wall clock measures the other load too; the CPU seconds are what this run cost
        print(f"CPU per frame, driver and workers: {report['cpu_ms_per_frame']:.2f} ms (driver {cpu['driver']:.1f} s, workers {cpu['workers']:.1f} s): "
              f"{args.workers} free cores at that cost make at most {1e3 * args.workers / report['cpu_ms_per_frame']:.0f} frames/s")
    print(f"generation: {summary['episodes_run_now']} episodes, {frames} frames in {summary['episodes_wall_s']:.1f} s: {summary['frames_per_s']} frames/s "
          f"({summary['episodes_per_s']} episodes/s; precompute {summary['precompute_s']} s; targets: paper spec < 900 s, 300 frames/s)")
    for n, t in report.get("train", {}).items():
        print(f"training {n} classes: {t['train_s']} s (target < 120 s); held-out people {t['test_people']}: "
              f"accuracy {t['accuracy_heldout_people']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
