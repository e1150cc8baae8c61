"""Backward Euler inertia of the discrete Cosserat rod (:mod:`fem.cosserat_rod`): the fast tier's rods in dynamics.

A step of size h from the nodes' positions x_n and velocities v_n solves, node by node,

    m_i (x_i - x_n,i - h v_n,i) / h^2 + a_M m_i (x_i - x_n,i) / h + dE/dx_i = 0,        v = (x - x_n) / h,

with E the rod's stored energy and loads (:func:`fem.cosserat_rod.energy`): backward Euler, as the
nonlinear tier's dynamics (:mod:`fem.dynamics`), first order and energy-stable at any step (its numerical
dissipation |v_{n+1} - v_n|_M^2 / 2 >= 0). The inertia and damping of node i are the energy of a spring

    k_i |x_i - a_i|^2 / 2,    k_i = m_i (1 / h^2 + a_M / h),    a_i = (x_n,i + h v_n,i + a_M h x_n,i) / (1 + a_M h),

so a step is the rod's static solve (:func:`fem.cosserat_rod.solve_static`) with one more spring per node
(:class:`fem.cosserat_rod.PointLoads`), and the Newton, its trust region past a buckling load, and the
compiled kernels are the statics' own. Under a large step the springs vanish and the step is the static
equilibrium; under a small one they hold the rod near its inertial prediction.

Simplifications (each stated where the figures are):

- lumped translational masses m_i = rho A l at the inner nodes and rho A l / 2 at the tip (rho A the
  section's mass per length, :class:`RodInertia`); the segments' rotary inertia is left out (Rayleigh's
  correction, of the order of the section's radius of gyration over the rod's length squared: the
  sensor's 12 x 5 mm rods, (1.25 / 12)^2 = 1 %, below backward Euler's own error at the reference's step);
- Rayleigh damping proportional to the mass, a_M, where the nonlinear tier damps in proportion to the
  stiffness, b_K = eta / omega_1 (:class:`fem.finite_strain._Inertia`): a_M = eta omega_1 gives the same
  ratio eta / 2 at the rods' first bending mode, which dominates their motion; the higher modes, which
  the stiffness-proportional damping kills, are killed here by backward Euler's numerical damping
  (a mode resolved by fewer than about 4 steps a period loses more than half its amplitude a step).

Verified in tests/test_cosserat_dynamics.py: the discrete rod's first mode against the Euler-Bernoulli
cantilever's, second order in the segments; a small release against the exact backward Euler recurrence
of that mode (period and decay, with and without damping); the energy never growing after a large
release; a step of a rod at rest under no load moving nothing.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fem import cosserat_rod as cr

__all__ = ["RodInertia", "joined", "step", "first_mode_rad_s"]


@dataclass(frozen=True)
class RodInertia:
    """The rods' lumped mass and backward Euler step: mass per length (kg/m), the step h (s) and the
    mass-proportional damping a_M (1/s)."""

    mass_per_length_kg_m: float
    time_step_s: float
    damping_per_s: float = 0.0

    def __post_init__(self):
        for name in ("mass_per_length_kg_m", "time_step_s"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0.0):
                raise ValueError(f"RodInertia.{name} = {value}: must be a finite number > 0")
        if not (np.isfinite(self.damping_per_s) and self.damping_per_s >= 0.0):
            raise ValueError(f"RodInertia.damping_per_s = {self.damping_per_s}: must be a finite number >= 0")

    def node_mass_kg(self, section: cr.RodSection, segments: int) -> np.ndarray:
        """The lumped masses (N + 1,) kg of the nodes, the root's (clamped, unused) included."""
        m = np.full(segments + 1, self.mass_per_length_kg_m * section.length_m / segments)
        m[[0, -1]] *= 0.5
        return m

    def springs(self, section: cr.RodSection, x_n: np.ndarray, v_n: np.ndarray) -> cr.PointLoads:
        """The step's inertia as springs on the nodes 1..N (:class:`fem.cosserat_rod.PointLoads` (..., N)),
        from positions x_n and velocities v_n (..., N + 1, 3) m, m/s."""
        x_n, v_n = np.asarray(x_n, dtype=float), np.asarray(v_n, dtype=float)
        segments = x_n.shape[-2] - 1
        h, a = self.time_step_s, self.damping_per_s
        k = self.node_mass_kg(section, segments)[1:] * (1.0 / h**2 + a / h)
        anchor = (x_n[..., 1:, :] + h * v_n[..., 1:, :] + a * h * x_n[..., 1:, :]) / (1.0 + a * h)
        lead = anchor.shape[:-2]
        segment = np.broadcast_to(np.arange(segments), lead + (segments,))
        return cr.PointLoads(segment, np.ones(lead + (segments,)), np.zeros(lead + (segments, 3)), np.zeros(lead + (segments, 3)),
                             np.broadcast_to(k[:, None, None] * np.eye(3), lead + (segments, 3, 3)), anchor)

    def nodal_forces(self, springs: cr.PointLoads, state: cr.RodState) -> np.ndarray:
        """The inertial and damping forces (..., N + 1, 3) N the nodes of ``state`` carry (the root's zero):
        -k_i (x_i - a_i), the load the rod's own solve felt from its inertia."""
        out = np.zeros_like(state.x)
        out[..., 1:, :] = springs.carried(state, state.x[..., 1:, :])
        return out

    def velocity(self, x: np.ndarray, x_n: np.ndarray) -> np.ndarray:
        """Backward Euler's velocity (x - x_n) / h (..., N + 1, 3) m/s."""
        return (np.asarray(x) - np.asarray(x_n)) / self.time_step_s

    def kinetic_energy_j(self, section: cr.RodSection, v: np.ndarray) -> np.ndarray:
        """sum_i m_i |v_i|^2 / 2 (...) J."""
        return 0.5 * np.einsum("i,...ij,...ij->...", self.node_mass_kg(section, v.shape[-2] - 1), v, v)


