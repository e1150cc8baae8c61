"""The suite's meshes are the shipped ones (tests/data/ship_meshes.py says why and how to regenerate)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "tests" / "data" / "meshes"


@pytest.mark.parametrize("scene_file", ["mavig_tiny.toml", "mavig_default.toml"])
def test_the_scenes_meshes_are_shipped(scene_file):
    from mlsim.pipeline import stage_key
    from mlsim.scene import load_scene

    key = stage_key(load_scene(ROOT / "scenes" / scene_file), "mesh")
    assert (SHIPPED / key / "mesh.npz").is_file(), (
        f"the mesh of scenes/{scene_file} (key {key[:12]}) is not in tests/data/meshes: the mesh stage's "
        "version or the fields it reads changed; regenerate as tests/data/ship_meshes.py describes")


def test_the_session_loads_the_shipped_mesh(tiny_mesh):
    """The tiny mesh a test gets is byte for byte the shipped one (its content hash), not a fresh build."""
    _, _, mesh, report = tiny_mesh
    from mlsim.pipeline import stage_key

    key = stage_key(tiny_mesh[0], "mesh")
    shipped = json.loads((SHIPPED / key / "report.json").read_text())
    assert mesh.content_hash() == shipped["mesh_hash"] == report["mesh_hash"]
    assert report["volume_rel_error"] == shipped["volume_rel_error"]
