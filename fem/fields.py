"""Per-tet stress from a solution vector: a sparse recovery operator, von Mises, strain energy density.

Stress is evaluated at each tet's centroid (one point per element; for P2 this is a
superconvergent-ish point of the linear stress field, for P1 the element's constant stress).
Voigt order throughout: xx, yy, zz, yz, xz, xy (Pa).

- displacement formulations: sigma = 2 mu eps + lambda tr(eps) I;
- P2P1: sigma = 2 mu eps + p I, with p the P1 pressure at the centroid (the Herrmann pressure,
  not lambda div u, which is meaningless as nu -> 1/2).

Because the map x -> sigma is linear, it is assembled once as a sparse matrix S (6 T, n_dofs);
a tier that superposes precomputed responses superposes S X instead of X.

Strain energy density from stress alone, the complementary energy of isotropic linear elasticity:
W = s : s / (4 mu) + (tr sigma)^2 / (18 K), s the deviator, K = lambda + 2 mu / 3 the bulk modulus
(for a linear material it equals eps : sigma / 2 and stays finite as lambda -> infinity).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import skfem
from skfem import ElementTetP1, ElementTetP2, ElementVector


__all__ = ["stress_operator", "voigt_to_tensor", "von_mises", "strain_energy_density", "VOIGT"]

VOIGT = ((0, 0), (1, 1), (2, 2), (1, 2), (0, 2), (0, 1))


def stress_operator(d, lam: np.ndarray, mu: np.ndarray) -> sp.csr_matrix:
    """S (6 T, n_dofs) with (S x).reshape(6, T) the centroid stress of each tet (Voigt rows).

    d: :class:`fem.elasticity.Discretisation`; lam, mu: (T,) Pa. For P2P1 the pressure columns act
    on the scaled unknowns of the assembled system (as :func:`fem.elasticity.split` undoes).
    """
    mesh = d.u.mesh
    T = mesh.nelements
    centroid = (np.full((3, 1), 0.25), np.array([1.0 / 6.0]))
    order = 1 if d.element == "P1" else 2
    e = ElementVector(ElementTetP1() if order == 1 else ElementTetP2())
    basis = skfem.Basis(mesh, e, quadrature=centroid)
    lam = np.broadcast_to(np.asarray(lam, dtype=float), (T,))
    mu = np.broadcast_to(np.asarray(mu, dtype=float), (T,))
    rows, cols, vals = [], [], []
    tet = np.arange(T)
    mixed = d.p is not None
    for j in range(basis.Nbfun):
        G = basis.basis[j][0].grad[:, :, :, 0]  # (3, 3, T): d phi_j,a / d x_b
        eps = 0.5 * (G + G.transpose(1, 0, 2))
        tr = np.trace(G)
        dof = basis.element_dofs[j]
        for r, (a, b) in enumerate(VOIGT):
            v = 2.0 * mu * eps[a, b]
            if a == b and not mixed:
                v = v + lam * tr
            rows.append(r * T + tet)
            cols.append(dof)
            vals.append(v)
    if mixed:
        # P1 pressure at the centroid: 1/4 of each vertex value, times the unknowns' scale
        pdofs = d.p.element_dofs  # (4, T)
        for j in range(4):
            for r in range(3):
                rows.append(r * T + tet)
                cols.append(d.n_u + pdofs[j])
                vals.append(np.full(T, 0.25 * d.pressure_scale))
    S = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(6 * T, d.n_dofs))
    return S.tocsr()


def voigt_to_tensor(sigma: np.ndarray) -> np.ndarray:
    """(6, ...) Voigt -> (..., 3, 3) symmetric tensors."""
    sigma = np.asarray(sigma)
    out = np.empty(sigma.shape[1:] + (3, 3), dtype=sigma.dtype)
    for r, (a, b) in enumerate(VOIGT):
        out[..., a, b] = sigma[r]
        out[..., b, a] = sigma[r]
    return out


def _trace_and_deviator_square(sigma: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """tr sigma and s : s (s the deviator) of Voigt stresses (6, ...), in float64."""
    sigma = np.asarray(sigma, dtype=float)
    tr = sigma[0] + sigma[1] + sigma[2]
    mean = tr / 3.0
    ss = (sigma[0] - mean) ** 2 + (sigma[1] - mean) ** 2 + (sigma[2] - mean) ** 2 + 2.0 * (sigma[3] ** 2 + sigma[4] ** 2 + sigma[5] ** 2)
    return tr, ss


def von_mises(sigma: np.ndarray) -> np.ndarray:
    """Von Mises stress (...,) Pa of Voigt stresses (6, ...): sqrt(3/2 s : s), as
    :func:`fem.materials.linear_elastic.von_mises` of the tensors, without building them (a tenth of the time)."""
    return np.sqrt(1.5 * _trace_and_deviator_square(sigma)[1])


def strain_energy_density(sigma: np.ndarray, lam, mu) -> np.ndarray:
    """Strain energy density (...,) J/m^3 of Voigt stresses (6, ...) for Lame parameters (...,)."""
    tr, ss = _trace_and_deviator_square(sigma)
    bulk = np.asarray(lam) + 2.0 * np.asarray(mu) / 3.0
    return ss / (4.0 * np.asarray(mu)) + tr**2 / (18.0 * bulk)


def von_mises_and_energy(stress: np.ndarray, lam, mu) -> tuple[np.ndarray, np.ndarray]:
    """(von Mises stress, strain energy density), each (U, T) float32, of an episode's stresses
    (U, 6, T) (float32, any strides) for Lame parameters (T,) or scalars: :func:`von_mises` and
    :func:`strain_energy_density` in float64 rounded to float32, bit for bit, in one compiled pass
    (:func:`fem.field_kernels.stress_invariants`)."""
    from fem.field_kernels import stress_invariants

    stress = np.asarray(stress)
    if stress.ndim != 3 or stress.shape[1] != 6:
        raise ValueError(f"stress of shape {stress.shape}: must be (loads, 6, tets)")
    if stress.dtype != np.float32:
        raise ValueError(f"stress of dtype {stress.dtype}: must be float32 (the episode's stored stresses)")
    U, _, T = stress.shape
    lam_t = np.ascontiguousarray(np.broadcast_to(np.asarray(lam, dtype=float), (T,)))
    mu_t = np.ascontiguousarray(np.broadcast_to(np.asarray(mu, dtype=float), (T,)))
    vm, sed = np.empty((U, T), np.float32), np.empty((U, T), np.float32)
    stress_invariants(stress, lam_t, mu_t, vm, sed)
    return vm, sed
