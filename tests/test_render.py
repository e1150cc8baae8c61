"""The render stage: radiometry against the closed form, linearity (a statistical test), transport
against path, the dark-frame rule, the emitting sheet's refinement and the camera-stage files."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

pytest.importorskip("mitsuba")

from fem.geometry import RodArray, emitting_surface  # noqa: E402
from mlsim.emission.patches import refine_to_edge_length  # noqa: E402
from mlsim.render import View, render_frames  # noqa: E402
from mlsim.render.sensor_scene import SensorScene, radiance_of  # noqa: E402
from mlsim.render.transport import trace_transport  # noqa: E402

N_CORE, N_ACRYLIC = 1.41, 1.49


def _view(px: int, fov_scale: float = 1.0) -> View:
    # the default camera's field of view (about 47 deg) at a smaller resolution
    return View(width_px=px, height_px=px, lens_below_base_m=0.043, image_distance_m=0.0023068 * fov_scale, pixel_pitch_m=5.8e-6 * 350 / px)


def _flat_sheet(half_m=0.015, z_m=0.001, n=8):
    """A flat square sheet at height z in the core, normals up (out of the core), n x n cells."""
    x = np.linspace(-half_m, half_m, n + 1)
    xx, yy = np.meshgrid(x, x)
    V = np.column_stack([xx.ravel(), yy.ravel(), np.full(xx.size, z_m)])
    idx = np.arange(V.shape[0]).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel(), idx[1:, :-1].ravel()
    F = np.vstack([np.column_stack([a, b, c]), np.column_stack([a, c, d])])
    return V, F


def _fresnel_normal(n1, n2):
    return ((n1 - n2) / (n1 + n2)) ** 2


# ------------------------------------------------------------------------------------ radiometry
@pytest.mark.parametrize("tier", ["path", "transport"])
def test_lambertian_patch_on_axis_matches_the_closed_form(tier):
    """A Lambertian sheet of radiance L0 in the core, seen on the axis through the core/acrylic and
    acrylic/air faces: L = L0 (1 - R_ca)(1 - R_aa) / n_core^2 (radiance over n^2 is invariant; no
    inter-reflection: reflectance 0). Then the camera equation gives the electrons per pixel."""
    V, F = _flat_sheet()
    sheet = SensorScene(V, F, _view(32), core_ior=N_CORE, acrylic_ior=N_ACRYLIC, acrylic_thickness_m=3e-3, base_half_size_m=0.02,
                        reflectance=0.0)
    L0 = 2.5e15
    e = np.full((1, len(V)), L0)
    if tier == "path":
        img = render_frames(sheet, e, "path", spp=512, seed=3).radiance[0]
    else:
        img = render_frames(sheet, e, "transport", transport=trace_transport(sheet, spp=512, seed=3, drop=0.0)).radiance[0]
    centre = float(img[14:18, 14:18].mean())
    expected = L0 * (1 - _fresnel_normal(N_CORE, N_ACRYLIC)) * (1 - _fresnel_normal(N_ACRYLIC, 1.0)) / N_CORE**2
    assert centre == pytest.approx(expected, rel=0.02)
    # photons per pixel through the lens (the camera equation of mlsim.camera, by hand)
    from mlsim.camera import CameraParams

    p = CameraParams()
    photons = centre * p.pixel_area_m2 * p.exposure_s * p.lens_transmittance * math.pi / (4 * p.f_number**2 * (1 + p.resolved_magnification) ** 2)
    assert p.electrons_per_radiance_m2_sr_s * centre == pytest.approx(photons, rel=1e-12)
    assert photons == pytest.approx(p.electrons_per_radiance_m2_sr_s * expected, rel=0.02)


def test_radiance_of_gives_the_patch_flux():
    """Lambertian: the flux of radiance L over area A is pi L A; a linear (per-vertex) radiance with a
    third of the faces' area per vertex integrates to the patch photon rates exactly."""
    V, F = _flat_sheet(n=4)
    area = np.bincount(F.ravel(), weights=np.repeat(0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1) / 3, 3))
    phi = np.random.default_rng(0).random(len(V)) * 1e12
    L = radiance_of(phi, area)
    # integral of the linear interpolant over each face = area_f * mean of its 3 vertex values
    face_area = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    flux = np.pi * (face_area * L[F].mean(axis=1)).sum()
    assert flux == pytest.approx(phi.sum(), rel=1e-12)


