"""SPEC 2's causal contact pipeline: filters, slope windows, a detector, the contact state machine and
dynamic re-baselining.

Per sample B_t (C, 3) uT (SPEC 2): subtract the initial baseline B0 (the mean of the samples in the
first ``calibration_s``) and the per-channel offsets O (C, 3); a causal median filter over the last m
samples, then a causal low-pass (2nd-order Butterworth, zero initial state); each channel's vector
norm enters a window of L samples whose least-squares slope is g_t (C,) uT/s; the last L slopes of a
channel, oldest first, are its row of G_t (L x C); the detector maps each row to {idle 0, onset 1,
release 2}. Onset sets the channel's contact state, release clears it, idle holds it.

Re-baselining (SPEC 2: "on a falling edge (contact -> no contact) the channel's offset O is
re-estimated from its recent no-contact signal"): a falling edge at sample k opens a re-baselining;
O becomes the mean of the channel's baseline-subtracted readings over the first span of
R = :data:`REBASELINE_SAMPLES` samples after k that is no-contact signal, and applies from the sample
after that span; an onset before then cancels it. A span is no-contact signal when the state
machine holds no contact over it and it is as quiet as the initial baseline's samples (which SPEC 2
takes out of contact): on every axis the median-filtered reading's range over the span is at most
:data:`QUIET_FACTOR` times its range over the initial baseline's samples. Choices (SPEC 2 says
neither how much no-contact signal nor how to know it): R = 75 samples is one 2 Hz gait period, so
the gait-periodic geomagnetic and motor fields average out of O, and fits twice into the pushes' 1 s
rest; the quiet test keeps a release called early (at a dip of a push on a walking head, which a
detector of slopes alone cannot tell from a release: the slopes hold no level) from re-baselining
on a loaded skin: the rest of the push moves the reading by hundreds of uT, the gait by tens.

Why the release is an event of the detector and not a quiet spell before it: the previous stand-in
released a channel only after 0.5 s in which |g| and the norm stayed small; on a walking head the
gait-periodic fields keep |g| above that on a loaded chip, and the skin's set keeps its norm up, so
the loaded chips (the ones that drift) seldom released and seldom re-baselined (MAE 2.36 N with
re-baselining against 2.25 N without on the shipped scene). SPEC 2's release is the detector's class
2 at the end of a push's falling edge, and O comes from the no-contact signal after it.

Detectors: the causal CNN (:mod:`classifiers.anyskin_contact_cnn`, through
:func:`other_sensors.anyskin.estimate.cnn_detector`) or, untrained, :class:`ThresholdStandIn`.

Implementation (same outputs as running sample by sample): the median filter and the low-pass act
on B - B0 once for the whole stream; O is piecewise constant per channel and the low-pass is linear
and time invariant, so a change dO at sample c + 1 subtracts dO times the filter's step response
from the channel's signal after c. The detector runs batched over chunks of samples; when a channel
commits a new O inside a chunk, only that channel's rest of the chunk is recomputed. Each output at
sample k depends on readings at samples <= k only (tests/test_anyskin_estimator.py checks it).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

__all__ = ["ContactTrack", "ThresholdStandIn", "window_slope_weights", "causal_median", "track_contacts", "IDLE", "ONSET",
           "RELEASE", "REBASELINE_SAMPLES", "QUIET_FACTOR", "CHUNK_SAMPLES", "quiet_spans"]

IDLE, ONSET, RELEASE = 0, 1, 2
REBASELINE_SAMPLES = 75  # see the module docstring
QUIET_FACTOR = 2.0  # see the module docstring
CHUNK_SAMPLES = 150  # samples per batched detector call (1 s); any value gives the same outputs


def window_slope_weights(length: int, rate_hz: float) -> np.ndarray:
    """Weights w (L,) with w @ y = the least-squares slope (per second) of y sampled at rate_hz, oldest first."""
    k = np.arange(length, dtype=float)
    centred = k - k.mean()
    return centred / (centred**2).sum() * rate_hz


def causal_median(raw, samples: int) -> np.ndarray:
    """Median over the last ``samples`` samples along axis 0 (the first sample repeated before the start)."""
    from numpy.lib.stride_tricks import sliding_window_view

    raw = np.asarray(raw, dtype=float)
    if samples == 1:
        return raw.copy()
    padded = np.concatenate([np.repeat(raw[:1], samples - 1, axis=0), raw])
    return np.median(sliding_window_view(padded, samples, axis=0), axis=-1)


class ThresholdStandIn:
    """The untrained stand-in for the causal CNN: thresholds on a window's two newest slopes.

    Onset (1) when the slope rises through ``onset_slope`` uT/s; release (2) when it climbs back
    through -release_slope from below (the end of a fall: the signal has stopped dropping); idle
    otherwise. A function of G_t alone, like the CNN, so it is causal. Use it only without trained
    weights: it fires on the dips of a wobbling push, which the CNN learns to ignore.
    """

    def __init__(self, onset_slope: float, release_slope: float):
        self.onset_slope, self.release_slope = float(onset_slope), float(release_slope)

    def __call__(self, windows) -> np.ndarray:
        g = np.asarray(windows, dtype=float)
        new, old = g[:, -1], g[:, -2]
        event = np.full(len(g), IDLE)
        event[(new > self.onset_slope) & (old <= self.onset_slope)] = ONSET
        event[(old < -self.release_slope) & (new >= -self.release_slope)] = RELEASE
        return event


@dataclass(frozen=True)
class ContactTrack:
    """signal (T, C, 3) uT filtered, baseline- and offset-free; slope (T, C) uT/s; event (T, C) int
    {0 idle, 1 onset, 2 release}; state (T, C) bool; offsets (T, C, 3) uT, O in force at each sample;
    rebaselines (T, C) bool, where a new O was committed; start: the first sample after the initial
    baseline (everything before it is 0)."""

    signal: np.ndarray
    slope: np.ndarray
    event: np.ndarray
    state: np.ndarray
    offsets: np.ndarray
    rebaselines: np.ndarray
    start: int


def _machine(events, quiet, s: int, b: int, state: bool, edge: int, r: int):
    """Run one channel's state machine over samples [s, b). events (n,) int; quiet (n,) bool, whether
    the R samples ending at each sample are quiet; edge: the open falling edge's sample (-1: none).
    Returns (state, edge, stop, changes): stop is the sample where a re-baseline commits (-1: none
    before b; the caller restarts the channel after it); changes [(k, state after k)]."""
    changes, lo = [], s
    for k in [*(np.flatnonzero(events[s:b]) + s), b]:
        if edge >= 0:  # idle samples [lo, k): the first quiet end of an R-sample span after the edge commits
            first = max(lo, edge + r)
            if first < k:
                hits = np.flatnonzero(quiet[first:k])
                if hits.size:
                    return state, -1, first + int(hits[0]), changes
        if k == b:
            break
        e = events[k]
        if e == ONSET:
            edge = -1  # back in contact: the no-contact span is cut
            if not state:
                state = True
                changes.append((k, True))
        elif e == RELEASE and state:  # a falling edge: open the re-baselining
            state = False
            changes.append((k, False))
            edge = k if r > 0 else -1
        lo = k + 1
    return state, edge, -1, changes


def quiet_spans(med, calibration_med, span: int, factor: float = QUIET_FACTOR) -> np.ndarray:
    """Whether the ``span`` samples ending at each sample are quiet, (n, C) bool (False before span
    samples): on every axis the range of med (n, C, 3) over them is <= factor x the range of
    calibration_med (n0, C, 3), the initial baseline's median-filtered samples."""
    from scipy.ndimage import maximum_filter1d, minimum_filter1d

    n = len(med)
    if span > n:
        return np.zeros(med.shape[:2], dtype=bool)
    limit = factor * np.ptp(calibration_med, axis=0)  # (C, 3)
    ends = (span - 1) // 2  # this origin makes the window [k - span + 1, k]: it ends at the sample (causal)
    rng = maximum_filter1d(med, span, axis=0, origin=ends) - minimum_filter1d(med, span, axis=0, origin=ends)
    quiet = (rng <= limit).all(axis=2)
    quiet[: span - 1] = False
    return quiet


