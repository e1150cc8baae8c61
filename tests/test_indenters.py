"""Rigid indenter signed distances: exact values, unit normals, 1-Lipschitz, pose, scene mapping."""

from __future__ import annotations

import numpy as np
import pytest

from fem.indenters import IndenterShape, Pose, gap_and_normal, gap_normal, gap_normal_hessian, shape_from_scene, signed_distance_local
from mlsim.scene import scene_from_dict

SHAPES = [
    IndenterShape("flat", (12.6e-3, 10e-3)),
    IndenterShape("sphere", (3e-3,)),
    IndenterShape("cylinder", (3.85e-3, 160e-3)),  # the M8 screw, SPEC 1.5
    IndenterShape("box", (2e-3, 2e-3, 4e-3)),  # the steel block of SPEC 1.4
]


def test_reference_values():
    flat, sphere, cyl, box = SHAPES
    below = np.array([[0.0, 0.0, -1e-3], [5e-3, 0.0, -2e-3]])
    np.testing.assert_allclose(signed_distance_local(flat, below), [1e-3, 2e-3])
    np.testing.assert_allclose(signed_distance_local(flat, [[12.6e-3 + 3e-3, 0.0, -4e-3]]), [5e-3])  # rim: 3-4-5
    np.testing.assert_allclose(signed_distance_local(sphere, [[0.0, 0.0, -1e-3], [0.0, 0.0, 3e-3]]), [1e-3, -3e-3])
    np.testing.assert_allclose(signed_distance_local(cyl, [[50e-3, 0.0, -1e-3], [0.0, 3.85e-3 + 2e-3, 3.85e-3]]), [1e-3, 2e-3])
    np.testing.assert_allclose(signed_distance_local(box, [[0.0, 0.0, -0.5e-3], [0.0, 0.0, 2e-3]]), [0.5e-3, -1e-3])


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.kind)
def test_unit_normals_lipschitz_and_surface(shape):
    rng = np.random.default_rng(7)
    scale = max(shape.size_m[:2])
    X = rng.uniform(-1.5 * scale, 1.5 * scale, (2000, 3)) * [1, 1, 0.5]
    pose = Pose((1e-3, -2e-3, 0.5e-3), yaw_rad=0.4)
    gap, n = gap_and_normal(shape, pose, X)
    np.testing.assert_allclose(np.linalg.norm(n, axis=0), 1.0, atol=1e-9)
    # 1-Lipschitz over random pairs
    Y = X + rng.normal(size=X.shape) * 1e-4
    gy, _ = gap_and_normal(shape, pose, Y)
    assert np.all(np.abs(gy - gap) <= np.linalg.norm(Y - X, axis=1) * (1 + 1e-9))
    # stepping along the normal by the gap lands on the surface (away from edges, where it is exact)
    far = np.abs(gap) > 1e-5
    landed, _ = gap_and_normal(shape, pose, X[far] - (gap[far] * n[:, far]).T)
    assert np.median(np.abs(landed)) < 1e-9 * scale * 1e3


ROUNDED = [
    IndenterShape("flat", (12.6e-3, 10e-3), 0.5e-3),
    IndenterShape("box", (2e-3, 3e-3, 4e-3), 0.3e-3),
]


