"""The CLS cavity's diffuse light path-traced with Mitsuba: a cross-check of :mod:`other_sensors.cls.cavity_radiosity` (issue 43).

The optical truth's diffuse light (:mod:`other_sensors.cls.optics`) is the two-surface radiosity
between the base and the shell at the shell's pose (:func:`other_sensors.cls.cavity_radiosity.diffuse_irradiance`).
This module renders the same light with Mitsuba 3's path tracer (``path``, unbounded depth with
Russian roulette) over the shell's actual (tilted, sheared, compressed) pose, to say how far the
radiosity is from it. It chose that model: the uniform-cavity formula (Goebel 1967) the truth held
first was 0.7-8.6x the rendered light, the radiosity is within 0.7 % of it (docs/uses/sibling-sensors.md).
The set-up:

- the base (reflectance rho_base) and the shell's inner surface (rho_shell) are two Lambertian
  rectangles of the optics' footprint (length along y, width along x), the base at z = 0 and the
  shell in the shell frame at the shell's pose (:func:`other_sensors.cls.ltv.planar_to_pose`); the
  sides are open (what leaves is lost);
- the LED is Mitsuba's ``spot`` emitter at the LED's as-posed position, along its axis, whose
  projected texture holds the generalised Lambertian beam cos^m(theta) (Moreno & Sun 2008, eq. 1; the
  texture's uv is (1 + tan(theta) (cos phi, sin phi) / tan(cutoff)) / 2, Mitsuba's ``spot.cpp``), so
  its intensity per unit I0 is the optics model's; the cutoff, 85 deg, drops cos^(m+1)(85 deg) of the
  flux (6.6e-7 of it at the default 30 deg half angle);
- the LTV is Mitsuba's ``irradiancemeter`` on a black disk of radius 0.5 mm, 0.01 mm above the base,
  facing up: it returns the irradiance (per unit I0, 1/mm^2, the scene in mm) averaged over the disk,
  with the LTV's cosine response.

A point emitter cannot be hit by a ray, so what the meter sees is only light that has bounced at
least once: the diffuse irradiance, the quantity :func:`diffuse_irradiance` models. The direct path
is point-source radiometry (:func:`other_sensors.cls.optics.direct_irradiance`), checked against its
closed forms in ``tests/test_cls_optics.py``. :func:`sphere_irradiance` renders an integrating sphere,
whose diffuse wall irradiance Phi rho / (4 pi R^2 (1 - rho)) is exact, to check this set-up (the
beam's flux, the meter's normalisation) before it judges the cavity.

Not rendered (nor modelled): the foam pillars. The pair layout puts the LTVs on the pillars' line (x = 0,
pillars 38.1 mm wide at y = -45, 0, 45 mm) in a 50 mm wide cavity, where no pillar fits beside them.
Mitsuba is imported on first use, in
the project's CPU variant (:data:`mlsim.render.sensor_scene.VARIANT`, mono).
"""

from __future__ import annotations

import numpy as np

from other_sensors.cls.ltv import PairLayout, planar_to_pose, quat_to_matrix
from other_sensors.cls.optics import Optics, lambert_order

__all__ = ["CUTOFF_DEG", "spot_texture", "cavity_scene", "rendered_diffuse_irradiance", "sphere_scene", "sphere_irradiance"]

#: the spot's cutoff: the beam beyond it (cos^(m+1) of the flux) is dropped
CUTOFF_DEG = 85.0
#: the LTV's disk radius (mm) and its lift off the base (mm), small against the 20-60 mm scale of the light's variation
LTV_RADIUS_MM = 0.5
LTV_LIFT_MM = 0.01
#: the LED's offset below the shell along its axis (mm), so a shadow ray to it does not graze the shell
LED_LIFT_MM = 0.01


def spot_texture(m: float, cutoff_deg: float = CUTOFF_DEG, n: int = 1025) -> np.ndarray:
    """cos^m(theta) on the ``spot`` emitter's texture grid: (n, n) float32 (pixel centres; n odd
    puts one on the axis). uv in [0, 1]^2 maps to tan(theta) (cos phi, sin phi) = (2 uv - 1) tan(cutoff)."""
    if not (0.0 < cutoff_deg < 90.0):
        raise ValueError(f"cutoff_deg = {cutoff_deg}: must be in (0, 90) deg")
    t = ((np.arange(n) + 0.5) / n * 2.0 - 1.0) * np.tan(np.radians(cutoff_deg))
    tx, ty = np.meshgrid(t, t)
    return (1.0 + tx * tx + ty * ty) ** (-0.5 * m)


def _mitsuba():
    from mlsim.render.sensor_scene import VARIANT, use_variant

    return use_variant(VARIANT)


def _grey(rho: float) -> dict:
    return {"type": "twosided", "material": {"type": "diffuse", "reflectance": {"type": "uniform", "value": float(rho)}}}


