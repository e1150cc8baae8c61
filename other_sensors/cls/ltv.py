"""LED / light-to-voltage (LTV) pairs of the compliant limb sensor: geometry and voltage model (SPEC 3).

One pair: an LED fixed on the shell, an LTV fixed on the base. With eta = (r, theta, psi), r the
LED-LTV distance, theta the angle between the LED's axis and the direction LED -> LTV, psi the
angle between the LTV's axis and the direction LTV -> LED, the LTV reads

    v = c1 / (r^2 + c2 r + c3) * cos(c4 theta) * (1 + c5 cos(c6 psi)) + c7        (SPEC 3)

Units inside this module: mm for lengths, rad for angles, V for voltages (the SPEC's bounds and
coefficients are in mm; metres would make c1 ~ 1e-3 and the LM tolerance meaningless).

Pose of the shell: mu = (p, q), p (3,) mm the shell frame's origin in the base frame, q (4,) a unit
quaternion (w, x, y, z) rotating shell-frame vectors into the base frame. The LED's pose is the
shell pose composed with the LED's fixed pose on the shell. Jacobians are taken with respect to
(dp (3,), dphi (3,)), dphi a small rotation applied on the left: R <- exp([dphi]x) R. The planar
prototype's pose (y, z, rx) is the restriction p = (0, y, z), q = rotation rx about x, whose
Jacobian is the columns (dp_y, dp_z, dphi_x) of the full one (exactly, since rotations about x
commute).

:func:`pair_model` is the same model in NumPy from the relative geometry (d, LED axis, LTV axis),
with the gradients that calibrating the mounting poses needs; :func:`ring_layout` places pairs off a
line, which a full 6-DoF pose needs (the prototype's line observes only y, z and theta_x).

The compiled kernel (:mod:`other_sensors.cls.ltv_kernel`, numba, imported on first use so that
loading a scene does not import numba) is shared by the vectorised public functions here and the
estimator: one implementation of the geometry, the model and their derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairLayout", "default_layout", "ring_layout", "DEFAULT_COEFFS", "ltv_voltage", "ltv_voltage_dc", "pair_model",
           "quat_to_matrix", "rotvec_to_quat", "matrix_to_rotvec", "pose6_to_pose",
           "planar_to_pose", "pair_geometry", "pair_voltages", "planar_voltages", "PLANAR_COLUMNS"]

# --- documented defaults (the SPEC does not give them) -------------------------------------------
# Seven coefficients per pair. A choice: with a rest gap of 40 mm the rest reading is ~1.3 V and the
# deepest compression the trajectories reach (r ~ 21 mm) reads ~4.3 V, inside a 0-5 V ADC; c3 keeps
# the near field finite; c4 = 1.6 puts the LED's half-power angle near 33 deg (a typical 5 mm LED);
# c5, c6 give the LTV a mild angular response; c7 is the dark offset.
DEFAULT_COEFFS = np.array([1875.0, 0.0, 100.0, 1.6, 0.2, 2.0, 0.05])  # c1 V mm^2, c2 mm, c3 mm^2, c4, c5, c6, c7 V
# Pair placement. A choice: 5 LTVs in a line along y at 20 mm pitch; each LED sits 6 mm off its
# LTV along y, alternately +/-: right above its LTV (theta = psi = 0) the voltage is even in a
# shear (v(+s) = v(-s)), so the sign of a shear would be unobservable to first order.
PAIR_PITCH_MM = 20.0
LED_STAGGER_MM = 6.0
# The shell frame's origin (where the LEDs sit, on the shell's underside) is 40 mm above the LTVs at
# rest: the 38.1 mm (1.5 in) pillars plus 1.9 mm of mounts. A choice, inside 15 < r < 60 mm.
REST_GAP_MM = 40.0

#: The planar pose's columns in the full (dp, dphi) Jacobian: p_y, p_z, phi_x.
PLANAR_COLUMNS = (1, 2, 3)


@dataclass(frozen=True)
class PairLayout:
    """Where the pairs are. led_pos (P, 3) mm and led_axis (P, 3) unit in the shell frame;
    ltv_pos (P, 3) mm and ltv_axis (P, 3) unit in the base frame; rest_p (3,) mm the shell origin
    at rest; coeffs (P, 7) the pairs' coefficients."""

    led_pos: np.ndarray
    led_axis: np.ndarray
    ltv_pos: np.ndarray
    ltv_axis: np.ndarray
    rest_p: np.ndarray
    coeffs: np.ndarray

    @property
    def n_pairs(self) -> int:
        return len(self.ltv_pos)

    def with_coeffs(self, coeffs) -> "PairLayout":
        coeffs = np.ascontiguousarray(np.broadcast_to(np.asarray(coeffs, float), (self.n_pairs, 7)))
        return PairLayout(self.led_pos, self.led_axis, self.ltv_pos, self.ltv_axis, self.rest_p, coeffs)


