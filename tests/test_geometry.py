"""Verification of fem.geometry: analytic measures, the depth field, boundary classification and
projection, and the manifold3d solids, against independent computations (Monte Carlo, brute-force
distances, finite differences, convergence rates).

All lengths in metres.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from fem.geometry import (
    FaceTag,
    Layer,
    RodArray,
    classify_boundary,
    depth_below_top,
    emitting_surface,
    layer_index,
    outer_surface,
    project_to_surface,
    solid_below_depth,
)

MM = 1e-3

#: The 2 x 2 array of the brief (pitch 7.2 mm, radius 2.5 mm, height 9 mm, base 2 mm, layers 0.3 / 0.5 mm).
G22 = RodArray(2, 2, 7.2 * MM, 7.2 * MM, 2.5 * MM, 9 * MM, 2 * MM, 0.3 * MM, 0.5 * MM)
#: A non-square array with unequal pitches and other layer thicknesses: catches x/y or row/col swaps.
G23 = RodArray(2, 3, 6.5 * MM, 8.0 * MM, 2.0 * MM, 6 * MM, 2.5 * MM, 0.25 * MM, 0.6 * MM)
GEOMS = [pytest.param(G22, id="2x2"), pytest.param(G23, id="2x3-aniso")]

#: manifold3d rounds its cross-sections and hands vertices back in float32: vertices lie up to
#: ~4e-9 m off their exact positions at these sizes (1e-6 of the body's size).
F32_TOL = 1e-8


# ----------------------------------------------------------------------------------- helpers
def inside_body(g: RodArray, p: np.ndarray) -> np.ndarray:
    """Independent membership test: in the base slab, or within R of the nearest rod axis (brute
    force over all axes, not rod_of) below the tip."""
    hx, hy = g.size_x_m / 2, g.size_y_m / 2
    in_box = (np.abs(p[:, 0]) <= hx) & (np.abs(p[:, 1]) <= hy) & (p[:, 2] >= 0)
    r = np.min(np.linalg.norm(p[:, None, :2] - g.centres_m[None], axis=2), axis=1)
    return in_box & ((p[:, 2] <= g.base_thickness_m) | ((r < g.rod_radius_m) & (p[:, 2] <= g.tip_z_m)))


def sample_box(g: RodArray, n: int, rng: np.random.Generator) -> tuple[np.ndarray, float]:
    lo = np.array([-g.size_x_m / 2, -g.size_y_m / 2, 0.0])
    hi = np.array([g.size_x_m / 2, g.size_y_m / 2, g.tip_z_m])
    return lo + (hi - lo) * rng.random((n, 3)), float(np.prod(hi - lo))


def sample_interior(g: RodArray, n: int, rng: np.random.Generator) -> np.ndarray:
    p, _ = sample_box(g, 4 * n, rng)
    p = p[inside_body(g, p)]
    assert len(p) >= n
    return p[:n]


def unique_edges_with_counts(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    return np.unique(e, axis=0, return_counts=True)


# ------------------------------------------------------------------- 1. analytic volumes (Monte Carlo)
@pytest.fixture(scope="module", params=GEOMS)
def mc(request):
    """2e6 uniform points in the bounding box of the body, with the independent membership test."""
    g = request.param
    rng = np.random.default_rng(12345)
    p, box = sample_box(g, 2_000_000, rng)
    inside = inside_body(g, p)
    return g, p, box, inside


def _mc_estimate(indicator: np.ndarray, box: float) -> tuple[float, float]:
    f = indicator.astype(float)
    return f.mean() * box, f.std(ddof=1) / math.sqrt(len(f)) * box


def test_total_volume_monte_carlo(mc):
    g, _, box, inside = mc
    est, se = _mc_estimate(inside, box)
    assert abs(est - g.volume_m3()) < 3 * se
    assert se < 2e-3 * g.volume_m3()  # the test is sharp enough to matter


def test_layer_volumes_monte_carlo(mc):
    g, p, box, inside = mc
    exact = g.layer_volumes_m3()
    assert set(exact) == {"absorber", "ml", "core"}
    layer = layer_index(g, p)
    for k, name in enumerate(("absorber", "ml", "core")):
        est, se = _mc_estimate(inside & (layer == k), box)
        assert abs(est - exact[name]) < 3 * se, (name, est, exact[name], se)
        assert se < 0.01 * exact[name]
    # The three layers partition the body.
    assert math.isclose(sum(exact.values()), g.volume_m3(), rel_tol=1e-12)
    assert all(v > 0 for v in exact.values())


@pytest.mark.parametrize("frac", [0.05, 0.2, 0.5, 0.9])
def test_volume_within_depth_monte_carlo(mc, frac):
    g, p, box, inside = mc
    d = frac * min(g.rod_radius_m, g.rod_height_m, g.base_thickness_m)
    depth = depth_below_top(g, p)
    est, se = _mc_estimate(inside & (depth < d), box)
    assert abs(est - g.volume_within_depth_m3(d)) < 3 * se, (est, g.volume_within_depth_m3(d), se)


@pytest.mark.parametrize("g", GEOMS)
def test_volume_within_depth_is_integral_of_sheet_area(g):
    """Coarea formula (|grad depth| = 1): d/dd V(<d) = A(d), and V(<0) = 0."""
    assert abs(g.volume_within_depth_m3(0.0)) < 1e-12 * g.volume_m3()
    dmax = min(g.rod_radius_m, g.rod_height_m, g.base_thickness_m)
    for d in np.linspace(0.05, 0.9, 7) * dmax:
        h = 1e-4 * dmax
        deriv = (g.volume_within_depth_m3(d + h) - g.volume_within_depth_m3(d - h)) / (2 * h)
        assert math.isclose(deriv, g.sheet_area_m2(d), rel_tol=1e-7), d


@pytest.mark.parametrize("g", GEOMS)
def test_sheet_area_zero_depth_is_top_surface(g):
    a = g.face_areas_m2()
    top = a[FaceTag.BASE_TOP] + a[FaceTag.ROD_SIDE] + a[FaceTag.ROD_TIP]
    assert math.isclose(g.sheet_area_m2(0.0), top, rel_tol=1e-12)


@pytest.mark.parametrize("g", GEOMS)
def test_face_areas_sum_to_outer_surface_area(g):
    """The five tagged analytic areas add up to the polygonal outer surface's area (chord error
    of second order: < 0.5 % at 48 segments, ~4x smaller at 96)."""
    exact = sum(g.face_areas_m2().values())
    err = [outer_surface(g, n).area / exact - 1 for n in (48, 96)]
    assert abs(err[0]) < 5e-3
    assert 3.5 < err[0] / err[1] < 4.5


def test_centres_and_rod_of_row_major():
    g = G23
    c = g.centres_m
    assert c.shape == (6, 2)
    # Row-major: n = row * cols + col, rows along +y, columns along +x, from the negative side.
    for n, (cx, cy) in enumerate(c):
        row, col = divmod(n, g.cols)
        assert math.isclose(cx, (col + 0.5) * g.pitch_x_m - g.size_x_m / 2, abs_tol=1e-15)
        assert math.isclose(cy, (row + 0.5) * g.pitch_y_m - g.size_y_m / 2, abs_tol=1e-15)
    rng = np.random.default_rng(7)
    p = np.column_stack([rng.uniform(-g.size_x_m / 2, g.size_x_m / 2, 5000), rng.uniform(-g.size_y_m / 2, g.size_y_m / 2, 5000)])
    brute = np.argmin(np.linalg.norm(p[:, None] - c[None], axis=2), axis=1)  # cells = Voronoi cells of the axes
    np.testing.assert_array_equal(g.rod_of(p), brute)


# --------------------------------------------------------------------------- 2. solid_below_depth
def _depths(g):
    return [0.0, g.absorber_m, g.core_depth_m]




@pytest.mark.parametrize(
    "g, d",
    [
        pytest.param(G22, 0.0, id="2x2-depth0"),
        pytest.param(G22, G22.absorber_m, id="2x2-absorber"),
        pytest.param(G22, G22.core_depth_m, id="2x2-core"),
        pytest.param(G23, 0.0, id="2x3-depth0"),
        pytest.param(G23, G23.core_depth_m, id="2x3-core"),
        pytest.param(G23, G23.absorber_m, id="2x3-absorber"),
        pytest.param(RodArray(1, 1, 7.2 * MM, 7.2 * MM, 2.5 * MM, 9 * MM, 2 * MM, 0.3 * MM, 0.5 * MM), 0.1 * MM, id="1x1-0.1mm"),
    ],
)
@pytest.mark.parametrize("segments", [48, 96])
def test_solid_below_depth_is_watertight(g, d, segments):
    s = solid_below_depth(g, d, segments)
    edges, counts = unique_edges_with_counts(np.asarray(s.faces))
    assert np.all(counts == 2), np.unique(counts)
    assert s.is_watertight and s.is_winding_consistent
    assert s.volume > 0  # outward normals
    # One connected body, of genus 0 (Euler characteristic 2).
    assert len(s.split(only_watertight=False)) == 1
    assert len(s.vertices) - len(edges) + len(s.faces) == 2


@pytest.mark.parametrize("g", GEOMS)
@pytest.mark.parametrize("which", [0, 1, 2], ids=["depth0", "absorber", "core"])
def test_solid_below_depth_volume_and_convergence(g, which):
    d = _depths(g)[which]
    exact = g.volume_m3() - g.volume_within_depth_m3(d)
    err = []
    for segments in (48, 96):
        s = solid_below_depth(g, d, segments)
        err.append(s.volume / exact - 1)
    assert abs(err[0]) < 5e-3
    # Chord error of a polygon inscribed in circles/arcs: second order in 1 / segments.
    assert 3.5 < err[0] / err[1] < 4.5, err


@pytest.mark.parametrize("which", [0, 1, 2], ids=["depth0", "absorber", "core"])
def test_solid_below_depth_vertices_lie_on_exact_sheet(which):
    """Every vertex not on the base bottom/sides lies on the sheet at depth d (vertices on exact circles/arcs)."""
    g = G22
    d = _depths(g)[which]
    v = solid_below_depth(g, d, 48).vertices
    on_bottom = np.abs(v[:, 2]) < F32_TOL
    assert on_bottom.sum() >= 4
    top = v[~on_bottom]
    # At depth 0 depth_below_top is 0 on the surface; compare with the piecewise distance instead.
    if d == 0.0:
        _, _, dist = classify_boundary(g, top)
        assert dist.max() < F32_TOL
    else:
        np.testing.assert_allclose(depth_below_top(g, top), d, atol=F32_TOL)
    # The rod tips sit at z = T + H - d.
    assert math.isclose(v[:, 2].max(), g.tip_z_m - d, abs_tol=F32_TOL)


# -------------------------------------------------------------------------- 3. emitting_surface
@pytest.fixture(scope="module", params=GEOMS)
def sheet(request):
    g = request.param
    return g, emitting_surface(g, 48)


def test_emitting_surface_area(sheet):
    g, s = sheet
    assert abs(s.area / g.sheet_area_m2(g.core_depth_m) - 1) < 5e-3


def test_emitting_surface_boundary_on_side_walls(sheet):
    g, s = sheet
    edges, counts = unique_edges_with_counts(np.asarray(s.faces))
    assert set(np.unique(counts)) <= {1, 2}  # a manifold sheet
    b = edges[counts == 1]
    pts = s.vertices[b.ravel()]
    z_cut = g.base_thickness_m - g.core_depth_m
    np.testing.assert_allclose(pts[:, 2], z_cut, atol=F32_TOL)
    wall = np.minimum(np.abs(np.abs(pts[:, 0]) - g.size_x_m / 2), np.abs(np.abs(pts[:, 1]) - g.size_y_m / 2))
    assert wall.max() < F32_TOL
    # The boundary is the whole rectangle at z = T - d, once.
    length = np.linalg.norm(s.vertices[b[:, 0]] - s.vertices[b[:, 1]], axis=1).sum()
    assert math.isclose(length, 2 * (g.size_x_m + g.size_y_m), rel_tol=1e-6)
    # Nothing of the bottom or the side walls below the cut is left.
    assert s.vertices[:, 2].min() > z_cut - F32_TOL


def test_emitting_surface_vertices_at_core_depth(sheet):
    g, s = sheet
    np.testing.assert_allclose(depth_below_top(g, s.vertices), g.core_depth_m, atol=F32_TOL)


def test_emitting_surface_normals_point_out_of_core(sheet):
    g, s = sheet
    assert s.is_winding_consistent
    n = s.face_normals
    c = s.triangles_center
    # Outwards = towards the layers = the direction in which depth decreases.
    h = 1e-7
    slope = (depth_below_top(g, c - h * n) - depth_below_top(g, c + h * n)) / (2 * h)
    assert slope.min() > 0.5
    assert np.median(slope) > 0.999
    # Rod tips (inner discs at z = tip - d) and the base plane (z = T - d): normals +z.
    tip = np.abs(c[:, 2] - (g.tip_z_m - g.core_depth_m)) < F32_TOL
    plane = np.abs(c[:, 2] - (g.base_thickness_m - g.core_depth_m)) < F32_TOL
    assert tip.sum() >= g.n_rods and plane.sum() > 0
    assert n[tip, 2].min() > 0.999999
    assert n[plane, 2].min() > 0.999999
    # Inner rod cylinders: radial outwards.
    rod, r = g.radial(c)
    cyl = (c[:, 2] > g.base_thickness_m + 1e-4) & (c[:, 2] < g.tip_z_m - g.core_depth_m - 1e-4)
    radial = (c[cyl, :2] - g.centres_m[rod[cyl]]) / r[cyl, None]
    assert np.einsum("ij,ij->i", n[cyl, :2], radial).min() > 0.99


# ------------------------------------------------------------------------- 4. depth_below_top
def test_depth_known_points():
    g = G23
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    hx = g.size_x_m / 2
    for cx, cy in g.centres_m:
        pts = np.array(
            [
                [cx, cy, t + g.rod_height_m / 2],  # rod axis, mid-height (H / 2 > R): depth R
                [cx + 0.5 * big_r, cy, tip - 0.3 * MM],  # under the tip: tip - z
                [cx, cy - 0.9 * big_r, t + 2 * MM],  # near the rod side: R - r
                [cx - (big_r - 0.2 * MM), cy, t - 0.1 * MM],  # under the rim: hypot(0.2, 0.1) mm
                [cx, cy + big_r + 0.5 * MM, t - 0.1 * MM],  # under the free base top: T - z
            ]
        )
        want = [big_r, 0.3 * MM, 0.1 * big_r, math.hypot(0.2 * MM, 0.1 * MM), 0.1 * MM]
        np.testing.assert_allclose(depth_below_top(g, pts), want, rtol=1e-12, atol=1e-18)
    # Between rods and next to the base's side wall (the side walls are not top surface).
    pts = np.array([[0.0, 0.0, t - 0.1 * MM], [hx - 1e-6, 0.0, t - 0.5 * MM]])
    np.testing.assert_allclose(depth_below_top(g, pts), [0.1 * MM, 0.5 * MM], rtol=1e-12)


def _top_surface_samples(g: RodArray, h: float) -> np.ndarray:
    """Points of the exact top surface (base top, rod sides, rod tips) on grids of spacing <= h."""
    hx, hy, t, tip, big_r = g.size_x_m / 2, g.size_y_m / 2, g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    x = np.linspace(-hx, hx, int(np.ceil(2 * hx / h)) + 1)
    y = np.linspace(-hy, hy, int(np.ceil(2 * hy / h)) + 1)
    xx, yy = np.meshgrid(x, y)
    base = np.column_stack([xx.ravel(), yy.ravel()])
    r_base = np.min(np.linalg.norm(base[:, None] - g.centres_m[None], axis=2), axis=1)
    base = base[r_base >= big_r]
    parts = [np.column_stack([base, np.full(len(base), t)])]
    n_theta = int(np.ceil(2 * np.pi * big_r / h))
    theta = np.linspace(0, 2 * np.pi, n_theta, endpoint=False)
    z = np.linspace(t, tip, int(np.ceil(g.rod_height_m / h)) + 1)
    tt, zz = np.meshgrid(theta, z)
    for cx, cy in g.centres_m:
        parts.append(np.column_stack([cx + big_r * np.cos(tt.ravel()), cy + big_r * np.sin(tt.ravel()), zz.ravel()]))
        u = np.linspace(-big_r, big_r, int(np.ceil(2 * big_r / h)) + 1)
        uu, vv = np.meshgrid(u, u)
        disc = np.hypot(uu, vv).ravel() <= big_r
        parts.append(np.column_stack([cx + uu.ravel()[disc], cy + vv.ravel()[disc], np.full(disc.sum(), tip)]))
    return np.concatenate(parts)


def test_depth_matches_brute_force_distance_to_top_surface():
    """Independent check: the distance to a dense sampling of the top surface is >= the exact
    distance and exceeds it by at most the sampling's covering radius."""
    g = G22
    h = 4e-5
    tree = cKDTree(_top_surface_samples(g, h))
    rng = np.random.default_rng(2024)
    p = sample_interior(g, 3000, rng)
    brute, _ = tree.query(p)
    depth = depth_below_top(g, p)
    assert np.all(depth <= brute + 1e-12)
    assert np.max(brute - depth) < h  # covering radius h / sqrt(2) on a grid, a bit more on the cylinders
    assert depth.max() > 1 * MM  # the sample reaches deep points


