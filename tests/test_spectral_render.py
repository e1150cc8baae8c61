"""The spectral reference render (mlsim.render.spectral): its units against the mono render times the
channel factors (within the Monte Carlo error estimated from independent renders), the channel order
and ratios of narrow bands, mono and spectral scenes in one process, the comparison table, bad input."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from mlsim import spectra as sp  # noqa: E402
from mlsim.render import ml_channel_factors  # noqa: E402
from mlsim.render.sensor_scene import SPECTRAL_VARIANT, VARIANT, SensorScene, use_variant  # noqa: E402
from mlsim.render.spectral import (RenderSpectra, compare_to_shortcut, ml_render_spectra, shortcut_images,  # noqa: E402
                                   spectral_reference, spectral_twin)
from mlsim.scene import Scene  # noqa: E402
from test_render import _flat_sheet, _view  # noqa: E402

L0 = 2.5e15  # photons s^-1 m^-2 sr^-1
CENTRE = (slice(12, 20), slice(12, 20))  # 8 x 8 pixels around the axis of a 32 x 32 view


def _flat_scene():
    V, F = _flat_sheet()
    scene = SensorScene(V, F, _view(32), base_half_size_m=0.02, reflectance=0.0)
    scene.set_radiance(np.full(len(V), L0))
    return scene


def _exact_linear_product_integral(wl, a, b):
    """Integral of the product of the linear interpolants of a and b (what Mitsuba's ``regular``
    spectra integrate), per interval h/6 (2 a0 b0 + a0 b1 + a1 b0 + 2 a1 b1)."""
    h = np.diff(wl)
    a0, a1, b0, b1 = a[..., :-1], a[..., 1:], b[..., :-1], b[..., 1:]
    return np.sum(h / 6.0 * (2 * a0 * b0 + a0 * b1 + a1 * b0 + 2 * a1 * b1), axis=-1)


def _mean_and_se(samples):
    x = np.asarray(samples, dtype=np.float64)
    return x.mean(axis=0), x.std(axis=0, ddof=1) / np.sqrt(len(x))


# ------------------------------------------------------------------------------------------ spectra
def test_render_spectra_integrate_to_the_shortcut_factors():
    """The reference's curves are the ones ml_channel_factors integrates (they are built twice: this
    keeps the two in step), on the default scene and on one with other path lengths."""
    for scene in (Scene(), Scene().with_values({"optics.acrylic_thickness_mm": 8.0, "sensor.rod.height_mm": 14.0})):
        spectra = ml_render_spectra(scene)
        assert spectra.channel_factors() == pytest.approx(ml_channel_factors(scene), rel=1e-12)
        assert spectra.channels == ("r", "g", "b")
        # the trapezoid rule of the shortcut against the exact integral of the linear interpolants
        # that Mitsuba's regular spectra integrate: the quadrature part of the difference is about
        # 1e-4 (the QE data have kinks between their 5 nm nodes), far below the 1 % target
        exact = _exact_linear_product_integral(spectra.wavelengths_nm, spectra.emission_per_nm[None], spectra.sensitivity)
        assert exact == pytest.approx(spectra.channel_factors(), rel=3e-4)


# ------------------------------------------------------------------------------ units, absolutely
def test_flat_patch_spectral_equals_mono_times_factors_within_monte_carlo_error():
    """A uniform Lambertian sheet on the axis (no inter-reflection): the spectral render's channel c
    equals the mono render times k_c. K independent renders on each side give the means and their
    standard errors; the difference must be within 4 combined standard errors, and the test must
    be able to see a 1 % error (4 standard errors < 1 %)."""
    mono = _flat_scene()
    spectra = ml_render_spectra(Scene())
    k = spectra.channel_factors()
    twin = spectral_twin(mono, spectra)
    twin.set_radiance(np.full(mono.n_vertices, L0))
    K, spp = 8, 256
    spec = [twin.render(spp, 100 + i)[CENTRE].reshape(-1, 3).mean(axis=0) for i in range(K)]
    flat = [mono.render(spp, 200 + i)[CENTRE].mean() for i in range(K)]
    s_mean, s_se = _mean_and_se(spec)
    m_mean, m_se = _mean_and_se(flat)
    expected = m_mean * k
    se = np.sqrt(s_se**2 + (k * m_se) ** 2)
    assert np.all(np.abs(s_mean - expected) <= 4 * se), (s_mean / expected - 1, se / expected)
    assert np.all(4 * se < 0.01 * expected)
    # and the value is the physics: about L0 (1 - R)(1 - R') / n_core^2 per photon weight
    assert s_mean[1] == pytest.approx(L0 * k[1] * (1 - 7.6e-4) * (1 - 0.0387) / 1.41**2, rel=0.02)


def test_narrow_bands_give_the_expected_channel_ratios():
    """A 10 nm band at 450 nm and one at 600 nm: each channel's share of the green channel is the
    ratio of the integrals of band x sensitivity (blue over green large at 450 nm, red over green at
    600 nm), within the Monte Carlo error of K independent renders."""
    mono = _flat_scene()
    base = ml_render_spectra(Scene())
    wl = base.wavelengths_nm
    for peak_nm in (450.0, 600.0):
        band = np.asarray(sp.photon_band_sd(peak_nm, 10.0).values, dtype=float)
        spectra = RenderSpectra(wl, band / np.trapezoid(band, wl), base.sensitivity, base.channels)
        expected = _exact_linear_product_integral(wl, spectra.emission_per_nm[None], spectra.sensitivity)
        twin = spectral_twin(mono, spectra)
        twin.set_radiance(np.full(mono.n_vertices, L0))
        sums = np.array([twin.render(64, 7 + i)[CENTRE].reshape(-1, 3).sum(axis=0) for i in range(8)])
        ratios = sums / sums[:, 1:2]  # per render: R/G, 1, B/G
        mean, se = _mean_and_se(ratios)
        want = expected / expected[1]
        assert np.all(np.abs(mean - want) <= 4 * se + 1e-12), (peak_nm, mean, want, se)
        assert np.all(4 * se[[0, 2]] < 0.02 * want[[0, 2]])  # the test resolves a 2 % error in the ratio
    # the two bands order the channels as their names say
    assert want[0] > 1.0  # 600 nm: red above green for this camera


def test_channel_order_and_absolute_value_of_box_channels():
    """Three box channels (400-450, 500-600, 650-700 nm) and a band at 550 nm: channels 0 and 2 see
    nothing (exactly 0), channel 1 sees the whole band, so it equals the mono render (the band has
    unit integral): within the Monte Carlo error."""
    mono = _flat_scene()
    wl = sp.wavelengths_nm()
    boxes = np.stack([(wl >= lo) & (wl <= hi) for lo, hi in ((400, 450), (500, 600), (650, 700))]).astype(float)
    band = np.asarray(sp.photon_band_sd(550.0, 30.0).values, dtype=float)
    band[(wl < 505) | (wl > 595)] = 0.0  # keep the band inside the middle box
    spectra = RenderSpectra(wl, band / np.trapezoid(band, wl), boxes, ("low", "mid", "high"))
    twin = spectral_twin(mono, spectra)
    twin.set_radiance(np.full(mono.n_vertices, L0))
    # 1024 spp: the film samples wavelengths by its curves (three boxes), not by the band, so
    # half of the wavelength samples miss it (several times the variance of a mono render)
    spec = np.array([twin.render(1024, 30 + i)[CENTRE].reshape(-1, 3).mean(axis=0) for i in range(8)])
    flat = np.array([mono.render(256, 60 + i)[CENTRE].mean() for i in range(8)])
    assert np.all(spec[:, [0, 2]] == 0.0)
    s_mean, s_se = _mean_and_se(spec[:, 1])
    m_mean, m_se = _mean_and_se(flat)
    assert abs(s_mean - m_mean) <= 4 * np.hypot(s_se, m_se)
    assert 4 * np.hypot(s_se, m_se) < 0.01 * m_mean  # a 1 % error would be seen


# ------------------------------------------------------------------- one process, two variants
def test_mono_and_spectral_scenes_take_turns_in_one_process():
    """Mitsuba's variant is global: a mono scene renders the same bytes before and after a spectral
    render, and the spectral scene renders again after the mono one; the pure function and the
    scene's render give the same image for the same seed."""
    import mitsuba as mi

    mono = _flat_scene()
    before = mono.render(16, 5)
    spectra = ml_render_spectra(Scene())
    twin = spectral_twin(mono, spectra)
    twin.set_radiance(np.full(mono.n_vertices, L0))
    first = twin.render(16, 9)
    assert mi.variant() == SPECTRAL_VARIANT and first.shape == (32, 32, 3)
    after = mono.render(16, 5)
    assert mi.variant() == VARIANT
    assert np.array_equal(before, after)
    mono.set_radiance(np.full(mono.n_vertices, 2 * L0))  # the mono scene's parameters, in its variant
    assert mono.render(16, 5) == pytest.approx(2 * before, rel=1e-6)
    twin.set_radiance(np.full(mono.n_vertices, L0))  # and back: the twin's objects still work
    assert np.array_equal(twin.render(16, 9), first)
    # the pure function renders frame f with its own seed; a frame of a batch is the single frame
    e = np.full((2, mono.n_vertices), L0)
    e[1] *= 3
    both = spectral_reference(mono, e, spectra, spp=16, seed=4)
    one = spectral_reference(mono, e[0], spectra, spp=16, seed=4)
    assert both.shape == (2, 32, 32, 3) and np.array_equal(both[0], one)
    assert twin.options == mono.options and twin.variant == SPECTRAL_VARIANT and mono.variant == VARIANT


