"""Finite-strain statics: mixed neo-Hookean solid, Newton's method with line search and load stepping.

The compressible neo-Hookean energy of :mod:`fem.materials.neo_hookean` is written in the
two-field (Herrmann-type) form [BonetWood2008]_ (sec. 8.6) so that it does not lock as
lambda -> infinity:

    Pi(u, p) = int [ mu/2 (I1 - 3) - mu ln J + p ln J - p^2 / (2 lambda) ] dV - W_ext(u)

Stationarity in p gives p = lambda ln J and recovers W exactly. Residuals and consistent tangent:

    R_u(v)        = int [ mu (F - F^-T) + p F^-T ] : grad v  - W_ext(v)
    R_p(q)        = int q (ln J - p / lambda)
    K_uu(du, v)   = int mu grad du : grad v + (mu - p) tr(F^-1 grad v F^-1 grad du)
    K_up(dp, v)   = int dp tr(F^-1 grad v),     K_pp(dp, q) = -int dp q / lambda

At F = I, p = 0 the tangent is the linear P2P1 operator of :mod:`fem.elasticity` (tested). The
pressure unknowns are scaled by the shear modulus, as there.

Newton: the tangent system is solved directly (SuperLU); the step is damped by backtracking on
the residual norm (Armijo-type sufficient decrease; the saddle point has no energy to minimise)
and by refusing any trial state that inverts an element (det F <= 0). Loads are applied in
increments; an increment that fails to converge is halved, down to a minimum, after which a
:class:`SolverError` names the load factor and the residual reached.

References
----------
.. [BonetWood2008] J. Bonet, R. D. Wood, "Nonlinear Continuum Mechanics for Finite Element
   Analysis", 2nd ed., Cambridge University Press (2008).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem
from skfem import BilinearForm, LinearForm
from skfem.helpers import ddot, det, grad, inv, mul, trace, transpose

from fem.elasticity import Discretisation, _per_qp
from mlsim.errors import MlsimError

__all__ = ["SolverError", "NewtonReport", "residual_and_tangent", "solve_nonlinear"]


class SolverError(MlsimError):
    """A nonlinear solve that did not converge (names the case, load factor and residual)."""


def _kinematics(w):
    F = _identity_like(w.prev.grad) + w.prev.grad
    return F, det(F), inv(F)


def _identity_like(g):
    out = np.zeros_like(g)
    for i in range(3):
        out[i, i] = 1.0
    return out


@LinearForm
def _residual_u(v, w):
    F, J, Finv = _kinematics(w)
    FinvT = transpose(Finv)
    P = w.mu * (F - FinvT) + w.s * w.p * FinvT
    return ddot(P, grad(v))


@LinearForm
def _residual_p(q, w):
    _, J, _ = _kinematics(w)
    return w.s * q * (np.log(J) - w.s * w.p / w.lam)


@BilinearForm
def _tangent_uu(du, v, w):
    F, J, Finv = _kinematics(w)
    return w.mu * ddot(grad(du), grad(v)) + (w.mu - w.s * w.p) * trace(mul(mul(Finv, grad(v)), mul(Finv, grad(du))))


@BilinearForm
def _tangent_up(dp, v, w):
    _, _, Finv = _kinematics(w)
    return w.s * dp * trace(mul(Finv, grad(v)))


@BilinearForm
def _tangent_pp(dp, q, w):
    return -(w.s * w.s) * dp * q / w.lam


def residual_and_tangent(d: Discretisation, x: np.ndarray, lam, mu, with_tangent: bool = True):
    """Internal residual (n,) and tangent (CSR) at state x = [u; p / scale] of a P2P1 discretisation.

    Raises FloatingPointError if any quadrature point has det F <= 0 (an inverted element).
    """
    if d.p is None:
        raise ValueError("the nonlinear tier uses the mixed P2P1 discretisation")
    s = d.pressure_scale
    u, ph = x[: d.n_u], x[d.n_u :]
    prev = d.u.interpolate(u)
    J = det(_identity_like(prev.grad) + prev.grad)
    if not np.all(J > 0):
        raise FloatingPointError(f"det F <= 0 at {int(np.sum(~(J > 0)))} quadrature point(s)")
    lam_q, mu_q = _per_qp(lam, d.u), _per_qp(mu, d.u)
    p_q = np.asarray(d.p.interpolate(ph))
    kw = dict(prev=prev, p=p_q, lam=lam_q, mu=mu_q, s=s)
    r = np.concatenate([skfem.asm(_residual_u, d.u, **kw), skfem.asm(_residual_p, d.p, prev=prev, p=p_q, lam=lam_q, s=s)])
    if not with_tangent:
        return r, None
    kuu = skfem.asm(_tangent_uu, d.u, **kw)
    kup = skfem.asm(_tangent_up, d.p, d.u, prev=prev, s=s)
    kpp = skfem.asm(_tangent_pp, d.p, lam=_per_qp(lam, d.p), s=s)
    return r, sp.bmat([[kuu, kup], [kup.T, kpp]], format="csr")


@dataclass
class NewtonReport:
    """What a nonlinear solve did: per load increment its factor, iterations and residual history."""

    load_factors: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    residuals: list = field(default_factory=list)  # per increment: the residual norms, first to last
    cuts: int = 0

    @property
    def total_iterations(self) -> int:
        return int(sum(self.iterations))


def solve_nonlinear(
    d: Discretisation,
    lam,
    mu,
    external: Callable[[float], np.ndarray],
    fixed: np.ndarray,
    fixed_values: Callable[[float], np.ndarray] | None = None,
    increments: int = 10,
    rtol: float = 1e-8,
    max_iterations: int = 25,
    min_increment: float = 1e-4,
    case: str = "nonlinear solve",
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, NewtonReport]:
    """Ramp the load factor t from 0 to 1 and solve R_int(x) = external(t) at each increment.

    external(t) -> (n,) external force vector (zeros on the pressure rows); fixed: constrained
    DOFs with values fixed_values(t) (default 0). An increment converges when the residual on the
    free DOFs falls below ``rtol`` times its value at the start of the increment (and below an
    absolute floor of 1e-14 of the load's size). Returns the state and a :class:`NewtonReport`.
    """
    n = d.n_dofs
    d.pressure_scale = float(np.max(mu))  # as in fem.elasticity.assemble
    x = np.zeros(n) if x0 is None else x0.copy()
    free = np.setdiff1d(np.arange(n), fixed)
    report = NewtonReport()
    t, dt = 0.0, 1.0 / increments
    while t < 1.0 - 1e-12:
        t_next = min(1.0, t + dt)
        trial = x.copy()
        if fixed_values is not None:
            trial[fixed] = fixed_values(t_next)
        ok, history = _newton(d, trial, lam, mu, external(t_next), free, rtol, max_iterations)
        if ok:
            x, t = trial, t_next
            report.load_factors.append(t)
            report.iterations.append(len(history) - 1)
            report.residuals.append(history)
            dt = min(dt * 1.5, 1.0 / increments * 4)
            continue
        report.cuts += 1
        dt *= 0.5
        if dt < min_increment:
            raise SolverError(
                f"{case}: Newton did not converge at load factor {t_next:.4g} (increment {dt * 2:.3g}); "
                f"residual {history[-1]:.3e} after {len(history) - 1} iterations, from {history[0]:.3e}"
            )
    if not np.all(np.isfinite(x)):
        raise SolverError(f"{case}: the solution contains NaN or Inf")
    return x, report


def _newton(d, x, lam, mu, f_ext, free, rtol, max_iterations):
    """Newton iterations in place on x; returns (converged, residual norms)."""
    try:
        r, k = residual_and_tangent(d, x, lam, mu)
    except FloatingPointError:
        return False, [np.inf]
    g = (r - f_ext)[free]
    history = [float(np.linalg.norm(g))]
    scale = max(history[0], 1e-300)
    floor = 1e-14 * max(np.linalg.norm(f_ext[free]), 1e-300)
    for _ in range(max_iterations):
        if history[-1] <= rtol * scale or history[-1] <= floor:
            return True, history
        kff = k[free][:, free].tocsc()
        try:
            dx = -spla.spsolve(kff, g)
        except RuntimeError:
            return False, history
        if not np.all(np.isfinite(dx)):
            return False, history
        alpha, accepted = 1.0, False
        while alpha >= 1.0 / 64:
            trial = x.copy()
            trial[free] += alpha * dx
            try:
                r_t, _ = residual_and_tangent(d, trial, lam, mu, with_tangent=False)
            except FloatingPointError:
                alpha *= 0.5
                continue
            g_t = (r_t - f_ext)[free]
            if np.linalg.norm(g_t) <= (1.0 - 1e-4 * alpha) * history[-1]:
                accepted = True
                break
            alpha *= 0.5
        if not accepted:
            return False, history
        x[:] = trial
        r, k = residual_and_tangent(d, x, lam, mu)
        g = (r - f_ext)[free]
        history.append(float(np.linalg.norm(g)))
    return history[-1] <= rtol * scale or history[-1] <= floor, history
