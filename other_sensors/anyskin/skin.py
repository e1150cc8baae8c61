"""One AnySkin sensor (SPEC 2): a magnetised elastomer skin over five three-axis magnetometers.

Frame: the sensor frame has z along the skin's outward normal, x and y in the board; the
magnetometers sit on the board (z = 0) in a cross (the centre and four at +-pitch along x and y).

Skin: a square layer (side s, thickness t) at height g above the magnetometers, magnetised along
+z with magnetisation M (A/m), lumped into an n x n grid of point dipoles at mid-thickness, each of
moment M s^2 t / n^2 (:mod:`other_sensors.anyskin.dipoles`). A simplification: one dipole layer
(the layer's field at the board is the same to O((t / 2 g)^2)), and the moments keep their
direction when the skin deforms (their tilt under shear is neglected).

Contact deformation: a thin elastic layer bonded to the board (a Winkler layer, Johnson, *Contact
Mechanics*, 1985, sec. 5.9), loaded by a Gaussian traction patch of radius a carrying the contact
force F (N, on the skin, sensor frame; F_z < 0 presses). A dipole at height h above the layer's
base moves by u = h (tau_x / G, tau_y / G, tau_z / E) (strain = stress / modulus, G = E / 3 for an
incompressible rubber), each strain saturated smoothly at +-max_strain (s tanh(e / s)). This
simplifies away the load's spreading between neighbouring points (a Boussinesq half-space
would spread it), the layer's incompressibility under the patch's edge, and large-strain elasticity.

Drift: see :func:`permanent_set` (skin creep, the dominant source), :func:`geomagnetic_reading`
(the Earth's field seen by a rotating head), :func:`motor_field` (gait-dependent motor fields).
Readings: :func:`read_out` adds white noise and quantises. Fields are returned in microtesla.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dipoles import dipole_field

__all__ = ["SkinGeometry", "skin_geometry", "contact_displacement", "skin_field", "permanent_set",
           "geomagnetic_reading", "motor_field", "read_out", "N_MAGNETOMETERS"]

N_MAGNETOMETERS = 5  # per sensor (SPEC 2): the centre and four around it
T_TO_UT = 1e6


@dataclass(frozen=True)
class SkinGeometry:
    """Rest state of one sensor's skin, sensor frame, SI: dipoles (N, 3) m, moments (N, 3) A m^2,
    magnetometers (5, 3) m, thickness m, dipole height above the layer's base m."""

    dipoles: np.ndarray
    moments: np.ndarray
    magnetometers: np.ndarray
    thickness: float
    height_in_layer: float


def skin_geometry(side_m: float, thickness_m: float, gap_m: float, grid: int, magnetisation_a_m: float,
                  magnetometer_pitch_m: float) -> SkinGeometry:
    """The lumped skin and the magnetometer cross; see the module docstring."""
    if grid < 1 or side_m <= 0 or thickness_m <= 0 or gap_m <= 0:
        raise ValueError(f"skin: grid {grid}, side {side_m} m, thickness {thickness_m} m, gap {gap_m} m must be > 0")
    c = (np.arange(grid) + 0.5) / grid * side_m - side_m / 2
    x, y = np.meshgrid(c, c, indexing="ij")
    z = np.full(x.size, gap_m + thickness_m / 2)
    dipoles = np.column_stack([x.ravel(), y.ravel(), z])
    moments = np.zeros_like(dipoles)
    moments[:, 2] = magnetisation_a_m * side_m**2 * thickness_m / grid**2
    p = magnetometer_pitch_m
    mags = np.array([[0, 0, 0], [p, 0, 0], [-p, 0, 0], [0, p, 0], [0, -p, 0]], dtype=float)
    return SkinGeometry(dipoles, moments, mags, thickness_m, thickness_m / 2)


def _saturate(strain, max_strain):
    return max_strain * np.tanh(strain / max_strain)


