"""The radiometric camera (mlsim.camera): camera equation, noise statistics, ADC, Bayer, timing."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import stats

from mlsim import camera as C
from mlsim.camera import (
    Camera,
    CameraParams,
    capture,
    cos4_relative_illumination,
    demosaic_rggb,
    digitize,
    electrons_per_radiance,
    exposure_windows_s,
    expose_electrons,
    frame_times_s,
    signal_electrons,
    to_8bit,
)

H = W = 350
P0 = CameraParams()
K0 = P0.electrons_per_radiance_m2_sr_s


def flat(electrons_rgb, shape=(H, W)):
    """Radiance (H, W, 3) that gives these mean electrons per channel at the default camera."""
    return np.broadcast_to(np.asarray(electrons_rgb, float) / K0, shape + (3,)).copy()


# ------------------------------------------------------------------------------------ radiometry
def test_camera_equation_matches_analytic():
    L = 3.7e15  # photons s^-1 m^-2 sr^-1
    pitch = 4 * 1.45e-6
    f, d = P0.focal_length_m, 0.060
    m = f / (d - f)
    expected = L * pitch**2 * 0.033 * 0.9 * math.pi / (4 * 2.0**2 * (1 + m) ** 2)
    e = expose_electrons(np.full((6, 8, 3), L), None, electrons_per_radiance=K0, noise=False, dtype=np.float64)
    assert e.shape == (6, 8)
    np.testing.assert_allclose(e, expected, rtol=1e-10, atol=0)
    np.testing.assert_allclose(signal_electrons(np.full((2, 2, 3), L), K0), expected, rtol=1e-10, atol=0)
    # other lens / exposure, explicit magnification
    p = CameraParams(f_number=2.8, exposure_s=0.01, lens_transmittance=0.8, magnification=0.1, binning=1)
    want = 1.45e-6**2 * 0.01 * 0.8 * math.pi / (4 * 2.8**2 * 1.1**2)
    assert p.electrons_per_radiance_m2_sr_s == pytest.approx(want, rel=1e-12)
    assert electrons_per_radiance(1e-12, 1.0, 1.0, 0.0, 1.0) == pytest.approx(math.pi / 4 * 1e-12, rel=1e-12)


def test_default_lens_puts_the_36_mm_surface_on_350_px():
    f, d = P0.focal_length_m, P0.object_distance_m
    m = f / (d - f)
    assert 0.036 * m / P0.effective_pixel_pitch_m == pytest.approx(350, rel=1e-9)
    assert f == pytest.approx(3.2027e-3, rel=1e-4)
    assert P0.resolved_magnification == pytest.approx(350 * 5.8e-6 / 0.036, rel=1e-12)


def test_bayer_photosites_keep_their_own_channel():
    rad = np.empty((4, 6, 3))
    rad[..., 0], rad[..., 1], rad[..., 2] = 100 / K0, 200 / K0, 300 / K0
    e = expose_electrons(rad, None, electrons_per_radiance=K0, noise=False, dtype=np.float64)
    np.testing.assert_allclose(e[0::2, 0::2], 100, rtol=1e-12)
    np.testing.assert_allclose(e[0::2, 1::2], 200, rtol=1e-12)
    np.testing.assert_allclose(e[1::2, 0::2], 200, rtol=1e-12)
    np.testing.assert_allclose(e[1::2, 1::2], 300, rtol=1e-12)


def test_cos4_relative_illumination():
    v = P0.image_distance_m
    rel = cos4_relative_illumination(5, 7, 1e-3, v)
    assert rel[2, 3] == 1.0
    r2 = (2e-3) ** 2 + (3e-3) ** 2
    assert rel[0, 0] == pytest.approx((v * v / (v * v + r2)) ** 2, rel=1e-12)
    # wired through the params: corner / centre of a uniform scene
    p = CameraParams(cos4_falloff=True, bayer=False)
    e = expose_electrons(flat([1000, 1000, 1000]), None, electrons_per_radiance=K0, bayer=False, noise=False,
                         relative_illumination=p.relative_illumination(), dtype=np.float64)
    corner_r2 = 2 * (174.5 * 5.8e-6) ** 2
    assert e[0, 0, 0] / 1000 == pytest.approx((v * v / (v * v + corner_r2)) ** 2, rel=1e-9)
    assert e[0, 0, 0] / 1000 == pytest.approx(0.719, abs=2e-3)


# --------------------------------------------------------------------------------------- noise
def test_shot_noise_small_mean_is_poisson():
    """Mean 5 e-, no read noise or dark: exact branch, chi-square against Poisson(5)."""
    e = expose_electrons(flat([5, 5, 5]), np.random.default_rng(11), electrons_per_radiance=K0, dtype=np.float64).ravel()
    assert np.all(e == np.round(e))  # integer electrons
    edges = np.arange(0, 14)
    observed = np.array([np.sum(e == k) for k in edges[:-1]] + [np.sum(e >= edges[-1])])
    pmf = stats.poisson.pmf(edges[:-1], 5.0)
    expected = e.size * np.append(pmf, 1 - pmf.sum())
    p = stats.chisquare(observed, expected).pvalue
    assert p > 1e-3, p


def test_shot_noise_large_mean_dispersion_and_skewness():
    """Mean 500 e-: normal branch; variance / mean = 1 (99.9 % chi-square interval), skewness 1/sqrt(500)."""
    e = expose_electrons(flat([500, 500, 500]), np.random.default_rng(12), electrons_per_radiance=K0, dtype=np.float64).ravel()
    n, mu = e.size, 500.0
    assert abs(e.mean() - mu) < 4 * math.sqrt(mu / n)
    stat = np.sum((e - mu) ** 2) / mu  # chi2(n) for Poisson dispersion
    lo, hi = stats.chi2.ppf([0.0005, 0.9995], n)
    assert lo < stat < hi, (stat / n, lo / n, hi / n)
    # the Cornish-Fisher term: a plain normal would give 0, 6 standard errors off
    assert abs(stats.skew(e) - 1 / math.sqrt(mu)) < 4 * math.sqrt(6 / n)


@pytest.mark.parametrize("sigma", [1.5, 3.0])  # 1.5: exact-Poisson branch (mu = 0); 3: normal branch
def test_read_noise_alone_is_gaussian(sigma):
    e = expose_electrons(np.zeros((H, W, 3)), np.random.default_rng(int(13 + 10 * sigma)), electrons_per_radiance=K0, read_noise_e=sigma, dtype=np.float64)
    p = stats.kstest(e.ravel() / sigma, "norm").pvalue
    assert p > 1e-3, p
    assert e.std() == pytest.approx(sigma, rel=0.01)


def _exact_cdf(x, mu, sr):
    if sr == 0:
        return stats.poisson.cdf(np.floor(x), mu)
    k = np.arange(0, int(mu + 12 * math.sqrt(mu) + 30))
    return (stats.poisson.pmf(k, mu)[None, :] * stats.norm.cdf((x[:, None] - k[None, :]) / sr)).sum(1)


@pytest.mark.parametrize("mu,sr", [(20.0, 0.0), (100.0, 0.0), (2.5, 2.0), (0.3, 2.0), (15.0, 2.0), (5.0, 4.0), (0.0, 3.0), (1000.0, 8.0)])
def test_normal_branch_error_bound(mu, sr):
    """The skewness-corrected normal is within 1e-3 (Kolmogorov) of Poisson + read noise where it is used.

    Stratified normals z_i = Phi^-1((i + 1/2) / N) make the sample CDF exact to 1/N.
    """
    n = 200_000
    z = stats.norm.ppf((np.arange(n) + 0.5) / n)
    s2 = np.full(n, mu + sr * sr)
    e = np.sort(C._gaussian_shot_read(np.full(n, mu), z.copy(), s2.copy()))
    s = math.sqrt(mu + sr * sr)
    x = np.arange(math.floor(max(0.0, mu - 8 * s)), mu + 8 * s + 1) + 0.5 if sr == 0 else np.linspace(mu - 8 * s, mu + 8 * s, 801)
    sample_cdf = np.searchsorted(e, x, side="right") / n
    err = np.abs(sample_cdf - _exact_cdf(x, mu, sr)).max()
    assert err < 1e-3, err
    if (mu, sr) == (20.0, 0.0):  # the test has teeth: a plain normal misses by 1.5e-2
        plain = np.abs(stats.norm.cdf((x - mu) / s) - _exact_cdf(x, mu, sr)).max()
        assert plain > 1e-2


# ------------------------------------------------------------------------------------- readout
def test_gain_6db_doubles_signal_above_black():
    e = expose_electrons(flat([20000, 20000, 20000]), np.random.default_rng(14), electrons_per_radiance=K0,
                         read_noise_e=P0.effective_read_noise_e, full_well_e=P0.effective_full_well_e)
    kw = dict(conversion_gain_dn_per_e=P0.effective_conversion_gain_dn_per_e, black_level_dn=50.0, adc_bits=10)
    dn0 = digitize(e, gain_db=0.0, **kw).mean() - 50.0
    dn6 = digitize(e, gain_db=6.02, **kw).mean() - 50.0
    assert dn0 == pytest.approx(250.0, rel=0.01)
    assert dn6 / dn0 == pytest.approx(10 ** (6.02 / 20), rel=1e-3)
    # and through the whole chain to 8 bits (floor quantisation: a looser tolerance)
    rad = flat([20000, 20000, 20000])
    out0 = capture(rad, np.random.default_rng(1), CameraParams()).mean() - 12.5
    out6 = capture(rad, np.random.default_rng(1), CameraParams(gain_db=6.02)).mean() - 12.5
    assert out6 / out0 == pytest.approx(2.0, rel=0.02)


@pytest.mark.parametrize("bayer", [True, False])
def test_saturation_gives_255_without_wraparound(bayer):
    p = CameraParams(bayer=bayer)
    for level in (1e25, 1e300):
        out = capture(np.full((2, 40, 40, 3), level), np.random.default_rng(15), p)
        assert out.dtype == np.uint8 and np.all(out == 255)
    # high gain: the ADC clips first, still no wrap
    out = capture(np.full((40, 40, 3), 1e25), np.random.default_rng(15), CameraParams(bayer=bayer, gain_db=30.0))
    assert np.all(out == 255)
    # the electrons stop at the full well
    e = expose_electrons(np.full((8, 8, 3), 1e30), np.random.default_rng(1), electrons_per_radiance=K0, read_noise_e=8.0, full_well_e=80000.0)
    assert np.all(e == 80000.0)


def test_dark_frame_sits_at_black_level():
    # 0 dB: sigma = 0.1 DN10, every 8-bit pixel is 50 >> 2 = 12
    assert np.all(capture(np.zeros((H, W, 3)), np.random.default_rng(16), P0) == 12)
    # 24 dB, no dark current: the 10-bit mean is the black level; the 8-bit mean the floor of it
    p = CameraParams(gain_db=24.0, dark_current_e_per_s=0.0)
    g = p.effective_conversion_gain_dn_per_e * 10 ** (24 / 20)
    e = expose_electrons(np.zeros((H, W, 3)), np.random.default_rng(17), electrons_per_radiance=K0, read_noise_e=p.effective_read_noise_e)
    dn = digitize(e, conversion_gain_dn_per_e=p.effective_conversion_gain_dn_per_e, gain_db=24.0, black_level_dn=50.0, adc_bits=10)
    sigma = p.effective_read_noise_e * g  # 1.6 DN
    assert abs(dn.mean() - 50.0) < 4 * sigma / math.sqrt(dn.size)
    assert dn.std() == pytest.approx(math.sqrt(sigma**2 + 1 / 12), rel=0.02)
    d = np.arange(30, 71)
    pd = stats.norm.cdf((d + 0.5 - 50) / sigma) - stats.norm.cdf((d - 0.5 - 50) / sigma)
    mean8 = np.sum(pd * (d // 4))
    out8 = to_8bit(dn, 10)
    assert abs(out8.mean() - mean8) < 4 * out8.std() / math.sqrt(out8.size)
    # with dark current the mean rises by dark_e x gain
    q = CameraParams(gain_db=24.0)
    e = expose_electrons(np.zeros((H, W, 3)), np.random.default_rng(18), electrons_per_radiance=K0,
                         dark_electrons=q.dark_electrons, read_noise_e=q.effective_read_noise_e)
    dn = digitize(e, conversion_gain_dn_per_e=q.effective_conversion_gain_dn_per_e, gain_db=24.0, black_level_dn=50.0, adc_bits=10)
    assert abs(dn.mean() - (50.0 + q.dark_electrons * g)) < 4 * 1.7 / math.sqrt(dn.size) + 1e-3


@pytest.mark.parametrize("channel", [0, 1, 2])
def test_bayer_demosaic_puts_each_colour_in_its_channel(channel):
    rgb = [0.0, 0.0, 0.0]
    rgb[channel] = 40000.0  # 500 DN10 above black -> 8-bit 137
    out = capture(flat(rgb), np.random.default_rng(19), P0)
    means = out.reshape(-1, 3).mean(0)
    assert means[channel] == pytest.approx(137.0, abs=1.0)
    others = [c for c in range(3) if c != channel]
    assert np.all(out[..., others] == 12)  # black level, 8 bits


def test_demosaic_opencv_naming():
    raw = np.full((8, 8), 10, np.uint8)
    raw[0::2, 0::2] = 200  # RGGB: red at row 0, column 0
    rgb = demosaic_rggb(raw)
    assert np.all(rgb[..., 0] == 200) and np.all(rgb[..., 1] == 10) and np.all(rgb[..., 2] == 10)


def test_no_bayer_three_channels():
    p = CameraParams(bayer=False)
    out = capture(flat([40000, 0, 0], (20, 20)), np.random.default_rng(2), p)
    assert out.shape == (20, 20, 3)
    assert out[..., 0].mean() == pytest.approx(137.0, abs=1.0) and np.all(out[..., 1:] == 12)
    e = expose_electrons(flat([500, 500, 500], (20, 20)), np.random.default_rng(3), electrons_per_radiance=K0, bayer=False)
    assert e.shape == (20, 20, 3) and not np.array_equal(e[..., 0], e[..., 1])


# -------------------------------------------------------------------------- determinism, shapes
def test_same_seed_same_bytes():
    rad = flat([300, 1000, 3000])
    a = capture(rad, np.random.default_rng(5), P0)
    b = capture(rad, np.random.default_rng(5), P0)
    c = capture(rad, np.random.default_rng(6), P0)
    assert a.tobytes() == b.tobytes()
    assert a.tobytes() != c.tobytes()
    # a batch gives the same bytes as its frames one at a time from the same generator
    batch = np.stack([rad, 2 * rad, 0 * rad])
    rng = np.random.default_rng(5)
    one_by_one = np.stack([capture(f, rng, P0) for f in batch])
    assert capture(batch, np.random.default_rng(5), P0).tobytes() == one_by_one.tobytes()


def test_class_and_functions_agree():
    for p in (CameraParams(gain_db=18.0), CameraParams(gain_db=18.0, cos4_falloff=True), CameraParams(bayer=False, read_noise_e=0.5)):
        rad = flat([30, 500, 5000])
        a = Camera(p)(rad, np.random.default_rng(9))
        b = capture(rad, np.random.default_rng(9), p)
        e = expose_electrons(rad, np.random.default_rng(9), electrons_per_radiance=p.electrons_per_radiance_m2_sr_s,
                             dark_electrons=p.dark_electrons, read_noise_e=p.effective_read_noise_e,
                             full_well_e=p.effective_full_well_e, bayer=p.bayer, relative_illumination=p.relative_illumination())
        dn = digitize(e, conversion_gain_dn_per_e=p.effective_conversion_gain_dn_per_e, gain_db=p.gain_db,
                      black_level_dn=p.black_level_dn, adc_bits=p.adc_bits)
        c = demosaic_rggb(to_8bit(dn, p.adc_bits)) if p.bayer else to_8bit(dn, p.adc_bits)
        assert np.array_equal(a, b) and np.array_equal(b, c)
        assert a.mean() > 13  # not a blank frame


def test_shapes():
    out = capture(flat([100, 100, 100], (10, 12)), np.random.default_rng(0), P0)
    assert out.shape == (10, 12, 3) and out.dtype == np.uint8
    out = capture(np.zeros((3, 10, 12, 3), np.float32), np.random.default_rng(0), P0)
    assert out.shape == (3, 10, 12, 3)
    assert Camera()(np.zeros((2, H, W, 3)), np.random.default_rng(0)).shape == (2, H, W, 3)


@pytest.mark.parametrize(
    "bad,match",
    [
        (np.full((4, 4, 3), -1.0), "negative"),
        (np.full((4, 4, 3), np.nan), "NaN"),
        (np.full((4, 4, 3), np.inf), "infinite"),
        (np.zeros((4, 4, 4)), "shape"),
        (np.zeros((4, 4)), "shape"),
        (np.zeros((4, 4, 3), complex), "dtype"),
    ],
)
def test_bad_radiance_is_rejected(bad, match):
    with pytest.raises(ValueError, match=match):
        capture(bad, np.random.default_rng(0), P0)
    with pytest.raises(ValueError, match=match):
        expose_electrons(bad, np.random.default_rng(0), electrons_per_radiance=1.0)


def test_camera_rejects_wrong_frame_size():
    with pytest.raises(ValueError, match="350 x 350"):
        Camera()(np.zeros((100, 120, 3)), np.random.default_rng(0))


@pytest.mark.parametrize(
    "field,value",
    [("f_number", -1.0), ("adc_bits", 7), ("lens_transmittance", 1.5), ("binning", 0), ("gain_db", float("nan")),
     ("width_px", 350.0), ("full_well_e", 0.0), ("bayer", 1)],
)
def test_params_errors_name_the_field(field, value):
    with pytest.raises(ValueError, match=field):
        CameraParams(**{field: value})
    with pytest.raises(ValueError, match="object_distance_m"):
        CameraParams(object_distance_m=0.002)


# -------------------------------------------------------------------------------------- timing
def test_frame_times_and_exposure_windows():
    np.testing.assert_allclose(frame_times_s(4, 30.0), [0, 1 / 30, 2 / 30, 3 / 30], rtol=0, atol=1e-15)
    w = exposure_windows_s(3, 25.0, 0.02)
    np.testing.assert_allclose(w, [[0, 0.02], [0.04, 0.06], [0.08, 0.10]], rtol=0, atol=1e-15)
    assert exposure_windows_s(2, 30.0, 1 / 30)[1, 1] == pytest.approx(2 / 30)  # a full-period exposure is fine
    with pytest.raises(ValueError, match=r"exposure_s = 0.04 exceeds the 33.3 ms frame period at fps = 30"):
        exposure_windows_s(2, 30.0, 0.04)
    with pytest.raises(ValueError, match="exceeds the 33.3 ms frame period"):
        CameraParams(exposure_s=0.04)
    np.testing.assert_allclose(Camera(CameraParams(fps=50.0, exposure_s=0.01)).exposure_windows_s(2), [[0, 0.01], [0.02, 0.03]])


def test_from_scene():
    from mlsim.scene import CameraSpec

    p = CameraParams.from_scene(CameraSpec(fps=25.0, width_px=200, height_px=120, exposure_ms=20.0, gain_db=12.0))
    assert (p.fps, p.width_px, p.height_px, p.gain_db) == (25.0, 200, 120, 12.0)
    assert p.exposure_s == pytest.approx(0.020, rel=1e-12)
    assert p.f_number == P0.f_number and p.focal_length_m == P0.focal_length_m and p.binning == P0.binning
    d = CameraParams.from_scene(CameraSpec())
    assert d.exposure_s == pytest.approx(0.033) and d.fps == 30.0
    with pytest.raises(ValueError) as err:
        CameraParams.from_scene(CameraSpec(exposure_ms=40.0))
    assert str(err.value) == "camera.exposure_ms = 40 exceeds the 33.3 ms frame period at camera.fps = 30: shorten the exposure or lower the frame rate"


@pytest.mark.parametrize("overrides", [{}, {"cos4_falloff": True, "gain_db": 24.0}, {"read_noise_e": 0.3, "gain_db": 30.0, "adc_bits": 12}],
                         ids=["default", "cos4-gain", "exact-poisson-12bit"])
def test_capture_mono_is_capture_of_the_channels_byte_for_byte(overrides):
    """capture_mono (the Bayer channels formed from the mono radiance, the camera stage's path for
    the ML light) gives capture's bytes of radiance[..., None] * k, with and without noise, from
    the dark (the exact Poisson branch) to past the full well, frame by frame or as a batch."""
    p = C.CameraParams(**(overrides | {"width_px": 80, "height_px": 64}))
    rng = np.random.default_rng(5)
    k = np.array([0.078, 0.552, 0.273], np.float32)  # the ML light's channel factors (default sensor)
    top = 1.5 * p.effective_full_well_e / p.electrons_per_radiance_m2_sr_s / float(k.max())
    rad = (rng.random((3, 64, 80)) ** 4 * top).astype(np.float32)
    rad[0, :10] = 0.0  # dark rows
    for noise in (True, False):
        ref = C.capture(rad[..., None] * k, np.random.default_rng(7), p, noise=noise)
        got = C.capture_mono(rad, k, np.random.default_rng(7), p, noise=noise)
        assert np.array_equal(got, ref), noise
        cam, g = C.Camera(p), np.random.default_rng(7)
        assert np.array_equal(np.stack([cam.mono(r, k, g, noise=noise) for r in rad]), ref)
    assert len(np.unique(ref)) > 100  # the 8-bit range exercised, not one code
    # what capture refuses, capture_mono refuses with capture's words
    bad = rad.copy()
    bad[1, 3, 3] = np.nan
    with pytest.raises(ValueError, match=r"radiance has 3 NaN value\(s\)"):
        C.capture_mono(bad, k, rng, p)
    with pytest.raises(ValueError, match=r"radiance is 64 x 81 px \(H x W\) but the camera is 64 x 80"):
        C.Camera(p).mono(np.zeros((64, 81), np.float32), k, rng)


def test_the_uniforms_from_whole_words_are_numpys_float32_uniforms():
    """_uniform_f32 (PCG64's 64-bit words split into two float32 uniforms) gives numpy's
    ``rng.random(n, dtype=np.float32)`` bytes and leaves the generator where numpy leaves it (the
    next draws agree); a generator holding a spare half-word, or another bit generator, takes
    numpy's loop (the same bytes)."""
    a, b = np.random.default_rng(11), np.random.default_rng(11)
    for n in (2, 10, 350 * 350, 2 * 61251):
        assert np.array_equal(a.random(n, dtype=np.float32).view(np.uint32), C._uniform_f32(b, n).view(np.uint32)), n
        assert a.random() == b.random()
    a.random(1, dtype=np.float32), b.random(1, dtype=np.float32)  # a spare half-word held
    assert np.array_equal(a.random(6, dtype=np.float32), C._uniform_f32(b, 6))
    assert a.random(3, dtype=np.float32).tolist() == C._uniform_f32(b, 3).tolist()
    p, q = np.random.Generator(np.random.Philox(3)), np.random.Generator(np.random.Philox(3))
    assert np.array_equal(p.random(8, dtype=np.float32), C._uniform_f32(q, 8))
    u = C._uniform_f32(np.random.default_rng(0), 200_000)
    assert u.dtype == np.float32 and u.min() >= 0.0 and u.max() < 1.0
    assert stats.kstest(u, "uniform").pvalue > 1e-3


@pytest.mark.parametrize("overrides, step", [({}, 12), ({"bayer": False}, 12), ({"black_level_dn": 2.0}, 0),
                                             ({"black_level_dn": 51.5}, None), ({"gain_db": 30.0}, None), ({"read_noise_e": 0.3, "gain_db": 30.0}, None)],
                         ids=["default", "no-bayer", "clipped-at-zero", "mean-on-a-step", "high-gain", "exact-poisson"])
def test_a_frame_without_light_is_drawn_only_where_its_noise_can_reach_another_step(overrides, step):
    """Camera.dark (the DLLM's idle frames) is ``camera(zeros, rng)`` byte for byte, frame after
    frame, and leaves the generator where that leaves it. dark_frame_dn8 names the 8-bit step
    that every draw reads (the defaults: 12, dark photosites at 49.4-50.6 DN of 10 bits) and
    refuses where a draw could read another: a mean on a step's edge (black level 51.5: 50.9-52.1
    DN), high gain (30 dB: +-18 DN), or the exact Poisson branch (read noise 0.3 e-: counts; at 30 dB)."""
    p = C.CameraParams(**(overrides | {"width_px": 48, "height_px": 40}))
    assert C.dark_frame_dn8(p) == step
    cam = C.Camera(p)
    for noise in (True, False):
        a, b = np.random.default_rng(3), np.random.default_rng(3)
        ref = np.stack([cam(np.zeros((40, 48, 3), np.float32), a, noise=noise) for _ in range(4)])
        got = np.stack([cam.dark(b, noise=noise) for _ in range(4)])
        assert np.array_equal(got, ref), noise
        assert a.random() == b.random()
        if step is not None:
            assert np.all(ref == step)
        elif noise:
            assert len(np.unique(ref)) > 1  # the draws do reach another step
    # the noise's full range: a large dark frame drawn at the defaults reads the one step
    big = C.capture(np.zeros((350, 350, 3), np.float32), np.random.default_rng(1), C.CameraParams())
    assert np.all(big == C.dark_frame_dn8(C.CameraParams()))


@pytest.mark.parametrize("overrides", [{}, {"cos4_falloff": True, "gain_db": 24.0}, {"adc_bits": 12, "gain_db": 7.3}, {"full_well_e": 10.0},
                                       {"black_level_dn": 0.0}], ids=["default", "cos4-gain", "12bit", "tiny-well", "no-black"])
def test_the_compiled_bayer_pass_is_numpys_exposure_and_read_out_byte_for_byte(overrides):
    """mlsim.camera_kernels.bayer_mono_codes (capture_mono's one pass per frame where the read
    noise rules out the exact Poisson branch) gives _expose_frame + _read_out's codes byte for
    byte, from the dark to a radiance that overflows the mean (3e38), and draws the same normals
    (the generators agree afterwards); where the exact branch may apply it declines, drawing nothing."""
    p = C.CameraParams(**(overrides | {"width_px": 80, "height_px": 64}))
    k = np.array([0.078, 0.552, 0.273], np.float32)
    rng = np.random.default_rng(5)
    top = 1.5 * p.effective_full_well_e / p.electrons_per_radiance_m2_sr_s / float(k.max())
    rad = (rng.random((4, 64, 80)) ** 4 * top).astype(np.float32)
    rad[0, :10] = 0.0
    rad[1, :5] = np.float32(3e38)
    cfg = C._exposure_config(rad.shape[1:], p.electrons_per_radiance_m2_sr_s, p.dark_electrons, p.effective_read_noise_e,
                             p.effective_full_well_e, True, True, p.relative_illumination(), C.EXACT_POISSON_BELOW_E2, np.float32)
    a, b = np.random.default_rng(9), np.random.default_rng(9)
    ref, got = np.empty(rad.shape + (3,), np.uint8), np.empty(rad.shape + (3,), np.uint8)
    for i in range(len(rad)):
        C._read_out(C._expose_frame(rad[i], a, cfg, mono_k=k), p, ref[i])
        assert C._capture_mono_compiled(rad[i], b, cfg, k, p, got[i])
    assert np.array_equal(got, ref)
    assert a.random() == b.random()
    assert len(np.unique(ref)) > (1 if overrides.get("full_well_e") else 100)
    exact = C._exposure_config(rad.shape[1:], p.electrons_per_radiance_m2_sr_s, p.dark_electrons, 0.5, p.effective_full_well_e, True, True,
                               None, C.EXACT_POISSON_BELOW_E2, np.float32)
    state = b.bit_generator.state
    assert not C._capture_mono_compiled(rad[0], b, exact, k, p, got[0])
    assert b.bit_generator.state == state
