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
normals, have unit length wherever they are defined (tested). Gradients and Hessians are analytic
(tested against finite differences): the contact Newton needs both at every iteration, and finite
differences cost 49 distance evaluations per point where the closed forms cost about two.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["IndenterShape", "Pose", "signed_distance_local", "gap", "gap_and_normal", "gap_normal", "gap_normal_hessian", "rigid_motion", "shape_from_scene"]


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


def _capped_cylinder_z(p, radius, height, derivatives: bool = False):
    """SDF of the solid {x^2 + y^2 <= r^2, 0 <= z <= h} (axis z); with ``derivatives`` also its
    gradient (M, 3) and Hessian (M, 3, 3).

    In the (rho, z) half-plane the distance is that of a 2-D box in (dr, dz) = (rho - r,
    max(-z, z - h)); the chain rule through rho = |(x, y)| adds (dD/d dr) (I_xy - e_rho e_rho^T) / rho,
    the curvature of the side."""
    r = np.hypot(p[:, 0], p[:, 1])
    dr = r - radius
    below = -p[:, 2] > p[:, 2] - height
    dz = np.where(below, -p[:, 2], p[:, 2] - height)
    a, b = np.maximum(dr, 0.0), np.maximum(dz, 0.0)
    outside = np.hypot(a, b)
    inside = np.minimum(np.maximum(dr, dz), 0.0)
    d = outside + inside
    if not derivatives:
        return d
    m = len(p)
    safe_r = np.maximum(r, 1e-300)
    e_r = np.zeros((m, 3))
    e_r[:, 0] = np.where(r > 0, p[:, 0] / safe_r, 1.0)  # on the axis any radial direction will do
    e_r[:, 1] = np.where(r > 0, p[:, 1] / safe_r, 0.0)
    e_z = np.zeros((m, 3))
    e_z[:, 2] = np.where(below, -1.0, 1.0)
    out = outside > 0
    safe_o = np.where(out, outside, 1.0)
    # d D / d(dr), d D / d(dz): (a, b) / |(a, b)| outside; the larger of (dr, dz) inside
    w_r = np.where(out, a / safe_o, (dr >= dz).astype(float))
    w_z = np.where(out, b / safe_o, (dr < dz).astype(float))
    grad = w_r[:, None] * e_r + w_z[:, None] * e_z
    if derivatives == "gradient":
        return d, grad
    # 2-D Hessian in (dr, dz): (diag(a > 0, b > 0) - w w^T) / |(a, b)| outside, zero inside
    pr, pz = (a > 0).astype(float), (b > 0).astype(float)
    h_rr = np.where(out, (pr - w_r * w_r) / safe_o, 0.0)
    h_zz = np.where(out, (pz - w_z * w_z) / safe_o, 0.0)
    h_rz = np.where(out, -w_r * w_z / safe_o, 0.0)
    H = (h_rr[:, None, None] * e_r[:, :, None] * e_r[:, None, :] + h_zz[:, None, None] * e_z[:, :, None] * e_z[:, None, :]
         + h_rz[:, None, None] * (e_r[:, :, None] * e_z[:, None, :] + e_z[:, :, None] * e_r[:, None, :]))
    P_xy = np.zeros((m, 3, 3))
    P_xy[:, 0, 0] = P_xy[:, 1, 1] = 1.0
    side = w_r / np.where(r > 0, safe_r, np.inf)  # no curvature term on the axis (w_r = 0 there but for a zero-radius solid)
    H += side[:, None, None] * (P_xy - e_r[:, :, None] * e_r[:, None, :])
    return d, grad, H