def test_depth_is_one_lipschitz_and_eikonal():
    g = G22
    rng = np.random.default_rng(99)
    p = sample_interior(g, 20000, rng)
    q = sample_interior(g, 20000, rng)
    dp, dq = depth_below_top(g, p), depth_below_top(g, q)
    assert np.all(np.abs(dp - dq) <= np.linalg.norm(p - q, axis=1) * (1 + 1e-12) + 1e-18)
    # Close pairs probe the local slope.
    step = rng.normal(size=p.shape)
    step *= 1e-4 / np.linalg.norm(step, axis=1, keepdims=True)
    q = p + step
    ok = inside_body(g, q)
    dist = np.linalg.norm(step[ok], axis=1)
    ratio = np.abs(dp[ok] - depth_below_top(g, q[ok])) / dist
    assert ratio.max() <= 1 + 1e-9
    # |grad depth| = 1 almost everywhere (distance function): central differences.
    e = 1e-8
    grad = np.stack([(depth_below_top(g, p + e * u) - depth_below_top(g, p - e * u)) / (2 * e) for u in np.eye(3)], axis=1)
    norm = np.linalg.norm(grad, axis=1)
    assert norm.max() < 1 + 1e-5
    assert np.median(np.abs(norm - 1)) < 1e-6


def test_depth_zero_above_top_surface():
    g = G22
    rng = np.random.default_rng(5)
    p, _ = sample_box(g, 20000, rng)
    p[:, 2] = rng.uniform(g.base_thickness_m, g.tip_z_m + 2 * MM, len(p))
    out = ~inside_body(g, p)
    assert out.sum() > 1000
    assert np.all(depth_below_top(g, p[out]) == 0.0)
    # And layer_index calls those points absorber (depth 0 < a), by construction.
    assert np.all(layer_index(g, p[out]) == Layer.ABSORBER)


