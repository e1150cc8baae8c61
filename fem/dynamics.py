"""Implicit dynamics of the mixed neo-Hookean solid: inertia, Rayleigh damping, and two time integrators.

The semi-discrete equations of motion of :mod:`fem.nonlinear`'s P2P1 solid are

    M a + C v + R_int(u, p) = f(t),        R_p(u, p) = 0,

with the consistent mass matrix M = int rho phi_i phi_j dV of the P2 displacement functions (no mass
on the pressure, which is a constraint field), and Rayleigh damping C = a_M M + b_K K_0 with K_0 the
stiffness at rest [Hughes2000]_ (sec. 9.3): a mode of angular frequency omega is damped by the ratio
zeta = a_M / (2 omega) + b_K omega / 2 (tested).

Time integrators (:data:`INTEGRATORS`):

- ``"generalized_alpha"`` [ChungHulbert1993]_: Newmark's update with the balance taken at
  t_{n+1-alpha_f} for the forces and t_{n+1-alpha_m} for the inertia,

      M a_{n+1-alpha_m} + C v_{n+1-alpha_f} + (1 - alpha_f) R_int(x_{n+1}) + alpha_f R_int(x_n) = f(t_{n+1-alpha_f}),

  with alpha_m = (2 rho_inf - 1) / (rho_inf + 1), alpha_f = rho_inf / (rho_inf + 1),
  gamma = 1/2 - alpha_m + alpha_f, beta = (1 - alpha_m + alpha_f)^2 / 4: second order, unconditionally
  stable for linear problems, the high frequencies damped to the spectral radius rho_inf (1: none,
  the trapezoidal rule; 0: annihilated in one step) while the low ones keep their amplitude. The
  internal force is interpolated between the two states (the "generalised-alpha with interpolated
  forces" of [Erlicher2002]_), which keeps the scheme's order for nonlinear problems but not its
  stability: released from a large bend (a 20:1 cantilever at P L^2 / EI = 3, steps of a tenth of
  the first period) it gained 2.7x its energy in ten steps with rho_inf = 0.8. Use it for resolved,
  small-amplitude motion (there it keeps the period within (omega dt)^2 / 12 and the energy to
  0.14 %: tests/test_dynamics.py); large rotations want backward Euler, the default.
- ``"backward_euler"``: v_{n+1} = (u_{n+1} - u_n) / dt, a_{n+1} = (v_{n+1} - v_n) / dt and the balance
  at t_{n+1}: first order, and energy-stable for any hyperelastic body and any step (the discrete
  energy never grows under a conservative load: the step's numerical dissipation is
  |v_{n+1} - v_n|_M^2 / 2 >= 0). It damps every mode it cannot resolve; with a large step it is a
  damped Newton that finds the stable equilibrium past a buckling load.

Each step is solved by :class:`fem.nonlinear.FullStepNewton` (the tier's one Newton) on the
effective residual R_int(x) + A (x - x_n) - f_eff, with A = (c_M M + c_C C) / (1 - alpha_f); a step
that does not converge is split in halves (:func:`integrate`).

References
----------
.. [ChungHulbert1993] J. Chung, G. M. Hulbert, "A time integration algorithm for structural dynamics
   with improved numerical dissipation: the generalized-alpha method", Journal of Applied Mechanics
   60 (1993) 371-375.
.. [Erlicher2002] S. Erlicher, L. Bonaventura, O. S. Bursi, "The analysis of the generalized-alpha
   method for non-linear dynamic problems", Computational Mechanics 28 (2002) 83-104.
.. [Hughes2000] T. J. R. Hughes, "The Finite Element Method: Linear Static and Dynamic Finite Element
   Analysis", Dover (2000), ch. 9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem
from skfem import BilinearForm
from skfem.helpers import det, dot

from fem.elasticity import Discretisation, _per_qp
from fem.nonlinear import FullStepNewton, _identity_like, residual_and_tangent
from mlsim.errors import SolverError

__all__ = ["cantilever_first_mode_rad_s", "INTEGRATORS", "TimeIntegrator", "time_integrator", "mass_matrix", "rayleigh_damping", "rayleigh_ratio",
           "strain_energy_j", "DynamicState", "DynamicReport", "integrate"]


# the first root of cos b cosh b = -1: the clamped-free Euler-Bernoulli beam's first mode
_CANTILEVER_ROOT = 1.8751040687119611


def cantilever_first_mode_rad_s(bending_stiffness_n_m2: float, mass_per_length_kg_m: float, length_m: float) -> float:
    """omega_1 = 1.8751^2 sqrt(EI / (m L^4)) (rad/s): the first bending mode of a clamped-free Euler-Bernoulli
    beam [Hughes2000]_ (the rods' time scale; shear and rotary inertia lower a stubby rod's, so this is an
    upper bound on the frequency and the step it asks for is conservative; tests/test_dynamics.py checks
    it on a slender rod)."""
    if not (bending_stiffness_n_m2 > 0 and mass_per_length_kg_m > 0 and length_m > 0):
        raise ValueError(f"EI = {bending_stiffness_n_m2} N m^2, m = {mass_per_length_kg_m} kg/m, L = {length_m} m: must be > 0")
    return _CANTILEVER_ROOT**2 * math.sqrt(bending_stiffness_n_m2 / (mass_per_length_kg_m * length_m**4))


@BilinearForm
def _mass_form(u, v, w):
    return w.rho * dot(u, v)


def mass_matrix(d: Discretisation, rho) -> sp.csr_matrix:
    """The consistent mass matrix (n_dofs, n_dofs) of the state [u; p]: int rho phi_i . phi_j dV on the
    displacement rows, zero on the pressure rows. rho: kg/m^3, a scalar or per element (T,)."""
    m_uu = skfem.asm(_mass_form, d.u, rho=_per_qp(rho, d.u))
    n_p = d.n_dofs - d.n_u
    return sp.block_diag([m_uu, sp.csr_matrix((n_p, n_p))], format="csr")


def rayleigh_damping(mass: sp.spmatrix, stiffness: sp.spmatrix, mass_coefficient_1_s: float, stiffness_coefficient_s: float,
                     n_u: int) -> sp.csr_matrix:
    """C = a_M M + b_K K_0 on the displacement rows (the pressure rows of a mixed stiffness carry no
    damping). mass_coefficient_1_s: a_M (1/s); stiffness_coefficient_s: b_K (s)."""
    if mass_coefficient_1_s < 0 or stiffness_coefficient_s < 0 or not (math.isfinite(mass_coefficient_1_s) and math.isfinite(stiffness_coefficient_s)):
        raise ValueError(f"Rayleigh coefficients a_M = {mass_coefficient_1_s}, b_K = {stiffness_coefficient_s}: must be finite and >= 0")
    k = sp.csr_matrix(stiffness)
    keep = sp.diags((np.arange(k.shape[0]) < n_u).astype(float))
    return (mass_coefficient_1_s * sp.csr_matrix(mass) + stiffness_coefficient_s * (keep @ k @ keep)).tocsr()


def rayleigh_ratio(omega_rad_s, mass_coefficient_1_s: float, stiffness_coefficient_s: float):
    """The damping ratio zeta = a_M / (2 omega) + b_K omega / 2 of a mode of angular frequency omega."""
    omega = np.asarray(omega_rad_s, dtype=float)
    return mass_coefficient_1_s / (2.0 * omega) + stiffness_coefficient_s * omega / 2.0


@dataclass(frozen=True)
class TimeIntegrator:
    """Coefficients of a one-step implicit integrator in Newmark form (see the module docstring)."""

    name: str
    alpha_m: float
    alpha_f: float
    beta: float
    gamma: float

    @property
    def first_order(self) -> bool:
        return self.name == "backward_euler"


def _generalized_alpha(spectral_radius: float) -> TimeIntegrator:
    r = spectral_radius
    if not (0.0 <= r <= 1.0):
        raise ValueError(f"spectral radius rho_inf = {r}: must be in [0, 1] (1: no numerical damping)")
    am, af = (2.0 * r - 1.0) / (r + 1.0), r / (r + 1.0)
    return TimeIntegrator("generalized_alpha", am, af, 0.25 * (1.0 - am + af) ** 2, 0.5 - am + af)


def _backward_euler(spectral_radius: float = 0.0) -> TimeIntegrator:
    return TimeIntegrator("backward_euler", 0.0, 0.0, 0.0, 1.0)


INTEGRATORS: dict[str, Callable[[float], TimeIntegrator]] = {"generalized_alpha": _generalized_alpha, "backward_euler": _backward_euler}


def time_integrator(name: str, spectral_radius: float = 0.8) -> TimeIntegrator:
    """The integrator registered as ``name`` (:data:`INTEGRATORS`); spectral_radius: generalised-alpha's rho_inf."""
    if name not in INTEGRATORS:
        raise ValueError(f'"{name}" is not a time integrator; choose one of: {", ".join(INTEGRATORS)}')
    return INTEGRATORS[name](spectral_radius)


