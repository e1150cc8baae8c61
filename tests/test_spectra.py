"""Tests of mlsim.spectra: emission band, absorbers, lamps, clear parts, camera QE, channel factors."""

from __future__ import annotations

import os
import struct
import subprocess
import sys
from pathlib import Path

import colour
import numpy as np
import pytest
from scipy import constants
from scipy.integrate import trapezoid

from mlsim import spectra as S

WL = S.wavelengths_nm()


def _fwhm_on_curve(wl, v):
    """Full width at half maximum measured on sampled values (linear interpolation at the crossings)."""
    half = v.max() / 2.0
    above = np.where(v >= half)[0]
    a, b = above[0], above[-1]
    lo = np.interp(half, [v[a - 1], v[a]], [wl[a - 1], wl[a]])
    hi = np.interp(half, [v[b + 1], v[b]], [wl[b + 1], wl[b]])
    return hi - lo


def _narrow_band(centre_nm, sigma_nm=0.3):
    v = np.exp(-0.5 * ((WL - centre_nm) / sigma_nm) ** 2)
    return colour.SpectralDistribution(v, WL, name="narrow")


# ---------------------------------------------------------------- emission


@pytest.mark.parametrize("peak_nm, fwhm_nm", [(512.0, 80.0), (450.0, 30.0), (600.0, 100.0)])
def test_emission_peak_fwhm_and_photon_normalisation(peak_nm, fwhm_nm):
    sd = S.zns_cu_emission_sd(peak_nm, fwhm_nm)
    v = np.asarray(sd.values)
    i = int(np.argmax(v))
    # parabolic refinement of the grid maximum
    d = 0.5 * (v[i - 1] - v[i + 1]) / (v[i - 1] - 2 * v[i] + v[i + 1])
    assert abs(WL[i] + d - peak_nm) < 0.5
    assert _fwhm_on_curve(WL, v) == pytest.approx(fwhm_nm, rel=0.01)
    assert trapezoid(v, WL) == pytest.approx(1.0, abs=1e-6)


def test_emission_defaults_are_spec_peak_and_documented_width():
    sd = S.zns_cu_emission_sd()
    assert WL[np.argmax(sd.values)] == 512.0
    assert S.ZNS_CU_PEAK_NM == 512.0 and S.ZNS_CU_FWHM_NM == 80.0


def test_emission_is_gaussian_in_photon_energy():
    # the density per eV, s(lambda) lambda^2 / (h c), must be a parabola in log against energy
    sd = S.zns_cu_emission_sd()
    v = np.asarray(sd.values)
    e_ev = constants.h * constants.c / constants.e / (WL * 1e-9)
    per_ev = v * WL**2
    keep = per_ev > 0.05 * per_ev.max()
    coef = np.polyfit(e_ev[keep], np.log(per_ev[keep]), 2)
    fitted = np.polyval(coef, e_ev[keep])
    assert np.max(np.abs(fitted - np.log(per_ev[keep]))) < 1e-9
    # and the wavelength curve is not symmetric: the red half is wider than the blue half
    half = v.max() / 2
    above = WL[v >= half]
    assert (above[-1] - 512.0) > (512.0 - above[0])


@pytest.mark.parametrize("kwargs", [{"fwhm_nm": 0.0}, {"fwhm_nm": -5.0}, {"peak_nm": 900.0}, {"peak_nm": float("nan")}])
def test_emission_bad_input_raises(kwargs):
    with pytest.raises(ValueError):
        S.zns_cu_emission_sd(**kwargs)


# ---------------------------------------------------------------- absorbers


def test_default_absorber_levels():
    t = S.absorber_transmittance_sd()
    assert t.name.startswith("absorber black_silicone_pigment")
    v = np.asarray(t.values)
    outside = ((WL >= 400) & (WL <= 491)) | ((WL >= 578) & (WL <= 850))
    window = (WL >= 492) & (WL <= 577)
    np.testing.assert_allclose(v[outside], 1e-3, rtol=0, atol=0)
    assert np.all(v[window] < 1e-3)
    np.testing.assert_allclose(v[window], 2e-4)
    np.testing.assert_array_equal(S.absorber_transmittance_sd("none").values, np.ones_like(WL))


