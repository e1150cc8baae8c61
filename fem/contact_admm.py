"""Frictional contact on the Delassus operator by ADMM, with bounded work per step [Carpentier2024]_.

The linear tiers condense the body onto m contact points (:mod:`fem.condensed`): with f (m, 3) the
forces on the body at the points (sensor frame), the points move by u = u_0 + E f, E the elastic
compliance (``linear``: C = W^T K^-1 W; ``reduced``: the patch compliance, every point moving with
its patch). The contact law is the penalty / Coulomb law of :mod:`fem.condensed` without its
smoothing: normal force f_n = k <-g>_+, tangential force by the return map with the same stiffness
k (k_t = k_n: one isotropic penalty per point). With the indenter's gap linearised at positions u*,
g(u) = g* + n . (u - u*), define each point's "velocity"

    sigma = g* n + n n^T (u - u*) + P (u - u_prev - d) + (f - P f_old) / k,     P = I - n n^T,

(d: the indenter's material motion at the point over the step, f_old the tangential force after the
last step). Its normal part is the penalty-regularised gap, its tangential part the plastic slip of
the return map. Penalty and return map together are then exactly the Coulomb friction problem

    f in K_mu,   sigma + Gamma(sigma) in K_mu^*,   f . (sigma + Gamma(sigma)) = 0,
    K_mu = {|f_T| <= mu f_n},  Gamma(sigma) = mu |sigma_T| n   (De Saxce's correction)

with sigma = G f + b affine in f and the Delassus operator G = E + diag(1/k) (x) I_3 symmetric
positive definite and independent of the contact frames. ADMM [Carpentier2024]_ (Alg. 1) splits the
cone from the quadratic,

    x <- (G + rho I)^-1 (rho y - z - b - s),   y <- Proj_K(x + z / rho),   z <- z + rho (x - y),
    s <- Gamma(sigma(x)),   sigma(x) = rho (y_old - x) - z_old - s_old   (no extra product with G),

so one factorisation of G + rho I serves every iteration, every re-linearisation and every step of
an episode (frames change b and the cones, never G). rho starts at sqrt(lambda_min lambda_max) of G
and adapts by the residual-balancing rule on a ladder of powers of 10^(1/4) (each rung factorised once
and kept; the dense operator is diagonalised once instead, so its rungs cost nothing). Warm starts
from the last step make a hold step converge in its first iteration. The iterations run compiled
(:mod:`fem.admm_kernels`); on the dense operator, whose iterations cost two products with a (3 m)^2
matrix, Anderson acceleration of the ADMM map [Zhang2020]_ takes 40 % fewer.

The work per step is bounded by design: at most ``max_iterations`` ADMM iterations per linearisation
and ``max_linearisations`` re-linearisations (the gap of a curved indenter moves with the points);
when a bound is hit the step's residual is returned, never hidden (:class:`AdmmInfo`).

References
----------
.. [Carpentier2024] J. Carpentier, Q. Le Lidec, L. Montaut, "From compliant to rigid contact
   simulation: a unified and efficient approach", Robotics: Science and Systems (2024).
.. [Zhang2020] J. Zhang, B. O'Donoghue, S. Boyd, "Globally convergent type-I Anderson acceleration
   for nonsmooth fixed-point iterations", SIAM J. Optim. 30 (2020) 3170-3197.
.. [DeSaxce1998] G. De Saxce, Z.-Q. Feng, "The bipotential method: a constructive approach to design
   the complete contact law with friction and improved numerical algorithms", Mathematical and
   Computer Modelling 28 (1998) 225-245.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from fem import admm_kernels

__all__ = ["DenseDelassus", "GroupedDelassus", "AdmmInfo", "project_cone", "de_saxce", "admm_contact"]

# the adaptive rho moves on this ladder, each rung factorised once. A half decade visited 7 rungs rather
# than 13 on the default demo's linear tier for the same iterations, but left force-controlled steps
# (rtol 1e-7) at their bound on the screw scene, whose grip hold then glowed: a quarter decade it is
RHO_RUNG = 10.0 ** 0.25
# a rho rung that is not factorised yet is taken only when the residual balancing asks for it twice
# in a row (a grouped operator's new rung costs a 3 M x 3 M solve, 3 ms on the demo; a dense one's
# is free, its operator diagonalised once)
NEW_RUNG_AFTER = 2
# Anderson acceleration (fem.admm_kernels.run_anderson) for the dense operator: on the default demo
# its 5 last differences cut the linear tier's iterations from 2447 to 1407 (max per step 351 -> 200).
# The grouped operator's iterations are so cheap (19 us) that the acceleration's own work cost more
# than the 36 % of iterations it saved, so it iterates plain.
DENSE_ANDERSON_MEMORY = 5
ANDERSON_MAX_REJECTIONS = 10  # per solve; then plain iterations
MAX_LINEARISATIONS = 6  # re-linearisations of the gap per step (solve_step)
# with second-order rod kinematics the loop is also the fixed point of q(f): more rounds allowed
SECOND_ORDER_LINEARISATIONS = 12
# ... and stops when q's last change moved at most this fraction of the total normal force (per rod):
# the kinematics' own error against the nonlinear tier is about 10 %
SECOND_ORDER_RTOL = 1e-2


_EMPTY_2D, _EMPTY_INT = np.zeros((0, 0)), np.zeros(0, dtype=np.int64)


class _Delassus:
    """G = E + diag(1/k) (x) I_3 on point forces (m, 3): E f the elastic displacement of the points."""

    inv_k: np.ndarray  # (m,) m/N
    anderson_memory = 0  # Anderson acceleration of the ADMM map (fem.admm_kernels.run_anderson): 0 = off

    def __init__(self):
        self._factors: dict[int, object] = {}
        self.factorisations = 0
        admm_kernels.warm_up()  # compile (or load) the kernels here, in the precompute, not in the first step
        self.rho0 = math.sqrt(self.lambda_min() * self.lambda_max())

    @property
    def m(self) -> int:
        return len(self.inv_k)

    def elastic(self, f: np.ndarray) -> np.ndarray:  # pragma: no cover - abstract
        raise NotImplementedError

    def group_sum(self, f: np.ndarray) -> np.ndarray:
        """Point forces (m, 3) summed onto the operator's unknowns: the points themselves here."""
        return f

    def elastic_unknowns(self, f: np.ndarray) -> np.ndarray:
        """The unknowns' elastic displacement (E f, before lifting to the points)."""
        return self.elastic(f)

    def apply(self, f: np.ndarray) -> np.ndarray:
        """G f (m, 3) m."""
        return self.elastic(f) + f * self.inv_k[:, None]

    def lambda_min(self) -> float:
        # E is positive semi-definite: G's smallest eigenvalue is at least min 1/k (and close to it
        # where E is rank deficient, as for patches)
        return float(self.inv_k.min())

    def lambda_max(self, iterations: int = 30) -> float:
        """Largest eigenvalue of G by power iteration from a seeded start (an estimate from below;
        1.05 x it is returned)."""
        v = np.random.default_rng(0).standard_normal((self.m, 3))
        lam = 0.0
        for _ in range(iterations):
            v /= np.linalg.norm(v)
            w = self.apply(v)
            lam = float(np.vdot(v, w))
            v = w
        return 1.05 * lam

    def rho(self, rung: int) -> float:
        return self.rho0 * RHO_RUNG**rung

    def solve(self, r: np.ndarray, rung: int) -> np.ndarray:
        """(G + rho I)^-1 r for rho = :meth:`rho` (rung); r (m, 3)."""
        return self._solve(self._factor(rung), r, self.rho(rung))

    def factorised(self, rung: int) -> bool:
        return rung in self._factors

    def _factor(self, rung: int):
        if rung not in self._factors:
            self._factors[rung] = self._factorise(self.rho(rung))
            self.factorisations += 1
        return self._factors[rung]

    def kernel_operator(self, rung: int) -> tuple:
        """The factor of rung in the form :func:`fem.admm_kernels.run` takes:
        (mode, inverse, K, d_inv, groups, n_groups)."""
        raise NotImplementedError  # pragma: no cover - abstract


