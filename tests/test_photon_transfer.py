"""The dark part of photon transfer (mlsim.photon_transfer) on idle frames of mlsim.camera: three
perturbed cameras at a gain where the 8-bit output keeps the noise give back their black level and
read noise within 3 stated standard uncertainties; at the default 0 dB every idle frame is the same
code and the read noise is reported as not determinable, the black level as its 8-bit step."""

from __future__ import annotations

import numpy as np
import pytest

from mlsim.camera import Camera, CameraParams
from mlsim.photon_transfer import dark_parameters, dark_statistics, native_sites


def _idle(params, n=40, seed=0):
    rng = np.random.default_rng(seed)
    return Camera(params)(np.zeros((n, params.height_px, params.width_px, 3), np.float32), rng)


@pytest.mark.parametrize("black, read_e, gain_db, seed", [(50.0, 2.0, 30.0, 1), (38.0, 3.5, 27.0, 2), (71.0, 1.2, 33.0, 3)])
def test_black_level_and_read_noise_are_recovered_within_their_uncertainty(black, read_e, gain_db, seed):
    params = CameraParams(width_px=96, height_px=96, black_level_dn=black, read_noise_e=read_e, gain_db=gain_db)
    stats = dark_statistics(_idle(params, seed=seed))
    fit = dark_parameters(stats, CameraParams(width_px=96, height_px=96, gain_db=gain_db))  # black and noise unknown to it
    assert fit["determinable"], fit["why"]
    assert abs(fit["black_level_dn"] - black) < 3.0 * fit["black_level_sigma"] + 0.05, fit
    assert abs(fit["read_noise_e"] - read_e) < 3.0 * fit["read_noise_sigma"], fit
    assert fit["read_noise_sigma"] < 0.05 * read_e  # 40 frames of 96 x 96 px: a few per cent


def test_the_default_camera_hides_its_dark_noise_in_the_8_bit_step():
    params = CameraParams(width_px=64, height_px=64)
    frames = _idle(params)
    assert len(np.unique(frames)) == 1  # every idle pixel the same code: 50 DN // 4 = 12
    fit = dark_parameters(dark_statistics(frames), params)
    assert not fit["determinable"] and fit["read_noise_e"] is None and "hides it" in fit["why"]
    assert fit["black_level_range_dn"][0] <= params.black_level_dn < fit["black_level_range_dn"][1]


def test_native_sites_are_the_raw_mosaic_and_the_variance_uncertainty_is_honest():
    """The demosaic keeps each site's own channel; over 200 repeats of a noisy camera the spread of
    the variance estimate matches its stated uncertainty within 15 %."""
    raw = np.arange(36, dtype=np.uint8).reshape(6, 6) * 7
    import cv2

    rgb = cv2.cvtColor(raw, getattr(cv2, "COLOR_BayerRGGB2RGB", cv2.COLOR_BayerBG2RGB))
    assert np.array_equal(native_sites(rgb[None])[0], raw[1:-1, 1:-1])
    params = CameraParams(width_px=32, height_px=32, gain_db=30.0, read_noise_e=2.0)
    est = [dark_statistics(_idle(params, n=6, seed=s)) for s in range(200)]
    v = np.array([e.temporal_var_dn8 for e in est])
    assert abs(v.std() / np.mean([e.var_sigma for e in est]) - 1.0) < 0.15
    with pytest.raises(ValueError, match="at least 2"):
        dark_statistics(_idle(params, n=1))
