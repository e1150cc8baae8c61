"""A discrete geometrically exact (Cosserat) rod in statics: large rotations, small strains.

The rod of issue 38's fast tier, first part: a clamped straight rod of N equal segments. Each segment
e carries a material frame, the unit quaternion q_e (its rotation R_e takes the section's axes d1, d2
and the tangent d3 from the reference frame), and joins the nodes x_e and x_{e+1}. The strains are
the discrete ones of Lang, Linn and Arnold [LangLinnArnold2011]_ (the kinematics of Gazzola et al.'s
discrete Cosserat rod [Gazzola2018]_, which PyElastica integrates):

    sigma_e = R_e^T (x_{e+1} - x_e) / l - d3                shear (1, 2) and stretch (3), per segment
    kappa_i = (2 / l_i) Im(conj(q_{i-1}) q_i)               bending (1, 2) and twist (3), per joint

with the joint's Voronoi length l_i = l between segments and l / 2 at the clamp, whose frame is the
fixed q_{-1} (the clamp acts at the root, s = 0, not at the first segment's centre: a clamp that
fixes the first segment's frame instead, as PyElastica's ``OneEndFixedBC`` does, makes that segment
rigid and the rod stiff by about 1.5 / N, see benchmarks/bench_elastica_pyelastica.py). The stored
energy is linear-elastic in these strains,

    E = sum_e (l / 2) sigma_e^T S sigma_e + sum_i (l_i / 2) kappa_i^T B kappa_i - F . x_N - (tip moment),

with S = diag(kappa G A, kappa G A, E A) and B = diag(E I_1, E I_2, G J): exact for any rotation, with
the strains small (the regime of the sensor's rods: 2-4 % peak strain under rotations of tens of
degrees, issue 38). Its curvature measure 2 sin(theta / 2) / l of a joint turned by theta differs
from theta / l by theta^2 / 24, the discretisation's second-order error with the midpoint-sampled
moments.

Equilibrium is found by Newton's method on the energy with the rotations updated multiplicatively,
q_e <- q_e cay(psi_e) (the Cayley map of a rotation increment in the segment's own frame), so that
every iteration is linearised at psi = 0, where the gradient and Hessian below are exact (their
second-order terms included: the geometric stiffness that buckles the rod). A dead tip moment's
load stiffness (not symmetric) is left out of the Hessian; it is in the residual. A Hessian that is
not positive definite (a rod past its buckling load, still straight) is handled by a trust region on
the energy whose model step is solved exactly ([NocedalWright2006]_, ch. 4).

Verified in tests/test_cosserat_rod.py: exact derivatives; Timoshenko's cantilever at small load; the
elastica (Bisshopp and Drucker) to 0.07 % at 32 segments, second order; pure torsion; the buckling
load, which with shear is Haringx's (the shear measured in the section's frame,
:func:`fem.elastica.haringx_load_n`), not Engesser's; the post-buckled column (Euler's elastica) at
1.5 x its load to 0.1 %. This is the rod alone: the coupling to the base's compliance, the contact,
the stress recovery in the ML layer and inertia (issue 38) build on it; it is not a solve tier yet.

References
----------
.. [LangLinnArnold2011] H. Lang, J. Linn, M. Arnold, "Multi-body dynamics simulation of geometrically
   exact Cosserat rods", Multibody System Dynamics 25 (2011) 285-312.
.. [Gazzola2018] M. Gazzola, L. H. Dudte, A. G. McCormick, L. Mahadevan, "Forward and inverse problems
   in the mechanics of soft filaments", Royal Society Open Science 5 (2018) 171628.
.. [NocedalWright2006] J. Nocedal, S. J. Wright, "Numerical Optimization", 2nd ed., Springer (2006), ch. 4.
.. [Bergou2008] M. Bergou, M. Wardetzky, S. Robinson, B. Audoly, E. Grinspun, "Discrete elastic rods",
   ACM Transactions on Graphics 27 (2008) 63.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from threadpoolctl import threadpool_limits

from mlsim.errors import SolverError

#: the largest rotation increment (rad) of a segment in one Newton iteration
MAX_TURN_RAD = 0.5

__all__ = ["RodSection", "RodState", "straight_rod", "energy", "gradient_and_hessian", "solve_static"]


@dataclass(frozen=True)
class RodSection:
    """A uniform rod's length and section stiffnesses (SI).

    shear_n: kappa G A (N) for both shear directions; axial_n: E A (N); bending_n_m2: (E I_1, E I_2)
    (N m^2); torsion_n_m2: G J (N m^2)."""

    length_m: float
    axial_n: float
    shear_n: float
    bending_n_m2: tuple[float, float]
    torsion_n_m2: float

    def __post_init__(self):
        for name, value in (("length_m", self.length_m), ("axial_n", self.axial_n), ("shear_n", self.shear_n),
                            ("bending_n_m2[0]", self.bending_n_m2[0]), ("bending_n_m2[1]", self.bending_n_m2[1]),
                            ("torsion_n_m2", self.torsion_n_m2)):
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"RodSection.{name} = {value}: must be a finite number > 0")

    @property
    def S(self) -> np.ndarray:
        """The shear-stretch stiffness diag(kappa G A, kappa G A, E A) (N)."""
        return np.array([self.shear_n, self.shear_n, self.axial_n])

    @property
    def B(self) -> np.ndarray:
        """The bend-twist stiffness diag(E I_1, E I_2, G J) (N m^2)."""
        return np.array([self.bending_n_m2[0], self.bending_n_m2[1], self.torsion_n_m2])

    @classmethod
    def circular(cls, length_m: float, radius_m: float, young_pa: float, poisson: float) -> "RodSection":
        """A solid circular section of a linear isotropic material (Cowper's shear coefficient)."""
        from fem.beam_theory import circular_shear_coefficient

        area, inertia = np.pi * radius_m**2, 0.25 * np.pi * radius_m**4
        shear_modulus = young_pa / (2.0 * (1.0 + poisson))
        ei = young_pa * inertia
        return cls(length_m, young_pa * area, circular_shear_coefficient(poisson) * shear_modulus * area, (ei, ei), shear_modulus * 2.0 * inertia)


@dataclass
class RodState:
    """Nodes x (N + 1, 3) (m; x[0] is the clamped root) and segment frames q (N, 4) (w, x, y, z)."""

    x: np.ndarray
    q: np.ndarray


# --- quaternions (w, x, y, z), vectorised over leading axes ---------------------------------------

def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The Hamilton product a b."""
    aw, av = a[..., :1], a[..., 1:]
    bw, bv = b[..., :1], b[..., 1:]
    return np.concatenate([aw * bw - np.sum(av * bv, axis=-1, keepdims=True), aw * bv + bw * av + np.cross(av, bv)], axis=-1)


def qconj(a: np.ndarray) -> np.ndarray:
    return a * np.array([1.0, -1.0, -1.0, -1.0])


def rotation_matrix(q: np.ndarray) -> np.ndarray:
    """R (..., 3, 3) of unit quaternions q (..., 4): R v = q v conj(q)."""
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack([np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
                     np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
                     np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1)], -2)


def cayley(psi: np.ndarray) -> np.ndarray:
    """The unit quaternion (1, psi / 2) / |(1, psi / 2)|: a rotation by 2 arctan(|psi| / 2) about psi,
    equal to exp(psi) to second order (the increments' parametrisation)."""
    q = np.concatenate([np.ones(psi.shape[:-1] + (1,)), 0.5 * psi], axis=-1)
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _skew(v: np.ndarray) -> np.ndarray:
    out = np.zeros(v.shape[:-1] + (3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


def straight_rod(section: RodSection, segments: int, root_m=(0.0, 0.0, 0.0), frame=(1.0, 0.0, 0.0, 0.0)) -> RodState:
    """The unloaded rod of ``segments`` segments along the clamp frame's d3 from ``root_m``."""
    if segments < 1:
        raise ValueError(f"segments = {segments}: must be >= 1")
    q0 = np.asarray(frame, dtype=float) / np.linalg.norm(frame)
    d3 = rotation_matrix(q0)[:, 2]
    s = np.linspace(0.0, section.length_m, segments + 1)
    return RodState(np.asarray(root_m, dtype=float) + s[:, None] * d3, np.tile(q0, (segments, 1)))


# --- strains, energy, gradient and Hessian -------------------------------------------------------

def _joints(q: np.ndarray, clamp: np.ndarray) -> np.ndarray:
    """p_i = conj(q_{i-1}) q_i for the joints i = 0..N-1 (q_{-1} the clamp), on the branch p_w >= 0."""
    before = np.concatenate([clamp[None], q[:-1]], axis=0)
    p = qmul(qconj(before), q)
    return np.where(p[:, :1] < 0.0, -p, p)


def strains(state: RodState, section: RodSection, clamp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma (N, 3), kappa (N, 3)): each segment's shear-stretch and each joint's bend-twist strain."""
    n = len(state.q)
    l = section.length_m / n
    R = rotation_matrix(state.q)
    b = np.einsum("eji,ej->ei", R, np.diff(state.x, axis=0) / l)
    sigma = b - np.array([0.0, 0.0, 1.0])
    lv = np.full(n, l)
    lv[0] = 0.5 * l
    kappa = 2.0 * _joints(state.q, clamp)[:, 1:] / lv[:, None]
    return sigma, kappa


def energy(state: RodState, section: RodSection, clamp: np.ndarray, tip_force_n=(0.0, 0.0, 0.0)) -> float:
    """The rod's stored energy less the dead tip force's potential (J)."""
    n = len(state.q)
    l = section.length_m / n
    lv = np.full(n, l)
    lv[0] = 0.5 * l
    sigma, kappa = strains(state, section, clamp)
    stored = 0.5 * l * np.sum(sigma**2 * section.S) + 0.5 * np.sum(lv[:, None] * kappa**2 * section.B)
    return float(stored - np.dot(tip_force_n, state.x[-1] - state.x[0]))


def gradient_and_hessian(state: RodState, section: RodSection, clamp: np.ndarray, tip_force_n=(0.0, 0.0, 0.0),
                         tip_moment_n_m=(0.0, 0.0, 0.0), hessian: bool = True):
    """The energy's gradient g (6N,) and Hessian H (6N, 6N) in the unknowns (psi_0, x_1, psi_1, x_2, ...,
    psi_{N-1}, x_N): each segment's rotation increment (in its own frame, q_e <- q_e cay(psi_e)) and the
    node at its far end, at psi = 0. The dead tip moment (spatial, N m) enters g only."""
    n = len(state.q)
    l = section.length_m / n
    S, Bk = section.S, section.B
    R = rotation_matrix(state.q)  # (N, 3, 3)
    RT = np.swapaxes(R, 1, 2)
    b = np.einsum("eij,ej->ei", RT, np.diff(state.x, axis=0) / l)
    nmat = (b - np.array([0.0, 0.0, 1.0])) * S  # the sections' force in their frames (N)
    p = _joints(state.q, clamp)
    lv = np.full(n, l)
    lv[0] = 0.5 * l
    m = 2.0 * p[:, 1:] / lv[:, None] * Bk  # the joints' moment, in the frames of the joints (N m)
    pw, pv = p[:, 0], p[:, 1:]
    g = np.zeros((n, 6))  # block e: (psi_e, x_{e+1})
    force = np.einsum("eij,ej->ei", R, nmat)  # spatial section forces
    g[:, 3:] += force
    g[:-1, 3:] -= force[1:]  # x_{e+1} is the start of segment e + 1
    g[:, :3] += -l * np.cross(b, nmat)
    # joint i between frames i - 1 (a) and i (b): dkappa/dpsi_b = (p_w I + [p_v]x) / l_i, dkappa/dpsi_a = (-p_w I + [p_v]x) / l_i
    g[:, :3] += pw[:, None] * m - np.cross(pv, m)
    g[:-1, :3] += -pw[1:, None] * m[1:] - np.cross(pv[1:], m[1:])
    g[-1, 3:] -= np.asarray(tip_force_n, dtype=float)
    g[-1, :3] -= RT[-1] @ np.asarray(tip_moment_n_m, dtype=float)
    if not hessian:
        return g.ravel(), None
    H = np.zeros((n, 6, n, 6))
    e = np.arange(n)
    # segment e: sigma = (I - [psi]x + [psi]x^2 / 2) R^T (x_{e+1} - x_e) / l - d3
    Jx = RT / l  # dsigma/dx_{e+1}; -Jx for x_e
    Jpsi = _skew(b)
    lS = l * S
    Kxx = np.einsum("eki,k,ekj->eij", Jx, lS, Jx)
    Kpp = np.einsum("eki,k,ekj->eij", Jpsi, lS, Jpsi) + l * (0.5 * (nmat[:, :, None] * b[:, None, :] + b[:, :, None] * nmat[:, None, :])
                                                         - np.einsum("ek,ek->e", nmat, b)[:, None, None] * np.eye(3))
    Kpx = np.einsum("eki,k,ekj->eij", Jpsi, lS, Jx) + np.einsum("eij,ejk->eik", _skew(nmat), RT)  # d2E / dpsi_e dx_{e+1}
    H[e, :3, e, :3] += Kpp
    H[e, :3, e, 3:] += Kpx
    H[e, 3:, e, :3] += np.swapaxes(Kpx, 1, 2)
    H[e, 3:, e, 3:] += Kxx
    # x_e (the node before segment e, free for e >= 1) sits in block e - 1
    f = e[1:]
    H[f - 1, 3:, f - 1, 3:] += Kxx[1:]
    H[f, :3, f - 1, 3:] -= Kpx[1:]
    H[f - 1, 3:, f, :3] -= np.swapaxes(Kpx[1:], 1, 2)
    H[f, 3:, f - 1, 3:] -= Kxx[1:]
    H[f - 1, 3:, f, 3:] -= Kxx[1:]
    # joint i: first-order J_b = (p_w I + [p_v]x) / l_i, J_a = (-p_w I + [p_v]x) / l_i; second-order terms of
    # 2 m . Im(conj(cay(a)) p cay(b)): -(m . p_v) / 2 on the aa and bb diagonals, (m p_v^T + [m]x (p_w I + [p_v]x)) / 2 for ab
    eye = np.eye(3)
    P = pw[:, None, None] * eye + _skew(pv)
    Jb = P / lv[:, None, None]
    Ja = (-pw[:, None, None] * eye + _skew(pv)) / lv[:, None, None]
    diag = -0.5 * np.einsum("ik,ik->i", m, pv)[:, None, None] * eye
    ab = 0.5 * (m[:, :, None] * pv[:, None, :] + _skew(m) @ P)
    lvB = lv[:, None] * Bk
    H[e, :3, e, :3] += np.einsum("ika,ik,ikb->iab", Jb, lvB, Jb) + diag
    i = e[1:]
    H[i - 1, :3, i - 1, :3] += np.einsum("ika,ik,ikb->iab", Ja[1:], lvB[1:], Ja[1:]) + diag[1:]
    cross = np.einsum("ika,ik,ikb->iab", Ja[1:], lvB[1:], Jb[1:]) + ab[1:]
    H[i - 1, :3, i, :3] += cross
    H[i, :3, i - 1, :3] += np.swapaxes(cross, 1, 2)
    return g.ravel(), H.reshape(6 * n, 6 * n)


def _update(state: RodState, step: np.ndarray) -> RodState:
    """The state after a Newton step (psi_e, dx_{e+1}) per block: the frames turned, q_e cay(psi_e), and each
    segment's chord rebuilt from its strain as the step changes it to first order, in the turned frame,
    x_{e+1} - x_e = l R_e' (b_e + db_e), b_e = R_e^T (x_{e+1} - x_e) / l, db_e = R_e^T (dx_{e+1} - dx_e) / l
    + b_e x psi_e. To first order this is the additive step (Newton's convergence is kept); for a large
    turn the nodes follow the frames along the arc instead of the tangent, which would stretch the rod by
    turn^2 / 2 and make a stiff axial spring cut every step short."""
    blocks = step.reshape(-1, 6)
    psi, dx = blocks[:, :3], np.vstack([np.zeros(3), blocks[:, 3:]])
    R = rotation_matrix(state.q)
    chords = np.diff(state.x, axis=0)
    b = np.einsum("eji,ej->ei", R, chords)
    db = np.einsum("eji,ej->ei", R, np.diff(dx, axis=0)) + np.cross(b, psi)
    q = qmul(state.q, cayley(psi))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    new_chords = np.einsum("eij,ej->ei", rotation_matrix(q), b + db)
    x = np.vstack([state.x[:1], state.x[:1] + np.cumsum(new_chords, axis=0)])
    return RodState(x, q)


def solve_static(section: RodSection, segments: int, tip_force_n=(0.0, 0.0, 0.0), tip_moment_n_m=(0.0, 0.0, 0.0),
                 clamp=(1.0, 0.0, 0.0, 0.0), root_m=(0.0, 0.0, 0.0), start: RodState | None = None, increments: int = 1,
                 rtol: float = 1e-10, max_iterations: int = 60) -> RodState:
    """The rod's equilibrium under a dead tip force (N) and tip moment (N m), both spatial, applied in
    ``increments`` equal load steps from ``start`` (default: the straight rod along the clamp frame's d3
    from ``root_m``). Converged when the nodes' forces are balanced to ``rtol`` of the load scale and the
    frames' moments to that times a segment's length (or to the stiffnesses' round-off, 100 eps E A).
    Raises :class:`mlsim.errors.SolverError` if Newton does not converge."""
    clamp = np.asarray(clamp, dtype=float) / np.linalg.norm(clamp)
    state = start if start is not None else straight_rod(section, segments, root_m, clamp)
    F, M = np.asarray(tip_force_n, dtype=float), np.asarray(tip_moment_n_m, dtype=float)
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(M))):
        raise ValueError(f"tip_force_n = {F.tolist()}, tip_moment_n_m = {M.tolist()}: must be finite")
    eps = np.finfo(float).eps
    load = max(float(np.linalg.norm(F)), float(np.linalg.norm(M)) / section.length_m, section.B.max() / section.length_m**2)
    force_tol = max(rtol * load, 100.0 * eps * section.S.max())
    l = section.length_m / len(state.q)
    tolerances = (force_tol, max(force_tol * l, 100.0 * eps * section.B.max() / l))
    # the matrices are small (6 N): BLAS threads only fight each other (60x slower on a loaded 2-core machine)
    with threadpool_limits(1, user_api="blas"):
        for k in range(1, increments + 1):
            state = _newton(state, section, clamp, F * k / increments, M * k / increments, tolerances, max_iterations,
                            f"load step {k}/{increments}")
    return state


def _imbalance(g: np.ndarray, tolerances: tuple[float, float]) -> float:
    """The larger of the nodes' unbalanced force and the frames' unbalanced moment, each over its tolerance."""
    blocks = g.reshape(-1, 6)
    return max(float(np.linalg.norm(blocks[:, 3:])) / tolerances[0], float(np.linalg.norm(blocks[:, :3])) / tolerances[1])


def _newton(state: RodState, section: RodSection, clamp: np.ndarray, F: np.ndarray, M: np.ndarray, tolerances, max_iterations: int,
            where: str) -> RodState:
    """Newton's method from ``state`` under (F, M). Under a dead force alone (conservative): a trust region
    on the energy, its model step solved exactly over the Hessian's eigenvalues ([NocedalWright2006]_
    Algorithm 4.3), which follows a column past its buckling load off the straight state (a saddle) to
    the bent one. With a dead moment (not conservative: no energy to judge a step by, and its load
    stiffness left out of H): Newton's step with a backtracking line search on the imbalance."""
    l = section.length_m / len(state.q)
    # the trust region's norm: turns in rad, node moves in segment lengths
    scale = np.tile(np.array([1.0, 1.0, 1.0, 1.0 / l, 1.0 / l, 1.0 / l]), len(state.q))
    radius = MAX_TURN_RAD
    conservative = not np.any(M)
    for _ in range(max_iterations):
        g, H = gradient_and_hessian(state, section, clamp, F, M)
        i0 = _imbalance(g, tolerances)
        if i0 <= 1.0:
            return state
        if conservative:
            # the model in scaled coordinates y = scale * step: g_s = g / scale, H_s = H / (scale scale^T)
            gs, Hs = g / scale, H / np.outer(scale, scale)
            step_s, predicted = _trust_region_step(gs, Hs, radius)
            trial = _update(state, step_s / scale)
            actual = energy(state, section, clamp, F) - energy(trial, section, clamp, F)
            ratio = actual / predicted if predicted > 0.0 else 0.0
            if ratio < 0.25:
                radius *= 0.25
            elif ratio > 0.75 and np.linalg.norm(step_s) > 0.99 * radius:
                radius = min(2.0 * radius, 16.0 * MAX_TURN_RAD)
            if ratio > 1e-4 or (actual >= 0.0 and _imbalance(gradient_and_hessian(trial, section, clamp, F, M, hessian=False)[0], tolerances) < i0):
                state = trial  # (the second: near the answer the energy's change is below its round-off)
            if radius < 1e-12:
                break
            continue
        step = -np.linalg.solve(H, g)
        turn = float(np.abs(step.reshape(-1, 6)[:, :3]).max())
        if turn > MAX_TURN_RAD:
            step *= MAX_TURN_RAD / turn
        t = 1.0
        while True:
            trial = _update(state, t * step)
            if _imbalance(gradient_and_hessian(trial, section, clamp, F, M, hessian=False)[0], tolerances) < i0 or t < 1e-6:
                break
            t *= 0.5
        state = trial
    blocks = gradient_and_hessian(state, section, clamp, F, M, hessian=False)[0].reshape(-1, 6)
    raise SolverError(f"cosserat rod: Newton did not converge in {max_iterations} iterations at {where}; unbalanced force "
                      f"{np.linalg.norm(blocks[:, 3:]):.3e} N (tolerance {tolerances[0]:.3e}), moment {np.linalg.norm(blocks[:, :3]):.3e} N m "
                      f"(tolerance {tolerances[1]:.3e})")


def _trust_region_step(g: np.ndarray, H: np.ndarray, radius: float) -> tuple[np.ndarray, float]:
    """argmin g.p + p.H.p / 2 over |p| <= radius, and the model's decrease: p = -(H + mu I)^-1 g with the
    least mu >= max(0, -lambda_min) that keeps |p| within the radius, over H's eigenvalues (in the hard
    case, g orthogonal to the lowest mode, that mode fills the radius) [NocedalWright2006]_ sec. 4.3."""
    lam, V = np.linalg.eigh(H)
    c = V.T @ g
    tiny = 1e-14 * max(float(np.abs(lam).max()), 1e-300)

    def p_of(mu):
        return -V @ (c / (lam + mu))

    if lam[0] > tiny:
        p = p_of(0.0)
        if np.linalg.norm(p) <= radius:
            return p, float(-(g @ p) - 0.5 * p @ (H @ p))
    lo = max(0.0, -lam[0]) + tiny
    if np.linalg.norm(p_of(lo)) <= radius:  # the hard case: the lowest mode fills what is left of the radius
        p = p_of(lo)
        v = V[:, 0]
        extra = np.sqrt(max(radius**2 - float(p @ p), 0.0))
        p = p + (extra if float(v @ g) <= 0.0 else -extra) * v
    else:
        hi = lo + float(np.linalg.norm(g)) / radius + abs(float(lam[0]))
        for _ in range(200):  # |p(mu)| falls monotonically in mu: bisect on 1 / |p| - 1 / radius (nearly linear)
            mid = 0.5 * (lo + hi)
            if np.linalg.norm(p_of(mid)) > radius:
                lo = mid
            else:
                hi = mid
            if hi - lo <= 1e-12 * hi:
                break
        p = p_of(hi)
    return p, float(-(g @ p) - 0.5 * p @ (H @ p))
