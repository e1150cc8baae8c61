"""Labelled tetrahedral mesh of the rod array.

Pipeline of :func:`build_mesh`:

1. The watertight outer surface (:func:`fem.geometry.outer_surface`) is tetrahedralised by fTetWild
   [Hu2020]_ through pytetwild, in a subprocess with a time limit, because fTetWild sometimes hangs
   or emits zero-volume tets (seen here with pytetwild 0.4.2 on the 5 x 5 array).
2. The result is validated: consistent orientation (fTetWild's tets come out negatively oriented;
   we swap two columns), no degenerate tets, total and per-rod volumes close to the analytic ones.
   A failed attempt is retried with a slightly perturbed edge length.
3. Boundary nodes are snapped onto the exact surface (:func:`fem.geometry.project_to_surface`):
   fTetWild keeps its surface within an envelope ``epsilon`` of the input but biased inwards
   (-0.65 % volume at epsilon = 0.05 mm on the default array); snapping removes that bias. Tets
   that a snap would invert keep their original nodes.
4. The mesh carries quadratic (10-node) geometry: a node at the middle of every edge, and on the
   boundary that node is projected onto the exact surface, so element faces follow the rods'
   curvature. Straight (linear) faces on the rods would be chords: at the default size they lose
   about 0.6 % of the body's volume, all of it from the 0.3 mm absorber (-3.6 %), and they thin
   the rods' bending section. A tet that curving would fold (Jacobian <= 10 % of its straight
   value at any check point) keeps straight edges.
5. Each tet gets the volume fraction of each layer (absorber, ML, core) by sampling the analytic
   layer classifier (:func:`fem.geometry.layer_index`) at the centroids of ``8**levels`` equal
   sub-tets of its red refinement [Bey1995]_, mapped through the quadratic geometry and weighted
   by its Jacobian; tets whose depth interval (centroid depth +- node radius, the depth being
   1-Lipschitz) lies inside one layer are pure and need no sampling.
6. Boundary faces are tagged by the nearest piece of the exact boundary (:class:`FaceTag`).

fTetWild is not deterministic (the same input gives a different mesh on every run), so the
accepted mesh is cached by content hash and the cached file is the artefact later stages use; its
hash (:meth:`TetMesh.content_hash`) is recorded in every output.

References
----------
.. [Hu2020] Y. Hu, T. Schneider, B. Wang, D. Zorin, D. Panozzo, "Fast Tetrahedral Meshing in the
   Wild", ACM Trans. Graph. 39(4) (2020) 117.
.. [Bey1995] J. Bey, "Tetrahedral grid refinement", Computing 55 (1995) 355-378.
"""

from __future__ import annotations

import hashlib
import math
import os
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from typing import Protocol

from fem.geometry import FaceTag
from mlsim.errors import MeshingError

__all__ = [
    "TetMesh",
    "MeshParams",
    "MeshableBody",
    "build_mesh",
    "signed_volumes",
    "locate_points",
    "boundary_faces",
    "edge_table",
    "dihedral_angles_deg",
    "quality_report",
    "orient_tets",
    "p2_map",
    "layer_fractions",
    "red_refinement",
    "red_refinement_centroids",
    "mesh_report",
    "write_vtu",
    "TET10_EDGES",
    "SLIVER_DIHEDRAL_DEG",
]

#: A tet whose smallest dihedral angle is below this is counted as a sliver in the quality report.
SLIVER_DIHEDRAL_DEG = 5.0
#: A tet smaller than this fraction of the mean tet volume is degenerate: the mesh is refused.
DEGENERATE_VOLUME_FRACTION = 1e-7
#: Local vertex pairs of the six edges of a 10-node tet, in VTK / meshio ``tetra10`` order.
TET10_EDGES = np.array([[0, 1], [1, 2], [0, 2], [0, 3], [1, 3], [2, 3]])
#: Local vertex pairs of the three edges of a 6-node triangle (VTK ``triangle6`` order).
TRI6_EDGES = np.array([[0, 1], [1, 2], [2, 0]])