def test_depth_zero_below_and_beside_the_base():
    g = G22
    hx = g.size_x_m / 2
    p = np.array([[0.0, 0.0, -1 * MM], [hx + 1 * MM, 0.0, 1 * MM], [0.0, -(hx + 0.5 * MM), 0.5 * MM]])
    assert not inside_body(g, p).any()
    np.testing.assert_array_equal(depth_below_top(g, p), 0.0)


def test_layer_index_thresholds():
    g = G22
    c = g.centres_m[0]
    # Points on a rod axis below the tip at known depths (tip - z, the axis being R deep).
    dz = np.array([0.1, 0.299, 0.301, 0.799, 0.801, 1.5]) * MM
    p = np.column_stack([np.full(6, c[0]), np.full(6, c[1]), g.tip_z_m - dz])
    np.testing.assert_array_equal(layer_index(g, p), [0, 0, 1, 1, 2, 2])


# ---------------------------------------------------------------- 5. classify_boundary / project
def _boundary_samples(g: RodArray, n: int, rng: np.random.Generator, margin: float):
    """Points on each analytic boundary piece, away from its edges by ``margin``: (points, outward
    unit normals, tag, rod)."""
    hx, hy, t, tip, big_r = g.size_x_m / 2, g.size_y_m / 2, g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    pts, nrm, tag, rod = [], [], [], []

    def add(p, nn, tg, rd):
        pts.append(p), nrm.append(nn), tag.append(np.full(len(p), tg)), rod.append(rd)

    xy = np.column_stack([rng.uniform(-hx + margin, hx - margin, n), rng.uniform(-hy + margin, hy - margin, n)])
    add(np.column_stack([xy, np.zeros(n)]), np.tile([0, 0, -1.0], (n, 1)), FaceTag.BASE_BOTTOM, np.full(n, -1))
    for axis, sign in [(0, 1), (0, -1), (1, 1), (1, -1)]:
        half_other = hy if axis == 0 else hx
        p = np.zeros((n, 3))
        p[:, axis] = sign * (hx if axis == 0 else hy)
        p[:, 1 - axis] = rng.uniform(-half_other + margin, half_other - margin, n)
        p[:, 2] = rng.uniform(margin, t - margin, n)
        nn = np.zeros((n, 3))
        nn[:, axis] = sign
        add(p, nn, FaceTag.BASE_SIDE, np.full(n, -1))
    xy = np.column_stack([rng.uniform(-hx + margin, hx - margin, 4 * n), rng.uniform(-hy + margin, hy - margin, 4 * n)])
    r_min = np.min(np.linalg.norm(xy[:, None] - g.centres_m[None], axis=2), axis=1)
    xy = xy[r_min > big_r + margin][:n]
    add(np.column_stack([xy, np.full(len(xy), t)]), np.tile([0, 0, 1.0], (len(xy), 1)), FaceTag.BASE_TOP, np.full(len(xy), -1))
    for k, (cx, cy) in enumerate(g.centres_m):
        th = rng.uniform(0, 2 * np.pi, n)
        u = np.column_stack([np.cos(th), np.sin(th), np.zeros(n)])
        p = np.column_stack([cx + big_r * u[:, 0], cy + big_r * u[:, 1], rng.uniform(t + margin, tip - margin, n)])
        add(p, u, FaceTag.ROD_SIDE, np.full(n, k))
        rr = (big_r - margin) * np.sqrt(rng.random(n))
        th = rng.uniform(0, 2 * np.pi, n)
        p = np.column_stack([cx + rr * np.cos(th), cy + rr * np.sin(th), np.full(n, tip)])
        add(p, np.tile([0, 0, 1.0], (n, 1)), FaceTag.ROD_TIP, np.full(n, k))
    return np.concatenate(pts), np.concatenate(nrm), np.concatenate(tag), np.concatenate(rod)


