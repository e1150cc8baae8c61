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

The compiled kernel (:mod:`other_sensors.cls.ltv_kernel`, numba, imported on first use so that
loading a scene does not import numba) is shared by the vectorised public functions here and the
estimator: one implementation of the geometry, the model and their derivatives.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["PairLayout", "default_layout", "DEFAULT_COEFFS", "ltv_voltage", "ltv_voltage_dc", "quat_to_matrix",
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
