"""The direction study (SPEC 1.5): the DLLM's angle against the direction a rod pushes the sensor.

For each applied direction theta (the scene's slide segment, ``direction_deg``) the scene runs through
FEM, light, camera and DLLM (:mod:`mlsim.pipeline`, so meshes and transport matrices are shared).
Each taxel that fires in an event frame gives one measured direction: its light's offset omega
(:mod:`dllm.features`, image axes) turned into the sensor's axes. The camera looks up through the
base, so the image is the sensor seen from below: image +x is sensor -x and image up is sensor +y,
hence theta_measured = 180 deg - omega. The episode's measured direction is the circular mean of
those, weighted by H l (bright, clearly offset taxels count most), and its error the wrapped
difference to theta.

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

__all__ = ["DirectionRow", "sensor_angle_deg", "episode_direction", "direction_study", "wrap_deg"]


def wrap_deg(a):
    """Angles to (-180, 180]."""
    return 180.0 - (180.0 - np.asarray(a, dtype=float)) % 360.0


def sensor_angle_deg(omega_image_deg):
    """The DLLM's image angle (from image +x towards image up) in the sensor's axes seen from above:
    180 - omega (the camera sees the sensor from below, mirrored), in [0, 360)."""
    return (180.0 - np.asarray(omega_image_deg, dtype=float)) % 360.0


def episode_direction(features, events) -> tuple[float, np.ndarray, np.ndarray]:
    """(the H l-weighted circular mean direction in sensor degrees, and the per-sample directions
    and weights) over the firing taxels of the event frames; NaN when nothing fired."""
    f = np.asarray(features)[np.asarray(events, bool)]
    fired = f[..., 0] > 0
    H, l, omega = f[..., 0][fired], f[..., 1][fired], f[..., 2][fired]
    theta = sensor_angle_deg(omega)
    w = H * l
    if not len(w) or w.sum() <= 0:
        return float("nan"), theta, w
    z = np.sum(w * np.exp(1j * np.radians(theta)))
    return float(np.degrees(np.angle(z)) % 360.0), theta, w


@dataclass
class DirectionRow:
    applied_deg: float
    measured_deg: float
    error_deg: float
    events: int
    samples: int
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
    rows = []
    for a in angles_deg:
        s = scene.with_values({f"load.segments[{slides[0]}].direction_deg": float(a), "outputs": ["dllm"]})
        log(f"[direction] {a:g} deg")
        d = pipeline.run(s, out_dir=None, cache=cache, progress=progress, log=lambda m: None).results["dllm"]
        measured, theta, w = episode_direction(d.features, d.events)
        rows.append(DirectionRow(float(a), measured, float(wrap_deg(measured - a)), int(d.events.sum()), int(len(theta)),
                                 [float(t) for t in theta]))
    if out_dir is not None:
        write(rows, Path(out_dir))
    return rows


def write(rows: list[DirectionRow], out_dir: Path) -> list[Path]:
    """``direction.csv``, ``direction.json`` and ``direction.png`` (box plot of the per-taxel
    measured directions against the applied one, with the episodes' means)."""
    from mlsim.io import atomic_bytes

    out_dir.mkdir(parents=True, exist_ok=True)
    lines = ["applied_deg,measured_deg,error_deg,events,samples"] + [
        f"{r.applied_deg:g},{r.measured_deg:.3f},{r.error_deg:.3f},{r.events},{r.samples}" for r in rows]
    ok = [r for r in rows if np.isfinite(r.error_deg)]
    summary = {"mean_abs_error_deg": float(np.mean([abs(r.error_deg) for r in ok])) if ok else None,
               "episodes_without_events": [r.applied_deg for r in rows if not np.isfinite(r.error_deg)],
               "rows": [r.__dict__ for r in rows]}
    files = [atomic_bytes(out_dir / "direction.csv", ("\n".join(lines) + "\n").encode()),
             atomic_bytes(out_dir / "direction.json", json.dumps(summary, indent=1, default=float).encode())]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 5), constrained_layout=True)
    data = [r.applied_deg + wrap_deg(np.asarray(r.sample_deg) - r.applied_deg) if r.sample_deg else [np.nan] for r in rows]
    pos = [r.applied_deg for r in rows]
    width = 0.6 * (np.min(np.diff(sorted(pos))) if len(pos) > 1 else 10.0)
    ax.boxplot(data, positions=pos, widths=width, showfliers=False, manage_ticks=False)
    ax.plot(pos, [r.applied_deg + r.error_deg for r in rows], "o", color="tab:red", label="episode mean (H l weighted)")
    lo, hi = min(pos) - 15, max(pos) + 15
    ax.plot([lo, hi], [lo, hi], "k:", label="measured = applied")
    ax.set_xlabel("applied direction (deg)")
    ax.set_ylabel("DLLM direction (deg, sensor axes)")
    mae = summary["mean_abs_error_deg"]
    ax.set_title(f"direction test: mean absolute error {mae:.1f} deg" if mae is not None else "direction test: no events", fontsize=10)
    ax.legend(fontsize=8)
    fig.savefig(out_dir / "direction.png", dpi=110)
    plt.close(fig)
    return files + [out_dir / "direction.png"]
