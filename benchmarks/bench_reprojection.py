"""The deformation-aware split (``mlsim.render.reprojection``) against path tracing on the deformed sheet.

For every lit frame of a scene's episode: the direct light from the camera's primary rays on the
deformed sheet plus the rest shape's bounces, and the rest-shape transport, against the mean of two
64 spp path renders of the deformed sheet (mono). Per-rod disk sums; prints the relative Frobenius
error over frames x rods, the worst frame of each, and the median seconds per frame of the
primary rays. Usage (a few minutes per scene on 2 cores):

    .venv/bin/python benchmarks/bench_reprojection.py [SCENE ...] [--spp 16] [--per-side 3]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from mlsim import pipeline, render
from mlsim.render import reprojection
from mlsim.render.optics import disk_masks
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def scene_errors(path, spp: int = 16, per_side: int = 3) -> dict:
    scene = load_scene(path)
    res = pipeline.run(scene.with_values({"outputs": ["emission", "solve"]}), out_dir=None, progress=False, log=lambda m: None)
    em, ep = res.results["emission"], res.results["solve"]
    vertices = render.deformed_vertices(ep, em.patches.vertices_m)
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2).astype(np.float32)
    total = em.photons_per_s.sum(axis=1)
    lit = np.flatnonzero(total >= 1e-3 * total.max())
    sheet = render.sensor_scene_for(scene, em.patches)
    centres, radius = render.rod_disks_px(scene)
    masks = disk_masks(sheet.view.height_px, sheet.view.width_px, centres, radius).reshape(len(centres), -1).astype(float)
    t0 = time.perf_counter()
    direct, bounces = reprojection.split_transport(sheet, spp=spp, seed=3)
    split_s = time.perf_counter() - t0
    ref, split, rest, seconds = [], [], [], []
    for f in lit:
        sheet.set_vertices(vertices[f])
        t0 = time.perf_counter()
        samples = reprojection.primary_samples(sheet, per_side)
        seconds.append(time.perf_counter() - t0)
        sheet.set_radiance(radiance[f])
        path = np.mean([sheet.render(64, 1000 + f + 7 * k) for k in range(2)], axis=0)
        b = bounces.apply(radiance[f])
        ref.append(masks @ path.reshape(-1))
        split.append(masks @ (reprojection.direct_image(samples, sheet.faces, radiance[f]) + b).reshape(-1))
        rest.append(masks @ (direct.apply(radiance[f]) + b).reshape(-1))
    ref, split, rest = map(np.array, (ref, split, rest))

    def err(x):
        return float(np.linalg.norm(x - ref) / np.linalg.norm(ref)), float(max(np.linalg.norm(x[i] - ref[i]) / np.linalg.norm(ref[i]) for i in range(len(ref))))

    return {"scene": str(path), "frames": len(lit), "split": err(split), "rest": err(rest), "primary_rays_s": float(np.median(seconds)), "split_trace_s": split_s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=[str(ROOT / "scenes" / s) for s in ("mavig_default.toml", "interactions/screw.toml", "direction_test.toml")])
    ap.add_argument("--spp", type=int, default=16, help="samples per pixel of the split transport")
    ap.add_argument("--per-side", type=int, default=3, help="primary rays per pixel side")
    args = ap.parse_args()
    print("| scene | lit frames | split: all frames / worst frame | rest shape: all / worst | primary rays (s/frame) | split trace (s) |")
    print("|---|---|---|---|---|---|")
    for s in args.scenes:
        r = scene_errors(s, args.spp, args.per_side)
        print(f"| {Path(s).stem} | {r['frames']} | {r['split'][0]:.2%} / {r['split'][1]:.1%} | {r['rest'][0]:.2%} / {r['rest'][1]:.1%} | "
              f"{r['primary_rays_s']:.2f} | {r['split_trace_s']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