def strain_energy_j(d: Discretisation, x: np.ndarray, lam, mu) -> float:
    """The stored energy (J) of the state x = [u; p / scale] in the two-field form of
    :mod:`fem.nonlinear`, int [mu/2 (I1 - 3) - mu ln J + p ln J - p^2 / (2 lambda)] dV, at the
    displacement basis's quadrature points. It equals int W dV where p = lambda ln J; read from the
    displacement alone (lambda/2 (ln J)^2) the P2 field's locked volume change would count many times
    over at nu = 0.49."""
    G = d.u.interpolate(x[: d.n_u]).grad
    F = np.asarray(_identity_like(G) + G)
    J = np.asarray(det(F))
    if not np.all(J > 0):
        raise SolverError(f"the state inverts {int(np.sum(~(J > 0)))} quadrature point(s) (det F <= 0)")
    I1 = np.einsum("ijeq,ijeq->eq", F, F)
    lnJ = np.log(J)
    p = d.pressure_scale * np.asarray(d.p.interpolate(x[d.n_u :]))
    mu_q, lam_q = _per_qp(mu, d.u), _per_qp(lam, d.u)
    W = 0.5 * mu_q * (I1 - 3.0) - mu_q * lnJ + p * lnJ - p**2 / (2.0 * lam_q)
    return float(np.sum(W * d.u.dx))


