"""mlsim.render.direct_raster and the deformed render tier: the projection through the flat
interfaces against Snell's law and Mitsuba's rays, the rasterised direct light against Mitsuba's
primary rays (at rest and with a rod bent), culling, thread-count invariance, the tier against path
tracing of the deformed sheet, and bad input."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from mlsim.render import render_frames  # noqa: E402
from mlsim.render import reprojection as rp  # noqa: E402
from mlsim.render.direct_raster import direct_raster, tangent_table  # noqa: E402
from mlsim.render.transport import trace_transport  # noqa: E402
from render_helpers import bent, blocks, small_sheet  # noqa: E402


def test_the_tangent_table_gives_the_air_ray_that_reaches_each_point():
    """Forward along the tabulated ray: (L - a) tan t0 + a tan t1 + z tan t2 = rho, with Snell's law
    at both faces, within 1e-4 mm over the table (points between its nodes); on the axis, the
    paraxial limit 1 / (L - a + a / n_a + z / n_c)."""
    L, a, na, nc = 43.0, 3.0, 1.49, 1.41
    q, dr2, dz = tangent_table(L, a, na, nc, 30.0, 25.0)
    rng = np.random.default_rng(1)
    rho, z = 30.0 * np.sqrt(rng.random(500)), 25.0 * rng.random(500)
    fr, fz = rho ** 2 / dr2, z / dz
    ir, iz = np.minimum(fr.astype(int), q.shape[0] - 2), np.minimum(fz.astype(int), q.shape[1] - 2)
    wr, wz = fr - ir, fz - iz
    qq = (1 - wr) * ((1 - wz) * q[ir, iz] + wz * q[ir, iz + 1]) + wr * ((1 - wz) * q[ir + 1, iz] + wz * q[ir + 1, iz + 1])
    t0 = np.arctan(qq * rho)
    s0 = np.sin(t0)
    t1, t2 = np.arcsin(s0 / na), np.arcsin(s0 / nc)
    reached = (L - a) * np.tan(t0) + a * np.tan(t1) + z * np.tan(t2)
    np.testing.assert_allclose(reached, rho, atol=1e-4)
    np.testing.assert_allclose(q[0], 1.0 / (L - a + a / na + np.linspace(0, 25.0, q.shape[1]) / nc), rtol=1e-12)


def test_the_projection_puts_mitsubas_hits_at_their_pixels():
    """Mitsuba's ray through each pixel centre, refracted by both faces, meets the sheet at a point
    that the projection sends back to that pixel centre (within 2e-3 px)."""
    _, _, _, sheet = small_sheet(32)
    raster = direct_raster(sheet, 1)
    samples = rp.primary_samples(sheet, 1)
    hit = samples.face >= 0
    corners = sheet.vertices_mm.astype(np.float64)[sheet.faces.astype(np.int64)[samples.face[hit]]]
    points_m = np.einsum("nk,nkd->nd", samples.bary[hit], corners) * 1e-3
    pix = samples.pixel[hit]
    centre = np.stack([pix % 32 + 0.5, pix // 32 + 0.5], axis=1)
    assert hit.sum() > 500
    np.testing.assert_allclose(raster.pixels_of(points_m), centre, atol=2e-3)


@pytest.mark.parametrize("per_side", [1, 2])
def test_the_rasterised_direct_light_is_mitsubas_primary_rays(per_side):
    """Same samples, two ways to find their first hits: rasterised against Mitsuba's ray casting,
    at rest and with rod 0 bent 2.5 mm (its tip face moves across the image): per rod within 0.2 %,
    per pixel within 3 % of the image's sum of |values| (the edge samples of the image-space
    barycentric weights)."""
    g, V, _, sheet = small_sheet(48)
    raster = direct_raster(sheet, per_side)
    rng = np.random.default_rng(0)
    # a third of the vertices dark, beside bright ones: the interpolation never goes below zero
    e = 1e15 * (0.5 + rng.random(len(V))) * np.where(g.rod_of(V) == 0, 1.0, 0.2) * (rng.random(len(V)) > 0.33)
    for moved in (V, bent(g, V, 2.5e-3)):
        sheet.set_vertices(moved)
        ref = rp.direct_image(rp.primary_samples(sheet, per_side), sheet.faces, e)
        got = raster.images(moved[None], e[None])[0]
        np.testing.assert_allclose(blocks(got), blocks(ref), rtol=2e-3)
        assert np.abs(got - ref).sum() < 0.03 * np.abs(ref).sum()
        assert got.min() >= 0.0
    sheet.set_vertices(V)


def test_faces_seen_from_behind_give_no_light_and_threads_do_not_change_the_image():
    """The faces that look down the lens axis (the tips and the base's top, seen from inside the
    core) give light; turned over, they are seen from outside the core and culled: a black image.
    The image is the same, bit for bit, on one thread and on all."""
    import numba

    g, V, _, sheet = small_sheet(32)
    raster = direct_raster(sheet, 2)
    e = np.full((1, len(V)), 1e15, dtype=np.float32)
    moved = bent(g, V, 1.5e-3)[None]
    full = raster.images(moved, e)
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        one = raster.images(moved, e)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one, full)
    assert full.sum() > 0
    tri = V[raster.faces]
    normal = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    down = normal[:, 2] < -0.99 * np.linalg.norm(normal, axis=1)  # into the core, towards the camera
    raster.faces = np.ascontiguousarray(raster.faces[down])
    assert raster.images(V[None], e).sum() > 0.5 * full.sum()
    raster.faces = np.ascontiguousarray(raster.faces[:, ::-1])
    assert raster.images(V[None], e).max() == 0.0


def test_the_rasters_images_are_those_of_the_kernel_before_issue_40_bit_for_bit():
    """DirectRaster.images (the sheet projected in the faces' vertex order, one pass, dark faces
    skipped where they cannot matter) against the path before it: pixels_of, numpy's float32
    depth and the banded kernel (tests/raster_reference.py) on the sheet's own numbering, bit for
    bit, on the sheet at rest and with a rod bent 1.5 mm, every vertex lit, a few, none, at 1 and
    2 samples per pixel side."""
    from raster_reference import rasterise_direct_banded

    g, V, _, sheet = small_sheet(32)
    rng = np.random.default_rng(6)
    for per_side in (1, 2):
        raster = direct_raster(sheet, per_side)
        at = np.stack([V, bent(g, V, 1.5e-3), bent(g, V, 1.5e-3, rod=1, axis=1), V])
        e = rng.uniform(1e14, 1e15, (4, len(V))).astype(np.float32)
        e[1] *= rng.random(len(V)) < 0.02  # a few lit vertices: the sparse path
        e[2] *= rng.random(len(V)) < 0.5
        e[3] = 0.0
        uv = raster.pixels_of(at)
        ref = rasterise_direct_banded(uv, np.ascontiguousarray(at[..., 2], dtype=np.float32), raster.faces, e, per_side,
                                      raster.orientation, raster.height_px, raster.width_px, raster.throughput, 8)
        new = raster.images(at, e)
        assert ref[1].max() > 0
        np.testing.assert_array_equal(new.view(np.uint32), ref.view(np.uint32))


def test_the_deformed_tier_is_the_direct_raster_plus_the_rest_bounces_and_tracks_path_tracing():
    """The tier's image is the rasterised direct light on the deformed sheet plus the rest shape's
    bounces (exactly). At rest it is the full transport within Monte Carlo error (2 % per rod).
    With rod 0 bent 2.5 mm (and brightest), against two 512-spp path renders of the bent sheet:
    per rod within 2 % (1.3-1.5 % measured), per 8 x 8 block within 3.5 % of the image norm. (On this small sheet the
    rest shape's transport is as close per rod, 1.2 %: the bounces, 19 % of the light, move the
    other way from the direct light; the demo's figures are in mlsim.render.reprojection.)"""
    g, V, F, sheet = small_sheet(48)
    rng = np.random.default_rng(2)
    e = (1e15 * (0.5 + rng.random(len(V))) * np.where(g.rod_of(V) == 0, 1.0, 0.2))[None].astype(np.float32)  # the bent rod brightest
    raster = direct_raster(sheet, 2)
    bounces = trace_transport(sheet, spp=128, seed=5, first_depth=rp.DIRECT_DEPTH, one_vertex=True)  # as the render stage traces it
    full = trace_transport(sheet, spp=128, seed=5)
    at_rest = render_frames(sheet, e, "deformed", transport=bounces, raster=raster).radiance
    np.testing.assert_allclose(blocks(at_rest), blocks(full.apply(e)), rtol=0.02)
    moved = bent(g, V, 2.5e-3)[None]
    got = render_frames(sheet, e, "deformed", transport=bounces, raster=raster, vertices_m=moved).radiance[0]
    np.testing.assert_array_equal(got, raster.images(moved, e)[0] + bounces.apply(e[0]))
    sheet.set_vertices(moved[0])
    sheet.set_radiance(e[0])
    path = np.mean([sheet.render(512, 70 + s) for s in range(2)], axis=0)
    sheet.set_vertices(V)
    np.testing.assert_allclose(blocks(got), blocks(path), rtol=0.02)
    assert np.linalg.norm(blocks(got, 8) - blocks(path, 8)) < 0.035 * np.linalg.norm(blocks(path, 8))


def test_one_vertex_per_hit_keeps_the_paths_and_the_mean_with_fewer_entries():
    """The bounces' matrix with each hit drawn to one vertex (trace_transport(one_vertex=True)):
    the same paths as the barycentric split, so every pixel's row sums to the same total (exactly,
    up to float32); per rod within 2 % for a random emission (the draw's noise); fewer than 0.6 x
    the entries; the same matrix for the same seed."""
    g, V, _, sheet = small_sheet(32)
    kw = dict(spp=32, seed=9, drop=0.0, first_depth=rp.DIRECT_DEPTH)
    spread = trace_transport(sheet, **kw).matrix
    one = trace_transport(sheet, one_vertex=True, **kw).matrix
    np.testing.assert_allclose(np.asarray(one.sum(axis=1)).ravel(), np.asarray(spread.sum(axis=1)).ravel(), rtol=1e-5,
                               atol=1e-6 * float(spread.sum(axis=1).max()))
    e = 1e15 * (0.5 + np.random.default_rng(3).random(len(V)))
    np.testing.assert_allclose(blocks((one @ e).reshape(32, 32)), blocks((spread @ e).reshape(32, 32)), rtol=0.02)
    assert one.nnz < 0.6 * spread.nnz
    again = trace_transport(sheet, one_vertex=True, **kw).matrix
    assert (again != one).nnz == 0


def test_bad_input_is_refused_with_the_fix():
    g, V, _, sheet = small_sheet(16)
    with pytest.raises(ValueError, match="per_side"):
        direct_raster(sheet, 0)
    raster = direct_raster(sheet, 1)
    e = np.ones((1, len(V)), np.float32)
    below = V.copy()
    below[:, 2] -= 3e-3  # the base top (2 mm) below the core's bottom face
    with pytest.raises(ValueError, match="core's bottom"):
        raster.images(below[None], e)
    with pytest.raises(ValueError, match=r"\(F, "):
        raster.images(V, e)
    full = trace_transport(sheet, spp=1, seed=0)
    with pytest.raises(ValueError, match="bounces only"):
        render_frames(sheet, e, "deformed", transport=full, raster=raster)
    with pytest.raises(ValueError, match="DirectRaster"):
        render_frames(sheet, e, "deformed", transport=trace_transport(sheet, spp=1, seed=0, first_depth=rp.DIRECT_DEPTH))


def test_frames_read_where_they_lie_are_the_gathered_frames_images():
    """DirectRaster.images(V, e, frames=k) (the render's lit frames, issue 40) is images(V[k], e)
    bit for bit, in any order and with repeats; frames outside V are refused."""
    g, V, _, sheet = small_sheet(32)
    raster = direct_raster(sheet, 2)
    moved = np.stack([bent(g, V, d) for d in (0.0, 0.5e-3, 1.0e-3, 1.5e-3)])
    rng = np.random.default_rng(5)
    frames = np.array([3, 1, 1, 0])
    e = (rng.uniform(0.0, 1e15, (len(frames), len(V)))).astype(np.float32)
    np.testing.assert_array_equal(raster.images(moved, e, frames=frames), raster.images(moved[frames], e))
    with pytest.raises(ValueError, match="frames"):
        raster.images(moved, e, frames=np.array([0, 1, 2, 4]))


def test_the_raster_read_back_from_its_file_is_the_same_raster(tmp_path):
    """DirectRaster.save / load (the deformed tier caches it for the sensor and view): every field
    and the images it makes, bit for bit."""
    import dataclasses

    from mlsim.render.direct_raster import DirectRaster

    g, V, _, sheet = small_sheet(32)
    raster = direct_raster(sheet, 2)
    raster.save(tmp_path / "raster.npz")
    back = DirectRaster.load(tmp_path / "raster.npz")
    for name in (f.name for f in dataclasses.fields(DirectRaster)):
        a, b = getattr(raster, name), getattr(back, name)
        assert type(a) is type(b) or isinstance(a, np.ndarray), name
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b), err_msg=name)
    at = np.stack([V, bent(g, V, 1.5e-3)])
    e = np.random.default_rng(3).uniform(1e14, 1e15, (2, len(V))).astype(np.float32)
    np.testing.assert_array_equal(back.images(at, e).view(np.uint32), raster.images(at, e).view(np.uint32))


