"""Batch calibration of the pairs' seven coefficients from a trajectory of measured poses (SPEC 3).

SPEC 3: the same LM as the pose estimator, over the coefficients (and the sensor/LED poses) from a
37 s trajectory of measured (motion-capture) poses; data outside theta < 40 deg, r > 20 mm, v < 0.8 V
ignored; tau = 1/40. Here:
- the poses are given (the reference poses at 80 Hz), so each pair's geometry is fixed and the pairs
  decouple: one 7-parameter LM per pair, with the analytic dv/dc of :func:`ltv.ltv_voltage_dc`;
- theta and r enter through the SPEC's soft weights w = 1 / (1 + zeta) with tau = 1/40 on
  -40 < theta < 40 deg and 20 < r < ``r_max_mm`` (the estimator's 60 mm: the SPEC gives no far bound);
- the voltage bound is a hard mask. Interpretation (a choice): the SPEC's 0.8 V cut removes readings
  near its hardware's saturation; the hardware's range is not given, so the cut is a setting,
  ``v_max_v``, default 0.9 of this ADC's full scale (4.5 V of 5 V);
- the sensor/LED mounting poses are NOT calibrated (not done: they are taken as designed).

Identifiability is reported from the singular values of the weighted Jacobian with each column
scaled by its coefficient's magnitude: a direction whose singular value is tiny against the
largest is a combination of coefficients the data cannot separate (e.g. c4 and c6 while theta and
psi stay small and nearly equal: cos(c theta) ~ 1 - c^2 theta^2 / 2 for both, so only a
combination of c4^2, c5 c6^2 is seen).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from other_sensors.cls.estimator import weight
from other_sensors.cls.ltv import PairLayout, ltv_voltage, ltv_voltage_dc, pair_geometry, planar_to_pose

__all__ = ["CalibrationSettings", "Calibration", "calibrate", "COEFF_NAMES"]

COEFF_NAMES = ("c1", "c2", "c3", "c4", "c5", "c6", "c7")


@dataclass(frozen=True)
class CalibrationSettings:
    tau: float = 1.0 / 40.0
    theta_max_deg: float = 40.0
    r_min_mm: float = 20.0
    r_max_mm: float = 60.0
    v_max_v: float = 4.5
    # A choice: calibration is offline, so it runs to a tight relative step (not the 1e-4 of the
    # real-time estimator) with room for many damped steps from the nominal coefficients.
    tolerance: float = 1e-10
    max_iterations: int = 200
    lambda0: float = 1e-3


@dataclass
class Calibration:
    """coeffs (P, 7) fitted; iterations (P,); rms_mv (P,) weighted residual RMS; used (P,) samples
    kept; singular (P, 7) scaled singular values / the largest; weak (P,) lists of the coefficients
    that dominate directions with a relative singular value under 1e-4 (not identifiable)."""

    coeffs: np.ndarray
    iterations: np.ndarray
    rms_mv: np.ndarray
    used: np.ndarray
    singular: np.ndarray
    weak: list


def _scale(c):
    # column scales for the identifiability analysis and the step test: a coefficient's magnitude,
    # with a floor (c2 and c7 may sit near 0)
    return np.maximum(np.abs(c), np.array([1.0, 1.0, 1.0, 0.1, 0.01, 0.1, 0.01]))


def _fit_pair(r, th, ps, v, c0, settings: CalibrationSettings):
    thmax = np.radians(settings.theta_max_deg)
    w = weight(th, -thmax, thmax, settings.tau) * weight(r, settings.r_min_mm, settings.r_max_mm, settings.tau)
    w = np.where(np.isfinite(v) & (v < settings.v_max_v), w, 0.0)
    v = np.nan_to_num(v)
    c = np.array(c0, float)
    e = ltv_voltage(r, th, ps, c) - v
    cost = np.sum((w * e) ** 2)
    lam = settings.lambda0
    it = 0
    while it < settings.max_iterations:
        it += 1
        J = ltv_voltage_dc(r, th, ps, c)
        A = (J * (w * w)[:, None]).T @ J
        g = (J * (w * w)[:, None]).T @ e
        try:
            step = np.linalg.solve(A + lam * np.diag(np.diag(A)), g)
        except np.linalg.LinAlgError:
            break
        cn = c - step
        en = ltv_voltage(r, th, ps, cn) - v
        cost_n = np.sum((w * en) ** 2)
        small = np.max(np.abs(step) / _scale(c)) < settings.tolerance
        if np.isfinite(cost_n) and cost_n <= cost:
            c, e, cost = cn, en, cost_n
            lam = max(lam / 10, 1e-12)
        else:
            lam = min(lam * 10, 1e12)
        if small:
            break
    Js = ltv_voltage_dc(r, th, ps, c) * w[:, None] * _scale(c)[None, :]
    _, sv, vt = np.linalg.svd(Js, full_matrices=False)
    rel = sv / sv[0]
    weak = sorted({COEFF_NAMES[int(np.argmax(np.abs(vt[k])))] for k in range(7) if rel[k] < 1e-4})
    rms = float(np.sqrt(cost / max(np.sum(w * w), 1e-300)) * 1e3)
    return c, it, rms, int(np.sum(w > 0.5)), rel, weak


def calibrate(poses, voltages, layout: PairLayout, settings: CalibrationSettings = CalibrationSettings()) -> Calibration:
    """Fit every pair's coefficients to voltages (N, P) V at measured planar poses (N, 3) = (y mm,
    z mm, rx rad), starting from ``layout.coeffs`` (the nominal ones)."""
    poses, V = np.asarray(poses, float), np.asarray(voltages, float)
    if poses.ndim != 2 or poses.shape[1] != 3 or V.shape != (len(poses), layout.n_pairs):
        raise ValueError(f"calibrate: poses must be (N, 3) and voltages (N, {layout.n_pairs}); got {poses.shape} and {V.shape}")
    r, th, ps = pair_geometry(*planar_to_pose(poses), layout)
    out = [_fit_pair(r[:, i], th[:, i], ps[:, i], V[:, i], layout.coeffs[i], settings) for i in range(layout.n_pairs)]
    return Calibration(np.array([o[0] for o in out]), np.array([o[1] for o in out]), np.array([o[2] for o in out]),
                       np.array([o[3] for o in out]), np.array([o[4] for o in out]), [o[5] for o in out])