@pytest.mark.parametrize("g", GEOMS)
def test_classify_and_project_points_pushed_off_each_piece(g):
    rng = np.random.default_rng(31415)
    margin = 1e-4
    foot, normal, tag, rod = _boundary_samples(g, 300, rng, margin)
    assert set(np.unique(tag)) == set(int(t) for t in FaceTag)
    scale = max(g.size_x_m, g.size_y_m, g.tip_z_m)
    for offset in (-1e-5, -1e-7, 0.0, 1e-7, 1e-5):  # inwards (< 0) and outwards; |offset| << margin
        p = foot + offset * normal
        got_tag, got_rod, dist = classify_boundary(g, p)
        np.testing.assert_array_equal(got_tag, tag)
        np.testing.assert_array_equal(got_rod, rod)
        assert got_tag.dtype == np.int8 and got_rod.dtype == np.int32
        np.testing.assert_allclose(dist, abs(offset), rtol=1e-6, atol=1e-12 * scale)
        proj = project_to_surface(g, p)
        assert np.max(np.linalg.norm(proj - foot, axis=1)) < 1e-12 * scale
        # Idempotent.
        again = project_to_surface(g, proj)
        assert np.max(np.linalg.norm(again - proj, axis=1)) < 1e-12 * scale


@pytest.mark.parametrize("g", GEOMS)
def test_projection_of_interior_points_is_on_surface_idempotent_and_nearest(g):
    rng = np.random.default_rng(271828)
    p = sample_interior(g, 5000, rng)
    scale = max(g.size_x_m, g.size_y_m, g.tip_z_m)
    proj = project_to_surface(g, p)
    _, _, on = classify_boundary(g, proj)
    assert on.max() < 1e-12 * scale  # lands on the exact boundary
    np.testing.assert_allclose(project_to_surface(g, proj), proj, rtol=0, atol=1e-12 * scale)
    # The projection distance is the distance classify_boundary reports, and no boundary sample is closer.
    _, _, dist = classify_boundary(g, p)
    np.testing.assert_allclose(np.linalg.norm(proj - p, axis=1), dist, rtol=1e-9, atol=1e-15)
    foot, *_ = _boundary_samples(g, 2000, np.random.default_rng(1), 0.0)
    brute, _ = cKDTree(foot).query(p)
    assert np.all(dist <= brute + 1e-15)


