"""A discrete geometrically exact (Cosserat) rod in statics: large rotations, small strains.

About 620 lines: one model, its energy, exact gradient and Hessian and the Newton / trust region on them.
Each of its pieces (the strains, the point loads and their springs, the axial law) enters the energy,
the gradient and the Hessian, which tests/test_cosserat_rod.py checks against each other term by term,
and fem.cosserat_kernels mirrors the file function by function; split, a piece's three terms would live
apart.

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
load to 0.02 % at 32 segments, second order, which with shear is Haringx's (the shear measured in the section's frame,
:func:`fem.elastica.haringx_load_n`), not Engesser's; the post-buckled column (Euler's elastica) at
1.5 x its load to 0.1 %. This is the rod alone: the coupling to the base's compliance, the contact,
the stress recovery in the ML layer and inertia (issue 38) build on it; it is not a solve tier yet.
Every function takes a batch of rods (leading axes), solved together and each as it would be alone
(benchmarks/bench_cosserat_rod.py: the default sensor's 25 rods at 8 segments, 49 ms a load step in
numpy on a loaded 2-core machine; compiled, fem.cosserat_kernels: 0.4-0.55 ms a load step for 9 rods under 40 point loads).

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

import contextlib
from dataclasses import dataclass

import numpy as np

from fem.linsolve import one_blas_thread
from mlsim.errors import SolverError

#: the largest rotation increment (rad) of a segment in one Newton iteration
MAX_TURN_RAD = 0.5

#: the axial laws of a section (RodSection.axial_law); the kernels take their index
AXIAL_LAWS = ("linear", "neo_hookean")


def axial_force(stretch: np.ndarray, axial_n: float, law: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The axial force n_3 (N), its tangent dn_3 / dlambda (N) and the stored energy per length (N) at the
    stretch lambda (...) of a section of E A = axial_n (N) under ``law`` (RodSection.axial_law)."""
    lam = np.asarray(stretch, dtype=float)
    if law == "linear":
        return axial_n * (lam - 1.0), np.full_like(lam, axial_n), 0.5 * axial_n * (lam - 1.0) ** 2
    mu_a = axial_n / 3.0
    # a segment turned inside out (lambda <= 0): infinite energy, so that a step there is refused
    with np.errstate(divide="ignore"):
        energy = np.where(lam > 0.0, mu_a * (0.5 * lam**2 + 1.0 / lam - 1.5), np.inf)
    return mu_a * (lam - lam**-2), mu_a * (1.0 + 2.0 * lam**-3), energy

__all__ = ["RodSection", "RodState", "PointLoads", "straight_rod", "energy", "gradient_and_hessian", "solve_static"]


@dataclass(frozen=True)
class RodSection:
    """A uniform rod's length and section stiffnesses (SI).

    shear_n: kappa G A (N) for both shear directions; axial_n: E A (N); bending_n_m2: (E I_1, E I_2)
    (N m^2); torsion_n_m2: G J (N m^2). axial_law: the axial force against the stretch lambda = 1 + sigma_3,
    ``"linear"`` E A (lambda - 1), or ``"neo_hookean"`` (E A / 3) (lambda - lambda^-2), an incompressible
    neo-Hookean bar in uniaxial stress (mu = E / 3; its energy per length (E A / 3) (lambda^2 / 2 + 1 / lambda
    - 3 / 2)): the same at lambda = 1, 12.9 % stiffer at 11 % compression, where the sensor's rods are pressed
    by the default demo's flat punch (the nonlinear tier's material is neo-Hookean)."""

    length_m: float
    axial_n: float
    shear_n: float
    bending_n_m2: tuple[float, float]
    torsion_n_m2: float
    axial_law: str = "linear"

    def __post_init__(self):
        if self.axial_law not in AXIAL_LAWS:
            raise ValueError(f"RodSection.axial_law = {self.axial_law!r}: choose one of {', '.join(AXIAL_LAWS)}")
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
    def axial_code(self) -> int:
        """The axial law as the compiled kernels take it (its index in AXIAL_LAWS)."""
        return AXIAL_LAWS.index(self.axial_law)

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


