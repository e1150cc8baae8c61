"""Verification of fem.mesh: straight and quadratic tet measures, orientation, red refinement, layer
fractions, and one fTetWild mesh of a 2 x 2 array checked against the analytic geometry.

All lengths in metres.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from fem.geometry import FaceTag, RodArray, classify_boundary, layer_index
from fem.mesh import (
    TET10_EDGES,
    MeshParams,
    TetMesh,
    boundary_faces,
    build_mesh,
    dihedral_angles_deg,
    edge_table,
    layer_fractions,
    mesh_report,
    orient_tets,
    p2_map,
    quality_report,
    red_refinement,
    red_refinement_centroids,
    signed_volumes,
    write_vtu,
)
from mlsim.errors import MeshingError

MM = 1e-3
G22 = RodArray(2, 2, 7.2 * MM, 7.2 * MM, 2.5 * MM, 9 * MM, 2 * MM, 0.3 * MM, 0.5 * MM)
REF = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]])
REGULAR = np.array([[1.0, 1, 1], [1, -1, -1], [-1, -1, 1], [-1, 1, -1]])  # edge 2 sqrt 2, volume 8 / 3, positive
#: Barycentric coordinates of the 10 nodes of a tetra10 (vertices, then edge midpoints in TET10_EDGES order).
NODE_BARY = np.vstack([np.eye(4), 0.5 * (np.eye(4)[TET10_EDGES[:, 0]] + np.eye(4)[TET10_EDGES[:, 1]])])


# ----------------------------------------------------------------------------------- helpers
def random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def random_tets(rng: np.random.Generator, n: int) -> np.ndarray:
    """(n, 4, 3) positively oriented, reasonably shaped tets."""
    out = []
    while len(out) < n:
        v = rng.normal(size=(4, 3))
        vol = np.dot(v[1] - v[0], np.cross(v[2] - v[0], v[3] - v[0])) / 6
        if abs(vol) > 0.05:
            out.append(v if vol > 0 else v[[0, 1, 3, 2]])
    return np.array(out)


def straight_nodes10(vertices: np.ndarray) -> np.ndarray:
    """(T, 10, 3) nodes with mid-edge nodes at the edge midpoints."""
    mids = 0.5 * (vertices[:, TET10_EDGES[:, 0]] + vertices[:, TET10_EDGES[:, 1]])
    return np.concatenate([vertices, mids], axis=1)


def ref_coords(bary: np.ndarray) -> np.ndarray:
    return bary[..., 1:]


def duffy_volume(nodes10: np.ndarray, n: int = 8) -> np.ndarray:
    """Independent volume: Stroud's conical-product rule (Gauss-Legendre on the collapsed cube),
    exact for polynomials of degree <= 2n - 3 on the reference tet; det J of a P2 map is cubic."""
    x, w = np.polynomial.legendre.leggauss(n)
    x, w = 0.5 * (x + 1), 0.5 * w
    u, v, t = np.meshgrid(x, x, x, indexing="ij")
    wu, wv, wt = np.meshgrid(w, w, w, indexing="ij")
    xi = u
    eta = (1 - u) * v
    zeta = (1 - u) * (1 - v) * t
    weight = (wu * wv * wt * (1 - u) ** 2 * (1 - v)).ravel()
    bary = np.column_stack([1 - xi.ravel() - eta.ravel() - zeta.ravel(), xi.ravel(), eta.ravel(), zeta.ravel()])
    _, det = p2_map(nodes10, bary)
    return det @ weight


def one_tet_mesh(nodes10: np.ndarray) -> TetMesh:
    """A TetMesh of a single (possibly curved) tet with the given 10 nodes (VTK order)."""
    tets = np.array([[0, 1, 2, 3]])
    faces = boundary_faces(tets)
    _, tet_edges, face_edges = edge_table(tets, faces)
    edge_nodes = np.empty((6, 3))
    edge_nodes[tet_edges[0]] = nodes10[4:]
    return TetMesh(
        points=nodes10[:4].copy(),
        tets=tets,
        edge_nodes=edge_nodes,
        tet_edges=tet_edges,
        layer_fraction=np.array([[0.0, 0.0, 1.0]]),
        tet_rod=np.array([-1], dtype=np.int32),
        faces=faces,
        face_edges=face_edges,
        face_tag=np.zeros(4, dtype=np.int8),
        face_rod=np.full(4, -1, dtype=np.int32),
    )


def kuhn_cube_mesh(n: int) -> tuple[np.ndarray, np.ndarray]:
    """An n x n x n grid of unit cubes, each split into the 6 Kuhn tets (conforming), positively oriented."""
    idx = np.arange((n + 1) ** 3).reshape(n + 1, n + 1, n + 1)
    g = np.stack(np.meshgrid(*[np.arange(n + 1.0)] * 3, indexing="ij"), axis=-1).reshape(-1, 3)
    perms = [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]
    tets = []
    for i in range(n):
        for j in range(n):
            for k in range(n):
                for p in perms:
                    c = np.array([i, j, k])
                    path = [c.copy()]
                    for axis in p:
                        c = c.copy()
                        c[axis] += 1
                        path.append(c)
                    tets.append([idx[tuple(q)] for q in path])
    tets = np.array(tets)
    neg = signed_volumes(g, tets) < 0
    tets[neg] = tets[neg][:, [0, 1, 3, 2]]
    return g, tets


# -------------------------------------------------------------------- 1. volumes and orientation
def test_signed_volume_reference_and_affine_maps():
    tets = np.array([[0, 1, 2, 3], [0, 1, 3, 2]])
    np.testing.assert_allclose(signed_volumes(REF, tets), [1 / 6, -1 / 6], rtol=1e-15)
    rng = np.random.default_rng(1)
    for _ in range(10):
        a = rng.normal(size=(3, 3))
        b = rng.normal(size=3)
        pts = REF @ a.T + b
        np.testing.assert_allclose(signed_volumes(pts, tets[:1]), [np.linalg.det(a) / 6], rtol=1e-12)
    np.testing.assert_allclose(signed_volumes(REGULAR, tets[:1]), [8 / 3], rtol=1e-15)


def test_orient_tets_swaps_a_negative_mesh():
    pts = np.vstack([REF, [[1.0, 1, 1]]])
    pos = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    assert np.all(signed_volumes(pts, pos) > 0)
    neg = pos[:, [1, 0, 2, 3]]
    out = orient_tets(pts, neg)
    np.testing.assert_array_equal(out, neg[:, [0, 1, 3, 2]])
    np.testing.assert_allclose(signed_volumes(pts, out), signed_volumes(pts, pos), rtol=1e-15)
    np.testing.assert_array_equal(orient_tets(pts, pos), pos)  # already positive: unchanged


def test_orient_tets_refuses_mixed_orientation():
    pts = np.vstack([REF, [[1.0, 1, 1]], REF + 5.0])
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4], [5, 6, 8, 7]])  # two positive, one inverted
    with pytest.raises(MeshingError, match="inverted"):
        orient_tets(pts, tets)
    with pytest.raises(MeshingError, match="inverted"):
        orient_tets(pts, tets[:, [0, 1, 3, 2]])  # the mirror image: two negative, one positive


def test_orient_tets_refuses_degenerate():
    flat = np.vstack([REF[:3], [[0.3, 0.3, 0.0]]])  # four coplanar points
    with pytest.raises(MeshingError, match="degenerate"):
        orient_tets(flat, np.array([[0, 1, 2, 3]]))
    # A sliver of 1e-9 of the mean volume among good tets is refused; 1e-6 is accepted.
    for height, ok in ((1e-9, False), (1e-6, True)):
        pts = np.vstack([REF, REF * [1, 1, height] + 3.0])
        tets = np.array([[0, 1, 2, 3], [4, 5, 6, 7]])
        if ok:
            orient_tets(pts, tets)
        else:
            with pytest.raises(MeshingError, match="degenerate"):
                orient_tets(pts, tets)


# -------------------------------------------------------------------------------- 2. p2_map
def test_p2_map_straight_is_affine_with_constant_jacobian():
    rng = np.random.default_rng(2)
    v = random_tets(rng, 40)
    nodes = straight_nodes10(v)
    bary = rng.dirichlet(np.ones(4), size=25)
    x, det = p2_map(nodes, bary)
    np.testing.assert_allclose(x, np.einsum("kb,tbd->tkd", bary, v), rtol=0, atol=1e-12)
    vol = signed_volumes(v.reshape(-1, 3), np.arange(4 * len(v)).reshape(-1, 4))
    np.testing.assert_allclose(det, np.repeat(6 * vol[:, None], len(bary), axis=1), rtol=1e-10)


def test_p2_map_interpolates_nodes_and_per_tet_points():
    rng = np.random.default_rng(3)
    v = random_tets(rng, 20)
    nodes = straight_nodes10(v) + 0.1 * rng.normal(size=(20, 10, 3))
    x, _ = p2_map(nodes, NODE_BARY)  # the shape functions are nodal in TET10_EDGES order
    np.testing.assert_allclose(x, nodes, rtol=0, atol=1e-13)
    bary = rng.dirichlet(np.ones(4), size=(20, 7))
    x_each, det_each = p2_map(nodes, bary)
    for t in range(20):
        x1, d1 = p2_map(nodes[t : t + 1], bary[t])
        np.testing.assert_allclose(x_each[t], x1[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(det_each[t], d1[0], rtol=1e-13, atol=1e-15)


def test_p2_jacobian_matches_finite_differences():
    rng = np.random.default_rng(4)
    nodes = straight_nodes10(random_tets(rng, 5)) + 0.1 * rng.normal(size=(5, 10, 3))
    bary = rng.dirichlet(np.ones(4) * 3, size=6)
    _, det = p2_map(nodes, bary)
    h = 1e-6
    cols = []
    for a in range(3):  # reference coordinate xi_a = lambda_{a+1}; lambda_0 absorbs the change
        step = np.zeros(4)
        step[a + 1], step[0] = h, -h
        xp, _ = p2_map(nodes, bary + step)
        xm, _ = p2_map(nodes, bary - step)
        cols.append((xp - xm) / (2 * h))
    jac = np.stack(cols, axis=-1)
    np.testing.assert_allclose(det, np.linalg.det(jac), rtol=1e-7)


def test_p2_volume_one_curved_edge_analytic():
    """Displacing the node of edge (0, 1) of the reference tet by delta: x = xi + 4 l0 l1 delta, so
    det J = 1 + 4 grad(l0 l1) . delta and the volume is 1/6 - (delta_y + delta_z) / 6."""
    for delta in ([0.0, -0.1, -0.1], [0.05, 0.2, -0.03], [0.3, 0.0, 0.0]):
        nodes = straight_nodes10(REF[None])
        nodes[0, 4] += delta
        want = 1 / 6 - (delta[1] + delta[2]) / 6
        assert math.isclose(one_tet_mesh(nodes[0]).volumes()[0], want, rel_tol=1e-13)
        assert math.isclose(duffy_volume(nodes)[0], want, rel_tol=1e-13)


def test_p2_volume_general_curved_tets_match_independent_rule():
    rng = np.random.default_rng(5)
    v = random_tets(rng, 60)
    scale = np.linalg.norm(v[:, 1] - v[:, 0], axis=1)[:, None, None]
    nodes = straight_nodes10(v)
    nodes[:, 4:] += 0.06 * scale * rng.normal(size=(60, 6, 3))  # all six edges curved: cubic det J
    _, det_nodes = p2_map(nodes, NODE_BARY)
    keep = det_nodes.min(axis=1) > 0
    assert keep.sum() >= 15
    nodes = nodes[keep]
    exact = duffy_volume(nodes, n=8)
    np.testing.assert_allclose(duffy_volume(nodes, n=5), exact, rtol=1e-12)  # already exact at n = 5
    got = np.array([one_tet_mesh(nd).volumes()[0] for nd in nodes])
    np.testing.assert_allclose(got, exact, rtol=1e-11)
    # The curving changed the volume noticeably, so the agreement is not trivial.
    lin = np.array([one_tet_mesh(nd).linear_volumes()[0] for nd in nodes])
    assert np.max(np.abs(exact / lin - 1)) > 0.05
    # The composite midpoint rule on red refinements converges to it (second order).
    errs = []
    for level in (2, 3):
        _, d = p2_map(nodes, red_refinement_centroids(level))
        errs.append(np.abs(d.mean(axis=1) / 6 / exact - 1).max())
    assert errs[1] < errs[0] / 3


def test_face_areas_straight_and_curved():
    nodes = straight_nodes10(REF[None])[0]
    m = one_tet_mesh(nodes)
    faces = m.faces
    want = 0.5 * np.linalg.norm(np.cross(m.points[faces[:, 1]] - m.points[faces[:, 0]], m.points[faces[:, 2]] - m.points[faces[:, 0]]), axis=1)
    np.testing.assert_allclose(m.face_areas(), want, rtol=1e-13)
    assert math.isclose(want.sum(), 1.5 + math.sqrt(3) / 2, rel_tol=1e-14)
    # Lift the node of edge (0, 1) by (0, 0, dz): face {0,1,3} (plane y = 0) stays planar with
    # area 1/2 - 2 dz / 3; face {0,1,2} becomes z = 4 dz u (1 - u - v) over the unit triangle.
    from scipy.integrate import dblquad

    dz = 0.1
    nodes[4] += [0, 0, dz]
    m = one_tet_mesh(nodes)
    area = dict(zip(map(frozenset, m.faces.tolist()), m.face_areas()))
    curved, _ = dblquad(lambda v, u: math.sqrt(1 + (4 * dz * (1 - 2 * u - v)) ** 2 + (4 * dz * u) ** 2), 0, 1, 0, lambda u: 1 - u, epsabs=1e-14)
    assert math.isclose(area[frozenset({0, 1, 3})], 0.5 - 2 * dz / 3, rel_tol=1e-13)
    assert math.isclose(area[frozenset({0, 2, 3})], 0.5, rel_tol=1e-13)
    assert math.isclose(area[frozenset({1, 2, 3})], math.sqrt(3) / 2, rel_tol=1e-13)
    assert math.isclose(area[frozenset({0, 1, 2})], curved, rel_tol=1e-5)
    assert curved > 0.5 * (1 + 1e-3)


# ---------------------------------------------------------------------------- 3. red refinement
@pytest.mark.parametrize("levels", [0, 1, 2, 3])
def test_red_refinement_tiles_the_tet_with_equal_subtets(levels):
    sub = red_refinement(levels)
    n = 8**levels
    assert sub.shape == (n, 4, 4)
    np.testing.assert_allclose(sub.sum(axis=2), 1.0, rtol=0, atol=1e-15)
    assert sub.min() >= 0
    # Vertices on the lattice of spacing 2^-levels.
    np.testing.assert_allclose(sub * 2**levels, np.round(sub * 2**levels), atol=1e-12)
    xyz = ref_coords(sub)
    vol = np.einsum("ij,ij->i", xyz[:, 1] - xyz[:, 0], np.cross(xyz[:, 2] - xyz[:, 0], xyz[:, 3] - xyz[:, 0])) / 6
    np.testing.assert_allclose(np.abs(vol), 1 / 6 / n, rtol=1e-12)
    assert math.isclose(np.abs(vol).sum(), 1 / 6, rel_tol=1e-12)
    # Tiling: every point of the tet lies in exactly one sub-tet.
    rng = np.random.default_rng(6)
    p = rng.dirichlet(np.ones(4), size=4000)[:, 1:]
    t = np.stack([xyz[:, 1] - xyz[:, 0], xyz[:, 2] - xyz[:, 0], xyz[:, 3] - xyz[:, 0]], axis=-1)  # (n, 3, 3)
    local = np.einsum("nij,pnj->pni", np.linalg.inv(t), p[:, None, :] - xyz[None, :, 0])
    lam = np.concatenate([1 - local.sum(axis=2, keepdims=True), local], axis=2)
    inside = np.all(lam >= -1e-12, axis=2)
    np.testing.assert_array_equal(inside.sum(axis=1), 1)


@pytest.mark.parametrize("levels", [1, 2, 3])
def test_red_refinement_centroid_rule(levels):
    c = red_refinement_centroids(levels)
    assert c.shape == (8**levels, 4)
    np.testing.assert_allclose(c, red_refinement(levels).mean(axis=1), rtol=0, atol=0)
    np.testing.assert_allclose(c.mean(axis=0), 0.25, rtol=0, atol=1e-14)
    # Exact for linear functions (mean over the tet = value at the centroid).
    rng = np.random.default_rng(7)
    a, b = rng.normal(), rng.normal(size=3)
    f = a + ref_coords(c) @ b
    assert math.isclose(f.mean(), a + b.sum() / 4, rel_tol=1e-13)
    # Not exact for xi^2 (mean 1/10), but second order: the error falls 4x per level.
    err = [abs((ref_coords(red_refinement_centroids(k))[:, 0] ** 2).mean() - 0.1) for k in (levels, levels + 1)]
    assert err[0] > 1e-6 and 3.8 < err[0] / err[1] < 4.2


# ------------------------------------------------------------------- 4. boundary faces, edges
def test_boundary_faces_two_tets():
    pts = np.vstack([REF, [[1.0, 1, 1]]])
    tets = np.array([[0, 1, 2, 3], [1, 2, 3, 4]])
    assert np.all(signed_volumes(pts, tets) > 0)
    faces = boundary_faces(tets)
    assert faces.shape == (6, 3)
    keys = {frozenset(f) for f in faces.tolist()}
    assert len(keys) == 6 and frozenset({1, 2, 3}) not in keys
    # Outward: each face's normal points away from the opposite vertex of its tet.
    for f in faces:
        tet = tets[[set(f) <= set(t) for t in tets.tolist()].index(True)]
        opp = pts[list(set(tet) - set(f))[0]]
        n = np.cross(pts[f[1]] - pts[f[0]], pts[f[2]] - pts[f[0]])
        assert np.dot(n, pts[f].mean(axis=0) - opp) > 0


def test_boundary_faces_cube_divergence_theorem():
    pts, tets = kuhn_cube_mesh(2)
    rng = np.random.default_rng(8)
    rot, shift, s = random_rotation(rng), rng.normal(size=3), 0.37
    pts = (s * pts) @ rot.T + shift
    vol = signed_volumes(pts, tets)
    assert np.all(vol > 0) and math.isclose(vol.sum(), 8 * s**3, rel_tol=1e-12)
    faces = boundary_faces(tets)
    assert faces.shape == (6 * 4 * 2, 3)
    p = pts[faces]
    na = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])  # normal * area
    c = p.mean(axis=1)
    np.testing.assert_allclose(na.sum(axis=0), 0.0, atol=1e-14)  # closed
    assert math.isclose(np.einsum("ij,ij->", c, na), 3 * vol.sum(), rel_tol=1e-12)  # outward
    assert math.isclose(np.linalg.norm(na, axis=1).sum(), 6 * 4 * s**2, rel_tol=1e-12)
    # Each boundary face lies on one face of the cube (local coordinate 0 or 2 s along some axis).
    local = (p - shift) @ rot / s
    on = [np.all(np.isclose(local[:, :, ax], side, atol=1e-12), axis=1) for ax in range(3) for side in (0, 2)]
    np.testing.assert_array_equal(np.sum(on, axis=0), 1)


def test_edge_table_consistency_and_euler():
    pts, tets = kuhn_cube_mesh(2)
    faces = boundary_faces(tets)
    edges, tet_edges, face_edges = edge_table(tets, faces)
    assert len(np.unique(edges, axis=0)) == len(edges)
    np.testing.assert_array_equal(edges[tet_edges], np.sort(tets[:, TET10_EDGES], axis=2))
    face_pairs = np.sort(faces[:, [[0, 1], [1, 2], [2, 0]]], axis=2)
    np.testing.assert_array_equal(edges[face_edges], face_pairs)
    n_faces = (4 * len(tets) + len(faces)) // 2
    assert len(pts) - len(edges) + n_faces - len(tets) == 1  # a ball


# ----------------------------------------------------------------------------- 5. dihedrals
def test_dihedral_angles_regular_and_right_corner():
    rng = np.random.default_rng(9)
    tet = np.array([[0, 1, 2, 3]])
    want = math.degrees(math.acos(1 / 3))
    assert math.isclose(want, 70.52877936550931, rel_tol=1e-14)
    for _ in range(3):  # invariant under rotation, scaling and translation
        pts = 2.7 * REGULAR @ random_rotation(rng).T + rng.normal(size=3)
        np.testing.assert_allclose(dihedral_angles_deg(pts, tet), want, rtol=1e-12)
    corner = np.sort(dihedral_angles_deg(REF, tet)[0])
    np.testing.assert_allclose(corner, [math.degrees(math.acos(1 / math.sqrt(3)))] * 3 + [90.0] * 3, rtol=1e-12)
    # quality_report counts a flattened corner as a sliver: its smallest dihedral angle (at the edge
    # opposite the apex) is the angle between z = 0 and the plane x + y + z / c = 1.
    c = 0.01
    q = quality_report(np.vstack([REGULAR, REF * [1, 1, c]]), np.array([[0, 1, 2, 3], [4, 5, 6, 7]]))
    assert q["slivers"] == 1
    assert math.isclose(q["min_dihedral_deg"], math.degrees(math.acos(1 / math.sqrt(1 + 2 * c * c))), rel_tol=1e-9)
    assert math.isclose(q["max_dihedral_deg"], 90.0, rel_tol=1e-12)
    assert math.isclose(q["mean_volume_m3"], (8 / 3 + c / 6) / 2, rel_tol=1e-12)
    assert math.isclose(q["min_volume_m3"], c / 6, rel_tol=1e-12)


# ------------------------------------------------------------------------ layer fractions (synthetic)
def _inverted_tets(g: RodArray, n: int, height: float, rng: np.random.Generator) -> np.ndarray:
    """Tets with a face on the free base top (z = T, around the point between the rods) and the
    apex ``height`` below it, randomly rotated about z. Volume within depth s: 1 - (1 - s/h)^3."""
    t = g.base_thickness_m
    out = []
    for _ in range(n):
        th = rng.uniform(0, 2 * np.pi) + np.array([0, 2 * np.pi / 3, 4 * np.pi / 3])
        top = np.column_stack([0.9 * MM * np.cos(th), 0.9 * MM * np.sin(th), np.full(3, t)])
        out.append(np.vstack([top, [[0.1 * MM, -0.05 * MM, t - height]]]))
    v = np.array(out)
    vol = signed_volumes(v.reshape(-1, 3), np.arange(4 * n).reshape(-1, 4))
    v[vol < 0] = v[vol < 0][:, [0, 2, 1, 3]]
    return v


def test_layer_fractions_unbiased_on_a_cone_of_known_fractions():
    g = G22
    h = 1.2 * MM
    assert np.min(np.linalg.norm(g.centres_m, axis=1)) > g.rod_radius_m + 1 * MM  # free base top
    v = _inverted_tets(g, 300, h, np.random.default_rng(10))
    f = layer_fractions(g, straight_nodes10(v), levels=2)
    cum = [1 - (1 - g.absorber_m / h) ** 3, 1 - (1 - g.core_depth_m / h) ** 3]
    want = np.array([cum[0], cum[1] - cum[0], 1 - cum[1]])  # 0.578, 0.385, 0.037
    mean = f.mean(axis=0)
    se = f.std(axis=0, ddof=1) / math.sqrt(len(f))
    assert np.all(se < 3e-3)
    assert np.all(se > 0)  # the tets really were sampled
    assert np.all(np.abs(mean - want) < 4 * se + 1e-12), (mean, want, se)
    np.testing.assert_allclose(f.sum(axis=1), 1.0, rtol=1e-12)


def test_layer_fractions_pure_tets_are_exact():
    g = G22
    t = g.base_thickness_m
    deep = np.array([[0, 0, 0.5 * MM], [0.3 * MM, 0, 0.5 * MM], [0, 0.3 * MM, 0.5 * MM], [0, 0, 0.8 * MM]])
    shallow = np.array([[0, 0, t - 0.2 * MM], [0.05 * MM, 0, t - 0.2 * MM], [0, 0.05 * MM, t - 0.2 * MM], [0, 0, t - 0.15 * MM]])
    ml = shallow - [0, 0, 0.3 * MM]
    f = layer_fractions(g, straight_nodes10(np.array([deep, shallow, ml])), levels=3)
    np.testing.assert_array_equal(f, [[0, 0, 1], [1, 0, 0], [0, 1, 0]])


def test_layer_fractions_deterministic_synthetic():
    g = G22
    v = _inverted_tets(g, 50, 1.0 * MM, np.random.default_rng(11))
    nodes = straight_nodes10(v)
    a = layer_fractions(g, nodes, levels=3)
    b = layer_fractions(g, nodes.copy(), levels=3)
    np.testing.assert_array_equal(a, b)
    assert np.all((a[:, 0] > 0) & (a[:, 0] < 1))  # mixed tets: the random sampling path ran


# ----------------------------------------------------------------------- 6. a real 2 x 2 mesh
@pytest.fixture(scope="module")
def built():
    mesh, report = build_mesh(G22, MeshParams(edge_length_m=2e-3, envelope_m=5e-5), progress=False)
    return G22, mesh, report


def test_mesh_volume_close_to_analytic_and_curving_helps(built):
    g, mesh, report = built
    exact = g.volume_m3()
    curved = mesh.volumes()
    linear = mesh.linear_volumes()
    assert np.all(curved > 0) and np.all(linear > 0)
    assert abs(curved.sum() / exact - 1) < 3e-3
    assert abs(curved.sum() / exact - 1) < abs(linear.sum() / exact - 1)
    assert math.isclose(report["volume_rel_error"], curved.sum() / exact - 1, rel_tol=1e-12, abs_tol=1e-15)
    assert math.isclose(report["linear_volume_rel_error"], linear.sum() / exact - 1, rel_tol=1e-12, abs_tol=1e-15)
    # Quadratic volumes agree with the independent conical-product rule.
    np.testing.assert_allclose(curved, duffy_volume(mesh.points10[mesh.tets10]), rtol=1e-10)


def test_mesh_layer_volumes(built):
    g, mesh, report = built
    f = mesh.layer_fraction
    assert f.shape == (mesh.n_tets, 3)
    np.testing.assert_allclose(f.sum(axis=1), 1.0, rtol=0, atol=1e-12)
    assert f.min() >= 0 and f.max() <= 1
    vol = (f * mesh.volumes()[:, None]).sum(axis=0)
    exact = g.layer_volumes_m3()
    for k, name in enumerate(("absorber", "ml", "core")):
        assert abs(vol[k] / exact[name] - 1) < 0.03, (name, vol[k], exact[name])
        assert math.isclose(report["layer_volume_m3"][name], vol[k], rel_tol=1e-12)
    # Per tet, against an independent deterministic estimate: the Jacobian-weighted midpoint rule on
    # a level-3 red refinement (512 points). Both estimates err by a few % on tets the layer
    # boundaries cut (seen: max 0.11, mean 0.019 over 4 builds); a tet wrongly taken as pure errs by more.
    x, det = p2_map(mesh.points10[mesh.tets10], red_refinement_centroids(3))
    lay = layer_index(g, x.reshape(-1, 3)).reshape(mesh.n_tets, -1)
    lattice = np.stack([np.where(lay == k, det, 0.0).sum(axis=1) / det.sum(axis=1) for k in range(3)], axis=1)
    assert np.abs(f - lattice).max() < 0.2
    assert np.abs(f - lattice).mean() < 0.03
    # Tets given a single layer (pure by the 1-Lipschitz depth bound, or sampled without a hit in
    # another layer) hold no more than a trace of another layer (seen: exactly 0 over 4 builds;
    # a pure test with 0.3 x the node radius leaves up to 23 % there).
    one = f.max(axis=1) == 1.0
    assert one.sum() > mesh.n_tets / 40
    assert np.max(1 - lattice[one, np.argmax(f[one], axis=1)]) < 0.01
    assert np.sum(f.max(axis=1) < 1) > mesh.n_tets / 4  # many tets are mixed


@pytest.mark.parametrize("tag", list(FaceTag), ids=lambda t: t.name)
def test_mesh_tagged_areas(built, tag):
    g, mesh, report = built
    area = mesh.face_areas()[mesh.face_tag == tag].sum()
    assert abs(area / g.face_areas_m2()[tag] - 1) < 5e-3, (tag.name, area / g.face_areas_m2()[tag] - 1)
    assert math.isclose(report["face_area_m2"][tag.name.lower()], area, rel_tol=1e-12)


def test_mesh_total_tagged_area(built):
    g, mesh, _ = built
    assert abs(mesh.face_areas().sum() / sum(g.face_areas_m2().values()) - 1) < 5e-3


def test_mesh_tip_rim_edges_follow_the_circle(built):
    """Boundary edges along the rod-tip rim carry their mid-edge node on the rim circle (a chord's
    midpoint lies on the tip disc, so plain nearest-point projection would leave the rim polygonal:
    rod-tip area -1.2 % on this mesh before project_to_surface gained ``edge_tol_m``)."""
    g, mesh, _ = built
    rod, r = g.radial(mesh.points)
    rim = (np.abs(r - g.rod_radius_m) < 1e-12) & (np.abs(mesh.points[:, 2] - g.tip_z_m) < 1e-12)
    e = mesh.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    on_rim = rim[e[:, 0]] & rim[e[:, 1]] & (rod[e[:, 0]] == rod[e[:, 1]])
    assert on_rim.sum() >= 3 * g.n_rods  # the check has material
    _check_rim_nodes(g, mesh, e[on_rim], mesh.face_edges.reshape(-1)[on_rim], g.tip_z_m)


def test_mesh_base_rim_edges_follow_the_circle(built):
    """The same at the rim where the rods meet the base."""
    g, mesh, _ = built
    rod, r = g.radial(mesh.points)
    rim = (np.abs(r - g.rod_radius_m) < 1e-12) & (np.abs(mesh.points[:, 2] - g.base_thickness_m) < 1e-12)
    e = mesh.faces[:, [[0, 1], [1, 2], [2, 0]]].reshape(-1, 2)
    on_rim = rim[e[:, 0]] & rim[e[:, 1]] & (rod[e[:, 0]] == rod[e[:, 1]])
    assert on_rim.sum() >= 3 * g.n_rods
    _check_rim_nodes(g, mesh, e[on_rim], mesh.face_edges.reshape(-1)[on_rim], g.base_thickness_m)


def _check_rim_nodes(g, mesh, pairs, edge_ids, z_rim):
    """Mid-edge nodes of rim edges lie on the rim circle, except where a tet next to them would fold
    if curved (documented fallback: the node stays at the chord's midpoint; seen for one rim edge
    in about 1 build in 15)."""
    nodes = mesh.edge_nodes[edge_ids]
    _, r_mid = g.radial(nodes)
    on_circle = (np.abs(r_mid / g.rod_radius_m - 1) < 1e-9) & (np.abs(nodes[:, 2] - z_rim) < 1e-12 * z_rim)
    chord_mid = 0.5 * (mesh.points[pairs[:, 0]] + mesh.points[pairs[:, 1]])
    straight = np.linalg.norm(nodes - chord_mid, axis=1) < 1e-15
    assert np.all(on_circle | straight)
    assert on_circle.mean() > 0.95, on_circle.mean()


def test_mesh_boundary_nodes_on_exact_surface(built):
    g, mesh, _ = built
    scale = g.tip_z_m
    _, _, dist = classify_boundary(g, mesh.points[np.unique(mesh.faces)])
    # Vertices snapped, except the odd one whose snap would squash a tet (kept where fTetWild put it,
    # inside its envelope of 5e-5 m; seen in about 1 build in 10: on a clean clone's make test of
    # 2026-11-28, 1.07 % of the boundary vertices, so the bound is 2 %)
    snapped = dist < 1e-12 * scale
    assert snapped.mean() > 0.98
    assert dist.max() < 2 * 5e-5
    # Boundary mid-edge nodes: on the exact surface, or (a tet that curving would fold) the chord midpoint.
    be = np.unique(mesh.face_edges)
    edges, _, _ = edge_table(mesh.tets, mesh.faces)
    mid = 0.5 * mesh.points[edges[be]].sum(axis=1)
    _, _, d_node = classify_boundary(g, mesh.edge_nodes[be])
    on_surface = d_node < 1e-12 * scale
    straight = np.linalg.norm(mesh.edge_nodes[be] - mid, axis=1) < 1e-15
    assert np.all(on_surface | straight)
    assert (~on_surface).sum() < 0.05 * len(be)
    # Interior edges keep their midpoints.
    interior = np.setdiff1d(np.arange(len(edges)), be)
    np.testing.assert_allclose(mesh.edge_nodes[interior], 0.5 * mesh.points[edges[interior]].sum(axis=1), rtol=0, atol=1e-18)


def test_mesh_face_tags_and_rods(built):
    g, mesh, _ = built
    c = mesh.points[mesh.faces].mean(axis=1)
    tag, rod, _ = classify_boundary(g, c)
    np.testing.assert_array_equal(mesh.face_tag, tag)
    np.testing.assert_array_equal(mesh.face_rod, rod)
    assert set(np.unique(mesh.face_tag)) == set(int(t) for t in FaceTag)
    on_rod = np.isin(mesh.face_tag, [FaceTag.ROD_SIDE, FaceTag.ROD_TIP])
    assert np.all(mesh.face_rod[~on_rod] == -1)
    assert np.all((mesh.face_rod[on_rod] >= 0) & (mesh.face_rod[on_rod] < g.n_rods))
    np.testing.assert_array_equal(mesh.face_rod[on_rod], g.rod_of(c[on_rod]))
    assert set(np.unique(mesh.face_rod[on_rod])) == set(range(g.n_rods))
    # tet_rod: -1 in the base, else the rod of the centroid.
    tc = mesh.points[mesh.tets].mean(axis=1)
    in_rod = tc[:, 2] > g.base_thickness_m
    np.testing.assert_array_equal(mesh.tet_rod, np.where(in_rod, g.rod_of(tc), -1))


def test_mesh_boundary_is_closed_and_outward(built):
    g, mesh, _ = built
    p = mesh.points[mesh.faces]
    na = 0.5 * np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    np.testing.assert_allclose(na.sum(axis=0), 0.0, atol=1e-12 * g.tip_z_m**2)
    lin = mesh.linear_volumes().sum()
    assert math.isclose(np.einsum("ij,ij->", p.mean(axis=1), na), 3 * lin, rel_tol=1e-10)
    # A ball: Euler characteristic 1, no cavities or tunnels.
    edges, _, _ = edge_table(mesh.tets, mesh.faces)
    n_faces = (4 * mesh.n_tets + len(mesh.faces)) // 2
    assert mesh.n_points - len(edges) + n_faces - mesh.n_tets == 1
    assert np.array_equal(np.unique(mesh.tets), np.arange(mesh.n_points))


def test_mesh_jacobian_positive_at_nodes(built):
    _, mesh, report = built
    nodes10 = mesh.points10[mesh.tets10]
    _, det = p2_map(nodes10, np.vstack([NODE_BARY, np.full((1, 4), 0.25)]))
    assert det.min() > 0
    # ... and not far from the straight one (the curving stays a small perturbation).
    straight = 6 * mesh.linear_volumes()
    assert np.min(det.min(axis=1) / straight) > 0.1
    assert report["quality"]["min_volume_m3"] > 0 and report["n_tets"] == mesh.n_tets


def test_mesh_save_load_roundtrip(built, tmp_path):
    _, mesh, report = built
    path = tmp_path / "mesh.npz"
    mesh.save(path)
    assert path.exists() and not list(tmp_path.glob("*.part*"))
    back = TetMesh.load(path)
    assert back.content_hash() == mesh.content_hash() == report["mesh_hash"]
    np.testing.assert_array_equal(back.volumes(), mesh.volumes())
    # The hash sees a one-ulp change of any one number (here the last of each float array).
    fields = ("points", "tets", "edge_nodes", "tet_edges", "layer_fraction", "tet_rod", "faces", "face_edges", "face_tag", "face_rod")
    for name in ("points", "edge_nodes", "layer_fraction"):
        a = getattr(mesh, name).copy()
        a[-1, -1] = np.nextafter(a[-1, -1], np.inf)
        changed = TetMesh(**{**{k: getattr(mesh, k) for k in fields}, name: a})
        assert changed.content_hash() != mesh.content_hash(), name
    # ... and the type of an array, not only its bytes.
    changed = TetMesh(**{**{k: getattr(mesh, k) for k in fields}, "face_tag": mesh.face_tag.astype(np.uint8)})
    assert changed.content_hash() != mesh.content_hash()


def test_mesh_write_vtu(built, tmp_path):
    import meshio

    _, mesh, _ = built
    path = tmp_path / "mesh.vtu"
    write_vtu(mesh, path)
    m = meshio.read(path)
    np.testing.assert_allclose(m.points, mesh.points10, rtol=0, atol=0)
    blocks = {c.type: c.data for c in m.cells}
    assert set(blocks) == {"tetra10", "triangle6"}
    assert len(blocks["tetra10"]) == mesh.n_tets and len(blocks["triangle6"]) == len(mesh.faces)
    np.testing.assert_array_equal(blocks["tetra10"], mesh.tets10)
    types = [c.type for c in m.cells]
    ti, fi = types.index("tetra10"), types.index("triangle6")
    assert set(m.cell_data) == {"absorber_fraction", "ml_fraction", "core_fraction", "rod", "face_tag"}
    for k, name in enumerate(("absorber_fraction", "ml_fraction", "core_fraction")):
        np.testing.assert_array_equal(m.cell_data[name][ti], mesh.layer_fraction[:, k])
        assert np.all(np.isnan(m.cell_data[name][fi]))
    np.testing.assert_array_equal(m.cell_data["rod"][ti], mesh.tet_rod)
    np.testing.assert_array_equal(m.cell_data["rod"][fi], mesh.face_rod)
    np.testing.assert_array_equal(m.cell_data["face_tag"][ti], -1)
    np.testing.assert_array_equal(m.cell_data["face_tag"][fi], mesh.face_tag)
    # The re-read quadratic cells have the same volumes.
    np.testing.assert_allclose(duffy_volume(m.points[blocks["tetra10"]]), mesh.volumes(), rtol=1e-10)


# ----------------------------------------------------------------- 7. layer_fractions determinism
def test_layer_fractions_deterministic_and_reproduce_the_mesh(built):
    g, mesh, _ = built
    nodes10 = mesh.points10[mesh.tets10]
    a = layer_fractions(g, nodes10, 3)
    b = layer_fractions(g, nodes10, 3)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, mesh.layer_fraction)  # the default fraction_levels is 3
    assert np.sum((a.max(axis=1) < 1)) > 0


def test_mesh_report_matches_mesh(built):
    g, mesh, report = built
    again = mesh_report(g, mesh)
    assert again == {k: v for k, v in report.items() if k != "attempts"}
    assert report["attempts"][-1]["outcome"] == "accepted"
    assert report["n_nodes_quadratic"] == len(mesh.points10)
