"""The DLLM over a simulated episode: calibrate on the calibration frame, initialise the thresholds
on 1 s of idle frames before the episode, run the detector on every camera frame (the pipeline's
``dllm`` stage), and write the feature time series, the events table and the taxel heatmap."""

from __future__ import annotations

import ast
import io
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from dllm.calibration import Calibration
from dllm.features import FEATURES

__all__ = ["DllmEpisode", "calibrate_scene", "detect", "run_episode", "write", "plot_heatmap"]


@dataclass
class DllmEpisode:
    """times_s (T,) frame starts; events (T,) bool; features (T, N, 3) (H, l px, omega deg); the
    calibration (taxels numbered row-major in the image); rod_of_taxel (N,) the sensor's rod each
    taxel sees (the nearest paraxial rod image: the camera looks up, so the image is mirrored);
    counts (frames, initialising, discarded, events); idle frames run before t = 0."""

    times_s: np.ndarray
    events: np.ndarray
    features: np.ndarray
    calibration: Calibration
    rod_of_taxel: np.ndarray
    counts: dict = field(default_factory=dict)
    idle_frames: int = 0

    def save(self, path) -> None:
        np.savez(path, times_s=self.times_s, events=self.events, features=self.features, rod_of_taxel=self.rod_of_taxel,
                 centres_px=self.calibration.centres_px,
                 radius_px=self.calibration.radius_px, shape_hw=np.array(self.calibration.shape_hw), counts=np.array(repr(self.counts)),
                 idle_frames=self.idle_frames)

    @classmethod
    def load(cls, path) -> "DllmEpisode":
        z = np.load(path)
        cal = Calibration(z["centres_px"], float(z["radius_px"]), tuple(int(v) for v in z["shape_hw"]))
        return cls(z["times_s"], z["events"], z["features"], cal, z["rod_of_taxel"], ast.literal_eval(str(z["counts"])), int(z["idle_frames"]))

    def summary(self) -> dict:
        fired = self.features[..., 0] > 0
        return {"frames": int(len(self.events)), "events": int(self.events.sum()), "idle_frames_before": self.idle_frames,
                "taxels_fired": int(fired.any(axis=0).sum()), "max_taxels_in_a_frame": int(fired.sum(axis=1).max()) if len(fired) else 0,
                "calibration_radius_px": round(self.calibration.radius_px, 3), "counts": dict(self.counts)}


def calibrate_scene(scene, calibration_rgb, debug_path=None) -> tuple[Calibration, np.ndarray]:
    """(the calibration of a scene's calibration frame (H, W, 3), with Hough's parameters from the
    optics' paraxial rod images; the rod each taxel sees (N,), the nearest of those images).
    ``debug_path``: where the overlay of the circles found is written (:func:`dllm.calibration.calibrate`)."""
    from dllm.calibration import calibrate, hough_params_for
    from mlsim.render import rod_disks_px

    g = scene.sensor
    expected = rod_disks_px(scene)
    cal = calibrate(calibration_rgb, g.rows, g.cols, hough_params_for(calibration_rgb.shape[:2], g.rows, g.cols, scene.dllm.blur_sigma_px,
                                                                      expected=expected), debug_path=debug_path)
    return cal, np.linalg.norm(cal.centres_px[:, None] - expected[0][None], axis=2).argmin(axis=1)


def detect(calibration: Calibration, params, idle, frames):
    """The streaming detector from a fresh state: its threshold initialisation on the ``idle``
    frames (n, H, W, 3), then ``frames`` -> (events (T,), features (T, N, 3), counts)."""
    from dllm.detector import Dllm

    det = Dllm(calibration, params)
    for f in idle:
        det.step(f)
    if not det.ready:
        raise ValueError(f"{len(idle)} idle frames do not complete the threshold initialisation ({det.params.init_frames} frames)")
    events, features = det.run(frames)
    return events, features, dict(det.counts)


def run_episode(scene, camera_frames, calibration_rgb, idle, calibration: tuple | None = None) -> DllmEpisode:
    """Calibrate on ``calibration_rgb`` (H, W, 3), then run the streaming detector on the ``idle``
    frames (n, H, W, 3) (its threshold initialisation) and on ``camera_frames`` (a
    :class:`mlsim.render.output.CameraFrames`). ``calibration``: :func:`calibrate_scene`'s result
    for this frame and scene when the caller already has it."""
    from dllm.detector import DllmParams

    cal, rod_of_taxel = calibrate_scene(scene, calibration_rgb) if calibration is None else calibration
    events, features, counts = detect(cal, DllmParams.from_scene(scene), idle, camera_frames.frames)
    return DllmEpisode(camera_frames.windows_s[:, 0].copy(), events, features, cal, rod_of_taxel, counts, len(idle))


