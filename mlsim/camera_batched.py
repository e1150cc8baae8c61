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

__all__ = ["CameraConstants", "channel_radiance_batched", "mosaic_mean_batched", "sensor_batched", "expose_batched", "demosaic_rggb_batched",
           "capture_batched", "capture_mono_batched"]

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


_RADIANCE_FIX = ("it comes from the render stage (the emission's photons through the transport matrix and the direct raster): check the "
                 "emission and the solve's stresses")
# RGGB: (row offset, column offset, channel) of the four photosites of a 2 x 2 cell (mlsim.camera._RGGB)
_RGGB = ((0, 0, 0), (0, 1, 1), (1, 0, 1), (1, 1, 2))


def channel_radiance_batched(radiance: torch.Tensor, k_ml: torch.Tensor, ambient: torch.Tensor | None = None,
                             level: torch.Tensor | None = None, k_ambient: torch.Tensor | None = None) -> torch.Tensor:
    """Effective photon radiance per channel (..., H, W, 3) float32 of mono ML radiance (..., H, W)
    float32 times the channel factors ``k_ml`` (3,) float32 (:func:`mlsim.render.optics.ml_channel_factors`),
    plus the ambient lamp's leak ``ambient`` (H, W) at ``level`` (...,) (float64, per frame) times its
    factors ``k_ambient`` (3,): :func:`mlsim.render.output.expose`'s sum, in its precision (the leak
    is added in float64 and rounded to float32, as numpy's in-place ``+=`` does)."""
    _check_finite(radiance, "radiance (..., H, W) into the camera", _RADIANCE_FIX)
    ch = radiance.to(torch.float32)[..., None] * k_ml.to(torch.float32)
    if ambient is None:
        return ch
    lv = level.to(torch.float64)
    leak = (lv[..., None, None] * ambient.to(torch.float64))[..., None] * k_ambient.to(torch.float32).to(torch.float64)
    # only frames whose lamp level is > 0 get the leak (expose's `if level[f] > 0`)
    on = (lv > 0)[..., None, None, None]
    return torch.where(on, (ch.to(torch.float64) + leak).to(torch.float32), ch)


def _illumination_and_dark(mu: torch.Tensor, c: CameraConstants) -> torch.Tensor:
    if c.relative_illumination is not None:
        rel = torch.as_tensor(c.relative_illumination, dtype=torch.float64, device=mu.device)
        # numpy multiplies float32 by the float64 map in float64 and rounds (mlsim.camera._expose_frame)
        mu = (mu.to(torch.float64) * (rel if c.bayer else rel[..., None])).to(torch.float32)
    if c.dark_electrons:
        mu = mu + np.float32(c.dark_electrons)
    return mu


def mosaic_mean_batched(radiance: torch.Tensor, k_ml: torch.Tensor, c: CameraConstants, ambient: torch.Tensor | None = None,
                        level: torch.Tensor | None = None, k_ambient: torch.Tensor | None = None) -> torch.Tensor:
    """Mean electrons per photosite (..., H, W) float32 of the RGGB mosaic, straight from mono ML
    radiance (..., H, W) float32: each site's channel of :func:`channel_radiance_batched` (the same
    float32 product rad k_c; the ambient leak added in float64 and rounded) times the camera
    equation's factor, then the relative illumination and the dark electrons, without the
    (..., H, W, 3) channel tensor of which the mosaic reads a third. ``level`` (...,) float64."""
    if not c.bayer:
        raise ValueError("mosaic_mean_batched is the Bayer camera's; without Bayer use channel_radiance_batched and capture_batched")
    _check_finite(radiance, "radiance (..., H, W) into the camera", _RADIANCE_FIX)
    rad = radiance.to(torch.float32)
    k = float(c.electrons_per_radiance)
    km = [float(v) for v in k_ml.to(torch.float32).cpu()]
    ka = None if ambient is None else [float(v) for v in k_ambient.to(torch.float32).cpu()]
    mu = torch.empty(rad.shape, dtype=torch.float32, device=rad.device)
    for r0, c0, chan in _RGGB:
        v = rad[..., r0::2, c0::2] * km[chan]
        if ambient is not None:
            lv = level.to(torch.float64)[..., None, None]
            leak = (lv * ambient[r0::2, c0::2].to(torch.float64)) * ka[chan]
            v = torch.where(lv > 0, (v.to(torch.float64) + leak).to(torch.float32), v)
        mu[..., r0::2, c0::2] = v * k
    return _illumination_and_dark(mu, c)


