"""Spectra of the sensor's light path: ML emission, absorbers, lamps, clear parts and the camera.

The renderer works in mono/RGB and applies spectra analytically. This module gives, per camera
channel, the factor that turns a photon rate emitted with a given spectrum into an electron rate
after the transmittances in the path (:func:`channel_factors`), and the same per joule for lamps
(:func:`channel_factors_power`):

    k_c = integral s(lambda) prod_i T_i(lambda) QE_c(lambda) d lambda,   c in (R, G, B),

with s the photon spectral density normalised to integrate to 1 (1/nm), T_i transmittances and
QE_c the quantum efficiency of channel c (electrons per photon incident on the pixel).

Conventions
-----------
- Every spectrum is a ``colour.SpectralDistribution`` (or ``MultiSpectralDistributions`` for the
  camera) on one grid, :data:`SPECTRAL_SHAPE` (360-860 nm at 1 nm). The wavelength domain is in nm
  because that is colour-science's convention; spectral densities are per nm. Conversions to SI
  (photon energy, photons per joule) happen inside, with ``scipy.constants``.
- Alignment (:func:`align_to_grid`): colour's ``align`` with its ``LinearInterpolator`` and
  ``Extrapolator`` (constant 0 outside the data's wavelength range); every spectrum this module
  returns also looks up (``sd[wavelength]``) with that rule. Linear, not colour's default
  Sprague/cubic: it never overshoots (transmittances and QE stay in [0, 1], lamp lines never ring negative) and on
  a refined grid it keeps the trapezoid integral of the coarse data. Zero outside the data: a
  spectrum says nothing where it was not measured, and a camera or lamp with no data there is
  taken not to respond or emit; a transmittance known only on part of the grid therefore blocks
  the rest (give it over the whole grid if that is not what you mean).
- One integration rule everywhere: the trapezoid rule on the grid (``scipy.integrate.trapezoid``).
- Registries (:data:`ABSORBERS`, :data:`LAMPS`, :data:`CAMERA_SENSITIVITIES`) with validating
  dispatchers whose error lists the valid names.

Defaults and where they come from (SPEC = /work/shared/SPEC.md)
---------------------------------------------------------------
- ZnS:Cu emission peak 512 nm: SPEC 1.1. Band FWHM 80 nm: not given (see
  :func:`zns_cu_emission_sd`); an assumption.
- Absorber: 99.9 % blocked from 400 to 850 nm, best from 492 to 577 nm: SPEC 1.3; the level in the
  best window (99.98 %), the values outside 400-850 nm and the alternatives' curves are
  assumptions (:data:`ABSORBERS`). Absorber thickness 0.3 mm: SPEC 1.1.
- Lamps: CIE FL1 (daylight fluorescent) and CIE LED-B4 (phosphor-converted white LED), from
  colour's datasets (CIE 15:2004 tables; CIE 015:2018).
- Acrylic: n(lambda) of Sultanova et al. (2009); 92 % and the UV edge from the ACRYLITE
  (Roehm) knowledge base. Silicone: typical values, assumptions (see the functions).
- Camera: NPL-measured Nikon 5100 relative sensitivities (Darrodi et al. 2015, shipped with
  colour) rescaled to assumed IMX415-class peak QE (:data:`CAMERA_PEAK_QE`).
"""

from __future__ import annotations

import csv
import importlib
import math
import os
import sys
import tempfile
import types
from pathlib import Path
from types import MappingProxyType
from typing import Callable, Iterable, Mapping


class _DeferredColourPlotting(types.ModuleType):
    """Stands in for ``colour.plotting`` until one of its names is read; then imports the package
    (and matplotlib) and answers from it, and ``colour.plotting`` is the package from then on."""

    def __getattr__(self, name: str):
        if name.startswith("__") and name != "__all__":  # the import system's probes (__path__, __file__) load nothing
            raise AttributeError(name)
        if sys.modules.get("colour.plotting") is self:
            del sys.modules["colour.plotting"]
        return getattr(importlib.import_module("colour.plotting"), name)


def _defer_colour_plotting() -> None:
    """colour-science's ``__init__`` imports ``colour.plotting`` and with it matplotlib, and has no
    setting to skip it: in a fresh dataset worker 1.7 s of its first episode's 5.2 s (cProfile, 2
    shared cores), for plots that mlsim draws with matplotlib itself. With the stand-in registered
    before colour is imported, ``colour.plotting`` loads on the first read of one of its names
    (``colour.plotting.plot_single_sd`` works as before) and a worker never imports matplotlib.
    Nothing is done where colour is already imported."""
    if "colour" in sys.modules or "colour.plotting" in sys.modules:
        return
    stub = _DeferredColourPlotting("colour.plotting")
    stub.__spec__ = None  # (the import system reads a listed module's __spec__; None is "loaded")
    sys.modules["colour.plotting"] = stub


_defer_colour_plotting()

import colour  # noqa: E402  (after _defer_colour_plotting)
import numpy as np  # noqa: E402
from colour.characterisation import MSDS_CAMERA_SENSITIVITIES  # noqa: E402
from scipy import constants  # noqa: E402
from scipy.integrate import trapezoid  # noqa: E402
from scipy.optimize import brentq  # noqa: E402

__all__ = [
    "SPECTRAL_SHAPE",
    "CHANNELS",
    "ZNS_CU_PEAK_NM",
    "ZNS_CU_FWHM_NM",
    "ABSORBER_REFERENCE_THICKNESS_MM",
    "CAMERA_PEAK_QE",
    "ABSORBERS",
    "LAMPS",
    "CAMERA_SENSITIVITIES",
    "wavelengths_nm",
    "align_to_grid",
    "photon_band_sd",
    "zns_cu_emission_sd",
    "beer_lambert_scale",
    "absorber_transmittance_sd",
    "lamp_sd",
    "photon_sd",
    "pmma_refractive_index",
    "acrylic_transmittance_sd",
    "elastomer_transmittance_sd",
    "read_camera_sensitivity_csv",
    "camera_sensitivity_msds",
    "channel_factors",
    "channel_factors_power",
    "plot_spectra",
]