def write(result: DllmEpisode, out_dir: Path) -> list[Path]:
    """``dllm_features.csv`` (a row per frame: time, event, then H, l and omega of every taxel),
    ``dllm_events.csv`` (a row per event: the taxels that fired and their summed H), the calibration
    (``dllm_calibration.json``), the taxel-to-rod table (``dllm_taxels.csv``) and ``dllm_heatmap.png``."""
    from mlsim.io import atomic_bytes

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    T, N, _ = result.features.shape
    header = ["frame", "t_s", "event"] + [f"taxel{n}_{name}" for n in range(N) for name in FEATURES]
    table = np.column_stack([np.arange(T), result.times_s, result.events.astype(int), result.features.reshape(T, -1)])
    buf = io.StringIO()
    buf.write(",".join(header) + "\n")
    np.savetxt(buf, table, delimiter=",", fmt="%.9g")
    files = [atomic_bytes(out_dir / "dllm_features.csv", buf.getvalue().encode())]
    buf = io.StringIO()
    buf.write("frame,t_s,n_taxels,taxels,sum_H\n")
    for f in np.flatnonzero(result.events):
        fired = np.flatnonzero(result.features[f, :, 0] > 0)
        buf.write(f"{f},{result.times_s[f]:.6f},{len(fired)},{' '.join(map(str, fired))},{result.features[f, fired, 0].sum():.9g}\n")
    files.append(atomic_bytes(out_dir / "dllm_events.csv", buf.getvalue().encode()))
    files.append(result.calibration.save(out_dir / "dllm_calibration.json"))
    buf = io.StringIO()
    buf.write("taxel,rod,centre_col_px,centre_row_px\n")
    for n, (c, r) in enumerate(zip(result.calibration.centres_px, result.rod_of_taxel)):
        buf.write(f"{n},{r},{c[0]:.2f},{c[1]:.2f}\n")
    files.append(atomic_bytes(out_dir / "dllm_taxels.csv", buf.getvalue().encode()))
    files.append(plot_heatmap(result, out_dir / "dllm_heatmap.png"))
    return files


def plot_heatmap(result: DllmEpisode, path: Path) -> Path:
    """Per taxel, on the sensor's grid: the summed intensity H over the episode (colour) and the
    direction of its light's offset at its brightest frame (arrow, length l); beside it, the number
    of firing taxels per frame."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cal = result.calibration
    H = result.features[..., 0]
    total = H.sum(axis=0)
    fig, (ax, ax2) = plt.subplots(1, 2, figsize=(10, 4.4), constrained_layout=True, gridspec_kw={"width_ratios": [1.1, 1]})
    c = cal.centres_px
    sc = ax.scatter(c[:, 0], c[:, 1], c=total, s=(cal.radius_px * 2.2) ** 2, cmap="viridis", marker="o", edgecolors="k")
    peak = H.argmax(axis=0)
    for n in np.flatnonzero(total > 0):
        l, w = result.features[peak[n], n, 1], np.radians(result.features[peak[n], n, 2])
        scale = cal.radius_px / max(result.features[..., 1].max(), 1e-9)
        ax.arrow(c[n, 0], c[n, 1], scale * l * np.cos(w), -scale * l * np.sin(w), color="w", width=0.6, head_width=4, length_includes_head=True)
    ax.set_xlim(0, cal.shape_hw[1])
    ax.set_ylim(cal.shape_hw[0], 0)
    ax.set_aspect("equal")
    ax.set_title("DLLM taxels: summed H (colour), offset at the peak (arrow)", fontsize=9)
    fig.colorbar(sc, ax=ax, label="sum of H over the episode (grey levels)")
    ax2.step(result.times_s, (H > 0).sum(axis=1), where="post")
    ax2.set_xlabel("time (s)")
    ax2.set_ylabel("taxels firing")
    ax2.set_title(f"{int(result.events.sum())} event frames of {len(result.events)}", fontsize=9)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
