"""Pose of the CLS shell from the pairs' voltages: motion detection, then weighted Levenberg-Marquardt (SPEC 3).

Per sample, before any pose estimate, motion is detected as a voltage change against rest (the mean
of the rest window): |v - v_rest| above a threshold on any usable pair. At rest the estimate is the
rest pose (0 iterations). In motion, LM minimises || W (f(mu) - v) ||^2 over the planar pose
mu = (y mm, z mm, rx rad), warm-started from the previous estimate, with the step

    delta = (J^T W^2 J + lambda diag(J^T W^2 J))^-1 J^T W^2 (f - v),  mu <- mu - delta

and per-pair weights w = w_r(r) w_theta(theta), w(x) = 1 / (1 + zeta(x)),
zeta(x) = exp((x_m - x) / (tau (x_M - x_m))) + exp((x - x_M) / (tau (x_M - x_m))), with
15 < r < 60 mm, -45 < theta < 45 deg and tau = 1/70. The weights are evaluated at the current
iterate and held fixed inside a step (their derivative is not in J: an iteratively reweighted fit).
lambda starts at ``lambda0``, is divided by 10 on an accepted step and multiplied by 10 on a
rejected one. It stops when the step's norm (mm and rad together) is under the tolerance (1e-4) or
after 50 iterations (a rejected step counts as an iteration).

Planar and 6-DoF: with the pairs in one line along y (SPEC 3's prototype), x, the rotation about y
and the rotation about z move no LED relative to its LTV to first order, so (y, z, rx) is all that
collinear pairs can observe: :func:`estimate_poses`. For pairs off a line (:func:`ltv.ring_layout`),
:func:`estimate_poses6` runs the same LM, detector and bad-input rules over the full pose
(p, R), with the step (dp, dphi) applied as p <- p - dp, R <- exp(-[dphi]x) R (the Jacobian's left
rotation increment) and poses reported as (x, y, z mm, rotation vector rad).

Bad input (documented degraded estimate, never a silent wrong pose):
- a voltage outside the ADC's range (below 0 or above full scale): ValueError (wrong units?);
- a NaN sample or a pair at a rail (0 V or full scale: dead, disconnected or saturated): that pair
  is left out of that sample's fit (weight 0) and out of motion detection;
- fewer usable pairs than the pose has unknowns (3): the estimate is NaN with status NO_DATA (the
  motion detector does not call such a sample "at rest" either), and the next sample warm-starts
  from the last estimate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit

from other_sensors.cls.ltv import PairLayout
from other_sensors.cls.ltv_kernel import pairs_kernel

__all__ = ["LmSettings", "Estimates", "weight", "estimate_poses", "estimate_pose", "estimate_poses6", "estimate_pose6",
           "usable", "rest_voltages",
           "CONVERGED", "MAX_ITERATIONS", "NO_DATA", "AT_REST", "SINGULAR", "STATUS_NAMES"]

CONVERGED, MAX_ITERATIONS, NO_DATA, AT_REST, SINGULAR = 0, 1, 2, 3, 4
STATUS_NAMES = {CONVERGED: "converged", MAX_ITERATIONS: "max_iterations", NO_DATA: "too_few_pairs",
                AT_REST: "at_rest", SINGULAR: "singular"}


@dataclass(frozen=True)
class LmSettings:
    """The estimator's constants (SPEC 3 values by default). Angles in degrees, lengths in mm."""

    tau: float = 1.0 / 70.0
    tolerance: float = 1e-4
    max_iterations: int = 50
    r_min_mm: float = 15.0
    r_max_mm: float = 60.0
    theta_max_deg: float = 45.0
    # A choice (the SPEC gives no starting lambda): 1e-5. A warm-started estimate often stops after
    # one step (its step is already under the tolerance); with lambda = 1e-3 that damped step left up
    # to 8e-6 mm of error along the ill-conditioned y / theta_x direction of noise-free data, with
    # 1e-5 under 5e-7 mm, at the same iteration counts.
    lambda0: float = 1e-5
    # A choice: 5 mV is 7 sigma of the 0.7 mV rest noise, so false alarms at rest are ~1e-11 per
    # sample and pair, while a 0.05 mm compression already moves a pair by ~5 mV.
    motion_threshold_mv: float = 5.0
    # SPEC 3: warm start from the previous estimate. Off (for benchmarks only): every estimate starts
    # from the rest pose, a cold start.
    warm_start: bool = True


