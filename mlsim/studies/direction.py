"""The direction study (SPEC 1.5): ``mlsim direction SCENE``, the DLLM's angle against the direction
a rod pushes the sensor.

For each applied direction theta (the scene's slide segment, ``direction_deg``: the way the probe
moves) the scene runs through FEM, light, camera and DLLM (:mod:`mlsim.pipeline`, so meshes and
transport matrices are shared), and the episode's direction is read from the pushed taxels in the
push frames (:mod:`dllm.direction`, which gives the physics and the sign convention: the DLLM
reports the bearing the probe comes from, theta + 180 deg). Writes ``direction.csv``,
``direction.json`` and ``direction.png``.

The published reference (SPEC 1.5) is a mean error "within a few degrees". What this study can
show depends on the simulated light: with the rest-shape transport tier the light of a pushed rod
does not move with the rod (only its emission pattern shifts); the default tier path-traces the
frames in which the sheet moved more than ``fidelity.render.transport_max_displacement_mm``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dllm.direction import SIGN_CONVENTION, approach_deg, episode_direction, push_frames, pushed_taxels, wrap_deg

__all__ = ["DirectionRow", "direction_study", "summary", "write"]


@dataclass
class DirectionRow:
    applied_deg: float  # where the probe moves (the slide's direction_deg)
    approach_deg: float  # where it comes from: applied + 180, the DLLM's expected reading
    measured_deg: float  # pushed taxels, push frames (module docstring)
    error_deg: float  # measured - approach, wrapped
    events: int
    samples: int
    measured_all_deg: float = float("nan")  # every firing taxel of every event frame
    error_all_deg: float = float("nan")
    push_events: int = 0
    taxels: list = field(default_factory=list)
    sample_deg: list = field(default_factory=list)


def direction_study(scene, angles_deg, out_dir=None, cache=None, progress: bool = True, log=print) -> list[DirectionRow]:
    """Run the scene at each applied direction; return the rows (and write CSV, JSON and the box
    plot to ``out_dir`` when given)."""
    from mlsim import pipeline

    if scene.load is None:
        raise ValueError("load: the direction study needs a scene with a [load] section and a slide segment")
    slides = [i for i, s in enumerate(scene.load.segments) if s.kind == "slide"]
    if not slides:
        raise ValueError("load.segments: the direction study turns the scene's slide segment; the scene has none")
    k = slides[0]
    push_start = sum(seg.seconds for seg in scene.load.segments[:k])
    push_end = push_start + scene.load.segments[k].seconds
    rows = []
    for a in angles_deg:
        s = scene.with_values({f"load.segments[{k}].direction_deg": float(a), "outputs": ["dllm", "camera", "solve"]})
        log(f"[direction] {a:g} deg")
        res = pipeline.run(s, out_dir=None, cache=cache, progress=progress, log=lambda m: None).results
        d, cam, ep = res["dllm"], res["camera"], res["solve"]
        push = push_frames(cam.windows_s, push_start, push_end)
        taxels = pushed_taxels(ep.frames("rod_force_n"), push, d.rod_of_taxel)
        measured, theta, _ = episode_direction(d.features, d.events & push, taxels)
        measured_all, _, _ = episode_direction(d.features, d.events)
        expected = float(approach_deg(a))
        rows.append(DirectionRow(float(a), expected, measured, float(wrap_deg(measured - expected)), int(d.events.sum()), int(len(theta)),
                                 measured_all, float(wrap_deg(measured_all - expected)), int((d.events & push).sum()),
                                 [int(t) for t in taxels], [float(t) for t in theta]))
    if out_dir is not None:
        write(rows, Path(out_dir))
    return rows


def summary(rows: list[DirectionRow]) -> dict:
    """The study's figures: the sign convention, the mean absolute errors of both estimates (None
    where no direction gave events), the directions without events, and the rows."""
    def mean_abs(errors):
        ok = [abs(e) for e in errors if np.isfinite(e)]
        return float(np.mean(ok)) if ok else None

    return {"sign_convention": SIGN_CONVENTION,
            "estimator": "H l-weighted circular mean over the pushed taxels in the push frames",
            "mean_abs_error_deg": mean_abs([r.error_deg for r in rows]),
            "mean_abs_error_all_taxels_deg": mean_abs([r.error_all_deg for r in rows]),
            "episodes_without_events": [r.applied_deg for r in rows if not np.isfinite(r.error_deg)],
            "rows": [r.__dict__ for r in rows]}


def write(rows: list[DirectionRow], out_dir: Path) -> list[Path]:
    """``direction.csv``, ``direction.json`` and ``direction.png`` (box plot of the pushed taxels'
    per-frame directions against the approach bearing, with the episodes' means)."""
    from mlsim.io import atomic_bytes

    out_dir.mkdir(parents=True, exist_ok=True)
    lines = ["applied_deg,approach_deg,measured_deg,error_deg,measured_all_deg,error_all_deg,events,push_events,samples,taxels"] + [
        f"{r.applied_deg:g},{r.approach_deg:g},{r.measured_deg:.3f},{r.error_deg:.3f},{r.measured_all_deg:.3f},{r.error_all_deg:.3f},"
        f"{r.events},{r.push_events},{r.samples},{' '.join(map(str, r.taxels))}" for r in rows]
    figures = summary(rows)
    files = [atomic_bytes(out_dir / "direction.csv", ("\n".join(lines) + "\n").encode()),
             atomic_bytes(out_dir / "direction.json", json.dumps(figures, indent=1, default=float).encode())]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    pos = [r.approach_deg for r in rows]
    data = [r.approach_deg + wrap_deg(np.asarray(r.sample_deg) - r.approach_deg) if r.sample_deg else [np.nan] for r in rows]
    width = 0.6 * (np.min(np.diff(sorted(pos))) if len(pos) > 1 else 10.0)
    ax.boxplot(data, positions=pos, widths=width, showfliers=False, manage_ticks=False)
    ax.plot(pos, [r.approach_deg + r.error_deg for r in rows], "o", color="tab:red", label="pushed taxels, push frames (H l weighted)")
    ax.plot(pos, [r.approach_deg + r.error_all_deg for r in rows], "x", color="tab:grey", label="every firing taxel and event frame")
    lo, hi = min(pos) - 15, max(pos) + 15
    ax.plot([lo, hi], [lo, hi], "k:", label="measured = approach")
    ax.set_xlabel("approach bearing: where the probe comes from (deg) = slide direction + 180")
    ax.set_ylabel("DLLM direction (deg, sensor axes)")
    mae = figures["mean_abs_error_deg"]
    ax.set_title(f"direction test: mean absolute error {mae:.1f} deg" if mae is not None else "direction test: no events", fontsize=10)
    ax.legend(fontsize=8)
    fig.savefig(out_dir / "direction.png", dpi=110)
    plt.close(fig)
    return files + [out_dir / "direction.png"]
