"""The skin models that generate the chips' field (the simulated world), chosen by ``sensor.skin.truth``.

- ``"magnet_volume"`` (the default, the richer world of issue 43): the skin as a finite magnetised
  volume over a thin incompressible neo-Hookean layer (:mod:`other_sensors.anyskin.skin_volume`);
- ``"point_dipole"``: a grid of point dipoles over a saturating linear Winkler layer
  (:mod:`other_sensors.anyskin.skin`), the simpler world the estimator was first built on; kept to
  compare against (the push study runs both).

Both take the contact forces (T, S, 3) N on S skins (sensor frames) and return the skins' field at
their chips (T, S, 5, 3) uT, the undeformed field (5, 3) uT and each skin's largest permanent set (T, S) mm.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from mlsim.errors import SceneError

from .skin import N_MAGNETOMETERS, contact_displacement, permanent_set, skin_field, skin_geometry

__all__ = ["SkinFields", "TRUTH_MODELS", "truth_model", "skin_fields", "worst_stretch"]


@dataclass(frozen=True)
class SkinFields:
    """skin (T, S, 5, 3) uT; baseline (5, 3) uT, the rest field; set_mm (T, S), each skin's largest set."""

    skin: np.ndarray
    baseline: np.ndarray
    set_mm: np.ndarray


def _set(x, sensor, dt):
    d = sensor.drift
    if d.enabled and d.set_fraction > 0:
        return permanent_set(x, dt, d.set_fraction, d.tau_set_s, d.tau_relax_s)
    return np.zeros_like(x)


def _point_dipole(sensor, force, dt) -> SkinFields:
    s = sensor.skin
    geometry = skin_geometry(s.side_mm * 1e-3, s.thickness_mm * 1e-3, s.gap_mm * 1e-3, s.grid, s.magnetisation_ka_m * 1e3,
                             sensor.magnetometers.pitch_mm * 1e-3)
    n_t, n_s = force.shape[:2]
    skin, set_mm = np.empty((n_t, n_s, N_MAGNETOMETERS, 3)), np.zeros((n_t, n_s))
    for i in range(n_s):
        u = contact_displacement(geometry, force[:, i], (0.0, 0.0), s.contact_radius_mm * 1e-3, s.modulus_kpa * 1e3, s.max_strain)
        st = _set(u, sensor, dt)
        set_mm[:, i] = 1e3 * np.linalg.norm(st, axis=-1).max(axis=-1)
        skin[:, i] = skin_field(geometry, u + st)
    return SkinFields(skin, skin_field(geometry), set_mm)


def volume_of(sensor):
    """The :class:`other_sensors.anyskin.skin_volume.VolumeSkin` of a sensor's ``[sensor.skin]``."""
    from .skin_volume import volume_skin

    s = sensor.skin
    return volume_skin(s.side_mm * 1e-3, s.thickness_mm * 1e-3, s.gap_mm * 1e-3, s.grid, s.magnetisation_ka_m * 1e3,
                       sensor.magnetometers.pitch_mm * 1e-3, s.modulus_kpa * 1e3, s.contact_radius_mm * 1e-3)


def worst_stretch(sensor, force_n: float) -> float:
    """The magnet volume's least column stretch 1 + h_z under a normal force force_n (N) on one skin with
    its set at the scene's fraction of it (the set's ceiling): <= 0 means the skin would invert."""
    from .thin_layer import compressive_stretch

    s = sensor.skin
    a = s.contact_radius_mm * 1e-3
    with np.errstate(over="ignore", divide="ignore"):
        pressure = np.float64(force_n) / (2 * np.pi * a * a)  # the patch's peak
    if not np.isfinite(pressure):
        return -np.inf  # a patch too small to carry the force: no stretch is left
    lam = float(compressive_stretch(pressure, s.modulus_kpa * 1e3 / 3.0))
    f = sensor.drift.set_fraction if sensor.drift.enabled else 0.0
    return 1.0 - (1.0 + f) * (1.0 - lam)


def _magnet_volume(sensor, force, dt) -> SkinFields:
    from .skin_volume import column_strains, volume_field

    vs = volume_of(sensor)
    n_t, n_s = force.shape[:2]
    strains, set_mm = [], np.zeros((n_t, n_s))
    for i in range(n_s):
        h = column_strains(vs, force[:, i])
        st = _set(h, sensor, dt)
        set_mm[:, i] = 1e3 * vs.thickness * np.linalg.norm(st, axis=-1).max(axis=-1)  # the top of the column moves by t s
        strains.append(h + st)
    h = np.concatenate(strains)  # one table for all the skins
    least = 1.0 + h[..., 2].min()
    if least <= 0:
        raise SceneError([("sensor.drift.set_fraction", sensor.drift.set_fraction,
                           f"the elastic compression plus the permanent set reach the skin's whole thickness (stretch "
                           f"{least:.3g} <= 0: the magnet volume inverts); lower it or sensor.push.peak_n, or raise "
                           "sensor.skin.modulus_kpa or contact_radius_mm")])
    field = volume_field(vs, h).reshape(n_s, n_t, N_MAGNETOMETERS, 3).transpose(1, 0, 2, 3)
    return SkinFields(field, volume_field(vs), set_mm)


TRUTH_MODELS: dict[str, Callable] = {"magnet_volume": _magnet_volume, "point_dipole": _point_dipole}


def truth_model(name: str) -> Callable:
    """The truth model called name; a ValueError names the choices."""
    if name not in TRUTH_MODELS:
        raise ValueError(f"sensor.skin.truth = {name!r} is not a truth model; choose one of: {', '.join(TRUTH_MODELS)}")
    return TRUTH_MODELS[name]


def skin_fields(sensor, force_n, dt_s: float) -> SkinFields:
    """The field of the scene's skins (its ``sensor.skin.truth``) under the contact forces (T, S, 3) N."""
    return truth_model(sensor.skin.truth)(sensor, np.asarray(force_n, dtype=float), dt_s)
