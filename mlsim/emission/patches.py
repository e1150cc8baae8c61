"""The emitting patches of the ML layer and the FEM stress they feel.

A patch is a vertex of the ML layer's inner face (:func:`fem.geometry.emitting_surface`, the sheet
the renderer draws and whose per-vertex emission it reads), with a third of the area of its
faces. The sheet as built has facets as long as a rod (a rod wall is one row of slivers from the
fillet to the tip, the flat base between rods is spanned by its rims' vertices alone), and the
emission is linear over each face, so the rods are built with rings of vertices ``max_edge_m``
apart (``step_m`` of :func:`fem.geometry.emitting_surface`), the flat base is triangulated afresh
(Delaunay on the rims' vertices and a grid of spacing ``max_edge_m``), and any edge still longer
is split (:func:`refine_to_edge_length`: the new vertices lie on the same flat facets). Its stress is the FEM stress at the middle of the ML layer above it: the vertex moved out
along its normal by half the ML thickness, located in the tet mesh. The FEM stress is one value
per tet (its centroid), so a patch takes its containing tet's value (piecewise constant; the
ML layer is resolved to the mesh's edge length, see ``fidelity.mesh.edge_length_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MLPatches", "ml_patches", "refine_to_edge_length"]


@dataclass
class MLPatches:
    """N patches: vertices (N, 3) m and faces (K, 3) of the emitting sheet, per-vertex normals (N, 3)
    (out of the core), areas (N,) m^2, rod index (N,) (-1: the base between rods), the stress
    sample points (N, 3) m and the tet holding each (N,)."""

    vertices_m: np.ndarray
    faces: np.ndarray
    normals: np.ndarray
    area_m2: np.ndarray
    rod: np.ndarray
    sample_m: np.ndarray
    tet: np.ndarray

    @property
    def n(self) -> int:
        return len(self.vertices_m)


def ml_patches(geometry, mesh, segments: int = 48, max_edge_m: float | None = 1e-3) -> MLPatches:
    """The emitting patches of a :class:`fem.geometry.RodArray` and the tets of its FEM ``mesh``
    (:class:`fem.mesh.TetMesh`) that hold their stress sample points; the sheet's edges are split
    down to ``max_edge_m`` (None: the sheet as built)."""
    from fem.geometry import emitting_surface
    from fem.mesh import locate_points

    sheet = emitting_surface(geometry, segments, max_edge_m)
    V, F = np.asarray(sheet.vertices, dtype=float), np.asarray(sheet.faces)
    if max_edge_m is not None:
        if not max_edge_m > 0:
            raise ValueError(f"max_edge_m = {max_edge_m}: must be > 0 (or None)")
        V, F = _retriangulate_base(geometry, V, F, max_edge_m)
        V, F = refine_to_edge_length(V, F, max_edge_m)
    import trimesh

    sheet = trimesh.Trimesh(V, F, process=False)
    area = np.bincount(F.ravel(), weights=np.repeat(sheet.area_faces / 3.0, 3), minlength=len(V))
    normals = np.asarray(sheet.vertex_normals, dtype=float)
    sample = V + 0.5 * geometry.ml_m * normals
    tet, _ = locate_points(mesh.points, mesh.tets, sample)
    on_base = V[:, 2] <= geometry.base_thickness_m - geometry.core_depth_m + 1e-9  # the core's top, under the layers
    _, r = geometry.radial(V)
    rod = np.where(on_base & (r > geometry.rod_radius_m - geometry.core_depth_m + 1e-9), -1, geometry.rod_of(V))
    return MLPatches(V, F, normals, area, rod, sample, tet)


def refine_to_edge_length(V, F, max_edge: float, max_rounds: int = 64):
    """Split a triangle mesh's edges until none is longer than ``max_edge``, conformingly.

    Each round marks the edges longer than ``max_edge``, adds their midpoints and splits each face
    by its marked edges (one: in two; two: in three; three: in four, the red/green patterns of
    Bank, Sherman and Weiser 1983), so a split edge is split on both of its faces and no crack or
    T-junction appears. Orientation and the surface are kept (midpoints of straight edges). Faces
    with no long edge are untouched, unlike whole-face subdivision, which also splits the short
    edges of a face with one long edge.
    Returns (V2 (N2, 3), F2 (K2, 3)).
    """
    if not max_edge > 0:
        raise ValueError(f"max_edge = {max_edge}: must be > 0")
    V = np.asarray(V, dtype=float)
    F = np.asarray(F, dtype=np.int64)
    for _ in range(max_rounds):
        e = np.stack([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]], axis=1)  # (K, 3, 2): edge j from vertex j
        key = np.sort(e, axis=2).reshape(-1, 2)
        uniq, inv = np.unique(key, axis=0, return_inverse=True)
        inv = inv.reshape(-1, 3)
        long_edge = np.linalg.norm(V[uniq[:, 0]] - V[uniq[:, 1]], axis=1) > max_edge
        if not long_edge.any():
            return V, F
        mid_index = np.full(len(uniq), -1, np.int64)
        mid_index[long_edge] = len(V) + np.arange(long_edge.sum())
        V = np.vstack([V, 0.5 * (V[uniq[long_edge, 0]] + V[uniq[long_edge, 1]])])
        marked = long_edge[inv]  # (K, 3)
        mids = mid_index[inv]  # (K, 3): midpoint of edge j (v_j, v_j+1), -1 when not split
        count = marked.sum(axis=1)
        # Rotate each face (v0 v1 v2) -> (v_k v_k+1 v_k+2) so that: one mark -> edge 0; two -> edges 0, 1.
        first = np.where(count == 1, np.argmax(marked, axis=1), np.where(count == 2, (np.argmin(marked, axis=1) + 1) % 3, 0))
        rot = (first[:, None] + np.arange(3)[None]) % 3
        rows = np.arange(len(F))[:, None]
        f, m = F[rows, rot], mids[rows, rot]
        v0, v1, v2, a, b, c = f[:, 0], f[:, 1], f[:, 2], m[:, 0], m[:, 1], m[:, 2]
        new = [f[count == 0]]
        s1 = count == 1
        new += [np.stack([v0, a, v2], 1)[s1], np.stack([a, v1, v2], 1)[s1]]
        s2 = count == 2
        new += [np.stack([a, v1, b], 1)[s2], np.stack([v0, a, b], 1)[s2], np.stack([v0, b, v2], 1)[s2]]
        s3 = count == 3
        new += [np.stack([v0, a, c], 1)[s3], np.stack([a, v1, b], 1)[s3], np.stack([c, b, v2], 1)[s3], np.stack([a, b, c], 1)[s3]]
        F = np.vstack(new)
    raise RuntimeError(f"refine_to_edge_length: edges still longer than {max_edge} after {max_rounds} rounds")


def _retriangulate_base(g, V, F, h: float):
    """Replace the sheet's flat base faces (the core's top between the rods, spanned by the rims'
    vertices alone) by a Delaunay triangulation of those rim vertices plus a square grid of spacing h
    that keeps h / 2 clear of the rims, the disks inside the rims removed. The rims' vertices and every
    other face are kept, so the sheet stays conforming."""
    from scipy.spatial import Delaunay

    z = g.base_thickness_m - g.core_depth_m
    tol = 1e-9 + 1e-6 * max(g.size_x_m, g.size_y_m)
    flat_v = np.abs(V[:, 2] - z) < tol
    flat_f = flat_v[F].all(axis=1)
    if not flat_f.any():
        return V, F
    rim_radius = g.rod_radius_m  # the core's fillet leaves the base plane at the rod's radius
    keep_f = F[~flat_f]
    used_by_others = np.zeros(len(V), bool)
    used_by_others[keep_f.ravel()] = True
    rim = np.flatnonzero(flat_v & used_by_others)
    hx, hy = g.size_x_m / 2, g.size_y_m / 2
    nx, ny = max(int(np.ceil(2 * hx / h)), 1), max(int(np.ceil(2 * hy / h)), 1)
    gx, gy = np.meshgrid(np.linspace(-hx, hx, nx + 1), np.linspace(-hy, hy, ny + 1))
    grid = np.stack([gx.ravel(), gy.ravel()], axis=1)
    d = np.linalg.norm(grid[:, None, :] - g.centres_m[None], axis=2).min(axis=1)
    grid = grid[d > rim_radius + 0.5 * h]
    # the rims' own points on the square's edge (a rod at the border) stay; drop grid points on top of them
    if len(rim):
        from scipy.spatial import cKDTree

        near, _ = cKDTree(V[rim, :2]).query(grid, k=1)
        grid = grid[near > 0.5 * h]
    pts2 = np.vstack([V[rim, :2], grid])
    tri = Delaunay(pts2).simplices
    c = pts2[tri].mean(axis=1)
    inside = (np.linalg.norm(c[:, None, :] - g.centres_m[None], axis=2) < rim_radius - tol).any(axis=1)
    tri = tri[~inside]
    a, b, cc = pts2[tri[:, 0]], pts2[tri[:, 1]], pts2[tri[:, 2]]
    ccw = (b[:, 0] - a[:, 0]) * (cc[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (cc[:, 0] - a[:, 0]) > 0
    tri = np.where(ccw[:, None], tri, tri[:, ::-1])  # normals up (+z), out of the core, like the rest
    index = np.concatenate([rim, len(V) + np.arange(len(grid))])
    V2 = np.vstack([V, np.column_stack([grid, np.full(len(grid), z)])])
    F2 = np.vstack([keep_f, index[tri]])
    used = np.zeros(len(V2), bool)
    used[F2.ravel()] = True
    remap = np.cumsum(used) - 1
    return V2[used], remap[F2]
