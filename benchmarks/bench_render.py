"""Render tiers on the default demo: precompute, per-frame cost, and the transport tier's error.

    .venv/bin/python benchmarks/bench_render.py [--scene scenes/mavig_default.toml] [--repeats 5] [--path-spp 64]

Prints medians (seconds, frames/s) and, per rod, the transport tier's intensity (the sum of the
radiance in the rod's disk, :func:`mlsim.render.rod_disks_px`) against the path tier's:

- path on the rest shape: the same geometry as transport, so the difference is Monte Carlo noise
  and the dropped entries (the tier's own error);
- path on the deformed shape (what the ``path`` tier renders): adds the error of ignoring the
  rods' deformation in the transport matrix.

Only frames and rods that carry at least 5 % of the brightest rod's intensity in that frame count
(dim rods' relative errors are noise over nothing). The stages before the render come from the
pipeline's cache (run ``make demo`` first to fill it, or this script computes them).
"""

from __future__ import annotations

import argparse
import platform
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/mavig_default.toml")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--path-spp", type=int, default=64, help="samples per pixel of the path reference")
    args = ap.parse_args()

    from mlsim import pipeline, render
    from mlsim.render.output import disk_masks
    from mlsim.scene import load_scene

    scene = load_scene(args.scene, {"outputs": ["emission", "solve"]})
    res = pipeline.run(scene, progress=False, log=lambda s: None)
    em, episode = res.results["emission"], res.results["solve"]
    sheet = render.sensor_scene_for(scene, em.patches)
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2).astype(np.float32)
    spec = scene.fidelity.render

    t0 = time.perf_counter()
    T = render.trace_transport(sheet, spp=spec.transport_spp, seed=scene.seed, drop=spec.transport_drop)
    trace_s = time.perf_counter() - t0
    lit = np.flatnonzero(radiance.max(axis=1) > 0)
    batch, single = [], []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        fast = T.apply(radiance[lit])
        batch.append((time.perf_counter() - t0) / len(lit))
        t0 = time.perf_counter()
        for f in lit:
            T.apply(radiance[f])
        single.append((time.perf_counter() - t0) / len(lit))

    path_s, ref_rest, ref_def = [], [], []
    vertices = render.deformed_vertices(episode, em.patches.vertices_m)
    for f in lit:
        sheet.set_vertices(em.patches.vertices_m)
        sheet.set_radiance(radiance[f])
        ref_rest.append(sheet.render(args.path_spp, 1000 + int(f)))
        sheet.set_vertices(vertices[f])
        t0 = time.perf_counter()
        sheet.render(spec.spp, 2000 + int(f))
        path_s.append(time.perf_counter() - t0)
        ref_def.append(sheet.render(args.path_spp, 3000 + int(f)))
    ref_rest, ref_def = np.array(ref_rest), np.array(ref_def)

    centres, radius = render.rod_disks_px(scene)
    masks = disk_masks(T.height_px, T.width_px, centres, radius).reshape(len(centres), -1).astype(np.float64)

    def per_rod(img):
        return img.reshape(len(img), -1).astype(np.float64) @ masks.T

    def errors(ref):
        a, b = per_rod(fast), per_rod(ref)
        keep = b >= 0.05 * b.max(axis=1, keepdims=True)
        rel = np.abs(a - b)[keep] / b[keep]
        return float(np.median(rel)), float(np.percentile(rel, 95)), float(rel.max()), int(keep.sum())

    print(f"machine: {platform.machine()} {platform.processor() or ''}, {__import__('os').cpu_count()} cores, Python {platform.python_version()}")
    print(f"scene {args.scene}: {len(radiance)} frames, {len(lit)} lit; sheet {sheet.n_vertices} vertices; view {T.width_px} x {T.height_px}")
    print(f"transport precompute ({spec.transport_spp} spp): {trace_s:.1f} s; nnz {T.matrix.nnz:,}; dropped share {T.dropped_fraction:.2e}")
    print(f"transport per frame, batch of {len(lit)}: median {np.median(batch) * 1e3:.3f} ms ({1 / np.median(batch):,.0f} frames/s)")
    print(f"transport per frame, one at a time:  median {np.median(single) * 1e3:.3f} ms ({1 / np.median(single):,.0f} frames/s)")
    print(f"path per frame at {spec.spp} spp (deformed sheet): median {np.median(path_s) * 1e3:.0f} ms")
    for name, ref in (("rest shape", ref_rest), ("deformed shape", ref_def)):
        med, p95, worst, n = errors(ref)
        print(f"transport vs path ({args.path_spp} spp, {name}): per-rod intensity error median {med * 100:.2f} %, "
              f"95th pct {p95 * 100:.2f} %, max {worst * 100:.2f} % over {n} rod-frames")


if __name__ == "__main__":
    main()