def test_classify_and_project_points_in_the_air_around_the_rods():
    """Points outside the body next to a rod (above the base top, beside or above the rod): the
    nearest boundary point is on the rod side, the base top, or (above the tip, beyond the
    radius) the tip rim, with the distance known in closed form."""
    g = G22
    t, tip, big_r = g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    rng = np.random.default_rng(4242)
    n = 4000
    k = rng.integers(0, g.n_rods, n)
    th = rng.uniform(0, 2 * np.pi, n)
    gap = rng.uniform(1e-6, 1 * MM, n)  # r - R; R + 1 mm stays inside the rod's cell
    z = rng.uniform(t + 1e-6, tip + 1 * MM, n)
    u = np.column_stack([np.cos(th), np.sin(th)])
    c = g.centres_m[k]
    p = np.column_stack([c + (big_r + gap)[:, None] * u, z])
    above = z >= tip
    to_side = ~above & (gap < z - t)
    foot = np.column_stack([c + big_r * u, np.where(above, tip, z)])  # rod side, or the tip rim
    foot[~above & ~to_side, :2] = p[~above & ~to_side, :2]  # straight down onto the base top
    foot[~above & ~to_side, 2] = t
    assert above.sum() > 100 and to_side.sum() > 100 and (~above & ~to_side).sum() > 100
    want = np.linalg.norm(p - foot, axis=1)
    tag, rod, dist = classify_boundary(g, p)
    np.testing.assert_allclose(dist, want, rtol=1e-9)
    np.testing.assert_array_equal(tag[to_side], FaceTag.ROD_SIDE)
    np.testing.assert_array_equal(tag[~above & ~to_side], FaceTag.BASE_TOP)
    assert np.all(np.isin(tag[above], [FaceTag.ROD_SIDE, FaceTag.ROD_TIP]))
    np.testing.assert_array_equal(rod[tag >= FaceTag.ROD_SIDE], k[tag >= FaceTag.ROD_SIDE])
    scale = g.tip_z_m
    assert np.max(np.linalg.norm(project_to_surface(g, p) - foot, axis=1)) < 1e-12 * scale
    assert np.all(depth_below_top(g, p) == 0.0)


