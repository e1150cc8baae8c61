"""The closed robot loop of SPEC 1.7: frames -> streaming DLLM -> CNN on the last 8 frames -> command.

Each camera frame goes through the streaming detector (:class:`dllm.detector.Dllm`, thresholds
initialised on the idle frames before the episode). From the 8th frame on, every ``stride`` frames the
window of the last 8 frames' features goes to the interaction CNN, which gives a class and its robot
command (SPEC 1.7: sliding -> forward, rotation clockwise -> turn right, anticlockwise -> turn left,
push/pull -> toggle bite/release). A window in which no frame passed the DLLM's global gate is
"idle": nothing touched the sensor, so the loop sends no command and does not run the CNN.

Latency: from the arrival of a window's last frame to its prediction, i.e. the detector's work on
that frame plus the CNN on the window, measured on this machine's clock. It is the compute part
of the robot's response time (SPEC 1.7 reference: < 0.7 s end to end on the real robot); exposure,
readout, transfer and the robot's own motion are not simulated.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["LoopResult", "run_loop", "write"]

IDLE = "idle"


@dataclass
class LoopResult:
    """One decision per window. last_frame (M,) the window's last frame; t_end_s (M,) its time;
    classes (M,) class id, -1 when idle; probability (M,) of that class (NaN when idle); names and
    commands (M,) strings; latency_ms (M,) from the last frame's arrival to the prediction."""

    last_frame: np.ndarray
    t_end_s: np.ndarray
    classes: np.ndarray
    probability: np.ndarray
    names: list
    commands: list
    latency_ms: np.ndarray
    n_classes: int
    info: dict = field(default_factory=dict)

    def summary(self) -> dict:
        active = self.classes >= 0
        lat = self.latency_ms
        return {"windows": int(len(self.classes)), "active_windows": int(active.sum()), "n_classes": self.n_classes,
                "predicted": {n: int(sum(1 for m in self.names if m == n)) for n in sorted(set(self.names))},
                "latency_ms_median": float(np.median(lat)) if len(lat) else None,
                "latency_ms_max": float(lat.max()) if len(lat) else None,
                "latency_ms_median_active": float(np.median(lat[active])) if active.any() else None} | self.info


def run_loop(frames: np.ndarray, idle: np.ndarray, calibration, dllm_params, model, fps: float, stride: int = 1) -> LoopResult:
    """Run the loop over camera ``frames`` (T, H, W, 3) uint8 after the ``idle`` frames (n, H, W, 3)
    that initialise the detector. ``model``: a :class:`classifiers.train.TrainResult`."""
    from classifiers.interaction_cnn import predict_proba
    from classifiers.windows import channels, class_names, robot_command
    from dllm.detector import Dllm
    from dllm.features import with_omega_rad

    if stride < 1:
        raise ValueError(f"stride = {stride}: must be >= 1")
    det = Dllm(calibration, dllm_params)
    for f in idle:
        det.step(f)
    if not det.ready:
        raise ValueError(f"{len(idle)} idle frames do not complete the DLLM's threshold initialisation ({det.params.init_frames} frames)")
    net = model.module()
    names_of = class_names(model.n_classes)
    L = model.window
    T = len(frames)
    feats = np.zeros((T, calibration.n_taxels, 3), np.float32)
    events = np.zeros(T, bool)
    out = {"last": [], "cls": [], "p": [], "lat": []}
    for k in range(T):
        t0 = time.perf_counter()
        r = det.step(frames[k])
        feats[k] = with_omega_rad(r.features)
        events[k] = r.event
        if k < L - 1 or (k - (L - 1)) % stride:
            continue
        cls, p = -1, float("nan")
        if events[k - L + 1 : k + 1].any():
            prob = predict_proba(net, model.standardizer.transform(channels(feats[k - L + 1 : k + 1], model.feature_set).T[None]))[0]
            cls, p = int(prob.argmax()), float(prob.max())
        out["lat"].append((time.perf_counter() - t0) * 1e3)
        out["last"].append(k)
        out["cls"].append(cls)
        out["p"].append(p)
    classes = np.array(out["cls"], np.int64)
    names = [names_of[c] if c >= 0 else IDLE for c in classes]
    commands = [robot_command(int(c), model.n_classes) if c >= 0 else "" for c in classes]
    last = np.array(out["last"], np.int64)
    return LoopResult(last, last / fps, classes, np.array(out["p"]), names, commands, np.array(out["lat"]), model.n_classes,
                      {"events": int(events.sum()), "frames": int(T)})


def write(result: LoopResult, out_dir: str | Path) -> list[Path]:
    """``classify.csv``: one row per window (time, class, probability, command, latency)."""
    from mlsim.io import atomic_bytes

    rows = ["last_frame,t_end_s,class_id,class,probability,command,latency_ms"]
    for i in range(len(result.classes)):
        rows.append(f"{result.last_frame[i]},{result.t_end_s[i]:.6f},{result.classes[i]},{result.names[i]},{result.probability[i]:.6g},"
                    f"{result.commands[i]},{result.latency_ms[i]:.4f}")
    path = Path(out_dir) / "classify.csv"
    return [atomic_bytes(path, ("\n".join(rows) + "\n").encode())]