def _mosaic_mean(ch: torch.Tensor, c: CameraConstants) -> torch.Tensor:
    """Mean electrons per photosite (..., H, W) float32 (Bayer; (..., H, W, 3) without) of channel
    radiance (..., H, W, 3)."""
    k = float(c.electrons_per_radiance)
    if c.bayer:
        mu = torch.empty(ch.shape[:-1], dtype=torch.float32, device=ch.device)
        for r0, c0, chan in _RGGB:
            mu[..., r0::2, c0::2] = ch[..., r0::2, c0::2, chan] * k
    else:
        mu = ch * k
    return _illumination_and_dark(mu, c)


def _check_generators(generators, n_frames, B: int, T: int) -> list:
    if generators is None or len(generators) != B:
        raise ValueError(f"generators: one torch.Generator per episode is needed ({B}), got "
                         f"{'none' if generators is None else len(generators)}")
    n = [T] * B if n_frames is None else [int(v) for v in n_frames]
    if len(n) != B or min(n) < 0 or max(n) > T:
        raise ValueError(f"n_frames = {n}: one count per episode, each in 0 .. {T}")
    return n


def _electrons(mu: torch.Tensor, z: torch.Tensor, c: CameraConstants, gens_of_rows: list) -> torch.Tensor:
    """Electrons (R, ...) float32 of frames' mean electrons mu (R, ...) and their standard normals z:
    Poisson(mu) + N(0, sigma_r^2) by the skewness-corrected normal mu + s z + mu / (6 s^2) (z^2 - 1),
    s^2 = mu + sigma_r^2 (mlsim.camera._gaussian_shot_read, its operations in its order); the exact
    branch's photosites a Poisson count from frame r's generator ``gens_of_rows[r]`` plus sigma_r z."""
    mu = torch.clamp(mu, max=np.float32(_cap(c)))
    s2 = mu + np.float32(c.read_noise_e ** 2)
    # s2 = 0 only where sigma_r = 0 and mu = 0: the exact branch below overwrites those (or, on a
    # padded frame, the caller), so the 0 / 0 there is never read (as in mlsim.camera)
    coeff = mu / s2
    coeff *= np.float32(1.0 / 6.0)
    e = z * z  # in place from here: the temporaries of a chunk stay few
    e -= 1.0
    e *= coeff
    s2.sqrt_()
    s2 *= z
    e += s2
    e += mu
    if c.read_noise_e < EXACT_POISSON_READ_NOISE_BELOW_E:
        small = (mu + np.float32(c.read_noise_e ** 2)) < EXACT_POISSON_BELOW_E2
        if bool(small.any()):
            for r, g in enumerate(gens_of_rows):  # frame by frame, in order: the stream does not depend on the chunking
                sr = small[r]
                if g is not None and bool(sr.any()):  # None: a padded frame, whose mean is used instead
                    counts = torch.poisson(mu[r][sr].to(torch.float64), generator=g)
                    e[r][sr] = (counts + c.read_noise_e * z[r][sr].to(torch.float64)).to(torch.float32)
    return torch.clamp(e, max=float(c.full_well_e)) if math.isfinite(c.full_well_e) else e


def _cap(c: CameraConstants) -> float:
    # charge far above the full well ends at the full well whatever the noise; capping the mean keeps
    # inf out of the arithmetic (as mlsim.camera)
    fw = float(c.full_well_e)
    return 2.0 * fw + 10.0 * c.read_noise_e + 100.0 if math.isfinite(fw) else float(np.finfo(np.float32).max / 4)


def _to_8bit(e: torch.Tensor, c: CameraConstants) -> torch.Tensor:
    """8-bit codes (uint8) of electrons: gain, black level, round half to even (np.rint), clip to the
    ADC's range, drop the low bits (mlsim.camera.capture's float32 operations)."""
    x = e * np.float32(c.gain_dn_per_e)
    x += np.float32(c.black_level_dn)
    x.round_().clamp_(0, 2 ** c.adc_bits - 1)
    x *= np.float32(2.0 ** (8 - c.adc_bits))
    return x.floor_().to(torch.uint8)  # exact: floor(DN / 2^(bits - 8)) of integer DN