def test_projection_near_convex_base_edges_from_outside():
    g = G22
    hx, hy, t = g.size_x_m / 2, g.size_y_m / 2, g.base_thickness_m
    e = 1e-4
    p = np.array([[hx + e, 0.1 * MM, -e], [hx + e, hy + 2 * e, 1 * MM], [hx + e, 0.1 * MM, t + e]])
    want = np.array([[hx, 0.1 * MM, 0.0], [hx, hy, 1 * MM], [hx, 0.1 * MM, t]])
    np.testing.assert_allclose(project_to_surface(g, p), want, rtol=0, atol=1e-15)
    _, _, dist = classify_boundary(g, p)
    np.testing.assert_allclose(dist, np.linalg.norm(p - want, axis=1), rtol=1e-12)


def _sharp_edge_cases(g: RodArray, rng: np.random.Generator, tol: float, n: int = 40):
    """Points within tol / 2 (per coordinate) of the body's sharp edges and corners, and where
    ``project_to_surface(..., edge_tol_m=tol)`` must put them: exactly on the edge / corner."""
    hx, hy, t, tip, big_r = g.size_x_m / 2, g.size_y_m / 2, g.base_thickness_m, g.tip_z_m, g.rod_radius_m
    u = lambda k: rng.uniform(-0.3 * tol, 0.3 * tol, (n, k))  # noqa: E731
    want, pts = [], []
    for z_edge in (0.0, t):  # base bottom / top edges of the x = +-hx and y = +-hy walls
        for sign in (1, -1):
            e = np.column_stack([np.full(n, sign * hx), rng.uniform(-hy + 1e-3, hy - 1e-3, n), np.full(n, z_edge)])
            want.append(e), pts.append(e + np.column_stack([u(1), np.zeros(n), u(1)]))
            e = np.column_stack([rng.uniform(-hx + 1e-3, hx - 1e-3, n), np.full(n, sign * hy), np.full(n, z_edge)])
            want.append(e), pts.append(e + np.column_stack([np.zeros(n), u(1), u(1)]))
    for sx in (1, -1):  # the 8 corners of the base (three pieces meet)
        for sy in (1, -1):
            for z_edge in (0.0, t):
                e = np.tile([sx * hx, sy * hy, z_edge], (n, 1))
                want.append(e), pts.append(e + u(3))
    for cx, cy in g.centres_m:  # rod foot and tip rims
        th = rng.uniform(0, 2 * np.pi, n)
        for z_edge in (t, tip):
            e = np.column_stack([cx + big_r * np.cos(th), cy + big_r * np.sin(th), np.full(n, z_edge)])
            dr, dz = u(1)[:, 0], u(1)[:, 0]
            p = np.column_stack([cx + (big_r + dr) * np.cos(th), cy + (big_r + dr) * np.sin(th), z_edge + dz])
            want.append(e), pts.append(p)
    return np.concatenate(pts), np.concatenate(want)