@dataclass(frozen=True)
class PointLoads:
    """Dead forces on points carried by the segments (contact forces on a rod's tip face and sides).

    Point k sits on segment ``segment[k]`` at p_k = (1 - s_k) x_e + s_k x_{e+1} + R_e rho_k: a fraction
    s_k = ``along[k]`` of the way along its chord, offset by rho_k = ``offset_m[k]`` (m, in the segment's
    frame) from the axis; it carries the spatial force ``force_n[k]`` (N), fixed in direction and size
    (a dead load). All four may carry the rods' leading axes: segment, along (..., K); offset_m,
    force_n (..., K, 3). A rod with fewer points pads with zero forces.

    Optionally each point is also held by a linear spring to a fixed point: stiffness_n_m (..., K, 3, 3)
    N/m (symmetric positive semi-definite; zero for none) and anchor_m (..., K, 3) m, adding the energy
    (p_k - a_k) . K_k (p_k - a_k) / 2, so that the point carries f_k - K_k (p_k - a_k). The rods' coupling
    to the contact (:mod:`fem.rod_exact`) holds the loaded points by the contact's stiffness this way (a
    Robin condition): a rod pressed past its free Euler load by a face that holds its tip stays up."""

    segment: np.ndarray
    along: np.ndarray
    offset_m: np.ndarray
    force_n: np.ndarray
    stiffness_n_m: np.ndarray | None = None
    anchor_m: np.ndarray | None = None

    def scaled(self, factor: float) -> "PointLoads":
        """The same points and springs with the dead forces times ``factor``."""
        return PointLoads(self.segment, self.along, self.offset_m, self.force_n * factor, self.stiffness_n_m, self.anchor_m)

    def take(self, rows) -> "PointLoads":
        """The loads of the rods ``rows`` of a flat batch (B, K, ...)."""
        springs = (None, None) if self.stiffness_n_m is None else (self.stiffness_n_m[rows], self.anchor_m[rows])
        return PointLoads(self.segment[rows], self.along[rows], self.offset_m[rows], self.force_n[rows], *springs)

    def carried(self, state: "RodState", positions: np.ndarray | None = None) -> np.ndarray:
        """The forces (..., K, 3) N the points carry in ``state``: the dead force less the spring's pull."""
        if self.stiffness_n_m is None:
            return self.force_n
        p = self.positions(state) if positions is None else positions
        return self.force_n - np.einsum("...kij,...kj->...ki", self.stiffness_n_m, p - self.anchor_m)

    def spring_energy(self, state: "RodState", positions: np.ndarray | None = None) -> np.ndarray:
        """sum_k (p_k - a_k) . K_k (p_k - a_k) / 2 (...) J; zero without springs."""
        if self.stiffness_n_m is None:
            return np.zeros(np.shape(self.force_n)[:-2])
        d = (self.positions(state) if positions is None else positions) - self.anchor_m
        return 0.5 * np.einsum("...ki,...kij,...kj->...", d, self.stiffness_n_m, d)

    def positions(self, state: "RodState", R: np.ndarray | None = None) -> np.ndarray:
        """The points p (..., K, 3) m in ``state`` (R: its frames' rotations, if already made)."""
        R = rotation_matrix(state.q) if R is None else R
        e = np.broadcast_to(self.segment, self.force_n.shape[:-1])
        s = np.broadcast_to(self.along, e.shape)[..., None]
        x0 = np.take_along_axis(state.x, e[..., None], axis=-2)
        x1 = np.take_along_axis(state.x, e[..., None] + 1, axis=-2)
        Re = np.take_along_axis(R, e[..., None, None], axis=-3)
        return (1.0 - s) * x0 + s * x1 + np.einsum("...kij,...kj->...ki", Re, np.broadcast_to(self.offset_m, self.force_n.shape))


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
    """The unloaded rod of ``segments`` segments along the clamp frame's d3 from ``root_m``; root_m (..., 3)
    and frame (..., 4) may carry leading axes (a batch of rods)."""
    if segments < 1:
        raise ValueError(f"segments = {segments}: must be >= 1")
    q0 = np.asarray(frame, dtype=float)
    q0 = q0 / np.linalg.norm(q0, axis=-1, keepdims=True)
    root = np.asarray(root_m, dtype=float)
    lead = np.broadcast_shapes(q0.shape[:-1], root.shape[:-1])
    q0, root = np.broadcast_to(q0, lead + (4,)), np.broadcast_to(root, lead + (3,))
    d3 = rotation_matrix(q0)[..., :, 2]
    s = np.linspace(0.0, section.length_m, segments + 1)
    x = root[..., None, :] + s[:, None] * d3[..., None, :]
    return RodState(x, np.repeat(q0[..., None, :], segments, axis=-2).copy())


# --- strains, energy, gradient and Hessian (leading axes: a batch of rods) --------------------------

def _voronoi(n: int, l: float) -> np.ndarray:
    """The joints' lengths: l between segments, l / 2 at the clamp."""
    lv = np.full(n, l)
    lv[0] = 0.5 * l
    return lv


def _joints(q: np.ndarray, clamp: np.ndarray) -> np.ndarray:
    """p_i = conj(q_{i-1}) q_i for the joints i = 0..N-1 (q_{-1} the clamp), on the branch p_w >= 0."""
    before = np.concatenate([np.broadcast_to(clamp[..., None, :], q[..., :1, :].shape), q[..., :-1, :]], axis=-2)
    p = qmul(qconj(before), q)
    return np.where(p[..., :1] < 0.0, -p, p)


def _kinematics(state: RodState, section: RodSection, clamp: np.ndarray):
    """(R (..., N, 3, 3), b = R^T (x_{e+1} - x_e) / l (..., N, 3), p (..., N, 4), the joints' lengths (N,)):
    what the strains and their derivatives are made of."""
    n = state.q.shape[-2]
    l = section.length_m / n
    R = rotation_matrix(state.q)
    b = np.einsum("...eji,...ej->...ei", R, np.diff(state.x, axis=-2) / l)
    return R, b, _joints(state.q, np.asarray(clamp, dtype=float)), _voronoi(n, l)


