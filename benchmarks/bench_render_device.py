"""Path tier per frame on each render device (``fidelity.render.device``): the CPU against an NVIDIA GPU.

A GPU machine of this project has no registries and none of the FEM's dependencies, so the
benchmark is in two steps: ``export`` runs the scene's solve and emission here (cached) and writes
what the renderer sees, per frame (the deformed sheet's vertices, per-vertex radiance, the view and
the scene's optical settings, a few MB); ``time`` renders those frames as the render stage's path
tier does (the sheet moved and its BVH rebuilt every frame, ``render_frames``), needing only
numpy, scipy, mitsuba and this repository's ``mlsim.render``. Usage:

    .venv/bin/python benchmarks/bench_render_device.py export scenes/mavig_default.toml --out benchmarks/device/default_frames.npz
    python3 benchmarks/bench_render_device.py time benchmarks/device/default_frames.npz --device cuda --spp 16 --repeats 5 --out OUT
    .venv/bin/python benchmarks/bench_render_device.py compare OUT/images_cuda.npz --out out/bench_device

``time`` reports the median over the repeats of each frame's seconds (the first pass, which compiles
the kernels, reported apart), the transport matrix's trace time on that device, and writes
``render_device_<device>.json`` and the images (``images_<device>.npz``). ``compare`` renders the
same frames here on the CPU with other seeds and tests, per rod disk, that the two devices agree
within Monte Carlo error (Welch t-tests over independent renders).
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

VIEW_KEYS = ("width_px", "height_px", "lens_below_base_m", "image_distance_m", "pixel_pitch_m")


def export(scene_file: str, out: Path) -> None:
    from mlsim import pipeline, render
    from mlsim.scene import load_scene

    scene = load_scene(scene_file)
    res = pipeline.run(scene, out_dir=None, outputs=("emission", "solve"), progress=True, log=print)
    em, episode = res.results["emission"], res.results["solve"]
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2).astype(np.float32)
    vertices = render.deformed_vertices(episode, em.patches.vertices_m).astype(np.float32)
    sheet = render.sensor_scene_for(scene, em.patches, "cpu")
    centres, radius = render.rod_disks_px(scene)
    options = {k: v for k, v in sheet.options.items() if k != "device"}
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(out, rest_vertices_m=np.asarray(em.patches.vertices_m, dtype=np.float64), faces=np.asarray(em.patches.faces),
                        vertices_m=vertices, radiance=radiance, view=np.array([getattr(sheet.view, k) for k in VIEW_KEYS], dtype=float),
                        options=json.dumps(options), scene=str(scene_file), seed=scene.seed, rod_centres_px=np.asarray(centres),
                        rod_radius_px=float(radius))
    print(f"wrote {out}: {len(radiance)} frames, {radiance.shape[1]} sheet vertices, {out.stat().st_size / 1e6:.1f} MB")


def _sheet(z, device: str):
    from mlsim.render import View
    from mlsim.render.sensor_scene import SensorScene

    view = View(*[int(v) if k.endswith("_px") else float(v) for k, v in zip(VIEW_KEYS, z["view"])])
    return SensorScene(z["rest_vertices_m"], z["faces"], view, device=device, **json.loads(str(z["options"])))


def time_device(inputs: Path, device: str, spp: int, repeats: int, out: Path, transport_spp: int) -> None:
    from mlsim.render import render_frames, trace_transport

    z = np.load(inputs)
    t0 = time.perf_counter()
    sheet = _sheet(z, device)
    build_s = time.perf_counter() - t0
    radiance, vertices = z["radiance"], z["vertices_m"].astype(np.float64)
    passes, images = [], None
    for k in range(repeats + 1):  # pass 0 compiles the kernels (Dr.Jit caches them on disk too)
        r = render_frames(sheet, radiance, "path", spp=spp, seed=int(z["seed"]) + 1000 * k, vertices_m=vertices)
        passes.append(r.frame_seconds[r.rendered])
        if k == 1:
            images = r.radiance
    per_frame = np.array(passes[1:])  # (repeats, rendered frames)
    t0 = time.perf_counter()
    T = trace_transport(sheet, spp=transport_spp, seed=int(z["seed"]))
    trace_s = time.perf_counter() - t0
    res = {
        "machine": platform.platform(), "processor": platform.processor() or platform.machine(), "device": device,
        "variant": sheet.variant, "scene": str(z["scene"]), "spp": spp, "repeats": repeats,
        "frames": int(len(radiance)), "rendered_frames": int(per_frame.shape[1]),
        "build_scene_s": round(build_s, 3),
        "first_pass_median_ms_per_frame": round(1e3 * float(np.median(passes[0])), 2),
        "first_pass_first_frame_ms": round(1e3 * float(passes[0][0]), 1),
        "median_ms_per_frame": round(1e3 * float(np.median(per_frame)), 2),
        "median_ms_per_frame_each_repeat": [round(1e3 * float(np.median(p)), 2) for p in per_frame],
        "max_ms_per_frame": round(1e3 * float(per_frame.max()), 2),
        "transport_trace_s": round(trace_s, 2), "transport_spp": transport_spp, "transport_nnz": int(T.matrix.nnz),
    }
    try:
        import subprocess

        res["gpu"] = subprocess.run(["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"], capture_output=True,
                                    text=True, timeout=20).stdout.strip() if device == "cuda" else None
    except (OSError, subprocess.SubprocessError):
        res["gpu"] = None
    out.mkdir(parents=True, exist_ok=True)
    (out / f"render_device_{device}.json").write_text(json.dumps(res, indent=2))
    np.savez_compressed(out / f"images_{device}.npz", radiance=images.astype(np.float32), seed=int(z["seed"]) + 1000, spp=spp,
                        inputs=str(inputs))
    print(json.dumps(res, indent=2))


def compare(images: Path, inputs: Path | None, repeats: int, out: Path) -> None:
    """Per rod disk and frame: the GPU images against ``repeats`` CPU renders with other seeds."""
    from scipy import stats

    from mlsim.render import render_frames
    from mlsim.render.optics import disk_masks

    g = np.load(images)
    z = np.load(inputs if inputs is not None else str(g["inputs"]))
    sheet = _sheet(z, "cpu")
    spp = int(g["spp"])
    view = sheet.view
    masks = disk_masks(view.height_px, view.width_px, z["rod_centres_px"], float(z["rod_radius_px"])).reshape(len(z["rod_centres_px"]), -1)
    per_rod = lambda img: img.reshape(len(img), -1).astype(np.float64) @ masks.T.astype(np.float64)  # noqa: E731 (F, rods)
    cpu = np.array([per_rod(render_frames(sheet, z["radiance"], "path", spp=spp, seed=7000 + k, vertices_m=z["vertices_m"].astype(float)).radiance)
                    for k in range(repeats)])  # (K, F, rods)
    gpu = per_rod(g["radiance"])  # (F, rods): one render
    mean, sd = cpu.mean(axis=0), cpu.std(axis=0, ddof=1)
    lit = mean > 1e-3 * mean.max()
    # one GPU render against K CPU renders: t = (x - mean) / (sd sqrt(1 + 1/K)), K - 1 degrees of freedom
    t = (gpu[lit] - mean[lit]) / (sd[lit] * np.sqrt(1 + 1 / repeats))
    p = 2 * stats.t.sf(np.abs(t), repeats - 1)
    rel = np.abs(gpu[lit] - mean[lit]) / mean[lit]
    res = {"frames": int(lit.any(axis=1).sum()), "rod_frames": int(lit.sum()), "cpu_repeats": repeats, "spp": spp,
           "fisher_p": float(stats.combine_pvalues(p, method="fisher").pvalue), "max_abs_t": float(np.abs(t).max()),
           "median_rel_diff": float(np.median(rel)), "p95_rel_diff": float(np.quantile(rel, 0.95)),
           "cpu_median_rel_sd": float(np.median(sd[lit] / mean[lit]))}
    out.mkdir(parents=True, exist_ok=True)
    (out / "render_device_compare.json").write_text(json.dumps(res, indent=2))
    print(json.dumps(res, indent=2))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="command", required=True)
    e = sub.add_parser("export", help="solve and emission here; write the frames the renderer sees")
    e.add_argument("scene")
    e.add_argument("--out", type=Path, default=ROOT / "benchmarks" / "device" / "default_frames.npz")
    t = sub.add_parser("time", help="render the exported frames on a device")
    t.add_argument("inputs", type=Path)
    t.add_argument("--device", choices=["cpu", "cuda"], default="cuda")
    t.add_argument("--spp", type=int, default=16)
    t.add_argument("--repeats", type=int, default=5)
    t.add_argument("--transport-spp", type=int, default=64)
    t.add_argument("--out", type=Path, default=ROOT / "out" / "bench_device")
    c = sub.add_parser("compare", help="the GPU's images against CPU renders, per rod (Monte Carlo error)")
    c.add_argument("images", type=Path)
    c.add_argument("--inputs", type=Path, default=None)
    c.add_argument("--repeats", type=int, default=6)
    c.add_argument("--out", type=Path, default=ROOT / "out" / "bench_device")
    a = p.parse_args(argv)
    if a.command == "export":
        export(a.scene, a.out)
    elif a.command == "time":
        time_device(a.inputs, a.device, a.spp, a.repeats, a.out, a.transport_spp)
    else:
        compare(a.images, a.inputs, a.repeats, a.out)


if __name__ == "__main__":
    main()