def contact_displacement(geometry: SkinGeometry, force_n, centre_m, radius_m: float, modulus_pa: float,
                         max_strain: float) -> np.ndarray:
    """Displacement of each dipole under a Gaussian traction patch.

    force_n: (T, 3) N on the skin, sensor frame (F_z < 0 presses; F_z >= 0 is no contact).
    centre_m: (2,) or (T, 2) m, the patch centre in the board. Returns u (T, N, 3) m.
    """
    force = np.atleast_2d(np.asarray(force_n, dtype=float))
    centre = np.broadcast_to(np.asarray(centre_m, dtype=float), (len(force), 2))
    d2 = ((geometry.dipoles[None, :, :2] - centre[:, None, :]) ** 2).sum(axis=-1)  # (T, N)
    weight = np.exp(-d2 / (2 * radius_m**2)) / (2 * np.pi * radius_m**2)  # 1/m^2, integrates to 1
    pressing = force[:, 2] < 0
    traction = np.where(pressing[:, None, None], force[:, None, :] * weight[:, :, None], 0.0)  # (T, N, 3) Pa
    strain = traction / np.array([modulus_pa / 3, modulus_pa / 3, modulus_pa])
    return geometry.height_in_layer * _saturate(strain, max_strain)


def skin_field(geometry: SkinGeometry, displacement=None) -> np.ndarray:
    """Flux density of the (displaced) skin at the magnetometers, microtesla.

    displacement: None (rest) or (T, N, 3) m. Returns (5, 3) at rest, else (T, 5, 3).
    """
    if displacement is None:
        return T_TO_UT * dipole_field(geometry.magnetometers, geometry.dipoles, geometry.moments)
    positions = geometry.dipoles[None] + displacement
    return T_TO_UT * dipole_field(geometry.magnetometers[None], positions, geometry.moments[None])


def permanent_set(elastic, dt_s: float, fraction: float, tau_set_s: float, tau_relax_s: float) -> np.ndarray:
    """Permanent deformation of the skin (creep and set), a first-order model per component.

    elastic: (T, ...) the elastic deformation (any unit). The set s follows the target fraction * elastic
    with time constant tau_set while it grows in magnitude (loading) and tau_relax while it shrinks:
    ds/dt = (fraction e - s) / tau. Updated exactly for an input held over each sample, so a step load
    e0 from s = 0 gives s(t) = fraction e0 (1 - exp(-t / tau_set)) and its release s(T) exp(-(t - T) / tau_relax).
    With tau_relax > tau_set and cycles shorter than both, the set ratchets up over repeated loads:
    the skin's dominant drift (SPEC 2). Returns s, the shape of elastic; s[0] = 0 (a fresh skin).
    """
    elastic = np.asarray(elastic, dtype=float)
    if tau_set_s <= 0 or tau_relax_s <= 0:
        raise ValueError(f"drift: tau_set_s {tau_set_s} and tau_relax_s {tau_relax_s} must be > 0")
    a_set, a_relax = np.exp(-dt_s / tau_set_s), np.exp(-dt_s / tau_relax_s)
    out = np.empty_like(elastic)
    s = np.zeros(elastic.shape[1:])
    for k in range(len(elastic)):
        out[k] = s
        target = fraction * elastic[k]
        decay = np.where(np.abs(target) > np.abs(s), a_set, a_relax)
        s = target + (s - target) * decay
    return out


def geomagnetic_reading(sensor_to_world, b_world_ut) -> np.ndarray:
    """The Earth's field in each sensor frame: R^T b. sensor_to_world: (..., 3, 3); b_world_ut (3,) uT.
    Returns (..., 3) uT; its magnitude is |b| whatever the orientation."""
    return np.einsum("...ji,j->...i", np.asarray(sensor_to_world, dtype=float), np.asarray(b_world_ut, dtype=float))


def motor_field(t_s, gait_hz: float, directions, amplitude_ut: float) -> np.ndarray:
    """Stray field of the neck and leg motors, (T, C, 3) uT: each channel sees a fixed direction
    (C, 3) (unit) scaled by |sin(2 pi f t)|, the motor current's envelope that peaks twice per gait cycle."""
    envelope = np.abs(np.sin(2 * np.pi * gait_hz * np.asarray(t_s, dtype=float)))
    return amplitude_ut * envelope[:, None, None] * np.asarray(directions, dtype=float)[None]


def read_out(clean_ut, noise_ut: float, lsb_ut: float, rng: np.random.Generator) -> np.ndarray:
    """Magnetometer readings: clean + N(0, noise^2) per axis, then rounded to multiples of lsb (0: no rounding)."""
    clean = np.asarray(clean_ut, dtype=float)
    noisy = clean + rng.normal(0.0, noise_ut, clean.shape) if noise_ut > 0 else clean.copy()
    return lsb_ut * np.round(noisy / lsb_ut) if lsb_ut > 0 else noisy
