"""Cost of the whole camera stage (mlsim.camera.capture) at 350 x 350 RGB.

Radiometry, Bayer sampling, dark current, shot and read noise, full well, gain, ADC, 8 bits and
OpenCV demosaic, on a realistic radiance image: five glowing rod-shaped discs of 300 to 3000
electrons per pixel (green-dominant ZnS:Cu), dark elsewhere. Prints the machine, then the median
per-frame time and frames/s, batched (one call on --frames frames) and one frame per call, for the
default camera (every photosite on the normal branch) and for a low-read-noise variant whose dark
photosites take the exact-Poisson branch. Writes out/bench/camera.json. Usage:

    .venv/bin/python benchmarks/bench_camera.py [--repeats 20] [--frames 30] [--out out/bench]
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

from mlsim.camera import Camera, CameraParams

ROOT = Path(__file__).resolve().parents[1]


def rod_radiance(params: CameraParams, rng: np.random.Generator) -> np.ndarray:
    """(H, W, 3) effective photon radiance: five discs of 300-3000 e- per pixel, dark elsewhere."""
    h, w = params.height_px, params.width_px
    yy, xx = np.mgrid[:h, :w]
    electrons = np.zeros((h, w, 3))
    colour = np.array([0.35, 1.0, 0.45])  # ZnS:Cu emits green; R and B see its tails
    for cy, cx, peak in [(0.25, 0.25, 300), (0.25, 0.75, 1000), (0.5, 0.5, 3000), (0.75, 0.25, 600), (0.75, 0.75, 2000)]:
        r2 = (yy - cy * h) ** 2 + (xx - cx * w) ** 2
        disc = np.exp(-r2 / (2 * (0.06 * w) ** 2)) * (r2 < (0.12 * w) ** 2)  # rod end: a soft spot
        electrons += peak * disc[..., None] * colour
    electrons *= 1.0 + 0.05 * rng.standard_normal((h, w, 1))  # some texture
    np.clip(electrons, 0, None, out=electrons)
    return electrons / params.electrons_per_radiance_m2_sr_s


def time_case(camera: Camera, radiance: np.ndarray, n_frames: int, repeats: int) -> dict:
    rng = np.random.default_rng(0)
    # distinct frames (as a renderer would hand over), so the input is not cache-hot
    frames = np.stack([radiance * (1.0 + 0.01 * k) for k in range(n_frames)])
    camera(frames[:2], rng)  # warm up
    batched, single = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        camera(frames, rng)
        batched.append((time.perf_counter() - t0) / n_frames)
        t0 = time.perf_counter()
        for f in frames:
            camera(f, rng)
        single.append((time.perf_counter() - t0) / n_frames)
    b, s = statistics.median(batched), statistics.median(single)
    return {"batched_ms_per_frame": b * 1e3, "batched_fps": 1.0 / b, "single_ms_per_frame": s * 1e3, "single_fps": 1.0 / s}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--frames", type=int, default=30, help="frames per batch")
    ap.add_argument("--out", default="out/bench")
    args = ap.parse_args()

    cases = {
        "default (IMX415-class, binning 4, read noise 8 e- effective)": CameraParams(gain_db=12.0),
        "low read noise (binning 1, 1 e-): exact-Poisson dark pixels": CameraParams(gain_db=12.0, binning=1, read_noise_e=1.0, focal_length_m=0.83e-3),
    }
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}, numpy {np.__version__}"
    print(f"camera benchmark, 350 x 350 RGB, {args.frames} frames x {args.repeats} repeats, {machine}")
    print("| case | batched ms/frame | batched frames/s | one-at-a-time ms/frame | one-at-a-time frames/s |")
    print("|---|---|---|---|---|")
    rows = []
    for name, params in cases.items():
        cam = Camera(params)
        rad = rod_radiance(params, np.random.default_rng(1))
        r = time_case(cam, rad, args.frames, args.repeats)
        rows.append({"case": name, **r})
        print(f"| {name} | {r['batched_ms_per_frame']:.3f} | {r['batched_fps']:.0f} | {r['single_ms_per_frame']:.3f} | {r['single_fps']:.0f} |")
    target = 500.0
    ok = rows[0]["batched_fps"] >= target and rows[0]["single_fps"] >= target
    print(f"target >= {target:.0f} frames/s (default camera): {'met' if ok else 'NOT met'}")

    out_dir = ROOT / args.out if not Path(args.out).is_absolute() else Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    result = {
        "machine": {"platform": platform.platform(), "processor": platform.processor() or platform.machine(), "cpu_count": os.cpu_count(),
                    "python": platform.python_version(), "numpy": np.__version__},
        "frame": [350, 350, 3],
        "frames_per_batch": args.frames,
        "repeats": args.repeats,
        "target_fps": target,
        "target_met": ok,
        "cases": rows,
    }
    tmp = out_dir / "camera.json.tmp"
    tmp.write_text(json.dumps(result, indent=2))
    tmp.replace(out_dir / "camera.json")  # atomic: no half-written file
    print(f"wrote {out_dir / 'camera.json'}")


if __name__ == "__main__":
    main()