# ------------------------------------------------------------------------------------- linearity
def _rod_sheet():
    g = RodArray(rows=2, cols=2, pitch_x_m=7.2e-3, pitch_y_m=7.2e-3, rod_radius_m=2.5e-3, rod_height_m=9e-3, base_thickness_m=2e-3,
                 absorber_m=0.3e-3, ml_m=0.5e-3)
    s = emitting_surface(g, 24, 1.5e-3)
    return g, np.asarray(s.vertices), np.asarray(s.faces)


def _blocks(img, n=4):
    h = img.shape[-1] // n
    return img[..., : n * h, : n * h].reshape(img.shape[:-2] + (n, h, n, h)).sum(axis=(-1, -3)).reshape(img.shape[:-2] + (n * n,))


def _linearity_pvalue(sheet, e1, e2, a, b, seeds, bias=1.0):
    """Fisher-combined p-value of per-block one-sample t-tests of R(a e1 + b e2) - a R(e1) - b R(e2),
    each render with its own seed (independent Monte Carlo)."""
    d = []
    for k in seeds:
        both = render_frames(sheet, (a * bias * e1 + b * e2)[None], "path", spp=8, seed=3 * k).radiance[0]
        one = render_frames(sheet, e1[None], "path", spp=8, seed=3 * k + 1).radiance[0]
        two = render_frames(sheet, e2[None], "path", spp=8, seed=3 * k + 2).radiance[0]
        d.append(_blocks(both - a * one - b * two, 6))
    d = np.array(d, dtype=np.float64)  # (K, blocks)
    d = d[:, d.std(axis=0) > 0]  # blocks that see no sheet are exactly zero
    assert d.shape[1] >= 8
    p = stats.ttest_1samp(d, 0.0, axis=0).pvalue
    return stats.combine_pvalues(p, method="fisher").pvalue


def test_render_is_linear_in_emission_within_monte_carlo_error():
    g, V, F = _rod_sheet()
    sheet = SensorScene(V, F, _view(48, fov_scale=2.4), base_half_size_m=7.2e-3, reflectance=0.5)
    rng = np.random.default_rng(7)
    e1 = rng.random(len(V)) * 1e15
    e2 = np.where(g.rod_of(V) == 0, 3e15, 0.0) + rng.random(len(V)) * 2e14
    seeds = range(1, 9)
    assert _linearity_pvalue(sheet, e1, e2, 0.7, 2.3, seeds) > 1e-3
    # the test has power: a 5 % gain on one term is found
    assert _linearity_pvalue(sheet, e1, e2, 0.7, 2.3, seeds, bias=1.05) < 1e-3


def test_same_seed_renders_are_linear_to_float_precision():
    """With the same seed the paths are the same (emitters are sampled by area, not by radiance), so
    linearity holds sample by sample."""
    g, V, F = _rod_sheet()
    sheet = SensorScene(V, F, _view(32), base_half_size_m=7.2e-3)
    rng = np.random.default_rng(1)
    e1, e2 = rng.random(len(V)) * 1e15, rng.random(len(V)) * 1e15
    r = render_frames(sheet, np.stack([0.3 * e1 + 1.7 * e2, e1, e2]), "path", spp=4, seed=5).radiance
    # render_frames seeds frames differently; render them with one seed instead
    imgs = []
    for e in (0.3 * e1 + 1.7 * e2, e1, e2):
        sheet.set_radiance(e)
        imgs.append(sheet.render(4, 11))
    assert np.allclose(imgs[0], 0.3 * imgs[1] + 1.7 * imgs[2], rtol=1e-4, atol=1e-6 * imgs[0].max())
    assert r.shape == (3, 32, 32)


