"""Batch calibration of the pairs' coefficients and mounting poses from a trajectory of measured poses (SPEC 3).

SPEC 3: the same LM as the pose estimator, over all pair coefficients and the sensor/LED poses, from
a 37 s trajectory of measured (motion-capture) poses; data outside theta < 40 deg, r > 20 mm,
v < 0.8 V ignored; tau = 1/40. Here:

- the shell poses are given (the reference poses), so the pairs decouple: one LM per pair over its
  17 parameters (:data:`PARAM_NAMES`): the seven coefficients c1..c7; the LED's position on the shell
  (shell frame, mm) and the LTV's on the base (base frame, mm); and each one's axis, as two tilt
  parameters: axis = normalise(n0 + t_x e_x + t_y e_y), n0 the designed axis and e_x, e_y the unit
  vectors perpendicular to it nearest to x and y (t is the tangent of the tilt, ~ rad when small);
- the Jacobian is analytic: dv/dc (:func:`ltv.ltv_voltage_dc`) and, through the relative geometry
  d = R a + p - b, m = R n_led, n = n_ltv, dv/da = R^T dv/dd, dv/db = -dv/dd and the axes' tangent
  gradients of :func:`ltv.pair_model`;
- the step is the SPEC's, (J^T W^2 J + lambda diag(J^T W^2 J))^-1 J^T W^2 (f - v), in parameters
  scaled by their tolerances, solved by least squares (minimum norm: a direction the data do not
  see is not moved, rather than moved at random by round-off);
- theta and r enter through the SPEC's soft weights w = 1 / (1 + zeta) with tau = 1/40 on
  -40 < theta < 40 deg and 20 < r < ``r_max_mm`` (the estimator's 60 mm: the SPEC gives no far
  bound); the voltage bound is a hard mask. Interpretation (a choice): the SPEC's 0.8 V cut removes
  readings near its hardware's saturation; that range is not given, so the cut is a setting,
  ``v_max_v``, default 0.9 of this ADC's full scale (4.5 V of 5 V).

Identifiability (reported per pair, see :class:`Calibration`). With the weighted Jacobian J_s of
the fit, each column scaled by its parameter's tolerance (the spread a designer expects before
calibration: ``coefficient_tolerance`` of the coefficient, ``position_tolerance_mm``,
``tilt_tolerance_deg``), the Cramer-Rao bound of the least-squares fit under white noise sigma
(``noise_rms_mv``, SPEC 3's 0.7 mV at rest) is sigma^2 (J_s^T J_s)^+. A parameter is *not
identifiable* when its bound's standard deviation exceeds its tolerance (the data cannot tell it
better than the datasheet does), or when its column is identically zero. On SPEC 3's planar
trajectories (y, z, theta_x), 37 s of general motion at 80 Hz, 0.7 mV (tests/test_cls_calibration.py,
and ``cls_identifiability.txt`` of ``mlsim run scenes/cls/general.toml``), the finding is:

- rank 13 of 17 per pair: the LED's and the LTV's x positions and their tilts towards x have
  identically zero columns. The motion is in the yz plane and mirror-symmetric in x: a pair mounted
  with an x offset +dx reads exactly what one mounted with -dx reads, so the voltages are even in
  these four parameters and their first derivatives vanish at the designed (x = 0) mounting; an
  offset enters only as dx^2 / (2 r) in r (0.003 mm for dx = 0.5 mm), which c3 absorbs. They are
  held at the design and never identifiable from planar data;
- of the 13 others, two or three directions have singular values 1e-4 to 1e-6 of the largest (and
  a Cramer-Rao bound above one tolerance): the near-field and offset terms (c2, c3, c7: an offset
  r -> r + dz turns r^2 + c2 r + c3 into r^2 + (c2 + 2 dz) r + ..., and c7 trades with the far
  field's c1 / r^2 over the narrow 25-40 mm range), the LTV's angular response (c5, c6 against c1:
  psi stays within ~20 deg, where 1 + c5 cos(c6 psi) is nearly a constant factor), and in some
  pairs c6 against the LTV's tilt. Every coefficient but c4 takes part, so c1, c2, c3, c5, c6 and c7
  are *individually* not identifiable once the mounting is free (their bounds are 2 to 20
  tolerances), although the voltages they predict are (the residual is the noise, and poses from
  the calibrated pairs have under 3 % of the nominal pairs' error, tests/test_cls_calibration.py);
- identifiable (bound under one tolerance, 0.1 to ~1): c4, the LED's and LTV's y and z positions
  and their tilts within the yz plane (the LED's z is borderline, ~1, in some pairs: it trades
  with c1 and c2 through r).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from other_sensors.cls.estimator import weight
from other_sensors.cls.ltv import PairLayout, pair_model, planar_to_pose, quat_to_matrix

__all__ = ["CalibrationSettings", "Calibration", "calibrate", "calibration_jacobian", "COEFF_NAMES", "MOUNT_NAMES",
           "PARAM_NAMES", "mount_params", "with_mounts", "tolerances"]

COEFF_NAMES = ("c1", "c2", "c3", "c4", "c5", "c6", "c7")
MOUNT_NAMES = ("led_x_mm", "led_y_mm", "led_z_mm", "led_tilt_x", "led_tilt_y",
               "ltv_x_mm", "ltv_y_mm", "ltv_z_mm", "ltv_tilt_x", "ltv_tilt_y")
PARAM_NAMES = COEFF_NAMES + MOUNT_NAMES
_LED_POS, _LED_TILT, _LTV_POS, _LTV_TILT = slice(7, 10), slice(10, 12), slice(12, 15), slice(15, 17)


@dataclass(frozen=True)
class CalibrationSettings:
    """The calibration's constants (SPEC 3 values where it gives them). ``fit_mounting``: also fit
    the LED and LTV positions and axes (SPEC 3); off, only the coefficients."""

    tau: float = 1.0 / 40.0
    theta_max_deg: float = 40.0
    r_min_mm: float = 20.0
    r_max_mm: float = 60.0
    v_max_v: float = 4.5
    fit_mounting: bool = True
    # A choice: calibration is offline, so it runs to a tight step (in tolerance units, not the 1e-4
    # of the real-time estimator) with room for many damped steps from the nominal parameters.
    tolerance: float = 1e-9
    max_iterations: int = 200
    lambda0: float = 1e-3
    # Tolerances (a choice: the part-to-part spread of the scenes, 3 %, placement to 0.5 mm and
    # axes to 2 deg) and the noise for the identifiability analysis (SPEC 3: 0.7 mV RMS at rest).
    coefficient_tolerance: float = 0.03
    position_tolerance_mm: float = 0.5
    tilt_tolerance_deg: float = 2.0
    noise_rms_mv: float = 0.7
    chi2_tolerance: float = 0.1


@dataclass
class Calibration:
    """The fit and what the data can tell.

    coeffs (P, 7); layout, the nominal layout with the fitted coefficients and mounting poses;
    params (P, 17) in :data:`PARAM_NAMES` order; iterations (P,); rms_mv (P,) weighted residual RMS;
    used (P,) samples with weight > 1/2; singular (P, 17, or 7 without the mounting) singular values
    of the tolerance-scaled, weighted Jacobian over the largest; crlb (P, 17) Cramer-Rao standard
    deviation of each parameter over its tolerance (inf: no first-order effect at all; NaN: not
    fitted); frozen (P, 17) bool, parameters held at
    their start because their column is identically zero; weak (P,) lists of the parameters that are
    not identifiable (crlb > 1); directions (P,) lists of the weak directions (those whose bound
    exceeds one tolerance): (relative singular value, {parameter: component} of its three largest).
    """

    coeffs: np.ndarray
    layout: PairLayout
    params: np.ndarray
    iterations: np.ndarray
    rms_mv: np.ndarray
    used: np.ndarray
    singular: np.ndarray
    crlb: np.ndarray
    frozen: np.ndarray
    weak: list
    directions: list = field(default_factory=list)


def _tangent_basis(n0):
    """(e_x, e_y): unit vectors perpendicular to the unit axis n0, nearest to x and to y."""
    n0 = np.asarray(n0, float)
    e1 = np.array([1.0, 0.0, 0.0]) - n0[0] * n0
    if np.linalg.norm(e1) < 1e-6:
        e1 = np.array([0.0, 0.0, 1.0]) - n0[2] * n0
    e1 /= np.linalg.norm(e1)
    e2 = np.array([0.0, 1.0, 0.0]) - n0[1] * n0 - e1[1] * e1
    if np.linalg.norm(e2) < 1e-6:
        e2 = np.cross(n0, e1)
    return e1, e2 / np.linalg.norm(e2)


def _axis(n0, t):
    """Axis (3,) of tilt parameters t (2,) about the designed axis n0, and d axis / d t (3, 2)."""
    e1, e2 = _tangent_basis(n0)
    u = n0 + t[0] * e1 + t[1] * e2
    nu = np.linalg.norm(u)
    n = u / nu
    proj = np.eye(3) - np.outer(n, n)
    return n, np.stack([proj @ e1, proj @ e2], axis=1) / nu


def _tilts(n0, n):
    """The tilt parameters (2,) that turn the designed axis n0 into the unit axis n (n . n0 > 0)."""
    e1, e2 = _tangent_basis(n0)
    u = n / np.dot(n, n0)
    return np.array([np.dot(u, e1), np.dot(u, e2)])


def mount_params(layout: PairLayout, nominal: PairLayout) -> np.ndarray:
    """The parameters (P, 17) of ``layout`` (:data:`PARAM_NAMES`), tilts measured from ``nominal``'s axes."""
    out = np.empty((layout.n_pairs, len(PARAM_NAMES)))
    for i in range(layout.n_pairs):
        out[i, :7] = layout.coeffs[i]
        out[i, _LED_POS] = layout.led_pos[i]
        out[i, _LED_TILT] = _tilts(nominal.led_axis[i], layout.led_axis[i])
        out[i, _LTV_POS] = layout.ltv_pos[i]
        out[i, _LTV_TILT] = _tilts(nominal.ltv_axis[i], layout.ltv_axis[i])
    return out