def strains(state: RodState, section: RodSection, clamp: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sigma (..., N, 3), kappa (..., N, 3)): each segment's shear-stretch and each joint's bend-twist strain."""
    _, b, p, lv = _kinematics(state, section, clamp)
    return b - np.array([0.0, 0.0, 1.0]), 2.0 * p[..., 1:] / lv[:, None]


def energy(state: RodState, section: RodSection, clamp: np.ndarray, tip_force_n=(0.0, 0.0, 0.0), loads: PointLoads | None = None) -> np.ndarray:
    """The rods' stored energy less the potential of the dead tip force and point loads (J), shape (...)."""
    n = state.q.shape[-2]
    l = section.length_m / n
    sigma, kappa = strains(state, section, clamp)
    stored = (0.5 * l * np.sum(sigma[..., :2] ** 2 * section.S[:2], axis=(-2, -1)) + l * np.sum(axial_force(1.0 + sigma[..., 2], section.axial_n, section.axial_law)[2], axis=-1)
              + 0.5 * np.sum(_voronoi(n, l)[:, None] * kappa**2 * section.B, axis=(-2, -1)))
    stored = stored - np.sum(np.asarray(tip_force_n, dtype=float) * (state.x[..., -1, :] - state.x[..., 0, :]), axis=-1)
    if loads is not None:
        p = loads.positions(state)
        stored = stored - np.sum(loads.force_n * (p - state.x[..., :1, :]), axis=(-2, -1)) + loads.spring_energy(state, p)
    return stored


