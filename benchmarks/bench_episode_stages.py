"""A dataset's episodes stage by stage: each stage inside the dataset beside the same stage on its own.

    .venv/bin/python benchmarks/bench_episode_stages.py [--spec scenes/interactions/paper.toml] [--episodes 8]
        [--compare DIR] [--rounds 3] [--profile]

Runs episodes of the spec the way a dataset worker does (one thread for every numerical library,
numba's included; the sensor's precomputes from the cache, built first if missing and not timed)
through :func:`mlsim.dataset.generate.run_episode_job`, and then each stage's own ``run`` on the
same episode's inputs held in memory (no plan, no cache look-ups, no summary: how the stage
benchmarks run a stage). Prints per stage the median milliseconds per frame inside the dataset and
on its own, their ratio (issue 40's target: within 1.3), and the frames per second of one worker
end to end (``run_episode_job`` whole).

``--compare DIR``: the same episodes also run from another checkout (``git worktree`` or an
unpacked ``git archive`` of, say, main), the two in alternating subprocesses (A B A B ... over
``--rounds`` rounds, a round runs every episode once), so that both see the same load: on a
shared machine only interleaved figures compare. Prints both sides' medians per stage and end to end.

``--profile``: cProfile over the episodes (this checkout), the 40 costliest functions.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
STAGES = ("mesh", "calibration", "solve", "emission", "render", "camera", "dllm")


def _one_thread() -> None:
    """A dataset worker's thread limits (mlsim.dataset.executors), before numpy and numba load."""
    for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS", "VECLIB_MAXIMUM_THREADS",
                 "NUMBA_NUM_THREADS"):
        os.environ[name] = "1"