@pytest.mark.parametrize("g", GEOMS)
def test_project_with_edge_tolerance_lands_on_sharp_edges(g):
    tol = 1e-4
    scale = max(g.size_x_m, g.size_y_m, g.tip_z_m)
    p, want = _sharp_edge_cases(g, np.random.default_rng(77), tol)
    got = project_to_surface(g, p, edge_tol_m=tol)
    assert np.max(np.linalg.norm(got - want, axis=1)) < 1e-12 * scale
    # Without the tolerance they land on one piece only, not on the edge (so the check above has teeth).
    assert np.median(np.linalg.norm(project_to_surface(g, p) - want, axis=1)) > 1e-2 * tol
    _, _, dist = classify_boundary(g, got)
    assert dist.max() < 1e-12 * scale
    np.testing.assert_allclose(project_to_surface(g, got, edge_tol_m=tol), got, rtol=0, atol=1e-12 * scale)


@pytest.mark.parametrize("g", GEOMS)
def test_project_with_edge_tolerance_leaves_points_away_from_edges_alone(g):
    tol = 1e-4
    scale = max(g.size_x_m, g.size_y_m, g.tip_z_m)
    foot, normal, _, _ = _boundary_samples(g, 200, np.random.default_rng(78), margin=3 * tol)
    p = foot + np.random.default_rng(79).uniform(-0.5, 0.5, (len(foot), 1)) * tol * normal
    got = project_to_surface(g, p, edge_tol_m=tol)
    np.testing.assert_allclose(got, project_to_surface(g, p), rtol=0, atol=0)
    assert np.max(np.linalg.norm(got - foot, axis=1)) < 1e-12 * scale