def gradient_and_hessian(state: RodState, section: RodSection, clamp: np.ndarray, tip_force_n=(0.0, 0.0, 0.0),
                         tip_moment_n_m=(0.0, 0.0, 0.0), hessian: bool = True, loads: PointLoads | None = None):
    """The energy's gradient g (..., 6N) and Hessian H (..., 6N, 6N) in the unknowns (psi_0, x_1, psi_1, x_2,
    ..., psi_{N-1}, x_N): each segment's rotation increment (in its own frame, q_e <- q_e cay(psi_e)) and
    the node at its far end, at psi = 0. The dead tip moment (spatial, N m) enters g only; the point
    loads' load stiffness (a dead force on an offset turns with its segment) enters H."""
    n = state.q.shape[-2]
    lead = state.q.shape[:-2]
    l = section.length_m / n
    S, Bk = section.S, section.B
    R, b, p, lv = _kinematics(state, section, clamp)
    RT = np.swapaxes(R, -1, -2)
    nmat = (b - np.array([0.0, 0.0, 1.0])) * S  # the sections' force in their frames (N)
    nmat[..., 2], axial_tangent, _ = axial_force(b[..., 2], section.axial_n, section.axial_law)
    lS = l * np.concatenate([np.broadcast_to(S[:2], b.shape[:-1] + (2,)), axial_tangent[..., None]], axis=-1)  # (..., N, 3): the tangent
    m = 2.0 * p[..., 1:] / lv[:, None] * Bk  # the joints' moment, in the frames of the joints (N m)
    pw, pv = p[..., 0], p[..., 1:]
    g = np.zeros(lead + (n, 6))  # block e: (psi_e, x_{e+1})
    force = np.einsum("...eij,...ej->...ei", R, nmat)  # spatial section forces
    g[..., 3:] += force
    g[..., :-1, 3:] -= force[..., 1:, :]  # x_{e+1} is the start of segment e + 1
    g[..., :3] += -l * np.cross(b, nmat)
    # joint i between frames i - 1 (a) and i (b): dkappa/dpsi_b = (p_w I + [p_v]x) / l_i, dkappa/dpsi_a = (-p_w I + [p_v]x) / l_i
    g[..., :3] += pw[..., None] * m - np.cross(pv, m)
    g[..., :-1, :3] += -pw[..., 1:, None] * m[..., 1:, :] - np.cross(pv[..., 1:, :], m[..., 1:, :])
    g[..., -1, 3:] -= np.asarray(tip_force_n, dtype=float)
    g[..., -1, :3] -= np.einsum("...ij,...j->...i", RT[..., -1, :, :], np.asarray(tip_moment_n_m, dtype=float))
    if loads is not None:
        # -f . ((1 - s) x_e + s x_{e+1} + R_e cay(psi_e) rho): x_{e+1} in block e, x_e in block e - 1 (the root's
        # share dropped), psi_e's first order -rho x (R_e^T f), its second -(R_e^T f) . (psi x (psi x rho)) / 2
        # a spring's force f - K (p - a) takes the dead force's place (its second-order term is a dead
        # force's); its J^T K J is added to H below
        f = loads.carried(state)
        e = np.broadcast_to(loads.segment, f.shape[:-1])
        s_k = np.broadcast_to(loads.along, e.shape)[..., None]
        rho = np.broadcast_to(loads.offset_m, f.shape)
        f_body = np.einsum("...kji,...kj->...ki", np.take_along_axis(R, e[..., None, None], axis=-3), f)  # R_e^T f
        gb = g.reshape(-1, n, 6)
        batch = np.broadcast_to(np.arange(gb.shape[0]).reshape(lead + (1,)) if lead else np.zeros(1, dtype=int), e.shape)
        np.add.at(gb, (batch, e, slice(3, 6)), -s_k * f)
        before = e >= 1
        np.add.at(gb, (batch[before], e[before] - 1, slice(3, 6)), -((1.0 - s_k) * f)[before])
        np.add.at(gb, (batch, e, slice(0, 3)), -np.cross(rho, f_body))
    g = g.reshape(lead + (6 * n,))
    if not hessian:
        return g, None
    # block-tridiagonal: D[e] the (psi_e, x_{e+1}) block, O[e] the coupling of block e - 1 to block e
    D = np.zeros(lead + (n, 6, 6))
    O = np.zeros(lead + (n, 6, 6))
    # segment e: sigma = (I - [psi]x + [psi]x^2 / 2) R^T (x_{e+1} - x_e) / l - d3
    Jx = RT / l  # dsigma/dx_{e+1}; -Jx for x_e
    Jpsi = _skew(b)
    Kxx = np.einsum("...eki,...ek,...ekj->...eij", Jx, lS, Jx)
    eye = np.eye(3)
    Kpp = np.einsum("...eki,...ek,...ekj->...eij", Jpsi, lS, Jpsi) + l * (
        0.5 * (nmat[..., :, None] * b[..., None, :] + b[..., :, None] * nmat[..., None, :])
        - np.einsum("...k,...k->...", nmat, b)[..., None, None] * eye)
    Kpx = np.einsum("...eki,...ek,...ekj->...eij", Jpsi, lS, Jx) + _skew(nmat) @ RT  # d2E / dpsi_e dx_{e+1}
    D[..., :3, :3] += Kpp
    D[..., :3, 3:] += Kpx
    D[..., 3:, :3] += np.swapaxes(Kpx, -1, -2)
    D[..., 3:, 3:] += Kxx
    # x_e (the node before segment e, free for e >= 1) sits in block e - 1
    D[..., :-1, 3:, 3:] += Kxx[..., 1:, :, :]
    O[..., 1:, 3:, :3] -= np.swapaxes(Kpx[..., 1:, :, :], -1, -2)  # (x_e, psi_e)
    O[..., 1:, 3:, 3:] -= Kxx[..., 1:, :, :]  # (x_e, x_{e+1})
    # joint i: first-order J_b = (p_w I + [p_v]x) / l_i, J_a = (-p_w I + [p_v]x) / l_i; second-order terms of
    # 2 m . Im(conj(cay(a)) p cay(b)): -(m . p_v) / 2 on the aa and bb diagonals, (m p_v^T + [m]x (p_w I + [p_v]x)) / 2 for ab
    P = pw[..., None, None] * eye + _skew(pv)
    Jb = P / lv[:, None, None]
    Ja = (-pw[..., None, None] * eye + _skew(pv)) / lv[:, None, None]
    diag = -0.5 * np.einsum("...k,...k->...", m, pv)[..., None, None] * eye
    lvB = lv[:, None] * Bk
    D[..., :3, :3] += np.einsum("...ika,ik,...ikb->...iab", Jb, lvB, Jb) + diag
    D[..., :-1, :3, :3] += np.einsum("...ika,ik,...ikb->...iab", Ja[..., 1:, :, :], lvB[1:], Ja[..., 1:, :, :]) + diag[..., 1:, :, :]
    O[..., 1:, :3, :3] += np.einsum("...ika,ik,...ikb->...iab", Ja[..., 1:, :, :], lvB[1:], Jb[..., 1:, :, :]) \
        + 0.5 * (m[..., 1:, :, None] * pv[..., 1:, None, :] + _skew(m[..., 1:, :]) @ P[..., 1:, :, :])
    if loads is not None:
        load_k = -0.5 * (rho[..., :, None] * f_body[..., None, :] + f_body[..., :, None] * rho[..., None, :]) \
            + np.einsum("...k,...k->...", rho, f_body)[..., None, None] * eye
        np.add.at(D.reshape(-1, n, 6, 6), (batch, e, slice(0, 3), slice(0, 3)), load_k)
        if loads.stiffness_n_m is not None:
            # J^T K J: dp/dpsi_e = A = -R_e [rho]x, dp/dx_{e+1} = s I, dp/dx_e = (1 - s) I (block e - 1)
            K = np.broadcast_to(loads.stiffness_n_m, f.shape + (3,))
            A = -np.take_along_axis(R, e[..., None, None], axis=-3) @ _skew(rho)
            KA = K @ A
            Db, Ob = D.reshape(-1, n, 6, 6), O.reshape(-1, n, 6, 6)
            s2 = s_k[..., None]
            np.add.at(Db, (batch, e, slice(0, 3), slice(0, 3)), np.swapaxes(A, -1, -2) @ KA)
            np.add.at(Db, (batch, e, slice(0, 3), slice(3, 6)), s2 * np.swapaxes(KA, -1, -2))
            np.add.at(Db, (batch, e, slice(3, 6), slice(0, 3)), s2 * KA)
            np.add.at(Db, (batch, e, slice(3, 6), slice(3, 6)), s2**2 * K)
            np.add.at(Db, (batch[before], e[before] - 1, slice(3, 6), slice(3, 6)), ((1.0 - s2) ** 2 * K)[before])
            np.add.at(Ob, (batch[before], e[before], slice(3, 6), slice(0, 3)), ((1.0 - s2) * KA)[before])
            np.add.at(Ob, (batch[before], e[before], slice(3, 6), slice(3, 6)), ((1.0 - s2) * s2 * K)[before])
    H = np.zeros(lead + (n, n, 6, 6))
    idx = np.arange(n)
    H[..., idx, idx, :, :] = D
    H[..., idx[:-1], idx[1:], :, :] = O[..., 1:, :, :]
    H[..., idx[1:], idx[:-1], :, :] = np.swapaxes(O[..., 1:, :, :], -1, -2)
    return g, np.swapaxes(H, -3, -2).reshape(lead + (6 * n, 6 * n))


