"""Ambient light: a lamp above the sensor, its light leaking through the absorber and the ML layer.

Model (a simplification, stated): the lamp is an isotropic point source of radiant power P (its
electrical rating times its luminous efficacy over the luminous efficacy of its spectrum, so the
lamp's *light* output is what counts), at height h above the rods' tips. The irradiance on the
sensor's outer surface at a point p with outward normal n follows the inverse-square and cosine laws

    E(p) = P / (4 pi r^2) max(0, n . l) V(p),   l = (lamp - p) / r,   r = |lamp - p|,

with V(p) = 0 where the rods shade p from the lamp (traced with Mitsuba against the ML layer's inner
face, which stands in for the outer surface 0.8 mm further out; ``ambient.occlusion = false`` drops
it). The absorber transmits T_abs(lambda) (:func:`mlsim.spectra.absorber_transmittance_sd`), the
ML layer a grey diffuse fraction t_ml (``optics.ml_layer_transmittance``), and the light leaves the
layer's inner face as a Lambertian emitter: per sheet vertex of area A,

    Phi = E(p) A t_ml integral( p_lamp(lambda) lambda / (h c) T_abs(lambda) dlambda )   photons/s,

with p_lamp the lamp's spectrum normalised to 1 W. That is one more emission component on the same
sheet, with its own spectrum (lamp x absorber), so the renderer renders it once per geometry and the
camera adds it with that spectrum's channel factors and the lamp's level in each exposure (mains
flicker and switching: :func:`lamp_level`). Left out: the lamp's extent (a point at 1.5 m is a
0.7 deg source for a 36 mm sensor), light scattered in the room, photoluminescence of ZnS:Cu under
the lamp's violet lines, and the change of the cosine factors as the rods deform (the leak is
rendered on the rest shape).

The calibration frame (SPEC 1.1, 1.6) is the same model with the absorber removed
(``absorber = "none"``) under the calibration lamp.

References
----------
.. [DOE2016] U.S. Department of Energy, "Adoption of Light-Emitting Diodes in Common Lighting
   Applications" (2017) and "Energy Savings Forecast of Solid-State Lighting" (2016): typical
   efficacies of linear fluorescent systems (halophosphate T12/T8 with ballast) about 55-70 lm/W,
   and of LED A-lamps about 80-110 lm/W.
.. [CIE15] CIE 015:2018, Colorimetry, 4th ed.: FL1 and LED-B4 spectra (via colour-science).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from types import MappingProxyType

import numpy as np
from scipy.integrate import trapezoid

__all__ = [
    "LAMP_EFFICACY_LM_PER_W",
    "radiant_power_w",
    "point_source_irradiance_w_m2",
    "lamp_visibility",
    "photons_per_joule_through",
    "lamp_level",
    "Leak",
    "leak_through_layers",
    "lamp_position_m",
    "lamp_above_tips_m",
    "leaked_photon_sd",
]

#: Typical luminous efficacy (lm per electrical W) of each lamp type [DOE2016]: the daylight tube
#: with its ballast, and a white LED lamp.
LAMP_EFFICACY_LM_PER_W = MappingProxyType({"daylight": 60.0, "white_led": 100.0})


def radiant_power_w(lamp: str, electrical_w: float, efficacy_lm_per_w: float | None = None) -> float:
    """Radiant power (W, 380-780 nm) of a lamp: P_el x efficacy / K, K the luminous efficacy of its
    spectrum (lm per optical W, :func:`colour.luminous_efficacy`; about 293 for FL1, 319 for LED-B4)."""
    from mlsim import spectra
    from mlsim.spectra import colour  # (imported there without its plotting package: mlsim.spectra._defer_colour_plotting)

    if lamp not in LAMP_EFFICACY_LM_PER_W:
        raise ValueError(f"lamp {lamp!r}: choose one of {', '.join(LAMP_EFFICACY_LM_PER_W)}")
    if not electrical_w >= 0:
        raise ValueError(f"electrical_w = {electrical_w}: must be >= 0")
    efficacy = LAMP_EFFICACY_LM_PER_W[lamp] if efficacy_lm_per_w is None else float(efficacy_lm_per_w)
    k_spectrum = float(colour.luminous_efficacy(spectra.lamp_sd(lamp)))
    if not 0 < efficacy < k_spectrum:
        raise ValueError(f"efficacy {efficacy:g} lm/W of the {lamp} lamp: must be in (0, {k_spectrum:.0f}) (its spectrum's own efficacy)")
    return float(electrical_w) * efficacy / k_spectrum


def lamp_position_m(scene) -> np.ndarray:
    """(3,) the ambient lamp's position: ``ambient.height_m`` above the rods' tips, at ``offset_mm``."""
    return lamp_above_tips_m(scene, scene.ambient.height_m, scene.ambient.offset_mm)


def lamp_above_tips_m(scene, height_m: float, offset_mm=(0.0, 0.0)) -> np.ndarray:
    """(3,) a lamp ``height_m`` above the rods' tips, at ``offset_mm`` (x, y) from the array's centre."""
    s = scene.sensor
    top_m = (s.base.thickness_mm + s.rod.height_mm) * 1e-3
    return np.array([offset_mm[0] * 1e-3, offset_mm[1] * 1e-3, top_m + height_m], dtype=float)


def point_source_irradiance_w_m2(points_m, normals, lamp_m, power_w: float, visible=None) -> np.ndarray:
    """Irradiance (N,) W/m^2 of an isotropic point source of ``power_w`` at ``lamp_m`` (3,) on
    surface points (N, 3) with unit outward normals (N, 3): P / (4 pi r^2) max(0, n . l) V."""
    p = np.asarray(points_m, dtype=float)
    n = np.asarray(normals, dtype=float)
    if p.ndim != 2 or p.shape[1] != 3 or n.shape != p.shape:
        raise ValueError(f"points {p.shape} and normals {n.shape}: must both be (N, 3)")
    d = np.asarray(lamp_m, dtype=float)[None] - p
    r2 = np.einsum("ij,ij->i", d, d)
    if np.any(r2 <= 0):
        raise ValueError("the lamp sits on the surface: move it (ambient.height_m > 0)")
    cos = np.clip(np.einsum("ij,ij->i", n, d) / np.sqrt(r2), 0.0, None)
    e = float(power_w) / (4.0 * math.pi * r2) * cos
    return e if visible is None else e * np.asarray(visible, dtype=float)


def lamp_visibility(sensor_scene, points_m, normals, lamp_m, offset_m: float = 1e-6) -> np.ndarray:
    """(N,) 1.0 where the segment from each point (moved ``offset_m`` along its normal) to the lamp
    meets nothing in the sensor scene, else 0.0 (Mitsuba's ``ray_test`` on its BVH)."""
    from mlsim.render.sensor_scene import use_variant

    mi = use_variant(sensor_scene.variant)  # the sheet scene's own (mono, on its device)
    o = (np.asarray(points_m, dtype=float) + offset_m * np.asarray(normals, dtype=float)) * 1e3  # Mitsuba works in mm
    d = np.asarray(lamp_m, dtype=float)[None] * 1e3 - o
    dist = np.linalg.norm(d, axis=1)
    d = d / dist[:, None]
    ray = mi.Ray3f(mi.Point3f(*[mi.Float(o[:, k].astype(np.float32)) for k in range(3)]),
                   mi.Vector3f(*[mi.Float(d[:, k].astype(np.float32)) for k in range(3)]))
    ray.maxt = mi.Float(dist.astype(np.float32))
    hit = np.array(sensor_scene.scene.ray_test(ray), dtype=bool)
    return (~hit).astype(float)


def photons_per_joule_through(lamp: str, absorber: str, absorber_thickness_mm: float | None = None) -> float:
    """Photons passing the absorber per joule of lamp light reaching it:
    integral( p_lamp(lambda) lambda / (h c) T_abs(lambda) dlambda ), p_lamp normalised to 1 W."""
    sd = leaked_photon_sd(lamp, absorber, absorber_thickness_mm)
    return float(trapezoid(np.asarray(sd.values, dtype=float), np.asarray(sd.wavelengths, dtype=float)))


def leaked_photon_sd(lamp: str, absorber: str, absorber_thickness_mm: float | None = None):
    """The photon spectrum (shape) of lamp light behind the absorber: p_lamp lambda / (h c) T_abs."""
    from mlsim import spectra

    wl = spectra.wavelengths_nm()
    n = np.asarray(spectra.photon_sd(spectra.lamp_sd(lamp)).values, dtype=float)
    t = np.asarray(spectra.absorber_transmittance_sd(absorber, absorber_thickness_mm).values, dtype=float)
    return spectra.colour.SpectralDistribution(dict(zip(wl, n * t)), name=f"{lamp} lamp behind absorber {absorber} (photons/s/nm)")


def lamp_level(windows_s, flicker_hz: float = 0.0, flicker_depth: float = 0.0, switch_on_s: float | None = None,
               switch_off_s: float | None = None) -> np.ndarray:
    """Mean relative lamp power over each exposure window (F, 2) s -> (F,).

    p(t) = (1 + m cos(2 pi f t)) on [switch_on, switch_off), 0 elsewhere: a lamp on mains whose
    light ripples at twice the line frequency (f = 100 or 120 Hz) with modulation depth
    m = (max - min) / (max + min), phase 0 at t = 0. The mean over [a, b] is exact:
    (b' - a' + m (sin 2 pi f b' - sin 2 pi f a') / (2 pi f)) / (b - a) on the lit part [a', b']."""
    w = np.asarray(windows_s, dtype=float)
    if w.ndim != 2 or w.shape[1] != 2 or np.any(w[:, 1] <= w[:, 0]):
        raise ValueError(f"windows_s of shape {w.shape}: must be (F, 2) with end > start")
    if not 0.0 <= flicker_depth <= 1.0 or not flicker_hz >= 0.0:
        raise ValueError(f"flicker_hz = {flicker_hz}, flicker_depth = {flicker_depth}: need hz >= 0 and depth in [0, 1]")
    a = w[:, 0] if switch_on_s is None else np.maximum(w[:, 0], switch_on_s)
    b = w[:, 1] if switch_off_s is None else np.minimum(w[:, 1], switch_off_s)
    lit = np.clip(b - a, 0.0, None)
    energy = lit.copy()
    if flicker_hz > 0 and flicker_depth > 0:
        omega = 2.0 * math.pi * flicker_hz
        energy += np.where(lit > 0, flicker_depth * (np.sin(omega * b) - np.sin(omega * a)) / omega, 0.0)
    return energy / (w[:, 1] - w[:, 0])


@dataclass(frozen=True)
class Leak:
    """Lamp light entering the core: ``photons_per_s`` (N,) per sheet vertex at lamp level 1, its
    photon spectrum ``sd`` (shape; for the channel factors), the irradiance on the outer surface
    (N,) W/m^2 and the share of the surface the rods shade from the lamp."""

    photons_per_s: np.ndarray
    sd: object
    irradiance_w_m2: np.ndarray
    shaded_fraction: float
    radiant_power_w: float


def leak_through_layers(scene, patches, sensor_scene, *, lamp: str, power_w: float, lamp_m, absorber: str,
                        efficacy_lm_per_w: float | None = None, occlusion: bool = True) -> Leak:
    """The :class:`Leak` of a lamp at ``lamp_m`` through ``absorber`` and the ML layer into the core,
    on the emitting sheet ``patches`` (:class:`mlsim.emission.patches.MLPatches`; outward normals)."""
    power = radiant_power_w(lamp, power_w, efficacy_lm_per_w)
    visible = lamp_visibility(sensor_scene, patches.vertices_m, patches.normals, lamp_m) if occlusion else None
    e = point_source_irradiance_w_m2(patches.vertices_m, patches.normals, lamp_m, power, visible)
    facing = point_source_irradiance_w_m2(patches.vertices_m, patches.normals, lamp_m, 1.0) > 0
    shaded = 0.0 if visible is None else float(((visible == 0) & facing).sum() / max(facing.sum(), 1))
    thickness = scene.sensor.layers.absorber_mm
    per_joule = photons_per_joule_through(lamp, absorber, thickness)
    photons = e * patches.area_m2 * scene.optics.ml_layer_transmittance * per_joule
    return Leak(photons, leaked_photon_sd(lamp, absorber, thickness), e, shaded, power)
