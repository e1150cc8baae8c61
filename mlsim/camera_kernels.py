"""Compiled loop of the camera (numba): one Bayer frame of the ML light from its mono radiance to
8-bit codes in a single pass over its photosites (:func:`mlsim.camera.capture_mono`'s usual path).

numpy forms the same codes in about fifteen passes over the frame (the channels' means, the cap,
the variance, the skewness-corrected normal, the full well, gain, black level, ADC rounding and
clipping, the 8 bits), each a few tens of microseconds on a 350 x 350 frame: 0.5 ms of the
camera stage's 1.4. Here every photosite goes through the same float32 operations in the same
order (float64 where numpy computes in float64: the relative-illumination map), so the codes are
numpy's byte for byte (``tests/test_camera.py``); the normals are still numpy's (the same draws).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["bayer_mono_codes"]


@njit(cache=True, inline="always", error_model="numpy")
def _code(mu, zz, dark, cap, read_var, full_well, gain, black, full_scale, to8):
    """One photosite's 8-bit code from its mean before the dark charge (float32) and its normal."""
    mu = mu + dark
    mu = min(mu, cap)
    s2 = mu + read_var
    c = mu / s2
    c = c * np.float32(1.0 / 6.0)
    s = np.sqrt(s2) * zz
    e = zz * zz
    e = e - np.float32(1.0)
    e = e * c
    e = e + s
    e = e + mu
    e = min(e, full_well)
    dn = e * gain
    dn = dn + black
    dn = np.rint(dn)
    dn = min(max(dn, np.float32(0.0)), full_scale)
    dn = dn * to8
    return np.uint8(np.floor(dn))


@njit(cache=True, error_model="numpy")  # a division by zero gives numpy's inf or NaN, not a raise (and the loop vectorises)
def bayer_mono_codes(rad, mono_k, k, rel, dark, cap, read_var, full_well, z, gain, black, full_scale, to8, out):
    """out (H, W) uint8, in place: the 8-bit code of each RGGB photosite of the mono radiance rad
    (H, W) float32 seen through its channel's factor mono_k (3,) float32 (red at row 0, column 0).

    Per photosite, as :func:`mlsim.camera._expose_frame` then :func:`mlsim.camera._read_out` (all
    float32 but the relative illumination rel (H, W) float64, or (0, 0) for none): the mean mu =
    rad mono_k[c] k (rel) + dark, capped at ``cap``; the charge mu + s z + (mu / s^2) / 6 (z^2 - 1),
    s^2 = mu + read_var, with the photosite's normal z (H W,) float32; the full well; then
    rint(e gain + black) clipped to [0, full_scale], times to8, floored. The exact Poisson branch
    is not here: the caller takes numpy's path where it applies. Returns nothing."""
    H, W = rad.shape
    # each row's channel factor per column: RGGB, red (0, 0), green (0, 1) and (1, 0), blue (1, 1)
    factor = np.empty((2, W), np.float32)
    for x in range(W):
        factor[0, x] = mono_k[x & 1]
        factor[1, x] = mono_k[1 + (x & 1)]
    # the two loops differ only by the relative illumination (kept out of the inner loop, which vectorises)
    if rel.shape[0] > 0:
        for y in range(H):
            f = factor[y & 1]
            for x in range(W):
                mu = np.float32(np.float64((rad[y, x] * f[x]) * k) * rel[y, x])
                out[y, x] = _code(mu, z[y * W + x], dark, cap, read_var, full_well, gain, black, full_scale, to8)
    else:
        for y in range(H):
            f = factor[y & 1]
            for x in range(W):
                mu = (rad[y, x] * f[x]) * k
                out[y, x] = _code(mu, z[y * W + x], dark, cap, read_var, full_well, gain, black, full_scale, to8)
