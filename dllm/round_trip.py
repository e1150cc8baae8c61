"""How far the DLLM's reading of a lossy recording may be from its reading of the frames the recording
was made from (``mlsim detect`` on a simulated run written as MP4, issue 41), and how far it is.

A lossy codec (OpenCV's MPEG-4 part 2 in YUV 4:2:0) changes each grey level by a few DN: on the
demo's episode by -2.1 DN on average (the colour conversion darkens the dark frame from 12 to 10)
with a spread of 1.7 DN, more at the edges of the glow (8 x 8 blocks). With eps that error budget per
pixel (``codec_dn``, 3 DN), N = pi R^2 the pixels of a taxel's disk and H the lossless run's taxel
sum (SPEC 1.6), the tolerance of each feature follows from its definition:

- H, a sum over the disk: |dH| <= eps N + 2 % of H (the codec's quantisation grows with the
  contrast it codes);
- l, the offset of the intensity-weighted centroid q: an error e_i on the disk's pixels moves it by
  sum_i e_i (x_i - q) / H to first order, and |x_i - q| <= R + l inside the disk: at most
  eps N (R + l) / H;
- omega, the offset's angle, where the offset is longer than that bound: an error of length at most
  dl_max on a vector of length l turns it by at most arcsin(dl_max / l);
- a taxel may fire in one run only where its H lies within eps N of the taxel gate beta B_n(t) (the
  lossless run's, SPEC 1.6: the codec's shift of H and of the idle B_n decide it);
- a frame may be an event in one run only where its M(t) lies within ``gate_dn`` per pixel of the
  global gate alpha D(t): a uniform shift of the frame and of the idle frames moves M - alpha D by
  (1 - alpha) times the shift, and the demo's frames moved against their idle ones by at most
  0.4 DN per pixel (0.5 DN allowed).

:func:`replay` runs the DLLM over the lossless frames (the idle second first) and keeps what the
rules read (M, H and both gates per frame); :func:`agreement` compares a reading of the recording
(``mlsim detect``'s events and features) with it and reports, per rule, the worst error over its
tolerance (<= 1: the recording reproduces the run within it).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Replay", "replay", "agreement", "CODEC_DN", "GATE_DN"]

#: The codec's error budget per pixel (DN) and its shift of a frame's M against the gate (DN per pixel).
CODEC_DN = 3.0
GATE_DN = 0.5


@dataclass(frozen=True)
class Replay:
    """The DLLM over an episode's frames after its initialisation: events (T,) bool, features (T, N, 3)
    (H, l px, omega deg), frame_sums M (T,), taxel_sums H (T, N) (NaN where the frame was discarded),
    gate_m alpha D (T,) and gate_h beta B (T, N) as the frame met them; pixels of a frame."""

    events: np.ndarray
    features: np.ndarray
    frame_sums: np.ndarray
    taxel_sums: np.ndarray
    gate_m: np.ndarray
    gate_h: np.ndarray
    pixels: int


def replay(frames, calibration, params) -> Replay:
    """Step :class:`dllm.detector.Dllm` through RGB frames (T, H, W, 3) uint8, the first
    ``params.init_frames`` idle, with ``calibration`` and ``params``; returns the :class:`Replay` of
    the frames after the idle ones."""
    from dllm.detector import Dllm

    det = Dllm(calibration, params)
    n = calibration.n_taxels
    rows = []
    for f in frames:
        gate_m, gate_h = params.alpha * det.D, params.beta * det.B.copy()
        r = det.step(f)
        if not r.initialising:
            H = np.full(n, np.nan) if r.taxel_sums is None else np.asarray(r.taxel_sums, float)
            rows.append((r.event, r.features, r.frame_sum, H, gate_m, gate_h))
    if not rows:
        raise ValueError(f"replay: {len(frames)} frames, none after the {params.init_frames} idle ones")
    ev, z, m, h, gm, gh = (np.array(c) for c in zip(*rows))
    return Replay(ev.astype(bool), z, m.astype(float), h, gm.astype(float), gh, int(np.prod(np.shape(frames)[1:3])))


def agreement(reference: Replay, events, features, calibration, *, codec_dn: float = CODEC_DN, gate_dn: float = GATE_DN) -> dict:
    """A reading of the recording against the DLLM's reading of the lossless frames (module docstring).

    Parameters
    ----------
    reference : Replay
        The DLLM over the lossless frames (:func:`replay`).
    events, features : numpy.ndarray
        The recording's reading over the same frames: (T,) bool and (T, N, 3) (H, l px, omega deg),
        as ``mlsim detect`` writes them in ``dllm_features.csv``.
    calibration : dllm.calibration.Calibration
        The taxels' disks (their radius sets the tolerances).
    codec_dn, gate_dn : float
        The codec's error budget per pixel (DN) and its shift of M against the global gate (DN per pixel).

    Returns
    -------
    dict
        ``frames``, ``event_frames_agree``, ``events_reference``, ``events_recorded``,
        ``firing_jaccard`` (taxel-frames firing in both over either), the errors of H (relative), l (px)
        and omega (deg, where l > 1 px) as median and max, and ``worst``: per rule (``events``,
        ``firing``, ``H``, ``l``, ``omega``) the largest error over its tolerance (0 where nothing
        differs; <= 1 within the tolerance).
    """
    ev_a, fa = reference.events, reference.features
    ev_b, fb = np.asarray(events, bool), np.asarray(features, float)
    if ev_b.shape != ev_a.shape or fb.shape != fa.shape:
        raise ValueError(f"agreement: the recording's reading {ev_b.shape}, {fb.shape} and the reference's {ev_a.shape}, {fa.shape}: "
                         "need the same frames and taxels (give the recording without its idle second)")
    if not (codec_dn > 0 and gate_dn > 0):
        raise ValueError(f"agreement: codec_dn = {codec_dn}, gate_dn = {gate_dn}: both must be > 0 (DN)")
    n_disk = np.pi * calibration.radius_px**2
    worst = {"events": 0.0, "firing": 0.0, "H": 0.0, "l": 0.0, "omega": 0.0}
    differ = np.flatnonzero(ev_a != ev_b)
    if len(differ):
        worst["events"] = float(np.max(np.abs(reference.frame_sums[differ] - reference.gate_m[differ]) / (gate_dn * reference.pixels)))
    both_events = (ev_a & ev_b)[:, None]
    fire_a, fire_b = (fa[..., 0] > 0) & both_events, (fb[..., 0] > 0) & both_events
    flips = fire_a != fire_b
    if flips.any():
        worst["firing"] = float(np.max(np.abs(reference.taxel_sums[flips] - reference.gate_h[flips]) / (codec_dn * n_disk)))
    both = fire_a & fire_b
    H0, H1 = fa[..., 0][both], fb[..., 0][both]
    l0, dl = fa[..., 1][both], np.abs(fb[..., 1][both] - fa[..., 1][both])
    dw = np.radians(np.abs((fb[..., 2][both] - fa[..., 2][both] + 180.0) % 360.0 - 180.0))  # omega in degrees (dllm.features)
    if both.any():
        worst["H"] = float(np.max(np.abs(H1 - H0) / (codec_dn * n_disk + 0.02 * H0)))
        dl_max = codec_dn * n_disk * (calibration.radius_px + l0) / H0
        worst["l"] = float(np.max(dl / dl_max))
        long = l0 > dl_max
        if long.any():
            worst["omega"] = float(np.max(dw[long] / np.arcsin(dl_max[long] / l0[long])))
    big = l0 > 1.0
    some = bool(both.any())
    return {"frames": len(ev_a), "event_frames_agree": int((ev_a == ev_b).sum()), "events_reference": int(ev_a.sum()),
            "events_recorded": int(ev_b.sum()), "firing_jaccard": float(both.sum() / max((fire_a | fire_b).sum(), 1)),
            "H_rel_median": float(np.median(np.abs(H1 / H0 - 1))) if some else 0.0,
            "H_rel_max": float(np.max(np.abs(H1 / H0 - 1))) if some else 0.0,
            "l_px_median": float(np.median(dl)) if some else 0.0, "l_px_max": float(dl.max()) if some else 0.0,
            "omega_deg_median": float(np.degrees(np.median(dw[big]))) if big.any() else None,
            "omega_deg_max": float(np.degrees(dw[big].max())) if big.any() else None, "worst": worst}