class DenseDelassus(_Delassus):
    """G = C + diag(1/k) with a dense point compliance C (3 m, 3 m) m/N (point-major) and penalties k (m,) N/m."""

    anderson_memory = DENSE_ANDERSON_MEMORY

    def __init__(self, C: np.ndarray, k: np.ndarray):
        self.C = np.ascontiguousarray(C)
        self.inv_k = 1.0 / np.asarray(k, dtype=float)
        # G = Q diag(lambda) Q^T once: every rho is then (G + rho I)^-1 = Q diag(1 / (lambda + rho)) Q^T,
        # two products per iteration (0.30 ms at 3 m = 1095) and no factorisation per rung. An explicit
        # inverse per rung takes one product (0.15 ms) but 55 ms to build: the default demo's linear tier
        # visits 13 rungs in about 1300 iterations (eigh: 0.2 s, once, in the precompute)
        G = self.C.copy()
        G[np.diag_indices_from(G)] += np.repeat(self.inv_k, 3)
        lam, Q = np.linalg.eigh(0.5 * (G + G.T))
        if not lam.min() > 0:
            raise np.linalg.LinAlgError(f"the Delassus operator is not positive definite (smallest eigenvalue {lam.min():.3g})")
        self.eigenvalues, self.Q = lam, np.ascontiguousarray(Q)
        super().__init__()

    def lambda_max(self, iterations: int = 30) -> float:
        return float(self.eigenvalues.max())

    def elastic(self, f):
        return (self.C @ f.ravel()).reshape(-1, 3)

    def _factorise(self, rho):
        return 1.0 / (self.eigenvalues + rho)

    def _solve(self, factor, r, rho):
        return (self.Q @ (factor * (r.ravel() @ self.Q))).reshape(-1, 3)

    def kernel_operator(self, rung):
        return admm_kernels.EIGEN, self.Q, _EMPTY_2D, self._factor(rung), _EMPTY_INT, 0