# ------------------------------------------------------------------------------ 6. bad input
def _bad_depths(g):
    top = min(g.rod_radius_m, g.rod_height_m, g.base_thickness_m)
    return [-1e-9, -1 * MM, top, top * 1.5, float("nan")]


@pytest.mark.parametrize("k", range(5))
def test_volume_within_depth_rejects_out_of_range(k):
    d = _bad_depths(G22)[k]
    with pytest.raises(ValueError, match="depth_m"):
        G22.volume_within_depth_m3(d)


@pytest.mark.parametrize("k", range(5))
def test_solid_below_depth_rejects_out_of_range(k):
    d = _bad_depths(G22)[k]
    with pytest.raises(ValueError, match="depth_m"):
        solid_below_depth(G22, d)


def test_too_thick_layers_rejected():
    # absorber + ML = 2.6 mm >= R = 2.5 mm: the core boundary does not exist.
    g = RodArray(2, 2, 7.2 * MM, 7.2 * MM, 2.5 * MM, 9 * MM, 3 * MM, 0.3 * MM, 2.3 * MM)
    assert g.volume_within_depth_m3(g.absorber_m) > 0  # the absorber alone is fine
    with pytest.raises(ValueError):
        g.layer_volumes_m3()
    with pytest.raises(ValueError):
        emitting_surface(g)


def test_largest_valid_depth_accepted():
    g = G22
    d = np.nextafter(min(g.rod_radius_m, g.rod_height_m, g.base_thickness_m), 0)
    assert g.volume_within_depth_m3(d) < g.volume_m3()


@pytest.mark.parametrize("k", [1, 2])
def test_sheet_area_rejects_out_of_range(k):
    with pytest.raises(ValueError):
        G22.sheet_area_m2(_bad_depths(G22)[k])
