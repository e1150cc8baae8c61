"""Terrain under the foot: a height field z = h(x, y) built from primitives (SI units, world frame).

World frame: z up, the ground plane usually at z = 0. Each primitive is a solid whose top surface
is a height function, -inf where the primitive is absent; the terrain is their union (the pointwise
maximum). Primitives: an infinite flat plane, a box (a flat top of given height over a rectangle,
possibly yawed), a sphere (its upper cap), a step (a flat half-plane) and a sampled height field
(bilinear, absent outside its grid).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Flat", "Box", "Sphere", "Step", "HeightField", "terrain_height"]


@dataclass(frozen=True)
class Flat:
    """The plane z = top (m) everywhere."""

    top: float

    def height(self, xy: np.ndarray) -> np.ndarray:
        return np.full(len(xy), self.top)


@dataclass(frozen=True)
class Box:
    """A box with its top at z = top (m) over the rectangle of centre (2,) m, size (2,) m, yaw rad."""

    centre: tuple[float, float]
    size: tuple[float, float]
    top: float
    yaw: float = 0.0

    def height(self, xy: np.ndarray) -> np.ndarray:
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        d = xy - np.asarray(self.centre)
        u, v = c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1]
        inside = (np.abs(u) <= self.size[0] / 2.0) & (np.abs(v) <= self.size[1] / 2.0)
        return np.where(inside, self.top, -np.inf)


@dataclass(frozen=True)
class Sphere:
    """A sphere of centre (3,) m and radius m: its upper cap z = c_z + sqrt(r^2 - rho^2)."""

    centre: tuple[float, float, float]
    radius: float

    def height(self, xy: np.ndarray) -> np.ndarray:
        rho2 = np.sum((xy - np.asarray(self.centre[:2])) ** 2, axis=1)
        r2 = self.radius * self.radius  # a product: a float power past 1e308 raises OverflowError, a product is inf
        inside = rho2 <= r2
        return np.where(inside, self.centre[2] + np.sqrt(np.maximum(r2 - rho2, 0.0)), -np.inf)


@dataclass(frozen=True)
class Step:
    """A flat half-plane at z = top (m): the points whose offset from ``point`` (2,) m along the unit
    direction ``direction`` (rad, in the ground plane) is >= 0."""

    point: tuple[float, float]
    direction: float
    top: float

    def height(self, xy: np.ndarray) -> np.ndarray:
        along = (xy - np.asarray(self.point)) @ np.array([np.cos(self.direction), np.sin(self.direction)])
        return np.where(along >= 0.0, self.top, -np.inf)


@dataclass(frozen=True)
class HeightField:
    """Heights (ny, nx) m on a grid from ``origin`` (2,) m at ``spacing`` m (row j: y, column i: x);
    bilinear inside the grid, absent outside."""

    origin: tuple[float, float]
    spacing: float
    heights: np.ndarray

    def height(self, xy: np.ndarray) -> np.ndarray:
        h = np.asarray(self.heights, dtype=float)
        ny, nx = h.shape
        gx = (xy[:, 0] - self.origin[0]) / self.spacing
        gy = (xy[:, 1] - self.origin[1]) / self.spacing
        inside = (gx >= 0) & (gx <= nx - 1) & (gy >= 0) & (gy <= ny - 1)
        i = np.clip(np.floor(gx).astype(int), 0, max(nx - 2, 0))
        j = np.clip(np.floor(gy).astype(int), 0, max(ny - 2, 0))
        fx, fy = np.clip(gx - i, 0, 1), np.clip(gy - j, 0, 1)
        i1, j1 = np.minimum(i + 1, nx - 1), np.minimum(j + 1, ny - 1)
        z = (h[j, i] * (1 - fx) * (1 - fy) + h[j, i1] * fx * (1 - fy) + h[j1, i] * (1 - fx) * fy + h[j1, i1] * fx * fy)
        return np.where(inside, z, -np.inf)


def terrain_height(primitives, xy: np.ndarray) -> np.ndarray:
    """Terrain height (M,) m at the points xy (M, 2) m: the union (maximum) of the primitives'
    heights; -inf where there is no terrain at all."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    z = np.full(len(xy), -np.inf)
    for p in primitives:
        z = np.maximum(z, p.height(xy))
    return z