@pytest.mark.parametrize("shape", SHAPES + ROUNDED, ids=lambda s: s.kind + ("_rounded" if s.edge_radius_m else ""))
def test_analytic_gradient_and_hessian_match_finite_differences(shape):
    """The closed-form normal and dn/dX against central differences of the distance (step 1e-7 of the
    size; truncation error h^2 / rho^2 ~ 1e-12), at points off the sets where they jump (edges, the
    axis, the medial surfaces inside), in a yawed, shifted pose."""
    rng = np.random.default_rng(11)
    scale = max(shape.size_m[:2])
    pose = Pose((1e-3, -2e-3, 0.5e-3), yaw_rad=0.7)
    X = rng.uniform(-1.5 * scale, 1.5 * scale, (3000, 3)) * [1, 1, 0.5]
    h = 1e-7 * scale
    gap, n, H = gap_normal_hessian(shape, pose, X)
    fd_n = np.empty_like(n)
    fd_H = np.empty_like(H)
    for k in range(3):
        e = np.zeros(3)
        e[k] = h
        gp, np_, _ = gap_normal_hessian(shape, pose, X + e)
        gm, nm, _ = gap_normal_hessian(shape, pose, X - e)
        fd_n[:, k] = (gp - gm) / (2 * h)
        fd_H[:, :, k] = (np_ - nm) / (2 * h)
    # smooth where the distance is twice differentiable across the whole stencil: same region at X +- 2h
    smooth = np.all(np.isfinite(fd_H), axis=(1, 2)) & (np.abs(gap) > 10 * h)
    for k in range(3):
        e = np.zeros(3)
        e[k] = 4 * h
        smooth &= np.all(np.abs(gap_normal_hessian(shape, pose, X + e)[2] - gap_normal_hessian(shape, pose, X - e)[2]) < 1e3 * h / scale**2, axis=(1, 2))
    assert smooth.mean() > 0.8  # the test does look at most points
    np.testing.assert_allclose(n[smooth], fd_n[smooth], atol=1e-6)
    np.testing.assert_allclose(H[smooth] * scale, fd_H[smooth] * scale, atol=1e-3)
    np.testing.assert_allclose(H, np.swapaxes(H, 1, 2), atol=1e-12)  # a Hessian is symmetric
    np.testing.assert_allclose(np.einsum("mij,mj->mi", H[smooth], n[smooth]), 0.0, atol=1e-6 / scale)  # n stays unit: H n = 0
    # a sphere's Hessian outside is (I - n n^T) / (gap + radius)
    if shape.kind == "sphere":
        out = gap > 0
        expect = (np.eye(3) - n[out, :, None] * n[out, None, :]) / (gap[out] + shape.size_m[0])[:, None, None]
        np.testing.assert_allclose(H[out], expect, rtol=1e-10, atol=1e-6)


@pytest.mark.parametrize("shape", SHAPES + [IndenterShape("flat", (12.6e-3, 5e-3), 0.5e-3), IndenterShape("box", (4e-3, 6e-3, 3e-3), 0.3e-3)],
                         ids=lambda s: f"{s.kind}-{s.edge_radius_m}")
def test_the_gap_and_normal_without_the_hessian_are_the_same(shape):
    """gap_normal (the contact steps' call) gives gap_normal_hessian's gap and normal exactly, rounded
    edges included, in a yawed pose, inside and outside the solid."""
    rng = np.random.default_rng(5)
    scale = min(max(shape.size_m[:2]), 10e-3)  # the screw's 160 mm: stay near its middle
    pose = Pose((1e-3, -2e-3, 0.5e-3), yaw_rad=0.7)
    X = rng.uniform(-1.5, 1.5, (400, 3)) * scale
    d, n = gap_normal(shape, pose, X)
    d_ref, n_ref, _ = gap_normal_hessian(shape, pose, X)
    assert (d < 0).any() and (d > 0).any()
    np.testing.assert_array_equal(d, d_ref)
    np.testing.assert_array_equal(n, n_ref)


def test_pose_translation_and_yaw():
    cyl = SHAPES[2]
    x = np.array([[0.0, 10e-3, -1e-3]])
    g0, _ = gap_and_normal(cyl, Pose((0.0, 0.0, 0.0), yaw_rad=0.0), x)  # axis along x: 10 mm off the axis
    g90, n90 = gap_and_normal(cyl, Pose((0.0, 0.0, 0.0), yaw_rad=np.pi / 2), x)  # axis along y: under it
    assert g0[0] > 5e-3 and g90[0] == pytest.approx(1e-3)
    np.testing.assert_allclose(n90[:, 0], [0, 0, -1], atol=1e-6)  # pushes the point straight down


def test_bad_shapes_and_scene_mapping():
    with pytest.raises(ValueError, match="choose one of: flat, sphere, cylinder, box"):
        IndenterShape("cone", (1.0,))
    with pytest.raises(ValueError, match="needs 3"):
        IndenterShape("box", (1.0, 1.0))
    scene = scene_from_dict({"load": {"indenter": {"shape": "flat", "tip_area_mm2": 500.0}, "segments": [{"kind": "hold", "duration_s": 1.0}]}})
    flat = shape_from_scene(scene.load.indenter)
    assert np.pi * flat.size_m[0] ** 2 == pytest.approx(500e-6)