# The common grid of every spectrum: 360-860 nm covers the camera's response (the NPL data stop at
# 780 nm, the IR-cut filter earlier), the absorber's specified 400-850 nm and the ZnS:Cu band's tails.
SPECTRAL_SHAPE = colour.SpectralShape(360, 860, 1)

CHANNELS = ("r", "g", "b")

ZNS_CU_PEAK_NM = 512.0  # SPEC 1.1
ZNS_CU_FWHM_NM = 80.0  # not given; assumption, see zns_cu_emission_sd

ABSORBER_REFERENCE_THICKNESS_MM = 0.3  # SPEC 1.1: light-absorbing layer "about 0.3 mm"

# Peak QE per channel of the default camera (assumption). Sony publishes only relative spectral
# response for the IMX415; back-illuminated STARVIS pixels behind a Bayer filter reach roughly
# 0.7-0.8 at the peak of each channel. Green 0.8, red and blue 0.7 (filters of R and B transmit less).
CAMERA_PEAK_QE = MappingProxyType({"r": 0.70, "g": 0.80, "b": 0.70})

_HC_EV_NM = constants.h * constants.c / constants.e * 1e9  # photon energy [eV] times wavelength [nm]
_FWHM_PER_SIGMA = 2.0 * math.sqrt(2.0 * math.log(2.0))


# --------------------------------------------------------------------------------------------
# grid and alignment


def wavelengths_nm(shape: colour.SpectralShape = SPECTRAL_SHAPE) -> np.ndarray:
    """Wavelengths of a spectral shape, (N,) float, nm."""
    return np.asarray(shape.wavelengths, dtype=float)


_ZERO_OUTSIDE = {"method": "Constant", "left": 0.0, "right": 0.0}


def _linear_zero_outside(signal):
    """Set colour's LinearInterpolator and a constant-zero Extrapolator on an SD or MSDS, in place."""
    signal.interpolator = colour.LinearInterpolator
    signal.interpolator_kwargs = {}
    signal.extrapolator = colour.Extrapolator
    signal.extrapolator_kwargs = dict(_ZERO_OUTSIDE)
    return signal


def _new_sd(values, wavelengths, name: str) -> colour.SpectralDistribution:
    """An SD whose look-ups (sd[wavelength]) follow the module's rule: linear inside, 0 outside.
    (colour's default, Sprague, leaves round-off of either sign even at the nodes.)"""
    return _linear_zero_outside(colour.SpectralDistribution(values, wavelengths, name=name))


def _new_msds(values, wavelengths, labels, name: str) -> colour.MultiSpectralDistributions:
    """The MultiSpectralDistributions counterpart of :func:`_new_sd`."""
    return _linear_zero_outside(colour.MultiSpectralDistributions(values, wavelengths, labels=labels, name=name))


def align_to_grid(sd, shape: colour.SpectralShape = SPECTRAL_SHAPE):
    """A copy of ``sd`` (SpectralDistribution or MultiSpectralDistributions) on ``shape``.

    Linear interpolation inside the data's wavelength range, zero outside (see the module notes for
    why). The input is not modified.
    """
    if not isinstance(sd, (colour.SpectralDistribution, colour.MultiSpectralDistributions)):
        raise TypeError(
            f"expected a colour.SpectralDistribution or MultiSpectralDistributions, got {type(sd).__name__}"
        )
    out = sd.copy()
    out.align(
        shape,
        interpolator=colour.LinearInterpolator,
        extrapolator=colour.Extrapolator,
        extrapolator_kwargs=dict(_ZERO_OUTSIDE),
    )
    # align leaves an MSDS's look-up interpolator at Sprague, whose out[wavelength] gives round-off
    # of either sign (about 1e-16) where the value is exactly 0; a negative QE is wrong.
    return _linear_zero_outside(out)


def _values_on_grid(sd, shape: colour.SpectralShape, what: str) -> np.ndarray:
    values = np.asarray(align_to_grid(sd, shape).values, dtype=float)
    if not np.all(np.isfinite(values)):
        raise ValueError(f"{what} has NaN or infinite values; give finite values")
    return values


def _check_positive(name: str, value: float, allow_zero: bool = False) -> float:
    value = float(value)
    ok = math.isfinite(value) and (value >= 0.0 if allow_zero else value > 0.0)
    if not ok:
        raise ValueError(f"{name} = {value!r}: must be a finite number {'>= 0' if allow_zero else '> 0'}")
    return value


# --------------------------------------------------------------------------------------------
# emission


def _band_log_shape(wavelength_nm, centre_ev: float, sigma_ev: float):
    """ln of a photon density per nm whose density per eV is Gaussian (centre_ev, sigma_ev)."""
    energy_ev = _HC_EV_NM / wavelength_nm
    # density per nm = density per eV * |dE/dlambda| = g(E) * E / lambda
    return -0.5 * ((energy_ev - centre_ev) / sigma_ev) ** 2 + np.log(energy_ev / wavelength_nm)


