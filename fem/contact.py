"""Frictional contact of the body with a rigid flat probe: penalty normal force, regularised Coulomb
friction with stick and slip, for small-strain (linear) solids.

At each quadrature point of the candidate contact facets (reference position X, displacement u):

- normal gap to the probe's flat face at height h: g = h - (X_z + u_z); penetration when g < 0;
  contact pressure p = eps_n <-g>_+ (penalty; the probe presses the body with traction -p e_z);
- tangential traction by a return map [Wriggers2006]_ (sec. 5.2): with the relative tangential
  slip of the body against the probe over the increment, dg_T = du_T - ds (ds: the probe's own
  tangential motion), the trial traction t* = t_old - eps_t dg_T; stick if |t*| <= mu p, else slip
  with t_T = mu p t* / |t*|. In slip the traction's size is exactly mu p, so the total friction
  force equals mu times the total normal force wherever every point slips.

The consistent tangent of the traction (dt/du) is returned with it: -eps_n on the normal
component in contact; -eps_t I in stick; in slip -(mu p / |t*|) eps_t (I - n n^T) on the tangential
block and mu eps_n n against u_z (unsymmetric, solved with LU).

Penalty parameters trade penetration (p / eps_n) against conditioning; the default eps_n is
100 E / h (E Young's modulus, h the element size), so penetration is about 1 % of the elastic
indentation of an element-sized contact.

References
----------
.. [Wriggers2006] P. Wriggers, "Computational Contact Mechanics", 2nd ed., Springer (2006),
   ch. 5 (penalty method, return mapping for Coulomb friction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem
from skfem import BilinearForm, LinearForm

from fem.nonlinear import SolverError

__all__ = ["FlatProbe", "ContactHistory", "coulomb_traction", "solve_contact_increment"]


@dataclass(frozen=True)
class FlatProbe:
    """A rigid flat face, normal -z, at height ``height_m``, moved by ``offset_m`` (x, y) in total."""

    height_m: float
    offset_m: tuple[float, float] = (0.0, 0.0)
    friction: float = 0.8
    eps_n: float = 1e9  # N/m^3
    eps_t: float = 1e9  # N/m^3


@dataclass
class ContactHistory:
    """State at the contact quadrature points after the last converged increment."""

    u: np.ndarray  # (3, F, Q) displacement
    traction_t: np.ndarray  # (2, F, Q) tangential traction on the body, Pa
    offset_m: np.ndarray  # (2,) probe offset

    @classmethod
    def zero(cls, shape):
        return cls(np.zeros((3,) + shape), np.zeros((2,) + shape), np.zeros(2))


def coulomb_traction(X, u, probe: FlatProbe, history: ContactHistory):
    """Traction on the body (3, F, Q) Pa, its tangent dt/du (3, 3, F, Q) Pa/m, the contact pressure
    (F, Q) and the stick mask (F, Q) at points X (3, F, Q) with displacements u (3, F, Q)."""
    gap = probe.height_m - (X[2] + u[2])
    pressure = probe.eps_n * np.maximum(-gap, 0.0)
    touching = gap < 0
    ds = np.asarray(probe.offset_m) - history.offset_m
    slip_increment = (u[:2] - history.u[:2]) - ds[:, None, None]
    trial = history.traction_t - probe.eps_t * slip_increment
    trial = np.where(touching[None], trial, 0.0)
    size = np.sqrt(trial[0] ** 2 + trial[1] ** 2)
    limit = probe.friction * pressure
    stick = size <= limit
    n = trial / np.maximum(size, 1e-300)
    traction_t = np.where(stick[None], trial, limit[None] * n)
    traction = np.concatenate([traction_t, -pressure[None]], axis=0)
    tangent = np.zeros((3, 3) + gap.shape)
    tangent[2, 2] = np.where(touching, -probe.eps_n, 0.0)
    eye2 = np.eye(2)[:, :, None, None]
    ratio = np.divide(limit, size, out=np.zeros_like(size), where=size > 0)
    slip_block = -ratio[None, None] * probe.eps_t * (eye2 - n[:, None] * n[None, :])
    tangent[:2, :2] = np.where(stick[None, None], -probe.eps_t * eye2 * touching[None, None], slip_block)
    # d(mu p)/du_z = mu eps_n in contact; the slip traction grows along n with it.
    tangent[:2, 2] = np.where((~stick & touching)[None], probe.friction * probe.eps_n * n, 0.0)
    return traction, tangent, pressure, stick & touching


@LinearForm
def _traction_form(v, w):
    return w.t[0] * v[0] + w.t[1] * v[1] + w.t[2] * v[2]


@BilinearForm
def _tangent_form(du, v, w):
    out = 0.0
    for i in range(3):
        for j in range(3):
            out = out + v[i] * w.D[i, j] * du[j]
    return out


def solve_contact_increment(K: sp.spmatrix, n_u: int, contact_basis: skfem.FacetBasis, fixed: np.ndarray, x: np.ndarray,
                            probe: FlatProbe, history: ContactHistory, f_ext: np.ndarray | None = None,
                            rtol: float = 1e-10, max_iterations: int = 40, case: str = "contact increment"):
    """Solve K x - f_contact(x) = f_ext for one probe position by semi-smooth Newton.

    K: linear system matrix (stiffness or mixed [u; p]); the contact acts on its first n_u rows.
    Returns (x, new history, diagnostics dict with the total normal and tangential force).
    """
    X = np.asarray(contact_basis.global_coordinates())
    f_ext = np.zeros(K.shape[0]) if f_ext is None else f_ext
    free = np.setdiff1d(np.arange(K.shape[0]), fixed)
    n_rest = K.shape[0] - n_u

    def evaluate(state):
        u_q = np.asarray(contact_basis.interpolate(state[:n_u]))
        t, D, pressure, stick = coulomb_traction(X, u_q, probe, history)
        fc = np.zeros(K.shape[0])
        fc[:n_u] = skfem.asm(_traction_form, contact_basis, t=t)
        return K @ state - fc - f_ext, t, D, pressure, stick, u_q

    x = x.copy()
    r, t, D, pressure, stick, u_q = evaluate(x)
    norms = [float(np.linalg.norm(r[free]))]
    # Converged when the residual is small against the loads in play: the starting residual, or
    # the contact force itself (an increment in steady slip starts almost in equilibrium).
    scale = max(norms[0], float(np.linalg.norm((K @ x - r)[free])), 1e-300)
    for it in range(max_iterations):
        if norms[-1] <= rtol * scale and it > 0:
            break
        if it == 0:
            # Stick predictor: the trial traction of a fresh increment (eps_t times the probe's
            # whole move) dwarfs mu p, and a slip linearisation, with no tangential stiffness,
            # throws the body far off; the first step assumes every touching point sticks.
            D = D.copy()
            touching = pressure > 0
            D[:2, :2] = -probe.eps_t * np.eye(2)[:, :, None, None] * touching[None, None]
            D[:2, 2] = 0.0
        # r = K x - f_c(x) - f_ext, so the tangent is K - d f_c / dx (f_c acts on the u rows only).
        kc = skfem.asm(_tangent_form, contact_basis, D=D)
        kt = (K - sp.bmat([[kc, None], [None, sp.csr_matrix((n_rest, n_rest))]], format="csr")).tocsr()
        dx = spla.spsolve(kt[free][:, free].tocsc(), -r[free])
        if not np.all(np.isfinite(dx)):
            raise SolverError(f"{case}: the contact tangent is singular (NaN in the Newton step)")
        alpha = 1.0
        while True:  # backtracking on the residual norm (stick/slip switches make Newton non-smooth)
            trial = x.copy()
            trial[free] += alpha * dx
            r_t, t_t, D_t, p_t, s_t, u_t = evaluate(trial)
            norm_t = float(np.linalg.norm(r_t[free]))
            if norm_t < norms[-1] or alpha < 1.0 / 256 or it == 0:
                break
            alpha *= 0.5
        x, r, t, D, pressure, stick, u_q = trial, r_t, t_t, D_t, p_t, s_t, u_t
        norms.append(norm_t)
    else:
        if not norms[-1] <= rtol * scale:
            raise SolverError(f"{case}: contact Newton did not converge; residual {norms[-1]:.3e} (start {norms[0]:.3e})")
    if not np.all(np.isfinite(x)):
        raise SolverError(f"{case}: the solution contains NaN or Inf")
    history_norms = norms
    weights = np.asarray(contact_basis.dx)
    forces = {
        "normal_n": float(np.sum(pressure * weights)),
        "tangential_n": [float(np.sum(t[0] * weights)), float(np.sum(t[1] * weights))],
        "stick_fraction": float(np.sum(stick * weights) / max(np.sum((pressure > 0) * weights), 1e-300)),
        "iterations": len(history_norms) - 1,
        "residuals": history_norms,
    }
    new_history = ContactHistory(u_q.copy(), t[:2].copy(), np.asarray(probe.offset_m, dtype=float).copy())
    return x, new_history, forces