@dataclass
class Estimates:
    """poses (N, 3) = (y mm, z mm, rx rad), NaN where no estimate; iterations (N,) int; status (N,)
    int (see STATUS_NAMES); moving (N,) bool, the motion detector's output."""

    poses: np.ndarray
    iterations: np.ndarray
    status: np.ndarray
    moving: np.ndarray


@njit(cache=True)
def _weight(x, lo, hi, tau):
    span = tau * (hi - lo)
    return 1.0 / (1.0 + np.exp((lo - x) / span) + np.exp((x - hi) / span))


def weight(x, lo, hi, tau):
    """w(x) = 1 / (1 + zeta(x)) of SPEC 3 (vectorised): ~1 inside (lo, hi), 1/2 at the bounds, ~0 outside."""
    x = np.asarray(x, float)
    span = tau * (hi - lo)
    with np.errstate(over="ignore"):
        return 1.0 / (1.0 + np.exp((lo - x) / span) + np.exp((x - hi) / span))


@njit(cache=True)
def _eval(mu, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, Jout, e, w, v, J6, r, th, ps):
    """Residual e = f - v, weights w and the planar Jacobian Jout (P, 3) at mu; returns the weighted cost."""
    p = np.array([0.0, mu[0], mu[1]])
    c, s = np.cos(mu[2]), np.sin(mu[2])
    R = np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])
    pairs_kernel(p, R, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, v, J6, r, th, ps, True)
    cost = 0.0
    for i in range(vm.shape[0]):
        if ok[i]:
            w[i] = _weight(r[i], rmin, rmax, tau) * _weight(th[i], -thmax, thmax, tau)
            e[i] = v[i] - vm[i]
        else:
            w[i] = 0.0
            e[i] = 0.0
        for k in range(3):
            Jout[i, k] = J6[i, k + 1]  # planar columns: p_y, p_z, phi_x
        cost += (w[i] * e[i]) ** 2
    return cost


@njit(cache=True)
def _solve3(A, b, x):
    """Gaussian elimination with partial pivoting of a 3 x 3 system; False if singular."""
    M = np.empty((3, 4))
    for i in range(3):
        for j in range(3):
            M[i, j] = A[i, j]
        M[i, 3] = b[i]
    scale = max(abs(A[0, 0]), abs(A[1, 1]), abs(A[2, 2]))
    if not scale > 0.0:
        return False
    for col in range(3):
        piv = col
        for row in range(col + 1, 3):
            if abs(M[row, col]) > abs(M[piv, col]):
                piv = row
        if abs(M[piv, col]) <= 1e-14 * scale:
            return False
        if piv != col:
            for j in range(4):
                M[col, j], M[piv, j] = M[piv, j], M[col, j]
        for row in range(col + 1, 3):
            f = M[row, col] / M[col, col]
            for j in range(col, 4):
                M[row, j] -= f * M[col, j]
    for i in range(2, -1, -1):
        acc = M[i, 3]
        for j in range(i + 1, 3):
            acc -= M[i, j] * x[j]
        x[i] = acc / M[i, i]
    return True


@njit(cache=True)
def _damped_normal_equations(J, w, e, lam, A, Ad, g):
    """The weighted LM system of SPEC 3 in place: A = J^T W^2 J, g = J^T W^2 e, Ad = A + lam diag(A)
    (J (n, k), w, e (n,); the planar and the 6-DoF solver share it)."""
    n, k = J.shape
    for a in range(k):
        g[a] = 0.0
        for b in range(k):
            A[a, b] = 0.0
        for i in range(n):
            ww = w[i] * w[i]
            g[a] += J[i, a] * ww * e[i]
            for b in range(k):
                A[a, b] += J[i, a] * ww * J[i, b]
    for a in range(k):
        for b in range(k):
            Ad[a, b] = A[a, b]
        Ad[a, a] += lam * A[a, a]


