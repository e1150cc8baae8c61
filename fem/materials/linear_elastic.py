"""Isotropic linear elasticity (small strain).

    sigma = lambda tr(eps) I + 2 mu eps,     W = lambda / 2 tr(eps)^2 + mu eps : eps

with the Lame parameters lambda = E nu / ((1 + nu)(1 - 2 nu)), mu = E / (2 (1 + nu)) [Sadd2009]_.
As nu -> 1/2, lambda -> infinity: displacement-only elements lock (see :mod:`fem.elasticity` for the
mixed displacement-pressure form that does not).

Arrays carry the tensor indices last: strain (..., 3, 3).

References
----------
.. [Sadd2009] M. H. Sadd, "Elasticity: Theory, Applications, and Numerics", 2nd ed., Academic Press
   (2009), ch. 4 (Hooke's law, eq. 4.2.8) and ch. 6 (strain energy, eq. 6.1.8).
"""

from __future__ import annotations

import numpy as np

__all__ = ["lame_parameters", "bulk_modulus", "stress", "strain_energy_density", "von_mises"]


def lame_parameters(young_modulus_pa, poisson_ratio):
    """(lambda, mu) in Pa from E (Pa) > 0 and -1 < nu < 1/2 (scalars or arrays)."""
    e = np.asarray(young_modulus_pa, dtype=float)
    nu = np.asarray(poisson_ratio, dtype=float)
    if np.any(~np.isfinite(e)) or np.any(e <= 0):
        raise ValueError(f"young_modulus_pa = {young_modulus_pa}: must be finite and > 0")
    if np.any(~np.isfinite(nu)) or np.any(nu <= -1) or np.any(nu >= 0.5):
        raise ValueError(f"poisson_ratio = {poisson_ratio}: must be within (-1, 0.5)")
    return e * nu / ((1 + nu) * (1 - 2 * nu)), e / (2 * (1 + nu))


def bulk_modulus(lam, mu):
    """kappa = lambda + 2 mu / 3 (Pa)."""
    return np.asarray(lam) + 2.0 * np.asarray(mu) / 3.0


def stress(strain, lam, mu):
    """Cauchy stress (..., 3, 3) Pa from the small strain (..., 3, 3); lam, mu broadcast over ``...``."""
    eps = np.asarray(strain, dtype=float)
    tr = np.trace(eps, axis1=-2, axis2=-1)
    lam = np.asarray(lam, dtype=float)[..., None, None]
    mu = np.asarray(mu, dtype=float)[..., None, None]
    return lam * tr[..., None, None] * np.eye(3) + 2.0 * mu * eps


def strain_energy_density(strain, lam, mu):
    """W (...) in J/m^3 for the small strain (..., 3, 3)."""
    eps = np.asarray(strain, dtype=float)
    tr = np.trace(eps, axis1=-2, axis2=-1)
    return 0.5 * np.asarray(lam) * tr**2 + np.asarray(mu) * np.einsum("...ij,...ij->...", eps, eps)


def von_mises(stress_pa):
    """Von Mises equivalent stress (...) Pa of a stress tensor (..., 3, 3): sqrt(3/2 s : s), s = dev(sigma)."""
    s = np.asarray(stress_pa, dtype=float)
    dev = s - np.trace(s, axis1=-2, axis2=-1)[..., None, None] * np.eye(3) / 3.0
    return np.sqrt(1.5 * np.einsum("...ij,...ij->...", dev, dev))