def with_mounts(nominal: PairLayout, params) -> PairLayout:
    """``nominal`` with the coefficients and mounting poses of ``params`` (P, 17), tilts from its axes."""
    params = np.asarray(params, float)
    if params.shape != (nominal.n_pairs, len(PARAM_NAMES)):
        raise ValueError(f"params: expected shape ({nominal.n_pairs}, {len(PARAM_NAMES)}), got {params.shape}")
    led_axis = np.array([_axis(nominal.led_axis[i], params[i, _LED_TILT])[0] for i in range(nominal.n_pairs)])
    ltv_axis = np.array([_axis(nominal.ltv_axis[i], params[i, _LTV_TILT])[0] for i in range(nominal.n_pairs)])
    return PairLayout(np.ascontiguousarray(params[:, _LED_POS]), led_axis, np.ascontiguousarray(params[:, _LTV_POS]), ltv_axis,
                      nominal.rest_p, np.ascontiguousarray(params[:, :7]))


def tolerances(nominal_coeffs, settings: CalibrationSettings) -> np.ndarray:
    """Each parameter's tolerance (17,): the coefficient's fraction (c2, nominally 0 mm, relative to
    20 mm; c7 to 0.05 V), positions in mm, tilts as their tangent."""
    c = np.maximum(np.abs(np.asarray(nominal_coeffs, float)), np.array([0.0, 20.0, 0.0, 0.0, 0.0, 0.0, 0.05]))
    tilt = np.tan(np.radians(settings.tilt_tolerance_deg))
    return np.r_[settings.coefficient_tolerance * c, np.full(3, settings.position_tolerance_mm), np.full(2, tilt),
                 np.full(3, settings.position_tolerance_mm), np.full(2, tilt)]


