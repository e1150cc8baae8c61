"""The LED -> LTV coupling from optics: the truth the CLS estimator's seven-coefficient law approximates (SPEC 3).

SPEC 3's estimator inverts v = c1 / (r^2 + c2 r + c3) cos(c4 theta) (1 + c5 cos(c6 psi)) + c7
(:mod:`other_sensors.cls.ltv`). When the signals come from that same law, the simulated pose errors
hold only the added noise. This module makes the voltages from the light instead:

- Direct path (radiometry of a point source): the LED is a generalised Lambertian emitter,
  I(theta) = I0 cos^m(theta), m = -ln 2 / ln cos(theta_half) (theta_half the datasheet's
  half-intensity angle; Moreno & Sun, "Modeling the radiation pattern of LEDs", Opt. Express 16,
  2008, eq. 1); the LTV is a flat photodiode behind a flat window, its response the projected area,
  cos(psi) (Lambert's cosine law), nothing past 90 deg. Irradiance E = I(theta) cos(psi) / r^2.
- Diffuse path (the cavity between base and shell, an integrating cavity with open sides): the
  LED's flux Phi = 2 pi I0 / (m + 1) first strikes the base (reflectance rho_base: the LED faces
  down), then bounces among the base, the shell's inner surface (rho_shell) and the foam pillars'
  sides (rho_foam, the foam's scattering taken as a diffuse wall); the open sides lose it. The
  uniform-radiance cavity result E_d = Phi rho_base / (A (1 - rho_mean (1 - f))) (Goebel, "Generalized
  integrating-sphere theory", Appl. Opt. 6, 1967; A the cavity's whole surface, f its open fraction,
  rho_mean the closed walls' area-weighted reflectance) gives every LTV the same diffuse irradiance.
  A simplification: the real cavity is flat (its radiance is not uniform), and the LTV sees the
  shell's side of it; the term's dependence on the gap (through A and f) is what the law cannot hold.
  Path-traced with Mitsuba (:mod:`other_sensors.cls.optics_render`), this term is 1.1-7x the
  rendered diffuse light, but the diffuse light is under 0.5 % of the signal: the coupling is within
  0.9 % of the rendered one (0.6 % once each pair's gain is set at rest; docs/uses/sibling-sensors.md).
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

from other_sensors.cls.ltv import PairLayout, pair_geometry, planar_to_pose

__all__ = ["Optics", "lambert_order", "direct_irradiance", "cavity_irradiance", "optical_voltages"]


@dataclass(frozen=True)
class Optics:
    """The optical parameters (their defaults' sources: :class:`other_sensors.cls.schema.OpticsSpec`).

    half_angle_deg: the LED's half-intensity angle. rho_base, rho_shell, rho_foam: diffuse
    reflectances of the base, the shell's inner surface and the foam pillars. footprint_mm (2,):
    the cavity's length (along the pairs, y) and width (x). pillar_width_mm: a pillar's side.
    dark_v: the LTV's dark output.
    """

    half_angle_deg: float = 30.0
    rho_base: float = 0.1
    rho_shell: float = 0.3
    rho_foam: float = 0.6
    footprint_mm: tuple[float, float] = (130.0, 50.0)
    pillar_width_mm: float = 38.1
    n_pillars: int = 3
    dark_v: float = 0.005

    def __post_init__(self):
        for name in ("rho_base", "rho_shell", "rho_foam"):
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


def cavity_irradiance(gap_mm, optics: Optics, m: float):
    """The cavity's uniform diffuse irradiance per unit I0 (1/mm^2) at the mean gap ``gap_mm`` (any shape)."""
    gap = np.asarray(gap_mm, float)
    length, width = optics.footprint_mm
    floor = length * width
    pillars = optics.n_pillars * 4.0 * optics.pillar_width_mm * gap  # their sides, inside the cavity
    sides = 2.0 * (length + width) * gap  # open
    total = 2.0 * floor + pillars + sides
    closed_rho = (floor * optics.rho_base + floor * optics.rho_shell + pillars * optics.rho_foam) / (2.0 * floor + pillars)
    closed = (2.0 * floor + pillars) / total
    flux = 2.0 * np.pi / (m + 1.0)
    return flux * optics.rho_base / (total * (1.0 - closed_rho * closed))


def _irradiance(pose3, layout: PairLayout, optics: Optics):
    m = lambert_order(optics.half_angle_deg)
    p, q = planar_to_pose(pose3)
    r, theta, psi = pair_geometry(p, q, layout)
    gap = np.asarray(pose3, float)[..., 1:2]  # the shell origin's height: the mean gap of a symmetric footprint
    return direct_irradiance(r, theta, psi, m) + cavity_irradiance(gap, optics, m)


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