class GroupedDelassus(_Delassus):
    """G = L C_p L^T + diag(1/k) for points that move with their groups (patches): C_p (3 M, 3 M) the
    patch compliance, ``groups`` (m,) the patch of each point (L^T sums point forces into patches, L
    lifts patch displacements to the points), k (m,) N/m.

    (G + rho I)^-1 by Woodbury's identity on the patches: with D = 1/k + rho per point and
    q = C_p L^T x, (I + C_p diag(sum_p 1/D)) q = C_p L^T (r / D) and x = (r - L q) / D: one 3 M x 3 M
    solve per rho, and per solve two passes over the points and one 3 M x 3 M product."""

    def __init__(self, C_patch: np.ndarray, groups: np.ndarray, k: np.ndarray):
        import scipy.sparse as sp

        self.Cp = np.ascontiguousarray(C_patch)
        self.groups = np.asarray(groups)
        self.n_groups = self.Cp.shape[0] // 3
        self.inv_k = 1.0 / np.asarray(k, dtype=float)
        m = len(self.groups)
        # L^T: the sum of the points' forces per group, as a sparse product (np.add.at is ten times slower)
        self._sum = sp.csr_matrix((np.ones(m), (self.groups, np.arange(m))), shape=(self.n_groups, m))
        self._groups_int = np.ascontiguousarray(self.groups, dtype=np.int64)
        super().__init__()

    def group_sum(self, f: np.ndarray) -> np.ndarray:
        return self._sum @ f

    def elastic_unknowns(self, f):
        return (self.Cp @ self.group_sum(f).ravel()).reshape(-1, 3)

    def elastic(self, f):
        return self.elastic_unknowns(f)[self.groups]

    def _factorise(self, rho):
        d_inv = 1.0 / (self.inv_k + rho)
        per_group = np.bincount(self.groups, weights=d_inv, minlength=self.n_groups)
        A = self.Cp * np.repeat(per_group, 3)[None, :]
        A[np.diag_indices_from(A)] += 1.0
        # (I + C_p diag)^-1 C_p: one small product per solve
        return np.ascontiguousarray(np.linalg.solve(A, self.Cp)), d_inv

    def _solve(self, factor, r, rho):
        K, d_inv = factor
        rd = r * d_inv[:, None]
        q = (K @ self.group_sum(rd).ravel()).reshape(-1, 3)
        return rd - q[self.groups] * d_inv[:, None]

    def kernel_operator(self, rung):
        K, d_inv = self._factor(rung)
        return admm_kernels.GROUPED, _EMPTY_2D, K, d_inv, self._groups_int, self.n_groups


def project_cone(v: np.ndarray, n: np.ndarray, mu: float) -> np.ndarray:
    """Euclidean projection of v (m, 3) onto the friction cones {|v_T| <= mu v_n} about the unit normals n (m, 3)."""
    vn = np.einsum("ij,ij->i", v, n)
    vt = v - vn[:, None] * n
    t = np.linalg.norm(vt, axis=1)
    inside = t <= mu * vn
    polar = mu * t <= -vn
    a = (vn + mu * t) / (1.0 + mu * mu)  # the normal part of the projection onto the cone's surface
    scale = np.divide(mu * a, t, out=np.zeros_like(t), where=t > 0)
    out = a[:, None] * n + scale[:, None] * vt
    out[inside] = v[inside]
    out[polar] = 0.0
    return out


