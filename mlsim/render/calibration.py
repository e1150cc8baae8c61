"""The absolute brightness constant ``emission.brightness_photons_per_m2`` and how to calibrate it.

Everything from the emission to the camera's mean signal is linear in B (photons per m^2 of ML
layer when all its traps empty), so one number fixes it. The measure is the green channel's
noiseless 8-bit level at a high percentile (99.5 %) of the brightest frame's pixels, above the
black level: robust to a few hot pixels, and green is where ZnS:Cu is bright.

From one real frame (the documented procedure):

1. film a press on the real sensor at a known force and loading profile with known camera
   settings, and note the 99.5-percentile green level of its brightest frame, ``measured_dn8``;
2. simulate the same press with the same camera settings (``outputs = ["render"]``) and take
   :func:`green_level_dn8` of its brightest frame;
3. set ``emission.brightness_photons_per_m2`` to :func:`brightness_to_match` of the two.

The shipped default follows the same procedure with a target instead of a measurement: a 16 N
press of the default probe (press over 0.15 s, force control) on the default sensor at default
camera settings gives a 99.5-percentile green level of 192 of 255 (the upper half of the range,
ISSUE 4); ``benchmarks/calibrate_brightness.py`` reruns it.
"""

from __future__ import annotations

import numpy as np

__all__ = ["green_level_dn8", "noiseless_dn8", "brightness_to_match", "DEFAULT_PERCENTILE"]

DEFAULT_PERCENTILE = 99.5


def green_level_dn8(scene, radiance_frame, percentile: float = DEFAULT_PERCENTILE) -> float:
    """Noiseless 8-bit green level of a radiance frame (H, W) at a percentile of its pixels (includes
    the black level), with the scene's camera (gain, exposure, lens) and spectra."""
    from mlsim.render.optics import camera_params, ml_channel_factors

    p = camera_params(scene)
    k_green = float(ml_channel_factors(scene)[1])
    electrons = np.percentile(np.asarray(radiance_frame, dtype=np.float64), percentile) * k_green * p.electrons_per_radiance_m2_sr_s
    return noiseless_dn8(p, electrons)


def noiseless_dn8(params, electrons) -> float:
    """The mean 8-bit level of a pixel collecting ``electrons`` (black level included, clipped at
    full scale, not quantised): (e K 10^(gain_db / 20) + black) / 2^(adc_bits - 8)."""
    dn = electrons * params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0) + params.black_level_dn
    return float(min(dn, 2**params.adc_bits - 1) * 2.0 ** (8 - params.adc_bits))


def brightness_to_match(brightness_photons_per_m2: float, simulated_dn8: float, target_dn8: float, black_level_dn8: float) -> float:
    """B that moves a simulated level to a target (both 8-bit, black level included): the signal
    above black is proportional to B. Raises when the simulated level is at black (no light) or
    either level is saturated (255: the ratio is unknown there)."""
    sim, target = float(simulated_dn8) - black_level_dn8, float(target_dn8) - black_level_dn8
    if not sim > 0:
        raise ValueError(f"simulated level {simulated_dn8:g} is at the black level {black_level_dn8:g}: simulate a press that glows")
    if max(simulated_dn8, target_dn8) >= 255:
        raise ValueError("a level of 255 is saturated: lower the camera gain or exposure for both frames and calibrate again")
    if not target > 0:
        raise ValueError(f"target level {target_dn8:g} must exceed the black level {black_level_dn8:g}")
    return float(brightness_photons_per_m2) * target / sim
