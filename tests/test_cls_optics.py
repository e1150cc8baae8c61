"""The CLS's optical truth (issue 43, SPEC 3): the LED's beam and the LTV's acceptance against
radiometry's closed forms, the working point, that the seven-coefficient law cannot hold the optics
(the calibration's residual above the noise), the motion capture's noise, the seed's deflection
ranges and bad input. The cavity's diffuse light: test_cls_cavity_radiosity.py."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from scipy import integrate, stats

import other_sensors.cls.kind  # noqa: F401  (registers the cls kind)
from mlsim.scene import load_scene
from other_sensors.cls.ltv import default_layout, planar_voltages
from other_sensors.cls.optics import Optics, direct_irradiance, lambert_order, optical_voltages
from other_sensors.cls.stages import DEFLECTION_BINS_MM, clean_voltages, layout_of, measured_voltages, true_layout_of
from scene_helpers import assert_edits_refused

ROOT = Path(__file__).resolve().parents[1]
LAYOUT = default_layout()


def test_the_led_beam_halves_at_its_half_angle_and_carries_2pi_over_m_plus_1():
    for half in (10.0, 30.0, 60.0):
        m = lambert_order(half)
        assert np.cos(np.radians(half)) ** m == pytest.approx(0.5, rel=1e-12)
        flux = integrate.quad(lambda t: np.cos(t) ** m * np.sin(t) * 2 * np.pi, 0, np.pi / 2)[0]
        assert flux == pytest.approx(2 * np.pi / (m + 1), rel=1e-9)
    assert lambert_order(60.0) == pytest.approx(1.0)  # a Lambertian LED


def test_the_direct_path_is_inverse_square_and_cosine_at_the_ltv():
    m = lambert_order(30.0)
    e = direct_irradiance(np.array([20.0, 40.0]), 0.0, 0.0, m)
    assert e[0] / e[1] == pytest.approx(4.0)
    assert direct_irradiance(30.0, 0.0, np.radians(60.0), m) == pytest.approx(0.5 / 900.0)
    assert direct_irradiance(30.0, np.radians(30.0), 0.0, m) == pytest.approx(0.5 / 900.0)
    assert direct_irradiance(30.0, np.radians(95.0), 0.0, m) == 0.0 and direct_irradiance(30.0, 0.0, np.radians(91.0), m) == 0.0


def test_the_designed_shell_at_rest_reads_the_nominal_working_point():
    o = Optics()
    rest = np.array([0.0, LAYOUT.rest_p[2], 0.0])
    np.testing.assert_allclose(optical_voltages(rest, LAYOUT, LAYOUT, o), planar_voltages(rest, LAYOUT), rtol=1e-12)
    # a pair's gain spread (its c1) scales its light, not its dark output
    built = LAYOUT.with_coeffs(LAYOUT.coeffs * [1.1, 1, 1, 1, 1, 1, 1])
    pose = np.array([[2.0, 30.0, 0.05]])
    v0, v1 = optical_voltages(pose, LAYOUT, LAYOUT, o), optical_voltages(pose, built, LAYOUT, o)
    np.testing.assert_allclose(v1 - o.dark_v, 1.1 * (v0 - o.dark_v), rtol=1e-12)
    # mirror symmetry: a shear to -y reads the mirrored pairs of a shear to +y (the layout's staggers alternate)
    mirrored = default_layout(stagger_mm=-6.0)
    np.testing.assert_allclose(optical_voltages(np.array([-3.0, 35.0, 0.0]), mirrored, mirrored, o)[::-1],
                               optical_voltages(np.array([3.0, 35.0, 0.0]), LAYOUT, LAYOUT, o), rtol=1e-12)


def test_the_law_cannot_hold_the_optics():
    """Fitted to noise-free optical voltages, the seven coefficients leave a residual the noise cannot
    explain (chi-square over the samples at 0.7 mV), while fitted to the law's own voltages they
    leave the noise alone."""
    from other_sensors.cls.calibration import CalibrationSettings, calibrate
    from other_sensors.cls.shell import digitise, trajectory

    scene = load_scene(ROOT / "scenes" / "cls" / "general.toml")
    s = scene.sensor
    t = np.arange(800) / 80.0
    poses = trajectory("general", t, 0.25, 40.0, 18.0, 6.0, 6.0, 0.5, np.random.default_rng(3))
    settings = CalibrationSettings(r_max_mm=60.0, noise_rms_mv=0.7)
    residual = {}
    for truth in ("optics", "law"):
        sensor = s if truth == "optics" else s.model_copy(update={"optics": None})
        clean = clean_voltages(sensor, poses, LAYOUT)
        volts = digitise(clean, 0.7, np.random.default_rng(4))
        residual[truth] = calibrate(poses, volts, LAYOUT, settings).rms_mv
    dof = 800  # samples per pair (some dropped by the calibration's gates: a conservative count)
    assert np.all(residual["law"] < 0.8)  # the noise (0.7 mV)
    # chi-square: n (rms / sigma)^2 far past its 99.9 % quantile for every pair
    assert np.all(dof * (residual["optics"] / 0.7) ** 2 > stats.chi2.ppf(0.999, dof))


def test_the_motion_capture_noise_reaches_the_calibration_and_the_ranges_are_the_seeds():
    assert DEFLECTION_BINS_MM == (0.0, 5.0, 10.0, 15.0, float("inf"))
    scene = load_scene(ROOT / "scenes" / "cls" / "compression.toml")
    cal = scene.sensor.calibration
    assert (cal.mocap_noise_mm, cal.mocap_noise_deg) == (0.15, 0.1)
    # the compression scene reaches past 15 mm while the LEDs stay over the estimator's 15 mm range
    from other_sensors.cls.ltv import pair_geometry, planar_to_pose

    deepest = np.array([0.0, 40.0 - scene.sensor.trajectory.compression_mm, 0.0])
    r = pair_geometry(*planar_to_pose(deepest), true_layout_of(scene.sensor, scene.seed))[0]
    assert scene.sensor.trajectory.compression_mm > 15.0 and r.min() > scene.sensor.estimator.r_min_mm
    # the same seed gives the same readings; the readings' noise is the scene's
    built = true_layout_of(scene.sensor, scene.seed)
    pose = np.tile([0.0, 40.0, 0.0], (4000, 1))
    one, clean = measured_voltages(scene.sensor, pose, built, np.random.default_rng(1))
    two, _ = measured_voltages(scene.sensor, pose, built, np.random.default_rng(1))
    np.testing.assert_array_equal(one, two)
    assert np.std(one - clean) * 1e3 == pytest.approx(0.7, rel=0.05)


def test_bad_optics_are_refused_naming_the_field(tmp_path):
    assert_edits_refused(ROOT / "scenes" / "cls" / "general.toml",
                         (("rho_shell = 0.3", "rho_shell = -0.2", "sensor.optics.rho_shell"),
                          ("rho_base = 0.1", "rho_base = 1.5", "sensor.optics.rho_base"),
                          ("half_angle_deg = 30.0", "half_angle_deg = 95.0", "sensor.optics.half_angle_deg"),
                          ("mocap_noise_mm = 0.15", "mocap_noise_mm = nan", "sensor.calibration.mocap_noise_mm")), tmp_path)
    with pytest.raises(ValueError, match="sensor.optics.rho_shell"):
        Optics(rho_shell=1.0)
    with pytest.raises(ValueError, match="half_angle_deg"):
        Optics(half_angle_deg=0.0)
    assert layout_of(load_scene(ROOT / "scenes" / "cls" / "rest.toml").sensor).n_pairs == 5