def _energy_gaussian_for(peak_nm: float, fwhm_nm: float) -> tuple[float, float]:
    """(centre_ev, sigma_ev) of the energy Gaussian whose per-nm photon density peaks at peak_nm
    and has the full width at half maximum fwhm_nm (both measured on the per-nm curve)."""
    peak_ev = _HC_EV_NM / peak_nm

    def centre(sigma):
        # d/dlambda of ln[g(E) E / lambda] = 0 at E_p  <=>  (E_p - E_0) E_p = 2 sigma^2
        return peak_ev - 2.0 * sigma**2 / peak_ev

    def width(sigma):
        e0 = centre(sigma)
        top = _band_log_shape(peak_nm, e0, sigma)

        def f(lam):
            return _band_log_shape(lam, e0, sigma) - top + math.log(2.0)

        lo = brentq(f, peak_nm / 4.0, peak_nm)
        hi = brentq(f, peak_nm, peak_nm * 20.0)
        return hi - lo

    sigma0 = _HC_EV_NM / peak_nm**2 * fwhm_nm / _FWHM_PER_SIGMA
    a, b = 0.5 * sigma0, 2.0 * sigma0
    sigma = brentq(lambda s: width(s) - fwhm_nm, a, b, xtol=1e-14, rtol=1e-13)
    return centre(sigma), sigma


def photon_band_sd(
    peak_nm: float, fwhm_nm: float, shape: colour.SpectralShape = SPECTRAL_SHAPE, name: str | None = None
) -> colour.SpectralDistribution:
    """A luminescence band: photon spectral density Gaussian in photon energy, normalised to 1.

    Parameters
    ----------
    peak_nm : float
        Wavelength of the maximum of the photon spectral density per nm.
    fwhm_nm : float
        Full width at half maximum of that density, in nm (the asymmetry of the energy Gaussian
        seen in wavelength is accounted for: both numbers hold on the per-nm curve).
    shape : colour.SpectralShape
        Grid; the normalisation is on this grid.

    Returns
    -------
    colour.SpectralDistribution
        s(lambda) in 1/nm with trapezoid integral over the grid equal to 1.

    Notes
    -----
    The band of a donor/trap-to-acceptor recombination is broadened by phonon coupling in photon
    *energy* (configuration-coordinate model: a Gaussian in E), so the density per eV is
    g(E) ~ exp(-(E - E0)^2 / (2 sigma^2)) and the density per nm is g(E(lambda)) h c / lambda^2
    (Henderson B. and Imbusch G. F., Optical Spectroscopy of Inorganic Solids, Oxford University
    Press, 1989). E0 and sigma are solved so that the per-nm curve has the requested peak and FWHM.
    """
    peak_nm = _check_positive("peak_nm", peak_nm)
    fwhm_nm = _check_positive("fwhm_nm", fwhm_nm)
    wl = wavelengths_nm(shape)
    if not (wl[0] < peak_nm < wl[-1]):
        raise ValueError(f"peak_nm = {peak_nm}: must lie inside the grid ({wl[0]:g}-{wl[-1]:g} nm)")
    if fwhm_nm > 0.5 * peak_nm:
        raise ValueError(f"fwhm_nm = {fwhm_nm}: must be < peak_nm / 2 for a single luminescence band")
    centre_ev, sigma_ev = _energy_gaussian_for(peak_nm, fwhm_nm)
    log_s = _band_log_shape(wl, centre_ev, sigma_ev)
    s = np.exp(log_s - log_s.max())
    total = trapezoid(s, wl)
    if not total > 0:
        raise ValueError(
            f"band peak_nm = {peak_nm}, fwhm_nm = {fwhm_nm} is too narrow for the {shape.interval} nm grid; "
            "use a finer shape or a wider band"
        )
    return _new_sd(s / total, wl, name=name or f"band {peak_nm:g} nm / {fwhm_nm:g} nm FWHM")


def zns_cu_emission_sd(
    peak_nm: float = ZNS_CU_PEAK_NM, fwhm_nm: float = ZNS_CU_FWHM_NM, shape: colour.SpectralShape = SPECTRAL_SHAPE
) -> colour.SpectralDistribution:
    """The green ZnS:Cu mechanoluminescence band as a normalised photon spectral density (1/nm).

    Parameters
    ----------
    peak_nm : float
        Peak of the photon density per nm. Default 512 nm (SPEC 1.1).
    fwhm_nm : float
        Full width at half maximum, nm. Default 80 nm: **not given** by the sensor's publication,
        and no source consulted states a number for ZnS:Cu mechanoluminescence in silicone. The
        green Cu band of ZnS is broad and sits next to blue Cu and self-activated bands (ZnS:Cu,Cl
        electroluminescence: Nien Y. T., Chen I. G., "Raman scattering and electroluminescence of
        ZnS:Cu,Cl phosphor powder", Applied Physics Letters 89, 261906, 2006), and ML of ZnS:Cu in
        PDMS shows one broad green band (Jeong S. M., Song S., Lee S.-K., Choi B., "Mechanically
        driven light-generator with high durability", Applied Physics Letters 102, 2013,
        doi:10.1063/1.4791689). 80 nm (0.38 eV at 512 nm) is chosen as a typical width of such a
        band; an assumption to replace with a measured spectrum when one exists.
    shape : colour.SpectralShape
        Grid; default :data:`SPECTRAL_SHAPE`.

    Returns
    -------
    colour.SpectralDistribution
        s(lambda) in 1/nm, trapezoid integral 1: multiply by a photon rate to get photons/s/nm.

    Notes
    -----
    Gaussian in photon energy (see :func:`photon_band_sd`): the green emission is a recombination
    of an electron from a shallow donor/trap level with a Cu acceptor (Bol A. A. et al.,
    "Luminescence of nanocrystalline ZnS:Cu2+", Journal of Luminescence 99, 325-334, 2002), whose
    width comes from phonon broadening in energy.
    """
    return photon_band_sd(peak_nm, fwhm_nm, shape, name="ZnS:Cu emission (photons, 1/nm)")


