"""The camera stage and the files of the render and camera stages.

:func:`expose` turns the render stage's mono radiance into 8-bit RGB frames: per-channel photon
radiance = radiance x :func:`mlsim.render.optics.ml_channel_factors`, then :func:`mlsim.camera.capture`
with the scene's camera (one seeded generator for the whole episode: same scene, same bytes).
Frames the renderer skipped are zero radiance: their pixels are the sensor's noise alone.

Files: ``camera.mp4`` (OpenCV, MPEG-4 part 2, at the camera's frame rate), ``frames/frame_NNNN.png``
(lossless, what a dataset should use), ``contact_sheet.png`` (a labelled grid of the episode),
``camera_frames.csv`` (per frame: time, exposure window, whether it was rendered, total intensity,
per rod the photons emitted in the exposure and the mean signal electrons in its disk).
"""

from __future__ import annotations

import io
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from mlsim.render.optics import disk_masks  # noqa: F401  (the camera stage's rod disks; defined with the view)

__all__ = ["CameraFrames", "expose", "idle_frames", "write_camera", "write_render", "render_summary", "contact_sheet", "write_mp4"]


@dataclass
class CameraFrames:
    """frames (F, H, W, 3) uint8 RGB; windows_s (F, 2) exposure windows; rendered (F,) bool;
    rod_photons (F, R) photons emitted per rod in each exposure; rod_signal_e (F, R) mean noiseless
    signal electrons per pixel (R + G + B) in each rod's disk from the ML light, rod_ambient_e (F, R)
    the same from the ambient lamp's leak (zeros without a lamp); lamp_level (F,) the lamp's mean
    relative power in each exposure; fps."""

    frames: np.ndarray
    windows_s: np.ndarray
    rendered: np.ndarray
    rod_photons: np.ndarray
    rod_signal_e: np.ndarray
    fps: float
    rod_ambient_e: np.ndarray | None = None
    lamp_level: np.ndarray | None = None

    def __post_init__(self):
        if self.rod_ambient_e is None:
            self.rod_ambient_e = np.zeros_like(self.rod_signal_e)
        if self.lamp_level is None:
            self.lamp_level = np.zeros(len(self.frames))

    def save(self, path) -> None:
        np.savez(path, frames=self.frames, windows_s=self.windows_s, rendered=self.rendered, rod_photons=self.rod_photons,
                 rod_signal_e=self.rod_signal_e, fps=self.fps, rod_ambient_e=self.rod_ambient_e, lamp_level=self.lamp_level)

    @classmethod
    def load(cls, path) -> "CameraFrames":
        z = np.load(path)
        return cls(z["frames"], z["windows_s"], z["rendered"], z["rod_photons"], z["rod_signal_e"], float(z["fps"]),
                   z["rod_ambient_e"], z["lamp_level"])

    def summary(self) -> dict:
        f = self.frames.astype(np.float64)
        peak_ml = float(self.rod_signal_e.max()) if self.rod_signal_e.size else 0.0
        peak_ambient = float(self.rod_ambient_e.max()) if self.rod_ambient_e.size else 0.0
        return {
            "n_frames": int(len(f)),
            "rendered_frames": int(self.rendered.sum()),
            "max_dn": [int(self.frames[..., c].max()) for c in range(3)],
            "mean_dn_per_frame": [round(float(v), 3) for v in f.mean(axis=(1, 2, 3))],
            "peak_rod_signal_e": peak_ml,
            "peak_rod_ambient_e": peak_ambient,
            # the brightest rod's ambient signal over the brightest rod's ML signal (ISSUE 4: ambient vs a press)
            "ambient_to_ml_peak": peak_ambient / peak_ml if peak_ml > 0 else None,
        }


def noise_seed(scene) -> int:
    """The seed of the camera's noise streams: ``scene.noise_seed``, else ``scene.seed``."""
    return scene.seed if scene.noise_seed is None else scene.noise_seed


