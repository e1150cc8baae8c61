"""The event-driven detector (DLLM, SPEC 1.6): thresholds, gates and features, one frame at a time.

Initialisation: over the first ``init_frames`` frames (1 s at 30 FPS), D = mean of M(t), the sum of
all grey pixel intensities, and B_n = mean of H_n(t), the sum over taxel n's disk. No events then.

Per frame afterwards: if M(t) <= alpha D the frame is discarded (no event, nothing else computed);
otherwise every taxel with H_n(t) > beta B_n gives Z_n = (H_n, l_n, omega_n)
(:mod:`dllm.features`), the others zeros.

Thresholds that follow recent data (the paper says that they do, not how; this rule is ours): after
each frame, with a = 1 - exp(-dt / tau),

- a discarded frame moves D towards M(t) with tau = ``adapt_s`` (1 s) and scales every B_n by the
  same relative change of D (its H_n was not computed; the ambient light that moves D lights the
  disks in proportion);
- an event frame moves D with tau = ``recover_s`` (5 s), each taxel that fired moves B_n towards
  H_n(t) with ``recover_s`` and each that did not with ``adapt_s``.

A press (under a second) barely moves the thresholds, while a lasting change (a lamp switched on)
is absorbed within a few ``recover_s``: the detector fires through the change, then recovers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from dllm.calibration import Calibration, _check_frame, grey
from dllm.features import TaxelIndex, taxel_features, taxel_index, taxel_sums

__all__ = ["DllmParams", "FrameResult", "Dllm", "frame_sum"]


@dataclass(frozen=True)
class DllmParams:
    """alpha (global gate), beta (taxel gate), init_frames (threshold initialisation), fps, and the
    time constants of the threshold update (s)."""

    alpha: float = 1.05
    beta: float = 1.3
    init_frames: int = 30
    fps: float = 30.0
    adapt_s: float = 1.0
    recover_s: float = 5.0

    def __post_init__(self):
        for name in ("alpha", "beta", "fps", "adapt_s", "recover_s"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise ValueError(f"DllmParams.{name} = {v!r}: must be a finite number > 0")
        if not (isinstance(self.init_frames, (int, np.integer)) and self.init_frames >= 1):
            raise ValueError(f"DllmParams.init_frames = {self.init_frames!r}: must be an integer >= 1")

    @classmethod
    def from_scene(cls, scene) -> "DllmParams":
        d = scene.dllm
        return cls(d.alpha, d.beta, max(int(round(d.init_s * scene.camera.fps)), 1), scene.camera.fps, d.adapt_s, d.recover_s)

    def rates(self) -> tuple[float, float]:
        """(a_adapt, a_recover): the per-frame update weights."""
        dt = 1.0 / self.fps
        return 1.0 - math.exp(-dt / self.adapt_s), 1.0 - math.exp(-dt / self.recover_s)


@dataclass
class FrameResult:
    """event (the global gate passed), features Z (N, 3) (zeros without an event), M(t), and the
    taxel sums H (N,) (None when the frame was discarded or still initialising)."""

    event: bool
    features: np.ndarray
    frame_sum: float
    taxel_sums: np.ndarray | None = None
    initialising: bool = False


def frame_sum(grey_frame) -> float:
    """M(t): the sum of all pixel intensities of a grey frame."""
    import cv2

    return float(cv2.sumElems(grey_frame)[0])


@dataclass
class Dllm:
    """The streaming detector: ``step(frame)`` per camera frame (a robot loop), state in between.

    ``counts`` holds frames seen, initialising, discarded and events."""

    calibration: Calibration
    params: DllmParams = field(default_factory=DllmParams)

    def __post_init__(self):
        self.index: TaxelIndex = taxel_index(self.calibration)
        self.a_adapt, self.a_recover = self.params.rates()
        self.reset()

    def reset(self) -> None:
        n = self.calibration.n_taxels
        self.D = 0.0
        self.B = np.zeros(n)
        self._init_M: list[float] = []
        self._init_H: list[np.ndarray] = []
        self.counts = {"frames": 0, "initialising": 0, "discarded": 0, "events": 0}
        self._zeros = np.zeros((n, 3))

    @property
    def ready(self) -> bool:
        return len(self._init_M) >= self.params.init_frames

    def step(self, frame) -> FrameResult:
        f = _check_frame(frame, "frame")
        if f.shape[:2] != tuple(self.calibration.shape_hw):
            raise ValueError(f"frame of {f.shape[:2]} pixels, but the calibration is of {tuple(self.calibration.shape_hw)}: "
                             "calibrate on a frame of this camera")
        g = grey(f)
        M = frame_sum(g)
        self.counts["frames"] += 1
        if not self.ready:
            H, _, _ = taxel_sums(g, self.index)
            self._init_M.append(M)
            self._init_H.append(H)
            self.counts["initialising"] += 1
            if self.ready:
                self.D = float(np.mean(self._init_M))
                self.B = np.mean(self._init_H, axis=0)
            return FrameResult(False, self._zeros.copy(), M, H, initialising=True)
        if M <= self.params.alpha * self.D:
            D_old = self.D
            self.D += (M - self.D) * self.a_adapt
            if D_old > 0:
                self.B *= self.D / D_old
            self.counts["discarded"] += 1
            return FrameResult(False, self._zeros.copy(), M)
        H, Sx, Sy = taxel_sums(g, self.index)
        firing = H > self.params.beta * self.B
        z = taxel_features(H, Sx, Sy, self.index.centres_px, firing)
        self.D += (M - self.D) * self.a_recover
        self.B += (H - self.B) * np.where(firing, self.a_recover, self.a_adapt)
        self.counts["events"] += 1
        return FrameResult(True, z, M, H)

    def run(self, frames) -> tuple[np.ndarray, np.ndarray]:
        """Step through frames (T, H, W[, 3]): (events (T,) bool, features (T, N, 3))."""
        out = [self.step(f) for f in frames]
        return np.array([r.event for r in out], bool), np.stack([r.features for r in out]) if out else np.zeros((0, self.calibration.n_taxels, 3))