def default_layout(n_pairs: int = 5, pitch_mm: float = PAIR_PITCH_MM, stagger_mm: float = LED_STAGGER_MM,
                   gap_mm: float = REST_GAP_MM, coeffs=DEFAULT_COEFFS) -> PairLayout:
    """The prototype's line of pairs along y (SPEC 3), LEDs facing down (-z), LTVs facing up (+z)."""
    y = (np.arange(n_pairs) - (n_pairs - 1) / 2) * pitch_mm
    sign = np.where(np.arange(n_pairs) % 2 == 0, 1.0, -1.0)
    zeros = np.zeros(n_pairs)
    led_pos = np.stack([zeros, y + sign * stagger_mm, zeros], axis=1)
    ltv_pos = np.stack([zeros, y, zeros], axis=1)
    down = np.tile([0.0, 0.0, -1.0], (n_pairs, 1))
    return PairLayout(led_pos, down, ltv_pos, -down, np.array([0.0, 0.0, gap_mm]),
                      np.ascontiguousarray(np.broadcast_to(np.asarray(coeffs, float), (n_pairs, 7))))


# --- the voltage model as a pure function ----------------------------------------------------------
def ltv_voltage(r, theta, psi, c):
    """v(r, theta, psi; c) of SPEC 3. r mm, theta and psi rad, broadcast together (shape S);
    c (..., 7) broadcast against S + (7,). Returns v (S) in V."""
    r, theta, psi = (np.asarray(a, float) for a in (r, theta, psi))
    c = np.asarray(c, float)
    c1, c2, c3, c4, c5, c6, c7 = np.moveaxis(c, -1, 0)
    return c1 / (r * r + c2 * r + c3) * np.cos(c4 * theta) * (1.0 + c5 * np.cos(c6 * psi)) + c7


def ltv_voltage_dc(r, theta, psi, c):
    """dv/dc (S + (7,)) of :func:`ltv_voltage`, for calibration."""
    r, theta, psi = (np.asarray(a, float) for a in (r, theta, psi))
    c = np.asarray(c, float)
    c1, c2, c3, c4, c5, c6, _ = np.moveaxis(c, -1, 0)
    den = r * r + c2 * r + c3
    a, b = np.cos(c4 * theta), 1.0 + c5 * np.cos(c6 * psi)
    g = c1 / den
    out = [a * b / den, -g * r / den * a * b, -g / den * a * b, -g * np.sin(c4 * theta) * theta * b,
           g * a * np.cos(c6 * psi), -g * a * c5 * np.sin(c6 * psi) * psi, np.ones_like(g)]
    return np.stack(np.broadcast_arrays(*out), axis=-1)


# --- pose helpers ----------------------------------------------------------------------------------
def quat_to_matrix(q):
    """Rotation matrices (..., 3, 3) of quaternions q (..., 4) = (w, x, y, z); q is normalised first."""
    q = np.asarray(q, float)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], -2)


def planar_to_pose(pose3):
    """Planar pose (..., 3) = (y mm, z mm, rx rad) -> (p (..., 3) mm, q (..., 4))."""
    pose3 = np.asarray(pose3, float)
    y, z, rx = np.moveaxis(pose3, -1, 0)
    p = np.stack([np.zeros_like(y), y, z], -1)
    q = np.stack([np.cos(rx / 2), np.sin(rx / 2), np.zeros_like(y), np.zeros_like(y)], -1)
    return p, q