def expose(scene, render_result, emission_result, channel_factors=None) -> CameraFrames:
    """The camera stage: 8-bit frames of a :class:`mlsim.render.RenderResult` (module docstring),
    with the ambient lamp's leak (``render_result.ambient``) at its level in each exposure.
    ``channel_factors``: the scene's :func:`mlsim.render.optics.ml_channel_factors` where the caller
    has them (the camera stage takes them from the cache), else computed here."""
    from fem.geometry import RodArray
    from mlsim.camera import Camera
    from mlsim.render.optics import camera_params, ml_channel_factors

    params = camera_params(scene)
    camera = Camera(params)
    k = np.asarray(ml_channel_factors(scene) if channel_factors is None else channel_factors).astype(np.float32)  # electrons per photon, R G B
    rng = np.random.default_rng([noise_seed(scene), 0xCA3E7A])  # the camera's own stream
    rad = render_result.radiance
    F, H, W = rad.shape
    windows = emission_result.windows_s
    ambient, level, k_amb = _ambient_terms(scene, render_result, windows)
    frames = np.empty((F, H, W, 3), np.uint8)
    for f in range(F):
        if ambient is not None and level[f] > 0:
            channels = rad[f][..., None] * k
            channels += (level[f] * ambient)[..., None] * k_amb
            frames[f] = camera(channels, rng, noise=scene.camera.noise)
        else:  # the ML light alone: the Bayer channels formed from the mono radiance (the same bytes, a third of the work)
            frames[f] = camera.mono(rad[f], k, rng, noise=scene.camera.noise)
    g = RodArray.from_sensor(scene.sensor)
    rod_photons = emission_result.per_rod(g.n_rods)[:, : g.n_rods] * (windows[:, 1] - windows[:, 0])[:, None]
    masks, per_radiance_e = rod_masks(scene, H, W)
    rod_signal_e = rod_signal_of(rad, masks, per_radiance_e, k)
    rod_ambient_e = np.zeros_like(rod_signal_e)
    if ambient is not None:
        rod_ambient_e = level[:, None] * ((ambient.reshape(1, -1) @ masks.T) * (float(k_amb.sum()) * per_radiance_e))
    return CameraFrames(frames, windows, render_result.rendered.copy(), rod_photons, rod_signal_e, params.fps, rod_ambient_e, level)


def rod_masks(scene, height_px: int, width_px: int) -> tuple[np.ndarray, np.ndarray]:
    """The rods' paraxial disks as masks (R, H * W) float32 and the electrons per unit radiance
    averaged over each disk (1, R)."""
    from fem.geometry import RodArray
    from mlsim.render.optics import camera_params, rod_disks_px

    n_rods = RodArray.from_sensor(scene.sensor).n_rods
    centres, radius = rod_disks_px(scene)
    masks = disk_masks(height_px, width_px, centres, radius).reshape(n_rods, -1).astype(np.float32)
    return masks, camera_params(scene).electrons_per_radiance_m2_sr_s / masks.sum(axis=1)[None]


def rod_signal_of(radiance: np.ndarray, masks: np.ndarray, per_radiance_e: np.ndarray, k: np.ndarray) -> np.ndarray:
    """(F, R) mean noiseless ML signal per rod (electrons) of radiance (F, H, W) float32, with
    :func:`rod_masks`'s masks and scale and the ML light's channel factors k (3,) float32."""
    F = len(radiance)
    return (radiance.reshape(F, -1) @ masks.T) * (float(k.sum()) * per_radiance_e)


