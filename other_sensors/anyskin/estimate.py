"""SPEC 2's estimator on the helmet's 20 channels, and its force estimates with and without re-baselining.

:class:`Estimator` is the whole causal pipeline: the stream's door (:mod:`.stream`), the filters,
slope windows, detector, contact state machine and re-baselining (:mod:`.contact_state`), then the
force map per sensor. With trained weights (``sensor.estimator.contact_model`` and ``force_model``,
files of ``mlsim anyskin-train``) the detector is the causal CNN
(:mod:`classifiers.anyskin_contact_cnn`) and the force map the LSTM-MLP
(:mod:`classifiers.anyskin_force_lstm`), as SPEC 2 has them; ``force_model = "bench"`` trains the
LSTM-MLP on the simulated calibration bench instead (:mod:`.bench`, seeded by the scene's seed). Without them two stand-ins, named as
such in every output: the slope-threshold detector (:class:`.contact_state.ThresholdStandIn`) and a
quadratic ridge map (:mod:`.force_map`) fitted on a calibration run (the same scene with the skin's
set switched off and the next seed, seed + 1).

:func:`estimate_contacts` tracks a scene's run twice, re-baselining on falling edges and with the
offsets held at 0, and scores both against the ground truth: mean absolute error over the samples
after the initial baseline, and per push cycle.
"""

from __future__ import annotations

from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from .contact_state import ThresholdStandIn, track_contacts
from .helmet import N_SENSORS
from .skin import N_MAGNETOMETERS
from .stream import check_stream

__all__ = ["BENCH_FORCE_MODEL", "Estimator", "EstimatorOutput", "ContactEstimate", "estimate_contacts", "make_estimator", "cnn_detector",
           "model_path", "push_cycles", "N_CHANNELS"]

N_CHANNELS = N_SENSORS * N_MAGNETOMETERS
BENCH_FORCE_MODEL = "bench"  # sensor.estimator.force_model: train the LSTM-MLP on the simulated calibration bench
ROOT = Path(__file__).resolve().parents[2]


def model_path(path: str) -> Path:
    """A model file named in a scene: as given (relative to the working directory), else relative to
    the project's root, so that the shipped scenes run from anywhere."""
    p = Path(path)
    return p if p.is_absolute() or p.exists() or not (ROOT / p).exists() else ROOT / p


def cnn_detector(model) -> Callable[[np.ndarray], np.ndarray]:
    """The causal CNN as a detector: slope windows (N, L) -> classes (N,), one batched call."""
    from classifiers.anyskin_contact_cnn import predict_events

    return lambda windows: predict_events(model, windows)


@dataclass(frozen=True)
class EstimatorOutput:
    """track: the :class:`ContactTrack` (20 channels); force (T, 4, 3) N per sensor, sensor frame, 0
    before the initial baseline's end; dropped (T, 20) bool, readings held by the stream's door."""

    track: object
    force: np.ndarray
    dropped: np.ndarray


@dataclass(frozen=True)
class Estimator:
    """SPEC 2's causal estimator for the helmet: settings, a detector and a force map.

    force_map: one sensor's signals (S, T, 15) uT -> forces (S, T, 3) N, causal in T.
    """

    rate_hz: float
    calibration_s: float
    median_samples: int
    lowpass_hz: float
    window: int
    detector: Callable[[np.ndarray], np.ndarray]
    force_map: Callable[[np.ndarray], np.ndarray]
    name: str = "stand-ins"
    meta: dict = field(default_factory=dict)
    torch: bool = False  # whether the detector or the force map are torch nets

    def run(self, readings, t_s, rebaseline: bool = True, chunk: int | None = None) -> EstimatorOutput:
        """Estimate contacts and forces from readings (T, 20, 3) uT at times t_s (T,) s (checked at the door)."""
        start = max(1, int(round(self.calibration_s * self.rate_hz)))
        readings, dropped = check_stream(readings, t_s, N_CHANNELS, start)
        kwargs = {} if chunk is None else {"chunk": chunk}
        with _one_torch_thread(self.torch):
            track = track_contacts(readings, self.rate_hz, self.calibration_s, self.median_samples, self.lowpass_hz, self.window,
                                   self.detector, rebaseline, **kwargs)
            n_t = len(readings)
            signal = track.signal[track.start:].reshape(n_t - track.start, N_SENSORS, N_MAGNETOMETERS * 3).transpose(1, 0, 2)
            force = np.zeros((n_t, N_SENSORS, 3))
            force[track.start:] = np.asarray(self.force_map(signal)).transpose(1, 0, 2)
        return EstimatorOutput(track, force, dropped)


@contextmanager
def _one_torch_thread(uses_torch: bool):
    """Run the nets on one thread: their batches are small, and on a shared 2-core machine a second
    thread made the estimator 10 x slower (measured), not faster. The caller's setting is restored."""
    if not uses_torch:
        yield
        return
    import torch

    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(previous)


