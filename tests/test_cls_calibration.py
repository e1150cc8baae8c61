"""Batch calibration of the CLS pairs' coefficients and mounting poses (SPEC 3, issue 20 item 3):
analytic Jacobians against central differences, exact recovery from noise-free data, recovery to
the Cramer-Rao bound from noisy data, and which parameters the planar trajectories cannot identify
(the mirror symmetry in x, shown on the voltages themselves)."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.cls import ltv
from other_sensors.cls.calibration import (PARAM_NAMES, CalibrationSettings, calibrate, calibration_jacobian, mount_params,
                                           tolerances, with_mounts)
from other_sensors.cls.estimator import AT_REST, LmSettings, estimate_poses
from other_sensors.cls.shell import ADC_RANGE_V, measure, trajectory

LAYOUT = ltv.default_layout()
SETTINGS = CalibrationSettings()
TOL = tolerances(LAYOUT.coeffs[0], SETTINGS)
X_PARAMS = ("led_x_mm", "led_tilt_x", "ltv_x_mm", "ltv_tilt_x")
IX = [PARAM_NAMES.index(n) for n in X_PARAMS]
# SPEC 3: 37 s of measured poses at the motion-capture rate (80 Hz), general motion
POSES = trajectory("general", np.arange(37 * 80) / 80.0, 0.25, 40.0, 10.0, 6.0, 6.0, 0.5, np.random.default_rng(1))


def _truth(seed: int, x_too: bool):
    """Nominal parameters plus one tolerance of Gaussian spread each (the x ones only if ``x_too``)."""
    nominal = mount_params(LAYOUT, LAYOUT)
    true = nominal + TOL * np.random.default_rng(seed).standard_normal(nominal.shape)
    if not x_too:
        true[:, IX] = nominal[:, IX]
    return true


def test_calibration_jacobian_matches_central_differences():
    true = _truth(4, x_too=True)
    p, q = ltv.planar_to_pose(POSES[::37])
    R = ltv.quat_to_matrix(q)
    v, J, _, _ = calibration_jacobian(true, LAYOUT, p, R)
    np.testing.assert_allclose(v, ltv.pair_voltages(p, q, with_mounts(LAYOUT, true)), rtol=1e-13)  # same model as the kernel
    for k in range(len(PARAM_NAMES)):
        h = 1e-4 * TOL[k]
        plus, minus = true.copy(), true.copy()
        plus[:, k] += h
        minus[:, k] -= h
        fd = (calibration_jacobian(plus, LAYOUT, p, R)[0] - calibration_jacobian(minus, LAYOUT, p, R)[0]) / (2 * h)
        np.testing.assert_allclose(J[..., k], fd, rtol=1e-6, atol=1e-6 * np.abs(J[..., k]).max() + 1e-12, err_msg=PARAM_NAMES[k])


def test_pair_model_axis_gradients_are_tangent_and_match_central_differences():
    rng = np.random.default_rng(8)
    d = rng.normal(0, 5, (6, 3)) + [0.0, 0.0, 35.0]
    m = rng.normal(0, 0.2, (6, 3)) + [0.0, 0.0, -1.0]
    n = rng.normal(0, 0.2, (6, 3)) + [0.0, 0.0, 1.0]
    m /= np.linalg.norm(m, axis=1, keepdims=True)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    v, gd, gm, gn, *_ = ltv.pair_model(d, m, n, ltv.DEFAULT_COEFFS)
    # the model sees the axes' directions only: no radial part, and scaling an axis changes nothing
    np.testing.assert_allclose(np.einsum("ij,ij->i", gm, m), 0.0, atol=1e-14)
    np.testing.assert_allclose(ltv.pair_model(d, 3 * m, n, ltv.DEFAULT_COEFFS)[0], v, rtol=1e-14)
    for name, arr, grad in (("d", d, gd), ("m", m, gm), ("n", n, gn)):
        for k in range(3):
            e = np.zeros(3)
            e[k] = 1e-6
            args_p = {"d": d, "m": m, "n": n} | {name: arr + e}
            args_m = {"d": d, "m": m, "n": n} | {name: arr - e}
            fd = (ltv.pair_model(**args_p, c=ltv.DEFAULT_COEFFS)[0] - ltv.pair_model(**args_m, c=ltv.DEFAULT_COEFFS)[0]) / 2e-6
            np.testing.assert_allclose(grad[:, k], fd, rtol=1e-6, atol=1e-6 * np.abs(grad).max(), err_msg=f"{name}[{k}]")


def test_noise_free_calibration_recovers_perturbed_poses_and_coefficients_exactly():
    """Every in-plane parameter (13 of 17 per pair) is locally identifiable: from one tolerance of
    error in each, noise-free data give them back to 1e-6 of their tolerance."""
    true = _truth(5, x_too=False)
    poses = POSES[::2]  # 37 s at 40 Hz: enough without noise, and half the time
    _, clean = measure(poses, with_mounts(LAYOUT, true), 0.0, np.random.default_rng(0))
    fit = calibrate(poses, clean, LAYOUT, CalibrationSettings(noise_rms_mv=1e-6))
    assert np.all(fit.rms_mv < 1e-6)
    assert np.max(np.abs(fit.params - true) / TOL) < 1e-6
    assert np.all(fit.frozen[:, IX]) and not fit.frozen[:, [k for k in range(17) if k not in IX]].any()


def test_the_x_mounting_is_invisible_to_planar_motion_mirror_symmetry():
    """x offsets and x tilts: the voltages are even in them (the planar motion is mirror-symmetric
    in x), so their sign cannot be told and their first derivatives vanish at the design."""
    true = _truth(6, x_too=True)
    mirrored = true.copy()
    mirrored[:, IX] *= -1
    v_true = ltv.planar_voltages(POSES, with_mounts(LAYOUT, true))
    v_mirror = ltv.planar_voltages(POSES, with_mounts(LAYOUT, mirrored))
    np.testing.assert_allclose(v_mirror, v_true, rtol=1e-13, atol=0)
    nominal = mount_params(LAYOUT, LAYOUT)
    p, q = ltv.planar_to_pose(POSES)
    _, J, _, _ = calibration_jacobian(nominal, LAYOUT, p, ltv.quat_to_matrix(q))
    assert np.all(J[..., IX] == 0.0)
    assert np.abs(J[..., [k for k in range(17) if k not in IX]]).min(axis=0).max() > 0


def test_noisy_calibration_recovers_within_the_cramer_rao_bound_and_names_what_is_not_identifiable():
    true = _truth(7, x_too=True)
    truth = with_mounts(LAYOUT, true)
    volts, _ = measure(POSES, truth, 0.7, np.random.default_rng(3))
    fit = calibrate(POSES, volts, LAYOUT)
    assert np.all(np.abs(fit.rms_mv - 0.7) < 0.05)  # the residual is the noise
    z = (fit.params - true) / TOL / fit.crlb  # error over its bound: ~ N(0, 1) where finite
    finite = np.isfinite(fit.crlb)
    assert np.all(finite[:, [k for k in range(17) if k not in IX]]) and not finite[:, IX].any()
    assert np.max(np.abs(z[finite])) < 4.0
    # the x parameters are held at the design (nothing to fit), the others moved
    np.testing.assert_array_equal(fit.params[:, IX], mount_params(LAYOUT, LAYOUT)[:, IX])
    # the partition of SPEC 3's parameters on this trajectory (Cramer-Rao std vs tolerance, 0.7 mV):
    identifiable = {"c4", "led_y_mm", "led_z_mm", "led_tilt_y", "ltv_y_mm", "ltv_z_mm", "ltv_tilt_y"}
    for weak, crlb in zip(fit.weak, fit.crlb):
        assert set(weak) == set(PARAM_NAMES) - identifiable, weak
        assert np.all(crlb[[PARAM_NAMES.index(n) for n in identifiable]] < 1.0)
    for directions in fit.directions:
        # two weak in-plane directions (the near field / offset trade c2, c3, c7 and the LTV's angular
        # response c5, c6 against c1) and the four x parameters
        # (and, in some pairs, a third: c6 against the LTV's tilt and c2); relative singular values
        # of 1e-4 to 1e-6 for the first, round-off (< 1e-15) for the x ones
        rel = np.array([sv for sv, _ in directions])
        in_plane = [set(c) for sv, c in directions if sv > 1e-15]
        assert np.sum(rel < 1e-15) == 4 and len(in_plane) in (2, 3) and np.all(rel[rel > 1e-15] < 2e-4)
        assert any(s & {"c5", "c6"} for s in in_plane) and any(s & {"c3", "c7"} for s in in_plane)
    # what matters: poses on another trajectory, from the calibrated pairs, are nearly as good as from the true ones
    t = np.arange(4000) / 2000.0
    test_poses = trajectory("general", t, 0.1, 40.0, 10.0, 6.0, 6.0, 1.0, np.random.default_rng(9))
    v2 = ltv.planar_voltages(test_poses, truth)
    rms = {}
    for name, layout in (("nominal", LAYOUT), ("calibrated", fit.layout), ("true", truth)):
        est = estimate_poses(v2, layout, LmSettings(), 200, ADC_RANGE_V)
        fitted = est.status != AT_REST
        rms[name] = np.sqrt(np.mean(np.sum((est.poses[fitted, :2] - test_poses[fitted, :2]) ** 2, axis=1)))
    assert rms["true"] < 1e-6 and rms["nominal"] > 0.3, rms
    assert rms["calibrated"] < 0.03 * rms["nominal"], rms


def test_calibration_refuses_mismatched_input():
    with pytest.raises(ValueError, match="calibrate"):
        calibrate(POSES, np.zeros((len(POSES), 3)), LAYOUT)
    with pytest.raises(ValueError, match="params"):
        with_mounts(LAYOUT, np.zeros((5, 7)))
