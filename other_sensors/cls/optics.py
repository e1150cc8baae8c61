"""The LED -> LTV coupling from optics: the truth the CLS estimator's seven-coefficient law approximates (SPEC 3).

SPEC 3's estimator inverts v = c1 / (r^2 + c2 r + c3) cos(c4 theta) (1 + c5 cos(c6 psi)) + c7
(:mod:`other_sensors.cls.ltv`). When the signals come from that same law, the simulated pose errors
hold only the added noise. This module makes the voltages from the light instead:

- Direct path (radiometry of a point source): the LED is a generalised Lambertian emitter,
  I(theta) = I0 cos^m(theta), m = -ln 2 / ln cos(theta_half) (theta_half the datasheet's
  half-intensity angle; Moreno & Sun, "Modeling the radiation pattern of LEDs", Opt. Express 16,
  2008, eq. 1); the LTV is a flat photodiode behind a flat window, its response the projected area,
  cos(psi) (Lambert's cosine law), nothing past 90 deg. Irradiance E = I(theta) cos(psi) / r^2.
- Diffuse path (the cavity between base and shell, open on its sides): the LED's light strikes the
  base (reflectance rho_base: the LED faces down), whose diffuse reflection lights the shell's inner
  surface (rho_shell), which lights the LTV; the bounces between the two surfaces are summed and what
  leaves by the sides is lost. Two-surface radiosity over the base's and the shell's footprints at
  the shell's pose (:mod:`other_sensors.cls.cavity_radiosity`; Siegel & Howell 2002, Modest 2013),
  within 0.7 % of Mitsuba's path-traced diffuse light over ten poses and five pairs
  (:mod:`other_sensors.cls.optics_render`, docs/uses/sibling-sensors.md). It depends on the shell's
  whole pose (its gap, shift and tilt), which the law cannot hold. The foam pillars are not surfaces
  of this cavity: the layout puts them on the pairs' line, where the LTVs are.
- The LTV's output: v = k E + v_dark, k the LED drive times the LTV's responsivity, set per pair
  so that the as-designed shell at rest reads what the nominal law reads there (a designer sets
  the LED current for that working point; no error figure enters), then scaled by each pair's
  part-to-part gain (its true c1 over the nominal c1).

Lengths mm, angles rad, voltages V. The pose's geometry (r, theta, psi) is
:func:`other_sensors.cls.ltv.pair_geometry`'s, on the as-built (mounted) layout.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from other_sensors.cls.cavity_radiosity import diffuse_irradiance_table
from other_sensors.cls.ltv import PairLayout, pair_geometry, planar_to_pose

__all__ = ["Optics", "lambert_order", "direct_irradiance", "optical_voltages"]


@dataclass(frozen=True)
class Optics:
    """The optical parameters (their defaults' sources: :class:`other_sensors.cls.schema.OpticsSpec`).

    half_angle_deg: the LED's half-intensity angle. rho_base, rho_shell: diffuse reflectances of the
    base and the shell's inner surface. footprint_mm (2,): the cavity's length (along the pairs, y)
    and width (x), the base's and the shell's. dark_v: the LTV's dark output.
    """

    half_angle_deg: float = 30.0
    rho_base: float = 0.1
    rho_shell: float = 0.3
    footprint_mm: tuple[float, float] = (130.0, 50.0)
    dark_v: float = 0.005

    def __post_init__(self):
        for name in ("rho_base", "rho_shell"):
            value = getattr(self, name)
            if not (np.isfinite(value) and 0.0 <= value < 1.0):
                raise ValueError(f"sensor.optics.{name} = {value}: a reflectance must be in [0, 1)")
        if not (0.0 < self.half_angle_deg < 90.0):
            raise ValueError(f"sensor.optics.half_angle_deg = {self.half_angle_deg}: must be in (0, 90) deg")


def lambert_order(half_angle_deg: float) -> float:
    """m of the generalised Lambertian I0 cos^m(theta) whose intensity halves at ``half_angle_deg``."""
    return float(-np.log(2.0) / np.log(np.cos(np.radians(half_angle_deg))))


def direct_irradiance(r, theta, psi, m: float):
    """The point source's irradiance per unit I0 (1/mm^2), any broadcast shape: cos^m(theta) cos(psi) / r^2,
    0 behind the LED (theta >= 90 deg) or the LTV (psi >= 90 deg)."""
    r, theta, psi = (np.asarray(a, float) for a in (r, theta, psi))
    ct, cp = np.cos(theta), np.cos(psi)
    return np.where((ct > 0) & (cp > 0), np.maximum(ct, 0.0) ** m * cp / (r * r), 0.0)


def _irradiance(pose3, layout: PairLayout, optics: Optics):
    """The direct plus the diffuse irradiance per unit I0 (1/mm^2), (..., P), of planar poses (..., 3)."""
    m = lambert_order(optics.half_angle_deg)
    p, q = planar_to_pose(pose3)
    r, theta, psi = pair_geometry(p, q, layout)
    diffuse = diffuse_irradiance_table(pose3, layout, *optics.footprint_mm, optics.rho_base, optics.rho_shell, m)
    return direct_irradiance(r, theta, psi, m) + diffuse


def optical_voltages(pose3, built: PairLayout, designed: PairLayout, optics: Optics):
    """Noise-free LTV voltages (..., P) V of planar poses (..., 3) = (y mm, z mm, rx rad).

    built: the as-built layout (true mounts; its c1 over ``designed``'s is each pair's gain spread).
    designed: the nominal layout, whose law sets each pair's working point at rest (module docstring).
    """
    from other_sensors.cls.ltv import planar_voltages

    rest = np.array([0.0, designed.rest_p[2], 0.0])
    target = planar_voltages(rest, designed) - optics.dark_v
    if np.any(target <= 0):
        raise ValueError("optics: the nominal law reads at or under the LTV's dark output at rest; no LED drive sets that working point")
    gain = target / _irradiance(rest, designed, optics) * (built.coeffs[:, 0] / designed.coeffs[:, 0])
    return gain * _irradiance(pose3, built, optics) + optics.dark_v
