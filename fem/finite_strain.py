"""The ``nonlinear`` tier: the rod array as a mixed neo-Hookean solid under a moving rigid indenter,
with frictional contact inside Newton's loop.

The body is the two-field neo-Hookean solid of :mod:`fem.nonlinear` (P2P1, locking-free as
nu -> 1/2), base bottom clamped, gravity as a dead load. Contact uses the same points, load
columns W and contact law as the linear tiers (:mod:`fem.condensed`): a point's displacement is
u_c = W^T u (the hat-weighted mean over its faces), its force f(u_c) acts on the body as W f.
Because u_c is linear in u, W f is the exact virtual work of the point forces in any
configuration. Per step the residual and its consistent tangent are

    R(x) = R_int(x) - F_gravity - W f(W^T x),    A = K_T(x) - W D W^T,    D = df/du_c (3 x 3 per point),

solved by one of two Newton methods (``fidelity.solve.nonlinear_newton``):

- ``"condensed"`` (default): the condensed Newton of :class:`CondensedBody`: the body linearised once and
  condensed onto the contact points, the frictional contact solved exactly in every iteration by the
  linear tiers' bounded ADMM, the body's nonlinearity by an Anderson-accelerated outer iteration; a
  step it does not converge goes to the penalty Newton below;
- ``"penalty"``: Newton on R with contact inside the loop, backtracking on |R| (trial states that
  invert an element are refused) and a trust region on the contact points (no point moves more than
  ``max_step`` per iteration).

A step that fails is split in halves, recursively, as in :func:`fem.condensed.solve_path`; so is a
step that carries the indenter deeper than ``max_jump`` into the points where they were (tunnelling).

Outputs per step as the linear tiers' (:class:`fem.quasistatic.Episode`): the Cauchy stress
sigma = (mu (F F^T - I) + p I) / J at each tet's centroid, its von Mises stress, the strain energy
density W = mu/2 (I1 - 3 - 2 ln J) + p^2 / (2 lambda) (the compressible neo-Hookean energy of
:mod:`fem.materials.neo_hookean` with its volumetric part lambda/2 (ln J)^2 taken from the
pressure, p = lambda ln J: non-negative, and finite as lambda -> infinity, as the linear tiers'
complementary form), vertex displacements, contact forces and the clamp's reaction.

Cost. The penalty Newton assembles the tangent every iteration (the frictional tangent is not
symmetric); its direction comes from GMRES preconditioned by :class:`ContactWoodbury`: the body's
tangent, factorised (symmetric, MKL PARDISO, else SuperLU) and kept while GMRES follows, with the
contact points' tangent applied exactly through Woodbury's identity on the touching points
(``tangent_factorisations``, ``preconditioned_directions`` in the timings). Default sensor, first
pressing step (98.7k free DOFs, 266 touching points): 554 s with the whole tangent factorised on most
iterations (45 in 50), 176 s with one factorisation, 3.2 s by the condensed Newton (5 iterations;
per-rod forces within 0.3 % of the penalty Newton's, which rounds the return map's corner).
This is the reference tier, not the fast one.
"""

from __future__ import annotations

import time

import numpy as np
import scipy.linalg as sla
import scipy.sparse as sp
import skfem
from skfem import ElementTetP1, ElementTetP2, ElementVector

from fem import condensed, fields, trajectory
from fem.indenters import Pose
from fem.indenters import gap as indenter_gap
from fem.nonlinear import SolverError, residual_and_tangent

__all__ = ["run_nonlinear_episode", "centroid_fields", "rod_first_mode_rad_s", "rod_mass_per_length_kg_m", "dynamics_substeps", "dynamics_step_problems"]

# Newton directions by GMRES on the tangent, preconditioned by an earlier factorised body tangent with
# the current contact tangent taken exactly (ContactWoodbury): to this true relative residual (an inexact
# Newton step with forcing term 1e-3: the outer iteration keeps converging, its own tolerance is checked
# on the true residual) in at most this many iterations per restart (two restarts), else the body tangent
# is factorised anew. Default sensor, first pressing step: 1 factorisation in 50 Newton iterations and
# 4.5 GMRES iterations per direction; with forcing term 1e-4 SciPy's GMRES, which stops on the
# preconditioned residual, missed by a factor 1-7 and caused 15 factorisations.
INNER_RTOL = 1e-3
INNER_ITERATIONS = 30
# the condensed Newton (CondensedBody): converged when the body's unbalanced force is this fraction of
# the load; its contact solves (ADMM) to this relative tolerance. Default demo (solve stage 16, quiet 2-core
# machine), 1e-4 against 1e-6: the episode's per-rod forces, von Mises stress and displacements within 3e-6,
# 1.4e-5, 3.2e-5 (worst step 1.4e-5, 4.3e-5, 8.5e-5: three decades below any error the tier is the reference
# for) in 227 outer iterations instead of 293 and 96 s of steps instead of 114 s at 1e-5 (241 iterations,
# within 4e-6 / 8e-6 of 1e-6). A step's tail is linear, 3-5 iterations a decade, and costs the most where
# the rods are bent and twisted (steps 9-15: 32 s at 1e-4, 46 s at 1e-5). The same imbalance that
# CONDENSED_STALL_ACCEPT takes from a stalled step.
CONDENSED_RTOL = 1e-4
CONDENSED_ADMM_RTOL = 1e-7
# Every contact solve to CONDENSED_ADMM_RTOL. Solve stage 14 loosened those of iterations far from balance
# (an inexact Newton forcing term, Eisenstat and Walker 1996: 1e-2 x the last relative residual); once each
# contact solve started from the last iterate's points (condensed_step) a tight solve late in a step costs
# 5-40 ADMM iterations, and on the default demo (quiet 2-core machine) the loose solves saved 4 s of 147 s
# for 53 more outer iterations, and left steps stalling between loose and tight solves (relative residuals
# 3e-7 and 4e-5 in turn): removed at stage 15
CONDENSED_ANDERSON_MEMORY = 5  # differences kept by the outer iteration's Anderson acceleration
# a step still this far off (relative residual) after this many iterations is halved: on the default demo
# converging steps took 5-24 iterations to 1e-6 and were below 1e-3 by the 12th; a release step that
# did not converge in 40 (0.03-0.14) converged in 12 as two halves
CONDENSED_SLOW_AFTER = 12
CONDENSED_SLOW_RESIDUAL = 1e-2
# a step the condensed Newton does not finish goes to the penalty Newton from its best iterate when that
# came this close (relative residual), else from the step's start
CONDENSED_POLISH_FROM = 1e-2
# a condensed iteration whose best relative residual is at most CONDENSED_STALL_ACCEPT and has not improved
# for CONDENSED_STALL_AFTER iterations has stalled near the answer: its best iterate is accepted (a force
# imbalance of 1e-4 of the load, far below every tier's stated error; counted in the episode's timings)
CONDENSED_STALL_ACCEPT = 1e-4
CONDENSED_STALL_AFTER = 6
# after a step that needed a fresh linearisation (and where making one cost less than the failed try), the
# next steps linearise at their start first (_Problem._fresh_first)
RELINEARISE_AT_START = True
# under implicit dynamics a fresh linearisation that carried a step is kept for the next steps (_Problem._adopts):
# the 10.5 mm rods' swipe at 200 mm/s linearised afresh at every step's start once the rim met the rods (455
# contact points: the tangent, its factorisation and 1365 columns of Z per step, 1-2 min a step on 2 shared cores)
ADOPT_UNDER_DYNAMICS = True


