"""Reproduce the default of ``emission.brightness_photons_per_m2`` (see mlsim/render/calibration.py).

    .venv/bin/python benchmarks/calibrate_brightness.py [--target-dn8 192] [--force-n 16]

Simulates a force-controlled press of the default probe (0.15 s ramp, then a 0.1 s hold) on the
default sensor at default camera settings, takes the 99.5-percentile noiseless green level of the
brightest frame and prints the brightness that moves it to the target, with the peak force reached.
"""

from __future__ import annotations

import argparse

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/mavig_default.toml")
    ap.add_argument("--force-n", type=float, default=16.0)
    ap.add_argument("--target-dn8", type=float, default=192.0)
    args = ap.parse_args()

    from mlsim import pipeline
    from mlsim.render.calibration import brightness_to_match, green_level_dn8
    from mlsim.render.optics import camera_params
    from mlsim.scene import load_scene

    segments = [{"kind": "press", "force_n": args.force_n, "duration_s": 0.15}, {"kind": "hold", "duration_s": 0.1}]
    scene = load_scene(args.scene, {"load.segments": segments, "outputs": ["render"]})
    res = pipeline.run(scene, progress=True)
    episode, rendered = res.results["solve"], res.results["render"]
    frame = int(np.argmax(rendered.radiance.reshape(rendered.n_frames, -1).sum(axis=1)))
    level = green_level_dn8(scene, rendered.radiance[frame])
    p = camera_params(scene)
    black8 = p.black_level_dn * 2.0 ** (8 - p.adc_bits)
    b = scene.emission.brightness_photons_per_m2
    print(f"peak normal force {episode.normal_force_n.max():.2f} N; brightest frame {frame}")
    print(f"green level at B = {b:.4g}: {level:.1f} of 255 (black {black8:g})")
    if level < 255:
        print(f"B for {args.target_dn8:g}: {brightness_to_match(b, level, args.target_dn8, black8):.4g} photons/m^2")
    else:
        print("saturated: halve emission.brightness_photons_per_m2 (--set) and run again")


if __name__ == "__main__":
    main()