@pytest.mark.parametrize("name", [n for n in S.ABSORBERS if n != "none"])
def test_every_absorber_blocks_at_least_99_percent_in_the_visible(name):
    v = np.asarray(S.absorber_transmittance_sd(name).values)
    vis = (WL >= 400) & (WL <= 600)
    assert np.all(v[vis] <= 1.1e-2) and np.all(v > 0)


def test_unknown_absorber_lists_names():
    with pytest.raises(ValueError) as err:
        S.absorber_transmittance_sd("soot")
    msg = str(err.value)
    assert '"soot" is not an absorber' in msg
    for name in S.ABSORBERS:
        assert name in msg


def test_beer_lambert_identities():
    t = np.array([1.0, 0.5, 1e-3, 0.0])
    np.testing.assert_array_equal(S.beer_lambert_scale(t, 1.0), t)
    np.testing.assert_allclose(S.beer_lambert_scale(t, 2.0), t**2, rtol=1e-15)
    np.testing.assert_array_equal(S.beer_lambert_scale(t[:3], 0.0), 1.0)
    assert S.beer_lambert_scale(0.25, 0.5) == pytest.approx(0.5, rel=1e-15)
    # a layer twice the reference 0.3 mm is the square of the reference
    thick = S.absorber_transmittance_sd(thickness_mm=2 * S.ABSORBER_REFERENCE_THICKNESS_MM)
    np.testing.assert_allclose(thick.values, S.absorber_transmittance_sd().values ** 2, rtol=1e-12)
    sd = S.beer_lambert_scale(S.absorber_transmittance_sd(), 3.0)
    assert isinstance(sd, colour.SpectralDistribution) and sd[600] == pytest.approx(1e-9, rel=1e-9)
    with pytest.raises(ValueError):
        S.beer_lambert_scale(1.2, 1.0)
    with pytest.raises(ValueError):
        S.beer_lambert_scale(0.5, -1.0)


# ---------------------------------------------------------------- lamps


@pytest.mark.parametrize("name", list(S.LAMPS))
def test_lamps_integrate_to_one_watt(name):
    sd = S.lamp_sd(name)
    assert sd.shape == S.SPECTRAL_SHAPE
    assert trapezoid(sd.values, WL) == pytest.approx(1.0, rel=1e-12)
    assert np.all(np.asarray(sd.values) >= 0)


def test_daylight_lamp_has_the_mercury_green_line():
    v = S.lamp_sd("daylight")
    assert v[545] > 2 * v[530]  # FL1's 546 nm Hg line (in the 545 nm bin) stands above the continuum


def test_unknown_lamp_lists_names():
    with pytest.raises(ValueError, match="daylight, white_led"):
        S.lamp_sd("sun")


def test_photon_sd_of_narrow_band_at_500_nm():
    band = _narrow_band(500.0)
    watt = colour.SpectralDistribution(band.values / trapezoid(band.values, WL), WL)
    n = trapezoid(S.photon_sd(watt).values, WL)
    assert n == pytest.approx(500e-9 / (constants.h * constants.c), rel=1e-6)


# ---------------------------------------------------------------- clear parts


def test_acrylic_transmittance():
    assert S.pmma_refractive_index(587.6) == pytest.approx(1.491, abs=1e-3)
    t = S.acrylic_transmittance_sd(3.0)
    assert t[550] == pytest.approx(0.924, abs=0.005)  # two Fresnel faces: the catalogue's 92 %
    assert t[360] < 0.9 * t[550] and t.values[0] < t[380] < t[400]  # UV edge
    internal = S.acrylic_transmittance_sd(3.0, fresnel_surfaces=0)
    assert 0.99 < internal[550] < 1.0
    # absorption scales with thickness (Beer-Lambert on the internal part)
    np.testing.assert_allclose(
        S.acrylic_transmittance_sd(6.0, fresnel_surfaces=0).values, internal.values**2, rtol=1e-12
    )
    with pytest.raises(ValueError):
        S.acrylic_transmittance_sd(3.0, fresnel_surfaces=3)
    with pytest.raises(ValueError):
        S.acrylic_transmittance_sd(-1.0)


def test_elastomer_transmittance():
    assert S.elastomer_transmittance_sd(0.0)[500] == 1.0
    t10 = S.elastomer_transmittance_sd(10.0)
    assert 0.9 < t10[550] < 1.0
    np.testing.assert_allclose(S.elastomer_transmittance_sd(20.0).values, t10.values**2, rtol=1e-12)
    assert 0.9 < S.elastomer_transmittance_sd(3.0, fresnel_surfaces=2)[550] < 0.95


