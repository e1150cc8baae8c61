"""The magnetic flux density of point dipoles, and its Jacobian with respect to the dipoles' positions.

A point dipole of moment m (A m^2) at p gives at x, with r = x - p (m),

    B(x) = mu0 / (4 pi) (3 (m . r_hat) r_hat - m) / |r|^3      (tesla)

(Jackson, *Classical Electrodynamics*, 3rd ed., eq. 5.56, outside the source). On the dipole's axis
this is mu0 m / (2 pi z^3), in its equatorial plane -mu0 m / (4 pi r^3). Fields of several dipoles
add (superposition, the field equations are linear). Everything here is SI: metres, A m^2, tesla;
the skin (:mod:`other_sensors.anyskin.skin`) converts to microtesla for the readings.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MU0", "dipole_field", "dipole_field_jacobian"]

MU0 = 4e-7 * np.pi  # T m / A; the pre-2019 exact value, within 1e-9 of the CODATA 2018 one


def _offsets(points, positions):
    points, positions = np.asarray(points, dtype=float), np.asarray(positions, dtype=float)
    if points.shape[-1] != 3 or positions.shape[-1] != 3:
        raise ValueError(f"points {points.shape} and positions {positions.shape} must end in 3 (x, y, z in m)")
    return points[..., :, None, :] - positions[..., None, :, :]  # (..., P, N, 3)


def dipole_field(points, positions, moments) -> np.ndarray:
    """Flux density of N point dipoles, summed, at P points.

    points: (..., P, 3) m. positions: (..., N, 3) m. moments: (..., N, 3) A m^2 (leading axes broadcast).
    Returns B (..., P, 3) tesla. A point on a dipole gives inf/NaN: keep points off the dipoles.
    """
    r = _offsets(points, positions)
    m = np.asarray(moments, dtype=float)[..., None, :, :]
    d2 = np.einsum("...i,...i->...", r, r)
    inv_d = 1.0 / np.sqrt(d2)
    m_dot_r = np.einsum("...i,...i->...", m, r)
    field = (3.0 * (m_dot_r * inv_d**5)[..., None] * r - (inv_d**3)[..., None] * m)
    return MU0 / (4.0 * np.pi) * field.sum(axis=-2)


def dipole_field_jacobian(points, positions, moments) -> np.ndarray:
    """dB_i(point p) / d position_j(dipole n), (..., P, 3, N, 3) T/m, moments held fixed.

    With r = x - p: dB_i/dr_j = mu0 / (4 pi) 3 / |r|^5 ((m.r) d_ij + m_i r_j + r_i m_j - 5 (m.r) r_i r_j / |r|^2),
    and d/dp = -d/dr.
    """
    r = _offsets(points, positions)  # (..., P, N, 3)
    m = np.broadcast_to(np.asarray(moments, dtype=float)[..., None, :, :], r.shape)
    d2 = np.einsum("...i,...i->...", r, r)
    m_dot_r = np.einsum("...i,...i->...", m, r)
    eye = np.eye(3)
    inner = (m_dot_r[..., None, None] * eye + m[..., :, None] * r[..., None, :] + r[..., :, None] * m[..., None, :]
             - 5.0 * (m_dot_r / d2)[..., None, None] * r[..., :, None] * r[..., None, :])
    jac = -MU0 / (4.0 * np.pi) * 3.0 * inner / (d2**2.5)[..., None, None]  # (..., P, N, 3, 3): [i, j]
    return np.moveaxis(jac, -2, -3)  # (..., P, 3, N, 3)
