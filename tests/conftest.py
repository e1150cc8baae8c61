"""Shared fixtures: a private cache for the whole session, and meshes built once per session."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def pytest_configure(config):
    # Never touch the user's cache from tests; runs inside the session share this one.
    if "MLSIM_CACHE_DIR" not in os.environ or not os.environ.get("MLSIM_TEST_KEEP_CACHE"):
        import tempfile

        os.environ["MLSIM_CACHE_DIR"] = tempfile.mkdtemp(prefix="mlsim_test_cache_")
        config._mlsim_made_cache = os.environ["MLSIM_CACHE_DIR"]
    # fTetWild gives a different mesh on every build: the suite uses the shipped ones (tests/data/ship_meshes.py)
    import runpy

    runpy.run_path(str(ROOT / "tests" / "data" / "ship_meshes.py"))["seed_cache"](Path(os.environ["MLSIM_CACHE_DIR"]))


def pytest_unconfigure(config):
    # the session's private cache goes with the session (they piled up in /tmp: ~0.5 GB each)
    made = getattr(config, "_mlsim_made_cache", None)
    if made:
        import shutil

        shutil.rmtree(made, ignore_errors=True)
        os.environ.pop("MLSIM_CACHE_DIR", None)


@pytest.fixture(scope="session")
def cache():
    from mlsim.pipeline import Cache

    return Cache(os.environ["MLSIM_CACHE_DIR"])


def _mesh_of(scene_file: str, cache):
    from mlsim import pipeline
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / scene_file)
    result = pipeline.run(scene, out_dir=None, cache=cache, outputs=("mesh",), progress=False, log=lambda m: None)
    from fem.geometry import RodArray

    mesh, report = result.results["mesh"]
    return scene, RodArray.from_sensor(scene.sensor), mesh, report


@pytest.fixture(scope="session")
def tiny_mesh(cache):
    """(scene, geometry, mesh, report) of scenes/mavig_tiny.toml (2 x 2 rods, about 5 s)."""
    return _mesh_of("mavig_tiny.toml", cache)


@pytest.fixture(scope="session")
def default_mesh(cache):
    """(scene, geometry, mesh, report) of scenes/mavig_default.toml at default fidelity (about 30 s)."""
    return _mesh_of("mavig_default.toml", cache)