def joined(a: cr.PointLoads | None, b: cr.PointLoads) -> cr.PointLoads:
    """Two sets of point loads on the same rods as one (along the points' axis); springs zero where a set has none."""
    if a is None:
        return b

    def springs(p: cr.PointLoads):
        if p.stiffness_n_m is not None:
            return p.stiffness_n_m, p.anchor_m
        shape = np.shape(p.force_n)
        return np.zeros(shape + (3,)), np.zeros(shape)

    (ka, aa), (kb, ab) = springs(a), springs(b)
    # the points' axis: last of segment and along (..., K), then -2 and -3 of the vectors and matrices
    return cr.PointLoads(np.concatenate([a.segment, b.segment], axis=-1), np.concatenate([a.along, b.along], axis=-1),
                         np.concatenate([a.offset_m, b.offset_m], axis=-2), np.concatenate([a.force_n, b.force_n], axis=-2),
                         np.concatenate([ka, kb], axis=-3), np.concatenate([aa, ab], axis=-2))


def step(section: cr.RodSection, inertia: RodInertia, state: cr.RodState, velocity: np.ndarray, loads: cr.PointLoads | None = None,
         tip_force_n=(0.0, 0.0, 0.0), clamp=(1.0, 0.0, 0.0, 0.0), root_m=None, rtol: float = 1e-10) -> tuple[cr.RodState, np.ndarray]:
    """One backward Euler step of clamped rods from ``state`` and nodal ``velocity`` (..., N + 1, 3) m/s under
    point ``loads`` and a dead tip force (N) at the step's end; the root at ``root_m`` (default: where it is).
    Returns (state, velocity) at the step's end."""
    segments = state.q.shape[-2]
    root = state.x[..., 0, :] if root_m is None else np.asarray(root_m, dtype=float)
    all_loads = joined(loads, inertia.springs(section, state.x, velocity))
    new = cr.solve_static(section, segments, tip_force_n=tip_force_n, clamp=clamp, root_m=root,
                          start=cr.RodState(state.x - state.x[..., :1, :] + root[..., None, :], state.q), rtol=rtol, loads=all_loads)
    return new, inertia.velocity(new.x, state.x)


def first_mode_rad_s(section: cr.RodSection, inertia: RodInertia, segments: int) -> float:
    """The discrete rod's first bending mode (rad/s): the straight clamped rod's Hessian (its stiffness) against
    the lumped masses, the frames' rotations (massless) condensed out (a Guyan reduction, exact here)."""
    straight = cr.straight_rod(section, segments)
    _, H = cr.gradient_and_hessian(straight, section, np.array([1.0, 0.0, 0.0, 0.0]))
    # the dofs per segment e: (psi_e (3), x_{e+1} (3)) (fem.cosserat_rod's ordering)
    idx = np.arange(6 * segments).reshape(segments, 6)
    rot, tra = idx[:, :3].ravel(), idx[:, 3:].ravel()
    K = H[np.ix_(tra, tra)] - H[np.ix_(tra, rot)] @ np.linalg.solve(H[np.ix_(rot, rot)], H[np.ix_(rot, tra)])
    m = np.repeat(inertia.node_mass_kg(section, segments)[1:], 3)
    w2 = scipy.linalg.eigh(K, np.diag(m), eigvals_only=True)
    return float(np.sqrt(w2[0]))