def make_estimator(sensor, seed: int = 0) -> Estimator:
    """The scene's estimator: the CNN and LSTM-MLP when ``sensor.estimator`` names their files, else
    the stand-ins (the quadratic map fitted on a calibration run of the scene with seed + 1)."""
    e, rate = sensor.estimator, sensor.magnetometers.rate_hz
    settings = (rate, e.calibration_s, e.median_samples, e.lowpass_hz, e.window_samples)
    if (e.contact_model is None) != (e.force_model is None):
        from mlsim.errors import SceneError

        raise SceneError([("sensor.estimator.force_model" if e.force_model is None else "sensor.estimator.contact_model", None,
                           "give both trained files (mlsim anyskin-train writes both) or neither (the stand-ins)")])
    if e.contact_model is not None:
        from classifiers.anyskin_contact_cnn import load_contact_cnn
        from classifiers.anyskin_force_lstm import load_force_lstm, predict_forces

        cnn = load_contact_cnn(model_path(e.contact_model))
        if e.force_model == BENCH_FORCE_MODEL:  # SPEC 2's calibration rig, simulated: trained here (issue 43)
            from .bench import bench_force_map

            lstm, what = bench_force_map(sensor, seed)[0], "bench-trained LSTM-MLP"
        else:
            lstm, what = load_force_lstm(model_path(e.force_model)), "LSTM-MLP"
        if cnn.window != e.window_samples:
            from mlsim.errors import SceneError

            raise SceneError([("sensor.estimator.window_samples", e.window_samples,
                               f"the CNN in {e.contact_model} takes windows of {cnn.window}; set it to {cnn.window} or retrain")])
        return Estimator(*settings, cnn_detector(cnn), lambda s: predict_forces(lstm, s), f"causal CNN + {what}",
                         {"contact": cnn.meta, "force": getattr(lstm, "meta", {})}, torch=True)
    from .force_map import fit_force_map, predict_force
    from .signals import simulate_helmet

    stand_in = Estimator(*settings, ThresholdStandIn(e.onset_slope_ut_s, e.release_slope_ut_s), lambda s: np.zeros(s.shape[:2] + (3,)),
                         "threshold stand-in + quadratic stand-in")
    calibration = simulate_helmet(sensor.model_copy(update={"drift": sensor.drift.model_copy(update={"enabled": False})}), seed + 1)
    cal = stand_in.run(calibration.readings.reshape(len(calibration.t), N_CHANNELS, 3), calibration.t, rebaseline=False)
    s0 = cal.track.start
    cal_signal = cal.track.signal[s0:].reshape(-1, N_SENSORS, N_MAGNETOMETERS, 3)
    weights = [fit_force_map(cal_signal[:, i], calibration.force_n[s0:, i]) for i in range(N_SENSORS)]

    def quadratic(signal):  # (S, T, 15) -> (S, T, 3)
        return np.stack([predict_force(weights[i], signal[i].reshape(-1, N_MAGNETOMETERS, 3)) for i in range(len(signal))])

    return Estimator(*settings, stand_in.detector, quadratic, stand_in.name)


def push_cycles(t_s, first_s: float, push_s: float, rest_s: float) -> np.ndarray:
    """Sample index where each push cycle starts, (K + 1,) with the stream's end last."""
    t = np.asarray(t_s, dtype=float)
    starts = first_s + (push_s + rest_s) * np.arange(int(np.ceil(max(t[-1] - first_s, 0.0) / (push_s + rest_s))) + 1)
    idx = np.searchsorted(t, starts[starts < t[-1]])
    return np.append(idx, len(t))


@dataclass(frozen=True)
class ContactEstimate:
    """t (T,) s; truth (T, 4, 3) N; rebaselined, static (T, 4, 3) N, the estimates with and without
    re-baselining; state (T, 4, 5) bool, the tracked contact state; onsets, releases, rebaselines
    (4,) counts; start: the first scored sample; cycles (K + 1,) the push cycles' first samples and the
    end; estimator: which detector and force map ran."""

    t: np.ndarray
    truth: np.ndarray
    rebaselined: np.ndarray
    static: np.ndarray
    state: np.ndarray
    onsets: np.ndarray
    releases: np.ndarray
    start: int
    rebaselines: np.ndarray = None
    cycles: np.ndarray = None
    estimator: str = "stand-ins"

    def mae(self, which: str = "rebaselined", axis: int | None = None) -> float:
        """Mean absolute error (N) over the scored samples, sensors and axes (or one axis: 0, 1, 2 = x, y, z)."""
        err = np.abs(getattr(self, which) - self.truth)[self.start:]
        return float(err.mean() if axis is None else err[..., axis].mean())

    def cycle_mae(self, which: str = "rebaselined") -> np.ndarray:
        """MAE (K, 3) N per push cycle and axis, over the scored samples of each cycle and all sensors."""
        err = np.abs(getattr(self, which) - self.truth)
        out = []
        for lo, hi in zip(self.cycles[:-1], self.cycles[1:]):
            lo = max(lo, self.start)
            out.append(err[lo:hi].mean(axis=(0, 1)) if hi > lo else np.full(3, np.nan))
        return np.array(out).reshape(-1, 3)


def estimate_contacts(sensor, signals, seed: int, estimator: Estimator | None = None) -> ContactEstimate:
    """See the module docstring."""
    est = estimator if estimator is not None else make_estimator(sensor, seed)
    n_t = len(signals.t)
    readings = signals.readings.reshape(n_t, N_CHANNELS, 3)
    with_rb, without = est.run(readings, signals.t, rebaseline=True), est.run(readings, signals.t, rebaseline=False)
    track = with_rb.track
    per_sensor = lambda mask: mask.reshape(len(mask), N_SENSORS, N_MAGNETOMETERS).sum(axis=(0, 2))  # noqa: E731
    rises = np.diff(track.state.astype(int), axis=0)  # the state's edges: one onset or release per contact, however many
    p = sensor.push                                    # samples the detector's class lasts
    return ContactEstimate(signals.t, signals.force_n, with_rb.force, without.force,
                           track.state.reshape(n_t, N_SENSORS, N_MAGNETOMETERS), per_sensor(rises == 1),
                           per_sensor(rises == -1), track.start, per_sensor(track.rebaselines),
                           push_cycles(signals.t, p.first_s, p.push_s, p.rest_s), est.name)
