"""mlsim.render.optics: the rod disks' pixel masks (the camera's per-rod signal and the DLLM's taxel
areas) and the ML light's channel factors, against their definitions."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from mlsim import spectra
from mlsim.render.optics import channel_factors_of, disk_masks, ml_channel_factors
from mlsim.scene import load_scene


def _disks_by_definition(h, w, centres, radius):
    rows, cols = np.mgrid[0:h, 0:w]
    c = np.asarray(centres, dtype=float)
    return (cols[None] - c[:, 0, None, None]) ** 2 + (rows[None] - c[:, 1, None, None]) ** 2 <= radius**2


def test_disk_masks_are_the_pixels_within_the_radius_even_at_the_edges():
    """Each disk computed on its bounding box is the whole-frame definition, pixel for pixel: centres
    on pixel centres and between them, radii that pass exactly through pixel centres (3, 5: a
    Pythagorean pair), disks cut by every edge of the frame and one wholly outside it. A disk of
    integer radius r about a pixel centre holds the lattice points of the circle, 29 for r = 3."""
    rng = np.random.default_rng(4)
    h, w = 40, 50
    centres = np.concatenate([rng.uniform(-5, 55, (30, 2)), [[10.0, 10.0], [0.0, 20.0], [49.5, 39.5], [-20.0, 5.0], [25.0, 0.3]]])
    for radius in (0.4, 3.0, 5.0, 7.3):
        got = disk_masks(h, w, centres, radius)
        assert got.shape == (len(centres), h, w) and got.dtype == bool
        np.testing.assert_array_equal(got, _disks_by_definition(h, w, centres, radius))
    assert disk_masks(h, w, [[10.0, 10.0]], 3.0).sum() == 29  # Gauss circle: N(3) = 29
    assert not disk_masks(h, w, [[-20.0, 5.0]], 5.0).any()
    assert not disk_masks(h, w, [[np.nan, 5.0]], 5.0).any()  # no pixel is within a NaN distance


def test_the_ml_channel_factors_are_made_once_per_scene_and_handed_out_as_copies():
    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml")
    k = ml_channel_factors(scene)
    np.testing.assert_array_equal(k, channel_factors_of(scene, spectra.zns_cu_emission_sd()))
    k[:] = 0.0  # a caller's copy: the next call is not changed
    np.testing.assert_array_equal(ml_channel_factors(scene), channel_factors_of(scene, spectra.zns_cu_emission_sd()))
    thicker = scene.with_values({"optics.acrylic_thickness_mm": 2 * scene.optics.acrylic_thickness_mm})
    assert np.all(ml_channel_factors(thicker) < ml_channel_factors(scene))  # more acrylic absorbs more, in every channel


def test_the_camera_stage_takes_the_channel_factors_from_the_cache(tmp_path):
    """mlsim.render.stage.ml_channel_factors_cached (issue 40: a dataset worker no longer imports
    colour-science for three numbers): the bits of ml_channel_factors, stored once per sensor and
    read back from disk in a fresh process without importing colour; a copy per call; another
    sensor's optics get their own entry."""
    import subprocess
    import sys

    from mlsim.pipeline import Cache
    from mlsim.render.stage import ML_CHANNEL_FACTORS, ml_channel_factors_cached
    from mlsim.stage import RunContext

    path = Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml"
    scene = load_scene(path)
    ctx = RunContext(scene, Cache(tmp_path), None, False, lambda _m: None)
    k = ml_channel_factors_cached(scene, ctx)
    assert k.tobytes() == ml_channel_factors(scene).tobytes()
    k[:] = 0.0
    assert ml_channel_factors_cached(scene, ctx).tobytes() == ml_channel_factors(scene).tobytes()
    assert len(list((tmp_path / ML_CHANNEL_FACTORS.name).iterdir())) == 1
    thicker = scene.with_values({"optics.acrylic_thickness_mm": 2 * scene.optics.acrylic_thickness_mm})
    assert ml_channel_factors_cached(thicker, ctx).tobytes() == ml_channel_factors(thicker).tobytes()
    assert len(list((tmp_path / ML_CHANNEL_FACTORS.name).iterdir())) == 2
    code = ("import sys; from mlsim.scene import load_scene; from mlsim.pipeline import Cache; from mlsim.stage import RunContext; "
            "from mlsim.render.stage import ml_channel_factors_cached; "
            f"s = load_scene({str(path)!r}); k = ml_channel_factors_cached(s, RunContext(s, Cache({str(tmp_path)!r}), None, False, print)); "
            "print(k.tobytes().hex(), 'colour' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split()[-2:] == [ml_channel_factors(scene).tobytes().hex(), "False"]
