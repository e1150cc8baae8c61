"""What the plantar skin tells the controller: centre of pressure, active cells, contact area,
support and pre-touch polygons, obstacle width (SPEC 4). Pure vectorised functions, SI units.

- CoP: p = sum_j p_j F_jz / sum_j F_jz over the cells of one sole (:func:`centre_of_pressure`);
  p_j is the cell's centre (SPEC 4, ``by="cell"``) or, finer, each force sensor's position with its
  own reading (``by="sensor"``: a cell's three readings locate its load inside the cell, so this
  equals the pressure field's CoP exactly, :mod:`other_sensors.sole.contact`).
- Active cells: F_jz > eps_F; contact area A = k A_cell for k active cells.
- Support polygon: the convex hull of every active hexagon's corners in the sole frame; in double
  support both soles' corners are taken to the world and one hull is made. The pre-touch polygon is
  made the same way from the cells whose proximity gap is under the sensor's range.
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["G", "centre_of_pressure", "sole_cop", "active_cells", "contact_area", "convex_hull", "polygon_area",
           "support_polygon", "pretouch_polygon", "double_support_polygon", "combined_cop", "bounding_box", "sidestep"]

G = 9.81  # m/s^2: eps_F is given in kg (SPEC 4: 0.15 kg)


def centre_of_pressure(points: np.ndarray, forces: np.ndarray) -> np.ndarray:
    """sum_j p_j F_j / sum_j F_j. points (..., 2) m, forces (...) N (same leading shape).
    Returns (2,) m; NaN when the total force is not positive (no contact)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    f = np.asarray(forces, dtype=float).reshape(-1)
    if len(p) != len(f):
        raise ValueError(f"centre_of_pressure: {len(p)} points but {len(f)} forces")
    total = f.sum()
    return f @ p / total if total > 0 else np.full(2, np.nan)


def sole_cop(layout, sensor_forces: np.ndarray, by: str = "sensor") -> np.ndarray:
    """One sole's CoP (2,) m in the sole frame from its readings sensor_forces (N, 3) N: over the
    force sensors' positions (``by="sensor"``) or the cells' centres with the cells' sums (``"cell"``)."""
    sensor_forces = np.asarray(sensor_forces, dtype=float)
    if by == "sensor":
        return centre_of_pressure(layout.sensors, sensor_forces)
    if by == "cell":
        return centre_of_pressure(layout.centres, sensor_forces.sum(axis=-1))
    raise ValueError(f'by = "{by}": choose one of: sensor, cell')


def active_cells(cell_forces: np.ndarray, eps_force_n: float) -> np.ndarray:
    """Cells in contact, (N,) bool: F_jz > eps_F (N)."""
    return np.asarray(cell_forces) > eps_force_n


def contact_area(active: np.ndarray, cell_area_m2: float) -> float:
    """A = k A_cell (m^2) for k active cells."""
    return float(np.count_nonzero(active)) * cell_area_m2


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Hull vertices (K, 2) counter-clockwise of points (M, 2), no collinear ones; (0, 2) for fewer
    than 3 points or points on a line (no area). Andrew's monotone chain, compiled: Qhull
    (scipy.spatial.ConvexHull) costs ~75 us a call, most of the 250 Hz tick's budget for 4-5 hulls."""
    points = np.asarray(points, dtype=float).reshape(-1, 2)
    if len(points) < 3:
        return np.zeros((0, 2))
    ordered = points[np.lexsort((points[:, 1], points[:, 0]))]
    # collinear within round-off (the hexagons' edges line up along the outline) counts as collinear
    tol = 1e-10 * float(np.ptp(ordered, axis=0).max()) ** 2
    hull = ordered[_monotone_chain(ordered, tol)]
    return hull if len(hull) >= 3 else np.zeros((0, 2))