def idle_frames(scene, render_result, n_frames: int, start_s: float | None = None, stream: int = 0) -> np.ndarray:
    """(n_frames, H, W, 3) uint8: camera frames with no ML light, starting at ``start_s`` (default
    -n / fps: the frames just before the episode): sensor noise and the ambient lamp at its level
    then. The DLLM initialises its thresholds on the frames before the episode (SPEC 1.6: 1 s of
    frames before capture). Their own seeded stream per ``stream``."""
    from mlsim.camera import Camera
    from mlsim.render.optics import camera_params

    params = camera_params(scene)
    camera = Camera(params)
    start = -n_frames / params.fps if start_s is None else float(start_s)
    windows = np.asarray(camera.exposure_windows_s(n_frames)) + start
    ambient, level, k_amb = _ambient_terms(scene, render_result, windows)
    H, W = render_result.radiance.shape[1:]
    rng = np.random.default_rng([noise_seed(scene), 0x1D1E, int(stream)])
    out = np.empty((n_frames, H, W, 3), np.uint8)
    for f in range(n_frames):
        if ambient is None or level[f] <= 0:
            out[f] = camera.dark(rng, noise=scene.camera.noise)  # the same bytes as camera(dark, rng), usually without its draws
        else:
            out[f] = camera((level[f] * ambient)[..., None] * k_amb, rng, noise=scene.camera.noise)
    return out


def _ambient_terms(scene, render_result, windows_s):
    """(ambient image (H, W) or None, lamp level per frame (F,), channel factors of the leak (3,))."""
    a = scene.ambient
    level = np.zeros(len(windows_s))
    if render_result.ambient is None or a.lamp == "none":
        return None, level, np.zeros(3, np.float32)
    # imported only with a lamp: the module imports scipy.integrate (0.6 s of a dataset worker's CPU)
    from mlsim.render import ambient
    from mlsim.render.optics import channel_factors_of

    level = ambient.lamp_level(windows_s, a.flicker_hz, a.flicker_depth, a.switch_on_s, a.switch_off_s)
    sd = ambient.leaked_photon_sd(a.lamp, scene.optics.absorber, scene.sensor.layers.absorber_mm)
    return render_result.ambient.astype(np.float32), level, channel_factors_of(scene, sd).astype(np.float32)


# ------------------------------------------------------------------------------------------ files
def write_png(path: Path, rgb: np.ndarray) -> Path:
    """Lossless PNG of an RGB image (H, W, 3) uint8, written atomically."""
    import cv2

    from mlsim.io import atomic_bytes

    ok, data = cv2.imencode(".png", np.ascontiguousarray(rgb[..., ::-1]))
    if not ok:
        raise OSError(f"OpenCV could not encode {path} as PNG")
    return atomic_bytes(Path(path), data.tobytes())


def write_mp4(path: Path, frames: np.ndarray, fps: float) -> Path:
    """MPEG-4 (``mp4v``) video of RGB frames (F, H, W, 3) uint8 with OpenCV, under a temporary name
    with the same suffix (OpenCV picks the container by it), then renamed."""
    import cv2

    path = Path(path)
    F, H, W, _ = frames.shape
    tmp = path.with_name(f".{path.stem}.part{path.suffix}")
    writer = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*"mp4v"), float(fps), (W, H))
    if not writer.isOpened():
        raise OSError(f"OpenCV cannot write MPEG-4 video to {tmp} (no FFmpeg back-end?)")
    for f in range(F):
        writer.write(np.ascontiguousarray(frames[f, :, :, ::-1]))
    writer.release()
    os.replace(tmp, path)
    return path


