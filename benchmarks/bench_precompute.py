"""The ``reduced`` solve tier's precompute (:func:`fem.quasistatic.build_reduced`) part by part.

The sensor of a scene (default: the screw sensor of the interaction datasets), its mesh from the
pipeline's cache (meshing is not part of the precompute: it is built first, untimed, if missing).
Each repeat builds everything after the mesh from scratch, in this process: the linear body
(assembly, factorisation, the stress operator and gravity load), the contact points and patches,
the loop of solves and products over the contact points' columns, and the far-field bases. Prints
the median and range of each part over ``--repeats``, the machine's ``nproc`` and its load average
at the start and the end (the machine may be shared: a load above its cores inflates every figure).

``--hash`` prints the sha256 of every array of the last repeat's model (compare two checkouts'
output: the precompute must give the same bytes); ``--profile N`` runs one more build under
cProfile and prints its N costliest functions (cumulative).

    MLSIM_CACHE_DIR=... .venv/bin/python benchmarks/bench_precompute.py [SCENE] [--repeats 3] [--hash] [--profile 30]
"""

from __future__ import annotations

import argparse
import cProfile
import hashlib
import os
import pstats
import time
from pathlib import Path

import numpy as np

from fem import condensed
from fem import quasistatic as qs
from mlsim import pipeline
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"{one:.2f} {five:.2f} {fifteen:.2f}"


def build_parts(scene, mesh) -> tuple[dict, qs.ReducedModel]:
    """One precompute, as :func:`fem.quasistatic.build_reduced` makes it; returns (seconds per part, model)."""
    settings = qs.SolveSettings.from_scene(scene)
    seconds = {}
    t0 = time.perf_counter()
    lame, rho, _ = qs.layer_materials(scene)
    body = qs.LinearBody(mesh, lame, rho, settings.element, settings.gravity, settings.backend)
    total = time.perf_counter() - t0
    seconds["body: assemble"] = body.seconds["assemble"]
    seconds["body: factorise"] = body.seconds["factorise"]
    seconds["body: stress operator, gravity"] = total - body.seconds["assemble"] - body.seconds["factorise"]
    t0 = time.perf_counter()
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, settings.contact_band_m))
    seconds["contact points"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    patches = condensed.group_patches(points, settings.patches_per_tip, settings.patches_per_side, qs.tip_height_m(mesh), seed=scene.seed)
    seconds["patches"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    model = qs.ReducedModel.build(body, points, patches)
    build = time.perf_counter() - t0
    # the build's own parts (ReducedModel.build records them), the rest of it apart
    inner = {k: v for k, v in model.seconds.items() if k != "precompute"}
    for k, v in inner.items():
        seconds[f"build: {k.replace('_', ' ')}"] = v
    seconds["build: rest"] = build - sum(inner.values())
    seconds["total"] = sum(seconds.values())
    return seconds, model


def array_hashes(model: qs.ReducedModel) -> dict[str, str]:
    """sha256 of each array of the model (its dtype and shape included)."""
    out = {}
    for k in model._ARRAYS:
        a = np.ascontiguousarray(getattr(model, k))
        out[k] = hashlib.sha256(f"{a.dtype}{a.shape}".encode() + a.tobytes()).hexdigest()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "scenes" / "interactions" / "screw.toml"))
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--hash", action="store_true", help="print the sha256 of every array of the model")
    ap.add_argument("--profile", type=int, default=0, metavar="N", help="one more build under cProfile: its N costliest functions")
    args = ap.parse_args()
    scene = load_scene(args.scene)
    mesh = pipeline.run(scene, out_dir=None, outputs=("mesh",), progress=False, log=lambda m: None).results["mesh"][0]
    print(f"scene {args.scene}: {mesh.n_tets} tets, {mesh.n_points} vertices; nproc {os.cpu_count()}; load average at start {_load()}")
    runs, model = [], None
    for i in range(args.repeats):
        seconds, model = build_parts(scene, mesh)
        runs.append(seconds)
        print(f"  repeat {i + 1}: total {seconds['total']:.1f} s (load {_load()})", flush=True)
    if runs:
        print(f"{'part':<34} {'median s':>9} {'min s':>8} {'max s':>8}")
        for k in runs[0]:
            v = np.array([r[k] for r in runs])
            print(f"{k:<34} {np.median(v):9.2f} {v.min():8.2f} {v.max():8.2f}")
    if args.hash and model is not None:
        for k, h in array_hashes(model).items():
            print(f"sha256 {k:<26} {h}")
    if args.profile:
        prof = cProfile.Profile()
        prof.enable()
        build_parts(scene, mesh)
        prof.disable()
        pstats.Stats(prof).sort_stats("cumulative").print_stats(args.profile)
    print(f"load average at end {_load()}")


if __name__ == "__main__":
    main()
