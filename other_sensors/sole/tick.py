"""The plantar skin's estimators for one control tick, compiled: the 250 Hz path (SPEC 4).

SPEC 4's cells report at up to 250 Hz; each tick the controller needs, per sole, the centre of
pressure p = sum_j p_j F_jz / sum_j F_jz, the active cells (F_jz > eps_F), the contact area k A_cell,
the support polygon (hull of the active hexagons' corners) and the pre-touch polygon (the same from
proximity), both feasibility rules (M_s >= eps_t, A_p / A_s <= eps_A) and the sidestep; in double
support, one hull of both soles in the world and the combined CoP. The formulas are those of
:mod:`other_sensors.sole.estimators` and :mod:`other_sensors.sole.feasibility` (the reference,
kept readable); this module computes the same numbers in one compiled call per sole, because at
42 cells the reference's cost is Python and NumPy call overhead (cProfile: ~270 us a tick for both
soles, of which the hulls' sorting, ``np.roll`` in the shoelace and the rotation matrices of the
foot poses took most), not arithmetic.

What makes it cheap, besides numba:
- the hull's sort is done once: every corner of the layout is sorted by (x, y) at construction,
  and the active corners are a subsequence of that order, already sorted (Andrew's monotone chain
  then runs in O(n) on them, with the reference's collinearity tolerance);
- the double-support hull is the hull of both soles' hulls taken to the world (a rigid motion maps
  a hull onto the hull of the moved points), ~20 points sorted by insertion instead of ~500;
- :func:`estimate_series` runs a whole recording (T ticks) in one call (vectorised over time).

Results equal the reference's: the active cells and the decisions exactly (the cell sums are formed
in the same order; an A_p / A_s that ties eps_A to round-off is a tie on both paths,
:data:`other_sensors.sole.feasibility.AREA_TIE_RTOL`), CoPs and areas to round-off (sums in another order); ``tests/test_sole_tick.py``
compares both on random loads.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

from .estimators import G
from .feasibility import AREA_TIE_RTOL, CLEARANCE_M, EPS_AREA, EPS_FORCE_KG, EPS_TORQUE_NM

__all__ = ["SoleEstimate", "SkinEstimator", "double_support", "SeriesEstimate", "estimate_series"]

# scalars written by the kernel, in this order
_SCALARS = ("cop_x", "cop_y", "cop_cells_x", "cop_cells_y", "force_n", "contact_area", "polygon_area", "pretouch_area",
            "ankle_moment", "ft_replan", "skin_replan", "sidestep", "box_low_x", "box_low_y", "box_high_x", "box_high_y")
_NS = len(_SCALARS)


class SoleEstimate(NamedTuple):
    """One sole at one tick (sole frame, SI units), as :func:`other_sensors.sole.feasibility.assess_step`.

    cop (2,) m: over the force sensors; cop_cells (2,) m: over the cells' centres (SPEC 4's formula);
    NaN without contact. force_n: the cells' total normal force. active (N,) bool. contact_area m^2.
    polygon (K, 2), pretouch (K', 2) m: counter-clockwise hulls; their areas m^2 (A_p, and the
    pre-touch one). ankle_moment: M_s N m. ft_replan, skin_replan: the rules. sidestep m: the
    re-plan's lateral step when either rule re-plans, else 0.
    """

    cop: np.ndarray
    cop_cells: np.ndarray
    force_n: float
    active: np.ndarray
    contact_area: float
    polygon: np.ndarray
    polygon_area: float
    pretouch: np.ndarray
    pretouch_area: float
    ankle_moment: float
    ft_replan: bool
    skin_replan: bool
    sidestep: float


@njit(cache=True, inline="always")
def _cross(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


@njit(cache=True)
def _chain(px, py, n, tol, out):
    """Andrew's monotone chain on points (px[i], py[i]), i < n, sorted by x then y; the hull's
    vertices counter-clockwise go to out (rows), turns with a cross product <= tol dropped (as
    :func:`other_sensors.sole.estimators._monotone_chain`). Returns the vertex count (0 when
    fewer than 3)."""
    if n < 3:
        return 0
    idx = np.empty(2 * n, dtype=np.int64)
    k = 0
    for i in range(n):
        while k >= 2 and _cross(px[idx[k - 2]], py[idx[k - 2]], px[idx[k - 1]], py[idx[k - 1]], px[i], py[i]) <= tol:
            k -= 1
        idx[k] = i
        k += 1
    lower = k + 1
    for i in range(n - 2, -1, -1):
        while k >= lower and _cross(px[idx[k - 2]], py[idx[k - 2]], px[idx[k - 1]], py[idx[k - 1]], px[i], py[i]) <= tol:
            k -= 1
        idx[k] = i
        k += 1
    m = k - 1
    if m < 3:
        return 0
    for j in range(m):
        out[j, 0] = px[idx[j]]
        out[j, 1] = py[idx[j]]
    return m


@njit(cache=True)
def _subset_hull(sorted_corners, corner_cell, mask, px, py, out):
    """Hull (into out) of the sorted corners whose cell is in mask: the subsequence stays sorted.
    The tolerance is the reference's, 1e-10 * (largest extent of the points)^2."""
    n = 0
    xmin, xmax, ymin, ymax = np.inf, -np.inf, np.inf, -np.inf
    for i in range(len(corner_cell)):
        if mask[corner_cell[i]]:
            x, y = sorted_corners[i, 0], sorted_corners[i, 1]
            px[n] = x
            py[n] = y
            n += 1
            xmin, xmax, ymin, ymax = min(xmin, x), max(xmax, x), min(ymin, y), max(ymax, y)
    if n < 3:
        return 0
    ext = max(xmax - xmin, ymax - ymin)
    return _chain(px, py, n, 1e-10 * ext * ext, out)


