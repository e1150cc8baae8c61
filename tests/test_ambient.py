"""Ambient light and the calibration frame: the point source's radiometry (power conservation,
inverse square, cosine), the lamp's level over an exposure (flicker, switching) against quadrature,
shading, and the leak through the pipeline (scaling with power and distance, the absorber's cut,
step changes); the calibration frame's 25 Hough circles."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import integrate

from mlsim.render import ambient

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------- the point source
def test_point_source_delivers_its_power_through_a_closed_sphere():
    """Conservation: a sphere around the lamp receives all of P (the mesh's quadrature converges)."""
    import trimesh

    lamp = np.array([0.1, -0.2, 1.5])
    errors = []
    for level in (2, 3, 4):
        s = trimesh.creation.icosphere(subdivisions=level, radius=0.3)
        area = np.bincount(s.faces.ravel(), weights=np.repeat(s.area_faces / 3, 3))
        e = ambient.point_source_irradiance_w_m2(s.vertices + lamp, -s.vertex_normals, lamp, 12.0)
        assert e.min() == 0.0 or np.all(e > 0)
        errors.append(abs((e * area).sum() / 12.0 - 1.0))  # inward normals face the lamp
    # the faceted sphere's area converges at second order
    assert errors[-1] < 2e-3 and errors[0] / errors[-1] > 10.0


def test_point_source_follows_the_inverse_square_and_cosine_laws():
    p = np.zeros((4, 3))
    n = np.array([[0, 0, 1.0], [0, math.sin(math.pi / 3), math.cos(math.pi / 3)], [0, 0, -1.0], [1.0, 0, 0]])
    e1 = ambient.point_source_irradiance_w_m2(p, n, [0, 0, 1.0], 4 * math.pi)
    e2 = ambient.point_source_irradiance_w_m2(p, n, [0, 0, 2.0], 4 * math.pi)
    assert e1 == pytest.approx([1.0, 0.5, 0.0, 0.0], abs=1e-12)
    assert e2 == pytest.approx(e1 / 4.0, abs=1e-12)
    with pytest.raises(ValueError, match="height_m"):
        ambient.point_source_irradiance_w_m2(p[:1], n[:1], [0, 0, 0], 1.0)


def test_radiant_power_uses_the_spectrum_efficacy():
    import colour

    from mlsim import spectra

    k = float(colour.luminous_efficacy(spectra.lamp_sd("white_led")))
    assert ambient.radiant_power_w("white_led", 40.0) == pytest.approx(40.0 * 100.0 / k, rel=1e-12)
    assert ambient.radiant_power_w("daylight", 50.0, 80.0) == pytest.approx(2 * ambient.radiant_power_w("daylight", 25.0, 80.0))
    with pytest.raises(ValueError, match="efficacy"):
        ambient.radiant_power_w("daylight", 50.0, 400.0)
    with pytest.raises(ValueError, match="lamp"):
        ambient.radiant_power_w("candle", 50.0)


def test_the_upper_plate_shades_the_lower_one():
    from mlsim.render import View
    from mlsim.render.sensor_scene import SensorScene

    x = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], float) * 2e-3
    lower = np.column_stack([x * 2.0, np.full(4, 1e-3)])
    upper = np.column_stack([x, np.full(4, 4e-3)])
    V = np.vstack([lower, upper])
    F = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]])
    sheet = SensorScene(V, F, View(8, 8, 0.043, 0.0023, 2e-4), base_half_size_m=8e-3)
    pts = np.array([[0, 0, 1e-3], [3.5e-3, 3.5e-3, 1e-3], [0, 0, 4e-3]])
    vis = ambient.lamp_visibility(sheet, pts, np.tile([0, 0, 1.0], (3, 1)), [0, 0, 1.5])
    assert vis.tolist() == [0.0, 1.0, 1.0]


# --------------------------------------------------------------------------- the lamp's level
@pytest.mark.parametrize("hz, depth, on, off", [(0.0, 0.0, None, None), (100.0, 0.3, None, None), (120.0, 0.8, 0.05, None),
                                                (100.0, 1.0, 0.02, 0.21)])
def test_lamp_level_is_the_mean_power_over_each_exposure(hz, depth, on, off):
    rng = np.random.default_rng(4)
    start = np.sort(rng.uniform(0.0, 0.3, 12))
    w = np.column_stack([start, start + rng.uniform(1e-3, 0.033, 12)])
    level = ambient.lamp_level(w, hz, depth, on, off)

    def p(t):
        lit = (on is None or t >= on) and (off is None or t < off)
        return (1.0 + depth * math.cos(2 * math.pi * hz * t)) if lit else 0.0

    brk = [b for b in (on, off) if b is not None]
    ref = [integrate.quad(p, a, b, points=[x for x in brk if a < x < b] or None, limit=200)[0] / (b - a) for a, b in w]
    assert level == pytest.approx(ref, abs=1e-9)


def test_flicker_averages_out_over_whole_periods():
    w = np.array([[0.0, 0.01], [0.013, 0.033], [0.1, 0.13]])  # 1, 2 and 3 periods of 100 Hz
    assert ambient.lamp_level(w, 100.0, 0.7) == pytest.approx([1.0, 1.0, 1.0], abs=1e-12)
    with pytest.raises(ValueError, match="depth"):
        ambient.lamp_level(w, 100.0, 1.5)


# ----------------------------------------------------------------------- through the pipeline
def _tiny(**values):
    from mlsim.scene import load_scene

    base = {"outputs": ["render", "camera"], "camera.width_px": 96, "camera.height_px": 96, "fidelity.render.transport_spp": 8,
            "camera.noise": False}
    return load_scene(ROOT / "scenes" / "mavig_tiny.toml", {**base, **values})


