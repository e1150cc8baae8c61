"""Radiometric model of the colour CMOS camera that films the glowing sensor from below.

SPEC 1.1: a Sony IMX415-class colour CMOS at 30 FPS, frames cropped to 350 x 350 x 3 8-bit RGB,
looking up through the acrylic plate at the sensor in the dark. One exposure per frame:

1. input: the *effective photon radiance* L_c of each colour channel c (photons s^-1 m^-2 sr^-1),
   already weighted by the channel's quantum efficiency and the optics' spectral transmittance
   (the spectra module integrates spectrum x transmittances x QE_c), so L_c counts the photons that
   become electrons in channel c. QE is therefore **not** applied here;
2. camera equation (on axis, Lambertian object) [1, 2]: mean electrons per pixel

       mu_c = L_c A_pix t_exp tau_lens pi / (4 N^2 (1 + m)^2)           (e-)

   with A_pix the (effective) pixel area, N the f-number, m = |image / object| the magnification
   (default m = f / (d - f) from the thin-lens focus at object distance d) and tau_lens the lens
   transmittance; an optional relative-illumination map (cos^4 law [2]) multiplies it;
3. sensor [3, 4]: RGGB Bayer filter (each photosite keeps its own channel's electrons), dark
   current over the exposure, shot noise (Poisson on signal + dark electrons), full-well clipping,
   Gaussian read noise; then DN = round(e- K 10^(G/20) + black) clipped to [0, 2^bits - 1] (the
   linear camera model of EMVA 1288 [3]: mu_y = mu_y.dark + K mu_e, sigma_y^2 = K^2 sigma_d^2 +
   sigma_q^2 + K (mu_y - mu_y.dark)); the 8-bit output drops the low bits (floor(DN 256 / 2^bits));
4. bilinear demosaic to RGB with OpenCV.

Effective pixel ("binning"). The 36 mm sensing surface, about 60 mm above the lens, must fill the
350 px crop. In all-pixel readout (1.45 um pitch) that needs a 0.83 mm focal length, which no
stock lens has; with ``binning`` b native pixels per output pixel along each axis the crop spans
350 b 1.45 um on the die and the focal length is f = m d / (1 + m), m = 350 b 1.45 um / 36 mm:

    b = 1: 0.83 mm   b = 2: 1.65 mm   b = 3: 2.44 mm   b = 4: 3.20 mm   b = 6: 4.69 mm

b = 4 (effective pitch 5.8 um: the IMX415's 2 x 2 binned readout scaled once more by 2, i.e. a
960 x 540 stream, in which a 350 x 350 crop fits) gives f = 3.20 mm, a common M12 board lens
(2.8-4 mm). The signal per output pixel does not depend on this choice (it is set by the object
area per pixel and the f-number); the noise does: the b^2 summed native pixels have b^2 times the
full well and dark current, b times the read noise (b^2 independent reads), and the ISP averages
them, so the conversion gain per summed electron is K / b^2.

Sampling (the fast path). numpy's Poisson sampler costs about 4.5 ms per 350 x 350 frame, more
than the whole 2 ms budget, so shot and read noise are drawn together from **one** float32 normal
z per photosite (Box-Muller on float32 uniforms, 3.5x faster here than numpy's float32 ziggurat;
the tails are cut at |z| = 5.77, probability 8e-9), with the Cornish-Fisher skewness term [5] so
that the first three cumulants of Poisson(mu) + N(0, sigma_r^2) are exact:

    e- = mu + s z + mu / (6 s^2) (z^2 - 1),    s^2 = mu + sigma_r^2.

Where the read noise is below ``EXACT_POISSON_READ_NOISE_BELOW_E`` (2 e-) *and* the total
variance s^2 below ``EXACT_POISSON_BELOW_E2`` (20 e-^2), the photosite instead gets an exact
Poisson count (numpy's sampler, on those photosites only) plus sigma_r z. Error of the normal
branch (Kolmogorov distance to Poisson(mu) + N(0, sigma_r^2), at half-integers when sigma_r = 0;
computed on a grid, checked by the tests): <= 9e-4 wherever it is used (6.8e-4 at mu = 20,
sigma_r = 0; 8.8e-4 at sigma_r = 2, mu = 2.5, the worst case; < 2e-4 for sigma_r >= 4), against
1.5e-2 for a plain normal at mu = 20. At the default effective read noise (8 e-) every photosite
takes the normal branch. The normal branch gives a continuous charge rather than an integer; the
ADC step (80 summed e- per 10-bit DN at 0 dB with the defaults) hides the lattice, except at very
high gain with sigma_r < 0.5 e-. torch was measured as an alternative: ``torch.randn`` takes
0.31 ms per frame against 0.28 ms for this Box-Muller, and the rest is a few tens of microseconds
of element-wise work, so numpy alone is kept. Frames are processed one at a time so that the
temporaries stay in cache (2x faster than whole-batch arrays).

The random stream, per frame in order: one ``rng.random((2, ceil(n / 2)), float32)`` for the
normals of the n photosites, then ``rng.poisson`` for the photosites of the exact branch. The same
generator state gives the same bytes, and a batch gives the same bytes as its frames one at a time.
With numpy's PCG64 the uniforms are its 64-bit words split in two (``_uniform_f32``: numpy's bytes,
0.17 ms a frame against 0.3-0.4 ms for numpy's float32 loop). A frame without light
(``Camera.dark``, the DLLM's idle frames) whose every draw reads the same 8-bit step
(:func:`dark_frame_dn8`: at the defaults a dark photosite reads 49.4-50.6 DN of 10 bits, 12 in
8 bits, whatever its draw) is that step, with the generator advanced past its draws: the same bytes.

Timing: frame k is exposed over [k / fps, k / fps + t_exp]; t_exp may not exceed 1 / fps.

References
----------
.. [1] W. J. Smith, *Modern Optical Engineering*, 4th ed., McGraw-Hill, 2008, chapter on radiometry
   (image irradiance E = pi tau L / (4 N^2 (1 + m)^2), cos^4 law); G. C. Holst, *CCD Arrays,
   Cameras and Displays*, 2nd ed., SPIE, 1998, pp. 33-34.
.. [2] J. R. Janesick, *Photon Transfer DN -> lambda*, SPIE Press, 2007 (signal chain,
   shot / read / dark noise, conversion gain).
.. [3] EMVA Standard 1288, Release 4.0 Linear, European Machine Vision Association, 2021
   (mathematical model: the linear camera model and its noise model).
.. [4] Sony IMX415-AAQR data sheet (1/2.8-type, 3864 x 2192 effective pixels, 1.45 um unit cell,
   10/12-bit ADC); Linux driver drivers/media/i2c/imx415.c (RAW10 GBRG output, black level 50 DN
   at 10 bits, analog gain 0-30 dB in 0.3 dB steps).
.. [5] E. A. Cornish and R. A. Fisher, "Moments and cumulants in the specification of
   distributions", Rev. Int. Stat. Inst. 5 (1938) 307-320.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import NamedTuple

import cv2
import numpy as np

__all__ = [
    "CameraParams",
    "Camera",
    "capture",
    "capture_mono",
    "frame_times_s",
    "exposure_windows_s",
    "magnification_from_focus",
    "focal_length_to_fit_m",
    "electrons_per_radiance",
    "cos4_relative_illumination",
    "signal_electrons",
    "expose_electrons",
    "digitize",
    "to_8bit",
    "demosaic_rggb",
    "EXACT_POISSON_BELOW_E2",
    "EXACT_POISSON_READ_NOISE_BELOW_E",
    "BOX_MULLER_Z_MAX",
    "dark_frame_dn8",
]

# A photosite gets an exact Poisson count where its total variance (shot + read) is below
# EXACT_POISSON_BELOW_E2 and the read noise is below EXACT_POISSON_READ_NOISE_BELOW_E; elsewhere the
# skewness-corrected normal is within 9e-4 in distribution (module docstring).
EXACT_POISSON_BELOW_E2 = 20.0
EXACT_POISSON_READ_NOISE_BELOW_E = 2.0

# RGGB: (row offset, column offset, channel) of the four photosites of a 2 x 2 cell.
_RGGB = ((0, 0, 0), (0, 1, 1), (1, 0, 1), (1, 1, 2))
# OpenCV names a Bayer pattern by the 2nd and 3rd pixels of its 2nd row, so RGGB (red top-left) is
# the legacy "BG"; OpenCV >= 4.x also has the explicit alias BayerRGGB (same value).
_CV_RGGB2RGB = getattr(cv2, "COLOR_BayerRGGB2RGB", cv2.COLOR_BayerBG2RGB)

# Geometry of SPEC 1.1 used for the default lens.
_SURFACE_WIDTH_M = 0.036  # sensing surface 36 mm x 36 mm (SPEC 1.1)
_OBJECT_DISTANCE_M = 0.060  # lens to the glowing surface, about 60 mm inside the 65 mm shell
_CROP_PX = 350  # SPEC 1.1 crop
_PIXEL_PITCH_M = 1.45e-6  # IMX415 unit cell [4]
_BINNING = 4  # see the module docstring: 2 x 2 binned readout scaled by 2 (960 x 540 stream)


# ---------------------------------------------------------------------------------- validation
def _check_radiance(radiance) -> np.ndarray:
    rad = np.asarray(radiance)
    if rad.ndim not in (3, 4) or rad.shape[-1] != 3:
        raise ValueError(f"radiance has shape {rad.shape}: must be (H, W, 3) or (B, H, W, 3), the last axis the R, G, B channels")
    if not (np.issubdtype(rad.dtype, np.floating) or np.issubdtype(rad.dtype, np.integer)) or rad.dtype == np.bool_:
        raise ValueError(f"radiance has dtype {rad.dtype}: must be real numbers (photons s^-1 m^-2 sr^-1)")
    if rad.size == 0:
        raise ValueError(f"radiance has shape {rad.shape}: it is empty")
    lo, hi = rad.min(), rad.max()
    if not (lo >= 0) or not np.isfinite(hi):  # NaN fails both comparisons
        n_nan = int(np.isnan(rad).sum()) if np.issubdtype(rad.dtype, np.floating) else 0
        n_inf = int(np.isinf(rad).sum()) if np.issubdtype(rad.dtype, np.floating) else 0
        n_neg = int((rad < 0).sum())
        parts = [f"{n} {what}" for n, what in ((n_nan, "NaN"), (n_inf, "infinite"), (n_neg, "negative")) if n]
        raise ValueError(f"radiance has {', '.join(parts)} value(s): it must be finite and >= 0 (photons s^-1 m^-2 sr^-1)")
    return rad


def _check_relative_illumination(rel, hw) -> np.ndarray:
    rel = np.asarray(rel, dtype=np.float64)
    if rel.shape != tuple(hw):
        raise ValueError(f"relative_illumination has shape {rel.shape}: must be (H, W) = {tuple(hw)}")
    if not (np.all(np.isfinite(rel)) and rel.min() >= 0):
        raise ValueError("relative_illumination must be finite and >= 0")
    return rel


def _finite(name, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"{name} = {value!r}: must be a number")
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"{name} = {v}: must be finite")
    return v


def _positive(name, value, allow_inf=False) -> float:
    if allow_inf and isinstance(value, (int, float, np.floating)) and not isinstance(value, bool) and value == math.inf:
        return math.inf
    v = _finite(name, value)
    if not v > 0:
        raise ValueError(f"{name} = {v:g}: must be > 0")
    return v


def _non_negative(name, value) -> float:
    v = _finite(name, value)
    if v < 0:
        raise ValueError(f"{name} = {v:g}: must be >= 0")
    return v


def _count(name, value) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
        raise ValueError(f"{name} = {value!r}: must be an integer >= 0")
    return int(value)


def _adc_bits(bits) -> int:
    if isinstance(bits, bool) or not isinstance(bits, (int, np.integer)) or not 8 <= bits <= 16:
        raise ValueError(f"adc_bits = {bits!r}: must be an integer from 8 to 16 (IMX415: 10 or 12)")
    return int(bits)


# ------------------------------------------------------------------------------------- timing
def frame_times_s(n_frames: int, fps: float) -> np.ndarray:
    """Start time (n_frames,) s of each frame: frame k starts at k / fps."""
    n = _count("n_frames", n_frames)
    fps = _positive("fps", fps)
    return np.arange(n, dtype=float) / fps


def exposure_windows_s(n_frames: int, fps: float, exposure_s: float) -> np.ndarray:
    """Exposure window (n_frames, 2) s of each frame: [k / fps, k / fps + exposure_s].

    Raises ValueError when exposure_s exceeds the frame period 1 / fps.
    """
    fps = _positive("fps", fps)
    exposure_s = _positive("exposure_s", exposure_s)
    _check_exposure(fps, exposure_s)
    start = frame_times_s(n_frames, fps)
    return np.stack([start, start + exposure_s], axis=-1)


def _check_exposure(fps: float, exposure_s: float, *, fps_name="fps", exposure_name="exposure_s", exposure_scale=1.0) -> None:
    """Raise if the exposure is longer than the frame period (a relative 1e-9 slack for rounding)."""
    period = 1.0 / fps
    if exposure_s > period * (1.0 + 1e-9):
        raise ValueError(
            f"{exposure_name} = {exposure_s * exposure_scale:g} exceeds the {period * 1e3:.1f} ms frame period at "
            f"{fps_name} = {fps:g}: shorten the exposure or lower the frame rate"
        )


# --------------------------------------------------------------------------------- radiometry
def magnification_from_focus(focal_length_m: float, object_distance_m: float) -> float:
    """|image / object| of a thin lens focused at the object: m = f / (d - f)."""
    f = _positive("focal_length_m", focal_length_m)
    d = _positive("object_distance_m", object_distance_m)
    if d <= f:
        raise ValueError(f"object_distance_m = {d:g} must exceed focal_length_m = {f:g}: a closer object forms no real image")
    return f / (d - f)


def focal_length_to_fit_m(object_width_m: float, image_width_px: int, pixel_pitch_m: float, object_distance_m: float) -> float:
    """Focal length (m) that images an object of this width onto exactly image_width_px pixels.

    m = image_width_px pixel_pitch_m / object_width_m; from m = f / (d - f): f = m d / (1 + m).
    """
    m = image_width_px * _positive("pixel_pitch_m", pixel_pitch_m) / _positive("object_width_m", object_width_m)
    return m * _positive("object_distance_m", object_distance_m) / (1.0 + m)


def electrons_per_radiance(
    pixel_area_m2: float, exposure_s: float, f_number: float, magnification: float, lens_transmittance: float
) -> float:
    """Camera equation: electrons per pixel per unit effective photon radiance (m^2 sr s).

    Parameters
    ----------
    pixel_area_m2 : float
        Light-collecting area of one (effective) pixel, m^2.
    exposure_s : float
        Integration time, s.
    f_number : float
        N = focal length / entrance-pupil diameter.
    magnification : float
        m = |image size / object size| (>= 0).
    lens_transmittance : float
        tau_lens in (0, 1].

    Returns
    -------
    float
        k = A_pix t_exp tau_lens pi / (4 N^2 (1 + m)^2); electrons = k L for an on-axis pixel
        seeing a Lambertian object of effective photon radiance L (photons s^-1 m^-2 sr^-1).

    References
    ----------
    Smith, *Modern Optical Engineering* (2008), radiometry; Holst, *CCD Arrays, Cameras and
    Displays* (1998) pp. 33-34; EMVA 1288 Release 4.0 Linear (2021), mathematical model.
    """
    a = _positive("pixel_area_m2", pixel_area_m2)
    t = _positive("exposure_s", exposure_s)
    n = _positive("f_number", f_number)
    m = _non_negative("magnification", magnification)
    tau = _positive("lens_transmittance", lens_transmittance)
    if tau > 1.0:
        raise ValueError(f"lens_transmittance = {tau:g}: must be in (0, 1]")
    return a * t * tau * math.pi / (4.0 * n * n * (1.0 + m) ** 2)


def cos4_relative_illumination(height_px: int, width_px: int, pixel_pitch_m: float, image_distance_m: float) -> np.ndarray:
    """cos^4 off-axis fall-off (H, W) of a crop centred on the optical axis (1 on axis).

    cos(theta) = v / sqrt(v^2 + r^2), with r the distance of the pixel centre from the crop centre
    on the die and v the lens-to-image distance (f (1 + m)) [Smith 2008, radiometry].
    """
    h, w = _count("height_px", height_px), _count("width_px", width_px)
    p = _positive("pixel_pitch_m", pixel_pitch_m)
    v = _positive("image_distance_m", image_distance_m)
    y = (np.arange(h) - (h - 1) / 2.0) * p
    x = (np.arange(w) - (w - 1) / 2.0) * p
    r2 = y[:, None] ** 2 + x[None, :] ** 2
    return (v * v / (v * v + r2)) ** 2


def signal_electrons(radiance, electrons_per_radiance: float, relative_illumination=None) -> np.ndarray:
    """Mean signal electrons (..., H, W, 3) float64 of effective photon radiance (..., H, W, 3).

    radiance: photons s^-1 m^-2 sr^-1 per channel (QE and optics already applied);
    electrons_per_radiance: m^2 sr s (:func:`electrons_per_radiance`); relative_illumination: None
    or (H, W) in [0, 1].
    """
    rad = _check_radiance(radiance)
    e = rad.astype(np.float64) * float(electrons_per_radiance)
    if relative_illumination is not None:
        e *= _check_relative_illumination(relative_illumination, rad.shape[-3:-1])[..., None]
    return e


# -------------------------------------------------------------------------------------- sensor
def expose_electrons(
    radiance,
    rng: np.random.Generator,
    *,
    electrons_per_radiance: float,
    dark_electrons: float = 0.0,
    read_noise_e: float = 0.0,
    full_well_e: float = math.inf,
    bayer: bool = True,
    noise: bool = True,
    relative_illumination=None,
    exact_poisson_below_e2: float = EXACT_POISSON_BELOW_E2,
    dtype=np.float32,
) -> np.ndarray:
    """Electrons read out of each photosite in one exposure (before gain and ADC).

    Parameters
    ----------
    radiance : array (H, W, 3) or (B, H, W, 3)
        Effective photon radiance per channel, photons s^-1 m^-2 sr^-1 (QE and optics applied).
    rng : numpy.random.Generator
        The only source of randomness (unused when ``noise`` is False).
    electrons_per_radiance : float
        Camera-equation factor k, m^2 sr s (:func:`electrons_per_radiance`).
    dark_electrons : float
        Mean dark electrons per photosite over the exposure (dark current x exposure).
    read_noise_e : float
        Read noise, e- rms.
    full_well_e : float
        Full-well capacity, e-: the collected charge saturates there.
    bayer : bool
        True: RGGB colour filter, one channel per photosite, output (..., H, W). False: every pixel
        sees all three channels (a three-chip camera), output (..., H, W, 3).
    noise : bool
        False: the mean (signal + dark) electrons clipped to the full well, no random numbers.
    relative_illumination : None or array (H, W)
        Multiplies the signal (e.g. :func:`cos4_relative_illumination`).
    exact_poisson_below_e2 : float
        Photosites whose shot + read variance is below this (e-^2) get an exact Poisson count
        when the read noise is below ``EXACT_POISSON_READ_NOISE_BELOW_E`` (2 e-); the others the
        skewness-corrected normal of the module docstring.
    dtype : numpy float dtype
        float32 (fast) or float64 (for exact comparisons).

    Returns
    -------
    ndarray (..., H, W) with Bayer, else (..., H, W, 3), of ``dtype``, e-; values above the full
    well are clipped to it; read noise may make dark values negative (below the black level).

    References
    ----------
    Janesick, *Photon Transfer* (2007); EMVA 1288 Release 4.0 Linear (2021), mathematical model.
    """
    rad = _check_radiance(radiance)
    cfg = _exposure_config(
        rad.shape[-3:-1], electrons_per_radiance, dark_electrons, read_noise_e, full_well_e, bayer, noise, relative_illumination, exact_poisson_below_e2, dtype
    )
    if rad.ndim == 3:
        return _expose_frame(rad, rng, cfg)
    # frame by frame: the temporaries of one frame stay in cache (2x faster than whole batches)
    out = np.empty(rad.shape[:-1] if cfg.bayer else rad.shape, cfg.dtype)
    for b in range(rad.shape[0]):
        out[b] = _expose_frame(rad[b], rng, cfg)
    return out


class _Exposure(NamedTuple):
    """Validated scalars of one exposure (see :func:`expose_electrons`)."""

    k: float
    dark: float
    sigma_r: float
    fw: float
    bayer: bool
    noise: bool
    rel: np.ndarray | None
    threshold: float
    dtype: np.dtype


def _exposure_config(hw, k, dark, sigma_r, fw, bayer, noise, rel, threshold, dtype) -> _Exposure:
    threshold = _positive("exact_poisson_below_e2", threshold)  # > 0: a zero variance is always exact
    dtype = np.dtype(dtype)
    if dtype not in (np.float32, np.float64):
        raise ValueError(f"dtype = {dtype}: must be float32 or float64")
    return _Exposure(
        k=_non_negative("electrons_per_radiance", k),
        dark=_non_negative("dark_electrons", dark),
        sigma_r=_non_negative("read_noise_e", sigma_r),
        fw=_positive("full_well_e", fw, allow_inf=True),
        bayer=bool(bayer),
        noise=bool(noise),
        rel=None if rel is None else _check_relative_illumination(rel, hw),
        threshold=threshold,
        dtype=dtype,
    )


def _expose_frame(rad: np.ndarray, rng: np.random.Generator, cfg: _Exposure, mono_k=None) -> np.ndarray:
    """:func:`expose_electrons` of one validated frame (H, W, 3); with ``mono_k`` (3,) float32, of
    the frame ``rad[..., None] * mono_k`` from its mono radiance ``rad`` (H, W), the Bayer sensor's
    one channel per photosite only (:func:`capture_mono`)."""
    k, dtype = cfg.k, cfg.dtype
    # mean electrons; a radiance near the float maximum may overflow to inf here, which the cap
    # below turns back into a finite, saturating value
    with np.errstate(over="ignore"):
        if cfg.bayer:
            mu = np.empty(rad.shape[:2], dtype)
            for r0, c0, ch in _RGGB:
                site = mu[r0::2, c0::2]
                if mono_k is None:
                    np.multiply(rad[r0::2, c0::2, ch], k, out=site, casting="same_kind")
                else:  # the channel's radiance rounded as the (H, W, 3) product rounds it, then the same product
                    np.multiply(rad[r0::2, c0::2], mono_k[ch], out=site, casting="same_kind")
                    np.multiply(site, k, out=site, casting="same_kind")
            if cfg.rel is not None:
                mu *= cfg.rel
        else:
            mu = np.multiply(rad if mono_k is None else rad[..., None] * mono_k, k, dtype=dtype)
            if cfg.rel is not None:
                mu *= cfg.rel[..., None]
    if cfg.dark:
        mu += dtype.type(cfg.dark)
    if not cfg.noise:
        return np.minimum(mu, cfg.fw, out=mu)
    # Charge far above the full well ends at the full well whatever the noise; capping the mean
    # keeps inf out of the arithmetic (inf - inf = nan).
    cap = 2.0 * cfg.fw + 10.0 * cfg.sigma_r + 100.0 if math.isfinite(cfg.fw) else np.finfo(np.float32).max / 4
    np.minimum(mu, dtype.type(cap), out=mu)

    z = _standard_normal_f32(rng, mu.size).reshape(mu.shape)
    if dtype == np.float64:
        z = z.astype(np.float64)
    s2 = mu + dtype.type(cfg.sigma_r**2)
    exact = None
    if cfg.sigma_r < EXACT_POISSON_READ_NOISE_BELOW_E:
        small = s2 < cfg.threshold
        exact = np.flatnonzero(small) if small.any() else None
    if exact is not None:
        mu_exact = mu.ravel()[exact].astype(np.float64)
        z_exact = z.ravel()[exact].astype(np.float64)
    with np.errstate(invalid="ignore", divide="ignore"):  # s2 = 0 only where the exact branch overwrites
        e = _gaussian_shot_read(mu, z, s2)
    if exact is not None:
        counts = rng.poisson(mu_exact)
        e.ravel()[exact] = counts + cfg.sigma_r * z_exact
    return np.minimum(e, dtype.type(cfg.fw), out=e)


def _gaussian_shot_read(mu: np.ndarray, z: np.ndarray, s2: np.ndarray) -> np.ndarray:
    """Poisson(mu) + N(0, s2 - mu) from standard normals z: mu + s z + mu / (6 s^2) (z^2 - 1).

    The Cornish-Fisher expansion to the skewness term: mean, variance (+1/18 e-^2 at most) and
    third cumulant (mu) match. Monotone in z for z > -3 s^3 / mu <= -13 when s^2 >= 20, far beyond
    the |z| <= 5.77 of the float32 Box-Muller. Overwrites z and s2; returns a new array.
    """
    c = np.divide(mu, s2)
    c *= c.dtype.type(1.0 / 6.0)
    np.sqrt(s2, out=s2)
    s2 *= z  # s z
    np.multiply(z, z, out=z)
    z -= 1.0
    z *= c  # skewness term
    z += s2
    z += mu
    return z


def _standard_normal_f32(rng: np.random.Generator, n: int) -> np.ndarray:
    """n standard normals, float32, by Box-Muller on float32 uniforms (|z| <= BOX_MULLER_Z_MAX)."""
    m = (n + 1) // 2
    u = _uniform_f32(rng, 2 * m).reshape(2, m)
    r, theta = u[0], u[1]
    np.subtract(np.float32(1.0), r, out=r)  # (0, 1]: log is finite
    np.log(r, out=r)
    r *= np.float32(-2.0)
    np.sqrt(r, out=r)
    theta *= np.float32(2.0 * math.pi)
    z = np.empty(2 * m, np.float32)
    np.cos(theta, out=z[:m])
    np.sin(theta, out=z[m:])
    z[:m] *= r
    z[m:] *= r
    return z[:n]


#: the largest |z| of :func:`_standard_normal_f32`: sqrt(-2 ln 2^-24) = 5.768 (its smallest uniform
#: 1 - u is 2^-24), rounded up past float32's rounding of the log and the root
BOX_MULLER_Z_MAX = 5.77


def _uniform_f32(rng: np.random.Generator, n: int) -> np.ndarray:
    """``rng.random(n, dtype=np.float32)`` byte for byte, n even, with the generator left where that
    leaves it (but for its spare half-word, which is unused while ``has_uint32`` is 0).

    numpy makes each float32 uniform from the next 32 bits of the bit generator, (w >> 8) 2^-24,
    and PCG64 hands out each 64-bit word as its low then its high half; drawing the n / 2 words
    at once (``random_raw``) and splitting them costs 0.14 + 0.03 ms per 350 x 350 frame against
    0.29-0.40 ms for numpy's float32 loop (a call per value). Other bit generators, or a PCG64
    holding a spare half-word, take numpy's own loop."""
    bits = rng.bit_generator
    if n % 2 or type(bits) is not np.random.PCG64 or bits.state["has_uint32"]:
        return rng.random(n, dtype=np.float32)
    words = bits.random_raw(n // 2).view(np.uint32)  # little-endian: low half, then high half
    if words.dtype.byteorder == ">" or (words.dtype.byteorder == "=" and np.little_endian is False):  # pragma: no cover - big-endian host
        words = words.reshape(-1, 2)[:, ::-1].ravel()
    words >>= np.uint32(8)
    u = words.astype(np.float32)
    u *= np.float32(2.0**-24)
    return u


def dark_frame_dn8(params: "CameraParams", *, noise: bool = True) -> int | None:
    """The 8-bit value that every photosite of a frame without light reads whatever its noise
    draw, or None where the draw can change it (or the exact Poisson branch draws counts).

    Without light each photosite's mean is the dark charge mu; its charge mu + s z + mu / (6 s^2)
    (z^2 - 1) grows with z over |z| <= BOX_MULLER_Z_MAX (where -3 s^3 / mu lies below it), and the
    gain, ADC and 8 bits keep the order, so the two ends of z bound every draw: where both ends,
    widened by 0.01 DN (float32's rounding of values below 2^bits), read the same 8-bit step, so
    does every photosite. At the defaults (read noise 8 e-, 80 e- per 10-bit DN) a dark photosite
    reads 49.4-50.6 DN: 12 in 8 bits, always."""
    cfg_dark = np.float32(params.dark_electrons)
    sigma_r = params.effective_read_noise_e
    fw = params.effective_full_well_e
    s2 = np.float32(cfg_dark + np.float32(sigma_r**2))
    if noise and sigma_r < EXACT_POISSON_READ_NOISE_BELOW_E and s2 < EXACT_POISSON_BELOW_E2:
        return None  # counts drawn from numpy's Poisson sampler: unbounded
    mu, s = float(cfg_dark), math.sqrt(float(s2))
    if noise and math.isfinite(fw):  # _expose_frame's cap on the mean
        mu = min(mu, 2.0 * fw + 10.0 * sigma_r + 100.0)
    if noise and mu > 0 and 3.0 * s**3 / mu <= BOX_MULLER_Z_MAX:
        return None  # the skewness term turns the charge back down within the draws' range
    zs = (-BOX_MULLER_Z_MAX, BOX_MULLER_Z_MAX) if noise and s > 0 else (0.0, 0.0)
    gain = params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0)
    full = 2**params.adc_bits - 1
    steps = set()
    for z, widen in zip(zs, (-0.01, 0.01)):
        e = mu + s * z + (mu / (6.0 * s * s) * (z * z - 1.0) if s > 0 else 0.0) if noise else mu
        dn = min(max(round(min(e, fw) * gain + params.black_level_dn + widen), 0), full)
        steps.add(int(dn) >> (params.adc_bits - 8))
    return steps.pop() if len(steps) == 1 else None