def _update(state: RodState, step: np.ndarray) -> RodState:
    """The state after a Newton step (psi_e, dx_{e+1}) per block: the frames turned, q_e cay(psi_e), and each
    segment's chord rebuilt from its strain as the step changes it to first order, in the turned frame,
    x_{e+1} - x_e = l R_e' (b_e + db_e), b_e = R_e^T (x_{e+1} - x_e) / l, db_e = R_e^T (dx_{e+1} - dx_e) / l
    + b_e x psi_e. To first order this is the additive step (Newton's convergence is kept); for a large
    turn the nodes follow the frames along the arc instead of the tangent, which would stretch the rod by
    turn^2 / 2 and make a stiff axial spring cut every step short."""
    blocks = step.reshape(step.shape[:-1] + (-1, 6))
    psi = blocks[..., :3]
    dx = np.concatenate([np.zeros(blocks.shape[:-2] + (1, 3)), blocks[..., 3:]], axis=-2)
    R = rotation_matrix(state.q)
    b = np.einsum("...eji,...ej->...ei", R, np.diff(state.x, axis=-2))
    db = np.einsum("...eji,...ej->...ei", R, np.diff(dx, axis=-2)) + np.cross(b, psi)
    q = qmul(state.q, cayley(psi))
    q /= np.linalg.norm(q, axis=-1, keepdims=True)
    chords = np.einsum("...eij,...ej->...ei", rotation_matrix(q), b + db)
    root = state.x[..., :1, :]
    return RodState(np.concatenate([root, root + np.cumsum(chords, axis=-2)], axis=-2), q)


def _where(mask: np.ndarray, a: RodState, b: RodState) -> RodState:
    """a where mask (...,) holds, else b."""
    return RodState(np.where(mask[..., None, None], a.x, b.x), np.where(mask[..., None, None], a.q, b.q))


