"""The 5-point rod height sweep of the default sensor (issue 18's budget: under 15 minutes on 2 cores
at the fast tiers), from an empty cache: every variant meshes, factorises, traces its transport matrix
and renders its calibration frame, then runs the press, the swipe and a 3-angle direction study.

    .venv/bin/python benchmarks/bench_sweep.py [--vary sensor.rod.height_mm=6,7.5,9,10.5,12] [--out DIR] [--cache DIR]

Prints the wall time of the sweep, each variant's and what its parts cost (the stages' seconds summed
over the loads), and the machine. The report lands in --out (default a temporary folder).
"""

from __future__ import annotations

import argparse
import os
import platform
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def main() -> None:
    from mlsim.scene import load_scene
    from mlsim.sweep.run import stored_records, sweep
    from mlsim.sweep.variants import parse_vary

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--vary", action="append", default=None)
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "mavig_default.toml"))
    ap.add_argument("--out")
    ap.add_argument("--cache", help="default: an empty temporary cache (the cost of a first sweep)")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args()
    varies = parse_vary(args.vary or ["sensor.rod.height_mm=6,7.5,9,10.5,12"])
    tmp = tempfile.mkdtemp(prefix="bench_sweep_")
    out = Path(args.out or Path(tmp) / "out")
    cache = args.cache or str(Path(tmp) / "cache")
    print(f"# {platform.processor() or platform.machine()}, {os.cpu_count()} cores, {args.workers} worker(s), python {platform.python_version()}; cache {cache}")
    t0 = time.perf_counter()
    summary = sweep(load_scene(args.scene), varies, out, cache_dir=cache, workers=args.workers, progress=True,
                    log=lambda m: print(m, file=sys.stderr))
    wall = time.perf_counter() - t0
    for rec in stored_records(out).values():
        parts = {}
        for name, r in rec.get("loads", {}).items():
            parts[name] = sum(r.get("seconds", {}).values()) if r.get("ok") else float("nan")
        for name in ("separation", "direction"):
            r = rec.get(name, {})
            parts[name] = sum(r.get("seconds", {}).values()) if r.get("ok") else float("nan")
        print(f"{rec['label']:>24}: {rec['seconds']:7.1f} s  " + "  ".join(f"{k} {v:.1f}" for k, v in parts.items()))
    print(f"sweep of {summary['variants']} variants: {wall / 60:.2f} min wall ({wall / max(summary['run_now'], 1):.1f} s per variant); "
          f"report in {out}")


if __name__ == "__main__":
    main()
