"""The classify stage of the ML rod array (``mlsim.ml_rod_array``): the closed robot loop of SPEC 1.7."""

from __future__ import annotations

from pathlib import Path

from dllm.stage import idle_before
from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage

__all__ = ["CLASSIFY"]


def _classify_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from classifiers.closed_loop import run_loop
    from classifiers.train import load_model
    from dllm.detector import DllmParams
    from dllm.episode import calibrate_scene

    model = load_model(scene.classify.model)
    calibration, _ = calibrate_scene(scene, inputs["calibration"].rgb)
    idle = idle_before(scene, inputs["render"])
    result = run_loop(inputs["camera"].frames, idle, calibration, DllmParams.from_scene(scene), model, scene.camera.fps, scene.classify.stride)
    for i in range(len(result.classes)):
        if result.classes[i] >= 0:
            ctx.log(f"[classify] t = {result.t_end_s[i]:6.3f} s  {result.names[i]:<14} p {result.probability[i]:.2f}  -> "
                    f"{result.commands[i]:<12} latency {result.latency_ms[i]:.2f} ms")
    s = result.summary()
    ctx.log(f"[classify] {s['active_windows']} of {s['windows']} windows active (the others idle: no DLLM event); "
            f"latency median {s['latency_ms_median']:.2f} ms, max {s['latency_ms_max']:.2f} ms from a window's last frame to its prediction")
    return result


def _classify_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from classifiers.closed_loop import write

    return write(result, out_dir)


CLASSIFY = Stage(
    name="classify",
    doc="the closed robot loop (SPEC 1.7): the streaming DLLM and the interaction CNN on the last 8 frames; prints a class and a "
        "robot command per window and the latency to each prediction; writes classify.csv (not cached: the model file may change)",
    reads=("classify", "dllm", "camera", "ambient", "optics", "sensor", "seed", "noise_seed"),
    needs=("camera", "calibration", "render"),
    run=_classify_run,
    write=_classify_write,
    summarize=lambda result: result.summary(),
)
