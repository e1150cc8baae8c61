"""Per-frame cost of the solve tiers on the default 5 x 5 sensor with the demo load.

For each tier (``linear``, ``reduced``, ``nonlinear``) and, for the first two, each contact solver
(--contact-solvers: ``admm``, ``newton``): the one-off costs (assembly, factorisation, and the
tier's precompute: the point compliance for ``linear``, the unit-patch responses for ``reduced``),
then the median over --repeats episodes of the per-frame cost (contact steps plus field recovery,
divided by the frames); per kind of frame (moving contact, hold, free) the median of each step's
contact time plus its share of the field recovery; the contact (for ``nonlinear``: Newton)
iterations per step and their largest; and each tier's difference from the first linear run
(peak per-rod ML-layer von Mises, per-rod normal force); for ``nonlinear`` each step's seconds, their
median and worst, and how many steps needed a retry (the penalty Newton, following the iterates). The
machine and the medians go to stdout and to ``OUT/tiers.json``. The nonlinear tier takes minutes per
episode (--nonlinear-repeats). Usage:

    .venv/bin/python benchmarks/bench_tiers.py [--repeats 3] [--tiers linear reduced nonlinear]
        [--contact-solvers admm newton] [--scene SCENE] [--set PATH=VALUE ...] [--out out/bench]

The default demo's scene runs the Cosserat rods' held rounds (issue 38; ``--tiers linear reduced
--contact-solvers admm`` for them); the small-rotation tiers as they were before that (first order):
``--set 'fidelity.solve.rod_kinematics="first_order"'``.
"""

from __future__ import annotations

import argparse
import dataclasses
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


def frame_kinds(ep) -> dict[str, np.ndarray]:
    """Step indices by kind: ``moving`` (in contact, the indenter moved), ``hold`` (in contact, it did
    not), ``free`` (no contact)."""
    contact = ep.normal_force_n > 0
    moved = np.r_[True, np.any(np.diff(ep.pose, axis=0) != 0, axis=1)]
    return {"moving": np.flatnonzero(contact & moved), "hold": np.flatnonzero(contact & ~moved), "free": np.flatnonzero(~contact)}