def _with_best(exc: SolverError, best) -> SolverError:
    """``exc`` carrying the condensed Newton's best iterate (relative residual, state) or None, for the
    fallbacks of :meth:`_Problem.path`."""
    exc.best = best
    return exc


def _closer(best, exc: SolverError):
    """The closer of ``best`` and the best iterate ``exc`` carries (:func:`_with_best`; either may be None)."""
    other = getattr(exc, "best", None)
    return other if other is not None and (best is None or other[0] < best[0]) else best


_CENTROID_BASES: dict = {}


def _centroid_bases(d) -> tuple:
    """The P2 vector and P1 scalar bases of ``d``'s mesh at each tet's centroid, kept for one discretisation
    at a time: made anew at every step they were 0.2 s of each step's fields (default demo, 17 110 tets),
    half the cost of a step that converges in one iteration."""
    hit = _CENTROID_BASES.get(id(d))
    if hit is not None and hit[0] is d:
        return hit[1]
    mesh = d.u.mesh
    centroid = (np.full((3, 1), 0.25), np.array([1.0 / 6.0]))
    bases = (skfem.Basis(mesh, ElementVector(ElementTetP2()), quadrature=centroid), skfem.Basis(mesh, ElementTetP1(), quadrature=centroid))
    _CENTROID_BASES.clear()
    _CENTROID_BASES[id(d)] = (d, bases)
    return bases


def centroid_fields(d, x: np.ndarray, lam: np.ndarray, mu: np.ndarray):
    """Cauchy stress (6, T) Pa (Voigt: xx, yy, zz, yz, xz, xy) and strain energy density (T,) J/m^3
    at each tet's centroid of the P2P1 state x = [u; p / scale]."""
    basis, pb = _centroid_bases(d)
    G = basis.interpolate(x[: d.n_u]).grad[:, :, :, 0]  # (3, 3, T)
    F = np.moveaxis(G, 2, 0) + np.eye(3)  # (T, 3, 3)
    J = np.linalg.det(F)
    if not np.all(J > 0):
        raise SolverError(f"the nonlinear state inverts {int(np.sum(~(J > 0)))} element(s) (det F <= 0)")
    p = d.pressure_scale * pb.interpolate(x[d.n_u :])[:, 0]  # (T,)
    B = F @ F.transpose(0, 2, 1)
    sigma_t = (mu[:, None, None] * (B - np.eye(3)) + p[:, None, None] * np.eye(3)) / J[:, None, None]
    sigma = np.stack([sigma_t[:, a, b] for a, b in fields.VOIGT])
    lnJ = np.log(J)
    I1 = np.trace(B, axis1=1, axis2=2)
    sed = 0.5 * mu * (I1 - 3.0 - 2.0 * lnJ) + p**2 / (2.0 * lam)
    return sigma, sed