def _batch(p, q, layout: PairLayout, want_j: bool):
    p = np.asarray(p, float)
    q = np.asarray(q, float)
    if p.shape[-1] != 3 or q.shape[-1] != 4 or p.shape[:-1] != q.shape[:-1]:
        raise ValueError(f"pose: p must be (..., 3) mm and q (..., 4) with the same leading shape; got {p.shape} and {q.shape}")
    if not (np.all(np.isfinite(p)) and np.all(np.isfinite(q))):
        raise ValueError("pose: p and q must be finite (got NaN or Inf)")
    if np.any(np.linalg.norm(q, axis=-1) < 1e-12):
        raise ValueError("pose: q must be a (unit) quaternion (w, x, y, z); got a zero one")
    from other_sensors.cls.ltv_kernel import pairs_batch

    lead = p.shape[:-1]
    Rs = quat_to_matrix(q).reshape(-1, 3, 3)
    out = pairs_batch(np.ascontiguousarray(p.reshape(-1, 3)), np.ascontiguousarray(Rs), layout.led_pos, layout.led_axis,
                       layout.ltv_pos, layout.ltv_axis, np.ascontiguousarray(layout.coeffs, dtype=float), want_j)
    V, J, rr, th, ps = out
    shape = lead + (layout.n_pairs,)
    return V.reshape(shape), J.reshape(shape + (6,)), rr.reshape(shape), th.reshape(shape), ps.reshape(shape)


def pair_geometry(p, q, layout: PairLayout):
    """eta of each pair for shell poses p (..., 3) mm, q (..., 4): (r, theta, psi), each (..., P), mm and rad."""
    _, _, r, theta, psi = _batch(p, q, layout, False)
    return r, theta, psi


def pair_voltages(p, q, layout: PairLayout, jacobian: bool = False):
    """Noise-free voltages (..., P) in V of shell poses p (..., 3) mm, q (..., 4); with ``jacobian``
    also dv/d(dp, dphi) (..., P, 6) in V/mm and V/rad (left rotation increment, see the module)."""
    V, J, *_ = _batch(p, q, layout, jacobian)
    return (V, J) if jacobian else V


def planar_voltages(pose3, layout: PairLayout, jacobian: bool = False):
    """The planar restriction: pose3 (..., 3) = (y mm, z mm, rx rad) -> voltages (..., P) and, with
    ``jacobian``, dv/d(y, z, rx) (..., P, 3)."""
    p, q = planar_to_pose(pose3)
    V, J, *_ = _batch(p, q, layout, jacobian)
    return (V, J[..., list(PLANAR_COLUMNS)]) if jacobian else V


# --- the model from the relative geometry, with its gradients (calibration of the mounting poses) --
def _cos_factor(c, cos_a, sin_a):
    """cos(c a) and d cos(c a) / d cos(a) = c sin(c a) / sin(a) = c^2 sinc(c a) / sinc(a) (finite at a = 0)."""
    a = np.arctan2(sin_a, cos_a)
    return np.cos(c * a), c * c * np.sinc(c * a / np.pi) / np.sinc(a / np.pi), a


