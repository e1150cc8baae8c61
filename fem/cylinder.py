"""A single solid rod clamped at its base: the body of the beam verification cases.

A circular cylinder of radius ``R`` and length ``L`` along +z, its base disk at z = 0. It implements
the body protocol of :func:`fem.mesh.build_mesh` (:class:`fem.mesh.MeshableBody`) with the tags of
:class:`fem.geometry.FaceTag`: ``BASE_BOTTOM`` (the clamped disk), ``ROD_SIDE`` and ``ROD_TIP``. It is
one material throughout (every point is "core"). Lengths in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from fem.geometry import FaceTag, Layer, midpoints_on_shared_pieces

__all__ = ["Cylinder"]


@dataclass(frozen=True)
class Cylinder:
    radius_m: float
    length_m: float

    def __post_init__(self):
        for name in ("radius_m", "length_m"):
            v = getattr(self, name)
            if not (np.isfinite(v) and v > 0):
                raise ValueError(f"{name} = {v}: must be finite and > 0")

    #: One material throughout: no layer interfaces.
    layer_interfaces_m: ClassVar[tuple[float, ...]] = ()

    # -- analytic measures -------------------------------------------------------------------
    def volume_m3(self) -> float:
        return math.pi * self.radius_m**2 * self.length_m

    def layer_volumes_m3(self) -> dict[str, float]:
        return {"absorber": 0.0, "ml": 0.0, "core": self.volume_m3()}

    def face_areas_m2(self) -> dict[FaceTag, float]:
        r, length = self.radius_m, self.length_m
        return {FaceTag.BASE_BOTTOM: math.pi * r * r, FaceTag.ROD_SIDE: 2 * math.pi * r * length, FaceTag.ROD_TIP: math.pi * r * r}

    # -- surfaces and points ------------------------------------------------------------------
    def outer_surface(self, segments: int = 48):
        import manifold3d as m3
        import trimesh

        mesh = m3.Manifold.cylinder(self.length_m, self.radius_m, self.radius_m, segments).to_mesh64()
        v = np.asarray(mesh.vert_properties, dtype=float)[:, :3]
        return trimesh.Trimesh(v, np.asarray(mesh.tri_verts, dtype=np.int64), process=False)

    def depth_below_top(self, points: np.ndarray) -> np.ndarray:
        """Distance to the loadable surface (side and tip); 0 outside."""
        p = np.asarray(points, dtype=float)
        r = np.hypot(p[:, 0], p[:, 1])
        d = np.minimum(self.radius_m - r, self.length_m - p[:, 2])
        return np.where((p[:, 2] < 0) | (d < 0), 0.0, d)

    def layer_index(self, points: np.ndarray) -> np.ndarray:
        return np.full(len(points), Layer.CORE, dtype=np.int8)

    def region_of(self, points: np.ndarray) -> np.ndarray:
        return np.zeros(len(points), dtype=np.int32)

    def check_regions(self, points, tets, volumes) -> str | None:
        return None  # one region: the total volume check of build_mesh covers it

    def _distances(self, points: np.ndarray):
        p = np.asarray(points, dtype=float)
        r = np.hypot(p[:, 0], p[:, 1])
        z = p[:, 2]
        big_r, length = self.radius_m, self.length_m
        d = np.full((len(p), len(FaceTag)), np.inf)
        d[:, FaceTag.BASE_BOTTOM] = np.hypot(z, np.maximum(r - big_r, 0.0))
        d[:, FaceTag.ROD_SIDE] = np.hypot(r - big_r, np.maximum(-z, 0.0) + np.maximum(z - length, 0.0))
        d[:, FaceTag.ROD_TIP] = np.hypot(z - length, np.maximum(r - big_r, 0.0))
        return d, np.zeros(len(p), dtype=np.int64)

    def classify_boundary(self, points: np.ndarray):
        d, _ = self._distances(points)
        tag = np.argmin(d, axis=1).astype(np.int8)
        on_rod = (tag == FaceTag.ROD_SIDE) | (tag == FaceTag.ROD_TIP)
        return tag, np.where(on_rod, 0, -1).astype(np.int32), d[np.arange(len(d)), tag]

    def _onto_carriers(self, points, pieces, part=None, tol=0.0):
        """Project onto each chosen piece's carrier (z = 0, r = R, z = L) in turn."""
        q = np.array(points, dtype=float)
        q[pieces[:, FaceTag.BASE_BOTTOM], 2] = 0.0
        q[pieces[:, FaceTag.ROD_TIP], 2] = self.length_m
        side = pieces[:, FaceTag.ROD_SIDE]
        r = np.maximum(np.hypot(q[side, 0], q[side, 1]), 1e-300)
        q[side, :2] *= (self.radius_m / r)[:, None]
        return q

    def project_to_surface(self, points: np.ndarray, edge_tol_m: float = 0.0) -> np.ndarray:
        p = np.asarray(points, dtype=float)
        d, _ = self._distances(p)
        tag = np.argmin(d, axis=1)
        pieces = np.zeros(d.shape, dtype=bool)
        pieces[np.arange(len(d)), tag] = True
        out = self._onto_carriers(p, pieces)
        # the nearest point of a cap, for points outside its rim, is on the rim
        r = np.hypot(out[:, 0], out[:, 1])
        cap = (tag != FaceTag.ROD_SIDE) & (r > self.radius_m)
        out[cap, :2] *= (self.radius_m / r[cap])[:, None]
        out[tag == FaceTag.ROD_SIDE, 2] = np.clip(out[tag == FaceTag.ROD_SIDE, 2], 0.0, self.length_m)
        if edge_tol_m > 0:
            corner = (d <= edge_tol_m).sum(axis=1) >= 2
            out[corner] = self._onto_carriers(p[corner], d[corner] <= edge_tol_m)
        return out

    def project_edge_midpoints(self, a: np.ndarray, b: np.ndarray, tol_m: float) -> np.ndarray:
        return midpoints_on_shared_pieces(self._distances, self.project_to_surface, self._onto_carriers, a, b, tol_m)