def solve_static(section: RodSection, segments: int, tip_force_n=(0.0, 0.0, 0.0), tip_moment_n_m=(0.0, 0.0, 0.0),
                 clamp=(1.0, 0.0, 0.0, 0.0), root_m=(0.0, 0.0, 0.0), start: RodState | None = None, increments: int = 1,
                 rtol: float = 1e-10, max_iterations: int = 60, loads: PointLoads | None = None, compiled: bool = True) -> RodState:
    """The rods' equilibrium under a dead tip force (N), tip moment (N m) and point ``loads`` (:class:`PointLoads`), all spatial, applied in
    ``increments`` equal load steps from ``start`` (default: the straight rods along the clamp frames'
    d3 from ``root_m``). Forces, moments, clamps and roots may carry leading axes: a batch of rods,
    solved together (each with its own trust region) and equal to solving each alone. Converged when
    the nodes' forces are balanced to ``rtol`` of the load scale and the frames' moments to that times
    a segment's length (or to the stiffnesses' round-off, 100 eps E A). Raises
    :class:`mlsim.errors.SolverError` if Newton does not converge. ``compiled``: Newton's iterations in
    :mod:`fem.cosserat_kernels` (numba) while a rod's Hessian is positive definite and its step inside the
    trust region, the numpy code below (the reference) for the rest; False: numpy throughout."""
    F, M = np.asarray(tip_force_n, dtype=float), np.asarray(tip_moment_n_m, dtype=float)
    if not (np.all(np.isfinite(F)) and np.all(np.isfinite(M))):
        raise ValueError(f"tip_force_n = {F.tolist()}, tip_moment_n_m = {M.tolist()}: must be finite")
    if loads is not None and not (np.all(np.isfinite(loads.force_n)) and np.all(np.isfinite(loads.offset_m))):
        raise ValueError("loads: the point forces and offsets must be finite")
    if loads is not None and loads.stiffness_n_m is not None and not (np.all(np.isfinite(loads.stiffness_n_m)) and np.all(np.isfinite(loads.anchor_m))):
        raise ValueError("loads: the points' spring stiffnesses and anchors must be finite")
    if loads is not None and (np.any(np.asarray(loads.segment) < 0) or np.any(np.asarray(loads.segment) >= segments)
                              or np.any(np.asarray(loads.along) < 0.0) or np.any(np.asarray(loads.along) > 1.0)):
        raise ValueError(f"loads: segment must lie in 0..{segments - 1} and along in [0, 1]")
    clamp = np.asarray(clamp, dtype=float)
    clamp = clamp / np.linalg.norm(clamp, axis=-1, keepdims=True)
    lead = np.broadcast_shapes(F.shape[:-1], M.shape[:-1], clamp.shape[:-1], np.shape(root_m)[:-1],
                               start.q.shape[:-2] if start is not None else ())
    clamp = np.broadcast_to(clamp, lead + (4,))
    F, M = np.broadcast_to(F, lead + (3,)), np.broadcast_to(M, lead + (3,))
    state = start if start is not None else straight_rod(section, segments, np.broadcast_to(np.asarray(root_m, dtype=float), lead + (3,)), clamp)
    eps = np.finfo(float).eps
    load = np.maximum(np.maximum(np.linalg.norm(F, axis=-1), np.linalg.norm(M, axis=-1) / section.length_m), section.B.max() / section.length_m**2)
    if loads is not None:
        load = np.maximum(load, np.linalg.norm(loads.force_n, axis=-1).sum(axis=-1))
    force_tol = np.maximum(rtol * load, 100.0 * eps * section.S.max())
    l = section.length_m / state.q.shape[-2]
    tolerances = (force_tol, np.maximum(force_tol * l, 100.0 * eps * section.B.max() / l))
    # the matrices are small (6 N): BLAS threads only fight each other (60x slower on a loaded 2-core machine);
    # the compiled path calls no BLAS but in its numpy fallback, which sets the limit itself (fem.linsolve.one_blas_thread:
    # the process's thread pools found once; threadpool_limits scanned them on every call, 0.6 ms)
    newton = _newton_compiled if compiled else _newton
    with contextlib.nullcontext() if compiled else one_blas_thread():
        for k in range(1, increments + 1):
            part = None if loads is None else loads.scaled(k / increments)
            state = newton(state, section, clamp, F * k / increments, M * k / increments, tolerances, max_iterations,
                            f"load step {k}/{increments}", part)
    return state


def _newton_compiled(state: RodState, section: RodSection, clamp, F, M, tolerances, max_iterations: int, where: str,
                     loads: PointLoads | None = None) -> RodState:
    """:func:`_newton`'s answer: the compiled Newton (:func:`fem.cosserat_kernels.newton_batch`) on every rod,
    with numpy's trust region compiled where a rod's Hessian is indefinite or it runs out of iterations under
    conservative loads; with a dead moment, numpy's Newton from where it stopped on the rods it flagged. Raises
    :class:`SolverError` as numpy's loop does. clamp, F, M and the tolerances are broadcast to the batch's
    leading shape."""
    from fem import cosserat_kernels as ck

    lead = np.broadcast_shapes(np.shape(clamp)[:-1], np.shape(F)[:-1], np.shape(M)[:-1], state.q.shape[:-2],
                               np.shape(tolerances[0]), np.shape(tolerances[1]))
    n = state.q.shape[-2]
    x, q, clamp_f, F_f, M_f, seg, along, offset, force, stiffness, anchor = ck.flatten_problem(state, section, clamp, F, M, loads, lead)
    nrods = x.shape[0]
    tol_f, tol_m = ck._owned(tolerances[0], lead).reshape(nrods), ck._owned(tolerances[1], lead).reshape(nrods)
    status, _ = ck.newton_batch(x, q, clamp_f, float(section.length_m), section.S, section.B, F_f, M_f, seg, along, offset, force,
                                stiffness, anchor, tol_f, tol_m, int(max_iterations), not np.any(M_f), MAX_TURN_RAD, section.axial_code)
    springs = (None, None) if loads is None or loads.stiffness_n_m is None else (stiffness, anchor)

    def part(rows):
        return (RodState(x[rows], q[rows]), clamp_f[rows], F_f[rows], M_f[rows], (tol_f[rows], tol_m[rows]),
                None if loads is None else PointLoads(seg, along, offset, force, *springs).take(rows))

    failed = np.flatnonzero(status == ck.FAILED)
    if failed.size:
        st, c, f, m, tol, ld = part(failed)
        _not_converged(st, section, c, f, m, tol, max_iterations, where, ld)
    rest = np.flatnonzero(status == ck.FALLBACK)
    if rest.size:
        st, c, f, m, tol, ld = part(rest)
        with one_blas_thread():  # small matrices: BLAS threads only fight each other
            done = _newton(st, section, c, f, m, tol, max_iterations, where, ld)
        x[rest], q[rest] = done.x, done.q
    return RodState(x.reshape(lead + (n + 1, 3)), q.reshape(lead + (n, 4)))