def pair_model(d, m, n, c):
    """The voltage model of SPEC 3 from the relative geometry of a pair, with its analytic gradients.

    Parameters
    ----------
    d : (S, 3) mm, LTV -> LED in the base frame.
    m : (S, 3) unit, the LED's axis in the base frame.
    n : (S, 3) unit, the LTV's axis in the base frame.
    c : (7,) or (S, 7), the pair's coefficients.

    Returns
    -------
    v : (S,) V; dv_dd (S, 3) V/mm; dv_dm, dv_dn (S, 3) V, the gradients along the unit sphere at m
    and n (the model depends on the axes' directions only, so the radial part is 0); dv_dc (S, 7);
    and r (S,) mm, theta (S,), psi (S,) rad.

    Notes
    -----
    r = |d|, cos theta = -m.d / r, cos psi = n.d / r (SPEC 3: the LED's and the LTV's incidence).
    The same model as the compiled kernel (:mod:`ltv_kernel`), in NumPy, since calibration also needs
    the derivatives with respect to the axes, which the pose estimator does not.
    """
    d, m, n = (np.asarray(a, float) for a in (d, m, n))
    c = np.broadcast_to(np.asarray(c, float), d.shape[:-1] + (7,))
    r = np.linalg.norm(d, axis=-1)
    md, nd = np.einsum("...k,...k", m, d), np.einsum("...k,...k", n, d)
    u_th, u_ps = -md / r, nd / r
    s_th = np.linalg.norm(np.cross(m, d), axis=-1) / r
    s_ps = np.linalg.norm(np.cross(n, d), axis=-1) / r
    c1, c2, c3, c4, c5, c6, _ = np.moveaxis(c, -1, 0)
    a, da, theta = _cos_factor(c4, u_th, s_th)
    cp, dcp, psi = _cos_factor(c6, u_ps, s_ps)
    den = r * r + c2 * r + c3
    g = c1 / den
    b = 1.0 + c5 * cp
    v = g * a * b + c[..., 6]
    dv_dr = -c1 * (2 * r + c2) / den ** 2 * a * b
    dv_duth, dv_dups = g * b * da, g * a * c5 * dcp
    dhat = d / r[..., None]
    # du_th/dd = -(m - (m.dhat) dhat) / r; du_ps/dd = (n - (n.dhat) dhat) / r
    dv_dd = (dv_dr[..., None] * dhat
             - dv_duth[..., None] * (m + u_th[..., None] * dhat) / r[..., None]
             + dv_dups[..., None] * (n - u_ps[..., None] * dhat) / r[..., None])
    dv_dm = -dv_duth[..., None] * (dhat + u_th[..., None] * m)  # -(I - m m^T) dhat
    dv_dn = dv_dups[..., None] * (dhat - u_ps[..., None] * n)  # (I - n n^T) dhat
    dv_dc = ltv_voltage_dc(r, theta, psi, c)
    return v, dv_dd, dv_dm, dv_dn, dv_dc, r, theta, psi


# --- a layout and poses for the full 6-DoF shell ---------------------------------------------------
def ring_layout(n_pairs: int = 6, radius_mm: float = 30.0, stagger_mm: float = LED_STAGGER_MM,
                gap_mm: float = REST_GAP_MM, coeffs=DEFAULT_COEFFS) -> PairLayout:
    """Pairs on a circle of ``radius_mm`` in the base's xy plane, LEDs staggered ``stagger_mm`` off
    their LTVs alternately along the tangent and the radius (a choice, not the SPEC's prototype).

    Notes
    -----
    SPEC 3's prototype has its pairs in a line and observes only (y, z, theta_x). A full 6-DoF pose
    needs pairs off the line and staggers in more than one direction: with every LED straight above
    its LTV, a sideways move changes no r, theta or psi to first order (they are even in it).
    """
    ang = 2 * np.pi * np.arange(n_pairs) / n_pairs
    radial = np.stack([np.cos(ang), np.sin(ang), np.zeros(n_pairs)], axis=1)
    tangent = np.stack([-np.sin(ang), np.cos(ang), np.zeros(n_pairs)], axis=1)
    stagger = np.where((np.arange(n_pairs) % 2 == 0)[:, None], tangent, radial) * stagger_mm
    ltv_pos = radius_mm * radial
    down = np.tile([0.0, 0.0, -1.0], (n_pairs, 1))
    return PairLayout(ltv_pos + stagger, down, ltv_pos, -down, np.array([0.0, 0.0, gap_mm]),
                      np.ascontiguousarray(np.broadcast_to(np.asarray(coeffs, float), (n_pairs, 7))))


def rotvec_to_quat(phi):
    """Quaternions (..., 4) = (w, x, y, z) of rotation vectors phi (..., 3) rad."""
    phi = np.asarray(phi, float)
    angle = np.linalg.norm(phi, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0
    k = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5 - angle ** 2 / 48)
    return np.concatenate([np.cos(half), k * phi], axis=-1)


def pose6_to_pose(pose6):
    """6-DoF pose (..., 6) = (x, y, z mm, rotation vector rad) -> (p (..., 3) mm, q (..., 4))."""
    pose6 = np.asarray(pose6, float)
    return pose6[..., :3].copy(), rotvec_to_quat(pose6[..., 3:])


def matrix_to_rotvec(R):
    """Rotation vectors (..., 3) rad of rotation matrices R (..., 3, 3) (angles below pi)."""
    R = np.asarray(R, float)
    cos = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    # angle / (2 sin angle) -> 1/2 as angle -> 0
    k = np.where(angle > 1e-8, angle / (2 * np.sin(np.maximum(angle, 1e-300))), 0.5 + angle ** 2 / 12)
    return k[..., None] * axis
