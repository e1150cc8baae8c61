"""The plantar skin's hexagonal cells: their layout on the sole, their corners and their force sensors (SPEC 4).

SPEC 4 gives 42 hexagonal cells per sole, 6.9 cm^2 each, each with three normal-force sensors and
a known pose on the sole; it does not give the sole's outline or the layout. Both are chosen here
(module constants below) and are parameters of :func:`sole_layout`.

Frames and units: the sole frame has its origin at the ankle's projection on the sole plane, x
forward (heel -> toe), y to the left, z up (out of the sole, into the foot); lengths in metres.

Layout: a honeycomb of regular hexagons with a vertex pointing along +-x (flat edges at +-y). A row
is a line of cells across the sole (along y, pitch sqrt(3) s), rows follow each other along x at
pitch 1.5 s, and a row of n cells is centred on y = 0, so rows of alternating parity interlock.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DEFAULT_ROW_COUNTS", "CELL_AREA_M2", "SENSOR_RADIUS_FRACTION", "SoleLayout", "sole_layout",
           "hexagon_side", "hexagon_corners", "cell_quadrature"]

# --- documented defaults (the SPEC does not give them) -------------------------------------------
# Cells per row, heel to toe: 42 cells (SPEC 4). A choice shaped like a humanoid's sole: a 4-5 cell
# heel and midfoot (113-141 mm wide), widest at the ball (6 cells, 169 mm), a narrower toe; nine rows
# make a 228 mm long sole. Alternate rows differ in parity so that they interlock (module docstring).
DEFAULT_ROW_COUNTS = (4, 5, 4, 5, 4, 5, 6, 5, 4)
# Cell area: 6.9 cm^2 (SPEC 4); the hexagon's side follows (16.3 mm).
CELL_AREA_M2 = 6.9e-4
# The three force sensors sit at 120 deg on a circle of half the hexagon's side around the cell's
# centre (a choice: inside the cell, far enough apart that their triangle holds the cell's middle).
SENSOR_RADIUS_FRACTION = 0.5


def hexagon_side(area_m2: float) -> float:
    """Side s (m) of the regular hexagon of area ``area_m2`` (m^2): A = 3 sqrt(3) / 2 s^2."""
    if not area_m2 > 0:
        raise ValueError(f"cell area = {area_m2}: must be > 0")
    return float(np.sqrt(2.0 * area_m2 / (3.0 * np.sqrt(3.0))))


def hexagon_corners(centres: np.ndarray, yaw: np.ndarray, side: float) -> np.ndarray:
    """Corners of regular hexagons. centres (N, 2) m, yaw (N,) rad (0: a vertex along +x), side m.
    Returns (N, 6, 2) m, counter-clockwise."""
    angles = np.asarray(yaw, dtype=float)[:, None] + np.arange(6) * np.pi / 3.0
    return np.asarray(centres, dtype=float)[:, None, :] + side * np.stack([np.cos(angles), np.sin(angles)], axis=-1)


def cell_quadrature(side: float, subdivisions: int) -> tuple[np.ndarray, np.ndarray]:
    """Points and weights that integrate over one hexagon (centred at 0, a vertex along +x).

    The hexagon is cut into 6 triangles, each into subdivisions^2 equal sub-triangles, one point at
    each sub-triangle's centroid (exact for linear fields; O(h^2) for smooth ones).
    Returns points (M, 2) m and weights (M,) m^2 summing to the hexagon's area, M = 6 subdivisions^2.
    """
    if subdivisions < 1:
        raise ValueError(f"sensor.cells.quadrature = {subdivisions}: must be >= 1")
    n = subdivisions
    # barycentric centroids of the n^2 sub-triangles of a triangle (upward and downward ones)
    bary = []
    for i in range(n):
        for j in range(n - i):
            bary.append(((i + 1 / 3) / n, (j + 1 / 3) / n))  # upward
            if i + j < n - 1:
                bary.append(((i + 2 / 3) / n, (j + 2 / 3) / n))  # downward
    bary = np.asarray(bary)  # (n^2, 2): weights of the triangle's 2nd and 3rd vertices
    points = []
    for k in range(6):
        a, b = k * np.pi / 3.0, (k + 1) * np.pi / 3.0
        va, vb = side * np.array([np.cos(a), np.sin(a)]), side * np.array([np.cos(b), np.sin(b)])
        points.append(bary[:, :1] * va + bary[:, 1:] * vb)  # first vertex: the centre (0, 0)
    points = np.concatenate(points)
    area = 1.5 * np.sqrt(3.0) * side**2
    return points, np.full(len(points), area / len(points))


@dataclass(frozen=True)
class SoleLayout:
    """One sole's cells in the sole frame (all lengths m).

    centres (N, 2), yaw (N,) rad: the cells' poses. corners (N, 6, 2): each hexagon's corners.
    sensors (N, 3, 2): each cell's three force sensors. side: the hexagons' side; cell_area: m^2.
    """

    centres: np.ndarray
    yaw: np.ndarray
    corners: np.ndarray
    sensors: np.ndarray
    side: float
    cell_area: float

    @property
    def n_cells(self) -> int:
        return len(self.centres)

    def outline(self) -> np.ndarray:
        """The sole's outline: the convex hull of every cell's corners, (K, 2) counter-clockwise."""
        from scipy.spatial import ConvexHull

        points = self.corners.reshape(-1, 2)
        return points[ConvexHull(points).vertices]

    def sole_area(self) -> float:
        """A_s (m^2): the area of :meth:`outline` (the whole sole, SPEC 4's skin rule)."""
        from scipy.spatial import ConvexHull

        return float(ConvexHull(self.corners.reshape(-1, 2)).volume)


def sole_layout(row_counts=DEFAULT_ROW_COUNTS, cell_area_m2: float = CELL_AREA_M2,
                sensor_radius_fraction: float = SENSOR_RADIUS_FRACTION) -> SoleLayout:
    """The honeycomb layout (module docstring): ``row_counts`` cells per row heel to toe, cells of
    ``cell_area_m2``. The origin is put at the cells' centroid: the ankle stands over the middle of
    the skin (a choice: standing on flat ground then loads no ankle moment)."""
    counts = [int(c) for c in row_counts]
    if not counts or min(counts) < 1:
        raise ValueError(f"sensor.cells.row_counts = {list(row_counts)}: give one or more rows of >= 1 cell")
    if any((a - b) % 2 == 0 for a, b in zip(counts, counts[1:])):
        raise ValueError(f"sensor.cells.row_counts = {counts}: neighbouring rows must differ in parity "
                         "(odd, even, odd, ...) for the hexagons to interlock")
    if not 0 < sensor_radius_fraction < np.sqrt(3) / 2:
        raise ValueError(f"sensor radius fraction = {sensor_radius_fraction}: must be in (0, 0.866) to stay inside the cell")
    side = hexagon_side(cell_area_m2)
    pitch_y, pitch_x = np.sqrt(3.0) * side, 1.5 * side
    centres = np.array([(r * pitch_x, (i - (n - 1) / 2.0) * pitch_y) for r, n in enumerate(counts) for i in range(n)])
    centres = centres - centres.mean(axis=0)
    yaw = np.zeros(len(centres))
    corners = hexagon_corners(centres, yaw, side)
    a = np.pi / 2.0 + np.arange(3) * 2.0 * np.pi / 3.0  # sensors at 90, 210, 330 deg
    offsets = sensor_radius_fraction * side * np.stack([np.cos(a), np.sin(a)], axis=-1)
    sensors = centres[:, None, :] + offsets[None]
    return SoleLayout(centres, yaw, corners, sensors, side, 1.5 * np.sqrt(3.0) * side**2)
