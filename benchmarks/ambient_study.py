"""Ambient light against the ML signal (ISSUE 4): the 50 W daylight lamp 1.5 m above the sensor vs
a 16 N press, for each absorber of SPEC 1.3 and none.

    .venv/bin/python benchmarks/ambient_study.py [--force-n 16] [--height-m 1.5] [--power-w 50]

Same press as benchmarks/calibrate_brightness.py (force control, 0.15 s ramp, 0.1 s hold, default
probe and camera). Prints, per absorber, the brightest rod's mean ambient signal (electrons per pixel
in its disk, R + G + B, noiseless) over the brightest rod's ML signal, and the ambient's 8-bit green
level above black in a dark frame.
"""

from __future__ import annotations

import argparse
import platform

import numpy as np


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", default="scenes/mavig_default.toml")
    ap.add_argument("--force-n", type=float, default=16.0)
    ap.add_argument("--height-m", type=float, default=1.5)
    ap.add_argument("--power-w", type=float, default=50.0)
    args = ap.parse_args()

    from mlsim import pipeline
    from mlsim.scene import ABSORBERS, load_scene

    segments = [{"kind": "press", "force_n": args.force_n, "duration_s": 0.15}, {"kind": "hold", "duration_s": 0.1}]
    print(f"machine: {platform.machine()}, Python {platform.python_version()}")
    print(f"daylight lamp {args.power_w:g} W, {args.height_m:g} m above the tips; press {args.force_n:g} N (0.15 s ramp)")
    print(f"{'absorber':26s} {'ambient / ML peak':>18s} {'ambient e/px':>13s} {'ML peak e/px':>13s} {'shaded':>7s}")
    for absorber in ABSORBERS:
        scene = load_scene(args.scene, {"load.segments": segments, "outputs": ["render", "camera"], "ambient.lamp": "daylight",
                                        "ambient.power_w": args.power_w, "ambient.height_m": args.height_m, "optics.absorber": absorber,
                                        "camera.noise": False})
        res = pipeline.run(scene, progress=False, log=lambda s: None)
        cam, info = res.results["camera"], res.results["render"].info["ambient"]
        s = cam.summary()
        print(f"{absorber:26s} {s['ambient_to_ml_peak']:18.3e} {s['peak_rod_ambient_e']:13.4g} {s['peak_rod_signal_e']:13.4g} "
              f"{info['shaded_fraction']:7.3f}")
    print(f"peak normal force {res.results['solve'].normal_force_n.max():.2f} N; irradiance on the top {info['irradiance_on_top_w_m2']:.3f} W/m^2 "
          f"(radiant power {info['radiant_power_w']:.2f} W)")


if __name__ == "__main__":
    main()
