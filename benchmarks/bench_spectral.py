"""Spectral shortcut against the full spectral render on the default demo (issue acceptance: per-channel
difference reported and under 1 %).

    .venv/bin/python benchmarks/bench_spectral.py [--scene scenes/mavig_default.toml] [--cache DIR]
        [--frames 3] [--batches 4] [--mono-spp 512] [--spectral-spp 1024]

On the rest geometry, for the brightest lit frames of the demo's emission:

- shortcut: the mono path render (``llvm_ad_mono``) times :func:`mlsim.render.ml_channel_factors`;
- reference: the same sheet rendered in ``llvm_ad_spectral`` with the ZnS:Cu band on the emitter and
  a ``specfilm`` whose channels are QE x internal transmittances (:mod:`mlsim.render.spectral`).

Each side is rendered as ``--batches`` independent renders (their own seeds) whose mean is compared,
so the Monte Carlo standard error of each difference is estimated from the spread of the batches.
Printed per channel: the difference of the image totals (all frames) with its standard error, and
over the rods (sum in each rod's disk, :func:`mlsim.render.rod_disks_px`; rod-frames with at least
5 % of the brightest rod in their frame and channel) the median and largest absolute difference and
the median standard error of one rod-frame's difference; then the time per frame of each render.
The spectral side needs more samples: its wavelengths are sampled by the film's curves, not by the
emission band (see :mod:`mlsim.render.spectral`). The stages before the render come from the
pipeline's cache (``--cache``, default the pipeline's own; they are computed if missing, about a minute).
"""

from __future__ import annotations

import argparse
import os
import platform
import time

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/mavig_default.toml")
    ap.add_argument("--cache", default=None, help="pipeline cache folder (default: the pipeline's own)")
    ap.add_argument("--frames", type=int, default=3, help="the brightest N lit frames")
    ap.add_argument("--batches", type=int, default=4, help="independent renders per side (>= 2 for error bars)")
    ap.add_argument("--mono-spp", type=int, default=512, help="total samples per pixel of the mono render, over the batches")
    ap.add_argument("--spectral-spp", type=int, default=1024, help="total samples per pixel of the spectral render")
    args = ap.parse_args()
    if args.batches < 1 or args.frames < 1:
        ap.error("--batches and --frames must be >= 1")

    from mlsim import pipeline, render
    from mlsim.render import spectral
    from mlsim.scene import load_scene

    scene = load_scene(args.scene, {"outputs": ["emission"]})
    cache = pipeline.Cache(args.cache) if args.cache else None
    res = pipeline.run(scene, cache=cache, progress=False, log=lambda s: None)
    em = res.results["emission"]
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2).astype(np.float32)
    total = radiance.sum(axis=1)
    frames = [int(f) for f in np.argsort(total)[::-1][: args.frames] if total[f] > 0]

    mono = render.sensor_scene_for(scene, em.patches)  # rest geometry: the sheet as built
    spectra = spectral.ml_render_spectra(scene)
    k = render.ml_channel_factors(scene)
    twin = spectral.spectral_twin(mono, spectra)
    mono_spp = max(args.mono_spp // args.batches, 1)
    spec_spp = max(args.spectral_spp // args.batches, 1)

    H, W = mono.view.height_px, mono.view.width_px
    shape = (args.batches, len(frames), H, W, 3)
    ref, cut = np.empty(shape, np.float32), np.empty(shape, np.float32)
    mono.set_radiance(radiance[frames[0]])  # compile both kernels before timing
    mono.render(1, 0)
    twin.set_radiance(radiance[frames[0]])
    twin.render(1, 0)
    mono_s, spec_s = [], []
    for b in range(args.batches):
        for i, f in enumerate(frames):
            mono.set_radiance(radiance[f])
            t0 = time.perf_counter()
            img = mono.render(mono_spp, 1000 * b + f)
            mono_s.append(time.perf_counter() - t0)
            cut[b, i] = spectral.shortcut_images(img, k)
            twin.set_radiance(radiance[f])
            t0 = time.perf_counter()
            ref[b, i] = twin.render(spec_spp, 500_000 + 1000 * b + f)
            spec_s.append(time.perf_counter() - t0)

    centres, radius = render.rod_disks_px(scene)
    table = spectral.compare_to_shortcut(ref, cut, centres, radius, channels=spectra.channels)

    print(f"machine: {platform.machine()} {platform.processor() or ''}, {os.cpu_count()} cores, Python {platform.python_version()}, "
          f"{platform.system()} {platform.release()}")
    import mitsuba as mi

    print(f"mitsuba {mi.__version__}; scene {args.scene}: {len(radiance)} frames, sheet {mono.n_vertices} vertices, view {W} x {H}")
    print(f"frames {frames} (the brightest {len(frames)}, rest geometry); {args.batches} independent renders per side: "
          f"mono {mono_spp} spp each ({mono_spp * args.batches} in all), spectral {spec_spp} spp each ({spec_spp * args.batches} in all)")
    print("channel factors k (e-/photon): shortcut " + ", ".join(f"{c} {v:.6f}" for c, v in zip(spectra.channels, k))
          + "; reference curves' trapezoid integral " + ", ".join(f"{v:.6f}" for v in spectra.channel_factors()))
    print("difference = shortcut / reference - 1 (percent); SE = Monte Carlo standard error from the batches")
    print(f"{'channel':>7} | {'total diff':>10} {'SE':>6} | {'rod median |diff|':>17} {'rod max |diff|':>14} {'rod median SE':>13} {'rod-frames':>10}")
    for c, name in enumerate(table["channels"]):
        print(f"{name:>7} | {table['total_diff_pct'][c]:>+9.3f}% {table['total_se_pct'][c]:>5.3f}% | "
              f"{table['rod_median_abs_diff_pct'][c]:>16.3f}% {table['rod_max_abs_diff_pct'][c]:>13.3f}% "
              f"{table['rod_median_se_pct'][c]:>12.3f}% {table['rod_frames'][c]:>10d}")
    for i, f in enumerate(frames):
        print(f"  frame {f}: total diff " + ", ".join(f"{n} {v:+.3f}%" for n, v in zip(table["channels"], table["frame_total_diff_pct"][i])))
    print(f"time per frame: mono {np.median(mono_s):.2f} s at {mono_spp} spp ({np.median(mono_s) / mono_spp * 1e3:.1f} ms/spp), "
          f"spectral {np.median(spec_s):.2f} s at {spec_spp} spp ({np.median(spec_s) / spec_spp * 1e3:.1f} ms/spp)")
    worst = max(abs(v) for v in table["total_diff_pct"])
    print(f"acceptance (per-channel total difference < 1 %): {'PASS' if worst < 1.0 else 'FAIL'} (largest {worst:.3f} %)")


if __name__ == "__main__":
    main()
