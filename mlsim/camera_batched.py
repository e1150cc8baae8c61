"""The camera model of :mod:`mlsim.camera` over a batch of episodes at once, in torch (any device).

The same radiometric and sensor model as :func:`mlsim.camera.capture` (camera equation [1], RGGB
Bayer, dark current, shot and read noise, full well, gain, black level, ADC [3], the 8-bit cut and
OpenCV's bilinear demosaic), on tensors of many frames of many episodes, so that a GPU runs it as
a few large kernels instead of a Python loop per frame.

What is the same and what is not (``tests/test_batched_chain.py``):

- without noise the frames are **the same bytes** as :func:`mlsim.camera.capture`: the same float32
  (and, where numpy widens, float64) operations in the same order, round-half-to-even in both, and
  :func:`demosaic_rggb_batched` reproduces OpenCV's fixed-point bilinear demosaic (interior
  (a + b + 1) >> 1 and (a + b + c + d + 2) >> 2, borders copied from the next row and column
  in), bit for bit on random mosaics;
- with noise the random numbers are torch's, not numpy's: each episode draws its standard
  normals from its own ``torch.Generator`` (``torch.randn``, one call per episode for all its
  frames: the same seed gives the same bytes whatever else is in the batch, on one device), and
  the exact Poisson branch (read noise below ``EXACT_POISSON_READ_NOISE_BELOW_E`` and variance
  below ``EXACT_POISSON_BELOW_E2``) draws ``torch.poisson`` from the same generator. The
  model's distribution is the CPU path's: the skewness-corrected normal of [5] elsewhere, whose
  first three cumulants are Poisson(mu) + N(0, sigma_r^2)'s. ``torch.randn`` has unbounded
  tails where the CPU's float32 Box-Muller stops at |z| = 5.77 (probability 8e-9).

References
----------
.. [1] W. J. Smith, *Modern Optical Engineering*, 4th ed., McGraw-Hill, 2008 (radiometry).
.. [3] EMVA Standard 1288, Release 4.0 Linear (2021), the linear camera model.
.. [5] E. A. Cornish and R. A. Fisher, "Moments and cumulants in the specification of
   distributions", Rev. Int. Stat. Inst. 5 (1938) 307-320.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["CameraConstants", "channel_radiance_batched", "expose_batched", "demosaic_rggb_batched", "capture_batched"]

# the thresholds of mlsim.camera's exact Poisson branch (kept equal by a test; not imported, so that
# this module needs only torch and numpy where it runs)
EXACT_POISSON_BELOW_E2 = 20.0
EXACT_POISSON_READ_NOISE_BELOW_E = 2.0


@dataclass(frozen=True)
class CameraConstants:
    """The numbers :func:`capture_batched` needs, from a :class:`mlsim.camera.CameraParams`
    (:meth:`of`): electrons per unit radiance (m^2 sr s), dark electrons, effective read noise (e-),
    full well (e-), DN per electron with the gain, black level (DN), ADC bits, Bayer or not, and
    the relative illumination (H, W) float64 or None."""

    electrons_per_radiance: float
    dark_electrons: float
    read_noise_e: float
    full_well_e: float
    gain_dn_per_e: float
    black_level_dn: float
    adc_bits: int
    bayer: bool
    relative_illumination: np.ndarray | None = None

    @classmethod
    def of(cls, params) -> "CameraConstants":
        """From a :class:`mlsim.camera.CameraParams` (its effective, binned values)."""
        rel = params.relative_illumination()
        return cls(float(params.electrons_per_radiance_m2_sr_s), float(params.dark_electrons), float(params.effective_read_noise_e),
                   float(params.effective_full_well_e), float(params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0)),
                   float(params.black_level_dn), int(params.adc_bits), bool(params.bayer), None if rel is None else np.asarray(rel, np.float64))


def _check_finite(x: torch.Tensor, name: str, fix: str) -> None:
    if x.is_floating_point() and not bool(torch.isfinite(x).all()):
        n_nan, n_inf = int(torch.isnan(x).sum()), int(torch.isinf(x).sum())
        raise ValueError(f"{name} has {n_nan} NaN and {n_inf} infinite value(s): {fix}")


def channel_radiance_batched(radiance: torch.Tensor, k_ml: torch.Tensor, ambient: torch.Tensor | None = None,
                             level: torch.Tensor | None = None, k_ambient: torch.Tensor | None = None) -> torch.Tensor:
    """Effective photon radiance per channel (..., H, W, 3) float32 of mono ML radiance (..., H, W)
    float32 times the channel factors ``k_ml`` (3,) float32 (:func:`mlsim.render.optics.ml_channel_factors`),
    plus the ambient lamp's leak ``ambient`` (H, W) at ``level`` (...,) (float64, per frame) times its
    factors ``k_ambient`` (3,): :func:`mlsim.render.output.expose`'s sum, in its precision (the leak
    is added in float64 and rounded to float32, as numpy's in-place ``+=`` does)."""
    _check_finite(radiance, "radiance (..., H, W) into the camera", "it comes from the render stage (the emission's photons through the "
                  "transport matrix and the direct raster): check the emission and the solve's stresses")
    ch = radiance.to(torch.float32)[..., None] * k_ml.to(torch.float32)
    if ambient is None:
        return ch
    lv = level.to(torch.float64)
    leak = (lv[..., None, None] * ambient.to(torch.float64))[..., None] * k_ambient.to(torch.float32).to(torch.float64)
    # only frames whose lamp level is > 0 get the leak (expose's `if level[f] > 0`)
    on = (lv > 0)[..., None, None, None]
    return torch.where(on, (ch.to(torch.float64) + leak).to(torch.float32), ch)


