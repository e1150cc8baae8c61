"""The LTV pairs' compiled kernel (numba): geometry eta = (r, theta, psi), voltages and analytic
Jacobians of all pairs for one shell pose; the model and conventions are those of
:mod:`other_sensors.cls.ltv` (mm, rad, V; Jacobian with respect to (dp, dphi), dphi a left rotation
increment). Shared by :mod:`ltv`'s vectorised functions and the estimator's LM loop.

Derivatives: with d = R a + p - b (LTV -> LED), m = R n_led, u_theta = -m.d / r, u_psi = n_ltv.d / r,
dv/du of cos(c a) is c sin(c a) / sin(a) = c^2 sinc(c a) / sinc(a), finite at a = 0 (where
d/da of arccos is not), and d(R a) = dphi x (R a), so g . d(R a) = dphi . ((R a) x g).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["pairs_kernel", "pairs_batch"]


@njit(cache=True, fastmath=False)
def _angle_factor(c, cos_a, sin_a):
    """cos(c a) and its derivative with respect to cos(a): c sin(c a) / sin(a) = c^2 sinc(c a)/sinc(a)
    (finite at a = 0, where d/da would need 1 / sin a)."""
    a = np.arctan2(sin_a, cos_a)
    ca = c * a
    s1 = np.sin(ca) / ca if ca != 0.0 else 1.0
    s0 = np.sin(a) / a if a != 0.0 else 1.0
    return np.cos(ca), c * c * s1 / s0, a


@njit(cache=True)
def pairs_kernel(p, R, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, v, J, r_out, theta_out, psi_out, want_j):
    """For one pose (p (3,), R (3, 3)): voltages v (P,), Jacobian J (P, 6) with respect to (dp, dphi)
    if want_j, and the geometry r (P,) mm, theta (P,), psi (P,) rad, all written in place."""
    n = ltv_pos.shape[0]
    for i in range(n):
        w = np.empty(3)  # R a: LED position relative to the shell origin, base frame
        m = np.empty(3)  # LED axis, base frame
        for k in range(3):
            w[k] = R[k, 0] * led_pos[i, 0] + R[k, 1] * led_pos[i, 1] + R[k, 2] * led_pos[i, 2]
            m[k] = R[k, 0] * led_axis[i, 0] + R[k, 1] * led_axis[i, 1] + R[k, 2] * led_axis[i, 2]
        d = np.empty(3)  # LTV -> LED
        for k in range(3):
            d[k] = w[k] + p[k] - ltv_pos[i, k]
        r = np.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        nd = ltv_axis[i, 0] * d[0] + ltv_axis[i, 1] * d[1] + ltv_axis[i, 2] * d[2]
        md = m[0] * d[0] + m[1] * d[1] + m[2] * d[2]
        u_psi = nd / r
        u_th = -md / r
        # sines from cross products: accurate near 0, where arccos is not
        cx = m[1] * d[2] - m[2] * d[1]
        cy = m[2] * d[0] - m[0] * d[2]
        cz = m[0] * d[1] - m[1] * d[0]
        s_th = np.sqrt(cx * cx + cy * cy + cz * cz) / r
        ex = ltv_axis[i, 1] * d[2] - ltv_axis[i, 2] * d[1]
        ey = ltv_axis[i, 2] * d[0] - ltv_axis[i, 0] * d[2]
        ez = ltv_axis[i, 0] * d[1] - ltv_axis[i, 1] * d[0]
        s_psi = np.sqrt(ex * ex + ey * ey + ez * ez) / r
        c1, c2, c3, c4, c5, c6, c7 = (coeffs[i, 0], coeffs[i, 1], coeffs[i, 2], coeffs[i, 3], coeffs[i, 4],
                                      coeffs[i, 5], coeffs[i, 6])
        den = r * r + c2 * r + c3
        g = c1 / den
        a, da_du, th = _angle_factor(c4, u_th, s_th)
        cp, dcp_du, ps = _angle_factor(c6, u_psi, s_psi)
        b = 1.0 + c5 * cp
        v[i] = g * a * b + c7
        r_out[i], theta_out[i], psi_out[i] = r, th, ps
        if want_j:
            dv_dr = -c1 * (2.0 * r + c2) / (den * den) * a * b
            dv_duth = g * b * da_du
            dv_dupsi = g * a * c5 * dcp_du
            r3 = r * r * r
            gd = np.empty(3)  # dv/dd
            for k in range(3):
                dr = d[k] / r
                duth = -m[k] / r + md * d[k] / r3
                dupsi = ltv_axis[i, k] / r - nd * d[k] / r3
                gd[k] = dv_dr * dr + dv_duth * duth + dv_dupsi * dupsi
            gm = np.empty(3)  # dv/dm (only through u_theta)
            for k in range(3):
                gm[k] = dv_duth * (-d[k] / r)
            for k in range(3):
                J[i, k] = gd[k]
            # d(Ra) = dphi x (Ra), dm = dphi x m: g . (dphi x w) = dphi . (w x g)
            J[i, 3] = (w[1] * gd[2] - w[2] * gd[1]) + (m[1] * gm[2] - m[2] * gm[1])
            J[i, 4] = (w[2] * gd[0] - w[0] * gd[2]) + (m[2] * gm[0] - m[0] * gm[2])
            J[i, 5] = (w[0] * gd[1] - w[1] * gd[0]) + (m[0] * gm[1] - m[1] * gm[0])


@njit(cache=True)
def pairs_batch(P, Rs, led_pos, led_axis, ltv_pos, ltv_axis, coeffs, want_j):
    n, npair = P.shape[0], ltv_pos.shape[0]
    V = np.empty((n, npair))
    J = np.zeros((n, npair, 6))
    rr, th, ps = np.empty((n, npair)), np.empty((n, npair)), np.empty((n, npair))
    for s in range(n):
        pairs_kernel(P[s], Rs[s], led_pos, led_axis, ltv_pos, ltv_axis, coeffs, V[s], J[s], rr[s], th[s], ps[s], want_j)
    return V, J, rr, th, ps
