"""SPEC 2's causal contact pipeline, with a slope-threshold detector standing in for the causal CNN.

Per sample B_t (C, 3) uT: subtract the initial baseline B0 (the mean of the first samples) and the
per-channel offsets O (C, 3); a causal median filter over the last m samples, then a causal
low-pass (2nd-order Butterworth, run sample by sample); each channel's vector norm enters a window
of L samples whose least-squares slope is g_t (C,) uT/s.

:func:`threshold_detector_step` stands in for SPEC 2's causal 1D CNN (a later task): per channel,
onset (1) when g > onset_slope while out of contact; in contact, a fall (g < -release_slope) arms
the release, and release (2) fires once the signal has been quiet for SETTLE_SAMPLES samples in a
row (|g| < release_slope / 2 and the norm under a quarter of its peak since onset), so that the dips
of a wobbling push do not end the contact; otherwise idle (0). The settling rule is a choice: it
re-baselines on a quiet signal.

Contact state: onset sets it, release clears it, idle holds it; on the falling edge (contact -> no
contact) the channel's offset O is re-estimated as the mean of its last `rebaseline_samples`
baseline-subtracted samples (dynamic re-baselining); without re-baselining O stays 0.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ContactTrack", "window_slope_weights", "threshold_detector_step", "track_contacts", "IDLE", "ONSET", "RELEASE",
           "REBASELINE_SAMPLES"]

IDLE, ONSET, RELEASE = 0, 1, 2
REBASELINE_SAMPLES = 75  # a choice: the quiet samples before the release, one gait period, so the gait-periodic
# geomagnetic and motor fields average out of O (a shorter window catches them at one phase)
SETTLE_SLOPE, SETTLE_NORM = 0.5, 0.25  # quiet: |g| < release_slope / 2 and the norm < 1/4 of its peak; a choice, see above
SETTLE_SAMPLES = 75  # a choice: 0.5 s of quiet, one 2 Hz gait period, longer than the dips of a wobbling push


def window_slope_weights(length: int, rate_hz: float) -> np.ndarray:
    """Weights w (L,) with w @ y = the least-squares slope (per second) of y sampled at rate_hz, oldest first."""
    k = np.arange(length, dtype=float)
    centred = k - k.mean()
    return centred / (centred**2).sum() * rate_hz


@dataclass(frozen=True)
class ContactTrack:
    """signal (T, C, 3) uT filtered, baseline- and offset-free; slope (T, C) uT/s; event (T, C) int
    {0 idle, 1 onset, 2 release}; state (T, C) bool; offsets (T, C, 3) uT, O in force at each sample;
    start: the first sample after the initial baseline."""

    signal: np.ndarray
    slope: np.ndarray
    event: np.ndarray
    state: np.ndarray
    offsets: np.ndarray
    start: int


def threshold_detector_step(g, norm, state, armed, quiet, peak, onset_slope: float, release_slope: float):
    """One sample of the stand-in detector for all channels: g, norm, peak (C,) uT/s, uT, uT; state, armed
    (C,) bool; quiet (C,) int, the samples in a row the armed channel has been quiet.
    Returns (event (C,), armed, quiet)."""
    event = np.full(g.shape, IDLE)
    event[~state & (g > onset_slope)] = ONSET
    armed = state & (armed | (g < -release_slope))
    calm = armed & (np.abs(g) < SETTLE_SLOPE * release_slope) & (norm < SETTLE_NORM * peak)
    quiet = np.where(calm, quiet + 1, 0)
    settled = quiet >= SETTLE_SAMPLES
    event[settled] = RELEASE
    return event, armed & ~settled, np.where(settled, 0, quiet)


def track_contacts(readings, rate_hz: float, calibration_s: float, median_samples: int, lowpass_hz: float, window: int,
                   onset_slope: float, release_slope: float, rebaseline: bool = True) -> ContactTrack:
    """Run the pipeline causally over readings (T, C, 3) uT; see the module docstring."""
    from scipy.signal import butter, sosfilt, sosfilt_zi

    readings = np.asarray(readings, dtype=float)
    n_t, n_c, _ = readings.shape
    start = max(1, int(round(calibration_s * rate_hz)))
    if start >= n_t:
        raise ValueError(f"sensor.estimator.calibration_s = {calibration_s}: leaves no samples after the baseline; shorten it")
    base = readings[:start].mean(axis=0)
    sos = butter(2, lowpass_hz, fs=rate_hz, output="sos")
    zi = sosfilt_zi(sos)[:, :, None] * np.zeros(n_c * 3)  # the filter starts at rest (zero signal)
    weights = window_slope_weights(window, rate_hz)
    raw_hist = np.zeros((max(median_samples, REBASELINE_SAMPLES), n_c, 3))
    norms = np.zeros((window, n_c))
    offsets = np.zeros((n_c, 3))
    state, armed, quiet, peak = np.zeros(n_c, bool), np.zeros(n_c, bool), np.zeros(n_c, int), np.zeros(n_c)
    out = ContactTrack(np.zeros((n_t, n_c, 3)), np.zeros((n_t, n_c)), np.zeros((n_t, n_c), int), np.zeros((n_t, n_c), bool),
                       np.zeros((n_t, n_c, 3)), start)
    for k in range(start, n_t):
        raw = readings[k] - base
        raw_hist = np.roll(raw_hist, -1, axis=0)
        raw_hist[-1] = raw
        filled = min(k - start + 1, median_samples)
        med = np.median(raw_hist[-filled:] - offsets, axis=0)
        filt, zi = sosfilt(sos, med.reshape(1, -1), axis=0, zi=zi)
        x = filt.reshape(n_c, 3)
        norm = np.linalg.norm(x, axis=1)
        norms = np.roll(norms, -1, axis=0)
        norms[-1] = norm
        if k - start + 1 < window:  # the window is not yet full: no slope, no events
            norms[: window - (k - start + 1)] = norm
        g = weights @ norms
        peak = np.where(state, np.maximum(peak, norm), 0.0)
        event, armed, quiet = threshold_detector_step(g, norm, state, armed, quiet, peak, onset_slope, release_slope)
        falling = state & (event == RELEASE)
        state = np.where(event == ONSET, True, np.where(event == RELEASE, False, state))
        if rebaseline and falling.any():
            recent = min(k - start + 1, REBASELINE_SAMPLES)
            offsets[falling] = raw_hist[-recent:, falling].mean(axis=0)
        out.signal[k], out.slope[k], out.event[k], out.state[k], out.offsets[k] = x, g, event, state, offsets
    return out