# ------------------------------------------------------------------------------- readout chain
def digitize(electrons, *, conversion_gain_dn_per_e: float, gain_db: float, black_level_dn: float, adc_bits: int) -> np.ndarray:
    """ADC output (same shape, uint16) DN = round(e- K 10^(gain_db / 20) + black), in [0, 2^bits - 1].

    electrons: float e- (may be negative from read noise); conversion_gain_dn_per_e: K, DN per e-
    at 0 dB and ``adc_bits``; black_level_dn at ``adc_bits`` [EMVA 1288 R4.0, linear model].
    """
    g = _positive("conversion_gain_dn_per_e", conversion_gain_dn_per_e) * 10.0 ** (_finite("gain_db", gain_db) / 20.0)
    bits = _adc_bits(adc_bits)
    black = _non_negative("black_level_dn", black_level_dn)
    x = np.asarray(electrons)
    x = x * np.float32(g) if x.dtype == np.float32 else x.astype(np.float64) * g
    return _adc_inplace(x, black, bits).astype(np.uint16)


def _adc_inplace(x: np.ndarray, black: float, bits: int) -> np.ndarray:
    """x (DN before the offset, float) -> round(x + black) clipped to [0, 2^bits - 1], in place."""
    x += x.dtype.type(black)
    np.rint(x, out=x)
    return np.clip(x, 0, 2**bits - 1, out=x)