def calibration_jacobian(theta, nominal: PairLayout, P, R):
    """Voltages (N, K) and their Jacobian (N, K, 17) with respect to the pairs' parameters ``theta``
    (K, 17) (:data:`PARAM_NAMES`, tilts from ``nominal``'s axes) at shell poses P (N, 3) mm and
    R (N, 3, 3). Also returns r (N, K) mm and theta (N, K) rad (for the weights)."""
    theta = np.asarray(theta, float)
    axes = [(_axis(nominal.led_axis[i], theta[i, _LED_TILT]), _axis(nominal.ltv_axis[i], theta[i, _LTV_TILT]))
            for i in range(len(theta))]
    m0, dm0 = np.array([a[0][0] for a in axes]), np.array([a[0][1] for a in axes])  # (K, 3), (K, 3, 2)
    n, dn = np.array([a[1][0] for a in axes]), np.array([a[1][1] for a in axes])
    d = np.einsum("nij,kj->nki", R, theta[:, _LED_POS]) + P[:, None, :] - theta[None, :, _LTV_POS]
    m = np.einsum("nij,kj->nki", R, m0)
    v, gd, gm, gn, gc, r, th, _ = pair_model(d, m, np.broadcast_to(n, d.shape), theta[:, :7])
    J = np.empty(v.shape + (len(PARAM_NAMES),))
    J[..., :7] = gc
    J[..., _LED_POS] = np.einsum("nji,nkj->nki", R, gd)  # R^T dv/dd
    J[..., _LED_TILT] = np.einsum("nki,kit->nkt", np.einsum("nji,nkj->nki", R, gm), dm0)  # dm = R d(n_led)
    J[..., _LTV_POS] = -gd
    J[..., _LTV_TILT] = np.einsum("nki,kit->nkt", gn, dn)
    return v, J, r, th