def _imbalance(g: np.ndarray, tolerances) -> np.ndarray:
    """The larger of the nodes' unbalanced force and the frames' unbalanced moment, each over its tolerance (...)."""
    blocks = g.reshape(g.shape[:-1] + (-1, 6))
    return np.maximum(np.linalg.norm(blocks[..., 3:], axis=(-2, -1)) / tolerances[0],
                      np.linalg.norm(blocks[..., :3], axis=(-2, -1)) / tolerances[1])


def _newton(state: RodState, section: RodSection, clamp: np.ndarray, F: np.ndarray, M: np.ndarray, tolerances, max_iterations: int,
            where: str, loads: PointLoads | None = None) -> RodState:
    """Newton's method from ``state`` under (F, M), every rod of the batch at once. Under a dead force
    alone (conservative): a trust region on each rod's energy, its model step solved exactly over the
    Hessian's eigenvalues ([NocedalWright2006]_ Algorithm 4.3), which follows a column past its buckling
    load off the straight state (a saddle) to the bent one. With a dead moment (not conservative: no
    energy to judge a step by, and its load stiffness left out of H): Newton's step with a
    backtracking line search on the imbalance."""
    n = state.q.shape[-2]
    l = section.length_m / n
    # the trust region's norm: turns in rad, node moves in segment lengths
    scale = np.tile(np.array([1.0, 1.0, 1.0, 1.0 / l, 1.0 / l, 1.0 / l]), n)
    lead = state.q.shape[:-2]
    radius = np.full(lead, MAX_TURN_RAD)
    conservative = not np.any(M)
    for _ in range(max_iterations):
        g, H = gradient_and_hessian(state, section, clamp, F, M, loads=loads)
        i0 = _imbalance(g, tolerances)
        todo = i0 > 1.0
        if not np.any(todo):
            return state
        if conservative:
            step_s, predicted = _trust_region_step(g / scale, H / np.outer(scale, scale), radius)
            trial = _update(state, step_s / scale)
            e_state = energy(state, section, clamp, F, loads)
            actual = e_state - energy(trial, section, clamp, F, loads)
            ratio = np.where(predicted > 0.0, actual / np.where(predicted > 0.0, predicted, 1.0), 0.0)
            full = np.linalg.norm(step_s, axis=-1) > 0.99 * radius
            radius = np.where(ratio < 0.25, 0.25 * radius, np.where((ratio > 0.75) & full, np.minimum(2.0 * radius, 16.0 * MAX_TURN_RAD), radius))
            # near the answer the energy's change is below its round-off (either sign): then a lower imbalance is progress
            noise = 1e-12 * (np.abs(e_state) + _round_off_scale(state, section, clamp, F, loads))
            accept = (ratio > 1e-4) | ((actual >= -noise) & (_imbalance(gradient_and_hessian(trial, section, clamp, F, M, hessian=False, loads=loads)[0], tolerances) < i0))
            state = _where(todo & accept, trial, state)
            if np.all(radius[todo] < 1e-12):
                break
            continue
        step = -np.linalg.solve(H, g[..., None])[..., 0]
        turn = np.abs(step.reshape(step.shape[:-1] + (-1, 6))[..., :3]).max(axis=(-2, -1))
        step *= np.minimum(1.0, MAX_TURN_RAD / np.maximum(turn, 1e-300))[..., None]
        t = np.ones(lead)
        trial = _update(state, step)
        for _ in range(20):
            worse = _imbalance(gradient_and_hessian(trial, section, clamp, F, M, hessian=False, loads=loads)[0], tolerances) >= i0
            if not np.any(worse):
                break
            t = np.where(worse, 0.5 * t, t)
            trial = _update(state, t[..., None] * step)
        state = _where(todo, trial, state)
    _not_converged(state, section, clamp, F, M, tolerances, max_iterations, where, loads)


def _not_converged(state: RodState, section: RodSection, clamp, F, M, tolerances, max_iterations: int, where: str,
                   loads: PointLoads | None) -> None:
    """Raise the :class:`SolverError` of rods that did not converge in ``max_iterations`` (their unbalance)."""
    blocks = gradient_and_hessian(state, section, clamp, F, M, hessian=False, loads=loads)[0]
    blocks = blocks.reshape(blocks.shape[:-1] + (-1, 6))
    raise SolverError(f"cosserat rod: Newton did not converge in {max_iterations} iterations at {where}; unbalanced force "
                      f"{np.linalg.norm(blocks[..., 3:], axis=(-2, -1)).max():.3e} N (tolerance {np.min(tolerances[0]):.3e}), moment "
                      f"{np.linalg.norm(blocks[..., :3], axis=(-2, -1)).max():.3e} N m (tolerance {np.min(tolerances[1]):.3e})")