def to_8bit(dn, adc_bits: int) -> np.ndarray:
    """8-bit output (uint8) of ADC codes: the low bits dropped, floor(DN 256 / 2^adc_bits)."""
    bits = _adc_bits(adc_bits)
    dn = np.asarray(dn)
    if not np.issubdtype(dn.dtype, np.integer):
        raise ValueError(f"dn has dtype {dn.dtype}: must be integer ADC codes (the output of digitize)")
    return (dn >> (bits - 8)).astype(np.uint8)


def demosaic_rggb(raw) -> np.ndarray:
    """RGB (..., H, W, 3) uint8 from an RGGB mosaic (..., H, W) uint8 (red at row 0, column 0).

    OpenCV's bilinear demosaic, frame by frame (H, W >= 2).
    """
    raw = np.asarray(raw)
    if raw.dtype != np.uint8 or raw.ndim not in (2, 3) or raw.shape[-1] < 2 or raw.shape[-2] < 2:
        raise ValueError(f"raw has shape {raw.shape} and dtype {raw.dtype}: need uint8 (H, W) or (B, H, W) with H, W >= 2")
    flat = np.ascontiguousarray(raw).reshape((-1,) + raw.shape[-2:])
    out = np.empty(flat.shape + (3,), np.uint8)
    for i in range(flat.shape[0]):
        cv2.cvtColor(flat[i], _CV_RGGB2RGB, dst=out[i])
    return out.reshape(raw.shape + (3,))