# --------------------------------------------------------------------------------------------
# absorbers


def beer_lambert_scale(transmittance, thickness_ratio: float):
    """Transmittance of a layer ``thickness_ratio`` times as thick: T ** ratio (Beer-Lambert).

    Parameters
    ----------
    transmittance : float, array_like or colour.SpectralDistribution
        Internal transmittance of the reference layer, in [0, 1].
    thickness_ratio : float
        New thickness / reference thickness, >= 0.

    Returns
    -------
    Same kind as ``transmittance``.

    Notes
    -----
    T = exp(-alpha d) gives T(r d) = T(d) ** r. Exact for the internal (absorption) transmittance;
    applied to a measured total transmittance it also scales the surface reflections, which is
    negligible for a strong absorber (T ~ 1e-3) but not for a clear layer.
    """
    ratio = _check_positive("thickness_ratio", thickness_ratio, allow_zero=True)
    if isinstance(transmittance, colour.SpectralDistribution):
        out = transmittance.copy()
        out.values = beer_lambert_scale(transmittance.values, ratio)
        return out
    t = np.asarray(transmittance, dtype=float)
    if not np.all(np.isfinite(t)) or np.any(t < 0.0) or np.any(t > 1.0):
        raise ValueError("transmittance must be finite and within [0, 1]")
    out = t**ratio
    return float(out) if out.ndim == 0 else out


def _log_logistic(wl, low: float, high: float, centre_nm: float, width_nm: float):
    """A smooth step from ``low`` (short wavelengths) to ``high`` (long), linear in log10 T."""
    x = 1.0 / (1.0 + np.exp(-(wl - centre_nm) / width_nm))
    return 10.0 ** (np.log10(low) + (np.log10(high) - np.log10(low)) * x)


def _black_silicone_pigment(wl):
    """SC37 + 2 wt% black silicone pigment, 0.3 mm (the sensor's default, SPEC 1.3).

    T = 1e-3 (99.9 % blocked, SPEC 1.3) and 2e-4 in 492-577 nm, where the pigment "blocks best"
    (the value 2e-4 is an assumption: SPEC gives only the window). Outside 400-850 nm, where the
    published measurement stops, T = 1e-3 is kept (assumption: black silicone pigments are carbon
    blacks, whose absorption is broad and smooth through the near UV and near IR).
    """
    return np.where((wl >= 492.0) & (wl <= 577.0), 2e-4, 1e-3)


def _uv_opaque_colorant(wl):
    """A UV-opaque colorant in SC37, 0.3 mm. Assumption: T = 1e-5 in the UV rising to 1e-2 in the
    visible (log-logistic step at 410 nm, 8 nm wide); a UV blocker stops UV well but is only a tint
    in the visible, so it blocks ten times less there than the pigment the authors kept."""
    return _log_logistic(wl, 1e-5, 1e-2, 410.0, 8.0)


def _carbon_nanotube(wl):
    """Carbon nanotubes in SC37, 0.3 mm. Assumption: flat T = 1e-3; CNT absorption is broadband and
    featureless from the UV to the NIR, and the level equals the reference's 99.9 % so that a
    comparison isolates the spectral shape."""
    return np.full_like(wl, 1e-3)


def _water_based_ink(wl):
    """A black water-based ink coat. Assumption: T = 1e-2 in the visible rising to 0.3 in the NIR
    (log-logistic step at 720 nm, 25 nm wide); a thin ink film blocks less than a pigmented
    0.3 mm layer, and dye-based black inks turn transparent beyond about 700 nm."""
    return _log_logistic(wl, 1e-2, 0.3, 720.0, 25.0)


def _no_absorber(wl):
    """No absorbing layer (the calibration copy of the sensor, SPEC 1.1): T = 1."""
    return np.ones_like(wl)


# name -> T(wavelength_nm) of a layer of ABSORBER_REFERENCE_THICKNESS_MM
ABSORBERS: Mapping[str, Callable[[np.ndarray], np.ndarray]] = MappingProxyType(
    {
        "black_silicone_pigment": _black_silicone_pigment,
        "uv_opaque_colorant": _uv_opaque_colorant,
        "carbon_nanotubes": _carbon_nanotube,
        "water_based_ink": _water_based_ink,
        "none": _no_absorber,
    }
)


def _unknown(name, kind: str, valid: Iterable[str], extra: str = "") -> ValueError:
    return ValueError(f'"{name}" is not {kind}; choose one of: {", ".join(valid)}{extra}')


def absorber_transmittance_sd(
    name: str = "black_silicone_pigment",
    thickness_mm: float | None = None,
    shape: colour.SpectralShape = SPECTRAL_SHAPE,
) -> colour.SpectralDistribution:
    """Transmittance of the light-absorbing layer (registry :data:`ABSORBERS`).

    Parameters
    ----------
    name : str
        One of :data:`ABSORBERS`; default "black_silicone_pigment" (SPEC 1.3). The curves of the
        alternatives are assumptions, documented on each entry.
    thickness_mm : float, optional
        Layer thickness; the registry gives a 0.3 mm layer (SPEC 1.1) and other thicknesses follow
        :func:`beer_lambert_scale`. None: 0.3 mm.
    shape : colour.SpectralShape
        Grid.

    Returns
    -------
    colour.SpectralDistribution
        T(lambda), dimensionless.
    """
    if name not in ABSORBERS:
        raise _unknown(name, "an absorber", ABSORBERS)
    t = np.asarray(ABSORBERS[name](wavelengths_nm(shape)), dtype=float)
    if thickness_mm is not None:
        thickness_mm = _check_positive("thickness_mm", thickness_mm, allow_zero=True)
        t = beer_lambert_scale(t, thickness_mm / ABSORBER_REFERENCE_THICKNESS_MM)
    label = f"absorber {name}" + ("" if thickness_mm is None else f" {thickness_mm:g} mm")
    return _new_sd(t, wavelengths_nm(shape), name=label)


