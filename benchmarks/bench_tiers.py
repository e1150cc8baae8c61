"""Per-frame cost of the solve tiers on the default 5 x 5 sensor with the demo load.

For each tier (``linear``, ``reduced``, ``nonlinear``): the one-off costs (assembly,
factorisation, and the tier's precompute: the point compliance for ``linear``, the unit-patch
responses for ``reduced``), then the median over --repeats episodes of the per-frame cost
(contact steps plus field recovery, divided by the frames) with the contact (for ``nonlinear``:
Newton) iterations per step, and each tier's difference from ``linear`` (peak per-rod ML-layer
von Mises, per-rod normal force). The machine and the medians go to stdout and to
``OUT/tiers.json``. The nonlinear tier takes minutes per episode (--nonlinear-repeats). Usage:

    .venv/bin/python benchmarks/bench_tiers.py [--repeats 3] [--tiers linear reduced nonlinear] [--out out/bench]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from fem import quasistatic as qs
from mlsim import pipeline
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def _episode_costs(scene, mesh, repeats, **kw):
    runs, ep = [], None
    for _ in range(repeats):
        ep = qs.run_episode(scene, mesh, **kw)
        runs.append(ep.seconds)
    per_frame = [1e3 * (r["contact_steps"] + r["fields"]) / ep.n_frames for r in runs]
    contact = [1e3 * r["contact_steps"] / ep.n_frames for r in runs]
    fields = [1e3 * r["fields"] / ep.n_frames for r in runs]
    return ep, {
        "per_frame_ms_median": statistics.median(per_frame),
        "per_frame_ms_runs": per_frame,
        "contact_ms_per_frame_median": statistics.median(contact),
        "fields_ms_per_frame_median": statistics.median(fields),
        "frames_per_s": 1e3 / statistics.median(per_frame),
        "n_frames": ep.n_frames,
        "contact_iterations_total": int(ep.iterations.sum()),
        "contact_iterations_per_step": ep.iterations.tolist(),
    }


def _rel(a, b):
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--tiers", nargs="+", default=["linear", "reduced", "nonlinear"], choices=["linear", "reduced", "nonlinear"])
    ap.add_argument("--nonlinear-repeats", type=int, default=1, help="the nonlinear tier takes minutes per episode")
    args = ap.parse_args()
    scene = load_scene(ROOT / "scenes" / "mavig_default.toml")
    mesh = pipeline.run(scene, out_dir=None, outputs=("mesh",), progress=False, log=lambda m: None).results["mesh"][0]
    settings = qs.SolveSettings.from_scene(scene)
    lame, rho, _ = qs.layer_materials(scene)
    body = qs.LinearBody(mesh, lame, rho, settings.element, settings.gravity)
    result = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()},
        "mesh": {"n_tets": mesh.n_tets, "n_points": mesh.n_points, "n_dofs": body.n_dofs, "element": body.element},
        "body_s": body.seconds,
    }
    lin_ep, result["linear"] = _episode_costs(scene, mesh, args.repeats, body=body, settings=settings)
    result["linear"]["precompute_s"] = lin_ep.seconds["precompute"]
    episodes = {"linear": lin_ep}
    if "reduced" in args.tiers:
        t0 = time.perf_counter()
        reduced = qs.build_reduced(scene, mesh, body)
        red_settings = qs.SolveSettings.from_scene(scene.with_values({"fidelity.solve.tier": "reduced"}))
        result["reduced"] = {"precompute_s": time.perf_counter() - t0, "n_patches": int(len(reduced.X))}
        episodes["reduced"], costs = _episode_costs(scene, mesh, args.repeats, reduced=reduced, settings=red_settings)
        result["reduced"].update(costs)
    if "nonlinear" in args.tiers:
        nl_scene = scene.with_values({"fidelity.solve.tier": "nonlinear"})
        episodes["nonlinear"], costs = _episode_costs(nl_scene, mesh, args.nonlinear_repeats, settings=qs.SolveSettings.from_scene(nl_scene))
        result["nonlinear"] = {"precompute_s": episodes["nonlinear"].seconds["precompute"], **costs}
    for tier, ep in episodes.items():
        if tier == "linear":
            continue
        lp, tp = lin_ep.rod_peaks(), ep.rod_peaks()
        result[tier]["difference_from_linear"] = {
            "rod_ml_von_mises_peak_rel": _rel(tp["ml_von_mises_kpa"], lp["ml_von_mises_kpa"]),
            "rod_normal_force_peak_rel": _rel(tp["normal_force_n"], lp["normal_force_n"]),
            "normal_force_series_rel": _rel(ep.normal_force_n, lin_ep.normal_force_n),
        }
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "tiers.json").write_text(json.dumps(result, indent=2, default=lambda o: o.item() if hasattr(o, "item") else str(o)))
    print(f"machine: {result['machine']}")
    print(f"mesh: {result['mesh']}; assembly {body.seconds['assemble']:.2f} s, factorisation {body.seconds['factorise']:.2f} s")
    print("| tier | precompute (s) | per frame (ms, median) | contact / fields (ms) | frames/s | contact iterations |")
    print("|---|---|---|---|---|---|")
    for tier in episodes:
        r = result[tier]
        print(f"| {tier} | {r['precompute_s']:.2f} | {r['per_frame_ms_median']:.1f} | {r['contact_ms_per_frame_median']:.1f} / "
              f"{r['fields_ms_per_frame_median']:.1f} | {r['frames_per_s']:.1f} | {r['contact_iterations_total']} |")
        if "difference_from_linear" in r:
            print(f"  {tier} vs linear: {r['difference_from_linear']}")
    if "nonlinear" in result:
        print("nonlinear Newton iterations per step:", result["nonlinear"]["contact_iterations_per_step"])


if __name__ == "__main__":
    main()