# ---------------------------------------------------------------- camera


def test_default_camera_green_peak_and_qe_scale():
    cam = S.camera_sensitivity_msds()
    q = np.asarray(cam.values)
    assert q.shape == (len(WL), 3)
    assert 500 <= WL[np.argmax(q[:, 1])] <= 570
    assert WL[np.argmax(q[:, 0])] > WL[np.argmax(q[:, 1])] > WL[np.argmax(q[:, 2])]
    np.testing.assert_allclose(q.max(axis=0), [S.CAMERA_PEAK_QE[c] for c in S.CHANNELS])
    assert np.all(q >= 0) and np.all(q[WL > 790] == 0)  # zero outside the NPL data (380-780 nm)


def test_camera_csv_round_trip(tmp_path):
    wl = np.arange(400.0, 701.0, 10.0)
    qe = np.stack([np.linspace(0.1, 0.6, wl.size), np.full(wl.size, 0.5), np.linspace(0.7, 0.0, wl.size)], axis=1)
    path = tmp_path / "cam.csv"
    lines = ["Wavelength_nm, R, G, B"] + [f"{w},{r},{g},{b}" for w, (r, g, b) in zip(wl, qe)]
    path.write_text("\n".join(lines) + "\n")
    raw = S.read_camera_sensitivity_csv(path)
    np.testing.assert_array_equal(raw.wavelengths, wl)
    np.testing.assert_allclose(raw.values, qe, rtol=1e-15)
    on_grid = S.camera_sensitivity_msds(str(path))
    np.testing.assert_allclose(on_grid[555], [np.interp(555.0, wl, qe[:, k]) for k in range(3)], rtol=1e-12)
    assert np.all(on_grid[[360, 399, 701, 860]] == 0)  # zero outside the file's range


@pytest.mark.parametrize(
    "text, message",
    [
        ("wavelength_nm,r,g\n400,0.1,0.2\n410,0.1,0.2\n", "missing column(s) b"),
        ("wavelength_nm,r,g,b\n400,0.1,0.2,0.3\n390,0.1,0.2,0.3\n", "must increase strictly"),
        ("wavelength_nm,r,g,b\n400,0.1,0.2,0.3\n400,0.1,0.2,0.3\n", "must increase strictly"),
        ("wavelength_nm,r,g,b\n400,0.1,20,0.3\n410,0.1,0.2,0.3\n", "column g = 20 at 400 nm: QE must be within [0, 1]"),
        ("wavelength_nm,r,g,b\n400,0.1,0.2,-0.1\n410,0.1,0.2,0.3\n", "column b = -0.1"),
        ("wavelength_nm,r,g,b\n400,0.1,x,0.3\n410,0.1,0.2,0.3\n", "column g = 'x': not a number"),
        ("", "empty"),
    ],
)
def test_bad_camera_csv_raises_with_clear_message(tmp_path, text, message):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(ValueError) as err:
        S.camera_sensitivity_msds(path)
    assert message in str(err.value)


def test_unknown_camera_lists_names_and_missing_file_is_reported(tmp_path):
    with pytest.raises(ValueError, match=r'"imx999" is not a camera; choose one of: imx415_like'):
        S.camera_sensitivity_msds("imx999")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        S.camera_sensitivity_msds(tmp_path / "nope.csv")


# ---------------------------------------------------------------- channel factors


def test_zns_cu_is_brightest_in_green():
    k = S.channel_factors(S.zns_cu_emission_sd())
    assert k.shape == (3,)
    assert k[1] > k[0] and k[1] > k[2]
    assert 0 < k.max() < max(S.CAMERA_PEAK_QE.values())


def test_channel_factors_are_linear_in_a_flat_transmittance():
    e = S.zns_cu_emission_sd()
    k0 = S.channel_factors(e)
    for t in (0.37, 1e-3):
        flat = colour.SpectralDistribution(np.full(WL.size, t), WL)
        np.testing.assert_allclose(S.channel_factors(e, [flat]), t * k0, rtol=1e-13)
    # scaling the emission does not change the factors (normalised inside)
    scaled = colour.SpectralDistribution(np.asarray(e.values) * 3.7e12, WL)
    np.testing.assert_allclose(S.channel_factors(scaled), k0, rtol=1e-13)