def _fit(theta0, nominal: PairLayout, P, R, V, tol, settings: CalibrationSettings):
    """The SPEC's LM for every pair at once (the pairs are independent; each has its own lambda and
    stops on its own); returns (theta (K, 17), iterations (K,), final J_s, w, e, frozen (K, 17))."""
    thmax = np.radians(settings.theta_max_deg)
    valid = np.isfinite(V) & (V < settings.v_max_v)
    V = np.nan_to_num(V)
    K = len(theta0)
    sigma = settings.noise_rms_mv * 1e-3

    def evaluate(theta):
        f, J, r, th = calibration_jacobian(theta, nominal, P, R)
        w = weight(th, -thmax, thmax, settings.tau) * weight(r, settings.r_min_mm, settings.r_max_mm, settings.tau)
        w = np.where(valid, w, 0.0)
        e = f - V
        return e, J * tol, w, np.sum((w * e) ** 2, axis=0)

    theta = np.array(theta0, float)
    e, Js, w, cost = evaluate(theta)
    # structurally unobservable parameters: a column that is identically zero at the start (e.g. the
    # x offsets on a planar, x-mirror-symmetric trajectory) is held; LM's diag(J^T J) would be singular
    colnorm = np.linalg.norm(Js * w[..., None], axis=0)  # (K, 17)
    frozen = colnorm <= 1e-9 * colnorm.max(axis=1, keepdims=True)
    free = ~frozen
    if not settings.fit_mounting:
        free[:, 7:] = False
    lam = np.full(K, settings.lambda0)
    iterations = np.zeros(K, int)
    active = np.ones(K, bool)
    while active.any():
        cand = theta.copy()
        steps = np.zeros(K)
        for k in np.flatnonzero(active):
            iterations[k] += 1
            Jf = Js[:, k][:, free[k]] * w[:, k, None]
            A = Jf.T @ Jf
            g = Jf.T @ (w[:, k] * e[:, k])
            step = np.linalg.lstsq(A + lam[k] * np.diag(np.diag(A)), g, rcond=1e-14)[0]
            cand[k, free[k]] -= step * tol[free[k]]
            steps[k] = np.max(np.abs(step))
        en, Jn, wn, cost_n = evaluate(cand)
        gain = cost - cost_n
        better = active & np.isfinite(cost_n) & (cost_n <= cost)
        theta[better], cost[better] = cand[better], cost_n[better]
        e[:, better], Js[:, better], w[:, better] = en[:, better], Jn[:, better], wn[:, better]
        lam = np.where(better, np.maximum(lam / 10, 1e-12), np.where(active, np.minimum(lam * 10, 1e12), lam))
        # converged: a step under the tolerance, or an accepted one that lowers the chi-square by
        # less than ``chi2_tolerance`` (the noise cannot tell the two fits apart; without it, LM
        # crawls along the curved, flat valleys of the weak directions for hundreds of steps)
        done = (steps < settings.tolerance) | (better & (gain < settings.chi2_tolerance * sigma ** 2))
        active &= ~done & (iterations < settings.max_iterations)
    return theta, iterations, Js, w, e, frozen