class MeshableBody(Protocol):
    """What :func:`build_mesh` needs of a body (metres): :class:`fem.geometry.RodArray` (the sensor)
    and :class:`fem.cylinder.Cylinder` (a clamped rod, for verification) implement it."""

    layer_interfaces_m: tuple[float, ...]

    def outer_surface(self, segments: int): ...
    def volume_m3(self) -> float: ...
    def layer_volumes_m3(self) -> dict[str, float]: ...
    def face_areas_m2(self) -> dict: ...
    def depth_below_top(self, points): ...
    def layer_index(self, points): ...
    def classify_boundary(self, points): ...
    def project_to_surface(self, points, edge_tol_m: float = 0.0): ...
    def project_edge_midpoints(self, a, b, tol_m: float): ...
    def region_of(self, points): ...
    def check_regions(self, points, tets, volumes) -> str | None: ...


@dataclass(frozen=True)
class MeshParams:
    """Meshing settings in SI units (from the scene's ``fidelity.mesh``)."""

    edge_length_m: float
    envelope_m: float
    coarsen: bool = True
    segments_per_circle: int = 48
    fraction_levels: int = 3
    timeout_s: float = 240.0
    retries: int = 3

    @classmethod
    def from_fidelity(cls, f) -> "MeshParams":
        return cls(
            edge_length_m=f.edge_length_mm * 1e-3,
            envelope_m=f.resolved_envelope_mm * 1e-3,
            coarsen=f.coarsen,
            segments_per_circle=f.segments_per_circle,
            fraction_levels=f.fraction_levels,
            timeout_s=f.timeout_s,
            retries=f.retries,
        )


@dataclass(frozen=True, eq=False)
class TetMesh:
    """A validated, positively oriented tet mesh with quadratic geometry, layer fractions and tagged faces.

    points: (P, 3) m, the vertices. tets: (T, 4) int64. edge_nodes: (E, 3) m, the mid-edge nodes
    (on the exact surface for boundary edges). tet_edges: (T, 6) edge index of each tet's edges in
    :data:`TET10_EDGES` order, so the 10-node connectivity is ``[tets, P + tet_edges]``.
    layer_fraction: (T, 3) absorber, ML, core (rows sum to 1). tet_rod: (T,) rod index of the tet's
    centroid, -1 in the base. faces: (F, 3) boundary triangles ordered so their normals point out
    of the body; face_edges: (F, 3) their edges in :data:`TRI6_EDGES` order. face_tag: (F,)
    :class:`FaceTag`. face_rod: (F,) rod index for rod faces, else -1.
    """

    points: np.ndarray
    tets: np.ndarray
    edge_nodes: np.ndarray
    tet_edges: np.ndarray
    layer_fraction: np.ndarray
    tet_rod: np.ndarray
    faces: np.ndarray
    face_edges: np.ndarray
    face_tag: np.ndarray
    face_rod: np.ndarray

    @property
    def n_points(self) -> int:
        return len(self.points)

    @property
    def n_tets(self) -> int:
        return len(self.tets)

    @property
    def points10(self) -> np.ndarray:
        """(P + E, 3) all nodes of the quadratic mesh."""
        return np.concatenate([self.points, self.edge_nodes])

    @property
    def tets10(self) -> np.ndarray:
        """(T, 10) quadratic connectivity (VTK ``tetra10`` order) into :attr:`points10`."""
        return np.concatenate([self.tets, self.n_points + self.tet_edges], axis=1)

    def volumes(self) -> np.ndarray:
        """(T,) volumes (m^3) of the curved tets, exact (degree-3 quadrature of the cubic Jacobian)."""
        return _p2_volumes(self.points10[self.tets10])

    def linear_volumes(self) -> np.ndarray:
        """(T,) volumes (m^3) of the straight-sided tets through the vertices."""
        return signed_volumes(self.points, self.tets)

    def face_areas(self) -> np.ndarray:
        """(F,) areas (m^2) of the curved boundary faces (degree-4 quadrature)."""
        nodes = np.concatenate([self.points[self.faces], self.edge_nodes[self.face_edges]], axis=1)
        return _p2_triangle_areas(nodes)

    def content_hash(self) -> str:
        """SHA-256 of the mesh's arrays: the identity of a mesh across runs and machines."""
        h = hashlib.sha256()
        for name in _ARRAYS:
            a = np.ascontiguousarray(getattr(self, name))
            h.update(name.encode())
            h.update(str(a.dtype).encode() + str(a.shape).encode())
            h.update(a.tobytes())
        return h.hexdigest()

    def save(self, path: str | Path) -> None:
        """Write an .npz atomically (a partial file never carries the final name)."""
        path = Path(path)
        tmp = path.with_name(path.name + ".part.npz")
        np.savez_compressed(tmp, **{k: getattr(self, k) for k in _ARRAYS})
        os.replace(tmp, path)

    @classmethod
    def load(cls, path: str | Path) -> "TetMesh":
        with np.load(path) as data:
            return cls(**{k: data[k] for k in _ARRAYS})