def contact_sheet(frames: np.ndarray, times_s: np.ndarray, max_tiles: int = 24, columns: int = 6) -> np.ndarray:
    """A labelled grid (RGB uint8) of up to ``max_tiles`` frames spread evenly over the episode."""
    import cv2

    F, H, W, _ = frames.shape
    pick = np.unique(np.round(np.linspace(0, F - 1, min(max_tiles, F))).astype(int))
    cols = min(columns, len(pick))
    rows = -(-len(pick) // cols)
    pad = 4
    sheet = np.full((rows * (H + pad) + pad, cols * (W + pad) + pad, 3), 32, np.uint8)
    for i, f in enumerate(pick):
        r, c = divmod(i, cols)
        y, x = pad + r * (H + pad), pad + c * (W + pad)
        tile = frames[f].copy()
        cv2.putText(tile, f"#{f}  {times_s[f] * 1e3:.0f} ms", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
        sheet[y : y + H, x : x + W] = tile
    return sheet


def write_camera(result: CameraFrames, out_dir: Path) -> list[Path]:
    from mlsim.io import atomic_bytes

    out_dir = Path(out_dir)
    frame_dir = out_dir / "frames"
    frame_dir.mkdir(parents=True, exist_ok=True)
    files = [write_png(frame_dir / f"frame_{f:04d}.png", result.frames[f]) for f in range(len(result.frames))]
    files.append(write_mp4(out_dir / "camera.mp4", result.frames, result.fps))
    files.append(write_png(out_dir / "contact_sheet.png", contact_sheet(result.frames, result.windows_s[:, 0])))
    cols = {
        "frame": np.arange(len(result.frames)),
        "t_s": result.windows_s[:, 0],
        "exposure_end_s": result.windows_s[:, 1],
        "rendered": result.rendered.astype(int),
        "mean_dn": result.frames.astype(np.float64).mean(axis=(1, 2, 3)),
        "sum_dn": result.frames.astype(np.float64).sum(axis=(1, 2, 3)),
    }
    for r in range(result.rod_photons.shape[1]):
        cols[f"rod{r}_photons"] = result.rod_photons[:, r]
    for r in range(result.rod_signal_e.shape[1]):
        cols[f"rod{r}_signal_e"] = result.rod_signal_e[:, r]
    if np.any(result.lamp_level > 0):
        cols["lamp_level"] = result.lamp_level
        for r in range(result.rod_ambient_e.shape[1]):
            cols[f"rod{r}_ambient_e"] = result.rod_ambient_e[:, r]
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    np.savetxt(buf, np.column_stack(list(cols.values())), delimiter=",", fmt="%.9g")
    files.append(atomic_bytes(out_dir / "camera_frames.csv", buf.getvalue().encode()))
    return files


def write_render(result, out_dir: Path) -> list[Path]:
    """``render_radiance.npz`` (float32 radiance per frame) and ``render_peak.png`` (the brightest frame, false colour)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mlsim.plots import save_png

    from mlsim.io import atomic_bytes

    out_dir = Path(out_dir)
    buf = io.BytesIO()
    np.savez_compressed(buf, radiance_photons_s_m2_sr=result.radiance, rendered=result.rendered, tier=result.tier, spp=result.spp)
    npz = atomic_bytes(out_dir / "render_radiance.npz", buf.getvalue())
    f = int(np.argmax(result.radiance.reshape(len(result.radiance), -1).sum(axis=1))) if result.n_frames else 0
    fig, ax = plt.subplots(figsize=(6, 5), constrained_layout=True)
    im = ax.imshow(result.radiance[f], cmap="inferno")
    fig.colorbar(im, ax=ax, label="radiance at the lens (photons s$^{-1}$ m$^{-2}$ sr$^{-1}$)")
    ax.set(title=f"frame {f}, {result.tier} tier", xlabel="column (px)", ylabel="row (px)")
    return [npz, save_png(fig, out_dir / "render_peak.png")]


def render_summary(result) -> dict:
    total = result.radiance.reshape(result.n_frames, -1).sum(axis=1)
    rendered_s = result.frame_seconds[result.rendered]
    return {
        "tier": result.tier,
        "spp": result.spp,
        "n_frames": result.n_frames,
        "rendered_frames": int(result.rendered.sum()),
        "median_seconds_per_rendered_frame": float(np.median(rendered_s)) if rendered_s.size else 0.0,
        "peak_frame": int(np.argmax(total)) if result.n_frames else None,
        **{k: v for k, v in result.info.items()},
    }
