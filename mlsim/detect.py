"""``mlsim detect``: a recording of a real (or simulated) sensor through the same DLLM and CNN as a
simulated run (DESIGN "Real sensors", SPEC 1.6-1.7).

Inputs:

- the recording: a video (MP4, AVI, MKV, MOV: decoded by OpenCV's FFmpeg back-end) or a folder of
  PNG/JPEG frames (read in natural name order: ``frame_2`` before ``frame_10``), 8-bit RGB;
- the calibration photo (SPEC 1.6: the sensor without its absorbing layer under a lamp), from the
  same camera at the same resolution: Hough finds rows x cols disks on it (:func:`dllm.calibration.calibrate`);
- optionally the scene of the sensor (``--scene``): its grid, its DLLM thresholds and, when the photo
  has the scene's resolution, its optics' paraxial disks to tune Hough (what a simulated run does,
  :func:`dllm.episode.calibrate_scene`); without it, SPEC 1.6's 5 x 5 grid and the default thresholds.

Threshold initialisation (SPEC 1.6: 1 s of frames before capture): the first ``init_frames``
frames of the recording (``--idle VIDEO``: of that recording instead) must be idle. An idle frame
is one whose summed grey level M stays within alpha of the darkest of those frames (the DLLM's
own global gate; the ML light only adds to a frame, so the darkest is idle): a recording that starts while the sensor glows, or that is shorter than 1 s, is
refused with the frame where the light starts, rather than initialising thresholds on a press.
The frames after them are the episode (t = 0 at the first); with ``--idle`` every frame of the
recording is.

Outputs (``dllm.episode.write``, the files of a simulated run's ``dllm`` stage): ``dllm_features.csv``,
``dllm_events.csv``, ``dllm_calibration.json``, ``dllm_taxels.csv``, ``dllm_heatmap.png``; with
``--model``, ``classify.csv`` (the closed loop of SPEC 1.7, :mod:`classifiers.closed_loop`);
``detect.json`` (inputs, frame rate, counts, the idle check). Frames are decoded one at a time (a
long recording does not fill memory), except with ``--model``, whose loop takes the episode whole.

Bad input is a :class:`RecordingError` (the CLI's exit 2): an unreadable file, a frame whose size
differs from the calibration photo's, a calibration photo without rows x cols circles (the overlay
of what Hough found is written as ``calibration_overlay.png``), too few idle frames.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from mlsim.errors import Problem, SceneError

__all__ = ["RecordingError", "Recording", "plan_detect", "run_command", "open_recording", "read_image", "idle_run", "detect_recording", "VIDEO_SUFFIXES",
           "IMAGE_SUFFIXES"]

VIDEO_SUFFIXES = (".mp4", ".avi", ".mkv", ".mov")
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg")


class RecordingError(SceneError):
    """Bad input to ``mlsim detect`` / ``mlsim calibrate`` (exit code 2): the argument, the value and the fix."""

    def __init__(self, argument: str, value, fix: str):
        super().__init__([Problem(argument, value, fix)])
        ValueError.__init__(self, f"invalid input: {Problem(argument, value, fix)}")


def read_image(path, argument: str = "--calibration") -> np.ndarray:
    """(H, W, 3) uint8 RGB of a PNG/JPEG file (grey images are repeated over the channels)."""
    import cv2

    path = Path(path)
    if not path.is_file():
        raise RecordingError(argument, str(path), "no such file")
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if img is None:
        raise RecordingError(argument, str(path), "not an image OpenCV can read; give a PNG or JPEG file")
    return np.ascontiguousarray(img[..., ::-1])


def _natural_key(name: str):
    return [int(t) if t.isdigit() else t.lower() for t in re.split(r"(\d+)", name)]


@dataclass
class Recording:
    """A video file or a folder of frames: ``frames()`` yields (H, W, 3) uint8 RGB in order; ``fps``
    from the container (None for a folder or a video that does not say); ``n_frames`` as the
    container states it (a video's count may be approximate; None where unknown)."""

    path: Path
    kind: str  # "video" or "folder"
    fps: float | None
    n_frames: int | None
    shape_hw: tuple[int, int]
    files: tuple[Path, ...] = ()

    def frames(self) -> Iterator[np.ndarray]:
        if self.kind == "folder":
            for k, f in enumerate(self.files):
                img = read_image(f, "RECORDING")
                if img.shape[:2] != self.shape_hw:
                    raise RecordingError("RECORDING", str(f), f"frame {k} is {img.shape[1]} x {img.shape[0]} px, the first "
                                                            f"{self.shape_hw[1]} x {self.shape_hw[0]}: every frame must have one size")
                yield img
            return
        import cv2

        cap = cv2.VideoCapture(str(self.path))
        try:
            while True:
                ok, bgr = cap.read()
                if not ok:
                    return
                yield np.ascontiguousarray(bgr[..., ::-1])
        finally:
            cap.release()


def open_recording(path, argument: str = "RECORDING") -> Recording:
    """A :class:`Recording` of a video file or a folder of PNG/JPEG frames; a :class:`RecordingError`
    when it is missing, empty or cannot be decoded (its first frame is read to check)."""
    path = Path(path)
    if path.is_dir():
        files = tuple(sorted((f for f in path.iterdir() if f.is_file() and f.suffix.lower() in IMAGE_SUFFIXES),
                             key=lambda f: _natural_key(f.name)))
        if not files:
            raise RecordingError(argument, str(path), f"a folder without frames: put the frames there as {', '.join(IMAGE_SUFFIXES)} files")
        first = read_image(files[0], argument)
        return Recording(path, "folder", None, len(files), first.shape[:2], files)
    if not path.is_file():
        raise RecordingError(argument, str(path), "no such file or folder")
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise RecordingError(argument, str(path), f"not a video ({', '.join(VIDEO_SUFFIXES)}) or a folder of frames")
    import cv2

    cap = cv2.VideoCapture(str(path))
    try:
        ok, bgr = cap.read() if cap.isOpened() else (False, None)
        if not ok:
            raise RecordingError(argument, str(path), "OpenCV cannot decode this video (damaged, or a codec its FFmpeg lacks); "
                                                      "re-encode it, e.g. ffmpeg -i IN -c:v libx264 -crf 10 OUT.mp4, or export its frames as PNG")
        fps = float(cap.get(cv2.CAP_PROP_FPS)) or None
        count = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
    finally:
        cap.release()
    return Recording(path, "video", fps if fps and np.isfinite(fps) and fps > 0 else None, count if count > 0 else None, bgr.shape[:2])


def idle_run(frame_sums, alpha: float) -> int:
    """How many leading frames are idle: the run of frames from the first whose summed grey level M
    stays within ``alpha`` times the smallest M of ``frame_sums`` (module docstring).

    frame_sums: (n,) M(t) of the first n frames. Returns an int in [0, n]."""
    m = np.asarray(frame_sums, dtype=np.float64)
    if len(m) == 0:
        return 0
    bright = np.flatnonzero(m > alpha * m.min())
    return int(bright[0]) if len(bright) else len(m)


def _check_shape(frame: np.ndarray, shape_hw, where: str, k: int, photo: str) -> None:
    if frame.shape[:2] != tuple(shape_hw):
        raise RecordingError(where, f"frame {k}: {frame.shape[1]} x {frame.shape[0]} px",
                             f"the calibration photo {photo} is {shape_hw[1]} x {shape_hw[0]} px: take the photo with the same camera "
                             "at the recording's resolution (and crop)")


def _calibrate(photo: np.ndarray, photo_path: str, scene, out_dir: Path, use_optics: bool):
    """(Calibration, rod_of_taxel) of the photo, through the scene's optics when ``use_optics`` and
    the photo has the scene's resolution (what the simulated run does), else through Hough's generic
    defaults (a real camera's optics are not the scene's)."""
    from dllm.calibration import CalibrationError, calibrate, hough_params_for
    from dllm.episode import calibrate_scene
    from mlsim.render import rod_disks_px

    overlay = out_dir / "calibration_overlay.png"
    same_view = photo.shape[:2] == (scene.camera.height_px, scene.camera.width_px)
    use_optics = use_optics and same_view
    view = scene if same_view else scene.with_values({"camera.width_px": photo.shape[1], "camera.height_px": photo.shape[0]})
    try:
        if use_optics:
            return calibrate_scene(scene, photo, debug_path=overlay)
        g = scene.sensor
        cal = calibrate(photo, g.rows, g.cols, hough_params_for(photo.shape[:2], g.rows, g.cols, scene.dllm.blur_sigma_px),
                        debug_path=overlay)
    except CalibrationError as exc:
        # the error names the overlay it wrote; say where it would be only when it did not
        why = str(exc) if exc.debug_image else f"{exc} (overlay of the circles found: {overlay})"
        raise RecordingError("--calibration", photo_path, why) from None
    # the rod each taxel sees: the nearest paraxial rod image of the default optics at the photo's size
    # (the camera looks up, so the image is mirrored; the scale does not change which rod is nearest)
    expected, _ = rod_disks_px(view)
    centred = lambda c: (c - c.mean(axis=0)) / max(np.ptp(c, axis=0).max(), 1e-9)  # noqa: E731
    return cal, np.linalg.norm(centred(cal.centres_px)[:, None] - centred(expected)[None], axis=2).argmin(axis=1)


def detect_recording(recording, calibration_photo, out_dir, *, scene=None, idle=None, fps: float | None = None, model=None,
                     use_optics: bool | None = None, progress: bool = True, log: Callable[[str], None] = print) -> dict:
    """Run the DLLM (and the CNN with ``model``) on a recording; write the files (module docstring)
    into ``out_dir``; returns the summary written to ``detect.json``.

    recording, idle: paths (video or folder). calibration_photo: a path. scene: a
    :class:`mlsim.scene.Scene` (None: the defaults). fps: frames per second of the recording (None:
    the container's, else the scene's camera). model: a path to a ``mlsim train`` model. use_optics:
    tune Hough by the scene's optics (None: when a scene is given)."""
    from tqdm.auto import tqdm

    from dllm.calibration import grey
    from dllm.detector import Dllm, DllmParams, frame_sum
    from dllm.episode import DllmEpisode, write
    from mlsim.io import atomic_bytes
    from mlsim.scene import Scene

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    use_optics = scene is not None if use_optics is None else use_optics
    scene = scene if scene is not None else Scene()
    rec, idle_rec, fps, fps_from = _open_inputs(recording, idle, fps, scene)
    params = DllmParams.from_scene(scene.with_values({"camera.fps": fps}))
    model_result = _load_model(model) if model is not None else None
    photo = read_image(calibration_photo)
    cal, rod_of_taxel = _calibrate(photo, str(calibration_photo), scene, out_dir, use_optics)
    log(f"[detect] calibration: {cal.n_taxels} disks of radius {cal.radius_px:.2f} px on {calibration_photo}")

    # the idle frames: the first init_frames of --idle, or of the recording
    n_init = params.init_frames
    source = idle_rec or rec
    where = "--idle" if idle_rec else "RECORDING"
    stream = source.frames()
    idle_frames = []
    for k, f in zip(range(n_init), stream):
        _check_shape(f, cal.shape_hw, where, k, str(calibration_photo))
        idle_frames.append(f)
    sums = [frame_sum(grey(f)) for f in idle_frames]
    n_idle = idle_run(sums, params.alpha)
    if len(idle_frames) < n_init or n_idle < n_init:
        why = (f"it has {len(idle_frames)} frames" if len(idle_frames) < n_init else
               f"frame {n_idle} is {sums[n_idle] / min(sums):.3f} x the darkest of the first {n_init} (over alpha = "
               f"{params.alpha:g}): the sensor glows before the threshold initialisation ends")
        raise RecordingError(where, str(source.path), f"too few idle frames: the DLLM initialises its thresholds on the first "
                                                     f"{n_init} frames ({n_init / fps:g} s at {fps:g} FPS, SPEC 1.6), but {why}; start "
                                                     "the recording a second before touching the sensor, or give an idle recording with --idle")
    if idle_rec is not None:
        stream = rec.frames()

    det = Dllm(cal, params)
    for f in idle_frames:
        det.step(f)
    total = None if rec.n_frames is None else rec.n_frames - (0 if idle_rec else n_init)
    events, features = [], []
    kept = [] if model_result is not None else None  # the CNN's loop takes the episode whole
    bar = tqdm(stream, total=total, unit="frame", desc=f"detect {rec.path.name}", disable=None if progress else True)
    for k, f in enumerate(bar):
        _check_shape(f, cal.shape_hw, "RECORDING", k + (0 if idle_rec else n_init), str(calibration_photo))
        r = det.step(f)
        events.append(r.event)
        features.append(r.features)
        if kept is not None:
            kept.append(f)
    bar.close()
    T = len(events)
    if T == 0:
        raise RecordingError("RECORDING", str(rec.path), f"no frames after the {n_init} idle ones: record the interaction too")
    episode = DllmEpisode(np.arange(T) / fps, np.array(events, bool), np.stack(features), cal, np.asarray(rod_of_taxel), dict(det.counts), n_init)
    files = write(episode, out_dir)
    summary = {"recording": str(rec.path), "kind": rec.kind, "calibration_photo": str(calibration_photo),
               "idle": str(idle_rec.path) if idle_rec else "the recording's first frames", "fps": fps,
               "fps_from": fps_from,
               "idle_frames": n_init, "idle_brightness_spread": float(np.ptp(sums) / min(sums)) if min(sums) > 0 else None,
               "dllm": {"alpha": params.alpha, "beta": params.beta, "init_frames": n_init}} | episode.summary()
    if model_result is not None:
        from classifiers.closed_loop import run_loop, write as write_loop

        loop = run_loop(np.stack(kept), np.stack(idle_frames), cal, params, model_result, fps, scene.classify.stride)
        files += write_loop(loop, out_dir)
        summary["classify"] = loop.summary()
    files.append(atomic_bytes(out_dir / "detect.json", (json.dumps(summary, indent=2, default=_jsonable) + "\n").encode()))
    summary["files"] = [str(f) for f in files]
    return summary


def _load_model(path):
    from classifiers.train import load_model

    if not Path(path).is_file():
        raise RecordingError("--model", str(path), "no such model file; train one with 'mlsim train DATASET --out DIR'")
    try:
        return load_model(path)
    except Exception as exc:  # a file that is not a model of mlsim train: torch's or our own loader's complaint
        raise RecordingError("--model", str(path), f"not a model of 'mlsim train' ({type(exc).__name__}: {exc})") from None


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    raise TypeError(f"cannot write {type(value).__name__} to JSON")


# ------------------------------------------------------------------------------ the command line
# (the parser is declared in mlsim.cli through the grammar's verb() helper: RECORDING, --calibration,
# --scene, --idle, --fps, --model and the shared --set, --dry-run, --out, --quiet)
def _open_inputs(recording, idle, fps: float | None, scene):
    """(recording, idle recording or None, frame rate, where the rate came from): the rate from --fps, else
    the container, else the scene's camera; a rate that is not a number > 0 refused naming --fps."""
    rec = open_recording(recording)
    idle_rec = open_recording(idle, "--idle") if idle is not None else None
    if fps is not None and not (np.isfinite(fps) and fps > 0):
        raise RecordingError("--fps", fps, "must be a number > 0")
    fps_from = "--fps" if fps is not None else ("the container" if rec.fps else "the scene's camera")
    return rec, idle_rec, float(fps or rec.fps or scene.camera.fps), fps_from


def plan_detect(recording, calibration_photo, out_dir, *, scene=None, idle=None, fps: float | None = None, model=None) -> str:
    """``mlsim detect --dry-run``: the inputs checked as far as reading them costs nothing (each
    recording's first frame, the photo, the sizes, the model file's presence), the frame rate, the
    idle frames and the files it would write; runs neither Hough nor the DLLM. Bad input raises
    :class:`RecordingError` as the run would."""
    from dllm.detector import DllmParams
    from mlsim.scene import Scene

    scene = scene if scene is not None else Scene()
    rec, idle_rec, fps, fps_from = _open_inputs(recording, idle, fps, scene)
    photo = read_image(calibration_photo)
    for where, r in (("RECORDING", rec), ("--idle", idle_rec)):
        if r is not None and r.shape_hw != photo.shape[:2]:
            _check_shape(np.empty(r.shape_hw + (3,), np.uint8), photo.shape[:2], where, 0, str(calibration_photo))
    if model is not None and not Path(model).is_file():
        raise RecordingError("--model", str(model), "no such model file; train one with 'mlsim train DATASET --out DIR'")
    n_init = DllmParams.from_scene(scene.with_values({"camera.fps": fps})).init_frames
    count = "an unknown number of" if rec.n_frames is None else str(rec.n_frames)
    files = ["dllm_features.csv", "dllm_events.csv", "dllm_calibration.json", "dllm_taxels.csv", "dllm_heatmap.png", "detect.json"]
    return "\n".join([
        f"detect (dry run): {rec.kind} {rec.path}: {count} frames of {rec.shape_hw[1]} x {rec.shape_hw[0]} px at {fps:g} FPS (from {fps_from})",
        f"  calibration photo {calibration_photo}: {photo.shape[1]} x {photo.shape[0]} px, Hough for {scene.sensor.rows} x {scene.sensor.cols} disks",
        f"  thresholds from the first {n_init} frames of " + (f"--idle {idle_rec.path}" if idle_rec else "the recording") + " (they must be idle)",
        f"  would write {', '.join(files + (['classify.csv'] if model is not None else []))} in {out_dir}",
        "  nothing run"])


def run_command(args, scene) -> int:
    """``mlsim detect`` with its arguments parsed and its scene loaded (:func:`mlsim.cli.cmd_detect`)."""
    import sys

    out = Path(args.out) if args.out else Path("out") / f"detect_{Path(args.recording).stem}"
    if args.dry_run:
        print(plan_detect(args.recording, args.calibration, out, scene=scene, idle=args.idle, fps=args.fps, model=args.model))
        return 0
    log = (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))
    s = detect_recording(args.recording, args.calibration, out, scene=scene, idle=args.idle, fps=args.fps, model=args.model,
                         use_optics=bool(args.scene), progress=not args.quiet, log=log)
    print(f"{s['frames']} frames at {s['fps']:g} FPS after {s['idle_frames']} idle ones: {s['events']} event frames, "
          f"{s['taxels_fired']} taxels fired")
    if "classify" in s:
        c = s["classify"]
        print(f"classifier: {c['active_windows']} of {c['windows']} windows active; predicted {c['predicted']}")
    print(f"wrote {', '.join(Path(f).name for f in s['files'])} in {out}")
    return 0