def test_moved_sheet_renders_as_a_sheet_built_there():
    """set_vertices must rebuild the scene's BVH: a sheet shifted by 20 um (far below a pixel's
    footprint) renders per rod as the unshifted one and as a scene built at the shifted place, within
    Monte Carlo error. (Updated through the mesh's parameters alone, the BVH kept the old boxes and
    rods lost up to half their light to rays that missed the moved triangles.)"""
    g, V, F = _rod_sheet()
    view = _view(48, fov_scale=2.4)
    shift = np.array([2e-5, 1e-5, 0.0])
    moved = SensorScene(V, F, view, base_half_size_m=7.2e-3)
    moved.set_vertices(V + shift)
    built = SensorScene(V + shift, F, view, base_half_size_m=7.2e-3)
    e = np.full(len(V), 1e15)
    per_rod = []
    for sheet in (moved, built):
        sheet.set_radiance(e)
        imgs = np.array([sheet.render(16, s) for s in range(6)], dtype=np.float64)
        per_rod.append(_blocks(imgs, 2))  # (6 seeds, 4 quadrants)
    (a, b) = per_rod
    se = np.sqrt(a.var(axis=0, ddof=1) / len(a) + b.var(axis=0, ddof=1) / len(b))
    z = (a.mean(axis=0) - b.mean(axis=0)) / se
    assert np.all(np.abs(z) < 4.0), z
    assert np.allclose(a.mean(axis=0), b.mean(axis=0), rtol=0.02)


# ------------------------------------------------------------------------- transport against path
def test_transport_matches_path_per_rod_within_3_percent():
    g, V, F = _rod_sheet()
    view = _view(64, fov_scale=2.4)
    sheet = SensorScene(V, F, view, base_half_size_m=7.2e-3, reflectance=0.5)
    T = trace_transport(sheet, spp=64, seed=1)
    assert T.dropped_fraction < 1e-3
    rng = np.random.default_rng(3)
    rod = g.rod_of(V)
    E = np.stack([np.where(rod == r, 1e15, 0.0) * (0.5 + rng.random(len(V))) for r in range(4)] + [np.full(len(V), 1e15)])
    fast = render_frames(sheet, E, "transport", transport=T).radiance
    ref = render_frames(sheet, E, "path", spp=256, seed=2).radiance
    # per rod: the image's quadrant that holds the rod (2 x 2 rods fill the view's centre)
    q = _blocks(fast, 2)
    qr = _blocks(ref, 2)
    for f in range(4):
        lit = np.argmax(qr[f])
        assert q[f, lit] == pytest.approx(qr[f, lit], rel=0.03)
    assert fast[4].sum() == pytest.approx(ref[4].sum(), rel=0.01)


def test_transport_matrix_round_trip(tmp_path):
    V, F = _flat_sheet(n=2)
    sheet = SensorScene(V, F, _view(16), base_half_size_m=0.02)
    T = trace_transport(sheet, spp=4, seed=0)
    T.save(tmp_path / "t.npz")
    T2 = type(T).load(tmp_path / "t.npz")
    e = np.arange(len(V), dtype=float)
    assert np.array_equal(T.apply(e), T2.apply(e))
    # same seed, same matrix
    assert np.array_equal(trace_transport(sheet, spp=4, seed=0).matrix.toarray(), T.matrix.toarray())