def track_contacts(readings, rate_hz: float, calibration_s: float, median_samples: int, lowpass_hz: float, window: int,
                   detector: Callable[[np.ndarray], np.ndarray], rebaseline: bool = True,
                   rebaseline_samples: int = REBASELINE_SAMPLES, chunk: int = CHUNK_SAMPLES) -> ContactTrack:
    """Run the pipeline causally over readings (T, C, 3) uT; see the module docstring.

    detector: slope windows (N, L) uT/s, oldest first -> classes (N,) int. Readings must be finite
    (:func:`other_sensors.anyskin.stream.check_stream` holds dropped samples).
    """
    from numpy.lib.stride_tricks import sliding_window_view
    from scipy.signal import butter, sosfilt

    readings = np.asarray(readings, dtype=float)
    n_t, n_c, _ = readings.shape
    start = max(1, int(round(calibration_s * rate_hz)))
    if start >= n_t:
        raise ValueError(f"sensor.estimator.calibration_s = {calibration_s}: leaves no samples after the baseline; shorten it")
    n, big_l, r = n_t - start, int(window), int(rebaseline_samples) if rebaseline else 0
    raw = readings[start:] - readings[:start].mean(axis=0)  # (n, C, 3)
    sos = butter(2, lowpass_hz, fs=rate_hz, output="sos")
    med = causal_median(raw, median_samples)
    x = sosfilt(sos, med, axis=0)  # O = 0 everywhere; commits subtract below
    quiet = quiet_spans(med, causal_median(readings[:start], median_samples), r) if r > 0 else None
    step = sosfilt(sos, np.ones(n))  # the low-pass's response to a unit step at sample 0
    weights = window_slope_weights(big_l, rate_hz)
    norm_p = np.empty((n + big_l - 1, n_c))  # norms, the first repeated L - 1 times before the start
    norm_p[big_l - 1:] = np.linalg.norm(x, axis=2)
    norm_p[: big_l - 1] = norm_p[big_l - 1]
    slope_p = np.zeros((n + big_l - 1, n_c))  # slopes, zeros (no change) before the start
    events, states = np.zeros((n, n_c), dtype=int), np.zeros((n, n_c), dtype=bool)
    offsets, committed = np.zeros((n, n_c, 3)), np.zeros((n, n_c), dtype=bool)
    state, edge, offset = np.zeros(n_c, dtype=bool), np.full(n_c, -1), np.zeros((n_c, 3))

    def slopes(channel, lo, hi):  # fill slope_p for samples [lo, hi) of the channels
        win = sliding_window_view(norm_p[lo:hi + big_l - 1, channel], big_l, axis=0)
        slope_p[big_l - 1 + lo:big_l - 1 + hi, channel] = win @ weights

    a = 0
    while a < n:
        b = min(a + max(1, int(chunk)), n)
        all_c = np.arange(n_c)
        slopes(all_c, a, b)
        g = sliding_window_view(slope_p[a:b + big_l - 1], big_l, axis=0)  # (b - a, C, L)
        events[a:b] = np.asarray(detector(g.reshape(-1, big_l))).reshape(b - a, n_c)
        todo = {c: a for c in range(n_c)}
        while todo:
            redo = {}
            for c, s in todo.items():
                before = state[c]
                state[c], edge[c], stop, changes = _machine(events[:, c], None if quiet is None else quiet[:, c], s, b,
                                                            bool(state[c]), int(edge[c]), r)
                end = b if stop < 0 else stop + 1
                k0, st = s, before
                for k, after in changes:
                    states[k0:k, c] = st
                    k0, st = k, after
                states[k0:end, c] = st
                if stop >= 0:  # commit a new O from the R no-contact samples after the edge; it applies from stop + 1
                    new = raw[stop - r + 1:stop + 1, c].mean(axis=0)
                    x[stop + 1:, c] -= (new - offset[c]) * step[: n - stop - 1, None]
                    offset[c] = new
                    committed[stop, c] = True
                    offsets[stop + 1:, c] = new
                    norm_p[big_l + stop:, c] = np.linalg.norm(x[stop + 1:, c], axis=1)
                    if stop + 1 < b:
                        redo[c] = stop + 1
            if redo:  # the redone channels' rest of the chunk, in one detector call
                wins = []
                for c, s in redo.items():
                    slopes(np.array([c]), s, b)
                    wins.append(sliding_window_view(slope_p[s:b + big_l - 1, c], big_l, axis=0))
                classes = np.asarray(detector(np.concatenate(wins)))
                i = 0
                for c, s in redo.items():
                    events[s:b, c] = classes[i:i + b - s]
                    i += b - s
            todo = redo
        a = b

    def full(part, dtype=float):
        out = np.zeros((n_t,) + part.shape[1:], dtype=dtype)
        out[start:] = part
        return out

    return ContactTrack(full(x), full(slope_p[big_l - 1:]), full(events, int), full(states, bool), full(offsets),
                        full(committed, bool), start)