# --------------------------------------------------------------------------------------------
# lamps

# name -> key of colour.SDS_ILLUMINANTS.
# "daylight": CIE FL1, the CIE's "daylight" halophosphate fluorescent lamp (CCT about 6430 K; CIE
#   15:2004 tables): the ordinary indoor daylight tube of SPEC 1.1, with its mercury lines at 405,
#   436, 546 and 578 nm (546 nm falls in the absorber's best window, so the lines matter).
# "white_led": CIE LED-B4, a phosphor-converted blue LED of about 5100 K (CIE 015:2018): a
#   "daylight white" LED lamp as used for the calibration light (SPEC 1.1 gives no type).
LAMPS: Mapping[str, str] = MappingProxyType({"daylight": "FL1", "white_led": "LED-B4"})


def lamp_sd(name: str, shape: colour.SpectralShape = SPECTRAL_SHAPE) -> colour.SpectralDistribution:
    """Spectral power of a lamp normalised to 1 W in total (registry :data:`LAMPS`).

    Parameters
    ----------
    name : str
        One of :data:`LAMPS`.
    shape : colour.SpectralShape
        Grid; the CIE tables (380-780 nm, 5 nm) are aligned to it (zero outside 380-780 nm).

    Returns
    -------
    colour.SpectralDistribution
        P(lambda) in W/nm with trapezoid integral 1 W: multiply by the lamp's optical power (not
        its electrical rating) falling on the surface in question.
    """
    if name not in LAMPS:
        raise _unknown(name, "a lamp", LAMPS)
    sd = align_to_grid(colour.SDS_ILLUMINANTS[LAMPS[name]], shape)
    wl = wavelengths_nm(shape)
    values = np.asarray(sd.values, dtype=float)
    return _new_sd(values / trapezoid(values, wl), wl, name=f"lamp {name} (W/nm, 1 W)")


def photon_sd(power_sd: colour.SpectralDistribution) -> colour.SpectralDistribution:
    """Convert a spectral power density (W/nm) to a photon rate density (photons/s/nm).

    N(lambda) = P(lambda) lambda / (h c), with lambda in m and h, c from ``scipy.constants``.
    The domain is kept.
    """
    if not isinstance(power_sd, colour.SpectralDistribution):
        raise TypeError(f"power_sd must be a colour.SpectralDistribution, got {type(power_sd).__name__}")
    wl_m = np.asarray(power_sd.wavelengths, dtype=float) * 1e-9
    values = np.asarray(power_sd.values, dtype=float) * wl_m / (constants.h * constants.c)
    return _new_sd(values, power_sd.wavelengths, name=f"{power_sd.name} (photons/s/nm)")


# --------------------------------------------------------------------------------------------
# clear parts of the light path


def pmma_refractive_index(wavelength_nm) -> np.ndarray:
    """Refractive index of PMMA: n^2 - 1 = 1.1819 lambda^2 / (lambda^2 - 0.011313), lambda in um.

    Sultanova N., Kasarova S., Nikolov I., "Dispersion properties of optical polymers", Acta Physica
    Polonica A 116, 585-587 (2009) (via refractiveindex.info); fitted over 437-1052 nm, n(589 nm) =
    1.491, used here down to 360 nm.
    """
    lam_um2 = (np.asarray(wavelength_nm, dtype=float) * 1e-3) ** 2
    return np.sqrt(1.0 + 1.1819 * lam_um2 / (lam_um2 - 0.011313))


def _slab_transmittance(n, internal, fresnel_surfaces: int):
    """Normal-incidence transmittance of a slab with 0, 1 or 2 faces in air (incoherent multiple
    reflections between two faces: T = (1-R)^2 t / (1 - R^2 t^2))."""
    if fresnel_surfaces not in (0, 1, 2):
        raise ValueError(f"fresnel_surfaces = {fresnel_surfaces!r}: must be 0, 1 or 2")
    r = ((n - 1.0) / (n + 1.0)) ** 2
    if fresnel_surfaces == 0:
        return internal
    if fresnel_surfaces == 1:
        return (1.0 - r) * internal
    return (1.0 - r) ** 2 * internal / (1.0 - r**2 * internal**2)


# Bulk absorption of cast PMMA [1/mm]: "less than 0.5 % of visible light per inch" (ACRYLITE
# knowledge base, Roehm: "Can you explain the visible light spectrum and transmission") gives
# -ln(0.995) / 25.4 mm.
_PMMA_ALPHA_VISIBLE_PER_MM = -math.log(0.995) / 25.4
# UV edge (Urbach-like exponential): ACRYLITE cast/extruded sheet transmits "very small amounts"
# below 345 nm, a thickness-dependent amount in 345-395 nm and 92 % at every thickness above 395 nm
# (ACRYLITE knowledge base, "ultraviolet radiation and transmission of acrylic sheet"). Fitted:
# 1 % internal transmittance through 3 mm at 345 nm, e-folding 7 nm, so 3 mm keeps 99.6 % at 395 nm.
_PMMA_ALPHA_345_PER_MM = -math.log(0.01) / 3.0
_PMMA_EDGE_WIDTH_NM = 7.0