# ----------------------------------------------------------------------------- comparison table
def test_comparison_reports_known_differences():
    rng = np.random.default_rng(0)
    B, F, H, W = 3, 2, 20, 20
    ref = rng.random((B, F, H, W, 3)) + 1.0
    gain = np.array([1.01, 0.98, 1.0])
    centres = np.array([[5.0, 5.0], [14.0, 14.0]])
    out = compare_to_shortcut(ref, ref * gain, centres, 3.0)
    assert out["total_diff_pct"] == pytest.approx([1.0, -2.0, 0.0], abs=1e-9)
    assert out["rod_median_abs_diff_pct"] == pytest.approx([1.0, 2.0, 0.0], abs=1e-9)
    assert out["rod_max_abs_diff_pct"] == pytest.approx([1.0, 2.0, 0.0], abs=1e-9)
    assert out["rod_frames"] == [F * 2] * 3
    assert np.allclose(out["frame_total_diff_pct"], [[1.0, -2.0, 0.0]] * F)
    # standard error: batches of the reference 0.9, 1.0, 1.1 times a noiseless shortcut -> 0.1 / sqrt(3)
    flat = np.ones((B, F, H, W, 3))
    spread = compare_to_shortcut(flat * np.array([0.9, 1.0, 1.1])[:, None, None, None, None], flat, centres, 3.0)
    assert spread["total_diff_pct"] == pytest.approx([0.0] * 3, abs=1e-9)
    assert spread["total_se_pct"] == pytest.approx([100 * 0.1 / np.sqrt(3)] * 3, rel=1e-9)
    assert spread["rod_median_se_pct"] == pytest.approx([100 * 0.1 / np.sqrt(3)] * 3, rel=1e-9)
    # one batch: no error estimate
    assert np.isnan(compare_to_shortcut(ref[:1], ref[:1], centres, 3.0)["total_se_pct"]).all()
    # a dim rod (below min_share of the brightest in its frame) is not counted
    dim = ref.copy()
    dim[:, :, :, :, :] *= np.where(np.hypot(*np.mgrid[0:H, 0:W] - 5.0) <= 3.0, 0.01, 1.0)[None, None, :, :, None]
    assert compare_to_shortcut(dim, dim * gain, centres, 3.0)["rod_frames"] == [F] * 3
    # the shortcut's images: mono times the factors
    mono = rng.random((F, H, W))
    assert np.allclose(shortcut_images(mono, [1.0, 2.0, 3.0])[..., 2], 3 * mono)