def test_default_absorber_drop_reflects_the_dark_window():
    e = S.zns_cu_emission_sd()
    ratio = S.channel_factors(e, [S.absorber_transmittance_sd()]) / S.channel_factors(e)
    assert np.all((ratio > 1e-4) & (ratio < 1e-3))
    # green sits in the 492-577 nm window, so it drops most
    assert ratio[1] < ratio[0] and ratio[1] < ratio[2]


@pytest.mark.parametrize("centre_nm", [550.0, 460.0, 610.0])
def test_narrow_emission_recovers_qe(centre_nm):
    cam = S.camera_sensitivity_msds()
    k = S.channel_factors(_narrow_band(centre_nm), [], cam)
    np.testing.assert_allclose(k, cam[centre_nm], rtol=0.01)


def test_channel_factors_power_is_photon_weighted():
    lamp = S.lamp_sd("white_led")
    k_power = S.channel_factors_power(lamp)
    photons = S.photon_sd(lamp)
    photons_per_joule = trapezoid(photons.values, WL)
    np.testing.assert_allclose(k_power, S.channel_factors(photons) * photons_per_joule, rtol=1e-12)
    # a narrow band at 550 nm: electrons per joule = QE(550) * 550 nm / (h c)
    k = S.channel_factors_power(_narrow_band(550.0))
    cam = S.camera_sensitivity_msds()
    np.testing.assert_allclose(k, cam[550.0] * 550e-9 / (constants.h * constants.c), rtol=0.01)


@pytest.mark.filterwarnings("ignore:.*not finite:colour.utilities.ColourRuntimeWarning")
def test_channel_factors_reject_bad_input():
    e = S.zns_cu_emission_sd()
    with pytest.raises(ValueError, match="outside"):
        S.channel_factors(e, [colour.SpectralDistribution(np.full(WL.size, 1.5), WL)])
    with pytest.raises(ValueError, match="NaN"):
        S.channel_factors(colour.SpectralDistribution(np.full(WL.size, np.nan), WL))
    with pytest.raises(ValueError, match="integrates to"):
        S.channel_factors(colour.SpectralDistribution(np.zeros(WL.size), WL))
    with pytest.raises(TypeError):
        S.channel_factors(e, [], camera_msds=np.ones((WL.size, 3)))
    # a single transmittance is accepted without a list
    t = S.absorber_transmittance_sd()
    np.testing.assert_array_equal(S.channel_factors(e, t), S.channel_factors(e, [t]))


def test_align_to_grid_is_linear_with_zero_outside():
    wl = np.arange(400.0, 701.0, 5.0)
    v = np.sin(wl / 40.0) ** 2 + 0.1
    sd = colour.SpectralDistribution(v, wl)
    out = S.align_to_grid(sd)
    assert out.shape == S.SPECTRAL_SHAPE
    np.testing.assert_allclose(out.values, np.interp(WL, wl, v, left=0.0, right=0.0), rtol=1e-12, atol=1e-15)
    np.testing.assert_array_equal(sd.values, v)  # input untouched


# ---------------------------------------------------------------- plot


def test_plot_spectra_writes_png(tmp_path):
    path = S.plot_spectra(tmp_path / "sub" / "spectra.png")
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    width, height = struct.unpack(">II", data[16:24])
    assert (width, height) == (880, 990)  # 8 x 9 in at 110 dpi
    assert [p.name for p in path.parent.iterdir()] == ["spectra.png"]  # no temporary left behind


# ---------------------------------------------------------------- import


def test_colour_imported_without_its_plotting_package():
    """A fresh process that imports mlsim.spectra has colour but not matplotlib (colour.plotting would
    import it: 1.7 s of a dataset worker's first episode); colour.plotting loads on first use, and is
    then the package itself, whichever way it is reached."""
    code = ("import sys; import mlsim.spectra, colour; print('matplotlib' in sys.modules); "
            "f = colour.plotting.plot_single_sd; import colour.plotting as p; from colour.plotting import plot_single_sd; "
            "print('matplotlib' in sys.modules, p is colour.plotting is sys.modules['colour.plotting'], p.plot_single_sd is f is plot_single_sd, "
            "p.__file__.endswith('__init__.py'))")
    root = Path(__file__).resolve().parents[1]
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(root), os.environ.get("PYTHONPATH", "")])}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, env=env, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["False", "True", "True", "True", "True"]