@njit(cache=True)
def _lm(vm, ok, mu0, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol, max_iter, lam0, mu_out):
    """One LM estimate; writes mu_out (3,) and returns (iterations, status)."""
    n = vm.shape[0]
    n_ok = 0
    for i in range(n):
        if ok[i]:
            n_ok += 1
    if n_ok < 3:
        for k in range(3):
            mu_out[k] = np.nan
        return 0, NO_DATA
    J, Jn = np.empty((n, 3)), np.empty((n, 3))
    e, en, w, wn = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    v, J6 = np.empty(n), np.zeros((n, 6))
    r, th, ps = np.empty(n), np.empty(n), np.empty(n)
    mu = mu0.copy()
    mun = np.empty(3)
    A, g, step = np.empty((3, 3)), np.empty(3), np.empty(3)
    Ad = np.empty((3, 3))
    cost = _eval(mu, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, J, e, w, v, J6, r, th, ps)
    lam = lam0
    status = MAX_ITERATIONS
    it = 0
    while it < max_iter:
        it += 1
        _damped_normal_equations(J, w, e, lam, A, Ad, g)
        if not _solve3(Ad, g, step):
            status = SINGULAR
            break
        for k in range(3):
            mun[k] = mu[k] - step[k]
        cost_n = _eval(mun, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, Jn, en, wn, v, J6, r, th, ps)
        small = np.sqrt(step[0] ** 2 + step[1] ** 2 + step[2] ** 2) < tol
        if cost_n <= cost:
            mu, mun = mun, mu
            J, Jn = Jn, J
            e, en = en, e
            w, wn = wn, w
            cost = cost_n
            lam = max(lam / 10.0, 1e-12)
        else:
            lam = min(lam * 10.0, 1e12)
        if small:
            status = CONVERGED
            break
    for k in range(3):
        mu_out[k] = mu[k]
    return it, status


@njit(cache=True)
def _series(V, ok, v_rest, mu_rest, thr, warm, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol, max_iter, lam0):
    N, P = V.shape
    poses = np.empty((N, 3))
    iters = np.zeros(N, np.int64)
    status = np.empty(N, np.int64)
    moving = np.zeros(N, np.bool_)
    mu = mu_rest.copy()
    out = np.empty(3)
    for s in range(N):
        n_ok = 0
        for i in range(P):
            if ok[s, i]:
                n_ok += 1
                if abs(V[s, i] - v_rest[i]) > thr:
                    moving[s] = True
        if n_ok < 3:  # neither rest nor a pose can be told from fewer pairs than unknowns
            poses[s, :] = np.nan
            status[s] = NO_DATA
            continue
        if not moving[s]:
            poses[s] = mu_rest
            status[s] = AT_REST
            mu[:] = mu_rest
            continue
        it, st = _lm(V[s], ok[s], mu if warm else mu_rest, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax,
                     tol, max_iter, lam0, out)
        poses[s] = out
        iters[s] = it
        status[s] = st
        if st != NO_DATA:
            mu[:] = out  # warm start; after a sample with no data keep the last estimate
    return poses, iters, status, moving


def usable(voltages, adc_range_v: float) -> np.ndarray:
    """Which samples (same shape) are usable: finite and strictly between the ADC's rails. Raises
    ValueError for values the ADC cannot produce (below 0 V or above ``adc_range_v``)."""
    V = np.asarray(voltages, float)
    finite = np.isfinite(V)
    top = adc_range_v * (1 - 1e-12)  # the full-scale code, allowing for its rounding to a float
    bad = finite & ((V < 0.0) | (V > adc_range_v * (1 + 1e-12)))
    if bad.any():
        raise ValueError(f"voltages: {int(bad.sum())} samples lie outside the ADC range 0..{adc_range_v} V "
                         f"(e.g. {V[bad][0]!r}); give volts from this ADC, or set sensor.noise.adc_range_v")
    return finite & (V > 0.0) & (V < top)