_ARRAYS = ("points", "tets", "edge_nodes", "tet_edges", "layer_fraction", "tet_rod", "faces", "face_edges", "face_tag", "face_rod")


# ----------------------------------------------------------------------------------- measures
def locate_points(points: np.ndarray, tets: np.ndarray, X: np.ndarray, k: int = 24, exhaustive_below: float | None = None):
    """The tet (points (P, 3), tets (T, 4)) holding each of X (M, 3), and X's barycentric coordinates in it.

    Candidates are the k tets with the nearest centroids; the holder is the one whose smallest
    barycentric coordinate is largest (exactly the containing tet when there is one; the nearest by
    that measure for a point just outside a curved boundary the straight tets cut). With
    ``exhaustive_below``, points whose best coordinate is below -exhaustive_below among the k (a long
    tet's centroid can be far from a point inside it) are tried against every tet.
    Returns tet (M,) and bary (M, 4).
    """
    from scipy.spatial import cKDTree

    V = points[tets]  # (T, 4, 3)
    X = np.atleast_2d(np.asarray(X, dtype=float))

    def best_of(cand, x):  # cand (M, C) tets for points x (M, 3)
        A = V[cand]
        E = np.stack([A[:, :, 1] - A[:, :, 0], A[:, :, 2] - A[:, :, 0], A[:, :, 3] - A[:, :, 0]], axis=-1)
        b = np.linalg.solve(E, (x[:, None, :] - A[:, :, 0])[..., None])[..., 0]
        bary = np.concatenate([1.0 - b.sum(axis=-1, keepdims=True), b], axis=-1)
        best = np.argmax(bary.min(axis=-1), axis=1)
        rows = np.arange(len(x))
        return cand[rows, best], bary[rows, best]

    _, cand = cKDTree(V.mean(axis=1)).query(X, k=min(k, len(tets)))
    tet, bary = best_of(np.asarray(cand).reshape(len(X), -1), X)
    if exhaustive_below is not None:
        for i in np.flatnonzero(bary.min(axis=1) < -exhaustive_below):
            t, b = best_of(np.arange(len(tets))[None], X[i : i + 1])
            tet[i], bary[i] = t[0], b[0]
    return tet, bary


def signed_volumes(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T,) signed volumes of straight tets (positive when (v1-v0, v2-v0, v3-v0) is right-handed)."""
    p = points[tets]
    a, b, c = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0], p[:, 3] - p[:, 0]
    return np.einsum("ij,ij->i", a, np.cross(b, c)) / 6.0


# Faces of a positively oriented tet, each ordered so its normal points outwards.
_TET_FACES = np.array([[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]])


def boundary_faces(tets: np.ndarray) -> np.ndarray:
    """(F, 3) faces that belong to exactly one tet, outward for positively oriented tets."""
    faces = tets[:, _TET_FACES].reshape(-1, 3)
    key = np.sort(faces, axis=1)
    _, inverse, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    return faces[counts[inverse.ravel()] == 1]


def edge_table(tets: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unique edges (E, 2), each tet's edges (T, 6) in :data:`TET10_EDGES` order, each face's (F, 3)."""
    pairs = np.sort(tets[:, TET10_EDGES].reshape(-1, 2), axis=1)
    edges, inverse = np.unique(pairs, axis=0, return_inverse=True)
    tet_edges = inverse.reshape(len(tets), 6)
    face_pairs = np.sort(faces[:, TRI6_EDGES].reshape(-1, 2), axis=1)
    n = int(tets.max()) + 1
    key_all = edges[:, 0] * n + edges[:, 1]  # sorted, since edges are unique-sorted lexicographically
    face_edges = np.searchsorted(key_all, face_pairs[:, 0] * n + face_pairs[:, 1]).reshape(len(faces), 3)
    return edges, tet_edges, face_edges


