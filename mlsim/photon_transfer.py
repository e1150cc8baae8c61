"""The camera's dark parameters from an idle recording: the dark part of the photon-transfer method
(EMVA Standard 1288, Release 4.0 Linear, sections 6.2-6.3 [1]; J. R. Janesick, *Photon Transfer*,
SPIE Press, 2007 [2]), inverted through the 8-bit output of :mod:`mlsim.camera`.

The idle frames' photosites (the native site of each pixel's colour: the bilinear demosaic keeps it)
carry, in 10-bit DN before the 8-bit cut,

    X = round(black + K' (mu_d + n)),   n ~ dark shot + read noise, var(n) = sigma_r'^2 + mu_d,

with K' = K 10^(G/20) / b^2 the conversion gain per summed electron, mu_d = b^2 I_d t_exp the dark
electrons and sigma_r' = b sigma_r the effective read noise (:class:`mlsim.camera.CameraParams`).
The 8-bit output drops the low bits, y = floor(X / 4) (10-bit ADC). When the 10-bit noise sigma_X
spans a few codes the low bits are uniform and independent of the rest (their periodic terms decay as
exp(-2 pi^2 sigma_X^2 / 16): 7e-3 at sigma_X = 2 DN), so

    E[y] = E[X] / 4 - 3/8,    var(y) = (sigma_X^2 + 1/12) / 16 + 5/64    (5/64 = var of the low bits / 16).

Estimators: the mean of y over every site and frame; the temporal variance by the EMVA difference
method on disjoint frame pairs, var(y) = mean((y_2k+1 - y_2k)^2) / 2 (the fixed pattern cancels),
with the standard uncertainty var sqrt(2 / M) over M independent pairs of sites (chi-square with M
degrees of freedom for normal noise).

What an idle recording determines, at one exposure and gain: two numbers, the dark offset
black + K' mu_d and the dark noise K'^2 (sigma_r'^2 + mu_d) (DN^2). With the scene's conversion gain
K and dark current I_d taken as known, they give the black level and the read noise (which is what
:func:`dark_parameters` returns); K and I_d themselves need frames under light or at several
exposures (not in an idle video). Where sigma_X < 2 DN (the default camera at 0 dB: 0.1 DN, every idle
frame the same 8-bit code) the 8-bit cut hides the noise: the read noise is not determinable and the
black level only to within the 4 codes of one 8-bit step; :func:`dark_parameters` says so.

References
----------
.. [1] EMVA Standard 1288 Release 4.0 Linear (2021): the linear camera model, the dark signal and the
   temporal variance from frame differences.
.. [2] J. R. Janesick, Photon Transfer DN -> lambda, SPIE Press, 2007.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DarkStats", "native_sites", "dark_statistics", "dark_parameters", "MIN_NOISE_DN10"]

#: Below this 10-bit temporal noise the 8-bit output hides it (module docstring).
MIN_NOISE_DN10 = 2.0

# RGGB: the channel native to each site of a 2 x 2 cell (mlsim.camera's Bayer pattern).
_RGGB = np.array([[0, 1], [1, 2]])


def native_sites(frames) -> np.ndarray:
    """(T, H - 2, W - 2) uint8: each inner pixel's value in its own Bayer channel (R at even rows and
    columns, B at odd ones, G elsewhere) of RGB frames (T, H, W, 3) from :mod:`mlsim.camera` (RGGB,
    OpenCV's bilinear demosaic, which keeps the native value inside and copies the border ring from
    its neighbours: the ring is left out)."""
    f = np.asarray(frames)
    if f.ndim != 4 or f.shape[-1] != 3 or f.dtype != np.uint8 or min(f.shape[1:3]) < 4:
        raise ValueError(f"frames have shape {f.shape} and dtype {f.dtype}: need (T, H, W, 3) uint8 RGB, H and W >= 4")
    H, W = f.shape[1:3]
    ch = np.tile(_RGGB, (-(-H // 2), -(-W // 2)))[:H, :W]
    return np.take_along_axis(f, ch[None, :, :, None], axis=3)[:, 1:-1, 1:-1, 0]


@dataclass(frozen=True)
class DarkStats:
    """mean_dn8 and temporal_var_dn8 (8-bit DN and DN^2) of the idle photosites, their standard
    uncertainties, the number of independent site pairs M and of frames."""

    mean_dn8: float
    mean_sigma: float
    temporal_var_dn8: float
    var_sigma: float
    pairs: int
    frames: int


def dark_statistics(frames) -> DarkStats:
    """:class:`DarkStats` of idle RGB frames (T, H, W, 3) uint8, T >= 2 (module docstring)."""
    y = native_sites(frames).astype(np.float64)
    T = len(y)
    if T < 2:
        raise ValueError(f"{T} idle frame(s): the temporal variance needs at least 2")
    d = y[1 : 2 * (T // 2) : 2] - y[0 : 2 * (T // 2) : 2]
    M = d.size
    var = float(np.mean(d**2) / 2.0)
    return DarkStats(float(y.mean()), float(np.sqrt(max(var, 1.0 / 12.0) / y.size)), var, var * float(np.sqrt(2.0 / M)), int(M), T)


def dark_parameters(stats: DarkStats, params) -> dict:
    """The black level (10-bit DN) and read noise (e-, per native pixel) that reproduce ``stats``
    with the camera ``params`` (:class:`mlsim.camera.CameraParams`: its conversion gain, gain, binning,
    dark current and exposure taken as known), each with its standard uncertainty, or why it is not
    determinable. Returns a dict: noise_dn10, black_level_dn, black_level_sigma, read_noise_e,
    read_noise_sigma, determinable (bool), why."""
    if params.adc_bits != 10:
        raise ValueError(f"adc_bits = {params.adc_bits}: the 8-bit inversion is written for a 10-bit ADC")
    k = params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0)  # DN10 per summed e-
    mu_d = params.dark_electrons
    noise2 = 16.0 * (stats.temporal_var_dn8 - 5.0 / 64.0) - 1.0 / 12.0  # sigma_X^2, DN10^2
    noise2_sigma = 16.0 * stats.var_sigma
    mean_dn10 = 4.0 * (stats.mean_dn8 + 0.375)
    out = {"noise_dn10": float(np.sqrt(max(noise2, 0.0))), "conversion_gain_dn10_per_e": k, "dark_electrons": mu_d}
    if noise2 < MIN_NOISE_DN10**2:
        lo = 4.0 * np.floor(stats.mean_dn8)
        return out | {"determinable": False, "black_level_dn": None, "read_noise_e": None,
                      "black_level_range_dn": [float(lo), float(lo + 4.0)],
                      "why": f"the idle frames' temporal noise ({out['noise_dn10']:.2f} DN at 10 bits) is below {MIN_NOISE_DN10:g} DN: the "
                             "8-bit output hides it; record the idle video at a higher gain (or as raw 10-bit frames)"}
    read2 = noise2 / k**2 - mu_d  # sigma_r'^2, e-^2
    read_eff = np.sqrt(max(read2, 0.0))
    b = params.binning
    read_sigma = noise2_sigma / k**2 / (2.0 * max(read_eff, 1e-12)) / b
    black = mean_dn10 - k * mu_d
    return out | {"determinable": True, "black_level_dn": float(black), "black_level_sigma": float(4.0 * stats.mean_sigma),
                  "read_noise_e": float(read_eff / b), "read_noise_sigma": float(read_sigma),
                  "why": "with the scene's conversion gain and dark current taken as known (an idle video at one exposure fixes two numbers)"}