def rest_voltages(voltages, ok) -> np.ndarray:
    """Mean voltage per pair (P,) over rest samples (n, P), usable ones only; NaN for a pair with none."""
    V = np.where(ok, voltages, 0.0)
    count = ok.sum(axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, V.sum(axis=0) / np.maximum(count, 1), np.nan)


def _args(layout: PairLayout, settings: LmSettings):
    return (layout.led_pos, layout.led_axis, layout.ltv_pos, layout.ltv_axis, np.ascontiguousarray(layout.coeffs, dtype=float),
            float(settings.tau), float(settings.r_min_mm), float(settings.r_max_mm), float(np.radians(settings.theta_max_deg)),
            float(settings.tolerance), int(settings.max_iterations), float(settings.lambda0))


def estimate_pose(v, layout: PairLayout, mu0, settings: LmSettings = LmSettings(), ok=None):
    """One LM estimate from voltages v (P,) V, warm start mu0 (3,) = (y mm, z mm, rx rad); ``ok`` (P,)
    which pairs to use (default: all finite). Returns (pose (3,), iterations, status)."""
    v = np.asarray(v, float)
    if v.shape != (layout.n_pairs,):
        raise ValueError(f"voltages: expected shape ({layout.n_pairs},), got {v.shape}")
    ok = np.isfinite(v) if ok is None else np.asarray(ok, bool) & np.isfinite(v)
    out = np.empty(3)
    it, st = _lm(np.where(ok, v, 0.0), ok, np.asarray(mu0, float), *_args(layout, settings), out)
    return out, int(it), int(st)


def estimate_poses(voltages, layout: PairLayout, settings: LmSettings, n_rest: int, adc_range_v: float) -> Estimates:
    """Estimates of a series of voltages (N, P) V sampled at a fixed rate, the first ``n_rest``
    samples at rest (they give v_rest and the rest pose, found by LM from the layout's nominal rest
    pose). See the module for the detector, the fit and how bad samples are handled."""
    V = np.asarray(voltages, float)
    if V.ndim != 2 or V.shape[1] != layout.n_pairs:
        raise ValueError(f"voltages: expected shape (N, {layout.n_pairs}), got {V.shape}")
    if not 1 <= n_rest <= len(V):
        raise ValueError(f"n_rest = {n_rest}: the rest window must hold 1 to {len(V)} samples (sensor.trajectory.rest_s)")
    ok = usable(V, adc_range_v)
    v_rest = rest_voltages(V[:n_rest], ok[:n_rest])
    ok = ok & np.isfinite(v_rest)[None, :]  # a pair with no usable rest sample is left out throughout
    nominal = np.array([layout.rest_p[1], layout.rest_p[2], 0.0])
    mu_rest, _, st = estimate_pose(np.nan_to_num(v_rest), layout, nominal, settings, ok=np.isfinite(v_rest))
    if st == NO_DATA:
        raise ValueError(f"voltages: fewer than 3 pairs give usable samples in the rest window "
                         f"({int(np.isfinite(v_rest).sum())} of {layout.n_pairs}); no pose can be estimated")
    poses, iters, status, moving = _series(np.where(ok, V, 0.0), ok, np.nan_to_num(v_rest), mu_rest,
                                           settings.motion_threshold_mv * 1e-3, bool(settings.warm_start), *_args(layout, settings))
    return Estimates(poses, iters, status, moving)


# ----------------------------------------------------------------------------- the full 6-DoF pose
@njit(cache=True)
def _solve_n(A, b, x):
    """Gaussian elimination with partial pivoting of an n x n system; False if singular."""
    n = A.shape[0]
    M = np.empty((n, n + 1))
    scale = 0.0
    for i in range(n):
        for j in range(n):
            M[i, j] = A[i, j]
        M[i, n] = b[i]
        scale = max(scale, abs(A[i, i]))
    if not scale > 0.0:
        return False
    for col in range(n):
        piv = col
        for row in range(col + 1, n):
            if abs(M[row, col]) > abs(M[piv, col]):
                piv = row
        if abs(M[piv, col]) <= 1e-14 * scale:
            return False
        if piv != col:
            for j in range(n + 1):
                M[col, j], M[piv, j] = M[piv, j], M[col, j]
        for row in range(col + 1, n):
            f = M[row, col] / M[col, col]
            for j in range(col, n + 1):
                M[row, j] -= f * M[col, j]
    for i in range(n - 1, -1, -1):
        acc = M[i, n]
        for j in range(i + 1, n):
            acc -= M[i, j] * x[j]
        x[i] = acc / M[i, i]
    return True


