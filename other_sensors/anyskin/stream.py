"""The estimator's door: a magnetometer sample stream checked before the causal pipeline sees it.

A stream is ``readings`` (T, C, 3) uT (C channels, x y z in each sensor's frame) with its clock
``t_s`` (T,) s. Rules (each refusal is a :class:`StreamError` naming the field, the value and the fix):

- ``readings`` must be (T, C, 3) with C = the helmet's 20 channels (4 sensors x 5 chips): refused;
- ``t_s`` must be (T,), finite and strictly increasing: refused (a clock that steps back or stalls
  means samples out of order or repeated; the estimator cannot re-order them causally);
- a reading that is NaN or infinite (a dropped I2C read) is flagged and skipped: the channel holds
  its last finite reading (sample-and-hold, causal) and ``dropped`` (T, C) marks it; a reading dropped
  before the channel's first finite one (inside the initial baseline's samples, which the pipeline
  averages before it outputs anything) takes the mean of the channel's finite baseline readings. A
  channel with no finite reading in the baseline's samples is refused (there is nothing to hold).
"""

from __future__ import annotations

import numpy as np

from mlsim.errors import Problem, SceneError

__all__ = ["StreamError", "check_stream"]


class StreamError(SceneError):
    """A sample stream the estimator refuses (exit code 2 on the command line): each problem names its field."""

    def __init__(self, problems):
        self.problems = [p if isinstance(p, Problem) else Problem(*p) for p in problems]
        self.source = None
        ValueError.__init__(self, "invalid AnySkin sample stream:\n" + "\n".join(f"  {p}" for p in self.problems))


def check_stream(readings, t_s, n_channels: int, baseline_samples: int):
    """Check a stream and hold its dropped readings; see the module docstring.

    Parameters
    ----------
    readings : array (T, C, 3) uT
    t_s : array (T,) s
    n_channels : int
        The channels expected (20 for the helmet).
    baseline_samples : int
        Samples of the initial baseline (calibration_s x rate).

    Returns
    -------
    (readings (T, C, 3) finite, dropped (T, C) bool)
    """
    r = np.asarray(readings, dtype=float)
    t = np.asarray(t_s, dtype=float)
    if r.ndim != 3 or r.shape[1:] != (n_channels, 3):
        raise StreamError([("readings.shape", tuple(r.shape), f"expected (samples, {n_channels}, 3): {n_channels} channels "
                                                              "(4 sensors x 5 chips) of x, y, z in uT")])
    if t.shape != (len(r),):
        raise StreamError([("t_s.shape", tuple(t.shape), f"expected ({len(r)},): one time per sample")])
    bad_t = np.flatnonzero(~np.isfinite(t))
    if bad_t.size:
        raise StreamError([(f"t_s[{bad_t[0]}]", float(t[bad_t[0]]), "times must be finite")])
    back = np.flatnonzero(np.diff(t) <= 0)
    if back.size:
        k = int(back[0]) + 1
        raise StreamError([(f"t_s[{k}]", float(t[k]), f"the clock must increase: t_s[{k - 1}] = {t[k - 1]!r}; "
                                                       "re-order or drop the repeated samples")])
    finite = np.isfinite(r).all(axis=2)  # (T, C)
    dropped = ~finite
    if not dropped.any():
        return r, dropped
    n0 = min(baseline_samples, len(r))
    empty = np.flatnonzero(~finite[:n0].any(axis=0))
    if empty.size:
        raise StreamError([(f"readings[:{n0}, {empty[0]}]", "NaN", "no finite reading in the initial baseline's samples; "
                                                                   "the channel cannot be held: check its chip")])
    # sample-and-hold: index of the last finite sample at or before k, per channel
    idx = np.where(finite, np.arange(len(r))[:, None], -1)
    last = np.maximum.accumulate(idx, axis=0)
    base = np.stack([np.nanmean(np.where(finite[:n0, c, None], r[:n0, c], np.nan), axis=0) for c in range(r.shape[1])])
    lead = last < 0  # dropped before the channel's first finite reading: hold the baseline mean
    held = r[np.maximum(last, 0), np.arange(r.shape[1])[None, :]]
    return np.where(lead[..., None], base[None], held), dropped
