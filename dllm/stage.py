"""The DLLM stage of the ML rod array (``mlsim.ml_rod_array``): the detector of SPEC 1.6 on the
camera's frames."""

from __future__ import annotations

from pathlib import Path

from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage, npz_io

__all__ = ["DLLM", "idle_before"]

_dllm_save, _dllm_load = npz_io("dllm.npz", "dllm.episode:DllmEpisode")


def idle_before(scene: Scene, render_result):
    """The idle frames before the episode on which the DLLM initialises its thresholds (SPEC 1.6)."""
    from dllm.detector import DllmParams
    from mlsim.render.output import idle_frames

    return idle_frames(scene, render_result, DllmParams.from_scene(scene).init_frames)


def _dllm_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from dllm.episode import run_episode

    rgb = inputs["calibration"].rgb
    return run_episode(scene, inputs["camera"], rgb, idle_before(scene, inputs["render"]), calibration=_calibration_of(scene, rgb))


# What the DLLM's calibration reads of a scene besides the calibration frame (dllm.episode.calibrate_scene:
# the grid, Hough's blur and the optics' paraxial rod images)
_CALIBRATION_FIELDS = ("sensor", "camera", "optics", "dllm.blur_sigma_px")


def _calibration_of(scene: Scene, rgb):
    """The Hough calibration of the calibration frame ``rgb`` (H, W, 3), made once per frame and scene
    fields in this process (shared: read only): a dataset's episodes share one calibration frame, and
    its Hough transform cost a few ms per episode."""
    import hashlib

    from dllm.episode import calibrate_scene
    from mlsim.stage import memo

    key = ("dllm_calibration", hashlib.sha256(rgb.tobytes()).hexdigest(), rgb.shape, scene.content_hash(_CALIBRATION_FIELDS))
    return memo(key, lambda: calibrate_scene(scene, rgb))


def _dllm_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from dllm.episode import write

    return write(result, out_dir)


DLLM = Stage(
    name="dllm",
    doc="the DLLM detector (SPEC 1.6) on the camera frames: calibration on the calibration frame, thresholds from 1 s of idle frames; "
        "writes the feature time series, the events table and a taxel heatmap",
    reads=("dllm", "camera", "ambient", "optics", "sensor", "seed", "noise_seed"),
    needs=("camera", "calibration", "render"),
    run=_dllm_run,
    save=_dllm_save,
    load=_dllm_load,
    write=_dllm_write,
    summarize=lambda result: result.summary(),
)