def _jobs(spec_path: str, n: int) -> list[dict]:
    from mlsim import pipeline
    from mlsim.dataset import generate as gen
    from mlsim.dataset.spec import load_dataset_spec

    spec, base = load_dataset_spec(spec_path, {"samples_per_action": max(1, -(-n // 8)), "people": 1})
    jobs, _ = gen.plan_episodes(spec)
    common = {"base_scene": base.model_dump(mode="json"), "interaction": spec.interaction.model_dump(mode="json"),
              "cache_dir": str(pipeline.default_cache_dir()), "store_frames": False}
    # the actions in turn (the plan lists them action by action)
    per_action = len(jobs) // len(spec.actions)
    order = [jobs[a * per_action + k] for k in range(per_action) for a in range(len(spec.actions))]
    return [j | common for j in order[:n]]


def measure(spec_path: str, n: int, alone: bool = True, profile: bool = False) -> dict:
    """{"episodes": [per episode: frames, seconds, stage seconds in the dataset and alone]}; the first
    episode of the process (the memos, numba's cache loads) runs before and is not counted."""
    import numpy as np  # noqa: F401  (after the thread limits)
    import torch

    from mlsim import pipeline
    from mlsim.dataset import generate as gen

    torch.set_num_threads(1)
    jobs = _jobs(spec_path, n)
    warm = jobs[-1] | {"noise_seed": jobs[-1]["noise_seed"] + 1}
    gen.run_episode_job(warm)  # precomputes (built and cached if missing), memos, JIT caches
    out = []
    prof = None
    if profile:
        import cProfile

        prof = cProfile.Profile()
    for job in jobs:
        if prof is not None:
            prof.enable()
        r = gen.run_episode_job(job)
        if prof is not None:
            prof.disable()
        row = {"episode": job["episode_id"], "frames": r["attrs"]["n_frames"], "seconds": r["attrs"]["seconds"],
               "dataset": r["attrs"]["stage_seconds"], "alone": {}}
        if alone:
            scene = gen.episode_scene(job)
            cache = pipeline.Cache(job["cache_dir"], keep=gen.CACHE_KEEP, in_memory=gen.CACHE_KEEP)
            res = pipeline.run(scene, cache=cache, outputs=("dllm",), progress=False, log=lambda _m: None)
            ctx = pipeline.RunContext(scene, cache, None, False, lambda _m: None)
            for step in res.steps:
                st = step.stage
                if st.name not in ("solve", "emission", "render", "camera", "dllm"):
                    continue
                t0 = time.perf_counter()
                st.run(scene, {k: res.results[k] for k in st.needs}, ctx)
                row["alone"][st.name] = time.perf_counter() - t0
        out.append(row)
    if prof is not None:
        import pstats

        pstats.Stats(prof, stream=sys.stderr).sort_stats("tottime").print_stats(40)
    return {"episodes": out}


def _per_frame_ms(rows: list[dict], part: str, stage: str) -> float | None:
    import numpy as np

    values = [1e3 * r[part][stage] / r["frames"] for r in rows if stage in r[part]]
    return float(np.median(values)) if values else None


def _fps(rows: list[dict]) -> float:
    return sum(r["frames"] for r in rows) / sum(r["seconds"] for r in rows)


def _fmt(v: float | None) -> str:
    return "-" if v is None else f"{v:.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--spec", default=str(ROOT / "scenes" / "interactions" / "paper.toml"))
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--compare", help="another checkout to run the same episodes from, alternating with this one")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--json-only", action="store_true", help=argparse.SUPPRESS)  # a subprocess of --compare
    ap.add_argument("--no-alone", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    _one_thread()
    machine = f"{platform.machine()}, {os.cpu_count()} CPUs, Python {platform.python_version()}; load average {os.getloadavg()[0]:.1f}"
    if args.json_only:
        print(json.dumps(measure(args.spec, args.episodes, alone=not args.no_alone)))
        return 0
    if not args.compare:
        rows = measure(args.spec, args.episodes, profile=args.profile)["episodes"]
        print(f"{machine}\n{len(rows)} episodes of {Path(args.spec).name}, {sum(r['frames'] for r in rows)} frames, one worker, one thread")
        print(f"{'stage':12s} {'dataset ms/frame':>17s} {'alone ms/frame':>15s} {'ratio':>6s}")
        for s in STAGES:
            d, a = _per_frame_ms(rows, "dataset", s), _per_frame_ms(rows, "alone", s)
            print(f"{s:12s} {_fmt(d):>17s} {_fmt(a):>15s} {_fmt(d / a if d and a else None):>6s}")
        print(f"end to end: {_fps(rows):.1f} frames/s per worker (median episode {sorted(r['seconds'] for r in rows)[len(rows) // 2]:.3f} s)")
        return 0
    sides = {"this": str(ROOT), "other": str(Path(args.compare).resolve())}
    rows: dict = {k: [] for k in sides}
    for rnd in range(args.rounds):
        for name in (("this", "other") if rnd % 2 == 0 else ("other", "this")):
            env = dict(os.environ, PYTHONPATH=sides[name])
            cmd = [sys.executable, str(Path(__file__).resolve()), "--json-only", "--no-alone", "--spec", args.spec, "--episodes", str(args.episodes)]
            done = subprocess.run(cmd, env=env, cwd=sides[name], capture_output=True, text=True, check=True)
            rows[name] += json.loads(done.stdout.strip().splitlines()[-1])["episodes"]
            print(f"round {rnd + 1} {name}: {_fps(rows[name][-args.episodes:]):.1f} frames/s", flush=True)
    print(f"{machine}\n{args.rounds} rounds x {args.episodes} episodes of {Path(args.spec).name}, alternating; "
          f"this = {sides['this']}, other = {sides['other']}")
    print(f"{'stage':12s} {'this ms/frame':>14s} {'other ms/frame':>15s}")
    for s in STAGES:
        print(f"{s:12s} {_fmt(_per_frame_ms(rows['this'], 'dataset', s)):>14s} {_fmt(_per_frame_ms(rows['other'], 'dataset', s)):>15s}")
    print(f"end to end, frames/s per worker: this {_fps(rows['this']):.1f}, other {_fps(rows['other']):.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