# ------------------------------------------------------------------------------------ parameters
_FOCAL_LENGTH_M = focal_length_to_fit_m(_SURFACE_WIDTH_M, _CROP_PX, _BINNING * _PIXEL_PITCH_M, _OBJECT_DISTANCE_M)  # 3.203 mm


@dataclass(frozen=True)
class CameraParams:
    """Camera parameters, SI units in the names; defaults are an IMX415-class camera.

    Per-pixel sensor values are for one **native** 1.45 um photosite; the effective (binned)
    values follow from ``binning`` (module docstring). The default focal length is derived so that
    the 36 mm surface at ``object_distance_m`` fills ``width_px`` effective pixels.
    """

    fps: float = 30.0  # SPEC 1.1
    width_px: int = 350  # SPEC 1.1 crop
    height_px: int = 350  # SPEC 1.1 crop
    exposure_s: float = 0.033  # scene default (camera.exposure_ms = 33); must be <= 1 / fps
    gain_db: float = 0.0  # analog (+ digital) gain; IMX415 analog range 0-30 dB [4]
    pixel_pitch_m: float = _PIXEL_PITCH_M  # IMX415 data sheet: 1.45 um unit cell [4]
    binning: int = _BINNING  # native pixels per output pixel along each axis (module docstring)
    focal_length_m: float = _FOCAL_LENGTH_M  # 3.203 mm: 36 mm at 60 mm onto 350 x 5.8 um (derived)
    f_number: float = 2.0  # typical M12 board lens, not given
    object_distance_m: float = _OBJECT_DISTANCE_M  # lens to sensing surface, ~60 mm in the 65 mm shell
    magnification: float | None = None  # None: f / (d - f) from the thin-lens focus
    lens_transmittance: float = 0.9  # typical multi-coated glass/plastic lens, not given
    cos4_falloff: bool = False  # off: the renderer models the geometry
    bayer: bool = True  # RGGB colour filter (IMX415 reads GBRG [4]; a crop from an odd row is RGGB)
    full_well_e: float = 5000.0  # typical for 1.4-1.5 um BSI pixels (4-6 ke-), not given [4]
    read_noise_e: float = 2.0  # e- rms at 0 dB, typical for small BSI pixels, not given
    dark_current_e_per_s: float = 5.0  # typical at a 40-60 C die, not given
    conversion_gain_dn_per_e: float = 0.2  # at 0 dB and 10 bits: full well ~ full scale (5000 x 0.2 + 50 > 1023); typical, not given
    black_level_dn: float = 50.0  # IMX415 BLKLEVEL default at 10 bits (Linux imx415 driver) [4]
    adc_bits: int = 10  # IMX415 RAW10 (12 also available [4]); K and the black level are at this depth

    def __post_init__(self):
        for name in ("fps", "exposure_s", "pixel_pitch_m", "focal_length_m", "f_number", "object_distance_m", "lens_transmittance", "full_well_e", "conversion_gain_dn_per_e"):
            _positive(name, getattr(self, name))
        for name in ("gain_db", "read_noise_e", "dark_current_e_per_s", "black_level_dn"):
            _non_negative(name, getattr(self, name))
        for name in ("width_px", "height_px", "binning", "adc_bits"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"{name} = {v!r}: must be an integer")
        for name in ("width_px", "height_px"):
            if getattr(self, name) < 2:
                raise ValueError(f"{name} = {getattr(self, name)}: must be >= 2 (a Bayer cell is 2 x 2)")
        if self.binning < 1:
            raise ValueError(f"binning = {self.binning}: must be >= 1 (native pixels per output pixel along each axis)")
        _adc_bits(self.adc_bits)
        for name in ("cos4_falloff", "bayer"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"{name} = {getattr(self, name)!r}: must be True or False")
        if self.lens_transmittance > 1.0:
            raise ValueError(f"lens_transmittance = {self.lens_transmittance:g}: must be in (0, 1]")
        if self.gain_db > 72.0:
            raise ValueError(f"gain_db = {self.gain_db:g}: must be <= 72 (a sanity bound: IMX415-class sensors give 30 dB analog plus digital gain)")
        if self.black_level_dn >= 2**self.adc_bits - 1:
            raise ValueError(f"black_level_dn = {self.black_level_dn:g}: must be below the {self.adc_bits}-bit full scale {2**self.adc_bits - 1}")
        if self.magnification is None:
            if self.object_distance_m <= self.focal_length_m:
                raise ValueError(
                    f"object_distance_m = {self.object_distance_m:g} must exceed focal_length_m = {self.focal_length_m:g}: "
                    "move the object beyond the focal length or set magnification"
                )
        else:
            _positive("magnification", self.magnification)
        _check_exposure(self.fps, self.exposure_s)

    @classmethod
    def from_scene(cls, camera_spec, **overrides) -> "CameraParams":
        """Parameters from the scene's camera section: every field both carry (``exposure_ms`` and
        ``focal_length_mm`` converted to seconds and metres; ``focal_length_mm = None`` keeps the
        default), then ``overrides`` (e.g. the renderer's ``focal_length_m`` and ``object_distance_m``)."""
        fps, exposure_ms = float(camera_spec.fps), float(camera_spec.exposure_ms)
        _check_exposure(fps, exposure_ms * 1e-3, fps_name="camera.fps", exposure_name="camera.exposure_ms", exposure_scale=1e3)
        values = {f.name: getattr(camera_spec, f.name) for f in fields(cls) if hasattr(camera_spec, f.name)}
        values["exposure_s"] = exposure_ms * 1e-3
        if getattr(camera_spec, "focal_length_mm", None) is not None:
            values["focal_length_m"] = camera_spec.focal_length_mm * 1e-3
        values.update(overrides)
        return cls(**values)

    # derived quantities --------------------------------------------------------------------
    @property
    def effective_pixel_pitch_m(self) -> float:
        return self.binning * self.pixel_pitch_m

    @property
    def pixel_area_m2(self) -> float:
        """Collecting area of one effective pixel (fill factor 1: BSI with microlenses)."""
        return self.effective_pixel_pitch_m**2

    @property
    def resolved_magnification(self) -> float:
        if self.magnification is not None:
            return float(self.magnification)
        return magnification_from_focus(self.focal_length_m, self.object_distance_m)

    @property
    def image_distance_m(self) -> float:
        return self.focal_length_m * (1.0 + self.resolved_magnification)

    @property
    def electrons_per_radiance_m2_sr_s(self) -> float:
        return electrons_per_radiance(self.pixel_area_m2, self.exposure_s, self.f_number, self.resolved_magnification, self.lens_transmittance)

    @property
    def effective_full_well_e(self) -> float:
        return self.binning**2 * self.full_well_e

    @property
    def effective_read_noise_e(self) -> float:
        return self.binning * self.read_noise_e

    @property
    def dark_electrons(self) -> float:
        """Mean dark electrons per effective pixel over one exposure."""
        return self.binning**2 * self.dark_current_e_per_s * self.exposure_s

    @property
    def effective_conversion_gain_dn_per_e(self) -> float:
        """DN per summed electron at 0 dB (the ISP averages the binning^2 native pixels)."""
        return self.conversion_gain_dn_per_e / self.binning**2

    def relative_illumination(self) -> np.ndarray | None:
        """The cos^4 map (H, W) when ``cos4_falloff`` is on, else None."""
        if not self.cos4_falloff:
            return None
        return cos4_relative_illumination(self.height_px, self.width_px, self.effective_pixel_pitch_m, self.image_distance_m)

    def as_dict(self) -> dict:
        return {f.name: getattr(self, f.name) for f in fields(self)}


