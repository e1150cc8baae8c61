"""Balance on one sole: the linear inverted pendulum under the capture-point ZMP regulator (SPEC 4).

LIPM (Kajita et al., 2001): a point mass m at constant height z_com over the ground,
    x'' = omega^2 (x - p) + F_push / m,   omega = sqrt(g / z_com),
x (2,) the CoM's ground projection and p (2,) the ZMP (m). The regulator of SPEC 4 (Englsberger's
capture point with a ZMP-tracking CoM velocity command, as in Kajita 2010):
    xi = x + x' / omega,  p_d = xi + (k_xi / omega)(xi - xi_d),  x'_d = k_f (p - p_d) + k_x (x_d - x),
(k_xi a pure number, k_f and k_x in 1/s: the scene's ``k_xi``, ``k_f_per_s``, ``k_x_per_s``)
with p the measured ZMP: the skin's CoP (the cells' centres weighted by their forces, SPEC 4's
formula) or the ankle F/T's. Standing still: x_d = xi_d = 0.

The robot is position-controlled: its CoM velocity follows the command with a first-order lag
(:data:`VELOCITY_LAG_S`), and the ZMP that results, p = x - (x'' - F_push / m) / omega^2, is what the
foot presses into the ground, held inside the sole's outline less a margin (:data:`ZMP_EDGE_MARGIN_M`,
:func:`zmp_limit`): a foot cannot push its ZMP past its edge; where the regulator asks for more, the
ZMP stays at the limit and the rest of the push accelerates the CoM (the foot tips, and the robot
falls if its capture point leaves the limit: with the ZMP at the edge, xi' = omega (xi - p) + F_push /
(m omega) only grows. The run then stops there, :attr:`BalanceRun.fall_time_s`, and its remaining
samples hold the state at the fall). Each control tick the sole's pressure field for that
ZMP is found on the Winkler layer (a rigid plate on a tensionless foundation carrying m g with
its centre of pressure at p, :func:`plate_depths`), the cells read it (with their noise), and the
measured ZMP feeds the next tick.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import estimators as est

__all__ = ["VELOCITY_LAG_S", "ZMP_EDGE_MARGIN_M", "UPRIGHT_TOLERANCE_M", "plate_depths", "zmp_limit", "BalanceRun", "simulate_balance"]

# The CoM velocity's tracking lag of the position-controlled robot. A choice (not given): 0.1 s, a
# joint-position servo loop's bandwidth of ~1.6 Hz for the whole body's CoM; it also keeps the
# one-tick feedback from the measured ZMP to the command stable (loop gain k_f / (lag omega^2) = 0.4).
VELOCITY_LAG_S = 0.1
# How far inside the sole's outline the ZMP can go. A choice (not given): 10 mm. On the Winkler
# layer a rigid sole carrying the robot's weight at its ZMP sinks 6.6 mm at its front edge with the
# ZMP 10 mm inside it (x = 102 mm) and without bound as the ZMP nears the edge (a line contact):
# the last centimetre is the foot rolling onto its edge, not standing. (Until version 2 of the
# balance stage the limit was the cells' centres' box, x <= 95 mm: short of SPEC 4's 10 cm.)
ZMP_EDGE_MARGIN_M = 0.01
# Upright at the end of a run: the CoM back within this distance of the ankle (a choice: 1 cm; a
# run that falls ends metres away, one that recovers within a millimetre or two).
UPRIGHT_TOLERANCE_M = 0.01


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


def zmp_limit(layout, margin_m: float = ZMP_EDGE_MARGIN_M) -> tuple[np.ndarray, np.ndarray]:
    """The region the ZMP can reach: the sole's outline (:meth:`other_sensors.sole.cells.SoleLayout.outline`)
    moved inward by ``margin_m``, as half-planes n_i . p <= c_i: normals (K, 2) and offsets (K,) m."""
    outline = layout.outline()  # counter-clockwise
    edges = np.roll(outline, -1, axis=0) - outline
    normals = np.column_stack([edges[:, 1], -edges[:, 0]]) / np.linalg.norm(edges, axis=1)[:, None]  # outward
    offsets = np.einsum("ij,ij->i", normals, outline) - margin_m
    if not (offsets > 0).all():
        raise ValueError(f"ZMP edge margin = {margin_m} m: leaves no region around the ankle; use a smaller margin")
    return normals, offsets


def _clip_to(p: np.ndarray, normals: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """p moved toward the ankle (the origin, inside the region) onto the region's boundary when outside."""
    reach = normals @ p
    out = reach > offsets
    return p * float(np.min(offsets[out] / reach[out])) if out.any() else p


@dataclass(frozen=True)
class BalanceRun:
    """A balance run's time series at the control rate (SI units, world = sole frame).

    t (T,) s; com (T, 2) m; xi (T, 2) m, capture point; zmp (T, 2) m, the true ZMP; zmp_skin and zmp_ft
    (T, 2) m, the measured ones; push (T,) N along x. fall_time_s: when the capture point left the
    region the ZMP can reach (the robot fell), NaN if it never did.
    """

    t: np.ndarray
    com: np.ndarray
    xi: np.ndarray
    zmp: np.ndarray
    zmp_skin: np.ndarray
    zmp_ft: np.ndarray
    push: np.ndarray
    fall_time_s: float = float("nan")

    def skin_ft_gap(self) -> float:
        """max_t |zmp_skin - zmp_ft| (m)."""
        return float(np.linalg.norm(self.zmp_skin - self.zmp_ft, axis=1).max())

    def zmp_excursion(self) -> float:
        """max_t |zmp_ft| (m): how far the pushes moved the ZMP."""
        return float(np.linalg.norm(self.zmp_ft, axis=1).max())

    def upright(self, tolerance_m: float = UPRIGHT_TOLERANCE_M) -> bool:
        """Whether the robot stood: it never fell and its CoM ends within ``tolerance_m`` of the ankle."""
        return bool(np.isnan(self.fall_time_s) and np.linalg.norm(self.com[-1]) < tolerance_m)


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
    normals, offsets = zmp_limit(layout)
    x, v, p_meas = np.zeros(2), np.zeros(2), np.zeros(2)
    out = {k: np.zeros((steps, 2)) for k in ("com", "xi", "zmp", "zmp_skin", "zmp_ft")}
    t = np.arange(steps) * dt
    push = np.where((t >= spec.push_start_s) & (t < spec.push_start_s + spec.push_duration_s), spec.push_n, 0.0)
    for k in range(steps):
        f_ext = np.array([push[k], 0.0])
        xi = x + v / omega
        p_d = xi + spec.k_xi / omega * (xi - 0.0)
        v_d = spec.k_f_per_s * (p_meas - p_d) + spec.k_x_per_s * (0.0 - x)
        a = (v_d - v) / VELOCITY_LAG_S
        p = _clip_to(x - (a - f_ext / m) / omega**2, normals, offsets)
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
        if (normals @ xi > offsets).any():  # the capture point is past the ZMP's reach: the robot falls
            fall = float(t[k])
            for series in out.values():
                series[k + 1:] = series[k]
            break
        v = v + a * dt
        x = x + v * dt
    else:
        fall = float("nan")
    return BalanceRun(t, out["com"], out["xi"], out["zmp"], out["zmp_skin"], out["zmp_ft"], push, fall)
