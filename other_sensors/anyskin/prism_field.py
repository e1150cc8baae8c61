"""The flux density of a uniformly magnetised rectangular prism, in closed form (the skin at rest, SPEC 2).

A prism [x1, x2] x [y1, y2] x [z1, z2] with uniform magnetisation M (A/m) is, outside it, the field
of the surface charges sigma = M . n on its faces (the charge model: Furlani, *Permanent Magnet and
Electromechanical Devices*, Academic Press, 2001, ch. 4; the prism's closed form: Engel-Herbert &
Hesjedal, "Calculation of the magnetic stray field of a uniaxial magnetic domain", J. Appl. Phys. 97,
074504, 2005). A face at
z = zf carrying sigma gives, with X_i = x - x_i, Y_j = y - y_j, Z = z - zf, R_ij = |(X_i, Y_j, Z)|
and s_1 = +1, s_2 = -1 (the integration limits),

    H_x = sigma / (4 pi) sum_ij s_i s_j (-ln(Y_j + R_ij))
    H_y = sigma / (4 pi) sum_ij s_i s_j (-ln(X_i + R_ij))
    H_z = sigma / (4 pi) sum_ij s_i s_j atan(X_i Y_j / (Z R_ij))

(the antiderivatives of the Coulomb kernel over the face), and B = mu0 H outside the magnet. The
components of M along x and y are the same faces' formula with the axes permuted. The logarithm's
argument is evaluated as (X^2 + Z^2) / (R - Y) where Y < 0, which keeps the digits that Y + R would
cancel. Points must lie outside the prism and off the planes of its charged faces (Z != 0).
"""

from __future__ import annotations

import numpy as np

from .dipoles import MU0

__all__ = ["prism_field"]


def _log_plus(a, r, b2):
    """ln(a + r) with r = sqrt(a^2 + b2), stable where a < 0 (there a + r = b2 / (r - a))."""
    pos = a >= 0
    return np.where(pos, np.log(np.where(pos, a + r, 1.0)), np.log(np.where(pos, 1.0, b2) / np.where(pos, 1.0, r - a)))


def _z_faces(p, lo, hi, m_z):
    """H (P, 3) A/m of the two faces normal to z of the prism [lo, hi], charged +-m_z (top +, bottom -)."""
    h = np.zeros_like(p)
    for zf, sigma in ((hi[2], m_z), (lo[2], -m_z)):
        z = p[:, 2] - zf
        if np.any(z == 0):
            raise ValueError("prism field: a point lies in the plane of a charged face; move it off the face")
        for i, xi in enumerate((lo[0], hi[0])):
            for j, yj in enumerate((lo[1], hi[1])):
                s = (1.0 if i == 0 else -1.0) * (1.0 if j == 0 else -1.0) * sigma / (4 * np.pi)
                x, y = p[:, 0] - xi, p[:, 1] - yj
                r = np.sqrt(x * x + y * y + z * z)
                h[:, 0] -= s * _log_plus(y, r, x * x + z * z)
                h[:, 1] -= s * _log_plus(x, r, y * y + z * z)
                h[:, 2] += s * np.arctan(x * y / (z * r))
    return h


def prism_field(points, lower_m, upper_m, magnetisation_a_m) -> np.ndarray:
    """Flux density B (P, 3) tesla of a uniformly magnetised prism at points (P, 3) m outside it.

    Parameters
    ----------
    points : array (P, 3) m
    lower_m, upper_m : array (3,) m
        The prism's opposite corners (lower < upper on every axis).
    magnetisation_a_m : array (3,) A/m

    Returns
    -------
    array (P, 3) tesla, see the module docstring.
    """
    p = np.atleast_2d(np.asarray(points, dtype=float))
    lo, hi, m = (np.asarray(v, dtype=float) for v in (lower_m, upper_m, magnetisation_a_m))
    if not np.all(hi > lo):
        raise ValueError(f"prism field: the corners {lo} and {hi} m must satisfy lower < upper on every axis")
    h = np.zeros_like(p)
    for axis in range(3):
        if m[axis] == 0:
            continue
        order = [(axis + 1) % 3, (axis + 2) % 3, axis]  # a cyclic permutation keeps the frame right-handed
        h[:, order] += _z_faces(p[:, order], lo[order], hi[order], m[axis])
    return MU0 * h