# ------------------------------------------------------------------------------------ bad input
def test_bad_input_names_the_field_and_the_fix():
    wl = sp.wavelengths_nm()
    s = np.asarray(sp.zns_cu_emission_sd().values, dtype=float)
    q = np.full((3, len(wl)), 0.5)
    with pytest.raises(ValueError, match=r"emission_per_nm of shape \(500,\): must be \(501,\)"):
        RenderSpectra(wl, s[:-1], q)
    with pytest.raises(ValueError, match="emission_per_nm integrates to 2.*divide it by its trapezoid integral"):
        RenderSpectra(wl, 2 * s, q)
    with pytest.raises(ValueError, match="emission_per_nm has NaN"):
        RenderSpectra(wl, np.where(wl == 500, np.nan, s), q)
    with pytest.raises(ValueError, match="emission_per_nm has negative"):
        RenderSpectra(wl, s - 1e-4 * (wl == 400), q)
    with pytest.raises(ValueError, match=r"sensitivity of shape \(2, 501\): must be \(3, 501\)"):
        RenderSpectra(wl, s, q[:2])
    with pytest.raises(ValueError, match="sensitivity spans .* not percent"):
        RenderSpectra(wl, s, 100 * q)
    with pytest.raises(ValueError, match="channel b is zero everywhere"):
        RenderSpectra(wl, s, q * np.array([[1], [1], [0]]))
    with pytest.raises(ValueError, match="wavelengths_nm .* regular increasing grid"):
        RenderSpectra(np.r_[wl[:-1], wl[-1] + 3], s, q)
    with pytest.raises(ValueError, match="channels .* distinct"):
        RenderSpectra(wl, s, q, ("g", "g", "b"))
    good = RenderSpectra(wl, s, q)
    with pytest.raises(ValueError, match="read-only"):
        good.sensitivity[0, 0] = 1.0  # the spectra are frozen
    V, F = _flat_sheet(n=2)
    with pytest.raises(TypeError, match="spectra is a dict: must be a mlsim.render.spectral.RenderSpectra"):
        SensorScene(V, F, _view(16), spectra={"emission": s})
    mono = SensorScene(V, F, _view(16), base_half_size_m=0.02)
    with pytest.raises(ValueError, match=r"vertex_radiance of shape \(2, 3\)"):
        spectral_reference(mono, np.ones((2, 3)), good, spp=4, seed=0)
    with pytest.raises(ValueError, match="finite"):
        spectral_reference(mono, np.full(len(V), np.nan), good, spp=4, seed=0)
    with pytest.raises(ValueError, match="must both be"):
        compare_to_shortcut(np.ones((1, 1, 4, 4, 3)), np.ones((1, 1, 4, 4, 2)), [[1.0, 1.0]], 1.0)
    with pytest.raises(ValueError, match="choose one of"):
        use_variant("scalar_rgb")