def de_saxce(sigma: np.ndarray, n: np.ndarray, mu: float) -> np.ndarray:
    """De Saxce's correction Gamma(sigma) = mu |sigma_T| n (m, 3)."""
    sn = np.einsum("ij,ij->i", sigma, n)
    return (mu * np.linalg.norm(sigma - sn[:, None] * n, axis=1))[:, None] * n


@dataclass
class AdmmInfo:
    """What one contact solve cost and how well it converged."""

    iterations: int = 0  # ADMM iterations, summed over the linearisations
    linearisations: int = 0
    residual_n: float = 0.0  # final max |x - y| and |y - y_old| (N): the force error bound reached
    tolerance_n: float = 0.0
    converged: bool = True
    gap_error_m: float = 0.0  # the last linearisation's largest gap error at a loaded point
    linearised: bool = True  # False: max_linearisations were not enough for the gap's curvature
    history: list = field(default_factory=list)


def admm_contact(G: _Delassus, b: np.ndarray, n: np.ndarray, mu: float, f0: np.ndarray | None = None, z0: np.ndarray | None = None,
                 rung: int = 0, rtol: float = 1e-5, f_scale: float = 0.0, max_iterations: int = 200):
    """Solve the linearised contact problem sigma = G f + b (see the module docstring) by ADMM.

    G: the Delassus operator; b (m, 3) m; n (m, 3) unit normals; mu the friction coefficient;
    f0, z0 (m, 3) warm starts (forces N and the cone multiplier m); ``rung`` the starting rho rung.
    Stops when max |x - y| and max |y - y_old| are at most rtol x max(|f|, f_scale) (N).
    Returns (f (m, 3) in the cones, z, rung reached, iterations, residual N, tolerance N).
    """
    m = len(b)
    b = np.ascontiguousarray(b, dtype=float)
    n = np.ascontiguousarray(n, dtype=float)
    y = np.zeros((m, 3)) if f0 is None else project_cone(f0, n, mu)
    sigma = G.apply(y) + b
    s = de_saxce(sigma, n, mu)
    z = -(sigma + s) if z0 is None else np.array(z0, dtype=float)
    it = 0
    # the iterations run compiled (fem.admm_kernels), at one rho each call: the kernel returns when the
    # residual balancing (Boyd et al. 2011, sec. 3.4.1, every 5 iterations, ratio 3 rather than Boyd's
    # 10: 18 % fewer iterations on the default demo's steps) asks for another rung; z is in metres and
    # stays as it is when rho changes
    pending = 0  # consecutive requests (signed: up > 0) for a rung not factorised yet
    memory = G.anderson_memory
    rejections = np.zeros(1, dtype=np.int64)
    while True:
        operator = G.kernel_operator(rung)
        common = (*operator, G.rho(rung), b, n, float(mu), y, z, s, it, int(max_iterations), float(rtol), float(f_scale))
        if memory > 0:
            status, it, primal, dual, tol = admm_kernels.run_anderson(*common, memory, rejections, ANDERSON_MAX_REJECTIONS)
        else:
            status, it, primal, dual, tol = admm_kernels.run(*common)
        if status in (admm_kernels.CONVERGED, admm_kernels.BOUND):
            return y, z, rung, it, max(primal, dual), tol
        step = 1 if status == admm_kernels.RUNG_UP else -1
        if abs(rung + step) > admm_kernels.MAX_RUNG:
            continue
        # count consecutive requests in one direction (a request the other way starts again)
        pending = (pending + step if pending * step >= 0 else step) if not G.factorised(rung + step) else step * NEW_RUNG_AFTER
        if abs(pending) >= NEW_RUNG_AFTER:
            rung, pending = rung + step, 0


@dataclass
class StepLaw:
    """The contact state after a step, in the form :mod:`fem.condensed` reports it."""

    f: np.ndarray  # (m, 3) force on the body at each point, N
    fn: np.ndarray  # (m,) normal force, N
    f_t: np.ndarray  # (m, 3) tangential force, N
    touching: np.ndarray  # (m,) bool
    stick: np.ndarray  # (m,) bool
    f_unknowns: np.ndarray  # forces summed per unknown (per group when grouped)
    f_extra: np.ndarray | None = None  # (m, 3) N second-order rod kinematics: the P-delta load on the points (not a contact force)


