"""Rigid indenter signed distances: exact values, unit normals, 1-Lipschitz, pose, scene mapping."""

from __future__ import annotations

import numpy as np
import pytest

from fem.indenters import IndenterShape, Pose, gap_and_normal, shape_from_scene, signed_distance_local
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
