"""Rigid indenters as signed distance functions: gap and contact normal at body points.

Each shape is described in its own frame: the origin at its lowest point on its vertical axis,
z up, x along the shape's length (for the cylinder); a pose (position of that origin and yaw about
the vertical axis) places it in the sensor frame. For points X (M, 3) in the sensor frame,
:func:`gap_and_normal` returns the signed distance to the indenter's surface (positive outside:
the gap; negative inside: the penetration) and the unit outward normal of the indenter at the
closest surface point, i.e. the direction the indenter pushes a penetrating point. Lengths in m.

Shapes (SPEC 1.5 and the scene's ``load.indenter``):

- ``flat``: a circular punch of radius a (its face at z = 0, its body above), e.g. the 5 cm^2 probe,
  its rim rounded with ``edge_radius_m`` (scene default 0.5 mm: a machined probe's edge is never
  sharp, and a sharp rim has no normal, which stalls the contact Newton on its leading edge);
- ``sphere``: radius rho, centre at z = rho;
- ``cylinder``: radius rho and length l lying along x (the M8 screw), axis at z = rho;
- ``box``: size (sx, sy, sz), bottom face at z = 0, edges rounded with ``edge_radius_m``.

The distances are exact Euclidean distances to these solids (the flat punch is a cylinder of
height h; the lying cylinder has flat end caps). They are 1-Lipschitz and their gradients, the
normals, have unit length wherever they are defined (tested).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IndenterShape", "Pose", "signed_distance_local", "gap_and_normal", "rigid_motion", "shape_from_scene"]


@dataclass(frozen=True)
class IndenterShape:
    kind: str  # "flat" | "sphere" | "cylinder" | "box"
    size_m: tuple[float, ...]  # flat: (radius, height); sphere: (radius,); cylinder: (radius, length); box: (sx, sy, sz)
    edge_radius_m: float = 0.0  # flat and box: the edges rounded with this radius (a sharp edge has no normal)

    def __post_init__(self):
        expected = {"flat": 2, "sphere": 1, "cylinder": 2, "box": 3}
        if self.kind not in expected:
            raise ValueError(f'"{self.kind}" is not an indenter shape; choose one of: {", ".join(expected)}')
        if len(self.size_m) != expected[self.kind] or not all(np.isfinite(s) and s > 0 for s in self.size_m):
            raise ValueError(f"{self.kind} indenter size_m = {self.size_m}: needs {expected[self.kind]} finite values > 0")
        if self.kind in ("flat", "box"):
            limit = min(self.size_m[0], self.size_m[1] / 2) if self.kind == "flat" else min(self.size_m) / 2
        else:
            limit = 0.0
        if not (0.0 <= self.edge_radius_m < limit or self.edge_radius_m == 0.0):
            raise ValueError(f"{self.kind} indenter edge_radius_m = {self.edge_radius_m}: must be >= 0 and below {limit} (half the smallest size)")


@dataclass(frozen=True)
class Pose:
    position_m: tuple[float, float, float]
    yaw_rad: float = 0.0


def _capped_cylinder_z(p, radius, height):
    """SDF of the solid {x^2 + y^2 <= r^2, 0 <= z <= h} (axis z)."""
    r = np.hypot(p[:, 0], p[:, 1])
    dr = r - radius
    dz = np.maximum(-p[:, 2], p[:, 2] - height)
    outside = np.hypot(np.maximum(dr, 0), np.maximum(dz, 0))
    inside = np.minimum(np.maximum(dr, dz), 0.0)
    return outside + inside


def _box(p, half):
    q = np.abs(p) - half
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def signed_distance_local(shape: IndenterShape, p: np.ndarray) -> np.ndarray:
    """Signed distance (M,) of points (M, 3) given in the indenter's own frame."""
    p = np.asarray(p, dtype=float)
    re = shape.edge_radius_m
    if shape.kind == "flat":
        radius, height = shape.size_m
        # rounded edges: the shrunk solid's distance minus the rounding radius (exact)
        return _capped_cylinder_z(p - [0.0, 0.0, re], radius - re, height - 2 * re) - re
    if shape.kind == "sphere":
        (radius,) = shape.size_m
        return np.linalg.norm(p - [0.0, 0.0, radius], axis=1) - radius
    if shape.kind == "cylinder":
        radius, length = shape.size_m
        # Axis along x at height radius: swap to a z-axis capped cylinder centred on its length.
        q = np.column_stack([p[:, 1], p[:, 2] - radius, p[:, 0] + length / 2])
        return _capped_cylinder_z(q, radius, length)
    sx, sy, sz = shape.size_m
    return _box(p - [0.0, 0.0, sz / 2], np.array([sx, sy, sz]) / 2 - re) - re


def _to_local(pose: Pose, X: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    d = np.asarray(X, dtype=float) - np.asarray(pose.position_m)
    return np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], d[:, 2]])


def _from_local(pose: Pose, p: np.ndarray) -> np.ndarray:
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    return np.column_stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1], p[:, 2]]) + np.asarray(pose.position_m)


def rigid_motion(old: Pose, new: Pose, X: np.ndarray) -> np.ndarray:
    """Displacement (M, 3) of the indenter's material points at X (M, 3) from pose ``old`` to ``new``
    (what a point of the body sticking to the indenter is dragged by)."""
    X = np.asarray(X, dtype=float)
    return _from_local(new, _to_local(old, X)) - X


def gap_and_normal(shape: IndenterShape, pose: Pose, X: np.ndarray, h: float | None = None):
    """Gap (M,) m and unit outward normal (3, M) of the posed indenter at points X (M, 3).

    The normal is the gradient of the signed distance, by central differences of step ``h``
    (default 1e-4 of the indenter's smallest size): exact for the planar and spherical pieces up
    to round-off, and within h / (radius of curvature) near edges and on curved sides.
    """
    X = np.asarray(X, dtype=float)
    h = 1e-4 * min(shape.size_m) if h is None else h
    gap = signed_distance_local(shape, _to_local(pose, X))
    grad = np.empty((3, len(X)))
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        grad[k] = (signed_distance_local(shape, _to_local(pose, X + e)) - signed_distance_local(shape, _to_local(pose, X - e))) / (2 * h)
    norm = np.linalg.norm(grad, axis=0)
    return gap, grad / np.maximum(norm, 1e-300)


def shape_from_scene(indenter) -> IndenterShape:
    """The shape of a validated scene indenter (:mod:`mlsim.scene`, millimetres) in metres."""
    mm = 1e-3
    if indenter.shape == "flat":
        return IndenterShape("flat", (indenter.tip_diameter_mm / 2 * mm, indenter.height_mm * mm), indenter.edge_radius_mm * mm)
    if indenter.shape == "sphere":
        return IndenterShape("sphere", (indenter.diameter_mm / 2 * mm,))
    if indenter.shape == "cylinder":
        return IndenterShape("cylinder", (indenter.diameter_mm / 2 * mm, indenter.length_mm * mm))
    return IndenterShape("box", tuple(s * mm for s in indenter.size_mm), indenter.edge_radius_mm * mm)