def _round_off_scale(state: RodState, section: RodSection, clamp: np.ndarray, F: np.ndarray, loads: PointLoads | None) -> np.ndarray:
    """The size (...) J of the energy's terms, against which the trust region judges a change as round-off: the
    loads' work |F . (x_N - x_0)| + |sum_k f_k . (p_k - x_0)|, the springs' sum_k |K_k (p_k - a_k) . (p_k - x_0)|,
    and the sections' forces and moments times the reach their nodes' round-off acts over, sum_e |n_e|_1 (max_i
    |x_i - x_0|_inf + l) + sum_i |m_i|_1 l_i. (A rod near rest with only the springs of its inertia, fem.cosserat_dynamics,
    has an energy of 1e-8 J whose round-off, from its nodes 1e-2 m from the origin, is that of its section forces'
    work: its trust region stalled at 1.2-1.5 x its tolerance when judged against the energy alone.)
    Mirrored by fem.cosserat_kernels._evaluate_rod."""
    n = state.q.shape[-2]
    l = section.length_m / n
    x0 = state.x[..., :1, :]
    work = np.abs(np.sum(F * (state.x[..., -1, :] - state.x[..., 0, :]), axis=-1))
    if loads is not None:
        p = loads.positions(state)
        work = work + np.abs(np.sum(loads.force_n * (p - x0), axis=(-2, -1)))
        if loads.stiffness_n_m is not None:
            pull = np.einsum("...kij,...kj->...ki", loads.stiffness_n_m, p - loads.anchor_m)
            work = work + np.sum(np.abs(pull * (p - x0)), axis=(-2, -1))
    sigma, kappa = strains(state, section, clamp)
    n_sec = sigma * section.S
    n_sec[..., 2] = axial_force(1.0 + sigma[..., 2], section.axial_n, section.axial_law)[0]
    reach = np.abs(state.x - x0).max(axis=(-2, -1)) + l
    internal = reach * np.abs(n_sec).sum(axis=(-2, -1)) + np.sum(_voronoi(n, l)[:, None] * np.abs(kappa * section.B), axis=(-2, -1))
    return work + internal


def _cho_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(L L^T)^-1 b for a stack of Cholesky factors (..., K, K) and right-hand sides (..., K)."""
    y = np.linalg.solve(L, b[..., None])
    return np.linalg.solve(np.swapaxes(L, -1, -2), y)[..., 0]


def _trust_region_step(g: np.ndarray, H: np.ndarray, radius: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """argmin g.p + p.H.p / 2 over |p| <= radius per rod (g (..., K), H (..., K, K), radius (...)), and the
    model's decrease: p = -(H + mu I)^-1 g with the least mu >= max(0, -lambda_min) that keeps |p| within
    the radius, over H's eigenvalues; in the hard case (g orthogonal to the lowest mode) that mode fills
    the radius [NocedalWright2006]_ sec. 4.3."""
    try:  # the common case, every rod's Hessian positive definite and its Newton step inside its radius
        L = np.linalg.cholesky(H)
        p = -_cho_solve(L, g)
        if np.all(np.linalg.norm(p, axis=-1) <= radius):
            return p, -np.einsum("...k,...k->...", g, p) - 0.5 * np.einsum("...k,...kl,...l->...", p, H, p)
    except np.linalg.LinAlgError:
        pass
    lam, V = np.linalg.eigh(H)
    c = np.einsum("...ki,...k->...i", V, g)
    tiny = 1e-14 * np.maximum(np.abs(lam).max(axis=-1), 1e-300)

    def p_of(mu):
        return -np.einsum("...ki,...i->...k", V, c / (lam + mu[..., None]))

    lo = np.maximum(0.0, -lam[..., 0]) + tiny
    newton = lam[..., 0] > tiny
    p0 = p_of(np.where(newton, 0.0, lo))
    inside = newton & (np.linalg.norm(p0, axis=-1) <= radius)
    p_lo = p_of(lo)
    hard = ~inside & (np.linalg.norm(p_lo, axis=-1) <= radius)
    hi = lo + np.linalg.norm(g, axis=-1) / radius + np.abs(lam[..., 0])
    a, b = lo.copy(), hi
    for _ in range(100):  # |p(mu)| falls monotonically in mu: bisection, each rod at once
        mid = 0.5 * (a + b)
        outside = np.linalg.norm(p_of(mid), axis=-1) > radius
        a, b = np.where(outside, mid, a), np.where(outside, b, mid)
    p = p_of(b)
    v = V[..., :, 0]
    extra = np.sqrt(np.maximum(radius**2 - np.sum(p_lo**2, axis=-1), 0.0))
    sign = np.where(np.einsum("...k,...k->...", v, g) <= 0.0, 1.0, -1.0)
    p_hard = p_lo + (sign * extra)[..., None] * v
    p = np.where(inside[..., None], p0, np.where(hard[..., None], p_hard, p))
    predicted = -np.einsum("...k,...k->...", g, p) - 0.5 * np.einsum("...k,...kl,...l->...", p, H, p)
    return p, predicted