def _box(p, half, derivatives: bool = False):
    """SDF of the box |p_i| <= half_i; with ``derivatives`` also gradient (M, 3) and Hessian (M, 3, 3):
    outside, the distance to the nearest face, edge or corner, (D - n n^T) / d with D the diagonal
    of the axes the point lies beyond; inside, the nearest face's (flat)."""
    q = np.abs(p) - half
    qp = np.maximum(q, 0.0)
    outside = np.linalg.norm(qp, axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    d = outside + inside
    if not derivatives:
        return d
    m = len(p)
    sign = np.where(p < 0, -1.0, 1.0)
    out = outside > 0
    safe_o = np.where(out, outside, 1.0)
    nearest = np.zeros((m, 3))
    nearest[np.arange(m), q.argmax(axis=1)] = 1.0
    grad = sign * np.where(out[:, None], qp / safe_o[:, None], nearest)
    if derivatives == "gradient":
        return d, grad
    beyond = (q > 0).astype(float)
    H = (beyond[:, :, None] * np.eye(3)[None] - grad[:, :, None] * grad[:, None, :]) / safe_o[:, None, None]
    H[~out] = 0.0
    return d, grad, H


def signed_distance_local(shape: IndenterShape, p: np.ndarray, derivatives: bool | str = False):
    """Signed distance (M,) of points (M, 3) given in the indenter's own frame; with ``derivatives``,
    (distance, gradient (M, 3), Hessian (M, 3, 3)), exact (analytic) wherever they are defined; with
    ``derivatives="gradient"``, (distance, gradient) (the Hessian is most of the cost)."""
    p = np.asarray(p, dtype=float)
    re = shape.edge_radius_m
    if shape.kind == "flat":
        radius, height = shape.size_m
        # rounded edges: the shrunk solid's distance minus the rounding radius (exact); same derivatives
        out = _capped_cylinder_z(p - [0.0, 0.0, re], radius - re, height - 2 * re, derivatives)
    elif shape.kind == "sphere":
        (radius,) = shape.size_m
        v = p - [0.0, 0.0, radius]
        dist = np.linalg.norm(v, axis=1)
        if not derivatives:
            return dist - radius
        safe = np.maximum(dist, 1e-300)
        n = v / safe[:, None]
        n[dist == 0] = [0.0, 0.0, 1.0]
        if derivatives == "gradient":
            return dist - radius, n
        return dist - radius, n, (np.eye(3)[None] - n[:, :, None] * n[:, None, :]) / safe[:, None, None]
    elif shape.kind == "cylinder":
        radius, length = shape.size_m
        # Axis along x at height radius: q = A p + b with the axis as q_z, a capped cylinder centred on its length.
        q = np.column_stack([p[:, 1], p[:, 2] - radius, p[:, 0] + length / 2])
        out = _capped_cylinder_z(q, radius, length, derivatives)
        if derivatives:
            perm = [2, 0, 1]  # A^T: p_x <- q_z, p_y <- q_x, p_z <- q_y
            out = (out[0], out[1][:, perm]) if derivatives == "gradient" else (out[0], out[1][:, perm], out[2][:, perm][:, :, perm])
    else:
        sx, sy, sz = shape.size_m
        out = _box(p - [0.0, 0.0, sz / 2], np.array([sx, sy, sz]) / 2 - re, derivatives)
    if not derivatives:
        return out - re
    return (out[0] - re, *out[1:])


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


def gap(shape: IndenterShape, pose: Pose, X: np.ndarray) -> np.ndarray:
    """Gap (M,) m of the posed indenter at points X (M, 3): the signed distance alone (no derivatives,
    for the per-step tunnelling guard and the path screening)."""
    return signed_distance_local(shape, _to_local(pose, np.asarray(X, dtype=float)))


def gap_and_normal(shape: IndenterShape, pose: Pose, X: np.ndarray):
    """Gap (M,) m and unit outward normal (3, M) of the posed indenter at points X (M, 3): the signed
    distance and its gradient, analytic (:func:`signed_distance_local`)."""
    gap, n = gap_normal(shape, pose, X)
    return gap, n.T


def gap_normal(shape: IndenterShape, pose: Pose, X: np.ndarray):
    """Gap (M,) m and unit outward normal (M, 3) of the posed indenter at points X (M, 3), in the
    sensor frame: :func:`gap_normal_hessian` without the Hessian (a seventh of its cost)."""
    d, g = signed_distance_local(shape, _to_local(pose, X), derivatives="gradient")
    R = _to_sensor(pose)
    return d, g @ R.T


def gap_normal_hessian(shape: IndenterShape, pose: Pose, X: np.ndarray):
    """Gap (M,) m, unit outward normal (M, 3) and the normal's gradient dn/dX = the distance's Hessian
    (M, 3, 3) 1/m, of the posed indenter at points X (M, 3), in the sensor frame.

    The Hessian is zero on flat faces, (I - n n^T) / rho on a sphere of radius rho, and jumps where a
    rounded edge meets a face; all exact, where finite differences straddling such a jump are right on
    neither side."""
    d, g, H = signed_distance_local(shape, _to_local(pose, X), derivatives=True)
    R = _to_sensor(pose)
    return d, g @ R.T, R @ H @ R.T


def _to_sensor(pose: Pose) -> np.ndarray:
    """The rotation (3, 3) from the indenter's frame to the sensor frame (its yaw about z)."""
    c, s = np.cos(pose.yaw_rad), np.sin(pose.yaw_rad)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


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
