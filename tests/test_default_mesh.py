"""Acceptance of the default sensor's mesh at default fidelity (SPEC 1.1 geometry, issue #2)."""

from __future__ import annotations

import numpy as np
import pytest

from fem.geometry import FaceTag, emitting_surface, solid_below_depth
from fem.mesh import TET10_EDGES, p2_map


def test_no_inverted_tets(default_mesh):
    _, g, mesh, _ = default_mesh
    assert mesh.linear_volumes().min() > 0
    node_bary = np.vstack([np.eye(4), 0.5 * (np.eye(4)[TET10_EDGES[:, 0]] + np.eye(4)[TET10_EDGES[:, 1]])])
    _, det = p2_map(mesh.points10[mesh.tets10], node_bary)
    assert det.min() > 0  # curved tets are not folded anywhere we can see


def test_total_volume_within_1_percent(default_mesh):
    _, g, mesh, report = default_mesh
    assert mesh.volumes().sum() == pytest.approx(g.volume_m3(), rel=0.01)
    assert abs(report["volume_rel_error"]) < 0.01


@pytest.mark.parametrize("layer", ["absorber", "ml", "core"])
def test_layer_volumes_within_2_percent(default_mesh, layer):
    _, g, mesh, _ = default_mesh
    k = ["absorber", "ml", "core"].index(layer)
    volume = float(mesh.layer_fraction[:, k] @ mesh.volumes())
    assert volume == pytest.approx(g.layer_volumes_m3()[layer], rel=0.02)


def test_base_bottom_area_within_1_percent(default_mesh):
    _, g, mesh, _ = default_mesh
    area = mesh.face_areas()[mesh.face_tag == FaceTag.BASE_BOTTOM].sum()
    assert area == pytest.approx(g.size_x_m * g.size_y_m, rel=0.01)
    # the bottom is flat: every base-bottom node at z = 0
    assert np.abs(mesh.points[mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM]][..., 2]).max() < 1e-12


def test_every_rod_is_tagged(default_mesh):
    _, g, mesh, _ = default_mesh
    for tag in (FaceTag.ROD_SIDE, FaceTag.ROD_TIP):
        rods = np.unique(mesh.face_rod[mesh.face_tag == tag])
        assert list(rods) == list(range(g.n_rods))
    areas = np.bincount(mesh.face_tag, weights=mesh.face_areas(), minlength=5)
    for tag, exact in g.face_areas_m2().items():
        assert areas[tag] == pytest.approx(exact, rel=0.03), tag.name


def test_ml_layer_surface_watertight_where_it_should_be_and_area(default_mesh):
    scene, g, _, _ = default_mesh
    segments = scene.fidelity.mesh.segments_per_circle
    core = solid_below_depth(g, g.core_depth_m, segments)
    assert core.is_watertight and core.is_winding_consistent
    sheet = emitting_surface(g, segments)
    assert sheet.area == pytest.approx(g.sheet_area_m2(g.core_depth_m), rel=0.01)
    # Open only along the base's side walls, at the core's top height there.
    edges = sheet.edges_sorted
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    border = sheet.vertices[np.unique(uniq[counts == 1])]
    on_wall = np.isclose(np.abs(border[:, 0]), g.size_x_m / 2) | np.isclose(np.abs(border[:, 1]), g.size_y_m / 2)
    assert on_wall.all()
    assert np.allclose(border[:, 2], g.base_thickness_m - g.core_depth_m)
    assert set(counts) <= {1, 2}  # manifold: no edge shared by three faces


def test_quality_report_is_sane(default_mesh):
    _, _, mesh, report = default_mesh
    q = report["quality"]
    assert 0 < q["min_dihedral_deg"] < 70.53 < q["max_dihedral_deg"] < 180
    assert q["slivers"] < 0.01 * mesh.n_tets
    assert report["mesh_hash"] == mesh.content_hash()