def acrylic_transmittance_sd(
    thickness_mm: float = 3.0, fresnel_surfaces: int = 2, shape: colour.SpectralShape = SPECTRAL_SHAPE
) -> colour.SpectralDistribution:
    """Transmittance of the clear acrylic (PMMA) plate at normal incidence.

    Parameters
    ----------
    thickness_mm : float
        Plate thickness; default 3 mm (SPEC 1.1, thickness not given: project default).
    fresnel_surfaces : {0, 1, 2}
        Faces in air whose Fresnel reflection is included; 2 (default) gives the sheet's catalogue
        transmittance, about 92 % in the visible. Use 0 when the renderer traces the interfaces.
    shape : colour.SpectralShape
        Grid.

    Returns
    -------
    colour.SpectralDistribution
        T(lambda) = slab(n(lambda), exp(-alpha(lambda) d)).

    Notes
    -----
    n from Sultanova et al. (2009) (:func:`pmma_refractive_index`), R = ((n-1)/(n+1))^2 about 3.9 %
    per face. alpha = visible bulk absorption + an exponential UV edge, both from the ACRYLITE
    (Roehm) knowledge base statements quoted next to the constants; the edge's shape is a fit.
    """
    d = _check_positive("thickness_mm", thickness_mm, allow_zero=True)
    wl = wavelengths_nm(shape)
    alpha = _PMMA_ALPHA_VISIBLE_PER_MM + _PMMA_ALPHA_345_PER_MM * np.exp(-(wl - 345.0) / _PMMA_EDGE_WIDTH_NM)
    t = _slab_transmittance(pmma_refractive_index(wl), np.exp(-alpha * d), fresnel_surfaces)
    return _new_sd(t, wl, name=f"acrylic {d:g} mm")


# Clear platinum-cure silicone (SC37; Smooth-On calls it "water clear" and gives no spectrum).
# Typical values, assumptions: n = 1.41 (PDMS-like silicones are 1.40-1.43) and a flat bulk
# absorption of 0.002 /mm (98 % internal transmittance through 10 mm), so that a few millimetres
# with two faces in air transmit about 93 %, as clear silicone sheets typically do in the visible.
_SILICONE_N = 1.41
_SILICONE_ALPHA_PER_MM = 0.002


def elastomer_transmittance_sd(
    thickness_mm: float, fresnel_surfaces: int = 0, shape: colour.SpectralShape = SPECTRAL_SHAPE
) -> colour.SpectralDistribution:
    """Transmittance of clear silicone elastomer (Sorta-Clear 37) at normal incidence.

    Parameters
    ----------
    thickness_mm : float
        Path length in the clear elastomer, >= 0.
    fresnel_surfaces : {0, 1, 2}
        Faces in air whose reflection is included. Default 0: inside the sensor the clear core is
        bonded to the ML layer and the base rests on the acrylic (n 1.41 against 1.49: R < 0.1 %).
    shape : colour.SpectralShape
        Grid.

    Returns
    -------
    colour.SpectralDistribution
        T(lambda); with the typical (assumed) values above, about 0.98 per 10 mm, flat over the grid.
    """
    d = _check_positive("thickness_mm", thickness_mm, allow_zero=True)
    wl = wavelengths_nm(shape)
    internal = np.full_like(wl, math.exp(-_SILICONE_ALPHA_PER_MM * d))
    t = _slab_transmittance(np.full_like(wl, _SILICONE_N), internal, fresnel_surfaces)
    return _new_sd(t, wl, name=f"silicone {d:g} mm")


# --------------------------------------------------------------------------------------------
# camera


def _imx415_like() -> colour.MultiSpectralDistributions:
    """NPL-measured Nikon D5100 sensitivities (Darrodi M. M., Finlayson G., Goodman T., Mackiewicz M.,
    "Reference data set for camera spectral sensitivity estimation", JOSA A 32(3), 381-391, 2015;
    shipped with colour), each channel peak-normalised to 1 by the data set, rescaled to the
    assumed IMX415-class peak QE of :data:`CAMERA_PEAK_QE`. The curves are of a whole Bayer colour
    CMOS camera with its IR-cut filter (zero beyond about 700 nm), which the sensor's camera module
    also has; an IMX415 relative response would replace them where available."""
    npl = MSDS_CAMERA_SENSITIVITIES["Nikon 5100 (NPL)"]
    rel = np.clip(np.asarray(npl.values, dtype=float), 0.0, None)
    rel = rel / rel.max(axis=0)
    qe = rel * np.array([CAMERA_PEAK_QE[c] for c in CHANNELS])
    return _new_msds(qe, npl.wavelengths, labels=CHANNELS, name="imx415_like QE")


CAMERA_SENSITIVITIES: Mapping[str, Callable[[], colour.MultiSpectralDistributions]] = MappingProxyType(
    {"imx415_like": _imx415_like}
)