def _mosaic_mean(ch: torch.Tensor, c: CameraConstants) -> torch.Tensor:
    """Mean electrons per photosite (..., H, W) float32 (Bayer) of channel radiance (..., H, W, 3)."""
    k = float(c.electrons_per_radiance)
    if c.bayer:
        mu = torch.empty(ch.shape[:-1], dtype=torch.float32, device=ch.device)
        for r0, c0, chan in ((0, 0, 0), (0, 1, 1), (1, 0, 1), (1, 1, 2)):  # RGGB
            mu[..., r0::2, c0::2] = ch[..., r0::2, c0::2, chan] * k
    else:
        mu = ch * k
    if c.relative_illumination is not None:
        rel = torch.as_tensor(c.relative_illumination, dtype=torch.float64, device=ch.device)
        mu = (mu.to(torch.float64) * (rel if c.bayer else rel[..., None])).to(torch.float32)
    if c.dark_electrons:
        mu = mu + np.float32(c.dark_electrons)
    return mu


def expose_batched(channel_radiance: torch.Tensor, c: CameraConstants, generators: list | None = None, noise: bool = True) -> torch.Tensor:
    """Electrons read out of each photosite (B, T, H, W) float32 (Bayer; (B, T, H, W, 3) without),
    for B episodes of T frames of channel radiance (B, T, H, W, 3): :func:`mlsim.camera.expose_electrons`.

    ``generators``: one ``torch.Generator`` on the data's device per episode (its frames' normals in
    one draw, then its Poisson counts); not used when ``noise`` is False. Values above the full well
    are clipped to it."""
    if channel_radiance.ndim != 5 or channel_radiance.shape[-1] != 3:
        raise ValueError(f"channel_radiance of shape {tuple(channel_radiance.shape)}: must be (episodes, frames, H, W, 3)")
    _check_finite(channel_radiance, "channel_radiance (episodes, frames, H, W, 3)", "it comes from the render stage and the channel factors")
    if bool((channel_radiance < 0).any()):
        raise ValueError("channel_radiance has negative values: photon radiance must be >= 0")
    mu = _mosaic_mean(channel_radiance, c)
    fw = float(c.full_well_e)
    if not noise:
        return torch.clamp(mu, max=fw) if math.isfinite(fw) else mu
    B = mu.shape[0]
    if generators is None or len(generators) != B:
        raise ValueError(f"generators: one torch.Generator per episode is needed ({B}), got "
                         f"{'none' if generators is None else len(generators)}")
    # charge far above the full well ends at the full well whatever the noise; capping the mean keeps
    # inf out of the arithmetic (as mlsim.camera)
    cap = 2.0 * fw + 10.0 * c.read_noise_e + 100.0 if math.isfinite(fw) else float(np.finfo(np.float32).max / 4)
    mu = torch.clamp(mu, max=np.float32(cap))
    z = torch.empty_like(mu)
    for b, g in enumerate(generators):
        z[b] = torch.randn(mu.shape[1:], generator=g, dtype=torch.float32, device=mu.device)
    s2 = mu + np.float32(c.read_noise_e ** 2)
    # Cornish-Fisher to the skewness term (mlsim.camera._gaussian_shot_read): mu + s z + mu / (6 s^2) (z^2 - 1)
    coeff = torch.where(s2 > 0, mu / torch.where(s2 > 0, s2, torch.ones_like(s2)), torch.zeros_like(s2)) * np.float32(1.0 / 6.0)
    e = (z * z - 1.0) * coeff + torch.sqrt(s2) * z + mu
    if c.read_noise_e < EXACT_POISSON_READ_NOISE_BELOW_E:
        small = s2 < EXACT_POISSON_BELOW_E2
        if bool(small.any()):
            for b, g in enumerate(generators):
                sb = small[b]
                if bool(sb.any()):
                    counts = torch.poisson(mu[b][sb].to(torch.float64), generator=g)
                    e[b][sb] = (counts + c.read_noise_e * z[b][sb].to(torch.float64)).to(torch.float32)
    return torch.clamp(e, max=fw) if math.isfinite(fw) else e