# ------------------------------------------------------------------------------------- pipeline
def capture(radiance, rng: np.random.Generator, params: CameraParams, *, noise: bool = True, relative_illumination=None) -> np.ndarray:
    """Camera frames: uint8 RGB (H, W, 3) or (B, H, W, 3) from effective photon radiance of that shape.

    radiance: photons s^-1 m^-2 sr^-1 per channel, QE and optics already applied (finite, >= 0).
    The whole chain of the module docstring: camera equation, Bayer, dark current, shot and read
    noise, full well, gain, black level, ADC, 8 bits, demosaic. ``relative_illumination`` (H, W)
    overrides the params' cos^4 map. ``noise=False`` gives the noiseless mean (still quantised).
    """
    if not isinstance(params, CameraParams):
        raise ValueError(f"params is a {type(params).__name__}: pass a CameraParams")
    rad = _check_radiance(radiance)
    if relative_illumination is None:
        relative_illumination = params.relative_illumination()
    cfg = _exposure_config(
        rad.shape[-3:-1],
        params.electrons_per_radiance_m2_sr_s,
        params.dark_electrons,
        params.effective_read_noise_e,
        params.effective_full_well_e,
        params.bayer,
        noise,
        relative_illumination,
        EXACT_POISSON_BELOW_E2,
        np.float32,
    )
    frames = rad[None] if rad.ndim == 3 else rad
    out = np.empty(frames.shape[:-1] + (3,), np.uint8)
    # frame by frame (same bytes as expose_electrons -> digitize -> to_8bit -> demosaic_rggb)
    for b in range(frames.shape[0]):
        _read_out(_expose_frame(frames[b], rng, cfg), params, out[b])
    return out[0] if rad.ndim == 3 else out