@dataclass
class DynamicState:
    """x = [u; p / scale], v and a (n_dofs,) at time t_s (v and a zero on the pressure rows)."""

    t_s: float
    x: np.ndarray
    v: np.ndarray
    a: np.ndarray


@dataclass
class DynamicReport:
    """What an integration did: per accepted step its size, Newton iterations; halvings."""

    steps_s: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    cuts: int = 0


class _Step:
    """The effective static problem of one step from a state: R_int(x) + A (x - x_n) = f_eff."""

    def __init__(self, scheme: TimeIntegrator, M, C, newton: FullStepNewton):
        self.scheme, self.M, self.C, self.newton = scheme, M, C, newton

    def take(self, state: DynamicState, dt: float, external: Callable[[float], np.ndarray], r_int_n: np.ndarray):
        s = self.scheme
        xn, vn, an = state.x, state.v, state.a
        if s.first_order:
            cm, cc, af = 1.0 / dt**2, 1.0 / dt, 0.0
            # a(x) = (x - xn) / dt^2 - vn / dt, v(x) = (x - xn) / dt at x = xn:
            a_star, v_star = -vn / dt, np.zeros_like(vn)
            f = external(state.t_s + dt)
        else:
            b, g, am, af = s.beta, s.gamma, s.alpha_m, s.alpha_f
            # a_{n+1}(x) = (x - xn) / (b dt^2) - vn / (b dt) - (1/2 - b) / b an, Newmark's v_{n+1}(x) likewise;
            # their values at x = xn, carried to t_{n+1-alpha_m} and t_{n+1-alpha_f}
            a1 = -vn / (b * dt) - (0.5 - b) / b * an
            v1 = vn + dt * ((1.0 - g) * an + g * a1)
            a_star = (1.0 - am) * a1 + am * an
            v_star = (1.0 - af) * v1 + af * vn
            cm, cc = (1.0 - am) / (b * dt**2), (1.0 - af) * g / (b * dt)
            f = external(state.t_s + (1.0 - af) * dt)
        A = ((cm * self.M + cc * self.C) / (1.0 - af)).tocsr()
        f_eff = (f - af * r_int_n - self.M @ a_star - self.C @ v_star) / (1.0 - af) + A @ xn
        guess = xn + dt * vn  # the state's own motion carried on
        ok, x, its, why = self.newton.solve(guess, f_eff, added_stiffness=A)
        if not ok and np.any(vn):
            ok, x, its2, why = self.newton.solve(xn, f_eff, added_stiffness=A)
            its += its2
        if not ok:
            return None, its, why
        if s.first_order:
            v = (x - xn) / dt
            a = (v - vn) / dt
        else:
            a = (x - xn) / (s.beta * dt**2) - vn / (s.beta * dt) - (0.5 - s.beta) / s.beta * an
            v = vn + dt * ((1.0 - s.gamma) * an + s.gamma * a)
        return DynamicState(state.t_s + dt, x, v, a), its, ""