@njit(cache=True)
def _area(poly, m):
    """Shoelace area of the first m rows of poly; 0 for fewer than 3."""
    if m < 3:
        return 0.0
    s = 0.0
    for i in range(m):
        j = i + 1 if i + 1 < m else 0
        s += poly[i, 0] * poly[j, 1] - poly[i, 1] * poly[j, 0]
    return 0.5 * abs(s)


@njit(cache=True)
def _sole(forces, gaps, wrench, sensors, centres, sorted_corners, corner_cell, params, active, hull, pre, px, py, scalars):
    """One sole, one tick. params: eps_force N, range m, eps_torque N m, eps_area, sole area m^2,
    cell area m^2, clearance m. Writes active (N,), hull and pre (rows), scalars (_SCALARS order);
    returns (hull vertices, pre-touch vertices)."""
    eps_force, range_m, eps_torque, eps_area, sole_area, cell_area, clearance = (
        params[0], params[1], params[2], params[3], params[4], params[5], params[6])
    n = forces.shape[0]
    sx = sy = cx = cy = total = 0.0
    n_active = 0
    near = np.empty(n, dtype=np.bool_)
    for j in range(n):
        cell = (forces[j, 0] + forces[j, 1]) + forces[j, 2]  # as forces.sum(axis=1): the same rounding
        for s in range(3):
            sx += forces[j, s] * sensors[j, s, 0]
            sy += forces[j, s] * sensors[j, s, 1]
        cx += cell * centres[j, 0]
        cy += cell * centres[j, 1]
        total += cell
        active[j] = cell > eps_force
        n_active += active[j]
        near[j] = gaps[j] < range_m
    if total > 0:
        scalars[0], scalars[1], scalars[2], scalars[3] = sx / total, sy / total, cx / total, cy / total
    else:
        scalars[0] = scalars[1] = scalars[2] = scalars[3] = np.nan
    scalars[4] = total
    scalars[5] = n_active * cell_area
    m = _subset_hull(sorted_corners, corner_cell, active, px, py, hull)
    a_p = _area(hull, m)
    q = _subset_hull(sorted_corners, corner_cell, near, px, py, pre)
    scalars[6] = a_p
    scalars[7] = _area(pre, q)
    moment = np.hypot(wrench[3], wrench[4])
    ft = moment >= eps_torque
    skin = a_p / sole_area <= eps_area * (1.0 + AREA_TIE_RTOL)  # feasibility.skin_rule, ties included
    scalars[8] = moment
    scalars[9] = 1.0 if ft else 0.0
    scalars[10] = 1.0 if skin else 0.0
    step = 0.0
    if m > 0:
        lx, ly, hx, hy = np.inf, np.inf, -np.inf, -np.inf
        for i in range(m):
            lx, hx = min(lx, hull[i, 0]), max(hx, hull[i, 0])
            ly, hy = min(ly, hull[i, 1]), max(hy, hull[i, 1])
        scalars[12], scalars[13], scalars[14], scalars[15] = lx, ly, hx, hy
        if ft or skin:  # estimators.sidestep: away from the box's centre, to +y when centred
            direction = -1.0 if (ly + hy) / 2.0 > 1e-9 else 1.0
            step = direction * ((hy - ly) + clearance)
    else:
        scalars[12] = scalars[13] = scalars[14] = scalars[15] = np.nan
    scalars[11] = step
    return m, q