def capture_mono(radiance, k, rng: np.random.Generator, params: CameraParams, *, noise: bool = True, relative_illumination=None) -> np.ndarray:
    """:func:`capture` of the frames ``radiance[..., None] * k``, byte for byte, from the mono
    radiance (H, W) or (B, H, W) float32 and the channels' factors k (3,) float32 (a light of one
    spectrum: the ML layer's). The Bayer sensor reads one channel per photosite, so only that one
    is formed: the (H, W, 3) product and its check cost 1.6 ms a 350 x 350 frame (numpy's
    broadcast over a last axis of 3), most of the camera stage."""
    rad = np.asarray(radiance)
    k = np.asarray(k)
    if rad.dtype != np.float32 or k.dtype != np.float32 or k.shape != (3,) or rad.ndim not in (2, 3) or not params.bayer:
        return capture(rad[..., None] * k, rng, params, noise=noise, relative_illumination=relative_illumination)
    frames = rad[None] if rad.ndim == 2 else rad
    # what capture's check of the (H, W, 3) product would refuse (NaN, inf, < 0, or a product that overflows)
    with np.errstate(over="ignore"):
        overflows = frames.size == 0 or not np.isfinite(frames.max() * k.max())
    if overflows or not (frames.min() >= 0 and k.min() >= 0):
        return capture(rad[..., None] * k, rng, params, noise=noise, relative_illumination=relative_illumination)
    if relative_illumination is None:
        relative_illumination = params.relative_illumination()
    cfg = _exposure_config(frames.shape[1:], params.electrons_per_radiance_m2_sr_s, params.dark_electrons, params.effective_read_noise_e,
                           params.effective_full_well_e, params.bayer, noise, relative_illumination, EXACT_POISSON_BELOW_E2, np.float32)
    out = np.empty(frames.shape + (3,), np.uint8)
    for b in range(frames.shape[0]):
        if not _capture_mono_compiled(frames[b], rng, cfg, k, params, out[b]):
            _read_out(_expose_frame(frames[b], rng, cfg, mono_k=k), params, out[b])
    return out[0] if rad.ndim == 2 else out


