"""Parametric geometry of the layered rod array (SPEC 1.1).

The body is a rectangular base slab ``[-Sx/2, Sx/2] x [-Sy/2, Sy/2] x [0, T]`` with ``rows x cols``
cylindrical rods of radius ``R`` and height ``H`` standing on it, each centred in its cell of the
``pitch_x x pitch_y`` grid. The *top surface* is everything a load can touch: the rod tips, the rod
sides and the top of the base. Over it lie the layers, outside in: the light-absorbing layer
(thickness ``a``), the ML layer (``m``), and the clear core fills the rest. The base's bottom (it
faces the camera) and its sides are not layered.

A point's layer follows from its *depth*, its distance to the top surface (:func:`depth_below_top`),
which is analytic: inside a rod ``min(R - r, T + H - z)``; in the base outside a rod's footprint
``T - z``; in the base under a rod ``sqrt((R - r)^2 + (T - z)^2)`` (the nearest top-surface point is
the rim where the rod meets the base). The set of points at one depth ``d`` is therefore a smooth
sheet: inner rod cylinders of radius ``R - d`` joined to the plane ``z = T - d`` by concave quarter-torus
fillets of radius ``d``. The inner face of the ML layer (``d = a + m``) is the core's boundary, the
surface that emits into the core and that the renderer draws.

The layers are thin (0.3 mm and 0.5 mm) next to useful element sizes (1-2.5 mm), so the volume mesh
does not resolve them: they are a material field over it (:mod:`fem.mesh` samples this classifier).

All lengths are in metres inside this module.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

__all__ = [
    "RodArray",
    "FaceTag",
    "depth_below_top",
    "layer_index",
    "classify_boundary",
    "project_to_surface",
    "project_onto_pieces",
    "project_edge_midpoints",
    "midpoints_on_shared_pieces",
    "solid_below_depth",
    "outer_surface",
    "emitting_surface",
]


class FaceTag(enum.IntEnum):
    """Tags of the body's boundary faces. The base bottom is both fixed (it rests on the acrylic
    plate) and camera-facing."""

    BASE_BOTTOM = 0
    BASE_SIDE = 1
    BASE_TOP = 2
    ROD_SIDE = 3
    ROD_TIP = 4


class Layer(enum.IntEnum):
    ABSORBER = 0
    ML = 1
    CORE = 2


@dataclass(frozen=True)
class RodArray:
    """The rod array's dimensions (metres). Rods are numbered row-major: ``n = row * cols + col``,
    rows along +y, columns along +x, both from the negative side."""

    rows: int
    cols: int
    pitch_x_m: float
    pitch_y_m: float
    rod_radius_m: float
    rod_height_m: float
    base_thickness_m: float
    absorber_m: float
    ml_m: float

    @classmethod
    def from_sensor(cls, sensor) -> "RodArray":
        """From a validated :class:`mlsim.scene.SensorSpec` (millimetres) to metres."""
        mm = 1e-3
        return cls(
            rows=sensor.rows,
            cols=sensor.cols,
            pitch_x_m=sensor.pitch_x_mm * mm,
            pitch_y_m=sensor.pitch_y_mm * mm,
            rod_radius_m=sensor.rod.diameter_mm / 2 * mm,
            rod_height_m=sensor.rod.height_mm * mm,
            base_thickness_m=sensor.base.thickness_mm * mm,
            absorber_m=sensor.layers.absorber_mm * mm,
            ml_m=sensor.layers.ml_mm * mm,
        )

    # -- derived dimensions ------------------------------------------------------------------
    @property
    def n_rods(self) -> int:
        return self.rows * self.cols

    @property
    def size_x_m(self) -> float:
        return self.cols * self.pitch_x_m

    @property
    def size_y_m(self) -> float:
        return self.rows * self.pitch_y_m

    @property
    def tip_z_m(self) -> float:
        return self.base_thickness_m + self.rod_height_m

    @property
    def core_depth_m(self) -> float:
        """Depth of the ML layer's inner face (the core's boundary) under the top surface."""
        return self.absorber_m + self.ml_m

    @property
    def centres_m(self) -> np.ndarray:
        """(N, 2) rod centres, row-major."""
        x = (np.arange(self.cols) + 0.5) * self.pitch_x_m - self.size_x_m / 2
        y = (np.arange(self.rows) + 0.5) * self.pitch_y_m - self.size_y_m / 2
        xx, yy = np.meshgrid(x, y)  # (rows, cols)
        return np.stack([xx.ravel(), yy.ravel()], axis=1)

    # -- analytic measures -------------------------------------------------------------------
    def volume_m3(self) -> float:
        """Volume of the whole body."""
        r, h, t = self.rod_radius_m, self.rod_height_m, self.base_thickness_m
        return self.size_x_m * self.size_y_m * t + self.n_rods * math.pi * r * r * h

    def volume_within_depth_m3(self, depth_m: float) -> float:
        """Volume of the points within ``depth_m`` of the top surface (0 <= depth < R, T, H).

        Base outside the rod footprints: a slab of thickness d. Rods: the cylinder less its inner
        cylinder of radius R - d and height H - d. Under each rod: the quarter disc of radius d about
        the rim revolved about the rod axis (Pappus: centroid at R - 4d / (3 pi)).
        """
        d = float(depth_m)
        r, h = self.rod_radius_m, self.rod_height_m
        if not (0 <= d < min(r, h, self.base_thickness_m)):
            raise ValueError(f"depth_m = {d}: must be within [0, min(R, H, T))")
        free_area = self.size_x_m * self.size_y_m - self.n_rods * math.pi * r * r
        rods = math.pi * r * r * h - math.pi * (r - d) ** 2 * (h - d)
        fillet = 2 * math.pi * (r - 4 * d / (3 * math.pi)) * math.pi * d * d / 4
        return free_area * d + self.n_rods * (rods + fillet)

    def layer_volumes_m3(self) -> dict[str, float]:
        """Analytic volume of each layer: ``{"absorber", "ml", "core"}``."""
        a = self.volume_within_depth_m3(self.absorber_m)
        am = self.volume_within_depth_m3(self.core_depth_m)
        return {"absorber": a, "ml": am - a, "core": self.volume_m3() - am}

    def sheet_area_m2(self, depth_m: float) -> float:
        """Area of the sheet of points at ``depth_m`` under the top surface (depth 0: the top
        surface itself; ``core_depth_m``: the ML layer's inner face).

        Plane ``z = T - d`` outside the rod footprints, inner rod sides and tips, and the quarter-torus
        fillets: integral of 2 pi r ds over the arc = pi^2 R d - 2 pi d^2.
        """
        d = float(depth_m)
        r, h = self.rod_radius_m, self.rod_height_m
        if not (0 <= d < min(r, h, self.base_thickness_m)):
            raise ValueError(f"depth_m = {d}: must be within [0, min(R, H, T))")
        free_area = self.size_x_m * self.size_y_m - self.n_rods * math.pi * r * r
        rod = 2 * math.pi * (r - d) * (h - d) + math.pi * (r - d) ** 2
        fillet = math.pi**2 * r * d - 2 * math.pi * d * d
        return free_area + self.n_rods * (rod + fillet)

    def face_areas_m2(self) -> dict[FaceTag, float]:
        """Analytic area of each tagged part of the boundary."""
        r, h, t = self.rod_radius_m, self.rod_height_m, self.base_thickness_m
        sx, sy = self.size_x_m, self.size_y_m
        return {
            FaceTag.BASE_BOTTOM: sx * sy,
            FaceTag.BASE_SIDE: 2 * (sx + sy) * t,
            FaceTag.BASE_TOP: sx * sy - self.n_rods * math.pi * r * r,
            FaceTag.ROD_SIDE: self.n_rods * 2 * math.pi * r * h,
            FaceTag.ROD_TIP: self.n_rods * math.pi * r * r,
        }

    # -- point location ---------------------------------------------------------------------
    def rod_of(self, xy: np.ndarray) -> np.ndarray:
        """(M,) index of the rod whose cell holds each point (M, 2+); points outside go to the nearest cell."""
        xy = np.asarray(xy, dtype=float)
        col = np.clip(np.floor((xy[:, 0] + self.size_x_m / 2) / self.pitch_x_m), 0, self.cols - 1)
        row = np.clip(np.floor((xy[:, 1] + self.size_y_m / 2) / self.pitch_y_m), 0, self.rows - 1)
        return (row * self.cols + col).astype(np.int64)

    def radial(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(rod index (M,), distance (M,) from that rod's axis) for points (M, 3)."""
        rod = self.rod_of(points)
        r = np.linalg.norm(points[:, :2] - self.centres_m[rod], axis=1)
        return rod, r

    # -- the body protocol of fem.mesh.build_mesh (see fem.mesh.MeshableBody) -----------------
    @property
    def layer_interfaces_m(self) -> tuple[float, ...]:
        """Depths under the top surface where the layer changes (absorber/ML, ML/core)."""
        return tuple(s for s in (self.absorber_m, self.core_depth_m) if s > 0)

    def outer_surface(self, segments: int = 48):
        return outer_surface(self, segments)

    def depth_below_top(self, points: np.ndarray) -> np.ndarray:
        return depth_below_top(self, points)

    def layer_index(self, points: np.ndarray) -> np.ndarray:
        return layer_index(self, points)

    def classify_boundary(self, points: np.ndarray):
        return classify_boundary(self, points)

    def project_to_surface(self, points: np.ndarray, edge_tol_m: float = 0.0) -> np.ndarray:
        return project_to_surface(self, points, edge_tol_m)

    def project_edge_midpoints(self, a: np.ndarray, b: np.ndarray, tol_m: float) -> np.ndarray:
        return project_edge_midpoints(self, a, b, tol_m)

    def region_of(self, points: np.ndarray) -> np.ndarray:
        """(M,) rod index of points above the base, -1 in the base."""
        points = np.asarray(points, dtype=float)
        return np.where(points[:, 2] > self.base_thickness_m, self.rod_of(points), -1).astype(np.int32)

    def check_regions(self, points: np.ndarray, tets: np.ndarray, volumes: np.ndarray) -> str | None:
        """A problem with a candidate mesh's parts (a rod missing volume), or None."""
        centroid = points[tets].mean(axis=1)
        in_rod = centroid[:, 2] > self.base_thickness_m
        per_rod = np.bincount(self.rod_of(centroid[in_rod]), weights=volumes[in_rod], minlength=self.n_rods)
        exact = math.pi * self.rod_radius_m**2 * self.rod_height_m
        worst = int(np.argmax(np.abs(per_rod / exact - 1)))
        if abs(per_rod[worst] / exact - 1) > 0.06:
            return f"rod {worst} has {100 * (per_rod[worst] / exact - 1):+.1f} % of its analytic volume"
        return None


def depth_below_top(g: RodArray, points: np.ndarray) -> np.ndarray:
    """Distance (m) from points inside the body to the top surface; 0 for points outside it.

    points: (M, 3) m. Returns (M,) m. Exact for the geometry of the module docstring, because the
    grid cells are the Voronoi cells of the rod axes and rods never overlap.
    """
    points = np.asarray(points, dtype=float)
    _, r = g.radial(points)
    z = points[:, 2]
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    in_rod = np.minimum(big_r - r, tip - z)
    under_rod = np.hypot(np.maximum(big_r - r, 0.0), t - z)
    depth = np.where(z >= t, np.where(r < big_r, in_rod, 0.0), np.where(r < big_r, under_rod, t - z))
    outside = (z < 0) | (np.abs(points[:, 0]) > g.size_x_m / 2) | (np.abs(points[:, 1]) > g.size_y_m / 2)
    return np.where(outside, 0.0, np.maximum(depth, 0.0))


def layer_index(g: RodArray, points: np.ndarray) -> np.ndarray:
    """Layer of each point (M, 3): 0 absorber, 1 ML, 2 core (see :class:`Layer`)."""
    depth = depth_below_top(g, points)
    out = np.full(depth.shape, Layer.CORE, dtype=np.int8)
    out[depth < g.core_depth_m] = Layer.ML
    out[depth < g.absorber_m] = Layer.ABSORBER
    return out


def _piece_distances(g: RodArray, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Distance (M, 5) from each point to each tagged boundary piece, and the rod index (M,)."""
    p = np.asarray(points, dtype=float)
    rod, r = g.radial(p)
    x, y, z = p[:, 0], p[:, 1], p[:, 2]
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    hx, hy = g.size_x_m / 2, g.size_y_m / 2
    out_x, out_y = _outside(np.abs(x), hx), _outside(np.abs(y), hy)  # how far beyond the footprint
    out_z = _outside(z, t) + _outside(-z, 0.0)  # how far above or below the base's height range
    wall_x = np.sqrt((hx - np.abs(x)) ** 2 + out_y**2 + out_z**2)
    wall_y = np.sqrt((hy - np.abs(y)) ** 2 + out_x**2 + out_z**2)
    d = np.empty((len(p), 5))
    d[:, FaceTag.BASE_BOTTOM] = np.sqrt(z**2 + out_x**2 + out_y**2)
    d[:, FaceTag.BASE_SIDE] = np.minimum(wall_x, wall_y)
    d[:, FaceTag.BASE_TOP] = np.sqrt((z - t) ** 2 + np.maximum(big_r - r, 0.0) ** 2 + out_x**2 + out_y**2)
    d[:, FaceTag.ROD_SIDE] = np.hypot(r - big_r, np.maximum(t - z, 0.0) + np.maximum(z - tip, 0.0))
    d[:, FaceTag.ROD_TIP] = np.hypot(z - tip, np.maximum(r - big_r, 0.0))
    return d, rod


def _outside(value: np.ndarray, limit: float) -> np.ndarray:
    return np.maximum(value - limit, 0.0)


def classify_boundary(g: RodArray, points: np.ndarray):
    """Tag boundary points (e.g. face centroids) by the nearest piece of the exact boundary.

    points: (M, 3) m. Returns (tag (M,) int8 of :class:`FaceTag`, rod (M,) int32 with -1 off the
    rods, distance (M,) m to that piece).
    """
    d, rod = _piece_distances(g, points)
    tag = np.argmin(d, axis=1).astype(np.int8)
    on_rod = (tag == FaceTag.ROD_SIDE) | (tag == FaceTag.ROD_TIP)
    return tag, np.where(on_rod, rod, -1).astype(np.int32), d[np.arange(len(d)), tag]


def project_to_surface(g: RodArray, points: np.ndarray, edge_tol_m: float = 0.0) -> np.ndarray:
    """Closest point (M, 3) on the exact boundary to each of ``points`` (M, 3), in metres.

    With ``edge_tol_m > 0``, a point within that distance of two or three boundary pieces goes to
    where they meet (a sharp edge or corner: base bottom and side, rod tip rim, rod foot): see
    :func:`project_onto_pieces`. Nodes on a mesh's sharp edges need this, or they sit on one face
    and miss the other.
    """
    p = np.asarray(points, dtype=float)
    d, rod = _piece_distances(g, p)
    out = _onto_piece(g, p, np.argmin(d, axis=1), rod)
    if edge_tol_m > 0:
        near = d <= edge_tol_m
        corner = near.sum(axis=1) >= 2
        out[corner] = project_onto_pieces(g, p[corner], near[corner], rod[corner], edge_tol_m)
    return out


def _onto_piece(g: RodArray, p: np.ndarray, tag: np.ndarray, rod: np.ndarray) -> np.ndarray:
    """Closest point of the piece ``tag`` (M,) to each point (M, 3) (pieces are closed sets)."""
    out = p.copy()
    c = g.centres_m[rod]
    rel = p[:, :2] - c
    r = np.linalg.norm(rel, axis=1)
    unit = rel / np.where(r > 0, r, 1.0)[:, None]
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    hx, hy = g.size_x_m / 2, g.size_y_m / 2
    inside_xy = np.column_stack([np.clip(p[:, 0], -hx, hx), np.clip(p[:, 1], -hy, hy)])

    m = tag == FaceTag.BASE_BOTTOM
    out[m, :2] = inside_xy[m]
    out[m, 2] = 0.0
    m = tag == FaceTag.BASE_SIDE
    on_x = np.abs(hx - np.abs(p[:, 0])) <= np.abs(hy - np.abs(p[:, 1]))
    mx, my = m & on_x, m & ~on_x
    out[mx, 0] = np.where(p[mx, 0] >= 0, hx, -hx)
    out[mx, 1] = inside_xy[mx, 1]
    out[my, 1] = np.where(p[my, 1] >= 0, hy, -hy)
    out[my, 0] = inside_xy[my, 0]
    out[m, 2] = np.clip(p[m, 2], 0.0, t)
    m = tag == FaceTag.BASE_TOP
    out[m, :2] = inside_xy[m]
    out[m, 2] = t
    inside = m & (r < big_r)  # closest point of the base top is then the rim
    out[inside, :2] = c[inside] + big_r * unit[inside]
    m = tag == FaceTag.ROD_SIDE
    out[m, :2] = c[m] + big_r * unit[m]
    out[m, 2] = np.clip(p[m, 2], t, tip)
    m = tag == FaceTag.ROD_TIP
    out[m, 2] = tip
    outside = m & (r > big_r)
    out[outside, :2] = c[outside] + big_r * unit[outside]
    return out


def project_onto_pieces(g: RodArray, points: np.ndarray, pieces: np.ndarray, rod: np.ndarray, side_tol_m: float) -> np.ndarray:
    """Project points (M, 3) onto the intersection of the carrier surfaces of the chosen pieces.

    pieces: (M, 5) bool, which :class:`FaceTag` pieces each point lies on. rod: (M,) the rod whose
    cylinder is meant. The carriers (planes x, y, z = const and the rod cylinders) meet at right
    angles, so projecting onto each in turn lands exactly on their common edge or corner. For the
    base side, the wall(s) within ``side_tol_m`` are used (both at a vertical corner edge), else
    the nearer one.
    """
    q = np.array(points, dtype=float)
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    hx, hy = g.size_x_m / 2, g.size_y_m / 2
    c = g.centres_m[rod]
    for _ in range(2):  # a second sweep settles points on three pieces (base corners)
        q[pieces[:, FaceTag.BASE_BOTTOM], 2] = 0.0
        side = pieces[:, FaceTag.BASE_SIDE]
        gap_x, gap_y = np.abs(hx - np.abs(q[:, 0])), np.abs(hy - np.abs(q[:, 1]))
        sx = side & ((gap_x <= side_tol_m) | (gap_x <= gap_y))
        sy = side & ((gap_y <= side_tol_m) | (gap_y < gap_x))
        q[sx, 0] = np.where(q[sx, 0] >= 0, hx, -hx)
        q[sy, 1] = np.where(q[sy, 1] >= 0, hy, -hy)
        q[pieces[:, FaceTag.BASE_TOP], 2] = t
        q[pieces[:, FaceTag.ROD_TIP], 2] = tip
        cyl = pieces[:, FaceTag.ROD_SIDE]
        rel = q[cyl, :2] - c[cyl]
        q[cyl, :2] = c[cyl] + big_r * rel / np.maximum(np.linalg.norm(rel, axis=1), 1e-300)[:, None]
    return q


def project_edge_midpoints(g: RodArray, a: np.ndarray, b: np.ndarray, tol_m: float) -> np.ndarray:
    """Mid-edge nodes (M, 3) of boundary edges a-b (each (M, 3)) placed on the exact surface.

    An edge whose two ends lie on the same piece(s) (within ``tol_m``) keeps to them: a chord of
    the tip rim gets its middle on the rim circle, a chord along a rod side on the cylinder, however
    far the chord sags. An edge that crosses from one piece to another (a chamfer of a sharp edge)
    gets its middle projected to the nearest surface point.
    """
    return midpoints_on_shared_pieces(
        lambda p: _piece_distances(g, p),
        lambda p, tol: project_to_surface(g, p, tol),
        lambda p, pieces, rod, tol: project_onto_pieces(g, p, pieces, rod, tol),
        a,
        b,
        tol_m,
        rod_pieces=(FaceTag.ROD_SIDE, FaceTag.ROD_TIP),
    )


def midpoints_on_shared_pieces(distances, project, onto_pieces, a, b, tol_m, rod_pieces=()):
    """Generic rule of :func:`project_edge_midpoints` for any body given as three functions:
    ``distances(p) -> (d (M, K), part (M,))``, ``project(p, tol)`` and
    ``onto_pieces(p, pieces (M, K) bool, part (M,), tol)``. For the pieces in ``rod_pieces`` both
    ends must also belong to the same part (rod)."""
    mid = 0.5 * (a + b)
    da, part_a = distances(a)
    db, part_b = distances(b)
    common = (da <= tol_m) & (db <= tol_m)
    if rod_pieces:
        common[:, list(rod_pieces)] &= (part_a == part_b)[:, None]
    out = project(mid, tol_m)
    shared = common.any(axis=1)
    out[shared] = onto_pieces(mid[shared], common[shared], part_a[shared], tol_m)
    return out


# -------------------------------------------------------------------------------- surfaces
def solid_below_depth(g: RodArray, depth_m: float, segments: int = 48, step_m: float | None = None):
    """Watertight solid (trimesh.Trimesh, metres) of the points deeper than ``depth_m`` under the
    top surface: depth 0 is the whole body; ``g.absorber_m`` is what lies inside the absorber;
    ``g.core_depth_m`` is the clear core.

    Built with manifold3d: the base slab (cut down by ``depth_m``) united with one solid of
    revolution per rod whose profile carries the quarter-circle fillet of radius ``depth_m``.
    ``segments`` is the number of facets around a full circle (vertices lie on the exact circles).
    ``step_m``: when given, the rods' walls and tips get rings of vertices at most this far apart
    (the emitting sheet needs them: its emission is one value per vertex); the meshing surfaces
    leave it unset.
    """
    import manifold3d as m3
    import trimesh

    d = float(depth_m)
    t, h, big_r = g.base_thickness_m, g.rod_height_m, g.rod_radius_m
    if not (0 <= d < min(big_r, h, t)):
        raise ValueError(f"depth_m = {d}: must be within [0, min(R, H, T))")
    sx, sy = g.size_x_m, g.size_y_m
    slab = m3.Manifold.cube([sx, sy, t - d]).translate([-sx / 2, -sy / 2, 0.0])
    z0 = (t - d) / 2  # the stem starts inside the slab so the union fuses them
    profile = [(0.0, z0), (big_r, z0), (big_r, t - d)]
    if d > 0:
        n_arc = max(2, int(math.ceil(segments / 4)))
        theta = np.linspace(0.0, math.pi / 2, n_arc + 1)[1:]
        profile += [(big_r - d * math.sin(a), t - d * math.cos(a)) for a in theta]
    top = [(big_r - d, t + h - d), (0.0, t + h - d)]
    if step_m is not None:
        wall_from = profile[-1]
        n_wall = max(1, int(math.ceil((t + h - d - wall_from[1]) / step_m)))
        profile += [(wall_from[0], wall_from[1] + (t + h - d - wall_from[1]) * k / n_wall) for k in range(1, n_wall)]
        n_cap = max(1, int(math.ceil((big_r - d) / step_m)))
        top = [top[0]] + [((big_r - d) * (1 - k / n_cap), t + h - d) for k in range(1, n_cap)] + [top[1]]
    profile += top
    stem = m3.Manifold.revolve(m3.CrossSection([profile]), circular_segments=segments)
    rods = [stem.translate([cx, cy, 0.0]) for cx, cy in g.centres_m]
    solid = m3.Manifold.batch_boolean([slab, *rods], m3.OpType.Add)
    mesh = solid.to_mesh64()
    vertices = np.asarray(mesh.vert_properties, dtype=float)[:, :3]
    faces = np.asarray(mesh.tri_verts, dtype=np.int64)
    # process=False: manifold3d's output is already merged and watertight. Where the slab's top
    # meets a fillet's rim it may hold a few zero-area slivers; trimesh's vertex merging would
    # collapse them into edges shared by six faces (non-manifold), so we keep them as they are.
    return trimesh.Trimesh(vertices, faces, process=False)


def outer_surface(g: RodArray, segments: int = 48):
    """The watertight outer surface of the rods fused to the base (trimesh.Trimesh, metres)."""
    return solid_below_depth(g, 0.0, segments)


def emitting_surface(g: RodArray, segments: int = 48, step_m: float | None = None):
    """The inner face of the ML layer, the sheet that emits into the core (trimesh.Trimesh, metres).

    It is the core solid's boundary less the base bottom and base sides: an open sheet whose only
    boundary edges lie on the base's side walls. Face normals point out of the core (towards the layers).
    """
    core = solid_below_depth(g, g.core_depth_m, segments, step_m)
    tri = core.triangles
    tol = 1e-9 + 1e-6 * max(g.size_x_m, g.size_y_m)
    on_bottom = np.all(np.abs(tri[:, :, 2]) < tol, axis=1)
    on_side = np.all(np.abs(np.abs(tri[:, :, 0]) - g.size_x_m / 2) < tol, axis=1) | np.all(
        np.abs(np.abs(tri[:, :, 1]) - g.size_y_m / 2) < tol, axis=1
    )
    sheet = core.submesh([np.flatnonzero(~(on_bottom | on_side))], append=True)
    return sheet