def _camera(scene, cache):
    from mlsim import pipeline

    res = pipeline.run(scene, out_dir=None, cache=cache, progress=False, log=lambda m: None)
    return res.results["camera"], res.results["render"]


def test_leak_scales_with_power_and_inverse_square_distance(cache):
    lamp = {"ambient.lamp": "daylight", "ambient.occlusion": False}
    cam1, r1 = _camera(_tiny(**lamp), cache)
    cam2, _ = _camera(_tiny(**lamp, **{"ambient.power_w": 25.0}), cache)
    cam3, _ = _camera(_tiny(**lamp, **{"ambient.height_m": 3.0}), cache)
    a1, a2, a3 = (c.rod_ambient_e[0] for c in (cam1, cam2, cam3))
    assert a1.min() > 0
    assert a2 == pytest.approx(a1 / 2.0, rel=1e-5)
    # r^2 grows by (3 + z)^2 / (1.5 + z)^2 for a surface z below the lamp's reference (the tips)
    assert a3 == pytest.approx(a1 / 4.0, rel=0.01)
    # the ML signal is untouched by the lamp; the lamp shows in the 8-bit frames of dark exposures
    cam0, _ = _camera(_tiny(), cache)
    assert np.array_equal(cam0.rod_signal_e, cam1.rod_signal_e)
    assert r1.info["ambient"]["radiant_power_w"] == pytest.approx(ambient.radiant_power_w("daylight", 50.0))


def test_absorber_blocks_the_lamp_by_its_spectral_transmittance(cache):
    from mlsim import spectra
    from mlsim.render.optics import channel_factors_of

    lamp = {"ambient.lamp": "daylight", "ambient.occlusion": False}
    with_abs, _ = _camera(_tiny(**lamp), cache)
    without, _ = _camera(_tiny(**lamp, **{"optics.absorber": "none"}), cache)
    scene = _tiny()
    wl = spectra.wavelengths_nm()
    t = np.asarray(spectra.absorber_transmittance_sd("black_silicone_pigment", 0.3).values)
    # expected ratio: the lamp's photons after the absorber, weighted by the camera's response
    lamp_n = np.asarray(spectra.photon_sd(spectra.lamp_sd("daylight")).values)
    k_with = channel_factors_of(scene, spectra._new_sd(lamp_n * t, wl, "with")).sum()
    k_without = channel_factors_of(scene, spectra._new_sd(lamp_n, wl, "without")).sum()
    from scipy.integrate import trapezoid

    expected = trapezoid(lamp_n * t, wl) * k_with / (trapezoid(lamp_n, wl) * k_without)
    ratio = with_abs.rod_ambient_e.sum() / without.rod_ambient_e.sum()
    assert ratio == pytest.approx(expected, rel=1e-4)
    assert ratio < 1e-3  # SPEC 1.3: 99.9 % blocked from 400 to 850 nm


def test_switching_the_lamp_on_shows_from_that_frame(cache):
    cam, _ = _camera(_tiny(**{"ambient.lamp": "white_led", "ambient.power_w": 4000.0, "optics.absorber": "none", "ambient.switch_on_s": 0.1,
                              "ambient.flicker_hz": 100.0}), cache)
    start = cam.windows_s[:, 0]
    before, after = cam.windows_s[:, 1] <= 0.1, start >= 0.1
    assert np.all(cam.lamp_level[before] == 0) and np.all(cam.rod_ambient_e[before] == 0)
    assert np.all(cam.lamp_level[after] > 0.5)
    # frame by frame, the ambient signal follows the lamp's level exactly
    per_level = cam.rod_ambient_e[after] / cam.lamp_level[after, None]
    assert np.allclose(per_level, per_level[0], rtol=1e-5)
    dark = cam.frames[before & ~cam.rendered].astype(float).mean()
    lit = cam.frames[after & ~cam.rendered].astype(float).mean()
    assert lit > dark + 1.0


# ------------------------------------------------------------------------ the calibration frame
def test_calibration_frame_shows_25_circles_to_hough(cache):
    """SPEC 1.6: grey-scale, Gaussian blur, Hough circles: 25 disks at the rods' paraxial centres."""
    import cv2

    from mlsim import pipeline
    from mlsim.render import rod_disks_px
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "mavig_default.toml", {"outputs": ["calibration"], "fidelity.render.tier": "path",
                                                                "fidelity.render.spp": 32})
    frame = pipeline.run(scene, out_dir=None, cache=cache, progress=False, log=lambda m: None).results["calibration"]
    assert frame.info["green_level_dn8"] == pytest.approx(scene.calibration.target_level_dn8, abs=0.5)
    centres, radius = rod_disks_px(scene)
    pitch = np.min(np.diff(np.unique(np.round(centres[:, 0]))))
    grey = cv2.GaussianBlur(cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY), (9, 9), 2)
    found = cv2.HoughCircles(grey, cv2.HOUGH_GRADIENT, dp=1, minDist=0.6 * pitch, param1=60, param2=20,
                             minRadius=int(0.6 * radius), maxRadius=int(1.6 * radius))
    assert found is not None and len(found[0]) == 25
    c = found[0][:, :2]
    nearest = np.linalg.norm(c[:, None] - centres[None], axis=2).min(axis=0)
    # every rod found near its paraxial centre (the paraxial image is about 2 px off at the corner
    # rods, and Hough fits the dark ring the walls make, which perspective pushes outwards)
    assert nearest.max() < 0.25 * radius