@njit(cache=True)
def _rotate_left(phi, R, out):
    """out = exp([phi]x) R (Rodrigues)."""
    a = np.sqrt(phi[0] ** 2 + phi[1] ** 2 + phi[2] ** 2)
    E = np.eye(3)
    if a > 0.0:
        k = phi / a
        K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
        E = E + np.sin(a) * K + (1.0 - np.cos(a)) * (K @ K)
    for i in range(3):
        for j in range(3):
            out[i, j] = E[i, 0] * R[0, j] + E[i, 1] * R[1, j] + E[i, 2] * R[2, j]


@njit(cache=True)
def _eval6(p, R, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, J, e, w, v, r, th, ps):
    pairs_kernel(p, R, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, v, J, r, th, ps, True)
    cost = 0.0
    for i in range(vm.shape[0]):
        if ok[i]:
            w[i] = _weight(r[i], rmin, rmax, tau) * _weight(th[i], -thmax, thmax, tau)
            e[i] = v[i] - vm[i]
        else:
            w[i] = 0.0
            e[i] = 0.0
        cost += (w[i] * e[i]) ** 2
    return cost


@njit(cache=True)
def _lm6(vm, ok, p0, R0, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol, max_iter, lam0, p_out, R_out):
    """One 6-DoF LM estimate from (p0, R0); writes p_out (3,), R_out (3, 3); returns (iterations, status)."""
    n = vm.shape[0]
    n_ok = 0
    for i in range(n):
        if ok[i]:
            n_ok += 1
    if n_ok < 6:
        p_out[:] = np.nan
        R_out[:, :] = np.nan
        return 0, NO_DATA
    J, Jn = np.zeros((n, 6)), np.zeros((n, 6))
    e, en, w, wn = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    v, r, th, ps = np.empty(n), np.empty(n), np.empty(n), np.empty(n)
    p, R = p0.copy(), R0.copy()
    pn, Rn = np.empty(3), np.empty((3, 3))
    A, Ad, g, step = np.empty((6, 6)), np.empty((6, 6)), np.empty(6), np.empty(6)
    cost = _eval6(p, R, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, J, e, w, v, r, th, ps)
    lam = lam0
    status = MAX_ITERATIONS
    it = 0
    while it < max_iter:
        it += 1
        _damped_normal_equations(J, w, e, lam, A, Ad, g)
        if not _solve_n(Ad, g, step):
            status = SINGULAR
            break
        for k in range(3):
            pn[k] = p[k] - step[k]
        _rotate_left(-step[3:], R, Rn)
        cost_n = _eval6(pn, Rn, vm, ok, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, Jn, en, wn, v, r, th, ps)
        small = np.sqrt(np.sum(step ** 2)) < tol
        if cost_n <= cost:
            p, pn = pn, p
            R, Rn = Rn, R
            J, Jn = Jn, J
            e, en = en, e
            w, wn = wn, w
            cost = cost_n
            lam = max(lam / 10.0, 1e-12)
        else:
            lam = min(lam * 10.0, 1e12)
        if small:
            status = CONVERGED
            break
    p_out[:] = p
    R_out[:, :] = R
    return it, status


