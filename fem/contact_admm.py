"""Frictional contact on the Delassus operator by ADMM, with bounded work per step [Carpentier2024]_.

The linear tiers condense the body onto m contact points (:mod:`fem.condensed`): with f (m, 3) the
forces on the body at the points (sensor frame), the points move by u = u_0 + E f, E the elastic
compliance (``linear``: C = W^T K^-1 W, dense; ``reduced``: each rod's block of C, the rods coupled
through their resultants, :class:`RodBlockDelassus`). The contact law is the penalty / Coulomb law of :mod:`fem.condensed` without its
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
from fem.linsolve import one_blas_thread
from mlsim.errors import SolverError, require_finite

__all__ = ["DenseDelassus", "RodBlockDelassus", "rod_resultant_coupling", "rod_block_compliance", "AdmmInfo", "project_cone", "de_saxce",
           "admm_contact", "admm_on_touching_rods"]

# the adaptive rho moves on this ladder, each rung factorised once. A half decade visited 7 rungs rather
# than 13 on the default demo's linear tier for the same iterations, but left force-controlled steps
# (rtol 1e-7) at their bound on the screw scene, whose grip hold then glowed: a quarter decade it is
RHO_RUNG = 10.0 ** 0.25
# a rho rung that is not factorised yet is taken only when the residual balancing asks for it twice
# in a row (a rod-block operator's new rung costs the block solves of its 3 resultant columns and a
# 3 R x 3 R solve; a dense one's is free, its operator diagonalised once). "Yet" means in this
# episode (WarmStart.rungs_seen), not in the operator's cache, which outlives episodes: an episode's
# answer must not depend on what ran before it
NEW_RUNG_AFTER = 2
# Anderson acceleration (fem.admm_kernels.run_anderson) of both operators: on the default demo its 5
# last differences cut the linear tier's iterations from 2447 to 1407 (max per step 351 -> 200), the
# reduced tier's from 2634 to 1410 (383 -> 255).
DENSE_ANDERSON_MEMORY = 5
ANDERSON_MAX_REJECTIONS = 10  # per solve; then plain iterations
MAX_LINEARISATIONS = 6  # re-linearisations of the gap per step (solve_step)
# with second-order rod kinematics the loop is also the fixed point of q(f): more rounds allowed
#: under-relaxed rod rounds (fem.rod_exact's held Cosserat rods) that have not settled in their budget go on, this many times,
#: at half the relaxation for another budget (solve_step)
ROUND_RELAXATION_HALVINGS = 2
SECOND_ORDER_LINEARISATIONS = 12
# ... and stops when q's last change moved at most this fraction of the total normal force (per rod):
# the kinematics' own error against the nonlinear tier is about 10 %
SECOND_ORDER_RTOL = 1e-2
# The rod-block operator's sub-operators (admm_on_touching_rods): a rod on which fewer than this fraction of
# its points are wanted (they reach the indenter unloaded, or carried force at the warm start) takes
# part with those points alone, its principal sub-block diagonalised anew (about 0.1 ms for a tip's
# worth of points); a rod with more takes part whole (its block diagonalised once). The screw scene
# (a cylinder lying across the tips: a strip of each tip touches), reduced tier: 4377 -> 2272 ADMM
# iterations per episode, 1051 -> 351 at most per step, contact 144 -> 82 ms per episode, and a step
# that stopped at its bound before converges (peak ML von Mises 1.6 % off the converged answer before,
# 0 after). Default demo (a flat punch on whole tips): 1588 -> 1542 iterations; tiny scene: 486 -> 391
# iterations, 8.4 -> 9.9 ms (its sub-blocks' diagonalisation costs more than the iterations it saves)
WHOLE_ROD_FRACTION = 0.5
# The rod blocks' inverses are streamed once per ADMM iteration (the default demo's 11 tips: 760 KB in
# float64, more than a core's share of L2), so solves at rtol >= this use a float32 copy (its rounding,
# 6e-8 relative, is far below the tolerance): reduced tier, default demo 4.0 -> 3.5 ms per frame, its
# per-rod forces within 11 mN of float64's on converged steps (of up to 3.4 N; relative Frobenius 0.1 %).
# Tighter solves (force control, rtol 1e-7) keep float64: in float32 the screw scene's took 20 % more
# iterations
SINGLE_PRECISION_RTOL = 1e-6
SUB_OPERATORS_KEPT = 64  # restricted operators (and their rho ladders) kept per operator
SUB_BLOCKS_KEPT = 1024  # diagonalised sub-blocks kept per operator
INVERSES_KEPT = 512  # the blocks' explicit inverses, per rho, kept per operator (a tip's: 93^2 doubles)


_EMPTY_1D, _EMPTY_2D, _EMPTY_INT = np.zeros(0), np.zeros((0, 0)), np.zeros(0, dtype=np.int64)


def _kept(cache: dict, key, make, limit: int):
    """cache[key], made by make() if missing; the oldest entries beyond ``limit`` are dropped (returned
    as a list, for their counts)."""
    if key not in cache:
        cache[key] = make()
    dropped = []
    while len(cache) > limit:
        dropped.append(cache.pop(next(iter(cache))))
    return cache[key], dropped


class _Delassus:
    """G = E + diag(1/k) (x) I_3 on point forces (m, 3): E f the elastic displacement of the points."""

    inv_k: np.ndarray  # (m,) m/N
    key = b""  # a sub-operator's: its points' indices in its root (RodBlockDelassus.restrict_points)
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

    def elastic_block(self, points: np.ndarray) -> np.ndarray:
        """E among ``points`` (k,): the (3 k, 3 k) m/N compliance (point-major), the columns of E f for unit
        forces on them (3 k products with E)."""
        points = np.asarray(points, dtype=np.int64)
        out = np.empty((3 * len(points), 3 * len(points)))
        f = np.zeros((self.m, 3))
        for c in range(3 * len(points)):
            f[points[c // 3], c % 3] = 1.0
            out[:, c] = self.elastic(f)[points].ravel()
            f[points[c // 3], c % 3] = 0.0
        return out

    def apply(self, f: np.ndarray) -> np.ndarray:
        """G f (m, 3) m."""
        return self.elastic(f) + f * self.inv_k[:, None]

    def lambda_min(self) -> float:
        # E is positive semi-definite: G's smallest eigenvalue is at least min 1/k
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

    @property
    def all_factorisations(self) -> int:
        """The rho rungs factorised so far (with a rod-block operator's restrictions)."""
        return self.factorisations

    def factorised(self, rung: int) -> bool:
        return rung in self._factors

    def _factor(self, rung: int):
        if rung not in self._factors:
            self._factors[rung] = self._factorise(self.rho(rung))
            self.factorisations += 1
        return self._factors[rung]

    def kernel_operator(self, rung: int, single: bool = False) -> tuple:
        """The factor of rung in the form :func:`fem.admm_kernels.run` takes:
        (mode, inverse, K, Y, d_inv, groups, n_groups); ``single``: the rod blocks' inverses in
        float32 where the operator has them (see :data:`SINGLE_PRECISION_RTOL`)."""
        raise NotImplementedError  # pragma: no cover - abstract


class DenseDelassus(_Delassus):
    """G = C + diag(1/k) with a dense point compliance C (3 m, 3 m) m/N (point-major) and penalties k (m,) N/m."""

    anderson_memory = DENSE_ANDERSON_MEMORY

    def __init__(self, C: np.ndarray, k: np.ndarray):
        if np.size(k) == 0:
            # eigh of a 0 x 0 operator has no smallest eigenvalue (numpy's "zero-size array" error)
            raise SolverError("the contact set is empty: no point of the sensor lies near the indenter's path, so there is no "
                              "contact problem to solve; check the load (load.start_xy_mm, the press depths) or solve without contact")
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

    def elastic_block(self, points):
        cols = (3 * np.asarray(points, dtype=np.int64)[:, None] + np.arange(3)).ravel()
        return self.C[np.ix_(cols, cols)]

    def _factorise(self, rho):
        return 1.0 / (self.eigenvalues + rho)

    def _solve(self, factor, r, rho):
        return (self.Q @ (factor * (r.ravel() @ self.Q))).reshape(-1, 3)

    def kernel_operator(self, rung, single: bool = False):
        return admm_kernels.EIGEN, self.Q, _EMPTY_2D, _EMPTY_2D, self._factor(rung), _EMPTY_INT, 0


class RodBlockDelassus(_Delassus):
    """G = blockdiag_a(C_aa) + S H S^T + diag(1/k) (x) I_3: each rod's point compliance C_aa exact, the
    rods coupled through their resultants (S (3 m, 3 R) sums a rod's point forces, H (3 R, 3 R) the
    rods' mean mutual compliance, zero on its diagonal blocks; :func:`rod_resultant_coupling`).

    Contact on one rod tip is a local problem: which points of the tip touch, and how the load spreads
    over them, needs the tip's own point compliance. Other rods feel it through the base, smoothly, as
    a resultant (the default demo's flat punch: per-rod force within 0.5 % of the full point compliance,
    2.3 % with no coupling at all). The points must come rod by rod (``rod`` non-decreasing).

    (G + rho I)^-1 per rod block and Woodbury on the 3 R resultants: B_a = C_aa + diag(1/k_a) + rho I =
    Q_a diag(lambda_a + rho) Q_a^T (diagonalised once: each rho's block inverse is one product,
    formed once per block and rho), v = B^-1 r, x = v - Y K S^T v with Y = B^-1 S and
    K = (I + H S^T Y)^-1 H (3 R x 3 R, per rho)."""

    anderson_memory = DENSE_ANDERSON_MEMORY

    def __init__(self, blocks: list, H: np.ndarray, rod: np.ndarray, k: np.ndarray):
        rod = np.asarray(rod)
        if np.any(np.diff(rod) < 0):
            raise ValueError("RodBlockDelassus: the points must come rod by rod (sort them by rod)")
        _, self.rod = np.unique(rod, return_inverse=True)
        self.n_rods = int(self.rod.max()) + 1 if len(rod) else 0
        sizes = np.bincount(self.rod, minlength=self.n_rods)
        if [b.shape[0] for b in blocks] != list(3 * sizes):
            raise ValueError("RodBlockDelassus: one (3 m_a, 3 m_a) block per rod, in the points' order")
        self.blocks = [np.ascontiguousarray(b) for b in blocks]
        self.H = np.ascontiguousarray(H)
        self.inv_k = 1.0 / np.asarray(k, dtype=float)
        self._starts = np.r_[0, np.cumsum(sizes)]
        eig, Qs = [], []
        for a, B in enumerate(self.blocks):
            lo, hi = self._starts[a], self._starts[a + 1]
            B = 0.5 * (B + B.T)
            B[np.diag_indices_from(B)] += np.repeat(self.inv_k[lo:hi], 3)
            with one_blas_thread():
                lam, Q = np.linalg.eigh(B)
            if not lam.min() > 0:
                raise np.linalg.LinAlgError(f"rod block {a} of the Delassus operator is not positive definite (smallest eigenvalue {lam.min():.3g})")
            eig.append(lam)
            Qs.append(Q)
        self._set_blocks(eig, Qs)
        self._root, self.points = None, np.arange(len(self.rod))  # a sub-operator's: its root, and its points there
        self._restricted: dict[bytes, RodBlockDelassus] = {}
        self._sub_blocks: dict[tuple, tuple] = {}  # (rod, its kept points) -> (C, eigenvalues, eigenvectors)
        self._evicted_factorisations = 0
        self._block_keys = [("rod", a) for a in range(self.n_rods)]  # each block's name in _inverses
        self._inverses: dict[tuple, np.ndarray] = {}  # (block key, rho) -> the block's (B_a + rho I)^-1, shared with the sub-operators
        super().__init__()

    def _set_blocks(self, eig: list, Qs: list) -> None:
        self._C_flat = np.ascontiguousarray(np.concatenate([C.ravel() for C in self.blocks]) if self.blocks else np.zeros(0))
        self._eig, self._Q = eig, Qs
        self._rod_int = np.ascontiguousarray(self.rod, dtype=np.int64)

    def restrict(self, rods: np.ndarray) -> "RodBlockDelassus":
        """The operator on the points of ``rods`` (ascending, this operator's rod numbers) alone: its
        principal sub-operator, exact where the other points carry no force (:meth:`restrict_points`)."""
        rods = np.asarray(rods, dtype=np.int64)
        points = np.concatenate([np.arange(self._starts[a], self._starts[a + 1]) for a in rods]) if len(rods) else np.zeros(0, dtype=np.int64)
        return self.restrict_points(points)

    def restrict_points(self, points: np.ndarray) -> "RodBlockDelassus":
        """The operator on ``points`` (ascending indices of this operator's points) alone: its principal
        sub-operator, exact where the other points carry no force. A rod all of whose points are kept
        shares this operator's diagonalised block; a rod cut to some of its points has its principal
        sub-block diagonalised (kept per set of points, as are the sub-operators and their rho ladders).
        The coupling H is unchanged: the rods' resultants sum the kept points' forces.

        A sub-operator's restrictions are its root's (the operator it was cut from), so they share one
        set of caches: an operator of the whole sensor kept with the reduced model
        (:meth:`fem.quasistatic.ReducedModel.contact_operator`) serves every episode, and the rods'
        diagonalised blocks, their inverses per rho and the sub-operators an episode needs are there
        for the next episode that needs them."""
        points = np.asarray(points, dtype=np.int64)
        if self._root is not None:
            return self._root.restrict_points(self.points[points])
        key = points.tobytes()
        if key not in self._restricted:
            point_rod = self.rod[points]
            rods = np.unique(point_rod)
            sizes = np.diff(self._starts)
            blocks, eig, Qs, keys = [], [], [], []
            for a in rods:
                mine = points[point_rod == a]
                if len(mine) == sizes[a]:
                    blocks.append(self.blocks[a])
                    eig.append(self._eig[a])
                    Qs.append(self._Q[a])
                    keys.append(self._block_keys[a])
                    continue
                local = mine - self._starts[a]
                sub_key = (self._block_keys[a], local.tobytes())
                keys.append(sub_key)
                (C, lam, Q), _ = _kept(self._sub_blocks, sub_key, lambda: self._sub_block(a, local), SUB_BLOCKS_KEPT)
                blocks.append(C)
                eig.append(lam)
                Qs.append(Q)
            sub = object.__new__(RodBlockDelassus)
            sub.blocks = blocks
            sel = (3 * rods[:, None] + np.arange(3)).ravel()
            sub.H = np.ascontiguousarray(self.H[np.ix_(sel, sel)])
            sub.inv_k = self.inv_k[points]
            sub.rod = np.searchsorted(rods, point_rod)
            sub.n_rods = len(rods)
            sub._starts = np.r_[0, np.cumsum(np.bincount(sub.rod, minlength=len(rods)))]
            sub._set_blocks(eig, Qs)
            sub._restricted, sub._sub_blocks, sub._factors, sub.factorisations, sub.rho0 = {}, {}, {}, 0, self.rho0
            sub._evicted_factorisations = 0
            sub._block_keys, sub._inverses = keys, self._inverses
            sub._root, sub.points, sub.key = self, points, key
            _, dropped = _kept(self._restricted, key, lambda: sub, SUB_OPERATORS_KEPT)
            self._evicted_factorisations += sum(d.factorisations for d in dropped)
        return self._restricted[key]

    def _sub_block(self, a: int, local: np.ndarray) -> tuple:
        """Rod a's block on its points ``local`` (indices within the rod): (C (3 k, 3 k), eigenvalues
        and eigenvectors of C + diag(1/k))."""
        idx = (3 * local[:, None] + np.arange(3)).ravel()
        C = np.ascontiguousarray(self.blocks[a][np.ix_(idx, idx)])
        B = 0.5 * (C + C.T)
        B[np.diag_indices_from(B)] += np.repeat(self.inv_k[self._starts[a] + local], 3)
        with one_blas_thread():
            lam, Q = np.linalg.eigh(B)
        return C, lam, Q

    @property
    def all_factorisations(self) -> int:
        """Factorisations of this operator and of its restrictions (a sub-operator's: its root's, whose
        restrictions its own are)."""
        if self._root is not None:
            return self._root.all_factorisations
        return self.factorisations + self._evicted_factorisations + sum(sub.factorisations for sub in self._restricted.values())

    def rod_sum(self, f: np.ndarray) -> np.ndarray:
        """S^T f: the forces (m, 3) summed per rod (R, 3)."""
        return np.stack([np.bincount(self.rod, weights=f[:, c], minlength=self.n_rods) for c in range(3)], axis=1)

    def elastic(self, f):
        return admm_kernels.rod_block_product(self._C_flat, self.H, self._rod_int, self.n_rods, np.ascontiguousarray(f, dtype=float))

    def _factorise(self, rho):
        # per block, once per rho (shared by every sub-operator that keeps the block): its explicit
        # inverse B_a^-1 (the compiled iterations take one product per rod with it instead of two with
        # Q_a), Y_a = B_a^-1 S_a (S_a sums the block's point forces per axis) and S_a^T Y_a
        Ys, inverses = [], []
        T = np.zeros((3 * self.n_rods, 3 * self.n_rods))
        with one_blas_thread():
            for a, (key, lam, Q) in enumerate(zip(self._block_keys, self._eig, self._Q)):
                (B_flat, Y_a, T_a), _ = _kept(self._inverses, (key, rho), lambda: _block_inverse(lam, Q, rho), INVERSES_KEPT)
                inverses.append(B_flat)
                Ys.append(Y_a)
                T[3 * a : 3 * a + 3, 3 * a : 3 * a + 3] = T_a
            K = np.linalg.solve(np.eye(3 * self.n_rods) + self.H @ T, self.H)
        Y = np.concatenate(Ys) if Ys else np.zeros((0, 3))
        inverse_flat = np.concatenate(inverses)[None, :] if inverses else np.zeros((1, 0))
        return np.ascontiguousarray(K), np.ascontiguousarray(Y), inverse_flat, inverse_flat.astype(np.float32)

    def _solve(self, factor, r, rho):
        K, Y, inverse_flat, _ = factor
        return admm_kernels.solve(admm_kernels.ROD_BLOCKS, inverse_flat, K, Y, _EMPTY_1D, self._rod_int, self.n_rods, np.ascontiguousarray(r, dtype=float))

    def kernel_operator(self, rung, single: bool = False):
        K, Y, inverse_flat, inverse_single = self._factor(rung)
        return admm_kernels.ROD_BLOCKS, inverse_single if single else inverse_flat, K, Y, _EMPTY_1D, self._rod_int, self.n_rods


def _block_inverse(lam: np.ndarray, Q: np.ndarray, rho: float) -> tuple:
    """A rod block's pieces at rho from its eigendecomposition B = Q diag(lam) Q^T: (B + rho I)^-1
    raveled, Y_a = (B + rho I)^-1 S_a (3 k, 3) with S_a summing the block's point forces per axis,
    and S_a^T Y_a (3, 3)."""
    B_inv = (Q / (lam + rho)) @ Q.T
    Y_a = np.stack([B_inv[:, c::3].sum(axis=1) for c in range(3)], axis=1)
    return B_inv.ravel(), Y_a, np.stack([Y_a[c::3].sum(axis=0) for c in range(3)])


def rod_block_compliance(blocks: list, H: np.ndarray, rod: np.ndarray) -> np.ndarray:
    """The elastic part of :class:`RodBlockDelassus`, blockdiag(C_aa) + S H S^T, as one (3 m, 3 m)
    matrix (for the Newton contact solver); ``rod`` (m,) non-decreasing."""
    _, idx = np.unique(rod, return_inverse=True)
    m = len(idx)
    S = np.zeros((3 * m, H.shape[0]))
    S[np.arange(3 * m), 3 * np.repeat(idx, 3) + np.tile(np.arange(3), m)] = 1.0
    E = S @ H @ S.T
    lo = 0
    for C in blocks:
        E[lo : lo + len(C), lo : lo + len(C)] += C
        lo += len(C)
    return E


def rod_resultant_coupling(C: np.ndarray, rod: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """H (3 R, 3 R) m/N: the mean mutual compliance of rods, H_ab = sum_ij w_i w_j C_ij (3 x 3 blocks,
    i on rod a, j on rod b, w the points' areas normalised per rod), zero for a = b. C (3 n, 3 n) a
    compliance of n points (or patches) with rods ``rod`` (n,) and areas ``weight`` (n,): a force
    spread over rod b in proportion to area moves rod a's points by H_ab on average."""
    rods, idx = np.unique(rod, return_inverse=True)
    R = len(rods)
    w = weight / np.bincount(idx, weights=weight)[idx]
    A = np.zeros((3 * R, 3 * len(rod)))  # the area-weighted mean per rod and axis
    A[3 * np.repeat(idx, 3) + np.tile(np.arange(3), len(rod)), np.arange(3 * len(rod))] = np.repeat(w, 3)
    H = A @ C @ A.T
    for a in range(R):
        H[3 * a : 3 * a + 3, 3 * a : 3 * a + 3] = 0.0
    return 0.5 * (H + H.T)


def project_cone(v: np.ndarray, n: np.ndarray, mu: float) -> np.ndarray:
    """Euclidean projection of v (m, 3) onto the friction cones {|v_T| <= mu v_n} about the unit normals n (m, 3)
    (compiled: :func:`fem.admm_kernels.project_cones`, the iterations' own projection)."""
    return admm_kernels.project_cones(np.ascontiguousarray(v, dtype=float), np.ascontiguousarray(n, dtype=float), float(mu))


def de_saxce(sigma: np.ndarray, n: np.ndarray, mu: float) -> np.ndarray:
    """De Saxce's correction Gamma(sigma) = mu |sigma_T| n (m, 3) (compiled: :func:`fem.admm_kernels.de_saxce`)."""
    return admm_kernels.de_saxce(np.ascontiguousarray(sigma, dtype=float), np.ascontiguousarray(n, dtype=float), float(mu))


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
    round_residual_n: float = 0.0  # rod kinematics: the rounds' fixed-point residual at the last one (N, summed per rod)
    history: list = field(default_factory=list)


def admm_contact(G: _Delassus, b: np.ndarray, n: np.ndarray, mu: float, f0: np.ndarray | None = None, z0: np.ndarray | None = None,
                 rung: int = 0, rtol: float = 1e-5, f_scale: float = 0.0, max_iterations: int = 200, rungs_seen: set | None = None):
    """Solve the linearised contact problem sigma = G f + b (see the module docstring) by ADMM.

    G: the Delassus operator; b (m, 3) m; n (m, 3) unit normals; mu the friction coefficient;
    f0, z0 (m, 3) warm starts (forces N and the cone multiplier m); ``rung`` the starting rho rung;
    ``rungs_seen`` the (operator key, rung) pairs an episode has used (read and updated; None: the
    rungs G has factorised).
    Stops when max |x - y| and max |y - y_old| are at most rtol x max(|f|, f_scale) (N).
    Returns (f (m, 3) in the cones, z, rung reached, iterations, residual N, tolerance N).
    """
    m = len(b)
    b = np.ascontiguousarray(b, dtype=float)
    n = np.ascontiguousarray(n, dtype=float)
    # the compiled iterations would carry a NaN into every coupled point's force and stop only at
    # the iteration bound, with a NaN residual that no convergence test catches
    require_finite(b, "the contact right-hand side b (points, 3) m (the points' gap under the body's free response)",
                   "the body's response or the indenter's pose of this step is not finite: check the load's segments and the mesh",
                   SolverError)
    require_finite(n, "the contact normals n (points, 3)", "the indenter's surface normals of this step are not finite: check its pose",
                   SolverError)
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
    seen = (lambda r: G.factorised(r)) if rungs_seen is None else (lambda r: (G.key, r) in rungs_seen)
    while True:
        if rungs_seen is not None:
            rungs_seen.add((G.key, rung))
        operator = G.kernel_operator(rung, single=rtol >= SINGLE_PRECISION_RTOL)
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
        pending = (pending + step if pending * step >= 0 else step) if not seen(rung + step) else step * NEW_RUNG_AFTER
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
    rungs_seen: set = field(default_factory=set)  # (operator key, rung) the episode has used (admm_contact)

    HIDDEN_KEPT = 64  # states remembered (force control tries a few heights per step, halves nest 8 deep)

    def starting_point(self) -> tuple:
        """(forces, cone multipliers, rho rung) the next solve starts from, for :meth:`restart_from`."""
        return self.f, self.z, self.rung

    def restart_from(self, point: tuple) -> None:
        """Start the next solve from a :meth:`starting_point` taken earlier (force control's trial heights
        each from the step's own, not from the trial before)."""
        self.f, self.z, self.rung = point

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



def admm_on_touching_rods(G: _Delassus, b: np.ndarray, n: np.ndarray, mu: float, f0=None, z0=None, rung: int = 0, max_iterations: int = 200,
                          **kw):
    """:func:`admm_contact` on the points that can touch, for a :class:`RodBlockDelassus` (any other
    operator: on all points). A point that does not reach the indenter unloaded (b_n >= 0) and carried
    no force at the warm start is left out of the problem, with zero force, unless its rod takes part
    whole: a rod on which at least WHOLE_ROD_FRACTION of the points are wanted takes part with all its points
    (its block is diagonalised once), any other rod with those points alone (:meth:`RodBlockDelassus.restrict_points`).
    The answer is then checked on the points left out, sigma_n = (G f + b)_n >= 0 at each (for a
    zero force this is the whole Coulomb condition), and a point that fails is added and the solve
    warm-started again (all within ``max_iterations``). Exact. On the default demo it leaves out
    about half of the rods near the path, and in the release steps most points of the tips that
    still touch. Same returns as :func:`admm_contact`."""
    if not isinstance(G, RodBlockDelassus):
        return admm_contact(G, b, n, mu, f0, z0, rung, max_iterations=max_iterations, **kw)
    m = len(b)
    f = np.zeros((m, 3)) if f0 is None else np.array(f0, dtype=float)
    z = None if z0 is None else np.array(z0, dtype=float)
    # the points that reach the indenter unloaded, and those loaded at the warm start: with friction the
    # contact problem can have several solutions (a bent tip's friction force can hold one edge against
    # the indenter), and keeping the warm start's loaded points keeps the solve on the branch the
    # episode is on (default demo, first release step: leaving them out released a rod that the
    # converged warm-started solve keeps at 0.66 N)
    wanted = (np.einsum("ij,ij->i", b, n) < 0.0) | np.any(f != 0.0, axis=1)
    sizes = np.diff(G._starts)
    used = 0
    while True:
        per_rod = np.bincount(G.rod[wanted], minlength=G.n_rods)
        whole = per_rod >= WHOLE_ROD_FRACTION * sizes
        taken = wanted | ((per_rod > 0) & whole)[G.rod]
        p = np.flatnonzero(taken)
        sub = G.restrict_points(p)
        f_p, z_p, rung, it, res, tol = admm_contact(sub, b[p], n[p], mu, f[p], None if z is None else z[p], rung,
                                                    max_iterations=max(max_iterations - used, 1), **kw)
        used += it
        f = np.zeros((m, 3))
        f[p] = f_p
        sigma = G.apply(f) + b
        # the left-out points' multipliers as admm_contact would start them: -(sigma + Gamma(sigma))
        z_full = -(sigma + de_saxce(sigma, n, mu))
        z_full[p] = z_p
        z = z_full
        sigma_n = np.einsum("ij,ij->i", sigma, n)
        failing = ~taken & (sigma_n < 0.0)
        if not failing.any():
            return f, z, rung, used, res, tol
        if used >= max_iterations:
            # out of iterations with left-out points inside the indenter: their missing force (the
            # penalty's, k |sigma_n|) is part of the residual, so the step is not reported converged
            return f, z, rung, used, max(res, float((-sigma_n[failing] / G.inv_k[failing]).max())), tol
        wanted = taken | failing


def solve_step(G: _Delassus, u0_points: np.ndarray, X: np.ndarray, shape, pose, pose_old, state, friction: float, k: np.ndarray,
               warm: WarmStart, guess_points: np.ndarray | None = None, rtol: float = 1e-5, max_iterations: int = 200,
               max_linearisations: int = MAX_LINEARISATIONS, f_floor_n: float = 1e-6, relaxation_halvings: int = ROUND_RELAXATION_HALVINGS):
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
    from fem.indenters import gap_normal, rigid_motion

    kin = warm.kinematics
    # the rounds' tolerance and mixing: the kinematics' own where it states them (fem.rod_exact's held rods:
    # under-relaxed, tighter), else Anderson's rule at SECOND_ORDER_RTOL
    round_rtol = getattr(kin, "round_rtol", SECOND_ORDER_RTOL)
    relaxation = getattr(kin, "round_relaxation", None)
    # under the rods' inertia, also to a fraction of the force the step moves (fem.rod_exact's ROUND_STEP_FRACTION)
    step_fraction = getattr(kin, "round_step_fraction", None)
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
    rounds = max_linearisations if kin is None else max(max_linearisations, getattr(kin, "max_rounds", SECOND_ORDER_LINEARISATIONS))
    # under-relaxed rounds that have not settled in their budget go on at half the relaxation, twice (ROUND_RELAXATION_HALVINGS):
    # the sweep's 9 x 3 mm rods pressed to 3 x their free Euler load cycled at 0.15 for 60 rounds in six steps and settled at 0.07
    # (estimated 1427 % off, its rounds' residual, then 2.2 %); a step that settles in its budget is as before
    for lin in range(rounds * (1 + relaxation_halvings) if relaxation is not None else rounds):
        gap, n = gap_normal(shape, pose, X + u_star)
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
            f, z, rung, it, res, tol = admm_on_touching_rods(G, b, n, friction, f, z, rung, rtol=rtol, f_scale=f_floor_n, max_iterations=max_iterations,
                                                             rungs_seen=warm.rungs_seen)
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
            # per point it would sit at the ADMM tolerance's noise). Under-relaxed rounds move only relaxation x
            # what the fixed point's residual would: divided by it, the test is of the residual, not of the damped
            # step (undivided, the held rods' rounds stopped early: the tiny scene's flat face pressed 1 mm, rods at 1.25 x
            # the free Euler load, 3.6 % off the nonlinear tier in tip displacement at relaxation 0.3, 8.4 % at 0.15; 1.9 % at both)
            u_full = u + hidden
            moved_h = kin.resultant_change(f - f_lin) / (relaxation or 1.0)
            h_of_f, load = _hidden(kin, G, f, _robin_hold(kin, G, fn > 0.0, hidden, load))
            # Anderson mixing of depth 1 on the fixed point h = h(f(h)) (Walker & Ni 2011): the plain
            # iteration contracts by only about 0.4 per round on the tiny scene's slide
            r = h_of_f - hidden
            if relaxation is not None:
                # under-relaxed: the held rods' rounds flip points between stick and slip, and Anderson's secant
                # over those kinks diverged on the default demo's press (0.5 cycled between two stick patterns)
                step = hidden + relaxation * r
            else:
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
        reached = 0.0
        if kin is not None:
            # the force the penalty would put on the points that carry nothing but that the rods' new state (h
            # unrelaxed) carries into the indenter: the fixed point's residual where the force does not move. Two
            # rounds at f = 0 passed the test on the force alone with the rods still inside the face (under inertia a
            # pressed rod whose contact one round let go: the next rounds, relaxed, kept it out of contact, and the
            # steps alternated between 0 and 1.7 N at 0.42 m/s)
            g_h = indenter_gap(shape, pose, X + u + hidden_true)
            free = (fn <= 0.0) & (g_h < 0.0)
            reached = float((-g_h[free] / G.inv_k[free]).sum()) if free.any() else 0.0
        floor = max(round_rtol * float(np.abs(fn).sum()), f_floor_n)
        if kin is not None and step_fraction is not None:
            # the step's move: from the last step's forces (f_est)
            floor = max(min(floor, step_fraction * kin.resultant_change(f - f_est)), kin.ROUND_RTOL_LEAST * float(np.abs(fn).sum()), f_floor_n)
        if misplaced <= max(10.0 * rtol * float(np.abs(fn).sum()), f_floor_n) and moved_h <= floor and reached <= max(floor, 10.0 * tol):
            break
        if relaxation is not None and (lin + 1) % rounds == 0:
            relaxation *= 0.5
    else:
        info.converged = info.linearised = False
    extra = None
    if kin is not None:
        info.round_residual_n = max(moved_h, reached)
        warm.remember(u, hidden_true, load)
        extra = load
    warm.f, warm.z, warm.rung = f, z, rung
    fn = np.einsum("ij,ij->i", f, n)
    f_t = f - fn[:, None] * n
    touching = fn > 0
    stick = touching & (np.linalg.norm(f_t, axis=1) < friction * fn * (1.0 - 1e-6))
    return u, StepLaw(f, fn, f_t, touching, stick, extra), info


def _hidden(kin, G: _Delassus, f: np.ndarray, hold=None) -> tuple[np.ndarray, np.ndarray]:
    """The points' displacement beyond u_0 + E f at point forces f (m, 3): q(f) + E f_pd, and f_pd (m, 3) N
    (``hold``: :func:`_robin_hold`'s, for kinematics that take it)."""
    q, load = kin.q_and_load(f) if hold is None else kin.q_and_load(f, hold=hold)
    return (q + G.elastic(load) if kin.pdelta else q), load


def _robin_hold(kin, G: _Delassus, touching: np.ndarray, hidden: np.ndarray, load: np.ndarray):
    """The Robin coupling of geometrically exact rods (``kin.holds``; :meth:`fem.rod_exact.CosseratKinematics.solve_rods`):
    (q_frozen, f_pd, K) with q_frozen = h - E f_pd the nonlinear part the round froze, f_pd its P-delta load
    (m, 3) N and K (m, 3, 3) N/m the contact's penalty at each point that touches (``touching`` (m,): a
    compressive normal force in this round's solution), isotropic. (Along the normal it is the contact's own stiffness, which holds a pressed face flat;
    across it, a slipping point's force does not follow its position, but at the rounds' fixed point the springs
    carry nothing whatever their stiffness, and holding only the sticking points let the default demo's rods
    buckle in their solves where their tips' points flipped to slip.) None for kinematics without the coupling."""
    if not getattr(kin, "holds", False):
        return None
    K = (touching / G.inv_k)[:, None, None] * np.eye(3)
    return (hidden - G.elastic(load) if kin.pdelta else hidden), load, K
