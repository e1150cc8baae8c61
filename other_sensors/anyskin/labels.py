"""Training labels for the causal contact CNN, from offline prominence peaks of the ground truth (SPEC 2).

SPEC 2: "Labels for training come from offline prominence-based peak/valley detection on the raw
signal (uses the future, so only for labelling); idle samples drawn away from events". Here the
signal is the simulator's ground truth, each sensor's plate force (N), which the real rig does not
have; every chip of a sensor shares its sensor's labels.

- A contact is a run of samples with force > ``contact_n`` that holds a peak of prominence >=
  ``prominence_n`` (``scipy.signal.find_peaks``); smaller bumps are left unlabelled (a 10 N touch
  moves a chip by about the gait's own 15 uT). The run's first sample is its onset, the sample after
  its last is its release: the valleys on either side of the peak where the force meets zero.
- The CNN sees only the past, and a press shows in the slopes a few samples after it starts, so the
  onset's class labels the ``span`` samples from the onset on (a choice: 15 samples, 0.1 s). The
  release's class labels ``span`` samples from ``release_delay`` (15 samples) after the release: a
  push on a walking head has dips that fall as steeply as a release and rise again within ~0.1 s
  (the 2 Hz gait), while after a release the signal stays flat; a release labelled at the valley
  itself cannot be told from a dip by a causal detector, and a release called at a dip re-baselines
  on a loaded skin. Samples less than ``guard`` before or after an event's labels are left out (-1);
  idle samples are the rest, drawn away from events.
"""

from __future__ import annotations

import numpy as np

__all__ = ["contact_runs", "event_labels", "CONTACT_N", "PROMINENCE_N", "SPAN_SAMPLES", "GUARD_SAMPLES", "RELEASE_DELAY_SAMPLES"]

CONTACT_N, PROMINENCE_N = 2.0, 10.0
SPAN_SAMPLES, GUARD_SAMPLES, RELEASE_DELAY_SAMPLES = 15, 30, 15
IGNORE = -1


def contact_runs(force_n, contact_n: float = CONTACT_N, prominence_n: float = PROMINENCE_N) -> np.ndarray:
    """(onset, release) sample pairs (K, 2) of one sensor's normal force (T,) N; see the module docstring."""
    from scipy.signal import find_peaks

    f = np.asarray(force_n, dtype=float)
    peaks, _ = find_peaks(np.concatenate([[0.0], f, [0.0]]), prominence=prominence_n)
    peaks = peaks - 1  # the zero pads let a peak at either end be found
    above = np.concatenate([[False], f > contact_n, [False]])
    edges = np.flatnonzero(np.diff(above.astype(int)))
    runs = edges.reshape(-1, 2)  # [first sample above, first sample below after it]
    keep = [(lo, hi) for lo, hi in runs if ((peaks >= lo) & (peaks < hi)).any()]
    return np.array(keep, dtype=int).reshape(-1, 2)


def event_labels(runs, n_samples: int, span: int = SPAN_SAMPLES, guard: int = GUARD_SAMPLES,
                 release_delay: int = RELEASE_DELAY_SAMPLES) -> np.ndarray:
    """Labels (T,) in {-1 left out, 0 idle, 1 onset, 2 release} from contact runs (K, 2)."""
    labels = np.zeros(n_samples, dtype=int)
    events = [(int(lo), 1) for lo, _ in runs] + [(int(hi) + release_delay, 2) for _, hi in runs if hi + release_delay < n_samples]
    for k, _ in events:  # the guard first, so that events override it
        labels[max(0, k - guard):min(n_samples, k + span + guard)] = IGNORE
    for k, cls in events:
        labels[k:min(n_samples, k + span)] = cls
    return labels