@njit(cache=True)
def _series6(V, ok, v_rest, p_rest, R_rest, thr, warm, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol,
             max_iter, lam0):
    N, P = V.shape
    ps = np.empty((N, 3))
    Rs = np.empty((N, 3, 3))
    iters = np.zeros(N, np.int64)
    status = np.empty(N, np.int64)
    moving = np.zeros(N, np.bool_)
    p, R = p_rest.copy(), R_rest.copy()
    p_out, R_out = np.empty(3), np.empty((3, 3))
    for s in range(N):
        n_ok = 0
        for i in range(P):
            if ok[s, i]:
                n_ok += 1
                if abs(V[s, i] - v_rest[i]) > thr:
                    moving[s] = True
        if n_ok < 6:
            ps[s, :] = np.nan
            Rs[s, :, :] = np.nan
            status[s] = NO_DATA
            continue
        if not moving[s]:
            ps[s], Rs[s] = p_rest, R_rest
            status[s] = AT_REST
            p[:], R[:, :] = p_rest, R_rest
            continue
        if warm:
            it, st = _lm6(V[s], ok[s], p, R, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol, max_iter,
                          lam0, p_out, R_out)
        else:
            it, st = _lm6(V[s], ok[s], p_rest, R_rest, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, tau, rmin, rmax, thmax, tol,
                          max_iter, lam0, p_out, R_out)
        ps[s], Rs[s] = p_out, R_out
        iters[s] = it
        status[s] = st
        if st != NO_DATA:
            p[:], R[:, :] = p_out, R_out
    return ps, Rs, iters, status, moving


def _pose6(p, R):
    from other_sensors.cls.ltv import matrix_to_rotvec

    return np.concatenate([p, matrix_to_rotvec(R)], axis=-1)


def estimate_pose6(v, layout: PairLayout, pose0, settings: LmSettings = LmSettings(), ok=None):
    """One 6-DoF LM estimate from voltages v (P,) V, start pose0 (6,) = (x, y, z mm, rotation vector
    rad); ``ok`` (P,) which pairs to use. Returns (pose (6,), iterations, status); at least 6 pairs."""
    from other_sensors.cls.ltv import pose6_to_pose, quat_to_matrix

    v = np.asarray(v, float)
    if v.shape != (layout.n_pairs,):
        raise ValueError(f"voltages: expected shape ({layout.n_pairs},), got {v.shape}")
    ok = np.isfinite(v) if ok is None else np.asarray(ok, bool) & np.isfinite(v)
    p0, q0 = pose6_to_pose(np.asarray(pose0, float))
    p_out, R_out = np.empty(3), np.empty((3, 3))
    it, st = _lm6(np.where(ok, v, 0.0), ok, p0, quat_to_matrix(q0), *_args(layout, settings), p_out, R_out)
    return _pose6(p_out, R_out), int(it), int(st)


def estimate_poses6(voltages, layout: PairLayout, settings: LmSettings, n_rest: int, adc_range_v: float) -> Estimates:
    """The 6-DoF counterpart of :func:`estimate_poses`: poses (N, 6) = (x, y, z mm, rotation vector
    rad); the same detector and bad-input rules, with 6 usable pairs needed instead of 3."""
    V = np.asarray(voltages, float)
    if V.ndim != 2 or V.shape[1] != layout.n_pairs:
        raise ValueError(f"voltages: expected shape (N, {layout.n_pairs}), got {V.shape}")
    if not 1 <= n_rest <= len(V):
        raise ValueError(f"n_rest = {n_rest}: the rest window must hold 1 to {len(V)} samples (sensor.trajectory.rest_s)")
    ok = usable(V, adc_range_v)
    v_rest = rest_voltages(V[:n_rest], ok[:n_rest])
    ok = ok & np.isfinite(v_rest)[None, :]
    rest6, _, st = estimate_pose6(np.nan_to_num(v_rest), layout, np.r_[layout.rest_p, 0.0, 0.0, 0.0], settings, ok=np.isfinite(v_rest))
    if st == NO_DATA:
        raise ValueError(f"voltages: fewer than 6 pairs give usable samples in the rest window "
                         f"({int(np.isfinite(v_rest).sum())} of {layout.n_pairs}); no 6-DoF pose can be estimated")
    from other_sensors.cls.ltv import pose6_to_pose, quat_to_matrix

    p_rest, q_rest = pose6_to_pose(rest6)
    ps, Rs, iters, status, moving = _series6(np.where(ok, V, 0.0), ok, np.nan_to_num(v_rest), p_rest, quat_to_matrix(q_rest),
                                             settings.motion_threshold_mv * 1e-3, bool(settings.warm_start), *_args(layout, settings))
    return Estimates(_pose6(ps, Rs), iters, status, moving)