def _capture_mono_compiled(rad: np.ndarray, rng: np.random.Generator, cfg: _Exposure, mono_k: np.ndarray, params: CameraParams,
                           out: np.ndarray) -> bool:
    """``_read_out(_expose_frame(rad, rng, cfg, mono_k), params, out)`` byte for byte in one compiled
    pass (:func:`mlsim.camera_kernels.bayer_mono_codes`) where no photosite can take the exact
    Poisson branch (read noise >= EXACT_POISSON_READ_NOISE_BELOW_E: the defaults); returns False,
    having drawn nothing, where it does not apply."""
    if not (cfg.noise and cfg.bayer and cfg.dtype == np.float32 and cfg.sigma_r >= EXACT_POISSON_READ_NOISE_BELOW_E):
        return False
    from mlsim.camera_kernels import bayer_mono_codes

    f32 = np.float32
    cap = 2.0 * cfg.fw + 10.0 * cfg.sigma_r + 100.0 if math.isfinite(cfg.fw) else np.finfo(np.float32).max / 4
    z = _standard_normal_f32(rng, rad.size)
    raw = np.empty(rad.shape, np.uint8)
    rel = np.zeros((0, 0)) if cfg.rel is None else cfg.rel
    gain = f32(params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0))
    with np.errstate(over="ignore"):  # as _expose_frame: a radiance near the float maximum overflows the mean, which the cap turns back
        bayer_mono_codes(np.ascontiguousarray(rad), mono_k, f32(cfg.k), rel, f32(cfg.dark), f32(cap), f32(cfg.sigma_r**2), f32(cfg.fw), z, gain,
                         f32(params.black_level_dn), f32(2**params.adc_bits - 1), f32(2.0 ** (8 - params.adc_bits)), raw)
    cv2.cvtColor(raw, _CV_RGGB2RGB, dst=out)
    return True