def dihedral_angles_deg(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """(T, 6) interior dihedral angles in degrees (pi minus the angle between outward face normals)."""
    p = points[tets]
    normals = []
    for f in _TET_FACES:
        a, b, c = p[:, f[0]], p[:, f[1]], p[:, f[2]]
        n = np.cross(b - a, c - a)
        normals.append(n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300))
    out = np.empty((len(tets), 6))
    for k, (i, j) in enumerate([(0, 1), (0, 2), (0, 3), (1, 2), (1, 3), (2, 3)]):
        cos = np.clip(np.einsum("ij,ij->i", normals[i], normals[j]), -1.0, 1.0)
        out[:, k] = 180.0 - np.degrees(np.arccos(cos))
    return out


def quality_report(points: np.ndarray, tets: np.ndarray) -> dict:
    """Min/max dihedral angle (deg), min/mean volume (m^3), and the count of slivers (straight tets)."""
    vol = signed_volumes(points, tets)
    dih = dihedral_angles_deg(points, tets)
    return {
        "min_dihedral_deg": float(dih.min()),
        "max_dihedral_deg": float(dih.max()),
        "min_volume_m3": float(vol.min()),
        "mean_volume_m3": float(vol.mean()),
        "slivers": int((dih.min(axis=1) < SLIVER_DIHEDRAL_DEG).sum()),
        "sliver_threshold_deg": SLIVER_DIHEDRAL_DEG,
    }


def orient_tets(points: np.ndarray, tets: np.ndarray) -> np.ndarray:
    """Return the tets positively oriented; raise :class:`MeshingError` on inverted or degenerate ones.

    A valid mesh has one orientation throughout; fTetWild's is negative, so two columns are swapped.
    Mixed signs mean inverted tets, and near-zero volumes degenerate ones: both are refused.
    """
    vol = signed_volumes(points, tets)
    if np.median(vol) < 0:
        tets = tets[:, [0, 1, 3, 2]]
        vol = -vol
    mean = np.abs(vol).mean()
    if np.any(vol < 0):
        raise MeshingError(f"{int((vol < 0).sum())} inverted tetrahedra (of {len(vol)})")
    small = vol <= DEGENERATE_VOLUME_FRACTION * mean
    if np.any(small):
        raise MeshingError(
            f"{int(small.sum())} degenerate tetrahedra (volume <= {DEGENERATE_VOLUME_FRACTION:g} x mean, smallest {vol.min():.3g} m^3)"
        )
    return np.ascontiguousarray(tets)


