"""Force estimates from the helmet's traces, with and without dynamic re-baselining (SPEC 2).

The flux-to-force map (:mod:`other_sensors.anyskin.force_map`, a stand-in for the LSTM + MLP) is fitted
on a calibration run: the same scene with the skin's set switched off and the next seed (seed + 1),
its traces through the same causal filters (:mod:`other_sensors.anyskin.contact_state`, no
re-baselining needed without set). The scene's run is then tracked twice, with the contact state
machine re-baselining on falling edges and with the offsets held at 0, and both estimates are
scored against the ground truth: mean absolute error over the samples after the initial baseline.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .contact_state import ONSET, RELEASE, track_contacts
from .force_map import fit_force_map, predict_force
from .helmet import N_SENSORS
from .skin import N_MAGNETOMETERS

__all__ = ["ContactEstimate", "estimate_contacts", "track_signals"]


@dataclass(frozen=True)
class ContactEstimate:
    """t (T,) s; truth (T, 4, 3) N; rebaselined, static (T, 4, 3) N, the estimates with and without
    re-baselining; state (T, 4, 5) bool, the tracked contact state; onsets, releases (4,) counts;
    start: the first scored sample."""

    t: np.ndarray
    truth: np.ndarray
    rebaselined: np.ndarray
    static: np.ndarray
    state: np.ndarray
    onsets: np.ndarray
    releases: np.ndarray
    start: int

    def mae(self, which: str = "rebaselined", axis: int | None = None) -> float:
        """Mean absolute error (N) over the scored samples, sensors and axes (or one axis: 0, 1, 2 = x, y, z)."""
        err = np.abs(getattr(self, which) - self.truth)[self.start:]
        return float(err.mean() if axis is None else err[..., axis].mean())


def track_signals(sensor, signals, rebaseline: bool):
    """The :class:`ContactTrack` of a :class:`HelmetSignals` under the sensor's estimator settings."""
    e, n_t = sensor.estimator, len(signals.t)
    return track_contacts(signals.readings.reshape(n_t, N_SENSORS * N_MAGNETOMETERS, 3), sensor.magnetometers.rate_hz,
                          e.calibration_s, e.median_samples, e.lowpass_hz, e.window_samples, e.onset_slope_ut_s,
                          e.release_slope_ut_s, rebaseline)


def _per_sensor(signal):
    return signal.reshape(len(signal), N_SENSORS, N_MAGNETOMETERS, 3)


def estimate_contacts(sensor, signals, seed: int) -> ContactEstimate:
    """See the module docstring."""
    from .signals import simulate_helmet

    calibration = simulate_helmet(sensor.model_copy(update={"drift": sensor.drift.model_copy(update={"enabled": False})}), seed + 1)
    cal = track_signals(sensor, calibration, rebaseline=False)
    cal_signal = _per_sensor(cal.signal)[cal.start:]
    weights = [fit_force_map(cal_signal[:, i], calibration.force_n[cal.start:, i]) for i in range(N_SENSORS)]

    def run(rebaseline):
        track = track_signals(sensor, signals, rebaseline)
        signal = _per_sensor(track.signal)
        est = np.stack([predict_force(weights[i], signal[:, i]) for i in range(N_SENSORS)], axis=1)
        est[: track.start] = 0.0
        return track, est

    track, rebaselined = run(True)
    _, static = run(False)
    per_sensor = lambda events: (events.reshape(len(events), N_SENSORS, N_MAGNETOMETERS)).sum(axis=(0, 2))  # noqa: E731
    return ContactEstimate(signals.t, signals.force_n, rebaselined, static,
                           track.state.reshape(len(signals.t), N_SENSORS, N_MAGNETOMETERS),
                           per_sensor(track.event == ONSET), per_sensor(track.event == RELEASE), track.start)