def read_camera_sensitivity_csv(path) -> colour.MultiSpectralDistributions:
    """Read a camera QE table: a CSV with a header holding wavelength_nm, r, g, b (QE 0..1).

    Header names are matched without regard to case or surrounding spaces; other columns are
    ignored. Wavelengths must increase strictly; QE values must be finite and within [0, 1].

    Returns
    -------
    colour.MultiSpectralDistributions
        Labels ("r", "g", "b"), on the file's own wavelengths.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"camera sensitivity file {path} does not exist")
    with path.open(newline="") as fh:
        rows = [row for row in csv.reader(fh) if row and any(cell.strip() for cell in row)]
    if not rows:
        raise ValueError(f"{path}: empty; expected a header 'wavelength_nm,r,g,b' and one row per wavelength")
    header = [h.strip().lower() for h in rows[0]]
    needed = ("wavelength_nm",) + CHANNELS
    missing = [c for c in needed if c not in header]
    if missing:
        raise ValueError(
            f"{path}: missing column(s) {', '.join(missing)}; the header has {', '.join(header) or 'nothing'} "
            "and must name wavelength_nm, r, g, b"
        )
    cols = [header.index(c) for c in needed]
    if len(rows) < 3:
        raise ValueError(f"{path}: needs at least two data rows, has {len(rows) - 1}")
    data = np.empty((len(rows) - 1, 4))
    for i, row in enumerate(rows[1:], start=2):
        for j, (c, name) in enumerate(zip(cols, needed)):
            try:
                data[i - 2, j] = float(row[c])
            except (IndexError, ValueError):
                cell = row[c] if c < len(row) else ""
                raise ValueError(f"{path}: line {i}, column {name} = {cell!r}: not a number") from None
    wl, qe = data[:, 0], data[:, 1:]
    if not np.all(np.isfinite(data)):
        i = int(np.argwhere(~np.isfinite(data))[0, 0])
        raise ValueError(f"{path}: line {i + 2} has NaN or infinite values")
    step = np.diff(wl)
    if np.any(step <= 0):
        i = int(np.argmax(step <= 0)) + 1
        raise ValueError(
            f"{path}: wavelength_nm must increase strictly; line {i + 2} ({wl[i]:g} nm) follows {wl[i - 1]:g} nm"
        )
    bad = (qe < 0.0) | (qe > 1.0)
    if np.any(bad):
        i, j = (int(k) for k in np.argwhere(bad)[0])
        raise ValueError(
            f"{path}: line {i + 2}, column {CHANNELS[j]} = {qe[i, j]:g} at {wl[i]:g} nm: QE must be within [0, 1] "
            "(a fraction of photons, not percent)"
        )
    return _new_msds(qe, wl, labels=CHANNELS, name=f"camera QE from {path.name}")


def camera_sensitivity_msds(
    name_or_path="imx415_like", shape: colour.SpectralShape = SPECTRAL_SHAPE
) -> colour.MultiSpectralDistributions:
    """Camera quantum efficiency per channel (R, G, B), electrons per incident photon, on ``shape``.

    Parameters
    ----------
    name_or_path : str or os.PathLike
        A name of :data:`CAMERA_SENSITIVITIES` (default "imx415_like") or the path of a CSV file
        (see :func:`read_camera_sensitivity_csv`).
    shape : colour.SpectralShape
        Grid (zero QE outside the data's range).

    Returns
    -------
    colour.MultiSpectralDistributions
        Columns in the order R, G, B.
    """
    if isinstance(name_or_path, str) and name_or_path in CAMERA_SENSITIVITIES:
        msds = CAMERA_SENSITIVITIES[name_or_path]()
    elif isinstance(name_or_path, os.PathLike) or (
        isinstance(name_or_path, str) and (name_or_path.lower().endswith(".csv") or os.sep in name_or_path)
    ):
        msds = read_camera_sensitivity_csv(name_or_path)
    else:
        raise _unknown(
            name_or_path, "a camera", CAMERA_SENSITIVITIES, " (or the path of a CSV file with columns wavelength_nm, r, g, b)"
        )
    return align_to_grid(msds, shape)


# --------------------------------------------------------------------------------------------
# channel factors


def _path_transmittance(transmittance_sds, shape) -> np.ndarray:
    if isinstance(transmittance_sds, colour.SpectralDistribution):
        transmittance_sds = (transmittance_sds,)
    t = np.ones(len(wavelengths_nm(shape)))
    for k, sd in enumerate(transmittance_sds):
        v = _values_on_grid(sd, shape, f"transmittance_sds[{k}] ({sd.name})")
        if np.any(v < 0.0) or np.any(v > 1.0 + 1e-9):
            raise ValueError(f"transmittance_sds[{k}] ({sd.name}) has values outside [0, 1]")
        t = t * np.clip(v, 0.0, 1.0)
    return t


def _camera_values(camera_msds, shape) -> np.ndarray:
    if camera_msds is None:
        camera_msds = camera_sensitivity_msds(shape=shape)
    if not isinstance(camera_msds, colour.MultiSpectralDistributions):
        raise TypeError(
            f"camera_msds must be a colour.MultiSpectralDistributions (see camera_sensitivity_msds), "
            f"got {type(camera_msds).__name__}"
        )
    q = _values_on_grid(camera_msds, shape, "camera_msds")
    if q.ndim != 2 or q.shape[1] != 3:
        raise ValueError(f"camera_msds must have 3 channels (R, G, B), has {q.shape[-1] if q.ndim == 2 else 1}")
    return q


def channel_factors(
    emission_sd: colour.SpectralDistribution,
    transmittance_sds=(),
    camera_msds: colour.MultiSpectralDistributions | None = None,
    shape: colour.SpectralShape = SPECTRAL_SHAPE,
) -> np.ndarray:
    """Electrons per emitted photon in each camera channel, after the path's transmittances.

    k_c = trapz( s(lambda) prod_i T_i(lambda) QE_c(lambda) ),  c = R, G, B.

    Parameters
    ----------
    emission_sd : colour.SpectralDistribution
        Photon spectral density of the source (any scale): it is normalised inside to a trapezoid
        integral of 1 over the grid, so an unnormalised spectrum (photons/s/nm) gives the same
        factors as its shape.
    transmittance_sds : sequence of colour.SpectralDistribution, or one
        Transmittances in the path (absorber, elastomer, acrylic ...), values in [0, 1]; empty:
        none. Zero outside each one's wavelength range (see :func:`align_to_grid`).
    camera_msds : colour.MultiSpectralDistributions, optional
        QE per channel, columns R, G, B; default :func:`camera_sensitivity_msds`.
    shape : colour.SpectralShape
        Integration grid; every input is aligned to it.

    Returns
    -------
    numpy.ndarray
        (3,) electrons per photon for R, G, B. Multiply a photon rate [1/s] reaching the pixel's
        footprint (geometry from the renderer) to get electrons/s.
    """
    wl, s = _unit_integral(emission_sd, shape, "emission_sd", "a photon spectral density")
    weight = s * _path_transmittance(transmittance_sds, shape)
    return trapezoid(weight[:, None] * _camera_values(camera_msds, shape), wl, axis=0)


def _unit_integral(sd, shape, name: str, what: str):
    """(grid (K,) nm, values of ``sd`` on it scaled to a trapezoid integral of 1); non-negative, > 0."""
    wl = wavelengths_nm(shape)
    v = _values_on_grid(sd, shape, name)
    if np.any(v < 0.0):
        raise ValueError(f"{name} has negative values; {what} is >= 0")
    total = trapezoid(v, wl)
    if not total > 0.0:
        raise ValueError(f"{name} integrates to {total} on the grid {wl[0]:g}-{wl[-1]:g} nm; it must be > 0 there")
    return wl, v / total


def channel_factors_power(
    power_sd: colour.SpectralDistribution,
    transmittance_sds=(),
    camera_msds: colour.MultiSpectralDistributions | None = None,
    shape: colour.SpectralShape = SPECTRAL_SHAPE,
) -> np.ndarray:
    """Electrons per joule of emitted radiant energy in each channel, for a lamp spectrum.

    k_c = trapz( p(lambda) lambda / (h c) prod_i T_i QE_c ),  p = P / trapz(P) in 1/nm.

    Parameters
    ----------
    power_sd : colour.SpectralDistribution
        Spectral power (W/nm, any scale; normalised to 1 W inside), e.g. :func:`lamp_sd`.
    transmittance_sds, camera_msds, shape
        As in :func:`channel_factors`.

    Returns
    -------
    numpy.ndarray
        (3,) electrons per joule for R, G, B: multiply by the radiant power [W] reaching the
        pixel's footprint to get electrons/s.
    """
    wl, p = _unit_integral(power_sd, shape, "power_sd", "a spectral power density")
    photons_per_joule = p * (wl * 1e-9) / (constants.h * constants.c)  # photons / J / nm
    weight = photons_per_joule * _path_transmittance(transmittance_sds, shape)
    return trapezoid(weight[:, None] * _camera_values(camera_msds, shape), wl, axis=0)


# --------------------------------------------------------------------------------------------
# plot


def plot_spectra(
    path,
    emission_sd: colour.SpectralDistribution | None = None,
    absorbers: Iterable[str] = tuple(ABSORBERS),
    lamps: Iterable[str] = tuple(LAMPS),
    camera="imx415_like",
    transmittance_sds=None,
    shape: colour.SpectralShape = SPECTRAL_SHAPE,
) -> Path:
    """Draw the emission band, camera QE, absorbers, clear parts and lamps on one PNG figure.

    Parameters
    ----------
    path : str or os.PathLike
        Output PNG; written atomically (a temporary file in the same folder, then renamed).
    emission_sd : colour.SpectralDistribution, optional
        Default :func:`zns_cu_emission_sd`.
    absorbers, lamps : iterables of registry names
        Curves to draw (default: all).
    camera : str or os.PathLike
        Passed to :func:`camera_sensitivity_msds`.
    transmittance_sds : sequence of colour.SpectralDistribution, optional
        Clear parts to draw with the absorbers; default 3 mm acrylic and 2 mm silicone.

    Returns
    -------
    pathlib.Path
        The written file.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    path = Path(path)
    wl = wavelengths_nm(shape)
    emission = align_to_grid(emission_sd if emission_sd is not None else zns_cu_emission_sd(shape=shape), shape)
    qe = camera_sensitivity_msds(camera, shape)
    if transmittance_sds is None:
        transmittance_sds = (acrylic_transmittance_sd(shape=shape), elastomer_transmittance_sd(2.0, shape=shape))

    fig = Figure(figsize=(8.0, 9.0), constrained_layout=True)
    FigureCanvasAgg(fig)
    ax_e, ax_t, ax_l = fig.subplots(3, 1, sharex=True)

    ax_e.fill_between(wl, emission.values / emission.values.max(), color="0.85", label=f"{emission.name} (peak = 1)")
    for k, colour_name in zip(range(3), ("tab:red", "tab:green", "tab:blue")):
        ax_e.plot(wl, qe.values[:, k], color=colour_name, label=f"QE {CHANNELS[k].upper()}")
    ax_e.set_ylabel("relative emission / QE")
    ax_e.set_title("emission and camera")
    ax_e.legend(fontsize=8)

    for name in absorbers:
        ax_t.semilogy(wl, absorber_transmittance_sd(name, shape=shape).values, label=f"absorber {name}")
    for sd in transmittance_sds:
        sd = align_to_grid(sd, shape)
        ax_t.semilogy(wl, sd.values, "--", label=sd.name)
    ax_t.axvspan(492, 577, color="0.92", zorder=0)
    ax_t.set_ylabel("transmittance")
    ax_t.set_title(f"absorbers ({ABSORBER_REFERENCE_THICKNESS_MM:g} mm) and clear parts")
    ax_t.legend(fontsize=7)

    for name in lamps:
        ax_l.plot(wl, lamp_sd(name, shape).values, label=f"{name} ({LAMPS[name]})")
    ax_l.set_ylabel("W/nm per W")
    ax_l.set_xlabel("wavelength (nm)")
    ax_l.set_title("lamps (1 W)")
    ax_l.legend(fontsize=8)

    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(suffix=".png", prefix=".tmp_", dir=path.parent)
    os.close(fd)
    try:
        fig.savefig(tmp, format="png", dpi=110)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path
