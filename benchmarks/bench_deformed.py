"""The deformed render tier against path tracing of the deformed sheet, and its speed, per scene.

For every lit frame of a scene's episode (at least 1e-3 of the brightest frame's light):

- **error**: the deformed tier (direct light rasterised on the deformed sheet, bounces from the
  rest shape's matrix) and the rest shape's transport, against the mean of two 64 spp mono path
  renders of the deformed sheet: per-rod disk sums, the relative Frobenius norm over frames x
  rods, and the worst frame's;
- **speed**: the tier's frames per second over the episode's lit frames as one batch (the render
  stage's call), the median of ``--repeats``, after a warm-up; and its two parts, the rasteriser
  and the bounces' product, alone;
- **precompute**: the bounces' matrix (``fidelity.render.transport_spp``) and the rasteriser's
  throughput and tables.

The spectral reference (``mlsim accuracy SCENE --stage render``) differs from the mono path by the
spectral shortcut, well under the errors here. Usage (a few minutes per scene on 2 cores):

    .venv/bin/python benchmarks/bench_deformed.py [SCENE ...] [--repeats 9] [--per-side 2] [--no-error]
"""

from __future__ import annotations

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from mlsim import pipeline, render
from mlsim.render.direct_raster import direct_raster
from mlsim.render.optics import disk_masks
from mlsim.render.reprojection import split_transport, trace_bounces
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def _median_per_frame(fn, frames: int, repeats: int) -> float:
    fn()  # warm: numba's compiled kernels load once per process
    seconds = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        seconds.append((time.perf_counter() - t0) / frames)
    return float(np.median(seconds))


def scene_figures(path, per_side: int = 2, repeats: int = 9, error: bool = True) -> dict:
    scene = load_scene(path)
    res = pipeline.run(scene.with_values({"outputs": ["emission", "solve"]}), out_dir=None, progress=False, log=lambda m: None)
    em, ep = res.results["emission"], res.results["solve"]
    vertices = render.deformed_vertices(ep, em.patches.vertices_m)
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2).astype(np.float32)
    total = em.photons_per_s.sum(axis=1)
    lit = np.flatnonzero(total >= 1e-3 * total.max())
    sheet = render.sensor_scene_for(scene, em.patches, "cpu")
    spec = scene.fidelity.render
    t0 = time.perf_counter()
    direct, _ = split_transport(sheet, spp=spec.transport_spp, seed=scene.seed, drop=spec.transport_drop)
    trace_s = time.perf_counter() - t0
    # the tier's bounces as the render stage traces them (one vertex per hit, mlsim.render.stage._cached_transport)
    bounces = trace_bounces(sheet, spp=spec.transport_spp, seed=scene.seed, drop=spec.transport_drop)
    t0 = time.perf_counter()
    raster = direct_raster(sheet, per_side)
    raster_s = time.perf_counter() - t0
    E, X = radiance[lit], vertices[lit]
    out = {"scene": Path(path).stem, "frames": len(lit), "bounce_trace_s": bounces.seconds, "raster_build_s": raster_s,
           "split_trace_s": trace_s, "displacement_mm": float(np.linalg.norm(vertices - sheet.rest_vertices_m, axis=2).max() * 1e3)}
    out["tier_s"] = _median_per_frame(lambda: render.render_frames(sheet, E, "deformed", transport=bounces, raster=raster, vertices_m=X),
                                      len(lit), repeats)
    out["raster_s"] = _median_per_frame(lambda: raster.images(X, E), len(lit), repeats)
    out["bounces_s"] = _median_per_frame(lambda: bounces.apply(E), len(lit), repeats)
    if not error:
        return out
    centres, radius = render.rod_disks_px(scene)
    masks = disk_masks(sheet.view.height_px, sheet.view.width_px, centres, radius).reshape(len(centres), -1).astype(float)
    tier = render.render_frames(sheet, E, "deformed", transport=bounces, raster=raster, vertices_m=X).radiance
    rest = direct.apply(E) + bounces.apply(E)
    ref = []
    for i, f in enumerate(lit):
        sheet.set_vertices(vertices[f])
        sheet.set_radiance(radiance[f])
        ref.append(masks @ np.mean([sheet.render(64, 1000 + f + 7 * k) for k in range(2)], axis=0).reshape(-1))
    sheet.set_vertices(sheet.rest_vertices_m)
    ref = np.array(ref)

    def err(images):
        rods = np.einsum("rp,fp->fr", masks, images.reshape(len(images), -1).astype(np.float64))
        worst = max(np.linalg.norm(rods[i] - ref[i]) / np.linalg.norm(ref[i]) for i in range(len(ref)))
        return float(np.linalg.norm(rods - ref) / np.linalg.norm(ref)), float(worst)

    out["tier_error"], out["rest_error"] = err(tier), err(rest)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scenes", nargs="*", default=[str(ROOT / "scenes" / s) for s in ("mavig_default.toml", "interactions/screw.toml", "direction_test.toml")])
    ap.add_argument("--per-side", type=int, default=2, help="the direct light's samples per pixel side")
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--no-error", action="store_true", help="speed only (skip the path renders)")
    args = ap.parse_args()
    print(f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores; direct light {args.per_side} x {args.per_side} per pixel")
    print("| scene | lit frames | sheet moves (mm) | deformed: all frames / worst | rest shape: all / worst | frames/s (ms) | raster ms | bounces ms | precompute s (bounces + raster) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for s in args.scenes:
        r = scene_figures(s, args.per_side, args.repeats, not args.no_error)
        errs = (f"{r['tier_error'][0]:.2%} / {r['tier_error'][1]:.1%} | {r['rest_error'][0]:.2%} / {r['rest_error'][1]:.1%}"
                if "tier_error" in r else "- | -")
        print(f"| {r['scene']} | {r['frames']} | {r['displacement_mm']:.2f} | {errs} | {1 / r['tier_s']:.0f} ({r['tier_s'] * 1e3:.2f}) | "
              f"{r['raster_s'] * 1e3:.2f} | {r['bounces_s'] * 1e3:.2f} | {r['bounce_trace_s']:.1f} + {r['raster_build_s']:.1f} |", flush=True)


if __name__ == "__main__":
    main()