@njit(cache=True)
def _series(forces, gaps, wrench, sensors, centres, sorted_corners, corner_cell, params, active, hulls, counts, scalars):
    """_sole over T ticks: forces (T, N, 3), gaps (T, N), wrench (T, 6) -> active (T, N), hulls
    (T, K, 2) with counts (T, 2) (support, pre-touch), scalars (T, _NS)."""
    n_pts = len(corner_cell)
    px, py = np.empty(n_pts), np.empty(n_pts)
    pre = np.empty((n_pts + 1, 2))
    for t in range(forces.shape[0]):
        m, q = _sole(forces[t], gaps[t], wrench[t], sensors, centres, sorted_corners, corner_cell, params,
                     active[t], hulls[t], pre, px, py, scalars[t])
        counts[t, 0], counts[t, 1] = m, q


@njit(cache=True)
def _double(hull_l, pose_l, cop_l, force_l, hull_r, pose_r, cop_r, force_r, out, cop):
    """Both soles' hulls (sole frame) and CoPs to the world by their poses (x, y, z, roll, pitch,
    yaw), one hull of the lot (into out; its vertex count returned) and the force-weighted CoP."""
    n = len(hull_l) + len(hull_r)
    px, py = np.empty(n), np.empty(n)
    sx = sy = total = 0.0
    k = 0
    for side in range(2):
        hull, pose, c, f = (hull_l, pose_l, cop_l, force_l) if side == 0 else (hull_r, pose_r, cop_r, force_r)
        cr, sr, cp, sp = np.cos(pose[3]), np.sin(pose[3]), np.cos(pose[4]), np.sin(pose[4])
        cyw, syw = np.cos(pose[5]), np.sin(pose[5])
        # the first two rows, first two columns of R = Rz(yaw) Ry(pitch) Rx(roll) (contact.rotation)
        r00, r01 = cyw * cp, cyw * sp * sr - syw * cr
        r10, r11 = syw * cp, syw * sp * sr + cyw * cr
        for i in range(len(hull)):
            x, y = r00 * hull[i, 0] + r01 * hull[i, 1] + pose[0], r10 * hull[i, 0] + r11 * hull[i, 1] + pose[1]
            j = k  # insertion sort by (x, y): ~20 points
            while j > 0 and (px[j - 1] > x or (px[j - 1] == x and py[j - 1] > y)):
                px[j], py[j] = px[j - 1], py[j - 1]
                j -= 1
            px[j], py[j] = x, y
            k += 1
        if f > 0:
            sx += f * (r00 * c[0] + r01 * c[1] + pose[0])
            sy += f * (r10 * c[0] + r11 * c[1] + pose[1])
            total += f
    if total > 0:
        cop[0], cop[1] = sx / total, sy / total
    else:
        cop[0] = cop[1] = np.nan
    if k < 3:
        return 0
    ext = max(px[k - 1] - px[0], py[:k].max() - py[:k].min())
    return _chain(px, py, k, 1e-10 * ext * ext, out)


