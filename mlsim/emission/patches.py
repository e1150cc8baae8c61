"""The emitting patches of the ML layer and the FEM stress they feel.

A patch is a vertex of the ML layer's inner face (:func:`fem.geometry.emitting_surface`, the sheet
the renderer draws and whose per-vertex emission it reads), with a third of the area of its
faces. Its stress is the FEM stress at the middle of the ML layer above it: the vertex moved out
along its normal by half the ML thickness, located in the tet mesh. The FEM stress is one value
per tet (its centroid), so a patch takes its containing tet's value (piecewise constant; the
ML layer is resolved to the mesh's edge length, see ``fidelity.mesh.edge_length_mm``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["MLPatches", "ml_patches"]


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


def ml_patches(geometry, mesh, segments: int = 48) -> MLPatches:
    """The emitting patches of a :class:`fem.geometry.RodArray` and the tets of its FEM ``mesh``
    (:class:`fem.mesh.TetMesh`) that hold their stress sample points."""
    from fem.geometry import emitting_surface
    from fem.mesh import locate_points

    sheet = emitting_surface(geometry, segments)
    V = np.asarray(sheet.vertices, dtype=float)
    F = np.asarray(sheet.faces)
    area = np.bincount(F.ravel(), weights=np.repeat(sheet.area_faces / 3.0, 3), minlength=len(V))
    normals = np.asarray(sheet.vertex_normals, dtype=float)
    sample = V + 0.5 * geometry.ml_m * normals
    tet, _ = locate_points(mesh.points, mesh.tets, sample)
    on_base = V[:, 2] <= geometry.base_thickness_m - geometry.core_depth_m + 1e-9  # the core's top, under the layers
    _, r = geometry.radial(V)
    rod = np.where(on_base & (r > geometry.rod_radius_m - geometry.core_depth_m + 1e-9), -1, geometry.rod_of(V))
    return MLPatches(V, F, normals, area, rod, sample, tet)
