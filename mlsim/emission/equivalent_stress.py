"""Equivalent (scalar) stresses of a Voigt stress: what drives the ML emission.

Glow patterns in ML composites follow von Mises stress contours (SPEC 1.3), so ``von_mises`` is the
default; the others let a user test that choice. Voigt order xx, yy, zz, yz, xz, xy (Pa), as
:mod:`fem.fields`.

- ``von_mises``: sqrt(3 J2), the distortion measure [Hill1950]_;
- ``tresca``: the largest principal stress difference (twice the largest shear) [Hill1950]_;
- ``max_principal``: the largest principal stress (tension positive), floored at zero: a
  piezoelectric de-trapping picture in which only tension opens traps is one reading of
  [Chandra2013]_;
- ``abs_pressure``: |tr sigma| / 3, the hydrostatic part alone, for comparison.

References
----------
.. [Hill1950] R. Hill, "The Mathematical Theory of Plasticity", Oxford (1950), ch. II.
.. [Chandra2013] V. K. Chandra, B. P. Chandra, P. Jha, "Strong luminescence induced by elastic
   deformation of piezoelectric crystals", Appl. Phys. Lett. 102, 241105 (2013).
"""

from __future__ import annotations

import numpy as np

__all__ = ["EQUIVALENT_STRESSES", "equivalent_stress", "von_mises", "tresca", "max_principal", "abs_pressure"]


def _check(sigma) -> np.ndarray:
    sigma = np.asarray(sigma, dtype=float)
    if sigma.ndim < 1 or sigma.shape[-1] != 6:
        raise ValueError(f"stress of shape {sigma.shape}: the last axis must hold the 6 Voigt components (xx, yy, zz, yz, xz, xy)")
    return sigma


def von_mises(sigma) -> np.ndarray:
    """sqrt(3 J2) (...,) Pa of Voigt stresses (..., 6) Pa."""
    s = _check(sigma)
    xx, yy, zz, yz, xz, xy = np.moveaxis(s, -1, 0)
    return np.sqrt(0.5 * ((xx - yy) ** 2 + (yy - zz) ** 2 + (zz - xx) ** 2) + 3.0 * (yz**2 + xz**2 + xy**2))


def _principal(sigma) -> np.ndarray:
    s = _check(sigma)
    T = np.empty(s.shape[:-1] + (3, 3))
    for r, (a, b) in enumerate(((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))):
        T[..., a, b] = T[..., b, a] = s[..., r]
    return np.linalg.eigvalsh(T)  # ascending


def tresca(sigma) -> np.ndarray:
    """sigma_1 - sigma_3 (...,) Pa of Voigt stresses (..., 6) Pa."""
    p = _principal(sigma)
    return p[..., 2] - p[..., 0]


def max_principal(sigma) -> np.ndarray:
    """max(sigma_1, 0) (...,) Pa of Voigt stresses (..., 6) Pa."""
    return np.maximum(_principal(sigma)[..., 2], 0.0)


def abs_pressure(sigma) -> np.ndarray:
    """|tr sigma| / 3 (...,) Pa of Voigt stresses (..., 6) Pa."""
    s = _check(sigma)
    return np.abs(s[..., 0] + s[..., 1] + s[..., 2]) / 3.0


EQUIVALENT_STRESSES = {"von_mises": von_mises, "tresca": tresca, "max_principal": max_principal, "abs_pressure": abs_pressure}


def equivalent_stress(name: str):
    """The equivalent-stress function registered as ``name``."""
    if name not in EQUIVALENT_STRESSES:
        raise ValueError(f'"{name}" is not an equivalent stress; choose one of: {", ".join(EQUIVALENT_STRESSES)}')
    return EQUIVALENT_STRESSES[name]
