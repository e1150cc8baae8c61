"""The run cost model (mlsim.cost_model) against measured runs: per stage the estimated and the
measured time, and the run's estimated and measured peak memory (the process's maximum resident
set), each scene in a fresh process from an empty cache (--shipped-meshes: the test suite's meshes
seeded, so meshing is loaded, not run). The acceptance of issue 39: within 2x on the default demo,
the screw scene and the tiny scene. Each stage's CPU seconds are printed beside its wall time: on a
machine that other jobs share, the wall time stretches with their load and the CPU time does not. Usage:

    .venv/bin/python benchmarks/bench_cost_model.py [--scene scenes/mavig_tiny.toml --outputs camera] ...

Prints a table per scene and the ratio estimate / measured; writes OUT/cost_model.json.

Measured 2026-11-27 11:15-11:43 (2 cores shared with other jobs, load 8-11), the model of fb6b88c,
estimate / measured over the whole run, time against CPU seconds (against wall seconds), and peak memory:
tiny to the camera 38.8 s: 1.06 (0.15), 1.49 GB against 1.43; default demo 171 s: 0.79 (0.29), 2.73 GB
against 2.59; screw scene 281 s: 0.95 (0.97), 3.06 GB against 2.36.

The sibling kinds (``--siblings``: their cheap scenes, each stage priced by its kind's ``cost`` hook), measured
2026-11-27 20:48-20:52 (2 shared cores, numba's kernels already compiled: a first run in a fresh checkout
spends seconds compiling them), estimate / measured time (CPU) and peak memory: sole/balance_push.toml 0.29 s
against 0.40 (0.72), 0.13 GB against 0.132; sole/balance_sweep.toml 2.9 s against 1.9 (1.53), 0.134 against
0.134 GB; cls/general.toml 4.48 s against 3.2 (1.40; calibrate 1.48, signals 1.13, estimate 1.22), 0.149 GB
against 0.183; anyskin/headon_push.toml to anyskin_signals 1.59 s against 1.15 CPU s (1.38), 0.367 GB
against 0.261.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_CASES = (("scenes/mavig_tiny.toml", "camera"), ("scenes/mavig_default.toml", ""), ("scenes/interactions/screw.toml", ""))
#: the sibling kinds' cheap scenes (--siblings): their kinds' cost hooks (other_sensors/<kind>/plausibility.py)
SIBLING_CASES = (("scenes/sole/balance_push.toml", ""), ("scenes/sole/balance_sweep.toml", ""), ("scenes/cls/general.toml", ""),
                 ("scenes/anyskin/headon_push.toml", "anyskin_signals"))


def child(scene_path: str, outputs: str, cache_dir: str) -> None:
    """Run one scene (in this fresh process) and print its per-stage seconds and peak memory as JSON."""
    from mlsim import pipeline, run_budget
    from mlsim.scene import load_scene

    scene = load_scene(scene_path)
    outs = tuple(o for o in outputs.split(",") if o) or None
    cache = pipeline.Cache(cache_dir)
    est = run_budget.estimate(scene, pipeline.plan(scene, cache, outs))
    cpu: dict[str, float] = {}

    def log(message: str) -> None:
        # a stage's CPU seconds (all its threads and children): on a machine that others share, its wall
        # time stretches with the load while its CPU time does not (a stage on both cores: CPU ~ 2 x wall)
        if message.startswith("[") and "]" in message:
            name = message[1:message.index("]")]
            ru, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
            now = ru.ru_utime + ru.ru_stime + ch.ru_utime + ch.ru_stime
            cpu[name] = now - cpu[name] if name in cpu else now

    t0 = time.perf_counter()
    res = pipeline.run(scene, out_dir=None, cache=cache, outputs=outs, progress=False, log=log)
    wall = time.perf_counter() - t0
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024.0
    cpu = {k: v for k, v in cpu.items() if k in res.seconds}
    print(json.dumps({"seconds": res.seconds, "cpu_s": cpu, "actions": {s.stage.name: s.action for s in res.steps}, "wall_s": wall, "peak_bytes": peak,
                      "estimate": {n: (None if c is None else {"seconds": c.seconds, "memory_bytes": c.memory_bytes}) for n, c in est.rows},
                      "estimate_seconds": est.seconds, "estimate_memory_bytes": est.memory_bytes}))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--scene", action="append", help="scene file (repeat; default: tiny (to the camera), default demo, screw)")
    parser.add_argument("--outputs", action="append", help="outputs per --scene, comma-separated ('' = the scene's)")
    parser.add_argument("--siblings", action="store_true", help="the sibling kinds' cheap scenes instead of the default cases")
    parser.add_argument("--shipped-meshes", action="store_true", help="seed the cache with tests/data/meshes (meshing not measured)")
    parser.add_argument("--out", default="out/bench")
    parser.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        return child(*args.child)
    cases = (list(zip(args.scene, args.outputs or [""] * len(args.scene))) if args.scene
             else list(SIBLING_CASES if args.siblings else DEFAULT_CASES))
    print(f"# {platform.node()}, {os.cpu_count()} CPUs, {time.strftime('%Y-%m-%d %H:%M')}; each scene in a fresh process, empty cache"
          + (" (shipped meshes seeded)" if args.shipped_meshes else ""))
    results = []
    for scene, outputs in cases:
        with tempfile.TemporaryDirectory(prefix="mlsim_cost_") as cache:
            if args.shipped_meshes:
                import runpy

                runpy.run_path(str(ROOT / "tests" / "data" / "ship_meshes.py"))["seed_cache"](Path(cache))
            proc = subprocess.run([sys.executable, __file__, "--child", scene, outputs, cache], capture_output=True, text=True, cwd=ROOT,
                                  env={**os.environ, "PYTHONPATH": str(ROOT)})
        if proc.returncode != 0:
            print(f"{scene}: failed\n{proc.stderr[-3000:]}")
            continue
        r = json.loads(proc.stdout.strip().splitlines()[-1])
        r.update(scene=scene, outputs=outputs)
        results.append(r)
        print(f"\n{scene} (outputs: {outputs or 'the scene'})")
        print(f"  {'stage':<12} {'action':>6} {'estimated s':>12} {'wall s':>9} {'CPU s':>9} {'est/wall':>9} {'est/CPU':>8}")
        for name, secs in r["seconds"].items():
            e = r["estimate"].get(name)
            est = "-" if e is None else f"{e['seconds']:.3g}"
            cpu = r["cpu_s"].get(name, float("nan"))
            ratios = ["-", "-"] if e is None or secs <= 0 else [f"{e['seconds'] / secs:.2f}", f"{e['seconds'] / cpu:.2f}"]
            print(f"  {name:<12} {r['actions'][name]:>6} {est:>12} {secs:>9.3g} {cpu:>9.3g} {ratios[0]:>9} {ratios[1]:>8}")
        cpu_all = sum(r["cpu_s"].values())
        print(f"  {'total':<12} {'':>6} {r['estimate_seconds']:>12.3g} {r['wall_s']:>9.3g} {cpu_all:>9.3g} "
              f"{r['estimate_seconds'] / r['wall_s']:>9.2f} {r['estimate_seconds'] / cpu_all:>8.2f}")
        print(f"  peak memory: estimated {r['estimate_memory_bytes'] / 1024**3:.3g} GB, measured {r['peak_bytes'] / 1024**3:.3g} GB "
              f"(max RSS), ratio {r['estimate_memory_bytes'] / r['peak_bytes']:.2f}")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "cost_model.json").write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
