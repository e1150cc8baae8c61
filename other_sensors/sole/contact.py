"""Foot-terrain contact through an elastic (Winkler) foundation: cell forces, proximity, ankle wrench (SPEC 4).

Kinematics: the foot is rigid; its pose is the sole frame's origin (the ankle's projection on the
sole, :mod:`other_sensors.sole.cells`) in the world, t (3,) m, and its roll, pitch, yaw (rad),
R = Rz(yaw) Ry(pitch) Rx(roll). A point q (2,) of the sole is at R [q, 0] + t in the world.

Pressure: the skin and its foam are a Winkler layer (an elastic foundation: independent springs
per unit area, Johnson, *Contact Mechanics*, 1985, sec. 5.9), p = k d, with d = max(0, h(x, y) -
z) the terrain's vertical overlap of the sole point at (x, y, z) and k (N/m^3) the foundation
modulus. A simplification: no spreading of load between neighbouring points (a layer thin against
the contact's size), normal pressure only (no friction), vertical rather than normal overlap (for
tilts under 10 deg they differ by under 1.5 %).

Integration: each cell's area is sampled by :func:`other_sensors.sole.cells.cell_quadrature`; the
force at each sample is split between the cell's three force sensors by the sample's barycentric
coordinates in the sensors' triangle, which is how a rigid cover on three point supports shares a
load (statics), so the three readings carry the cell's force and its moment exactly. The ankle
force/torque sensor reads the wrench of the same pressure field, so sensor moments and the F/T
moment agree by construction. Forces are in the sole frame (z along the sole's normal). With
normal forces only, the ankle's height above the sole changes no moment about horizontal axes.

Proximity: each cell's pre-touch sensor reads the vertical gap from its centre to the terrain.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .cells import SoleLayout, cell_quadrature
from .terrain import terrain_height

__all__ = ["rotation", "FootPose", "SoleContact", "barycentric_weights", "cell_sampling", "sole_contact", "height_for_load"]


def rotation(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), (3, 3); angles rad."""
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    return rz @ ry @ rx


@dataclass(frozen=True)
class FootPose:
    """The sole frame in the world: position (3,) m, roll, pitch, yaw rad."""

    position: tuple[float, float, float]
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0

    def matrix(self) -> np.ndarray:
        return rotation(self.roll, self.pitch, self.yaw)

    def to_world(self, q: np.ndarray) -> np.ndarray:
        """Sole points q (..., 2) m -> world points (..., 3) m."""
        q = np.asarray(q, dtype=float)
        q3 = np.concatenate([q, np.zeros(q.shape[:-1] + (1,))], axis=-1)
        return q3 @ self.matrix().T + np.asarray(self.position)

    def with_height(self, z: float) -> "FootPose":
        return FootPose((self.position[0], self.position[1], float(z)), self.roll, self.pitch, self.yaw)


@dataclass(frozen=True)
class SoleContact:
    """What one sole feels (sole frame, SI units).

    sensor_forces (N, 3) N: each cell's three normal-force readings. cell_forces (N,) N: their sums.
    wrench (6,): the ankle F/T reading (Fx, Fy, Fz N, Mx, My, Mz N m) about the sole frame's origin.
    gaps (N,) m: each cell's proximity reading (the least vertical gap from its face to the terrain, 0 in contact, inf with
    no terrain below). pose: the foot's pose. ankle_wrench (6,) or None: what the ankle F/T reads at its own
    height when the contact carries friction (a landing, :mod:`other_sensors.sole.landing`); None when the
    contact is normal pressure only, where the ankle's height changes no moment and ``wrench`` is the reading.
    """

    sensor_forces: np.ndarray
    cell_forces: np.ndarray
    wrench: np.ndarray
    gaps: np.ndarray
    pose: FootPose
    ankle_wrench: np.ndarray | None = None

    @property
    def ankle_moment(self) -> float:
        """M_s (N m): the horizontal ankle moment's magnitude, sqrt(Mx^2 + My^2) (SPEC 4), at the ankle F/T."""
        w = self.wrench if self.ankle_wrench is None else self.ankle_wrench
        return float(np.hypot(w[3], w[4]))