class SkinEstimator:
    """The per-tick estimators of one sole's layout (a thin wrapper of the compiled kernel, which
    holds the formulas; the thresholds are SPEC 4's by default).

    layout: :class:`other_sensors.sole.cells.SoleLayout`. eps_force_n N, proximity_range_m m,
    eps_torque_nm N m, eps_area, clearance_m m: as :func:`other_sensors.sole.feasibility.assess_step`.
    """

    def __init__(self, layout, eps_force_n: float = EPS_FORCE_KG * G, proximity_range_m: float = 0.03,
                 eps_torque_nm: float = EPS_TORQUE_NM, eps_area: float = EPS_AREA, clearance_m: float = CLEARANCE_M):
        self.layout = layout
        corners = np.ascontiguousarray(layout.corners, dtype=float).reshape(-1, 2)
        order = np.lexsort((corners[:, 1], corners[:, 0]))  # x, then y: the reference hull's order
        self._sorted = np.ascontiguousarray(corners[order])
        self._cell = (order // layout.corners.shape[1]).astype(np.int64)
        self._sensors = np.ascontiguousarray(layout.sensors, dtype=float)
        self._centres = np.ascontiguousarray(layout.centres, dtype=float)
        self._params = np.array([eps_force_n, proximity_range_m, eps_torque_nm, eps_area, layout.sole_area(),
                                 layout.cell_area, clearance_m], dtype=float)
        n_pts = len(corners)
        self._px, self._py = np.empty(n_pts), np.empty(n_pts)
        self._hull, self._pre = np.empty((n_pts + 1, 2)), np.empty((n_pts + 1, 2))
        self._scalars = np.empty(_NS)

    def __call__(self, sensor_forces: np.ndarray, gaps: np.ndarray, wrench: np.ndarray) -> SoleEstimate:
        """sensor_forces (N, 3) N, gaps (N,) m, wrench (6,) (Fx, Fy, Fz N, Mx, My, Mz N m) of one tick."""
        forces = np.ascontiguousarray(sensor_forces, dtype=float)
        if forces.shape != self._sensors.shape[:2]:
            raise ValueError(f"sensor_forces has shape {forces.shape}; this layout reads {self._sensors.shape[:2]}")
        active = np.empty(len(forces), dtype=np.bool_)
        s = self._scalars
        m, q = _sole(forces, np.ascontiguousarray(gaps, dtype=float), np.ascontiguousarray(wrench, dtype=float), self._sensors,
                     self._centres, self._sorted, self._cell, self._params, active, self._hull, self._pre, self._px, self._py, s)
        return SoleEstimate(s[0:2].copy(), s[2:4].copy(), float(s[4]), active, float(s[5]), self._hull[:m].copy(), float(s[6]),
                            self._pre[:q].copy(), float(s[7]), float(s[8]), bool(s[9]), bool(s[10]), float(s[11]))


def _pose_vector(pose) -> np.ndarray:
    return np.array([*pose.position, pose.roll, pose.pitch, pose.yaw], dtype=float)


def double_support(left: SoleEstimate, pose_left, right: SoleEstimate, pose_right) -> tuple[np.ndarray, np.ndarray]:
    """The double-support polygon (K, 2) m (one hull in the world's ground plane, as
    :func:`other_sensors.sole.estimators.double_support_polygon`) and the combined CoP (2,) m (as
    :func:`other_sensors.sole.estimators.combined_cop`) from both soles' estimates and their
    :class:`other_sensors.sole.contact.FootPose`."""
    out, cop = np.empty((len(left.polygon) + len(right.polygon) + 1, 2)), np.empty(2)
    k = _double(left.polygon, _pose_vector(pose_left), left.cop, left.force_n, right.polygon, _pose_vector(pose_right),
                right.cop, right.force_n, out, cop)
    return out[:k].copy(), cop


class SeriesEstimate(NamedTuple):
    """One sole over T ticks (:func:`estimate_series`); fields as :class:`SoleEstimate`, each with a
    leading time axis; the hulls are padded: polygons (T, K, 2) with polygon_count (T,) vertices."""

    cop: np.ndarray
    cop_cells: np.ndarray
    force_n: np.ndarray
    active: np.ndarray
    contact_area: np.ndarray
    polygons: np.ndarray
    polygon_count: np.ndarray
    polygon_area: np.ndarray
    pretouch_count: np.ndarray
    pretouch_area: np.ndarray
    ankle_moment: np.ndarray
    ft_replan: np.ndarray
    skin_replan: np.ndarray
    sidestep: np.ndarray


def estimate_series(estimator: SkinEstimator, sensor_forces: np.ndarray, gaps: np.ndarray, wrench: np.ndarray) -> SeriesEstimate:
    """A recording's estimates in one compiled call: sensor_forces (T, N, 3) N, gaps (T, N) m,
    wrench (T, 6). Tick t equals ``estimator(sensor_forces[t], gaps[t], wrench[t])``."""
    forces = np.ascontiguousarray(sensor_forces, dtype=float)
    t, n = forces.shape[:2]
    gaps, wrench = np.ascontiguousarray(gaps, dtype=float), np.ascontiguousarray(wrench, dtype=float)
    if forces.shape[1:] != estimator._sensors.shape[:2] or gaps.shape != (t, n) or wrench.shape != (t, 6):
        raise ValueError(f"estimate_series: sensor_forces {forces.shape}, gaps {gaps.shape}, wrench {wrench.shape}; "
                         f"expected (T, {n}, 3), (T, {n}), (T, 6)")
    k = len(estimator._cell) + 1
    active, hulls = np.empty((t, n), dtype=np.bool_), np.zeros((t, k, 2))
    counts, s = np.empty((t, 2), dtype=np.int64), np.empty((t, _NS))
    _series(forces, gaps, wrench, estimator._sensors, estimator._centres, estimator._sorted, estimator._cell, estimator._params,
            active, hulls, counts, s)
    kmax = max(int(counts[:, 0].max(initial=0)), 1)
    return SeriesEstimate(s[:, 0:2], s[:, 2:4], s[:, 4], active, s[:, 5], hulls[:, :kmax], counts[:, 0], s[:, 6], counts[:, 1],
                          s[:, 7], s[:, 8], s[:, 9] > 0.5, s[:, 10] > 0.5, s[:, 11])