@njit(cache=True)
def _monotone_chain(p, tol):
    """Indices of the hull of points p (M, 2) sorted by x then y, counter-clockwise; turns with a
    cross product <= tol are dropped."""
    n = len(p)
    idx = np.empty(2 * n, dtype=np.int64)
    k = 0
    for i in range(n):  # lower hull
        while k >= 2 and ((p[idx[k - 1], 0] - p[idx[k - 2], 0]) * (p[i, 1] - p[idx[k - 2], 1])
                          - (p[idx[k - 1], 1] - p[idx[k - 2], 1]) * (p[i, 0] - p[idx[k - 2], 0])) <= tol:
            k -= 1
        idx[k] = i
        k += 1
    lower = k + 1
    for i in range(n - 2, -1, -1):  # upper hull
        while k >= lower and ((p[idx[k - 1], 0] - p[idx[k - 2], 0]) * (p[i, 1] - p[idx[k - 2], 1])
                              - (p[idx[k - 1], 1] - p[idx[k - 2], 1]) * (p[i, 0] - p[idx[k - 2], 0])) <= tol:
            k -= 1
        idx[k] = i
        k += 1
    return idx[:k - 1]  # the last point is the first again


def polygon_area(polygon: np.ndarray) -> float:
    """Area (m^2) of a simple polygon (K, 2) by the shoelace formula; 0 for fewer than 3 vertices."""
    p = np.asarray(polygon, dtype=float)
    if len(p) < 3:
        return 0.0
    x, y = p[:, 0], p[:, 1]
    return float(0.5 * abs(x @ np.roll(y, -1) - y @ np.roll(x, -1)))


def support_polygon(corners: np.ndarray, active: np.ndarray) -> np.ndarray:
    """The hull (K, 2) m of the active hexagons' corners. corners (N, 6, 2) m, active (N,) bool."""
    return convex_hull(np.asarray(corners)[np.asarray(active, dtype=bool)].reshape(-1, 2))


def pretouch_polygon(corners: np.ndarray, gaps: np.ndarray, range_m: float) -> np.ndarray:
    """The hull (K, 2) m of the corners of the cells whose proximity gap (N,) m is under range_m."""
    return support_polygon(corners, np.asarray(gaps) < range_m)


def double_support_polygon(corners_left, active_left, pose_left, corners_right, active_right, pose_right) -> np.ndarray:
    """One hull (K, 2) m in the world's ground plane of both soles' active corners; each pose is a
    :class:`other_sensors.sole.contact.FootPose` (its x, y of the world points are kept)."""
    pts = [pose.to_world(np.asarray(c)[np.asarray(a, dtype=bool)].reshape(-1, 2))[:, :2]
           for c, a, pose in ((corners_left, active_left, pose_left), (corners_right, active_right, pose_right))]
    return convex_hull(np.concatenate(pts))


def combined_cop(cops_world: np.ndarray, totals: np.ndarray) -> np.ndarray:
    """The CoP (2,) m of both soles together from each sole's CoP in the world (S, 2) m and its total
    normal force (S,) N (soles without contact, NaN CoP and zero force, drop out)."""
    cops, totals = np.asarray(cops_world, dtype=float), np.asarray(totals, dtype=float)
    keep = totals > 0
    return centre_of_pressure(cops[keep], totals[keep])


def bounding_box(polygon: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(low (2,), high (2,)) m of a polygon (K, 2); NaNs when it is empty."""
    p = np.asarray(polygon, dtype=float)
    if len(p) == 0:
        return np.full(2, np.nan), np.full(2, np.nan)
    return p.min(axis=0), p.max(axis=0)


def sidestep(polygon: np.ndarray, clearance_m: float) -> float:
    """The lateral (sole y) re-plan (m) that clears an obstacle whose contact polygon (K, 2) m is
    given: its bounding box's width in y plus the clearance, away from the box's centre (to +y, the
    left, when the box is centred: a choice). 0 for an empty polygon."""
    low, high = bounding_box(polygon)
    if not np.isfinite(low).all():
        return 0.0
    direction = -1.0 if (low[1] + high[1]) / 2.0 > 1e-9 else 1.0
    return float(direction * ((high[1] - low[1]) + clearance_m))