# ------------------------------------------------------------------------------- the dark frames
def test_dark_and_repeated_frames_never_call_the_renderer(monkeypatch):
    V, F = _flat_sheet(n=2)
    sheet = SensorScene(V, F, _view(16), base_half_size_m=0.02)
    calls = []
    real = SensorScene.render
    monkeypatch.setattr(SensorScene, "render", lambda self, spp, seed: calls.append(seed) or real(self, spp, seed))
    e = np.zeros((5, len(V)))
    e[1] = 1e15
    e[2] = 1e15  # a repeat of frame 1
    e[4] = 2e15
    res = render_frames(sheet, e, "path", spp=4, seed=0)
    assert len(calls) == 2
    assert res.rendered.tolist() == [False, True, False, False, True]
    assert np.all(res.radiance[0] == 0) and np.all(res.radiance[3] == 0)
    assert np.array_equal(res.radiance[2], res.radiance[1])
    # the transport tier multiplies only the lit, changed frames
    T = trace_transport(sheet, spp=2, seed=0)
    applied = []
    real_apply = type(T).apply
    monkeypatch.setattr(type(T), "apply", lambda self, r: applied.append(np.shape(r)) or real_apply(self, r))
    res = render_frames(sheet, e, "transport", transport=T)
    assert applied == [(2, len(V))]
    assert res.rendered.tolist() == [False, True, False, False, True]


def test_transport_hands_frames_that_moved_too_far_to_the_path_tracer(monkeypatch):
    """The matrix is of the rest shape: a frame whose sheet moved beyond the limit is path-traced on
    its deformed sheet (exactly the path tier's frame); the others come from the matrix."""
    V, F = _flat_sheet(n=2)
    sheet = SensorScene(V, F, _view(16), base_half_size_m=0.02)
    T = trace_transport(sheet, spp=64, seed=0)
    e = np.full((3, len(V)), 1e15)
    e[1] *= 2.0
    e[2] *= 3.0
    moved = np.stack([V, V + [0, 0, 2e-4], V + [0, 0, 2e-3]])  # 0, 0.2 and 2 mm up
    calls = []
    real = SensorScene.render
    monkeypatch.setattr(SensorScene, "render", lambda self, spp, seed: calls.append(self.vertices_mm[0, 2]) or real(self, spp, seed))
    res = render_frames(sheet, e, "transport", transport=T, vertices_m=moved, path_above_m=1e-3, spp=8, seed=1)
    assert res.info["path_frames"] == [2] and len(calls) == 1
    assert calls[0] == pytest.approx(1e3 * (V[0, 2] + 2e-3))  # rendered on the moved sheet
    assert np.array_equal(res.radiance[:2], T.apply(e[:2]))
    # without the limit, every frame from the matrix
    pure = render_frames(sheet, e, "transport", transport=T, vertices_m=moved)
    assert pure.info["path_frames"] == [] and len(calls) == 1
    # the handed-over frame is the path tier's frame, sample for sample
    path = render_frames(sheet, e, "path", vertices_m=moved, spp=8, seed=1)
    assert np.array_equal(res.radiance[2], path.radiance[2])


def test_bad_input_is_refused_with_the_fix():
    V, F = _flat_sheet(n=2)
    sheet = SensorScene(V, F, _view(16), base_half_size_m=0.02)
    with pytest.raises(ValueError, match="frames"):
        render_frames(sheet, np.ones(len(V)), "path")
    with pytest.raises(ValueError, match="finite"):
        render_frames(sheet, np.full((1, len(V)), np.nan), "path")
    with pytest.raises(ValueError, match="choose one of"):
        render_frames(sheet, np.ones((1, len(V))), "raster")
    with pytest.raises(ValueError, match="TransportMatrix"):
        render_frames(sheet, np.ones((1, len(V))), "transport")


# ---------------------------------------------------------------------------- the emitting sheet
def test_refinement_is_conforming_and_keeps_the_surface():
    g, V, F = _rod_sheet()
    V2, F2 = refine_to_edge_length(V, F, 0.4e-3)
    import trimesh

    a, b = trimesh.Trimesh(V, F, process=False), trimesh.Trimesh(V2, F2, process=False)
    assert b.edges_unique_length.max() <= 0.4e-3
    assert b.area == pytest.approx(a.area, rel=1e-12)
    assert b.is_winding_consistent
    assert b.euler_number == a.euler_number  # no crack, no T-junction: the topology is the same
    # the boundary (the sheet's open edges on the base's sides) keeps its length
    def boundary_length(m):
        e = trimesh.grouping.group_rows(m.edges_sorted, require_count=1)
        return np.linalg.norm(np.diff(m.vertices[m.edges_sorted[e]], axis=1), axis=2).sum()

    assert boundary_length(b) == pytest.approx(boundary_length(a), rel=1e-12)


