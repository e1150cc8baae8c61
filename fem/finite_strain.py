"""The ``nonlinear`` tier: the rod array as a mixed neo-Hookean solid under a moving rigid indenter,
with frictional contact inside Newton's loop.

The body is the two-field neo-Hookean solid of :mod:`fem.nonlinear` (P2P1, locking-free as
nu -> 1/2), base bottom clamped, gravity as a dead load. Contact uses the same points, load
columns W and contact law as the linear tiers (:mod:`fem.condensed`): a point's displacement is
u_c = W^T u (the hat-weighted mean over its faces), its force f(u_c) acts on the body as W f.
Because u_c is linear in u, W f is the exact virtual work of the point forces in any
configuration. Per step the residual and its consistent tangent are

    R(x) = R_int(x) - F_gravity - W f(W^T x),    A = K_T(x) - W D W^T,    D = df/du_c (3 x 3 per point),

solved by Newton with backtracking on |R| (trial states that invert an element are refused) and a
trust region on the contact points (no point moves more than ``max_step`` per iteration). A step
that fails is split in halves, recursively, as in :func:`fem.condensed.solve_path`; so is a step
that carries the indenter deeper than ``max_jump`` into the points where they were (tunnelling).

Outputs per step as the linear tiers' (:class:`fem.quasistatic.Episode`): the Cauchy stress
sigma = (mu (F F^T - I) + p I) / J at each tet's centroid, its von Mises stress, the strain energy
density W = mu/2 (I1 - 3 - 2 ln J) + p^2 / (2 lambda) (the compressible neo-Hookean energy of
:mod:`fem.materials.neo_hookean` with its volumetric part lambda/2 (ln J)^2 taken from the
pressure, p = lambda ln J: non-negative, and finite as lambda -> infinity, as the linear tiers'
complementary form), vertex displacements, contact forces and the clamp's reaction.

Cost: every Newton iteration assembles the tangent (the frictional tangent is not symmetric). Its
direction comes from GMRES preconditioned by :class:`ContactWoodbury`: the body's tangent, factorised
(symmetric, MKL PARDISO, else SuperLU) and kept while GMRES follows, with the contact points' tangent
applied exactly through Woodbury's identity on the touching points. The body tangent is factorised
anew only when GMRES misses (``tangent_factorisations`` and ``preconditioned_directions``, the GMRES
iterations, in the timings). Default sensor, first pressing step (98.7k free DOFs, 266 touching
points): 554 s with the whole tangent factorised on most iterations (45 in 50), 176 s with one
factorisation. This is the reference tier, not the fast one.
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

__all__ = ["run_nonlinear_episode", "centroid_fields"]

# Newton directions by GMRES on the tangent, preconditioned by an earlier factorised body tangent with
# the current contact tangent taken exactly (ContactWoodbury): to this true relative residual (an inexact
# Newton step with forcing term 1e-3: the outer iteration keeps converging, its own tolerance is checked
# on the true residual) in at most this many iterations per restart (two restarts), else the body tangent
# is factorised anew. Default sensor, first pressing step: 1 factorisation in 50 Newton iterations and
# 4.5 GMRES iterations per direction; with forcing term 1e-4 SciPy's GMRES, which stops on the
# preconditioned residual, missed by a factor 1-7 and caused 15 factorisations.
INNER_RTOL = 1e-3
INNER_ITERATIONS = 30


def centroid_fields(d, x: np.ndarray, lam: np.ndarray, mu: np.ndarray):
    """Cauchy stress (6, T) Pa (Voigt: xx, yy, zz, yz, xz, xy) and strain energy density (T,) J/m^3
    at each tet's centroid of the P2P1 state x = [u; p / scale]."""
    mesh = d.u.mesh
    centroid = (np.full((3, 1), 0.25), np.array([1.0 / 6.0]))
    basis = skfem.Basis(mesh, ElementVector(ElementTetP2()), quadrature=centroid)
    G = basis.interpolate(x[: d.n_u]).grad[:, :, :, 0]  # (3, 3, T)
    F = np.moveaxis(G, 2, 0) + np.eye(3)  # (T, 3, 3)
    J = np.linalg.det(F)
    if not np.all(J > 0):
        raise SolverError(f"the nonlinear state inverts {int(np.sum(~(J > 0)))} element(s) (det F <= 0)")
    pb = skfem.Basis(mesh, ElementTetP1(), quadrature=centroid)
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
                 max_penetration_m, rtol=1e-8, max_iterations=40):
        self.body, self.d = body, body.d
        self.points, self.W = points, points.W.tocsr()
        self.WT = self.W.T.tocsr()
        self.shape, self.friction, self.k_n, self.k_t = shape, friction, k_n, k_t
        self.smooth_m, self.max_step_m, self.max_jump_m, self.max_penetration_m = smooth_m, max_step_m, max_jump_m, max_penetration_m
        self.rtol, self.max_iterations = rtol, max_iterations
        self.free = body.free
        self.f_ext = body.f_gravity
        self.iterations = 0
        self._woodbury = ContactWoodbury(self.W[self.free])
        m = points.m
        blocks = np.arange(3 * m).reshape(m, 3)
        self._rows = np.repeat(blocks, 3, axis=1).ravel()
        self._cols = np.tile(blocks, (1, 3)).ravel()

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
        r_int, K = residual_and_tangent(self.d, x, self.body.lam, self.body.mu, with_tangent)
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
        scale = max(float(np.linalg.norm(self.f_ext[free])), float(np.linalg.norm((self.W @ law.f.ravel())[free])), 1e-12)
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

    def path(self, x0, pose, pose_old, state, case, depth=8):
        """:meth:`newton` from ``pose_old`` to ``pose``, halving the move on failure or tunnelling
        (:func:`fem.continuation.solve_with_halving`)."""
        from fem.continuation import solve_with_halving

        def step(p_old, p, start, whole):
            x_start, st = start
            x, law, _ = self.newton(x_start, p, p_old, st, case)
            return x, law

        def jumps(p, start):
            return -float(indenter_gap(self.shape, p, self.points.X + start[1].u).min()) > self.max_jump_m

        def too_deep(result):
            law = result[1]
            deep = float(np.max(law.fn / self.k_n)) if law.fn.size else 0.0
            return None if deep <= self.max_penetration_m else f"{case}: penetration {deep * 1e6:.1f} um"

        def next_start(result):
            x1, law1 = result
            return x1, condensed.PointState(self.point_u(x1), law1.f_t.copy())

        return solve_with_halving(step, pose_old, pose, (x0, state), depth, jumps=jumps, too_deep=too_deep, deep_at_the_end="return",
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


def run_nonlinear_episode(scene, mesh, settings=None, progress: bool = False):
    """Solve the scene's load on ``mesh`` with the ``nonlinear`` tier; returns a
    :class:`fem.quasistatic.Episode` (tier ``"nonlinear"``, element ``"P2P1"``)."""
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
    problem = _Problem(body, points, shape, load.friction_coefficient, k_n, k_t, **setup.solve_kw())
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
    # gravity alone first (the state before the indenter arrives), as a dead load in 4 increments
    x = np.zeros(body.n_dofs)
    state = trajectory.initial_state(load, tip_z)
    pose_old = Pose(tuple(state.position_m), state.yaw_rad)
    pstate = condensed.PointState(np.zeros((m, 3)), np.zeros((m, 3)))
    if settings.gravity:
        f_full = problem.f_ext
        for k in (0.25, 0.5, 0.75, 1.0):
            problem.f_ext = k * f_full
            x, law, _ = problem.newton(x, pose_old, pose_old, pstate, "gravity")
        pstate = condensed.PointState(problem.point_u(x), np.zeros((m, 3)))
    bar = _bar(progress, S, "solve (nonlinear)")
    normal_now = 0.0
    x_last, last_move = None, None
    t_loop = time.perf_counter()
    for s, t in enumerate(steps):
        state = trajectory.advance(load, state, t, normal_now)
        case = f"step {s} (t = {t * 1e3:.1f} ms)"
        before = problem.iterations
        if state.force_target_n is None:
            pose = Pose(tuple(state.position_m), state.yaw_rad)
            move = np.array([*pose.position_m, pose.yaw_rad]) - np.array([*pose_old.position_m, pose_old.yaw_rad])
            guess = x
            if x_last is not None and np.allclose(move, last_move, rtol=1e-9, atol=1e-15) and np.any(move != 0):
                guess = 2.0 * x - x_last  # the same motion as the last step: extrapolate the state
            x_before = x
            x, law = problem.path(guess, pose, pose_old, pstate, case)
            x_last, last_move = x_before, move
        else:
            z_free = tip_z + 1e-4 + float(np.abs(pstate.u[:, 2]).max())

            def at_z(z, x_start=x):
                p = Pose((state.position_m[0], state.position_m[1], z), state.yaw_rad)
                xz, lz = problem.path(x_start, p, pose_old, pstate, case)
                return condensed.normal_force(lz), (xz, lz, p)

            z, (x, law, pose), _ = condensed.solve_points_at_force(state.force_target_n, state.position_m[2], at_z, z_free, case=case)
            x_last = None
            state = trajectory.IndenterState(state.t_s, (state.position_m[0], state.position_m[1], z), state.yaw_rad, state.force_target_n, state.ramp_from_n)
            target[s] = state.force_target_n
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
        # the clamp's force on the body: minus the body's unbalanced force at the fixed DOFs
        unbalanced = (r_int - problem.f_ext - points.W @ law.f.ravel())[body.fixed]
        reaction[s] = [unbalanced[comp_fixed == c].sum() for c in range(3)]
        bar(s + 1)
    timings["contact_steps"] = time.perf_counter() - t_loop
    timings["tangent_factorisations"] = problem.factorisations
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