def integrate(
    d: Discretisation,
    lam,
    mu,
    rho,
    external: Callable[[float], np.ndarray],
    fixed: np.ndarray,
    times_s: np.ndarray,
    damping: tuple[float, float] = (0.0, 0.0),
    scheme: str = "backward_euler",
    spectral_radius: float = 0.8,
    start: DynamicState | None = None,
    min_step_s: float | None = None,
    max_iterations: int = 20,
    case: str = "dynamic solve",
    on_step: Callable[[DynamicState], None] | None = None,
) -> tuple[list[DynamicState], DynamicReport]:
    """Integrate M a + C v + R_int(x) = external(t) through ``times_s`` (increasing, s), from ``start``
    (default: at rest, undeformed, at times_s[0]). Returns the states at times_s[1:] and a report.

    external(t) -> (n_dofs,) N; fixed: constrained DOFs (held at the start's values); damping: Rayleigh
    (a_M 1/s, b_K s) with K_0 the tangent at rest; scheme: :data:`INTEGRATORS`. A step whose Newton
    fails is split in halves down to ``min_step_s`` (default 1e-4 of the smallest interval), then a
    :class:`SolverError` says at which time and why.
    """
    times = np.asarray(times_s, dtype=float)
    if times.ndim != 1 or times.size < 2 or not np.all(np.isfinite(times)) or np.any(np.diff(times) <= 0):
        raise ValueError("times_s: must be at least two finite, strictly increasing times (s)")
    integrator = time_integrator(scheme, spectral_radius)
    n = d.n_dofs
    d.pressure_scale = float(np.max(mu))
    M = mass_matrix(d, rho)
    _, K0 = residual_and_tangent(d, np.zeros(n), lam, mu)
    C = rayleigh_damping(M, K0, damping[0], damping[1], d.n_u)
    newton = FullStepNewton(d, lam, mu, np.asarray(fixed), rtol=1e-9, max_iterations=max_iterations)
    stepper = _Step(integrator, M, C, newton)
    state = start or DynamicState(float(times[0]), np.zeros(n), np.zeros(n), np.zeros(n))
    if start is None and np.any(external(times[0])):
        # at rest under a load: the initial acceleration M a0 = f(t0) - R_int(0) (pressure rows: none)
        free_u = np.setdiff1d(np.arange(d.n_u), fixed)
        m_ff = M[free_u][:, free_u].tocsc()
        a0 = np.zeros(n)
        a0[free_u] = spla.spsolve(m_ff, external(times[0])[free_u])
        state.a = a0
    min_step = min_step_s if min_step_s is not None else 1e-4 * float(np.min(np.diff(times)))
    report = DynamicReport()
    out: list[DynamicState] = []
    r_int, _ = residual_and_tangent(d, state.x, lam, mu, with_tangent=False)
    for t_target in times[1:]:
        dt = t_target - state.t_s
        while state.t_s < t_target - 1e-12 * max(1.0, abs(t_target)):
            dt = min(dt, t_target - state.t_s)
            new, its, why = stepper.take(state, dt, external, r_int)
            if new is None:
                report.cuts += 1
                dt *= 0.5
                if dt < min_step:
                    raise SolverError(f"{case}: the step from t = {state.t_s * 1e3:.6g} ms did not converge down to a "
                                      f"{2 * dt * 1e3:.3g} ms step: {why}")
                continue
            if not np.all(np.isfinite(new.x)) or not np.all(np.isfinite(new.v)):
                raise SolverError(f"{case}: NaN or Inf in the state at t = {new.t_s * 1e3:.6g} ms")
            report.steps_s.append(dt)
            report.iterations.append(its)
            state = new
            r_int, _ = residual_and_tangent(d, state.x, lam, mu, with_tangent=False)
            dt = min(2.0 * dt, t_target - state.t_s) if state.t_s < t_target else dt
        state.t_s = float(t_target)
        out.append(DynamicState(state.t_s, state.x.copy(), state.v.copy(), state.a.copy()))
        if on_step is not None:
            on_step(out[-1])
    return out, report