def _episode_costs(scene, mesh, repeats, **kw):
    runs, ep = [], None
    for _ in range(repeats):
        ep = qs.run_episode(scene, mesh, **kw)
        runs.append(ep.seconds)
    per_frame = [1e3 * (r["contact_steps"] + r["fields"]) / ep.n_frames for r in runs]
    contact = [1e3 * r["contact_steps"] / ep.n_frames for r in runs]
    fields = [1e3 * r["fields"] / ep.n_frames for r in runs]
    by_kind = {}
    if "contact_step_ms" in runs[0]:
        # each step's own contact time plus its share of the (batched) field recovery (a step whose loads
        # repeat the last step's, a hold, copies its fields: no share); median over the steps of a kind
        # in each run, then over the runs
        def fields_ms(r):
            return np.asarray(r.get("fields_step_ms", np.full(ep.n_frames, 1e3 * r["fields"] / ep.n_frames)))

        for kind, idx in frame_kinds(ep).items():
            if len(idx):
                per_run = [statistics.median((np.asarray(r["contact_step_ms"]) + fields_ms(r))[idx]) for r in runs]
                by_kind[kind] = {"steps": int(len(idx)), "ms_median": statistics.median(per_run), "frames_per_s": 1e3 / statistics.median(per_run),
                                 "iterations_max": int(ep.iterations[idx].max())}
    return ep, {
        "per_step_kind": by_kind,
        "contact_iterations_max_per_step": int(ep.iterations.max()),
        "contact_worst_residual_n": ep.seconds.get("contact_worst_residual_n"),
        "per_frame_ms_median": statistics.median(per_frame),
        "per_frame_ms_runs": per_frame,
        # the first episode makes the reduced tier's contact operator pieces (its rods' inverses per rho,
        # sub-operators) that the sensor's later episodes share (ReducedModel.contact_operator)
        "per_frame_ms_first": per_frame[0],
        "contact_ms_per_frame_median": statistics.median(contact),
        "fields_ms_per_frame_median": statistics.median(fields),
        "frames_per_s": 1e3 / statistics.median(per_frame),
        "n_frames": ep.n_frames,
        "contact_iterations_total": int(ep.iterations.sum()),
        "contact_iterations_per_step": ep.iterations.tolist(),
        # each step's own wall time (first run): the nonlinear tier's cost is in its worst steps
        "step_ms": [float(v) for v in runs[0].get("contact_step_ms", [])],
        "step_counts": {k: runs[0][k] for k in ("penalty_newton_steps", "followed_iterates_steps", "stalled_steps_accepted") if k in runs[0]},
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
    ap.add_argument("--contact-solvers", nargs="+", default=["newton", "admm"], choices=["newton", "admm"],
                    help="the linear and reduced tiers' contact solvers to time (fidelity.solve.contact_solver)")
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "mavig_default.toml"))
    ap.add_argument("--set", action="append", metavar="PATH=VALUE", dest="sets",
                    help='a scene field for every run, as mlsim run\'s (TOML values), e.g. fidelity.solve.rod_kinematics="cosserat"')
    args = ap.parse_args()
    from mlsim.cli_grammar import parse_sets

    scene = load_scene(args.scene).with_values(parse_sets(args.sets))
    mesh = pipeline.run(scene, out_dir=None, outputs=("mesh",), progress=False, log=lambda m: None).results["mesh"][0]
    settings = qs.SolveSettings.from_scene(scene)
    lame, rho, _ = qs.layer_materials(scene)
    body = qs.LinearBody(mesh, lame, rho, settings.element, settings.gravity)
    result = {
        "machine": {"platform": platform.platform(), "python": platform.python_version(), "cpus": os.cpu_count()},
        "mesh": {"n_tets": mesh.n_tets, "n_points": mesh.n_points, "n_dofs": body.n_dofs, "element": body.element},
        "body_s": body.seconds,
    }
    episodes = {}
    reduced = None
    for solver in args.contact_solvers:
        for tier in ("linear", "reduced"):
            if tier not in args.tiers:
                continue
            name = f"{tier}-{solver}"
            if tier == "reduced" and reduced is None:
                t0 = time.perf_counter()
                reduced = qs.build_reduced(scene, mesh, body)
                reduced_s = time.perf_counter() - t0
            st = dataclasses.replace(settings, tier=tier, contact_solver=solver)
            ep, costs = _episode_costs(scene, mesh, args.repeats, body=body, settings=st, reduced=reduced if tier == "reduced" else None)
            episodes[name] = ep
            result[name] = {"precompute_s": ep.seconds["precompute"] + (reduced_s if tier == "reduced" else 0.0), **costs}
            if tier == "reduced":
                result[name]["n_patches"] = int(len(reduced.X))
    lin_name = next((n for n in episodes if n.startswith("linear")), None)
    lin_ep = episodes.get(lin_name)
    if "nonlinear" in args.tiers:
        nl_scene = scene.with_values({"fidelity.solve.tier": "nonlinear"})
        episodes["nonlinear"], costs = _episode_costs(nl_scene, mesh, args.nonlinear_repeats, settings=qs.SolveSettings.from_scene(nl_scene))
        result["nonlinear"] = {"precompute_s": episodes["nonlinear"].seconds["precompute"], **costs}
    for tier, ep in episodes.items():
        if tier == lin_name or lin_ep is None:
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
    print("| tier-solver | precompute (s) | per frame (ms, mean over the episode) | contact / fields (ms) | frames/s | "
          "moving frames: median ms (frames/s) | hold frames: median ms (frames/s) | iterations: total, max per step |")
    print("|---|---|---|---|---|---|---|---|")
    for tier in episodes:
        r = result[tier]
        k = r.get("per_step_kind", {})
        cell = lambda kind: f"{k[kind]['ms_median']:.2f} ({k[kind]['frames_per_s']:.0f})" if kind in k else "-"
        print(f"| {tier} | {r['precompute_s']:.2f} | {r['per_frame_ms_median']:.1f} | {r['contact_ms_per_frame_median']:.1f} / "
              f"{r['fields_ms_per_frame_median']:.1f} | {r['frames_per_s']:.1f} | {cell('moving')} | {cell('hold')} | "
              f"{r['contact_iterations_total']}, {r['contact_iterations_max_per_step']} |")
        print(f"  {tier}: first episode {r['per_frame_ms_first']:.1f} ms per frame (its operator pieces made, not shared)")
        if "difference_from_linear" in r:
            print(f"  {tier} vs {lin_name}: {r['difference_from_linear']}")
    if "nonlinear" in result:
        r = result["nonlinear"]
        print("nonlinear Newton iterations per step:", r["contact_iterations_per_step"])
        if r["step_ms"]:
            steps_s = np.asarray(r["step_ms"]) / 1e3
            print(f"nonlinear seconds per step (median {np.median(steps_s):.1f}, worst {steps_s.max():.1f} at step {int(steps_s.argmax())}, "
                  f"total {steps_s.sum():.0f}):", np.round(steps_s, 1).tolist())
            print("nonlinear steps by how they converged:", r["step_counts"])


if __name__ == "__main__":
    main()