def sensor_batched(mu: torch.Tensor, c: CameraConstants, generators: list | None = None, n_frames=None, noise: bool = True,
                   chunk_frames: int | None = None, out: torch.Tensor | None = None) -> torch.Tensor:
    """8-bit RGB frames (B, T, H, W, 3) uint8 (Bayer; (B, T, H, W, 3) three-chip) of the mean
    electrons (B, T, H, W) (Bayer) or (B, T, H, W, 3) (:func:`mosaic_mean_batched`, :func:`_mosaic_mean`).

    ``generators``: one ``torch.Generator`` on the data's device per episode; episode b's first
    ``n_frames[b]`` frames (default all T) draw their normals in one ``torch.randn`` from it, then
    the exact branch's Poisson counts frame by frame; its padded frames get no noise. The same
    seed gives the same bytes whatever the rest of the batch and ``chunk_frames`` (frames per pass of
    the arithmetic: a few on a CPU, where the temporaries then stay in cache; all on a GPU)."""
    B, T = mu.shape[:2]
    fw = float(c.full_well_e)
    frames_shape = tuple(mu.shape[:4]) + (3,)
    out = torch.empty(frames_shape, dtype=torch.uint8, device=mu.device) if out is None else out
    flat_mu = mu.reshape((B * T,) + tuple(mu.shape[2:]))
    flat_out = out.view((B * T,) + frames_shape[2:])
    if noise:
        n_frames = _check_generators(generators, n_frames, B, T)
        z = torch.zeros(mu.shape, dtype=torch.float32, device=mu.device)
        for b, g in enumerate(generators):
            if n_frames[b]:
                z[b, : n_frames[b]] = torch.randn((n_frames[b],) + tuple(mu.shape[2:]), generator=g, dtype=torch.float32, device=mu.device)
        flat_z = z.view_as(flat_mu)
        live = torch.tensor([t < n_frames[b] for b in range(B) for t in range(T)])
    step = B * T if chunk_frames is None else max(1, int(chunk_frames))
    for r0 in range(0, B * T, step):
        r1 = min(B * T, r0 + step)
        m = flat_mu[r0:r1]
        if noise:
            gens = [generators[r // T] if bool(live[r]) else None for r in range(r0, r1)]
            e = _electrons(m, flat_z[r0:r1], c, gens)
            if not bool(live[r0:r1].all()):  # padded frames: the mean, no noise
                dead = ~live[r0:r1].to(m.device)
                e[dead] = torch.clamp(m[dead], max=fw) if math.isfinite(fw) else m[dead]
        else:
            e = torch.clamp(m, max=fw) if math.isfinite(fw) else m
        codes = _to_8bit(e, c)
        flat_out[r0:r1] = demosaic_rggb_batched(codes) if c.bayer else codes
    return out


def expose_batched(channel_radiance: torch.Tensor, c: CameraConstants, generators: list | None = None, noise: bool = True,
                   n_frames=None) -> torch.Tensor:
    """Electrons read out of each photosite (B, T, H, W) float32 (Bayer; (B, T, H, W, 3) without),
    for B episodes of T frames of channel radiance (B, T, H, W, 3): :func:`mlsim.camera.expose_electrons`,
    the random stream as :func:`sensor_batched`'s. Values above the full well are clipped to it."""
    if channel_radiance.ndim != 5 or channel_radiance.shape[-1] != 3:
        raise ValueError(f"channel_radiance of shape {tuple(channel_radiance.shape)}: must be (episodes, frames, H, W, 3)")
    _check_finite(channel_radiance, "channel_radiance (episodes, frames, H, W, 3)", "it comes from the render stage and the channel factors")
    if bool((channel_radiance < 0).any()):
        raise ValueError("channel_radiance has negative values: photon radiance must be >= 0")
    mu = _mosaic_mean(channel_radiance, c)
    fw = float(c.full_well_e)
    if not noise:
        return torch.clamp(mu, max=fw) if math.isfinite(fw) else mu
    B, T = mu.shape[:2]
    n_frames = _check_generators(generators, n_frames, B, T)
    z = torch.zeros(mu.shape, dtype=torch.float32, device=mu.device)
    for b, g in enumerate(generators):
        if n_frames[b]:
            z[b, : n_frames[b]] = torch.randn((n_frames[b],) + tuple(mu.shape[2:]), generator=g, dtype=torch.float32, device=mu.device)
    gens = [generators[r // T] for r in range(B * T)]
    e = _electrons(mu.reshape((B * T,) + tuple(mu.shape[2:])), z.reshape((B * T,) + tuple(mu.shape[2:])), c, gens)
    return e.view_as(mu)


def demosaic_rggb_batched(raw: torch.Tensor) -> torch.Tensor:
    """RGB (..., H, W, 3) uint8 from RGGB mosaics (..., H, W) uint8: OpenCV's bilinear
    ``COLOR_BayerRGGB2RGB`` bit for bit (its fixed-point rounding: (a + b + 1) >> 1 and
    (a + b + c + d + 2) >> 2; the outer rows and columns copied from their neighbours inside), on
    any device. H, W >= 3; even sizes take the fast path (each colour site's values computed on the
    quarter-size planes of its own parity, int16)."""
    if raw.dtype != torch.uint8 or raw.ndim < 2 or raw.shape[-1] < 3 or raw.shape[-2] < 3:
        raise ValueError(f"raw of dtype {raw.dtype} and shape {tuple(raw.shape)}: need uint8 (..., H, W) with H, W >= 3")
    H, W = raw.shape[-2:]
    out = torch.empty(raw.shape + (3,), dtype=torch.uint8, device=raw.device)
    if H % 2 == 0 and W % 2 == 0:
        _demosaic_even(raw, out)
    else:
        _demosaic_any(raw, out)
    # OpenCV fills the outer columns, then the outer rows, from their inner neighbours
    out[..., 1:-1, 0, :] = out[..., 1:-1, 1, :]
    out[..., 1:-1, -1, :] = out[..., 1:-1, -2, :]
    out[..., 0, :, :] = out[..., 1, :, :]
    out[..., -1, :, :] = out[..., -2, :, :]
    return out


def _demosaic_even(raw: torch.Tensor, out: torch.Tensor) -> None:
    """The inner pixels of an even mosaic from its four quarter-size planes, R (even row, even
    column), Gr (even, odd), Gb (odd, even), B (odd, odd), int16: each kind of site over the cells
    whose neighbours all exist (the others lie on the outer rows and columns, copied afterwards)."""
    r = raw.to(torch.int16)
    R, Gr, Gb, Bl = r[..., 0::2, 0::2], r[..., 0::2, 1::2], r[..., 1::2, 0::2], r[..., 1::2, 1::2]
    u8 = torch.uint8

    def put(rows, cols, rgb):
        for ch, v in enumerate(rgb):
            out[..., rows, cols, ch] = v.to(u8)

    # red sites (2i, 2j), i, j >= 1: G from Gr left and right, Gb up and down; B on the diagonals
    put(slice(2, None, 2), slice(2, None, 2),
        (R[..., 1:, 1:], (Gr[..., 1:, :-1] + Gr[..., 1:, 1:] + Gb[..., :-1, 1:] + Gb[..., 1:, 1:] + 2) >> 2,
         (Bl[..., :-1, :-1] + Bl[..., :-1, 1:] + Bl[..., 1:, :-1] + Bl[..., 1:, 1:] + 2) >> 2))
    # green sites between reds (2i, 2j + 1), i >= 1, j <= w - 2: R along the row, B along the column
    put(slice(2, None, 2), slice(1, -1, 2),
        ((R[..., 1:, :-1] + R[..., 1:, 1:] + 1) >> 1, Gr[..., 1:, :-1], (Bl[..., :-1, :-1] + Bl[..., 1:, :-1] + 1) >> 1))
    # green sites between blues (2i + 1, 2j), i <= h - 2, j >= 1: R along the column, B along the row
    put(slice(1, -1, 2), slice(2, None, 2),
        ((R[..., :-1, 1:] + R[..., 1:, 1:] + 1) >> 1, Gb[..., :-1, 1:], (Bl[..., :-1, :-1] + Bl[..., :-1, 1:] + 1) >> 1))
    # blue sites (2i + 1, 2j + 1), i <= h - 2, j <= w - 2: R on the diagonals, G from Gb and Gr
    put(slice(1, -1, 2), slice(1, -1, 2),
        ((R[..., :-1, :-1] + R[..., :-1, 1:] + R[..., 1:, :-1] + R[..., 1:, 1:] + 2) >> 2,
         (Gb[..., :-1, :-1] + Gb[..., :-1, 1:] + Gr[..., :-1, :-1] + Gr[..., 1:, :-1] + 2) >> 2, Bl[..., :-1, :-1]))


def _demosaic_any(raw: torch.Tensor, out: torch.Tensor) -> None:
    """The interior of a mosaic of any size (full-resolution candidates, chosen by parity)."""
    r = raw.to(torch.int32)
    H, W = r.shape[-2:]
    c = r[..., 1:-1, 1:-1]
    up, down, left, right = r[..., :-2, 1:-1], r[..., 2:, 1:-1], r[..., 1:-1, :-2], r[..., 1:-1, 2:]
    cross = (up + down + left + right + 2) >> 2
    diag = (r[..., :-2, :-2] + r[..., :-2, 2:] + r[..., 2:, :-2] + r[..., 2:, 2:] + 2) >> 2
    hor = (left + right + 1) >> 1
    ver = (up + down + 1) >> 1
    ys = (torch.arange(1, H - 1, device=raw.device) % 2)[:, None]
    xs = (torch.arange(1, W - 1, device=raw.device) % 2)[None, :]
    red_site = (ys == 0) & (xs == 0)
    blue_site = (ys == 1) & (xs == 1)
    g_red_row = (ys == 0) & (xs == 1)  # green between reds along the row
    red = torch.where(red_site, c, torch.where(blue_site, diag, torch.where(g_red_row, hor, ver)))
    blue = torch.where(blue_site, c, torch.where(red_site, diag, torch.where(g_red_row, ver, hor)))
    green = torch.where(red_site | blue_site, cross, c)
    out[..., 1:-1, 1:-1, :] = torch.stack([red, green, blue], dim=-1).to(torch.uint8)


def capture_batched(channel_radiance: torch.Tensor, c: CameraConstants, generators: list | None = None, noise: bool = True,
                    n_frames=None, chunk_frames: int | None = None) -> torch.Tensor:
    """8-bit RGB frames (B, T, H, W, 3) uint8 of channel radiance (B, T, H, W, 3) float32,
    photons s^-1 m^-2 sr^-1 (QE and optics applied): :func:`mlsim.camera.capture` of every frame
    (camera equation, Bayer, noise, full well, gain, black level, ADC, 8 bits, demosaic).
    ``generators``, ``n_frames``, ``chunk_frames``: :func:`sensor_batched`."""
    if channel_radiance.ndim != 5 or channel_radiance.shape[-1] != 3:
        raise ValueError(f"channel_radiance of shape {tuple(channel_radiance.shape)}: must be (episodes, frames, H, W, 3)")
    _check_finite(channel_radiance, "channel_radiance (episodes, frames, H, W, 3)", "it comes from the render stage and the channel factors")
    if bool((channel_radiance < 0).any()):
        raise ValueError("channel_radiance has negative values: photon radiance must be >= 0")
    return sensor_batched(_mosaic_mean(channel_radiance, c), c, generators, n_frames, noise, chunk_frames)


def capture_mono_batched(radiance: torch.Tensor, k_ml: torch.Tensor, c: CameraConstants, generators: list | None = None,
                         n_frames=None, noise: bool = True, ambient: torch.Tensor | None = None, level: torch.Tensor | None = None,
                         k_ambient: torch.Tensor | None = None, chunk_frames: int | None = None) -> torch.Tensor:
    """8-bit RGB frames (B, T, H, W, 3) uint8 of mono ML radiance (B, T, H, W) float32 (the render's
    output) with the channel factors ``k_ml`` (3,) and the ambient leak (:func:`mosaic_mean_batched`),
    through a Bayer camera: what :func:`mlsim.render.output.expose` makes of each frame, chunk by
    chunk of ``chunk_frames`` frames (the mean electrons of one chunk at a time)."""
    if radiance.ndim != 4:
        raise ValueError(f"radiance of shape {tuple(radiance.shape)}: must be (episodes, frames, H, W)")
    if bool((radiance < 0).any()):
        raise ValueError("radiance has negative values: photon radiance must be >= 0")
    B, T, H, W = radiance.shape
    if not noise:
        generators = None
    else:
        n_frames = _check_generators(generators, n_frames, B, T)
    if chunk_frames is None:
        mu = mosaic_mean_batched(radiance, k_ml, c, ambient, level, k_ambient)
        return sensor_batched(mu, c, generators, n_frames, noise)
    # on a CPU: the mean electrons a chunk of each episode's frames at a time (the noise stream is
    # still each episode's own: sensor_batched draws it per episode)
    out = torch.empty((B, T, H, W, 3), dtype=torch.uint8, device=radiance.device)
    for b in range(B):
        lv = None if level is None else level[b:b + 1]
        mu = mosaic_mean_batched(radiance[b:b + 1], k_ml, c, ambient, lv, k_ambient)
        sensor_batched(mu, c, None if generators is None else generators[b:b + 1], None if n_frames is None else n_frames[b:b + 1],
                       noise, chunk_frames, out[b:b + 1])
    return out