class _Problem:
    """The discrete nonlinear contact problem of one episode: body, contact points, and a step solver."""

    def __init__(self, body, points: condensed.ContactPoints, shape, friction, k_n, k_t, smooth_m, max_step_m, max_jump_m,
                 max_penetration_m, rtol=1e-8, max_iterations=40, contact_solver="admm", contact_max_iterations=200):
        self.body, self.d = body, body.d
        self.points, self.W = points, points.W.tocsr()
        self.WT = self.W.T.tocsr()
        self.shape, self.friction, self.k_n, self.k_t = shape, friction, k_n, k_t
        self.smooth_m, self.max_step_m, self.max_jump_m, self.max_penetration_m = smooth_m, max_step_m, max_jump_m, max_penetration_m
        self.rtol, self.max_iterations = rtol, max_iterations
        self.free = body.free
        self.f_ext = body.f_gravity
        # implicit dynamics (set_inertia): the step's inertia and damping as a constant stiffness added to the
        # body, R_int(x) + A x = f_ext + W f; the forces' scale then excludes f_ext's inertial part
        self.added = None
        self.force_scale_n = None
        self._bodies: dict = {}  # the condensed Newton's linearisations, one per step size
        self._added_key = None
        self.iterations = 0
        self._woodbury = ContactWoodbury(self.W[self.free])
        self.contact_solver, self.contact_max_iterations = contact_solver, contact_max_iterations
        self._condensed = None  # the condensed Newton's linearisation (CondensedBody), kept over steps
        # linearise at each step's start before trying the kept linearisation: set once a step has needed a
        # fresh linearisation and making one cost less than the failed try it saves (measured), cleared when a
        # fresh one fails (path). A 2 x 12 mm rod pushed sideways by a frictionless sphere: every step past a third
        # of its height failed on the first state's linearisation (13 iterations, 4-6 s) and converged in 2-7 on
        # one made at its start (1-2 s); on the default demo a linearisation (9 s) costs more than such a try
        self._fresh_first = False
        self.condensed_rtol = CONDENSED_RTOL
        self.admm_rtol = CONDENSED_ADMM_RTOL
        self.contact_iterations = 0
        self.linearisations = 0
        self.followed_steps = 0  # steps the condensed Newton finished only by following its iterates (path)
        self.fallbacks = 0  # steps the condensed Newton handed to the penalty Newton
        self.stalled_steps, self.max_stalled_residual = 0, 0.0  # condensed steps accepted at a stall (CONDENSED_STALL_ACCEPT)
        m = points.m
        blocks = np.arange(3 * m).reshape(m, 3)
        self._rows = np.repeat(blocks, 3, axis=1).ravel()
        self._cols = np.tile(blocks, (1, 3)).ravel()

    def set_inertia(self, added: sp.csr_matrix | None, f_ext: np.ndarray, force_scale_n: float | None, key=None) -> None:
        """The next steps' added stiffness (an implicit step's (M / dt^2 + C / dt), or None), right-hand side
        and force scale; ``key`` names the added stiffness (the step size): the condensed Newton keeps one
        linearisation per key, since its kept tangent must carry the step's inertia."""
        if key != self._added_key:
            self._bodies[self._added_key] = self._condensed
            self._condensed = self._bodies.pop(key, None)
            self._added_key = key
        self.added, self.f_ext, self.force_scale_n = added, f_ext, force_scale_n

    def internal(self, x, with_tangent=True):
        """R_int(x) (+ A x) and its tangent (+ A): the body with the step's inertia, if any."""
        r, K = residual_and_tangent(self.d, x, self.body.lam, self.body.mu, with_tangent)
        if self.added is None:
            return r, K
        return r + self.added @ x, (K + self.added if with_tangent else None)

    def _force_scale(self, extra: float) -> float:
        own = self.force_scale_n if self.force_scale_n is not None else float(np.linalg.norm(self.f_ext[self.free]))
        return max(own, extra, 1e-12)

    def _direction(self, A: sp.csr_matrix, K: sp.csr_matrix, D: np.ndarray, rhs: np.ndarray) -> np.ndarray:
        """A^-1 rhs for the Newton direction, A = K - W D W^T on the free DOFs (:class:`ContactWoodbury`)."""
        return self._woodbury.direction(A, K, D, rhs)

    def point_u(self, x):
        return (self.WT @ x).reshape(-1, 3)

    @property
    def factorisations(self) -> int:
        return self._woodbury.factorisations

    @property
    def inner_solves(self) -> int:
        return self._woodbury.iterations

    def _evaluate(self, x, pose, drag, state, predictor, with_tangent):
        r_int, K = self.internal(x, with_tangent)
        u_c = self.point_u(x)
        law = condensed._contact_law(self.points.X, u_c, self.shape, pose, drag, state, self.friction, self.k_n, self.k_t, predictor, self.smooth_m)
        R = r_int - self.f_ext - self.W @ law.f.ravel()
        A = None
        if with_tangent:
            Dm = sp.csr_matrix((law.D.ravel(), (self._rows, self._cols)), shape=(3 * self.points.m,) * 2)
            free = self.free
            K = K[free][:, free].tocsr()
            A = (K - self.W[free] @ Dm @ self.WT[:, free]).tocsr()
            A = (A, K)
        return R, A, law

    def newton(self, x0, pose, pose_old, state, case):
        """Newton for one step from x0; returns (x, law) or raises SolverError."""
        drag = condensed.rigid_motion(pose_old, pose, self.points.X + state.u)
        x = x0.copy()
        free = self.free
        try:
            R, A, law = self._evaluate(x, pose, drag, state, True, True)
        except FloatingPointError as exc:
            raise SolverError(f"{case}: {exc}") from None
        scale = self._force_scale(float(np.linalg.norm((self.W @ law.f.ravel())[free])))
        norm = float(np.linalg.norm(R[free]))
        history = [norm]
        for it in range(self.max_iterations):
            if norm <= self.rtol * scale:
                return x, law, it
            dx = np.zeros_like(x)
            dx[free] = self._direction(A[0], A[1], law.D, -R[free])
            if not np.all(np.isfinite(dx)):
                raise SolverError(f"{case}: the nonlinear contact tangent is singular (iteration {it})")
            du_c = np.linalg.norm(self.point_u(dx), axis=1).max()
            if du_c > self.max_step_m:
                dx *= self.max_step_m / du_c
            alpha, accepted = 1.0, False
            while alpha >= 1.0 / 64:
                trial = x + alpha * dx
                try:
                    R_t, _, law_t = self._evaluate(trial, pose, drag, state, False, False)
                except FloatingPointError:
                    alpha *= 0.5
                    continue
                n_t = float(np.linalg.norm(R_t[free]))
                if n_t < (1.0 - 1e-4 * alpha) * norm or it == 0:
                    accepted = True
                    break
                alpha *= 0.5
            if not accepted:
                raise SolverError(f"{case}: the nonlinear line search stalled at iteration {it}; residual {norm:.3e} N (start {history[0]:.3e} N)")
            x = trial
            R, A, law = self._evaluate(x, pose, drag, state, False, True)
            norm = float(np.linalg.norm(R[free]))
            history.append(norm)
            self.iterations += 1
            scale = max(scale, float(np.linalg.norm((self.W @ law.f.ravel())[free])))
            if not np.isfinite(norm):
                raise SolverError(f"{case}: NaN or Inf in the nonlinear iteration {it}")
            if it >= 12 and norm > 1e-1 * history[0]:
                # far from quadratic convergence: a half step is cheaper than plodding on
                raise SolverError(f"{case}: nonlinear Newton is converging slowly (residual {norm:.3e} N after {it + 1} "
                                  f"iterations, from {history[0]:.3e} N)")
        if norm <= self.rtol * scale:
            return x, law, self.max_iterations
        raise SolverError(f"{case}: nonlinear Newton did not converge in {self.max_iterations} iterations; residual {norm:.3e} N "
                          f"(start {history[0]:.3e} N, tolerance {self.rtol * scale:.3e} N)")

    def condensed_step(self, x0, pose, pose_old, state, case, follow_iterates=False):
        """One step by the condensed Newton of :class:`CondensedBody`: the contact solved exactly (ADMM,
        :func:`fem.condensed.solve_path`) on the body linearised at the episode's first state, the
        body's nonlinearity by the outer fixed-point iteration, accelerated by Anderson's rule. Each
        contact solve after the first linearises the indenter's gap at the last iterate's points
        (:meth:`_linearise_at`; ``follow_iterates``: there alone, the retry of :meth:`path`). Returns
        (x, law, outer iterations) or raises SolverError."""
        body = self._condensed
        if body is None:
            body = self._condensed = CondensedBody(self, x0)
        free = self.free

        def residual(x):
            try:
                r_int, _ = self.internal(x, with_tangent=False)
            except FloatingPointError:
                return None
            return (self.f_ext - r_int)[free]

        x, r = x0.copy(), residual(x0)
        if r is None:
            raise SolverError(f"{case}: the step's start inverts an element")
        history: list[float] = []
        best, best_it = None, 0  # (relative residual, state, law) of the best iterate where the contact forces were found
        xs, gs = [], []  # Anderson's memory: iterates and their updates G(x) - x (free DOFs)
        u_guess = None  # the first contact solve linearises the gap at the points carried by the indenter
        anchor = state.u + condensed.rigid_motion(pose_old, pose, self.points.X + state.u)
        for it in range(self.max_iterations):
            y = body.fact.solve(r)
            u0 = self.point_u(x) + (body.Wf.T @ y).reshape(-1, 3)
            u_points, law, info = condensed.solve_path(body.C, u0, self.points.X, self.shape, pose, pose_old, state, self.friction,
                                                       self.k_n, self.k_t, case=case, delassus=body.delassus, warm=body.warm, guess=u_guess,
                                                       max_iterations=self.contact_max_iterations, admm_rtol=self.admm_rtol,
                                                       max_penetration_m=self.max_penetration_m, max_jump_m=self.max_jump_m)
            self.contact_iterations += info["iterations"]
            self.iterations += 1
            f = info["f"].ravel()
            g = y + body.Z @ f
            # the plain update puts the points where the contact forces f were found: its unbalanced
            # force is the body's nonlinearity alone
            x_c = x.copy()
            x_c[free] += g
            r_c = residual(x_c)
            alpha = 1.0
            while r_c is None and alpha > 1.0 / 64:
                # the update inverts an element (a kept linearisation far from this state overshoots):
                # shorten it; the next iteration finds the contact forces again where it lands
                alpha *= 0.5
                g = alpha * g
                x_c = x.copy()
                x_c[free] += g
                r_c = residual(x_c)
                xs, gs = [], []
            if r_c is None:
                raise SolverError(f"{case}: a condensed Newton iterate inverts an element (iteration {it}) even at 1/64 of the update")
            if alpha < 1.0:
                # not the points where f was found: no convergence test here, iterate on
                x, r = x_c, r_c
                history.append(np.inf)
                continue
            Wf_f = body.Wf @ f
            norm = float(np.linalg.norm(r_c + Wf_f))
            scale = self._force_scale(float(np.linalg.norm(Wf_f)))
            history.append(norm / scale)
            # the next contact solve linearises the indenter's gap where these forces put the points, not where
            # the step started: on the default demo every outer iteration re-ran the step's 4 gap linearisations
            # from its start (95 + 81 + 27 + 23 ADMM iterations at each iteration of step 9: 5-40 from here)
            u_guess = u_points if follow_iterates else self._linearise_at(u_points, anchor, pose)
            if norm <= self.condensed_rtol * scale:
                return x_c, law, it + 1
            if not np.isfinite(norm):
                raise SolverError(f"{case}: NaN or Inf in the condensed Newton iteration {it}")
            if best is None or history[-1] < best[0]:
                best, best_it = (history[-1], x_c, law), it
            if best[0] <= CONDENSED_STALL_ACCEPT and it - best_it >= CONDENSED_STALL_AFTER:
                # stalled near the answer (the active set of a curved contact cycling between iterates: seen
                # at relative residuals 4e-6 to 2e-5 on a rod pushed sideways by a sphere, where the
                # penalty Newton stalled at 1e-2): the best iterate is the step's answer, and the episode
                # reports the largest residual accepted so
                return (*self._accept_stall(best), it + 1)
            if it >= CONDENSED_SLOW_AFTER and history[-1] > CONDENSED_SLOW_RESIDUAL:
                # far from converging: half steps are cheaper (self.path) than plodding on
                raise _with_best(SolverError(f"{case}: the condensed Newton is converging slowly (relative residual {history[-1]:.1e} after "
                                             f"{it + 1} iterations)"), best)
            xs.append(x[free].copy())
            gs.append(g)
            if len(xs) > CONDENSED_ANDERSON_MEMORY + 1:
                xs.pop(0)
                gs.pop(0)
            x_next = x_c
            if len(xs) >= 2:
                dX = np.stack([b - a for a, b in zip(xs[:-1], xs[1:])], axis=1)
                dG = np.stack([b - a for a, b in zip(gs[:-1], gs[1:])], axis=1)
                gamma = np.linalg.lstsq(dG, g, rcond=None)[0]
                x_next = x.copy()
                x_next[free] += g - (dX + dG) @ gamma
            r_next = residual(x_next) if x_next is not x_c else r_c
            if r_next is None:  # the extrapolation inverted an element: the plain update, memory cleared
                x_next, r_next, xs, gs = x_c, r_c, [], []
            x, r = x_next, r_next
        if best is not None and best[0] <= CONDENSED_STALL_ACCEPT:
            return (*self._accept_stall(best), self.max_iterations)
        raise _with_best(SolverError(f"{case}: the condensed Newton did not converge in {self.max_iterations} iterations; relative residuals "
                                     + ", ".join(f"{h:.1e}" for h in history[-4:])), best)

    def _linearise_at(self, u_points: np.ndarray, anchor: np.ndarray, pose) -> np.ndarray:
        """Where the next contact solve linearises the indenter's gap: at each point's last solution
        ``u_points``, except where that lies off the indenter and the step's start carried by the indenter
        (``anchor``) lies in it: there at ``anchor``.

        Frictional contact can have several solutions, and the step's answer must be the one its start
        continues. An outer iterate far from balance can carry a point off the indenter (a bent rod's tip
        past the punch's rim); linearised there, the contact solve finds the rod free, and the step
        converges to that other equilibrium: default demo, first release step, a rod held by friction at
        the rim came free with its tip 1.5 mm away, where the same move in 8 steps keeps it at 0.29 N.
        Linearised at its start, the point keeps the contact until the contact law itself lets it go (the
        8 steps' answer). Points in contact at both stay at their solution: linearising them at the start
        as well (whichever lay deeper) cost 3x the ADMM iterations on the demo (421 s against 177 s)."""
        g_new = indenter_gap(self.shape, pose, self.points.X + u_points)
        g_old = indenter_gap(self.shape, pose, self.points.X + anchor)
        return np.where(((g_old < 0.0) & (g_new > 0.0))[:, None], anchor, u_points)

    def _accept_stall(self, best) -> tuple:
        """(state, law) of a stalled condensed iteration's best iterate (relative residual, state, law),
        counted in the episode's timings."""
        self.stalled_steps += 1
        self.max_stalled_residual = max(self.max_stalled_residual, best[0])
        return best[1], best[2]

    @property
    def _adopts(self) -> bool:
        """Does a fresh linearisation that carried a step become the kept one? Under implicit dynamics
        (``ADOPT_UNDER_DYNAMICS``): the step's inertia M / dt^2 keeps the tangent of a bent or pressed
        state definite, and the next steps start near it. Quasi-static steps keep the first state's."""
        return ADOPT_UNDER_DYNAMICS and self.added is not None

    def _step_linearised_at(self, x_lin, pose, pose_old, state, case) -> tuple:
        """:meth:`condensed_step` from ``x_lin`` on the body linearised there; the kept linearisation is left
        as it was unless the step converged and the problem :attr:`_adopts` (then the new one is kept).
        Returns (x, law, seconds the linearisation took) or raises."""
        kept = self._condensed
        try:
            seconds = time.perf_counter()
            self._condensed = CondensedBody(self, x_lin)
            seconds = time.perf_counter() - seconds
            x, law, _ = self.condensed_step(x_lin, pose, pose_old, state, case)
            if self._adopts:
                kept = self._condensed
            return x, law, seconds
        finally:
            self._condensed = kept

    def contact_start(self) -> tuple:
        """Where the kept linearisation's contact solve starts (its ADMM warm start, or a fresh one's before
        the episode's first condensed step), for :meth:`restart_contact`."""
        from fem.contact_admm import WarmStart

        return (self._condensed.warm if self._condensed is not None else WarmStart()).starting_point()

    def restart_contact(self, start: tuple) -> None:
        """Start the next condensed step's contact solve from ``start`` (:meth:`contact_start`): force control's
        trial heights each from the step's own, not from the trial before, so that the answer does not
        depend on the order the search tries heights in (as in the linear tiers, fem.quasistatic)."""
        if self._condensed is not None:
            self._condensed.warm.restart_from(start)

    def jumps(self, pose, state) -> bool:
        """Would the indenter at ``pose`` sink deeper than ``max_jump`` into the points where they are (tunnelling)?"""
        return -float(indenter_gap(self.shape, pose, self.points.X + state.u).min()) > self.max_jump_m

    def path(self, x0, pose, pose_old, state, case, depth=8, guess=None):
        """:meth:`newton` from ``pose_old`` to ``pose``, halving the move on failure or tunnelling
        (:func:`fem.continuation.solve_with_halving`). ``x0`` is the converged state at ``pose_old``;
        ``guess``, if given, a starting iterate for the whole move only (an extrapolation): a half
        starts from the state it continues, never from a guess made for the whole move (whose
        rotations, on a rod bent far, can be far from a half's answer or invert elements)."""
        from fem.continuation import solve_with_halving

        def step(p_old, p, start, whole):
            x_start, st = start
            if whole and guess is not None:
                x_start = guess
            guess_n = x_start
            if self.contact_solver == "admm" and self._fresh_first and RELINEARISE_AT_START:
                try:
                    x, law, _ = self._step_linearised_at(x_start, p, p_old, st, case)
                    self._fresh_first = not self._adopts  # an adopted linearisation is the step's start already
                    return x, law
                except (SolverError, FloatingPointError):
                    self._fresh_first = False
            if self.contact_solver == "admm":
                t_try = time.perf_counter()
                try:
                    x, law, _ = self.condensed_step(x_start, p, p_old, st, case)
                    return x, law
                except SolverError as exc:
                    t_try = time.perf_counter() - t_try
                    # the kept linearisation does not carry this move (seen on the demo's release under a
                    # twisted, stuck probe; a rod bent far sideways): two retries, then the penalty Newton on the
                    # true tangent from the closest iterate, then halves.
                    # - fresh: once more, linearised where the first try came closest (else at the step's start);
                    # - follow: the kept linearisation with every contact solve linearised at the last iterate's
                    #   points alone. On the default demo the release steps where the punch lets rods go (the body at
                    #   the step's start unstable without its contact: the rods are held bent by friction alone and
                    #   snap back) converged so in 20 and 13 iterations, where the first try's iterates oscillated
                    #   and the penalty Newton took 1-3 min (docs/stages/solve.md: past the snap the quasi-static
                    #   answer is one of several equilibria).
                    # Quasi-static steps follow first: there the fresh linearisation failed on both those steps
                    # (unstable, or diverging) and cost the demo 10-30 s each (its Z: 1104 solves). Under dynamics the fresh
                    # linearisation comes first: it is kept for the next steps (_adopts), which start near it.
                    best = getattr(exc, "best", None)
                    for kind in (("fresh", "follow") if self._adopts else ("follow", "fresh")):
                        if kind == "fresh" and whole:
                            near = best[1] if best is not None and best[0] < 1.0 else x_start
                            try:
                                x, law, t_lin = self._step_linearised_at(near, p, p_old, st, case)
                                self._fresh_first = t_lin < t_try and not self._adopts
                                return x, law
                            except SolverError as again:
                                best = _closer(best, again)
                        elif kind == "follow":
                            try:
                                x, law, _ = self.condensed_step(x_start, p, p_old, st, case, follow_iterates=True)
                                self.followed_steps += 1
                                return x, law
                            except SolverError as again:
                                best = _closer(best, again)
                    if best is not None and best[0] < CONDENSED_POLISH_FROM:
                        # stalled near the answer (the active set of a curved contact cycling between iterates,
                        # seen at relative residuals 1e-5 on a rod pushed sideways): Newton's quadratic tail
                        # from there costs a few iterations, from the step's start tens
                        guess_n = best[1]
                    self.fallbacks += 1
            x, law, _ = self.newton(guess_n, p, p_old, st, case)
            return x, law

        def jumps(p, start):
            return self.jumps(p, start[1])

        def too_deep(result):
            law = result[1]
            deep = float(np.max(law.fn / self.k_n)) if law.fn.size else 0.0
            return None if deep <= self.max_penetration_m else f"{case}: penetration {deep * 1e6:.1f} um"

        def next_start(result):
            x1, law1 = result
            return x1, condensed.PointState(self.point_u(x1), law1.f_t.copy())

        return solve_with_halving(step, pose_old, pose, (x0, state), depth, jumps=jumps, too_deep=too_deep,
                                  deep_at_the_end="return" if depth > 0 else "raise",
                                  next_start=next_start)