def demosaic_rggb_batched(raw: torch.Tensor) -> torch.Tensor:
    """RGB (..., H, W, 3) uint8 from RGGB mosaics (..., H, W) uint8: OpenCV's bilinear
    ``COLOR_BayerRGGB2RGB`` bit for bit (its fixed-point rounding; the outer rows and columns copied
    from their neighbours inside), on any device. H, W >= 3."""
    if raw.dtype != torch.uint8 or raw.ndim < 2 or raw.shape[-1] < 3 or raw.shape[-2] < 3:
        raise ValueError(f"raw of dtype {raw.dtype} and shape {tuple(raw.shape)}: need uint8 (..., H, W) with H, W >= 3")
    r = raw.to(torch.int32)
    H, W = r.shape[-2:]
    c = r[..., 1:-1, 1:-1]
    up, down, left, right = r[..., :-2, 1:-1], r[..., 2:, 1:-1], r[..., 1:-1, :-2], r[..., 1:-1, 2:]
    cross = (up + down + left + right + 2) >> 2
    diag = (r[..., :-2, :-2] + r[..., :-2, 2:] + r[..., 2:, :-2] + r[..., 2:, 2:] + 2) >> 2
    hor = (left + right + 1) >> 1
    ver = (up + down + 1) >> 1
    # the parity of each interior pixel (row y + 1, column x + 1 of the mosaic)
    ys = (torch.arange(1, H - 1, device=raw.device) % 2)[:, None]
    xs = (torch.arange(1, W - 1, device=raw.device) % 2)[None, :]
    red_site = (ys == 0) & (xs == 0)
    blue_site = (ys == 1) & (xs == 1)
    g_red_row = (ys == 0) & (xs == 1)  # green between reds along the row
    red = torch.where(red_site, c, torch.where(blue_site, diag, torch.where(g_red_row, hor, ver)))
    blue = torch.where(blue_site, c, torch.where(red_site, diag, torch.where(g_red_row, ver, hor)))
    green = torch.where(red_site | blue_site, cross, c)
    out = torch.empty(raw.shape + (3,), dtype=torch.uint8, device=raw.device)
    out[..., 1:-1, 1:-1, :] = torch.stack([red, green, blue], dim=-1).to(torch.uint8)
    out[..., 1:-1, 0, :] = out[..., 1:-1, 1, :]
    out[..., 1:-1, -1, :] = out[..., 1:-1, -2, :]
    out[..., 0, :, :] = out[..., 1, :, :]
    out[..., -1, :, :] = out[..., -2, :, :]
    return out


def capture_batched(channel_radiance: torch.Tensor, c: CameraConstants, generators: list | None = None, noise: bool = True) -> torch.Tensor:
    """8-bit RGB frames (B, T, H, W, 3) uint8 of channel radiance (B, T, H, W, 3) float32,
    photons s^-1 m^-2 sr^-1 (QE and optics applied): :func:`mlsim.camera.capture` of every frame
    (camera equation, Bayer, noise, full well, gain, black level, ADC, 8 bits, demosaic).
    ``generators``: one per episode (:func:`expose_batched`)."""
    x = expose_batched(channel_radiance, c, generators, noise)
    x = x * np.float32(c.gain_dn_per_e)
    x = x + np.float32(c.black_level_dn)
    x = torch.clamp(torch.round(x), 0, 2 ** c.adc_bits - 1)  # round half to even, as np.rint
    x = torch.floor(x * np.float32(2.0 ** (8 - c.adc_bits)))  # exact: floor(DN / 2^(bits - 8)) of integer DN
    u8 = x.to(torch.uint8)
    return demosaic_rggb_batched(u8) if c.bayer else u8
