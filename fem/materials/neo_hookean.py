"""Compressible neo-Hookean solid.

Strain energy per unit reference volume [BonetWood2008]_ (eq. 6.28):

    W(F) = mu / 2 (I1 - 3) - mu ln J + lambda / 2 (ln J)^2,     I1 = tr(F^T F), J = det F

First Piola-Kirchhoff stress (eq. 6.29, pulled back):  P = mu (F - F^-T) + lambda ln(J) F^-T.
Its derivative, the first elasticity tensor A_iJkL = dP_iJ / dF_kL:

    A = mu I_ik I_JL + (mu - lambda ln J) F^-1_Li F^-1_Jk + lambda F^-1_Ji F^-1_Lk

It reduces to linear elasticity with the same (lambda, mu) at small strain, which the tests check.
Near incompressibility (large lambda) it is used in the mixed form of :mod:`fem.elasticity`.

Arrays carry the tensor indices last: F (..., 3, 3).

References
----------
.. [BonetWood2008] J. Bonet, R. D. Wood, "Nonlinear Continuum Mechanics for Finite Element
   Analysis", 2nd ed., Cambridge University Press (2008), sec. 6.4.3.
"""

from __future__ import annotations

import numpy as np

__all__ = ["strain_energy_density", "first_piola", "first_elasticity", "cauchy_stress"]


def _invariants(F):
    F = np.asarray(F, dtype=float)
    J = np.linalg.det(F)
    if np.any(~(J > 0)):
        raise FloatingPointError(f"det F <= 0 at {int(np.sum(~(J > 0)))} point(s): the deformation inverts the material")
    return F, J, np.linalg.inv(F)


def strain_energy_density(F, lam, mu):
    """W (...) in J/m^3 for the deformation gradient F (..., 3, 3)."""
    F, J, _ = _invariants(F)
    logj = np.log(J)
    i1 = np.einsum("...ij,...ij->...", F, F)
    return 0.5 * mu * (i1 - 3.0) - mu * logj + 0.5 * lam * logj**2


def first_piola(F, lam, mu):
    """P (..., 3, 3) in Pa."""
    F, J, Finv = _invariants(F)
    FinvT = np.swapaxes(Finv, -1, -2)
    lam = np.asarray(lam, dtype=float)[..., None, None]
    mu = np.asarray(mu, dtype=float)[..., None, None]
    return mu * (F - FinvT) + lam * np.log(J)[..., None, None] * FinvT


def first_elasticity(F, lam, mu):
    """A (..., 3, 3, 3, 3) with A[..., i, J, k, L] = dP_iJ / dF_kL, in Pa."""
    F, J, Finv = _invariants(F)
    lam = np.asarray(lam, dtype=float)
    mu = np.asarray(mu, dtype=float)
    eye = np.eye(3)
    c1 = mu[..., None, None, None, None] if np.ndim(mu) else mu
    c2 = (mu - lam * np.log(J))[..., None, None, None, None]
    c3 = lam[..., None, None, None, None] if np.ndim(lam) else lam
    a = c1 * np.einsum("ik,JL->iJkL", eye, eye)
    a = a + c2 * np.einsum("...Li,...Jk->...iJkL", Finv, Finv)
    a = a + c3 * np.einsum("...Ji,...Lk->...iJkL", Finv, Finv)
    return a


def cauchy_stress(F, lam, mu):
    """sigma = J^-1 P F^T (..., 3, 3) in Pa."""
    F, J, _ = _invariants(F)
    return first_piola(F, lam, mu) @ np.swapaxes(F, -1, -2) / J[..., None, None]