# ------------------------------------------------------------------------- the stage, end to end
def test_pipeline_writes_the_video_the_frames_and_the_table(tmp_path, cache):
    """The tiny scene through render and camera: an MP4 OpenCV reads back frame for frame, one PNG
    per frame, the per-frame table; dark frames are sensor noise at the black level; the same scene
    and seed give the same bytes."""
    import csv

    import cv2

    from mlsim import pipeline
    from mlsim.scene import load_scene

    from pathlib import Path

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml", {"outputs": ["camera"], "camera.width_px": 96, "camera.height_px": 96,
                                                              "fidelity.render.transport_spp": 8})
    res = pipeline.run(scene, out_dir=tmp_path, cache=cache, progress=False, log=lambda m: None)
    cam = res.results["camera"]
    F = len(cam.frames)
    cap = cv2.VideoCapture(str(tmp_path / "camera.mp4"))
    n, size = 0, None
    while True:
        ok, img = cap.read()
        if not ok:
            break
        n, size = n + 1, img.shape
    assert (n, size) == (F, (96, 96, 3))
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == F
    png = cv2.imread(str(tmp_path / "frames" / "frame_0000.png"))[..., ::-1]
    assert np.array_equal(png, cam.frames[0])
    rows = list(csv.DictReader(open(tmp_path / "camera_frames.csv")))
    assert len(rows) == F and "rod3_photons" in rows[0]
    rendered = np.array([int(r["rendered"]) for r in rows], bool)
    assert rendered.any() and (~rendered).any()
    # dark frames: black level 50 DN at 10 bits = 12.5 at 8 bits, floor -> 12, plus read noise
    dark = cam.frames[~rendered].astype(float)
    assert abs(dark.mean() - 12.0) < 1.0
    assert cam.frames[rendered].astype(float).mean() > dark.mean()
    # emitted photons and camera signal rise and fall together
    assert np.corrcoef(cam.rod_photons.sum(axis=1), cam.rod_signal_e.sum(axis=1))[0, 1] > 0.9
    # fTetWild gives a different mesh on each build (see the notes), so the rerun starts from this
    # mesh and recomputes everything after it
    fresh = pipeline.Cache(tmp_path / "c2")
    mesh_key = pipeline.stage_key(scene, "mesh")
    fresh.store(pipeline.STAGES["mesh"], mesh_key, cache.fetch(pipeline.STAGES["mesh"], mesh_key))
    again = pipeline.run(scene, out_dir=None, cache=fresh, progress=False, log=lambda m: None)
    assert [s.action for s in again.steps if s.stage.name != "geometry"] == ["load", "run", "run", "run", "run"]
    assert np.array_equal(again.results["camera"].frames, cam.frames)


def test_brightness_calibration_hits_its_target():
    """The green level above black is linear in B: scaling the radiance by the matched B ratio lands
    on the target; saturated or black levels are refused with the fix."""
    from mlsim.render.calibration import brightness_to_match, green_level_dn8
    from mlsim.scene import Scene

    scene = Scene()
    rad = np.random.default_rng(0).random((40, 40)) * 3e13
    level = green_level_dn8(scene, rad)
    assert 12.5 < level < 255
    b = brightness_to_match(1e19, level, 150.0, 12.5)
    assert green_level_dn8(scene, rad * b / 1e19) == pytest.approx(150.0, rel=1e-9)
    with pytest.raises(ValueError, match="saturated"):
        brightness_to_match(1e19, 255.0, 150.0, 12.5)
    with pytest.raises(ValueError, match="glows"):
        brightness_to_match(1e19, 12.5, 150.0, 12.5)