def _read_out(x: np.ndarray, params: CameraParams, out: np.ndarray) -> None:
    """Electrons (H, W) float32 -> gain, ADC, 8 bits, demosaic into ``out`` (H, W, 3) uint8 (x is overwritten)."""
    gain = np.float32(params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0))
    to8 = np.float32(2.0 ** (8 - params.adc_bits))  # exact: floor(DN / 2^(bits - 8)) of integer DN
    x *= gain
    _adc_inplace(x, params.black_level_dn, params.adc_bits)
    x *= to8
    np.floor(x, out=x)
    if params.bayer:
        cv2.cvtColor(x.astype(np.uint8), _CV_RGGB2RGB, dst=out)
    else:
        out[...] = x


class Camera:
    """The camera with fixed parameters: ``Camera(params)(radiance, rng)`` is :func:`capture`."""

    def __init__(self, params: CameraParams | None = None):
        self.params = CameraParams() if params is None else params
        if not isinstance(self.params, CameraParams):
            raise ValueError(f"params is a {type(self.params).__name__}: pass a CameraParams")
        self._relative_illumination = self.params.relative_illumination()
        self._dark_frames: dict[bool, np.ndarray | None] = {}  # noise -> the frame without light, where no draw changes it

    def __call__(self, radiance, rng: np.random.Generator, *, noise: bool = True) -> np.ndarray:
        p = self.params
        shape = np.shape(radiance)
        if len(shape) >= 3 and shape[-3:-1] != (p.height_px, p.width_px):
            raise ValueError(
                f"radiance is {shape[-3]} x {shape[-2]} px (H x W) but the camera is {p.height_px} x {p.width_px}: "
                "render at the camera's height_px x width_px"
            )
        return capture(radiance, rng, p, noise=noise, relative_illumination=self._relative_illumination)

    def mono(self, radiance, k, rng: np.random.Generator, *, noise: bool = True) -> np.ndarray:
        """:func:`capture_mono`: ``self(radiance[..., None] * k, rng)`` byte for byte, from the mono radiance (H, W)."""
        p = self.params
        if np.shape(radiance)[-2:] != (p.height_px, p.width_px):
            raise ValueError(f"radiance is {' x '.join(map(str, np.shape(radiance)[-2:]))} px (H x W) but the camera is {p.height_px} x "
                             f"{p.width_px}: render at the camera's height_px x width_px")
        return capture_mono(radiance, k, rng, p, noise=noise, relative_illumination=self._relative_illumination)

    def dark(self, rng: np.random.Generator, *, noise: bool = True) -> np.ndarray:
        """``self(np.zeros((H, W, 3), np.float32), rng, noise=noise)`` byte for byte, with ``rng``
        left where that leaves it (but for PCG64's unused spare half-word): a frame without light.

        Where no draw of the noise reaches another 8-bit step (:func:`dark_frame_dn8`; at the
        defaults a dark photosite reads 12 whatever its draw) the frame is that step demosaiced,
        and a PCG64 generator is advanced past the draws the frame would have taken (a
        350 x 350 frame's normals cost 0.4-0.7 ms; the DLLM initialises on 30 such frames before
        each episode). Otherwise, or with another bit generator, the frame is drawn."""
        p = self.params
        bits = rng.bit_generator
        if noise and (type(bits) is not np.random.PCG64 or bits.state["has_uint32"]):
            return self(np.zeros((p.height_px, p.width_px, 3), np.float32), rng, noise=noise)
        if noise not in self._dark_frames:
            dn8 = dark_frame_dn8(p, noise=noise)
            frame = None
            if dn8 is not None:
                frame = np.empty((p.height_px, p.width_px, 3), np.uint8)
                if p.bayer:  # as _read_out: the mosaic demosaiced by OpenCV (a constant stays one, but its bytes are OpenCV's)
                    cv2.cvtColor(np.full((p.height_px, p.width_px), dn8, np.uint8), _CV_RGGB2RGB, dst=frame)
                else:
                    frame[...] = dn8
            self._dark_frames[noise] = frame
        frame = self._dark_frames[noise]
        if frame is None:
            return self(np.zeros((p.height_px, p.width_px, 3), np.float32), rng, noise=noise)
        if noise:  # _expose_frame's one draw of float32 uniforms: ceil(n / 2) words for its n photosites
            n = p.height_px * p.width_px * (1 if p.bayer else 3)
            bits.advance((n + 1) // 2)
        return frame.copy()

    def frame_times_s(self, n_frames: int) -> np.ndarray:
        return frame_times_s(n_frames, self.params.fps)

    def exposure_windows_s(self, n_frames: int) -> np.ndarray:
        return exposure_windows_s(n_frames, self.params.fps, self.params.exposure_s)
