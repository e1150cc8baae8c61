"""Balance on one sole: the linear inverted pendulum under the capture-point ZMP regulator (SPEC 4).

LIPM (Kajita et al., 2001): a point mass m at constant height z_com over the ground,
    x'' = omega^2 (x - p) + F_push / m,   omega = sqrt(g / z_com),
x (2,) the CoM's ground projection and p (2,) the ZMP (m). The regulator of SPEC 4 (Englsberger's
capture point with a ZMP-tracking CoM velocity command, as in Kajita 2010):
    xi = x + x' / omega,  p_d = xi + (k_xi / omega)(xi - xi_d),  x'_d = k_f (p - p_d) + k_x (x_d - x),
with p the measured ZMP: the skin's CoP (the cells' centres weighted by their forces, SPEC 4's
formula) or the ankle F/T's. Standing still: x_d = xi_d = 0.

The robot is position-controlled: its CoM velocity follows the command with a first-order lag
(:data:`VELOCITY_LAG_S`), and the ZMP that results, p = x - (x'' - F_push / m) / omega^2, is what the
foot presses into the ground, held inside the cells' centres' box (a foot cannot push its ZMP
past its edge; past it the robot would tip). Each control tick the sole's pressure field for that
ZMP is found on the Winkler layer (a rigid plate on a tensionless foundation carrying m g with
its centre of pressure at p, :func:`plate_depths`), the cells read it (with their noise), and the
measured ZMP feeds the next tick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import estimators as est

__all__ = ["VELOCITY_LAG_S", "plate_depths", "BalanceRun", "simulate_balance"]

# The CoM velocity's tracking lag of the position-controlled robot. A choice (not given): 0.1 s, a
# joint-position servo loop's bandwidth of ~1.6 Hz for the whole body's CoM; it also keeps the
# one-tick feedback from the measured ZMP to the command stable (loop gain k_f / (lag omega^2) = 0.4).
VELOCITY_LAG_S = 0.1


def plate_depths(points: np.ndarray, weights: np.ndarray, stiffness_n_m3: float, force_n: float, cop: np.ndarray,
                 iterations: int = 60) -> np.ndarray:
    """Depths (M,) m of a rigid plate pressed into a tensionless Winkler layer with total force
    ``force_n`` (N) and centre of pressure ``cop`` (2,) m: d_i = max(0, d0 + a x_i + b y_i) at the
    sample points (M, 2) m of area ``weights`` (M,) m^2, (d0, a, b) by Newton's method on the three
    equilibrium equations (piecewise linear; a damped step keeps the residual falling)."""
    pts = np.asarray(points, dtype=float)
    basis = np.column_stack([np.ones(len(pts)), pts])  # (M, 3)
    target = force_n / stiffness_n_m3 * np.array([1.0, cop[0], cop[1]])  # sum w d [1, x, y]

    def residual(c):
        d = np.maximum(basis @ c, 0.0)
        return basis.T @ (weights * d) - target

    full = (basis * weights[:, None]).T @ basis
    c = np.linalg.solve(full, target)  # all in contact
    r = residual(c)
    scale = np.abs(target).max()
    for _ in range(iterations):
        if np.abs(r).max() <= 1e-12 * scale:
            break
        on = (basis @ c) > 0
        jac = (basis[on] * weights[on, None]).T @ basis[on]
        step = np.linalg.lstsq(jac, -r, rcond=None)[0]
        t = 1.0
        while t > 1e-4:
            trial = residual(c + t * step)
            if np.linalg.norm(trial) < np.linalg.norm(r):
                break
            t *= 0.5
        c, r = c + t * step, trial
    return np.maximum(basis @ c, 0.0)


@dataclass(frozen=True)
class BalanceRun:
    """A balance run's time series at the control rate (SI units, world = sole frame).

    t (T,) s; com (T, 2) m; xi (T, 2) m, capture point; zmp (T, 2) m, the true ZMP; zmp_skin and zmp_ft
    (T, 2) m, the measured ones; push (T,) N along x.
    """

    t: np.ndarray
    com: np.ndarray
    xi: np.ndarray
    zmp: np.ndarray
    zmp_skin: np.ndarray
    zmp_ft: np.ndarray
    push: np.ndarray

    def skin_ft_gap(self) -> float:
        """max_t |zmp_skin - zmp_ft| (m)."""
        return float(np.linalg.norm(self.zmp_skin - self.zmp_ft, axis=1).max())

    def zmp_excursion(self) -> float:
        """max_t |zmp_ft| (m): how far the pushes moved the ZMP."""
        return float(np.linalg.norm(self.zmp_ft, axis=1).max())


def simulate_balance(layout, spec, stiffness_n_m3: float, rng: np.random.Generator, subdivisions: int = 3,
                     force_noise_n: float = 0.0, eps_force_n: float = 0.15 * est.G) -> BalanceRun:
    """Run the loop of the module docstring for ``spec`` (:class:`other_sensors.sole.schema.BalanceSpec`)
    on ``layout``'s sole; the cells' noise (N rms per force sensor) comes from ``rng``."""
    from .contact import cell_sampling

    sampling = cell_sampling(layout, subdivisions)
    pts, w = sampling.points.reshape(-1, 2), np.tile(sampling.weights, layout.n_cells)
    n_cells, m_per = sampling.points.shape[:2]
    g, m = est.G, spec.mass_kg
    omega = np.sqrt(g / spec.z_com_m)
    dt = 1.0 / spec.rate_hz
    steps = int(round(spec.duration_s * spec.rate_hz))
    low, high = layout.centres.min(axis=0), layout.centres.max(axis=0)
    x, v, p_meas = np.zeros(2), np.zeros(2), np.zeros(2)
    out = {k: np.zeros((steps, 2)) for k in ("com", "xi", "zmp", "zmp_skin", "zmp_ft")}
    t = np.arange(steps) * dt
    push = np.where((t >= spec.push_start_s) & (t < spec.push_start_s + spec.push_duration_s), spec.push_n, 0.0)
    for k in range(steps):
        f_ext = np.array([push[k], 0.0])
        xi = x + v / omega
        p_d = xi + spec.k_xi / omega * (xi - 0.0)
        v_d = spec.k_f * (p_meas - p_d) + spec.k_x * (0.0 - x)
        a = (v_d - v) / VELOCITY_LAG_S
        p = np.clip(x - (a - f_ext / m) / omega**2, low, high)
        a = omega**2 * (x - p) + f_ext / m
        # what the sole feels: the pressure field of weight m g with its CoP at p
        depth = plate_depths(pts, w, stiffness_n_m3, m * g, p)
        f = (stiffness_n_m3 * depth * w).reshape(n_cells, m_per)
        sensors = f @ sampling.split + rng.normal(0.0, force_noise_n, (n_cells, 3))
        cells = sensors.sum(axis=1)
        on = est.active_cells(cells, eps_force_n)
        p_skin = est.centre_of_pressure(layout.centres[on], cells[on])
        p_ft = f.ravel() @ pts / f.sum()
        p_meas = p_skin if spec.zmp_source == "skin" else p_ft
        for key, value in (("com", x), ("xi", xi), ("zmp", p), ("zmp_skin", p_skin), ("zmp_ft", p_ft)):
            out[key][k] = value
        v = v + a * dt
        x = x + v * dt
    return BalanceRun(t, out["com"], out["xi"], out["zmp"], out["zmp_skin"], out["zmp_ft"], push)