_RERENDER = """
import json, sys
import numpy as np
from mlsim import pipeline
from mlsim.scene import load_scene
scene = load_scene(sys.argv[1]).with_values(json.loads(sys.argv[3]))
res = pipeline.run(scene, cache=pipeline.Cache(sys.argv[2]), outputs=("camera",), progress=False, log=lambda m: None)
print(json.dumps({"mitsuba": "mitsuba" in sys.modules, "drjit": "drjit" in sys.modules, "scipy.integrate": "scipy.integrate" in sys.modules,
                  "actions": {s.stage.name: s.action for s in res.steps},
                  "radiance": np.asarray(res.results["render"].radiance, dtype=np.float32).tobytes().hex()}))
"""


def test_the_deformed_tier_from_a_warm_cache_never_imports_mitsuba(tmp_path, tiny_mesh, cache):
    """A run of the deformed tier whose sensor's matrix and rasteriser are cached (a dataset's
    episode, a new load on a known sensor) reads only the sheet's geometry: Mitsuba is not imported
    (0.6 s of each dataset worker's CPU), nor is scipy.integrate without an ambient lamp, and the
    image is the one the run that made the cache rendered, scaled by the new brightness (to 2e-6)."""
    import json
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from mlsim import pipeline

    scene = tiny_mesh[0]
    # render too: the session's cache may hold the camera already (make test's kernel warm-up runs this scene)
    first = pipeline.run(scene, cache=cache, outputs=("render", "camera"), progress=False, log=lambda m: None)
    assert scene.fidelity.render.tier == "deformed" and scene.ambient.lamp == "none"
    root = Path(__file__).resolve().parents[1]
    # the emission made anew (a new brightness) so that the render runs, on the cached solve and sensor
    values = {"emission.brightness_photons_per_m2": 3.1e19}
    changed = scene.with_values(values)
    for name in ("emission", "render", "camera"):  # a kept test cache (MLSIM_TEST_KEEP_CACHE) may hold these from a run before
        shutil.rmtree(cache.path(name, pipeline.stage_key(changed, name)), ignore_errors=True)
    proc = subprocess.run([sys.executable, "-c", _RERENDER, str(root / "scenes" / "mavig_tiny.toml"), str(cache.root), json.dumps(values)],
                          capture_output=True, text=True, cwd=root, timeout=600)
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    assert not out["mitsuba"] and not out["drjit"] and not out["scipy.integrate"], out
    assert out["actions"] == {"geometry": "run", "mesh": "load", "solve": "load", "emission": "run", "render": "run", "camera": "run"}
    # the same sheet and parts: the brightness scales the radiance, so the image is the first run's times 3.1 / 2.7
    again = np.frombuffer(bytes.fromhex(out["radiance"]), np.float32).reshape(first.results["render"].radiance.shape)
    np.testing.assert_allclose(again, first.results["render"].radiance * (3.1e19 / scene.emission.brightness_photons_per_m2), rtol=2e-6, atol=0)