# --------------------------------------------------------------------------- quadratic geometry
def _p2_shape(bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """P2 shape functions (..., 10) and their gradients (..., 10, 3) w.r.t. the reference coordinates
    (lambda1, lambda2, lambda3) at barycentric points (..., 4)."""
    lam = np.asarray(bary, dtype=float)
    # d lambda_i / d xi_m: lambda0 = 1 - xi - eta - zeta.
    dlam = np.array([[-1.0, -1.0, -1.0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
    n = np.empty(lam.shape[:-1] + (10,))
    dn = np.empty(lam.shape[:-1] + (10, 3))
    for i in range(4):
        n[..., i] = lam[..., i] * (2 * lam[..., i] - 1)
        dn[..., i, :] = (4 * lam[..., i] - 1)[..., None] * dlam[i]
    for e, (i, j) in enumerate(TET10_EDGES):
        n[..., 4 + e] = 4 * lam[..., i] * lam[..., j]
        dn[..., 4 + e, :] = 4 * (lam[..., j][..., None] * dlam[i] + lam[..., i][..., None] * dlam[j])
    return n, dn


def p2_map(nodes10: np.ndarray, bary: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Map barycentric points through curved tets.

    nodes10: (T, 10, 3) node coordinates. bary: (K, 4) shared by all tets, or (T, K, 4) per tet.
    Returns x (T, K, 3) and det J (T, K) of the map from the reference tet (volume 1/6).
    """
    n, dn = _p2_shape(bary)
    if n.ndim == 2:
        x = np.einsum("kn,tnd->tkd", n, nodes10)
        jac = np.einsum("kna,tnd->tkda", dn, nodes10)
    else:
        x = np.einsum("tkn,tnd->tkd", n, nodes10)
        jac = np.einsum("tkna,tnd->tkda", dn, nodes10)
    return x, np.linalg.det(jac)


def _tet_rule():
    from skfem.quadrature import get_quadrature
    from skfem.refdom import RefTet

    xi, w = get_quadrature(RefTet, 3)  # exact for the cubic Jacobian determinant of a P2 map
    bary = np.column_stack([1 - xi.sum(axis=0), xi.T])
    return bary, w


def _p2_volumes(nodes10: np.ndarray) -> np.ndarray:
    bary, w = _tet_rule()
    _, det = p2_map(nodes10, bary)
    return det @ w


def _p2_triangle_areas(nodes6: np.ndarray) -> np.ndarray:
    """Areas of curved 6-node triangles (F, 6, 3) by a degree-4 rule."""
    from skfem.quadrature import get_quadrature
    from skfem.refdom import RefTri

    uv, w = get_quadrature(RefTri, 4)
    u, v = uv
    l0 = 1 - u - v
    # Derivatives of the 6 shape functions w.r.t. u (= lambda1) and v (= lambda2).
    du = np.stack([-(4 * l0 - 1), 4 * u - 1, 0 * u, 4 * (l0 - u), 4 * v, -4 * v], axis=1)
    dv = np.stack([-(4 * l0 - 1), 0 * u, 4 * v - 1, -4 * u, 4 * u, 4 * (l0 - v)], axis=1)
    xu = np.einsum("kn,fnd->fkd", du, nodes6)
    xv = np.einsum("kn,fnd->fkd", dv, nodes6)
    return np.linalg.norm(np.cross(xu, xv), axis=2) @ w


# Points where a curved tet must keep a positive Jacobian: its 10 nodes and its centroid.
_CHECK_BARY = np.vstack([np.eye(4), 0.5 * (np.eye(4)[TET10_EDGES[:, 0]] + np.eye(4)[TET10_EDGES[:, 1]]), np.full((1, 4), 0.25)])


def _curve_boundary(g: "MeshableBody", points, tets, edges, tet_edges, faces, face_edges, edge_tol_m: float, max_rounds: int = 6):
    """Mid-edge nodes: straight midpoints, with boundary ones projected onto the exact surface;
    tets that would fold keep straight edges."""
    mids = 0.5 * (points[edges[:, 0]] + points[edges[:, 1]])
    curved = mids.copy()
    bnd = np.unique(face_edges)
    curved[bnd] = g.project_edge_midpoints(points[edges[bnd, 0]], points[edges[bnd, 1]], edge_tol_m)
    straight_det = 6.0 * signed_volumes(points, tets)
    for _ in range(max_rounds):
        nodes10 = np.concatenate([points[tets], curved[tet_edges]], axis=1)
        _, det = p2_map(nodes10, _CHECK_BARY)
        bad = det.min(axis=1) <= 0.1 * straight_det
        if not bad.any():
            break
        undo = np.unique(tet_edges[bad])
        curved[undo] = mids[undo]
    return curved


# ------------------------------------------------------------------------------- layer fractions
def red_refinement(levels: int) -> np.ndarray:
    """(8**levels, 4, 4) barycentric vertices of the sub-tets of ``levels`` red refinements
    [Bey1995]_. All sub-tets have the same volume."""
    tets = np.eye(4)[None]  # (n, 4 vertices, 4 barycentric)
    for _ in range(levels):
        v = [tets[:, i] for i in range(4)]
        m = {(i, j): 0.5 * (v[i] + v[j]) for i in range(4) for j in range(i + 1, 4)}
        children = [
            (v[0], m[0, 1], m[0, 2], m[0, 3]),
            (m[0, 1], v[1], m[1, 2], m[1, 3]),
            (m[0, 2], m[1, 2], v[2], m[2, 3]),
            (m[0, 3], m[1, 3], m[2, 3], v[3]),
            (m[0, 1], m[0, 2], m[0, 3], m[1, 3]),
            (m[0, 1], m[0, 2], m[1, 2], m[1, 3]),
            (m[0, 2], m[0, 3], m[1, 3], m[2, 3]),
            (m[0, 2], m[1, 2], m[1, 3], m[2, 3]),
        ]
        tets = np.concatenate([np.stack(c, axis=1) for c in children], axis=0)
    return tets


def red_refinement_centroids(levels: int) -> np.ndarray:
    """(8**levels, 4) barycentric centroids of the sub-tets of ``levels`` red refinements: a
    composite midpoint rule with equal weights, exact for linear functions."""
    return red_refinement(levels).mean(axis=1)


#: Seed of the jittered sampling of layer fractions: fixed, so a mesh's fractions are reproducible.
FRACTION_SAMPLING_SEED = 20261121


def layer_fractions(g: "MeshableBody", nodes10: np.ndarray, levels: int = 3, chunk: int = 512) -> np.ndarray:
    """(T, 3) volume fraction of absorber, ML and core in each curved tet (rows sum to 1).

    nodes10: (T, 10, 3) m. A mixed tet is sampled at one point drawn uniformly inside each of its
    ``8**levels`` red-refinement sub-tets (stratified sampling), mapped through the quadratic
    geometry and weighted by the Jacobian. The sampling is unbiased for every tet and independent
    between tets, so summed layer volumes converge; a fixed lattice is not: next to a boundary face
    the absorber is a slab of a fixed fraction of the tet's height, and a lattice systematically
    under-counts such thin slabs (-2 % absorber volume on the default array at levels = 3).
    Randomness comes from a generator with the fixed seed :data:`FRACTION_SAMPLING_SEED`.
    """
    centroid, _ = p2_map(nodes10, np.full((1, 4), 0.25))
    centroid = centroid[:, 0]
    # Curved tets bulge at most a little beyond their nodes; 10 % covers it.
    radius = 1.1 * np.linalg.norm(nodes10 - centroid[:, None], axis=2).max(axis=1)
    depth = g.depth_below_top(centroid)
    mixed = np.zeros(len(nodes10), dtype=bool)
    for s in g.layer_interfaces_m:
        mixed |= np.abs(depth - s) <= radius
    out = np.zeros((len(nodes10), 3))
    pure = np.flatnonzero(~mixed)
    out[pure, g.layer_index(centroid[pure])] = 1.0
    sub = red_refinement(levels)  # (K, 4, 4)
    rng = np.random.default_rng(FRACTION_SAMPLING_SEED)
    idx = np.flatnonzero(mixed)
    for start in range(0, len(idx), chunk):
        sel = idx[start : start + chunk]
        weights = rng.dirichlet(np.ones(4), size=(len(sel), len(sub)))  # uniform in each sub-tet
        bary = np.einsum("tkv,kvb->tkb", weights, sub)
        x, det = p2_map(nodes10[sel], bary)
        lay = g.layer_index(x.reshape(-1, 3)).reshape(len(sel), -1)
        total = det.sum(axis=1)
        for k in range(3):
            out[sel, k] = np.where(lay == k, det, 0.0).sum(axis=1) / total
    return out


# ------------------------------------------------------------------------------------- meshing
def _run_tetwild(vertices_mm, faces, edge_length_mm, epsilon_rel, coarsen, timeout_s, bar=None):
    """fTetWild in a subprocess; returns (points_mm, tets) or raises MeshingError on timeout/failure."""
    with tempfile.TemporaryDirectory(prefix="mlsim_tetwild_") as tmp:
        src, dst = os.path.join(tmp, "in.npz"), os.path.join(tmp, "out.npz")
        np.savez(
            src,
            vertices=vertices_mm,
            faces=faces,
            edge_length=edge_length_mm,
            epsilon_rel=epsilon_rel,
            coarsen=coarsen,
            num_threads=0,
        )
        cmd = [sys.executable, "-m", "fem.tetwild_worker", src, dst]
        env = dict(os.environ)
        root = str(Path(__file__).resolve().parent.parent)
        env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
        # cwd=tmp: fTetWild writes a scratch file (__tracked_surface.stl) into the working directory.
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, cwd=tmp)
        start = time.monotonic()
        try:
            while proc.poll() is None:
                if time.monotonic() - start > timeout_s:
                    proc.kill()
                    proc.wait()
                    raise MeshingError(f"fTetWild did not finish within {timeout_s:g} s")
                time.sleep(0.1)
                if bar is not None:
                    bar.set_postfix_str(f"{time.monotonic() - start:.0f} s")
        except BaseException:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            raise
        _, err = proc.communicate()
        if proc.returncode != 0 or not os.path.exists(dst):
            tail = err.decode(errors="replace").strip().splitlines()[-3:]
            raise MeshingError(f"fTetWild failed (exit {proc.returncode}): {' | '.join(tail)}")
        with np.load(dst) as out:
            return out["points"], out["tets"]


def _drop_unused(points, tets):
    used = np.unique(tets)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[tets]


def _snap_boundary(g: "MeshableBody", points, tets, faces, edge_tol_m: float, max_rounds: int = 6):
    """Move boundary nodes onto the exact surface, keeping any node whose move would squash a tet."""
    nodes = np.unique(faces)
    snapped = points.copy()
    snapped[nodes] = g.project_to_surface(points[nodes], edge_tol_m)
    vol0 = signed_volumes(points, tets)
    for _ in range(max_rounds):
        bad = signed_volumes(snapped, tets) <= 0.05 * vol0
        if not bad.any():
            break
        revert = np.intersect1d(np.unique(tets[bad]), nodes)
        snapped[revert] = points[revert]
    return snapped


def _validate(g: "MeshableBody", points, tets, params: MeshParams):
    """Checks an accepted mesh must pass; raise MeshingError (then build_mesh retries)."""
    vol = signed_volumes(points, tets)
    total, exact = vol.sum(), g.volume_m3()
    if abs(total / exact - 1) > 0.03:
        raise MeshingError(f"mesh volume {total:.4g} m^3 is {100 * (total / exact - 1):+.2f} % off the analytic {exact:.4g} m^3")
    problem = g.check_regions(points, tets, vol)
    if problem:
        raise MeshingError(problem)
    faces = boundary_faces(tets)
    _, _, dist = g.classify_boundary(points[faces].mean(axis=1))
    tol = max(4 * params.envelope_m, 0.25 * params.edge_length_m)
    if dist.max() > tol:
        raise MeshingError(f"a boundary face lies {dist.max() * 1e3:.3g} mm from the exact surface (limit {tol * 1e3:.3g} mm): hole or cavity")
    return faces


def build_mesh(g: "MeshableBody", params: MeshParams, progress: bool = True) -> tuple[TetMesh, dict]:
    """Tetrahedralise the rod array, validate, snap, curve, label. Returns (mesh, report).

    The report has the attempts made (edge length, seconds, outcome) and :func:`mesh_report`.
    Raises :class:`MeshingError` when every attempt failed.
    """
    from tqdm.auto import tqdm

    surface = g.outer_surface(params.segments_per_circle)
    vertices_mm = np.asarray(surface.vertices) * 1e3
    faces_in = np.asarray(surface.faces, dtype=np.int32)
    diag_mm = float(np.linalg.norm(vertices_mm.max(0) - vertices_mm.min(0)))
    epsilon_rel = params.envelope_m * 1e3 / diag_mm
    attempts = []
    # disable=None: a bar on a terminal only, so CI logs are not flooded.
    bar = tqdm(total=params.retries + 1, desc="meshing (fTetWild)", unit="try", disable=None if progress else True, leave=False, mininterval=0.5)
    try:
        for k in range(params.retries + 1):
            # Perturb the edge length on retries: fTetWild's failures depend on the size. Coarser first
            # (+4 %, -4 %, +8 %): it meshes faster (the 7.5 mm rods of a height sweep: 190 s to a mesh with
            # degenerate tets at 2 mm, then 240 s to the timeout at 1.92 mm, where 2.08 mm took 46 s)
            edge_mm = params.edge_length_m * 1e3 * (1.0 + 0.04 * math.ceil(k / 2) * (-1) ** (k + 1))
            t0 = time.perf_counter()
            try:
                pts_mm, tets = _run_tetwild(vertices_mm, faces_in, edge_mm, epsilon_rel, params.coarsen, params.timeout_s, bar)
                points, tets = _drop_unused(pts_mm * 1e-3, tets.astype(np.int64))
                tets = orient_tets(points, tets)
                faces = _validate(g, points, tets, params)
            except MeshingError as exc:
                attempts.append({"edge_length_mm": edge_mm, "seconds": time.perf_counter() - t0, "outcome": str(exc)})
                bar.update(1)
                continue
            tetwild_s = time.perf_counter() - t0
            # fTetWild's surface strays up to the envelope from the exact one, so nodes within twice
            # that of two pieces are taken to lie on their common (sharp) edge.
            edge_tol = 2.0 * params.envelope_m
            points = _snap_boundary(g, points, tets, faces, edge_tol)
            tets = orient_tets(points, tets)
            edges, tet_edges, face_edges = edge_table(tets, faces)
            edge_nodes = _curve_boundary(g, points, tets, edges, tet_edges, faces, face_edges, edge_tol)
            nodes10 = np.concatenate([points[tets], edge_nodes[tet_edges]], axis=1)
            centroid = points[tets].mean(axis=1)
            face_tag, face_rod, _ = g.classify_boundary(points[faces].mean(axis=1))
            mesh = TetMesh(
                points=points,
                tets=tets,
                edge_nodes=edge_nodes,
                tet_edges=tet_edges,
                layer_fraction=layer_fractions(g, nodes10, params.fraction_levels),
                tet_rod=g.region_of(centroid),
                faces=faces,
                face_edges=face_edges,
                face_tag=face_tag,
                face_rod=face_rod,
            )
            attempts.append({"edge_length_mm": edge_mm, "seconds": time.perf_counter() - t0, "tetwild_seconds": tetwild_s, "outcome": "accepted"})
            bar.update(bar.total - bar.n)
            return mesh, {"attempts": attempts, **mesh_report(g, mesh)}
    finally:
        bar.close()
    lines = "; ".join(f"edge {a['edge_length_mm']:.3g} mm: {a['outcome']}" for a in attempts)
    raise MeshingError(
        f"tetrahedral meshing failed after {len(attempts)} attempts ({lines}). Try another "
        "fidelity.mesh.edge_length_mm, a larger fidelity.mesh.timeout_s, or fidelity.mesh.coarsen = false"
    )


# --------------------------------------------------------------------------------------- reports
def mesh_report(g: "MeshableBody", mesh: TetMesh) -> dict:
    """Counts, quality, and the relative errors of volumes and tagged areas against the analytic ones."""
    vol = mesh.volumes()
    linear = mesh.linear_volumes()
    layer_vol = (mesh.layer_fraction * vol[:, None]).sum(axis=0)
    exact_layers = g.layer_volumes_m3()
    areas = np.bincount(mesh.face_tag, weights=mesh.face_areas(), minlength=len(FaceTag))
    exact_areas = g.face_areas_m2()
    names = ("absorber", "ml", "core")
    return {
        "n_points": mesh.n_points,
        "n_nodes_quadratic": mesh.n_points + len(mesh.edge_nodes),
        "n_tets": mesh.n_tets,
        "n_boundary_faces": len(mesh.faces),
        "mesh_hash": mesh.content_hash(),
        "volume_m3": float(vol.sum()),
        "volume_rel_error": float(vol.sum() / g.volume_m3() - 1),
        "linear_volume_rel_error": float(linear.sum() / g.volume_m3() - 1),
        "layer_volume_m3": {n: float(v) for n, v in zip(names, layer_vol)},
        "layer_volume_rel_error": {n: float(v / exact_layers[n] - 1) for n, v in zip(names, layer_vol) if exact_layers[n] > 0},
        "face_area_m2": {t.name.lower(): float(areas[t]) for t in FaceTag if exact_areas.get(t, 0) > 0},
        "face_area_rel_error": {t.name.lower(): float(areas[t] / exact_areas[t] - 1) for t in FaceTag if exact_areas.get(t, 0) > 0},
        "quality": quality_report(mesh.points, mesh.tets),
    }


def write_vtu(mesh: TetMesh, path: str | Path) -> None:
    """VTU (ParaView) of the quadratic mesh: ``tetra10`` cells with layer fractions and rod index,
    ``triangle6`` boundary faces with their tags. Coordinates in metres. Cell data that does not
    apply to a block is -1 (tags) or NaN (fractions)."""
    import meshio

    path = Path(path)
    nt, nf = mesh.n_tets, len(mesh.faces)
    nan_f = np.full(nf, np.nan)
    cell_data = {
        "absorber_fraction": [mesh.layer_fraction[:, 0], nan_f],
        "ml_fraction": [mesh.layer_fraction[:, 1], nan_f],
        "core_fraction": [mesh.layer_fraction[:, 2], nan_f],
        "rod": [mesh.tet_rod.astype(np.int32), mesh.face_rod.astype(np.int32)],
        "face_tag": [np.full(nt, -1, dtype=np.int32), mesh.face_tag.astype(np.int32)],
    }
    faces6 = np.concatenate([mesh.faces, mesh.n_points + mesh.face_edges], axis=1)
    out = meshio.Mesh(mesh.points10, [("tetra10", mesh.tets10), ("triangle6", faces6)], cell_data=cell_data)
    tmp = path.with_name(path.name + ".part.vtu")
    out.write(tmp)
    os.replace(tmp, path)