def _spot(mi, origin, axis, m: float) -> dict:
    axis = np.asarray(axis, float)
    up = [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0]
    texture = mi.Bitmap(spot_texture(m).astype(np.float32)[..., None])
    return {"type": "spot", "cutoff_angle": CUTOFF_DEG, "beam_width": CUTOFF_DEG - 1e-3,
            "to_world": mi.ScalarTransform4f.look_at(origin=list(map(float, origin)), target=list(map(float, origin + axis)), up=up),
            "intensity": {"type": "uniform", "value": 1.0},
            "texture": {"type": "bitmap", "bitmap": texture, "raw": True, "filter_type": "bilinear", "wrap_mode": "clamp"}}


def _meter(mi, to_world) -> dict:
    return {"type": "disk", "to_world": to_world, "bsdf": _grey(0.0),
            "sensor": {"type": "irradiancemeter", "sampler": {"type": "independent"},
                       "film": {"type": "hdrfilm", "width": 1, "height": 1, "pixel_format": "luminance", "rfilter": {"type": "box"}}}}


def cavity_scene(pose3, pair: int, layout: PairLayout, optics: Optics) -> dict:
    """Mitsuba's scene dictionary of the cavity at a planar pose (3,) = (y mm, z mm, rx rad), lit by
    pair ``pair``'s LED and measured at its LTV (module docstring)."""
    mi = _mitsuba()
    T = mi.ScalarTransform4f
    p, q = planar_to_pose(np.asarray(pose3, float))
    rot = quat_to_matrix(q)
    length, width = optics.footprint_mm
    shell = np.eye(4)
    shell[:3, :3] = rot @ np.diag([width / 2.0, length / 2.0, 1.0])
    shell[:3, 3] = p
    axis = rot @ layout.led_axis[pair]
    led = p + rot @ layout.led_pos[pair] + LED_LIFT_MM * axis
    ltv = layout.ltv_pos[pair] + LTV_LIFT_MM * layout.ltv_axis[pair]
    if not np.allclose(layout.ltv_axis[pair], [0.0, 0.0, 1.0]):
        raise ValueError(f"layout.ltv_axis[{pair}] = {layout.ltv_axis[pair].tolist()}: the render places the LTV flat on the base, facing +z")
    return {"type": "scene", "integrator": {"type": "path", "max_depth": -1},
            "base": {"type": "rectangle", "to_world": T.scale([width / 2.0, length / 2.0, 1.0]), "bsdf": _grey(optics.rho_base)},
            "shell": {"type": "rectangle", "to_world": T(shell.tolist()), "bsdf": _grey(optics.rho_shell)},
            "led": _spot(mi, led, axis, lambert_order(optics.half_angle_deg)),
            "ltv": _meter(mi, T.translate(ltv.tolist()) @ T.scale(LTV_RADIUS_MM))}


def _render(mi, scene_dict: dict, spp: int, seed: int) -> float:
    return float(np.asarray(mi.render(mi.load_dict(scene_dict), spp=int(spp), seed=int(seed))).ravel()[0])


def rendered_diffuse_irradiance(pose3, layout: PairLayout, optics: Optics, pairs=None, spp: int = 1 << 18, seed: int = 0) -> np.ndarray:
    """The diffuse irradiance per unit I0 (1/mm^2) at each of ``pairs`` (default all) LTVs, path-traced:
    (len(pairs),). Comparable with :func:`other_sensors.cls.cavity_radiosity.diffuse_irradiance` at the
    pose. Monte Carlo: the relative standard error is about 1 / sqrt(spp) times a few (measured: 0.1 %
    at 2^20 samples)."""
    mi = _mitsuba()
    pairs = range(layout.n_pairs) if pairs is None else pairs
    return np.array([_render(mi, cavity_scene(pose3, k, layout, optics), spp, seed + 7919 * k) for k in pairs])


def sphere_scene(radius_mm: float, rho: float, half_angle_deg: float) -> dict:
    """An integrating sphere of ``radius_mm`` and reflectance ``rho`` with the LED at its centre
    (facing -z) and the LTV's meter on its wall at +x, facing in."""
    mi = _mitsuba()
    T = mi.ScalarTransform4f
    m = lambert_order(half_angle_deg)
    return {"type": "scene", "integrator": {"type": "path", "max_depth": -1},
            "ball": {"type": "sphere", "radius": float(radius_mm), "flip_normals": True, "bsdf": _grey(rho)},
            "led": _spot(mi, np.zeros(3), np.array([0.0, 0.0, -1.0]), m),
            "ltv": _meter(mi, T.translate([radius_mm - LTV_LIFT_MM, 0.0, 0.0]) @ T.rotate([0, 1, 0], -90.0) @ T.scale(LTV_RADIUS_MM))}


def sphere_irradiance(radius_mm: float, rho: float, half_angle_deg: float, spp: int = 1 << 18, seed: int = 0) -> float:
    """The sphere's rendered diffuse wall irradiance per unit I0 (1/mm^2); its closed form is
    Phi rho / (4 pi R^2 (1 - rho)), Phi = 2 pi / (m + 1) (Goebel 1967)."""
    return _render(_mitsuba(), sphere_scene(radius_mm, rho, half_angle_deg), spp, seed)
