"""What sets the direction study's error (issue 16): the study of ``dllm.direction`` rerun with one
cause of scatter removed at a time, 0-90 deg in 15 deg steps, and each row's mean absolute error
for both estimators (the pushed taxels in the push frames, and every firing taxel of every event
frame).

Causes, one per variant against the one before it:

- ``shipped``: the scene as it is (``scenes/direction_test.toml``: 1.5 mm mesh, camera noise, the
  deformed render tier);
- ``noiseless camera``: ``camera.noise = false`` (shot, read and dark noise off; still quantised);
- ``+ path 64 spp``: every frame path-traced on the deformed sheet at 64 samples per pixel instead
  of the deformed tier (whose bounces are the rest shape's);
- ``+ no Bayer``: a monochrome sensor (no mosaic, no demosaicing);
- ``2 mm mesh (noiseless)``: the default sensor's mesh, whose fTetWild asymmetry the scene's 1.5 mm avoids.

Also, per variant: the mean error on the square grid's mirror lines (0, 45, 90 deg, where a
symmetric sensor gives none: what is left there is the mesh's and the noise's asymmetry) and off
them (15, 30, 60, 75 deg: the grid's anisotropy adds there), and the few-event-frames term, the
mean over episodes of the circular spread of the pushed taxels' per-frame directions over the
square root of their count (the standard error of the episode's mean). Prints a Markdown table and
writes ``OUT/direction_scatter.json``. Usage (about 25 minutes on 2 cores with cold caches):

    .venv/bin/python benchmarks/direction_scatter.py [--out out/direction_scatter] [--angles 0 15 ...]
"""

from __future__ import annotations

import argparse
import json
import math
from pathlib import Path

import numpy as np

from dllm.direction import wrap_deg
from mlsim.scene import load_scene
from mlsim.studies.direction import direction_study, summary

ROOT = Path(__file__).resolve().parents[1]

VARIANTS = {
    "shipped": {},
    "noiseless camera": {"camera.noise": False},
    "+ path 64 spp": {"camera.noise": False, "fidelity.render.tier": "path", "fidelity.render.spp": 64},
    "+ no Bayer": {"camera.noise": False, "fidelity.render.tier": "path", "fidelity.render.spp": 64, "camera.bayer": False},
    "2 mm mesh (noiseless)": {"camera.noise": False, "fidelity.mesh.edge_length_mm": 2.0},
}
MIRROR_LINES_DEG = (0.0, 45.0, 90.0)


def _circular_spread_deg(samples_deg) -> float:
    """Circular standard deviation (deg) of directions; 0 for fewer than two."""
    a = np.radians(np.asarray(samples_deg, dtype=float))
    if len(a) < 2:
        return 0.0
    r = abs(np.mean(np.exp(1j * a)))
    return math.degrees(math.sqrt(max(-2.0 * math.log(max(r, 1e-300)), 0.0)))


def summarise(rows) -> dict:
    """Mean absolute errors (pushed taxels; every taxel), on and off the mirror lines, and the
    few-frames term, of one variant's study rows."""
    err = np.array([r.error_deg for r in rows])
    err_all = np.array([r.error_all_deg for r in rows])
    on = np.isin([r.applied_deg % 90.0 for r in rows], [a % 90.0 for a in MIRROR_LINES_DEG])
    frames_term = [_circular_spread_deg(wrap_deg(np.asarray(r.sample_deg) - r.approach_deg)) / math.sqrt(max(len(r.sample_deg), 1)) for r in rows]
    figures = summary(rows)
    return {"mean_abs_error_deg": figures["mean_abs_error_deg"], "mean_abs_error_all_taxels_deg": figures["mean_abs_error_all_taxels_deg"],
            "mean_error_deg": float(np.nanmean(err)), "mirror_lines_mean_abs_deg": float(np.nanmean(np.abs(err[on]))) if on.any() else None,
            "off_mirror_lines_mean_abs_deg": float(np.nanmean(np.abs(err[~on]))) if (~on).any() else None,
            "few_frames_standard_error_deg": float(np.mean(frames_term)), "errors_deg": err.tolist(), "errors_all_taxels_deg": err_all.tolist()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/direction_scatter")
    ap.add_argument("--angles", nargs="+", type=float, default=[0, 15, 30, 45, 60, 75, 90])
    ap.add_argument("--scene", default=str(ROOT / "scenes" / "direction_test.toml"))
    args = ap.parse_args()
    base = load_scene(args.scene)
    result = {}
    for name, values in VARIANTS.items():
        scene = base.with_values(values) if values else base
        rows = direction_study(scene, args.angles, progress=False, log=lambda m: None)
        result[name] = {"set": values, **summarise(rows)}
        print(f"{name}: {result[name]['mean_abs_error_deg']:.2f} deg", flush=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "direction_scatter.json").write_text(json.dumps(result, indent=1))
    print("| variant | pushed taxels: mean abs error (deg) | every taxel (deg) | on mirror lines | off them | few frames (std. error) |")
    print("|---|---|---|---|---|---|")
    def cell(v):
        return "-" if v is None else f"{v:.2f}"

    for name, r in result.items():
        print(f"| {name} | {cell(r['mean_abs_error_deg'])} | {cell(r['mean_abs_error_all_taxels_deg'])} | {cell(r['mirror_lines_mean_abs_deg'])} | "
              f"{cell(r['off_mirror_lines_mean_abs_deg'])} | {cell(r['few_frames_standard_error_deg'])} |")


if __name__ == "__main__":
    main()