@dataclass
class WarmStart:
    """The last solve's forces, cone multipliers and rho rung (a step starts from them).

    ``kinematics``: a :class:`fem.rod_kinematics.RodKinematics` for second-order rod kinematics (None:
    first order). The steps then remember, per converged point state, the part of the points'
    displacement that is not u_0 + E f (the rotation term q and the P-delta load's displacement),
    keyed by the state's u: a step from that state (the next step, a half step, a force-control
    trial) starts from where the points really were."""

    f: np.ndarray | None = None
    z: np.ndarray | None = None
    rung: int = 0
    kinematics: object | None = None
    hidden: dict = field(default_factory=dict)

    HIDDEN_KEPT = 64  # states remembered (force control tries a few heights per step, halves nest 8 deep)

    def hidden_at(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """(h, P-delta load) remembered for the point state u, or None."""
        return self.hidden.get(_state_key(u))

    def remember(self, u: np.ndarray, hidden: np.ndarray, load: np.ndarray) -> None:
        self.hidden[_state_key(u)] = (hidden, load)
        while len(self.hidden) > self.HIDDEN_KEPT:
            self.hidden.pop(next(iter(self.hidden)))


def _state_key(u: np.ndarray) -> bytes:
    import hashlib

    return hashlib.blake2b(np.ascontiguousarray(u, dtype=float).tobytes(), digest_size=16).digest()



def solve_step(G: _Delassus, u0_points: np.ndarray, X: np.ndarray, shape, pose, pose_old, state, friction: float, k: np.ndarray,
               warm: WarmStart, guess_points: np.ndarray | None = None, rtol: float = 1e-5, max_iterations: int = 200,
               max_linearisations: int = MAX_LINEARISATIONS, f_floor_n: float = 1e-6):
    """One quasi-static contact step from ``pose_old`` (where the points were at ``state.u``, with
    tangential forces ``state.f_t``) to ``pose``.

    G: the Delassus operator of the points; u0_points (m, 3) the points' displacements without
    contact forces; X (m, 3) their reference positions; k (m,) penalties N/m. The gap is linearised
    at the points' positions, first at ``guess_points`` (else ``state.u`` moved with the indenter), then at each solution,
    until the linearisation's gap error at loaded points costs less than rtol of the largest force
    (at most ``max_linearisations``; a flat face needs one): the force the last linearisation
    misplaces, k |g - g_lin| summed over the loaded points, is at most 10 rtol of the total normal
    force. ``warm`` is read and updated.

    With ``warm.kinematics`` (:mod:`fem.rod_kinematics`) the points sit at X + u + h, u = u_0 + E f and
    h = q(f) + E f_pd (the rods' second-order rotation terms and the P-delta load's displacement): h
    is frozen over each linearisation and re-evaluated at its solution, mixed by Anderson's rule of
    depth 1, and the loop also runs until h's last change moved at most SECOND_ORDER_RTOL of the
    total normal force (summed per rod; at most SECOND_ORDER_LINEARISATIONS rounds). The returned u is u_0 + E f (the state's
    u); h and f_pd are kept in ``warm`` per state and f_pd is returned in :class:`StepLaw`.

    Returns (u_points (m, 3), :class:`StepLaw`, :class:`AdmmInfo`).
    """
    from fem.indenters import gap as indenter_gap
    from fem.indenters import gap_normal_hessian, rigid_motion

    kin = warm.kinematics
    if kin is None:
        u_prev = state.u
    else:
        # second-order rod kinematics (fem.rod_kinematics): the points sit at X + u + h, h = q(f) + E f_pd
        # the part of their displacement that is not u_0 + E f; h is frozen over a linearisation and
        # re-evaluated at each solution (the re-linearisation loop is its fixed point)
        seen = warm.hidden_at(state.u)
        h_prev = _hidden(kin, G, np.zeros_like(X))[0] if seen is None else seen[0]
        u_prev = state.u + h_prev
        f_est = warm.f if warm.f is not None and warm.f.shape == X.shape else np.zeros_like(X)
        hidden, load = _hidden(kin, G, f_est)
        f_last = warm.f if warm.f is not None and warm.f.shape == X.shape else None
        mix = None
    drag = rigid_motion(pose_old, pose, X + u_prev)
    # first linearisation point: the guess, else every point carried along by the indenter (exact for
    # a sticking point, and for a flat face whatever the point does)
    if guess_points is None:
        u_star = u_prev + drag
    else:
        u_star = guess_points if kin is None else guess_points + h_prev
    f, z, rung = warm.f, warm.z, warm.rung
    info = AdmmInfo()
    u = u_star
    for lin in range(max_linearisations if kin is None else max(max_linearisations, SECOND_ORDER_LINEARISATIONS)):
        gap, n, _ = gap_normal_hessian(shape, pose, X + u_star)
        P_old_t = state.f_t - np.einsum("ij,ij->i", state.f_t, n)[:, None] * n  # the last tangential force in today's plane
        moved = u_prev + drag
        c = n * (gap - np.einsum("ij,ij->i", n, u_star))[:, None] - (moved - np.einsum("ij,ij->i", moved, n)[:, None] * n) - P_old_t * G.inv_k[:, None]
        b = (u0_points if kin is None else u0_points + hidden) + c
        info.linearisations += 1
        if np.all(np.einsum("ij,ij->i", b, n) >= 0.0):
            f = np.zeros_like(b)  # no point reaches the indenter unloaded: f = 0 solves the problem exactly
            z = None
            it, res, tol = 0, 0.0, 0.0
        else:
            f, z, rung, it, res, tol = admm_contact(G, b, n, friction, f, z, rung, rtol=rtol, f_scale=f_floor_n, max_iterations=max_iterations)
        if kin is not None:
            f_lin, f_last = (f_last if f_last is not None else np.zeros_like(f)), f
        info.iterations += it
        info.history.append((it, res))
        info.residual_n, info.tolerance_n = res, tol
        info.converged = info.converged and res <= tol
        u = u0_points + G.elastic(f)
        fn = np.einsum("ij,ij->i", f, n)
        if kin is None:
            u_full, u_next, moved_h = u, u, 0.0
        else:
            # the linearisation's error at the h it froze (the gap's curvature), and h's change through
            # the force it moves between the last two solutions, per rod (the fixed point's residual; k |dh|
            # would bound it at the penalty's stiffness, 100 x the body's at the default penalty, and
            # per point it would sit at the ADMM tolerance's noise)
            u_full = u + hidden
            moved_h = kin.resultant_change(f - f_lin)
            h_of_f, load = _hidden(kin, G, f)
            # Anderson mixing of depth 1 on the fixed point h = h(f(h)) (Walker & Ni 2011): the plain
            # iteration contracts by only about 0.4 per round on the tiny scene's slide
            r = h_of_f - hidden
            step = h_of_f
            if mix is not None:
                dr, dg = r - mix[0], h_of_f - mix[1]
                denom = float(np.vdot(dr, dr))
                if denom > 0.0:
                    step = h_of_f - (float(np.vdot(r, dr)) / denom) * dg
            mix = (r, h_of_f)
            hidden_true, hidden = h_of_f, step
            u_next = u + hidden
        g_lin = gap + np.einsum("ij,ij->i", n, u_full - u_star)
        g_new = indenter_gap(shape, pose, X + u_full)
        loaded = (fn > 0) | (g_new < 0)
        info.gap_error_m = float(np.abs(g_new - g_lin)[loaded].max()) if loaded.any() else 0.0
        u_star = u_next
        # the force the linearisation misplaces, summed over the loaded points, against the total
        # normal force: a per-rod total error bound (one point's share can be larger on a curved rim)
        misplaced = float((np.abs(g_new - g_lin) / G.inv_k)[loaded].sum()) if loaded.any() else 0.0
        if misplaced <= max(10.0 * rtol * float(np.abs(fn).sum()), f_floor_n) and moved_h <= max(SECOND_ORDER_RTOL * float(np.abs(fn).sum()), f_floor_n):
            break
    else:
        info.converged = info.linearised = False
    extra = None
    if kin is not None:
        warm.remember(u, hidden_true, load)
        extra = load
    warm.f, warm.z, warm.rung = f, z, rung
    fn = np.einsum("ij,ij->i", f, n)
    f_t = f - fn[:, None] * n
    touching = fn > 0
    stick = touching & (np.linalg.norm(f_t, axis=1) < friction * fn * (1.0 - 1e-6))
    return u, StepLaw(f, fn, f_t, touching, stick, f, extra), info


def _hidden(kin, G: _Delassus, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points' displacement beyond u_0 + E f at point forces f (m, 3): q(f) + E f_pd, and f_pd (m, 3) N."""
    q, load = kin.q_and_load(f, G.group_sum(f))
    return (q + G.elastic(load) if kin.pdelta else q), load

