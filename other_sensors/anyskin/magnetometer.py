"""The read-out of a three-axis Hall magnetometer (an MLX90393, the chip under AnySkin's skins): per-chip
offset and sensitivity matrix with cross-axis terms, white noise per axis, quantisation (SPEC 2).

A chip c reads the flux density b (uT, its own axes) as

    r = S_c b + o_c + n,   n ~ N(0, diag(sigma_xy^2, sigma_xy^2, sigma_z^2)),

then rounded to its LSB per axis (lsb_xy, lsb_z). S_c = I + diag(g_c) + X_c: g_c the chip's gain errors
and X_c (zero diagonal) its cross-axis sensitivity, drawn once per chip with standard deviations
``gain_error_pct`` and ``cross_axis_pct``; o_c its offset, drawn once with standard deviation ``offset_ut``.
The chips of the helmet and of the calibration bench are different draws, so a force map calibrated
on one skin meets other chips on the helmet, as on the real robot.

Sources (parameter by parameter, :mod:`other_sensors.anyskin.schema`): the LSBs 0.150 uT (x, y) and
0.242 uT (z) are the MLX90393's sensitivities at GAIN_SEL = 7, RES = 0, HALLCONF = 0xC (Melexis,
*MLX90393 Triaxis Magnetic Node datasheet*, rev. 006, 2020, table of sensitivities); checked on
2026-11-27 against the table that Adafruit's driver transcribes from that datasheet
(``adafruit/Adafruit_CircuitPython_MLX90393``, ``adafruit_mlx90393.py``, ``_LSB_LOOKUP``: HALLCONF 0xC,
gain 1x (GAIN_SEL 7), RES 0 -> (0.150, 0.242) uT/LSB; GAIN_SEL 0 -> (0.751, 1.210); HALLCONF 0x0, GAIN_SEL 7
-> (0.157, 0.253); commit 89aed8d): they agree. Its z plate is 1.6 x less sensitive than the x, y
flux-concentrator channels, so with the same noise in LSB the z noise in uT is the x, y noise times 0.242 / 0.150. The x, y noise
(1.5 uT rms at the 150 Hz rate), the offset spread, the gain spread and the cross-axis spread are stated
choices of typical Hall-sensor magnitudes (the defaults in the schema say so), not fitted to any published
error, and not checked against the datasheet: its noise and offset tables were not among the sources that
could be read when this was checked (only the datasheet's first pages are indexed there).
"""

from __future__ import annotations

import numpy as np

__all__ = ["chip_errors", "read_chips"]


def _check(name: str, value) -> np.ndarray:
    v = np.asarray(value, dtype=float)
    if not np.all(np.isfinite(v)) or np.any(v < 0):
        raise ValueError(f"sensor.noise.{name} = {value!r}: must be finite and >= 0; give a standard deviation or a step")
    return v


def chip_errors(n_chips: int, offset_ut: float, gain_error_pct: float, cross_axis_pct: float, rng: np.random.Generator):
    """Each chip's offset (C, 3) uT and sensitivity matrix (C, 3, 3), drawn once from rng; see the module docstring.
    gain_error_pct, cross_axis_pct: the standard deviations of g_c and X_c, in % (of 1)."""
    _check("offset_ut", offset_ut), _check("gain_error_pct", gain_error_pct), _check("cross_axis_pct", cross_axis_pct)
    offsets = rng.normal(0.0, 1.0, (n_chips, 3)) * offset_ut
    gains = rng.normal(0.0, 1.0, (n_chips, 3)) * gain_error_pct / 100.0
    cross = rng.normal(0.0, 1.0, (n_chips, 3, 3)) * cross_axis_pct / 100.0
    cross[:, np.arange(3), np.arange(3)] = 0.0
    return offsets, np.eye(3)[None] + gains[:, :, None] * np.eye(3)[None] + cross


def read_chips(clean_ut, offsets_ut, sensitivity, noise_ut, lsb_ut, rng: np.random.Generator) -> np.ndarray:
    """Readings (T, C, 3) uT of chips seeing clean_ut (T, C, 3) uT.

    Parameters
    ----------
    offsets_ut : (C, 3) uT. sensitivity : (C, 3, 3). noise_ut : (3,) uT rms per axis (0: none).
    lsb_ut : (3,) uT per LSB per axis (0: no rounding on that axis). rng : the noise's generator.
    """
    noise, lsb = _check("rms_ut", np.broadcast_to(noise_ut, (3,))), _check("lsb_ut", np.broadcast_to(lsb_ut, (3,)))
    clean = np.asarray(clean_ut, dtype=float)
    r = np.einsum("cij,tcj->tci", np.asarray(sensitivity, dtype=float), clean) + np.asarray(offsets_ut, dtype=float)[None]
    if np.any(noise > 0):
        r = r + rng.normal(0.0, 1.0, r.shape) * noise
    step = np.where(lsb > 0, lsb, 1.0)
    return np.where(lsb > 0, step * np.round(r / step), r)