def _identifiability(Js, w, frozen, fitted, sigma):
    """Relative singular values (n_fitted,), Cramer-Rao std over tolerance (17,; inf for a held
    parameter, NaN for one not fitted), the weak parameters and the weak directions of one pair's
    tolerance-scaled Jacobian Js (N, 17) with weights w (N,), over the ``fitted`` parameters."""
    cols = np.flatnonzero(fitted)
    Jw = Js[:, cols] * w[:, None]
    _, sv, vt = np.linalg.svd(Jw, full_matrices=False)
    live = cols[~frozen[cols]]
    cov = np.linalg.pinv((Js[:, live] * w[:, None]).T @ (Js[:, live] * w[:, None]), rcond=1e-15, hermitian=True)
    crlb = np.full(len(PARAM_NAMES), np.nan)
    crlb[cols] = np.inf
    crlb[live] = sigma * np.sqrt(np.maximum(np.diag(cov), 0.0))
    weak = [PARAM_NAMES[k] for k in cols if crlb[k] > 1.0]
    directions = []
    for k in range(len(sv)):
        if sv[k] < sigma:  # along this direction the bound exceeds one tolerance
            top = np.argsort(-np.abs(vt[k]))[:3]
            directions.append((float(sv[k] / sv[0]), {PARAM_NAMES[cols[j]]: round(float(vt[k, j]), 3) for j in top}))
    return sv / sv[0], crlb, weak, directions


def calibrate(poses, voltages, layout: PairLayout, settings: CalibrationSettings = CalibrationSettings()) -> Calibration:
    """Fit every pair's coefficients and (``settings.fit_mounting``) its LED's and LTV's mounting
    poses to voltages (N, P) V at measured planar poses (N, 3) = (y mm, z mm, rx rad), starting from
    ``layout`` (the nominal, as-designed pairs). See the module for the method and identifiability."""
    poses, V = np.asarray(poses, float), np.asarray(voltages, float)
    if poses.ndim != 2 or poses.shape[1] != 3 or V.shape != (len(poses), layout.n_pairs):
        raise ValueError(f"calibrate: poses must be (N, 3) and voltages (N, {layout.n_pairs}); got {poses.shape} and {V.shape}")
    p, q = planar_to_pose(poses)
    R = quat_to_matrix(q)
    tol = tolerances(layout.coeffs.mean(axis=0), settings)
    theta, iterations, Js, w, e, frozen = _fit(mount_params(layout, layout), layout, p, R, V, tol, settings)
    fitted = np.arange(len(PARAM_NAMES)) < (len(PARAM_NAMES) if settings.fit_mounting else 7)
    ident = [_identifiability(Js[:, k], w[:, k], frozen[k], fitted, settings.noise_rms_mv * 1e-3) for k in range(layout.n_pairs)]
    rms = np.sqrt(np.sum((w * e) ** 2, axis=0) / np.maximum(np.sum(w * w, axis=0), 1e-300)) * 1e3
    return Calibration(with_mounts(layout, theta).coeffs, with_mounts(layout, theta), theta, iterations, rms,
                       np.sum(w > 0.5, axis=0), np.array([i[0] for i in ident]), np.array([i[1] for i in ident]),
                       frozen, [i[2] for i in ident], [i[3] for i in ident])