class ContactWoodbury:
    """Newton directions of the contact problem, A dx = b with A = K - W D W^T (free DOFs): the body's
    tangent K (symmetric), the contact points' load columns W (n, 3 m) and their 3 x 3 contact
    tangents D (m, 3, 3; zero off contact, not symmetric with friction).

    The contact part changes from one Newton iteration to the next (points touch, stick, slip), the
    body's tangent only slowly. So K is factorised (PARDISO, symmetric indefinite) and kept, with
    Z = K^-1 W for the touching points' columns (computed when a point first touches), and A^-1 is
    applied exactly by Woodbury's identity on the touching points a:

        A^-1 b = y + Z_a s,   y = K^-1 b,   (I - D_a C_aa) s = D_a W_a^T y,   C_aa = W_a^T Z_a.

    When K has moved on since its factorisation, this is the preconditioner of GMRES on the true A
    (only the body's change is left for GMRES); when GMRES misses ``rtol`` in ``restart`` iterations,
    the current K is factorised and its Woodbury form is exact. Before this, the whole frictional
    tangent (general LU, 6 s on the default sensor) was factorised on nearly every iteration: a new
    touching or slipping point is a change GMRES cannot follow cheaply, but Woodbury takes exactly.
    """

    def __init__(self, W: sp.spmatrix, rtol: float = INNER_RTOL, restart: int = INNER_ITERATIONS, block: int = 96):
        self.W = W.tocsc()
        self.WT = W.T.tocsr()
        self.n, self.m = W.shape[0], W.shape[1] // 3
        self.rtol, self.restart, self.block = rtol, restart, block
        self.factorisations = 0
        self.iterations = 0
        self._fact = None
        self._slot = np.full(self.m, -1)  # each point's place in Z (columns 3 slot .. 3 slot + 2), -1: not computed
        self._Z = None
        self._count = 0

    def _refactor(self, K: sp.csr_matrix) -> None:
        from fem.linsolve import factorise

        self._fact = factorise(K, definite=False, symmetric=True)
        self.factorisations += 1
        self._slot[:] = -1
        self._count = 0

    def _columns(self, points: np.ndarray) -> np.ndarray:
        """The Z columns of ``points`` (computed now for those not yet seen); returns their Z column indices.
        Z is kept in C order (a sparse-times-dense product with a Fortran-ordered Z copies it whole), and
        with each block of new columns its products with every point's W^T (``_C``), so that C_aa of any
        touching set is a lookup."""
        need = points[self._slot[points] < 0]
        if need.size:
            if self._Z is None:
                self._Z = np.empty((self.n, 3 * self.m))  # pages are touched only as columns fill
                self._C = np.empty((3 * self.m, 3 * self.m))
            for i in range(0, need.size, self.block // 3):
                chunk = need[i : i + self.block // 3]
                cols = (3 * chunk[:, None] + np.arange(3)).ravel()
                at = 3 * self._count
                Zb = np.ascontiguousarray(self._fact.solve(self.W[:, cols].toarray()))
                self._Z[:, at : at + cols.size] = Zb
                self._C[:, at : at + cols.size] = self.WT @ Zb
                self._slot[chunk] = self._count + np.arange(chunk.size)
                self._count += chunk.size
        return (3 * self._slot[points][:, None] + np.arange(3)).ravel()

    def _operator(self, D: np.ndarray):
        """M^-1 as a function: the exact inverse of K_factorised - W D W^T."""
        active = np.flatnonzero(np.any(D != 0.0, axis=(1, 2)))
        if active.size == 0:
            return self._fact.solve
        zcols = self._columns(active)
        wcols = (3 * active[:, None] + np.arange(3)).ravel()
        k = 3 * self._count
        Z = self._Z[:, :k]
        Wa_T = self.WT[wcols]
        Dblk = D[active]  # (a, 3, 3)
        C = self._C[np.ix_(wcols, zcols)]  # (3 a, 3 a)
        DC = np.einsum("pij,pjk->pik", Dblk, C.reshape(active.size, 3, -1))
        cap = np.eye(3 * active.size) - DC.reshape(3 * active.size, -1)  # I - D_a C_aa
        lu = sla.lu_factor(cap, check_finite=False)

        def apply(b):
            y = self._fact.solve(b)
            t = np.einsum("pij,pj->pi", Dblk, (Wa_T @ y).reshape(-1, 3)).ravel()
            sz = np.zeros(k)
            sz[zcols] = sla.lu_solve(lu, t, check_finite=False)
            return y + Z @ sz

        return apply

    def direction(self, A: sp.csr_matrix, K: sp.csr_matrix, D: np.ndarray, b: np.ndarray) -> np.ndarray:
        import scipy.sparse.linalg as spla

        if self._fact is not None and self._fact.n == A.shape[0]:
            M = spla.LinearOperator(A.shape, matvec=self._operator(D), dtype=float)
            count = [0]

            def counted(_):
                count[0] += 1

            # SciPy's GMRES stops on the preconditioned residual: ask it for ten times less, accept on the
            # true one (an inexact Newton direction with forcing term rtol)
            x, info = spla.gmres(A, b, M=M, rtol=0.1 * self.rtol, atol=0.0, restart=self.restart, maxiter=2, callback=counted,
                                 callback_type="pr_norm")
            self.iterations += count[0]
            relative = float(np.linalg.norm(A @ x - b)) / max(float(np.linalg.norm(b)), 1e-300)
            if relative <= self.rtol and np.all(np.isfinite(x)):
                return x
        self._refactor(K)
        x = self._operator(D)(b)
        self.iterations += 1
        return x


class CondensedBody:
    """The body linearised at a state x_L and condensed onto the contact points, for the condensed Newton
    of :meth:`_Problem.condensed_step`: the factorised tangent K (symmetric, free DOFs), Z = K^-1 W for
    every contact point, the point compliance C = W^T Z and its Delassus operator.

    The condensed Newton solves each step as a sequence of the linear tiers' contact problem: at the
    state x_k, with r_k = f_ext - R_int(x_k),

        x_{k+1} = x_k + K^-1 r_k + Z f,   f = the frictional contact forces on the points, solved by ADMM
                                           (fem.condensed.solve_path) for the free displacements
                                           u_0 = W^T (x_k + K^-1 r_k) and the compliance C,

    until R_int(x) - f_ext - W f vanishes: the same equations as the penalty Newton of
    :meth:`_Problem.newton` (one contact law for every tier), with the contact's non-smoothness
    (touching, sticking, slipping) solved exactly in every iteration by the bounded ADMM and the body's
    smooth nonlinearity left to the outer iteration, accelerated by Anderson's rule
    (``CONDENSED_ANDERSON_MEMORY``). K is the tangent at the episode's first state (the body under
    gravity) and is kept: a modified Newton. It is the stiffest tangent the episode meets, so the
    iteration is damped rather than divergent; a tangent of a pressed state is not (rods pressed past
    their free Euler load have an indefinite tangent without the contact that holds them, and when
    the probe lifts they stiffen past it: both seen on the demo). A step it does not converge within
    ``CONDENSED_SLOW_AFTER`` iterations is retried (:meth:`_Problem.path`): following its own iterates and
    on the body linearised where it came closest (quasi-static steps in that order, dynamic ones in the
    other), then by the penalty Newton, then in halves. Halving first with the kept linearisation was
    slower (a release step of the demo ran past 5 minutes). Z costs 3 m solves (the default sensor: about
    1100 columns, about 9 s, once). Default demo at solve stage 16 (quiet 2-core machine): 1-14
    iterations and 0.3-6.5 s a step, the snap-back release steps 30 and 25 iterations (25 s and 14 s),
    98 s for the 22 steps, against 2.5-9.5 min for the first pressing step with the penalty Newton alone
    (docs/stages/solve.md has each stage's figures).
    """

    def __init__(self, problem: "_Problem", x: np.ndarray):
        from fem.contact_admm import DenseDelassus, WarmStart
        from fem.linsolve import factorise

        free = problem.free
        _, K = problem.internal(x, with_tangent=True)
        self.fact = factorise(K[free][:, free].tocsr(), definite=False, symmetric=True)
        self.Wf = problem.W[free].tocsc()
        n, k = self.Wf.shape
        self.Z = np.empty((n, k))
        for lo in range(0, k, 96):
            self.Z[:, lo : lo + 96] = self.fact.solve(self.Wf[:, lo : lo + 96].toarray())
        self.Wf = self.Wf.tocsr()
        C = np.asarray(self.Wf.T @ self.Z)
        self.C = 0.5 * (C + C.T)  # symmetric up to the solver's round-off
        try:
            self.delassus = DenseDelassus(self.C, problem.k_n)
        except np.linalg.LinAlgError as exc:
            raise SolverError(f"the body linearised at this state is not stable ({exc})") from None
        self.warm = WarmStart()
        problem.linearisations += 1


def rod_first_mode_rad_s(scene) -> float:
    """The first bending mode (rad/s) of the scene's rods: a clamped-free Euler-Bernoulli beam
    (:func:`fem.dynamics.cantilever_first_mode_rad_s`) with the layered section's EI
    (:func:`fem.rod_kinematics.euler_load_n`) and its layers' mass per length."""
    from fem import dynamics
    from fem.geometry import RodArray
    from fem.rod_kinematics import layered_bending_stiffness_n_m2

    g = RodArray.from_sensor(scene.sensor)
    young = [scene.material(r).young_modulus_pa.value for r in ("absorber", "ml_layer", "core")]
    bending = layered_bending_stiffness_n_m2(g.rod_radius_m, young, [g.absorber_m, g.ml_m])
    return dynamics.cantilever_first_mode_rad_s(bending, rod_mass_per_length_kg_m(scene), g.rod_height_m)


def rod_mass_per_length_kg_m(scene) -> float:
    """The scene's rods' mass per length (kg/m): the absorber, ML layer and core rings' densities times their areas."""
    from fem.geometry import RodArray

    g = RodArray.from_sensor(scene.sensor)
    rho = np.array([float(scene.material(r).density_kg_m3.value or 0.0) for r in ("absorber", "ml_layer", "core")])
    outer = g.rod_radius_m - np.array([0.0, g.absorber_m, g.absorber_m + g.ml_m])
    inner = np.append(outer[1:], 0.0).clip(min=0.0)
    return float(np.sum(rho * np.pi * (outer.clip(min=0.0) ** 2 - inner**2)))


def dynamics_substeps(scene) -> int:
    """The least ``fidelity.solve.substeps`` at which the nonlinear tier's dynamics resolve the rods'
    first bending mode (:func:`rod_first_mode_rad_s`) with ``fidelity.solve.steps_per_period`` steps a
    period, at the camera's frame rate: ceil(steps_per_period / (fps T_1))."""
    period = 2.0 * np.pi / rod_first_mode_rad_s(scene)
    # the 1e-9 keeps a step of exactly T_1 / steps_per_period (up to rounding) accepted
    return max(1, int(np.ceil(scene.fidelity.solve.steps_per_period / (scene.camera.fps * period) * (1.0 - 1e-9))))


def dynamics_step_problems(scene) -> list[tuple]:
    """[(field, value, fix)] of a scene whose nonlinear dynamics cannot run: a layer without a density,
    or a step (1 / (fps x substeps)) longer than the rods' first bending period over
    ``fidelity.solve.steps_per_period`` (the sensor kind's check: ``mlsim check`` says it before a run)."""
    f = scene.fidelity.solve
    # the nonlinear tier's dynamics, and the fast tiers' Cosserat rods' (fem.quasistatic.rod_inertia), at the same steps
    if not (f.tier == "nonlinear" or f.rod_kinematics == "cosserat") or f.dynamics == "quasi_static" or scene.load is None:
        return []
    regions = ("absorber", "ml_layer", "core")
    if any(not (scene.material(r).density_kg_m3.value or 0.0) > 0 for r in regions):
        return [("sensor.materials", [getattr(scene.sensor.materials, r) for r in regions],
                 "fidelity.solve.dynamics needs every layer's density (materials.NAME.density_kg_m3)")]
    period = 2.0 * np.pi / rod_first_mode_rad_s(scene)
    dt = 1.0 / (scene.camera.fps * f.substeps)
    need = dynamics_substeps(scene)
    if f.substeps >= need:
        return []
    return [("fidelity.solve.substeps", f.substeps,
             f"a {dt * 1e3:.3g} ms step cannot resolve the rods' first bending mode ({1.0 / period:.0f} Hz, {period * 1e3:.3g} ms; "
             f"fidelity.solve.steps_per_period = {f.steps_per_period:g}): set substeps to {need} or more, or dynamics to \"quasi_static\"")]


class _Inertia:
    """Backward Euler's inertia and damping for the nonlinear tier's steps (``fidelity.solve.dynamics``).

    A step of size dt from (x_n, v_n) solves M (x - x_n - dt v_n) / dt^2 + C (x - x_n) / dt + R_int(x)
    = f_gravity + W f(x): the body with the constant stiffness A = M / dt^2 + C / dt added and the
    right-hand side f_gravity + M (x_n + dt v_n) / dt^2 + C x_n / dt (:meth:`_Problem.set_inertia`);
    then v = (x - x_n) / dt. M is the consistent mass of the layers' densities
    (:func:`fem.dynamics.mass_matrix`), C = b_K K_0 stiffness-proportional Rayleigh damping with
    b_K = loss_factor / omega_1: the damping ratio loss_factor / 2 at the rods' first bending mode
    omega_1 (:func:`fem.dynamics.cantilever_first_mode_rad_s` of the layered section, the rods'
    mean density). Backward Euler is energy-stable at any step (fem.dynamics); a step that fails, or
    that would carry the indenter through the points (tunnelling), is split in halves in time and
    space alike, the second half from the first's state and velocity, down to 1 / 2^8 of the step.
    """

    def __init__(self, M: sp.csr_matrix, C: sp.csr_matrix, f_gravity: np.ndarray, omega_1: float):
        self.M, self.C, self.f_gravity, self.omega_1 = M, C, f_gravity, omega_1
        self.halvings = 0
        self._added: dict = {}
        self._known = (None, None)  # (state, R_int(state)): the episode loop's last assembly, reused by set()

    @classmethod
    def from_scene(cls, scene, body, settings, steps) -> "_Inertia":
        from fem import dynamics
        from mlsim.errors import Problem, SceneError

        problems = dynamics_step_problems(scene)
        if problems:
            raise SceneError([Problem(*p) for p in problems])
        omega_1 = rod_first_mode_rad_s(scene)
        M = dynamics.mass_matrix(body.d, body.rho)
        _, K0 = residual_and_tangent(body.d, np.zeros(body.n_dofs), body.lam, body.mu)
        C = dynamics.rayleigh_damping(M, K0, 0.0, settings.loss_factor / omega_1, body.d.n_u)
        return cls(M, C, body.f_gravity, omega_1)

    def set(self, problem: "_Problem", x: np.ndarray, v: np.ndarray, dt: float) -> None:
        """Put the step from (x, v) of size dt into the problem."""
        key = round(dt, 15)
        if key not in self._added:
            self._added[key] = (self.M / dt**2 + self.C / dt).tocsr()
        free = problem.free
        f = self.f_gravity + self.M @ (x + dt * v) / dt**2 + self.C @ x / dt
        state, r_int = self._known
        if state is not x:  # a half step's start: not assembled yet
            r_int, _ = residual_and_tangent(problem.d, x, problem.body.lam, problem.body.mu, with_tangent=False)
        scale = max(float(np.linalg.norm(self.f_gravity[free])), float(np.linalg.norm(r_int[free])))
        problem.set_inertia(self._added[key], f, scale, key)

    def remember(self, x: np.ndarray, r_int: np.ndarray) -> None:
        """R_int(x), assembled by the caller (the clamp's reaction), for the next step from x."""
        self._known = (x, r_int)

    def advance(self, problem: "_Problem", x, v, pstate, pose_old: Pose, pose: Pose, dt: float, case: str, depth: int = 8):
        """The state (x, v, law) a step of size dt later, the indenter moving from pose_old to pose."""
        from fem.continuation import midpoint

        if not problem.jumps(pose, pstate) or depth <= 0:
            self.set(problem, x, v, dt)
            try:
                x1, law = problem.path(x + dt * v, pose, pose_old, pstate, case, depth=0)
                return x1, (x1 - x) / dt, law
            except SolverError:
                if depth <= 0:
                    raise
        self.halvings += 1
        mid = midpoint(pose_old, pose)
        xa, va, law_a = self.advance(problem, x, v, pstate, pose_old, mid, 0.5 * dt, case, depth - 1)
        pa = condensed.PointState(problem.point_u(xa), law_a.f_t.copy())
        return self.advance(problem, xa, va, pa, mid, pose, 0.5 * dt, case, depth - 1)


def run_nonlinear_episode(scene, mesh, settings=None, progress: bool = False, log=None):
    """Solve the scene's load on ``mesh`` with the ``nonlinear`` tier; returns a
    :class:`fem.quasistatic.Episode` (tier ``"nonlinear"``, element ``"P2P1"``). ``log`` (a callable
    taking a line) gets a warning naming the steps that only following their iterates finished."""
    from fem.elasticity import dof_components
    from fem.episode import ContactSetup, Episode, LinearBody, SolveSettings, _bar, _check_finite, layer_materials, path_points

    settings = settings or SolveSettings.from_scene(scene)
    if scene.load is None:
        raise ValueError("load: the scene has no load; add a [load] section with an indenter and segments")
    timings: dict = {}
    lame, rho, e_contact = layer_materials(scene)
    body = LinearBody(mesh, lame, rho, "P2P1", settings.gravity, settings.backend, factorise=False)
    body.d.pressure_scale = float(np.max(body.mu))
    timings.update({f"body_{k}": v for k, v in body.seconds.items()})
    load = scene.load
    setup = ContactSetup.from_scene(scene, mesh, settings, e_contact)
    shape, tip_z, grid = setup.shape, setup.tip_z_m, setup.grid
    t0 = time.perf_counter()
    faces = condensed.contact_faces(mesh, settings.contact_band_m)
    all_points = condensed.contact_points(mesh, body.skmesh, body.d, faces)
    points = all_points.subset(path_points(all_points.X, shape, load, grid, tip_z, settings.path_margin_m))
    timings["precompute"] = time.perf_counter() - t0
    m = points.m
    k_n, k_t = setup.penalties(points.area_m2)
    problem = _Problem(body, points, shape, load.friction_coefficient, k_n, k_t, **setup.solve_kw(), contact_solver="admm" if settings.nonlinear_newton == "condensed" else "newton",
                       contact_max_iterations=settings.contact_max_iterations)
    n_rods = int(mesh.tet_rod.max()) + 1
    steps = grid.step_times_s
    S, T = len(steps), mesh.n_tets
    stress = np.zeros((S, 6, T), dtype=np.float32)
    sed = np.zeros((S, T), dtype=np.float32)
    disp = np.zeros((S, mesh.n_points, 3), dtype=np.float32)
    forces = np.zeros((S, m, 3))
    reaction = np.zeros((S, 3))
    pose_arr = np.zeros((S, 4))
    target = np.full(S, np.nan)
    iters = np.zeros(S, dtype=np.int64)
    stick = np.zeros(S)
    comp_fixed = dof_components(body.d.u)[body.fixed]
    # gravity alone first (the state before the indenter arrives), as a dead load: in one step (the rods' own
    # weight strains them by about 1e-4), by the condensed Newton where it is the method (its linearisation at
    # the unloaded body is the one the episode keeps: no factorisation of its own; the tiny scene 20.4 ->
    # 15.0 s on a shared machine), else by the penalty Newton, else in 4 increments
    x = np.zeros(body.n_dofs)
    state = trajectory.initial_state(load, tip_z)
    pose_old = Pose(tuple(state.position_m), state.yaw_rad)
    pstate = condensed.PointState(np.zeros((m, 3)), np.zeros((m, 3)))
    if settings.gravity:
        f_full = problem.f_ext
        try:
            if problem.contact_solver == "admm":
                x, law, _ = problem.condensed_step(x, pose_old, pose_old, pstate, "gravity")
            else:
                x, law, _ = problem.newton(x, pose_old, pose_old, pstate, "gravity")
        except SolverError:
            x = np.zeros(body.n_dofs)
            for k in (0.25, 0.5, 0.75, 1.0):
                problem.f_ext = k * f_full
                x, law, _ = problem.newton(x, pose_old, pose_old, pstate, "gravity")
        pstate = condensed.PointState(problem.point_u(x), np.zeros((m, 3)))
    bar = _bar(progress, S, "solve (nonlinear)")
    normal_now = 0.0
    x_last, last_move = None, None
    inertia = _Inertia.from_scene(scene, body, settings, steps) if settings.dynamics != "quasi_static" else None
    v, t_prev = np.zeros(body.n_dofs), 0.0
    if inertia is not None:
        timings["rod_first_mode_hz"] = inertia.omega_1 / (2.0 * np.pi)
    t_loop = time.perf_counter()
    step_ms = np.zeros(S)
    followed = []  # steps finished only by following their iterates (_Problem.path's last condensed retry)
    for s, t in enumerate(steps):
        followed_before = problem.followed_steps
        t_step = time.perf_counter()
        state = trajectory.advance(load, state, t, normal_now)
        case = f"step {s} (t = {t * 1e3:.1f} ms)"
        before = problem.iterations
        dynamic = inertia is not None and t > t_prev
        if inertia is not None and not dynamic:  # the episode's first step, at the start time: an equilibrium
            problem.set_inertia(None, body.f_gravity, None, None)
        if dynamic:
            x_prev = x
            if state.force_target_n is None:
                pose = Pose(tuple(state.position_m), state.yaw_rad)
                x, v, law = inertia.advance(problem, x, v, pstate, pose_old, pose, t - t_prev, case)
            else:
                inertia.set(problem, x, v, t - t_prev)
        elif state.force_target_n is None:
            pose = Pose(tuple(state.position_m), state.yaw_rad)
            move = np.array([*pose.position_m, pose.yaw_rad]) - np.array([*pose_old.position_m, pose_old.yaw_rad])
            guess = None
            if x_last is not None and np.allclose(move, last_move, rtol=1e-9, atol=1e-15) and np.any(move != 0):
                guess = 2.0 * x - x_last  # the same motion as the last step: extrapolate the state
            x_before = x
            x, law = problem.path(x, pose, pose_old, pstate, case, guess=guess)
            x_last, last_move = x_before, move
        if state.force_target_n is not None:
            z_free = tip_z + 1e-4 + float(np.abs(pstate.u[:, 2]).max())
            contact_start = problem.contact_start()

            def at_z(z, x_start=x):
                problem.restart_contact(contact_start)
                p = Pose((state.position_m[0], state.position_m[1], z), state.yaw_rad)
                xz, lz = problem.path(x_start, p, pose_old, pstate, case, depth=0 if dynamic else 8)
                return condensed.normal_force(lz), (xz, lz, p)

            z, (x, law, pose), _ = condensed.solve_points_at_force(state.force_target_n, state.position_m[2], at_z, z_free, case=case,
                                                                z_min=tip_z - scene.sensor.rod.height_mm * 1e-3)
            x_last = None
            state = trajectory.IndenterState(state.t_s, (state.position_m[0], state.position_m[1], z), state.yaw_rad, state.force_target_n, state.ramp_from_n)
            target[s] = state.force_target_n
            if dynamic:
                v = (x - x_prev) / (t - t_prev)
        t_prev = t
        pstate = condensed.PointState(problem.point_u(x), law.f_t.copy())
        pose_old = pose
        forces[s] = law.f
        normal_now = condensed.normal_force(law)
        pose_arr[s] = (*pose.position_m, pose.yaw_rad)
        iters[s] = problem.iterations - before
        stick[s] = float(law.stick.sum() / law.touching.sum()) if law.touching.any() else np.nan
        sig, w = centroid_fields(body.d, x, body.lam, body.mu)
        stress[s], sed[s] = sig, w
        disp[s] = x[body.vertex_dofs.ravel()].reshape(-1, 3)
        r_int, _ = residual_and_tangent(body.d, x, body.lam, body.mu, with_tangent=False)
        # the clamp's force on the body: minus the body's unbalanced force at the fixed DOFs (with dynamics, less the
        # inertia of the consistent mass's clamp rows, which is left out)
        unbalanced = (r_int - body.f_gravity - points.W @ law.f.ravel())[body.fixed]
        reaction[s] = [unbalanced[comp_fixed == c].sum() for c in range(3)]
        if inertia is not None:
            inertia.remember(x, r_int)
        step_ms[s] = 1e3 * (time.perf_counter() - t_step)
        if problem.followed_steps > followed_before:
            followed.append(s)
        bar(s + 1)
    timings["contact_steps"] = time.perf_counter() - t_loop
    # each step's wall time, its fields included (benchmarks/bench_tiers.py: median and worst by kind of step)
    timings["contact_step_ms"] = step_ms.tolist()
    timings["tangent_factorisations"] = problem.factorisations + problem.linearisations
    timings["contact_iterations"] = problem.contact_iterations
    timings["penalty_newton_steps"] = problem.fallbacks
    timings["followed_iterates_steps"] = problem.followed_steps
    if followed and log is not None and inertia is None:
        log(f"warning: steps {followed} converged only following their own iterates, where the kept linearisation's "
            "first tries failed: on the default demo these were release steps where rods held bent by friction "
            "snap back, past which a quasi-static step has one of several equilibria (two of them 1.8 % apart "
            "in that step's per-rod forces); for the snap itself set fidelity.solve.dynamics = \"backward_euler\"")
    timings["stalled_steps_accepted"] = problem.stalled_steps
    timings["max_stalled_relative_residual"] = problem.max_stalled_residual
    if inertia is not None:
        timings["dynamic_step_halvings"] = inertia.halvings
    timings["preconditioned_directions"] = problem.inner_solves
    timings["fields"] = 0.0
    timings["per_frame_ms"] = 1e3 * timings["contact_steps"] / grid.n_frames
    vm = fields.von_mises(np.moveaxis(stress, 1, 0)).astype(np.float32)
    total = forces.sum(axis=1)
    on_rod = points.rod >= 0
    rod_force = np.zeros((S, n_rods, 3))
    np.add.at(rod_force, (slice(None), points.rod[on_rod]), forces[:, on_rod])
    episode = Episode("nonlinear", "P2P1", steps, grid.frame_step, pose_arr, target, stress, vm, sed, disp, rod_force, total, -total[:, 2],
                      reaction, iters, stick, mesh.points, mesh.tets, mesh.tet_rod, mesh.layer_fraction, timings)
    _check_finite(episode)
    return episode