def barycentric_weights(points: np.ndarray, triangle: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (M, 3) of points (M, 2) in the triangle (3, 2): each row sums to 1
    and sum_k w_k triangle_k = point (negative outside the triangle)."""
    a = np.vstack([np.asarray(triangle, dtype=float).T, np.ones(3)])  # (3, 3)
    b = np.vstack([np.asarray(points, dtype=float).T, np.ones(len(points))])
    return np.linalg.solve(a, b).T


class CellSampling:
    """The layout's quadrature points in the sole frame and their split between sensors."""

    def __init__(self, layout: SoleLayout, subdivisions: int):
        local, self.weights = cell_quadrature(layout.side, subdivisions)  # (M, 2), (M,)
        c, s = np.cos(layout.yaw)[:, None], np.sin(layout.yaw)[:, None]
        self.points = np.stack([layout.centres[:, None, 0] + c * local[:, 0] - s * local[:, 1],
                                layout.centres[:, None, 1] + s * local[:, 0] + c * local[:, 1]], axis=-1)  # (N, M, 2)
        # the split is the same in every cell's own frame (the sensors turn with the cell)
        self.split = barycentric_weights(local, layout.sensors[0] - layout.centres[0])  # (M, 3)


_SAMPLING_MEMO: dict = {}


def cell_sampling(layout: SoleLayout, subdivisions: int) -> CellSampling:
    key = (id(layout), subdivisions)
    if key not in _SAMPLING_MEMO:
        if len(_SAMPLING_MEMO) > 8:
            _SAMPLING_MEMO.clear()
        _SAMPLING_MEMO[key] = (layout, CellSampling(layout, subdivisions))  # keep the layout alive with its id
    return _SAMPLING_MEMO[key][1]


def _sample_clearance(sampling: CellSampling, pose: FootPose, primitives) -> np.ndarray:
    """Height (N, M) m of each quadrature point above the terrain below it (negative: sunk in)."""
    world = pose.to_world(sampling.points)  # (N, M, 3)
    h = terrain_height(primitives, world[..., :2].reshape(-1, 2)).reshape(world.shape[:2])
    return world[..., 2] - h


def _sample_forces(sampling: CellSampling, pose: FootPose, primitives, stiffness: float, clearance: np.ndarray | None = None) -> np.ndarray:
    """Normal force (N, M) N at each quadrature point."""
    clearance = _sample_clearance(sampling, pose, primitives) if clearance is None else clearance
    return stiffness * np.maximum(-clearance, 0.0) * sampling.weights


def sole_contact(layout: SoleLayout, pose: FootPose, primitives, stiffness_n_m3: float, subdivisions: int = 6) -> SoleContact:
    """The sole's cell readings, ankle wrench and proximity for a foot pose over the terrain.

    layout: the cells. pose: the foot. primitives: :mod:`other_sensors.sole.terrain` primitives.
    stiffness_n_m3: the Winkler modulus k (N/m^3). subdivisions: quadrature refinement per cell.
    """
    if not stiffness_n_m3 > 0:
        raise ValueError(f"sensor.foundation.stiffness_n_m3 = {stiffness_n_m3}: must be > 0")
    sampling = cell_sampling(layout, subdivisions)
    clearance = _sample_clearance(sampling, pose, primitives)  # (N, M)
    f = _sample_forces(sampling, pose, primitives, stiffness_n_m3, clearance)  # (N, M)
    sensor_forces = f @ sampling.split  # (N, 3)
    x, y = sampling.points[..., 0], sampling.points[..., 1]
    fz = float(f.sum())
    wrench = np.array([0.0, 0.0, fz, float((y * f).sum()), float(-(x * f).sum()), 0.0])
    # proximity: the nearest terrain under the cell's face. The sensor's field of view is taken as the
    # cell's footprint looking straight down (a simplification of its cone); read at the centre alone,
    # a cell half over a small obstacle touched it without seeing it, and the pre-touch polygon came
    # out smaller than the support polygon
    gaps = np.maximum(clearance.min(axis=1), 0.0)
    return SoleContact(sensor_forces, sensor_forces.sum(axis=1), wrench, gaps, pose)


def height_for_load(layout: SoleLayout, pose: FootPose, primitives, stiffness_n_m3: float, load_n: float,
                    subdivisions: int = 6) -> float:
    """The foot height z (m) at which the terrain carries ``load_n`` (N) with the pose's x, y and
    angles held: the foot is lowered onto the terrain until its normal force is the load (monotone
    in z, solved by Brent's method)."""
    from scipy.optimize import brentq

    if not load_n > 0:
        raise ValueError(f"sensor.foot.load_n = {load_n}: must be > 0")
    sampling = cell_sampling(layout, subdivisions)
    probe = pose.with_height(0.0).to_world(sampling.points)
    h = terrain_height(primitives, probe[..., :2].reshape(-1, 2))
    if not np.isfinite(h).any():
        raise ValueError("sensor.terrain: no terrain under the sole; add a flat ground or move sensor.foot")
    touch = float(np.max(h - probe[..., 2].ravel()))  # the height of first contact

    def excess(z: float) -> float:
        return float(_sample_forces(sampling, pose.with_height(z), primitives, stiffness_n_m3).sum()) - load_n

    step = 1e-5
    while excess(touch - step) < 0.0:
        step *= 2.0
        if step > 1.0:
            raise ValueError(f"sensor.foot.load_n = {load_n}: the terrain cannot carry it within 1 m of sink; "
                             "raise sensor.foundation.stiffness_n_m3 or lower the load")
    return float(brentq(excess, touch - step, touch, xtol=1e-12, rtol=1e-12))
