"""A thin hyperelastic layer under a contact traction: the magnetised skin's deformation without FEM (SPEC 2).

The siblings keep simpler mechanics than the main sensor's FEM. The skin is a layer of thickness t
whose base (z = base) is held and whose top carries a traction field (tau_x, tau_y, -p) (Pa; p >= 0
presses). Each vertical column deforms on its own (a Winkler-type simplification: no load spreading
between columns, as :mod:`other_sensors.anyskin.skin`'s; Johnson, *Contact Mechanics*, 1985, sec. 5.9)
as an incompressible neo-Hookean solid (shear modulus mu; Ogden, *Non-linear Elastic Deformations*,
1984, sec. 7.2):

- compression: uniaxial stress, nominal stress P = mu (lambda - lambda^-2), so a pressure p gives the
  stretch lambda in (0, 1] of mu lambda^3 + p lambda^2 - mu = 0 (one root there; lambda ~ 1 - p / (3 mu)
  for small p, ~ sqrt(mu / p) for large: it never reaches 0, so a pressed skin never inverts);
- shear: simple shear, whose Cauchy shear stress is exactly mu gamma for the neo-Hookean solid:
  gamma = tau / mu.

A point at height zeta over the base moves by (gamma_x zeta, gamma_y zeta, (lambda - 1) zeta). The
columns' lateral bulge (lambda^-1/2 in free uniaxial stress) is neglected: a simplification that
loses volume under compression (the moment m = F M~ dV0 of :mod:`other_sensors.anyskin.magnet_volume`
shrinks with lambda accordingly); a tensile (pulling) normal traction is no contact (zero).
"""

from __future__ import annotations

import numpy as np

__all__ = ["compressive_stretch", "layer_displacement"]


def compressive_stretch(pressure_pa, shear_modulus_pa: float):
    """The neo-Hookean column's stretch lambda (any shape, in (0, 1]) under a compressive pressure
    (any shape, Pa; values <= 0 give 1): the root in (0, 1] of mu l^3 + p l^2 - mu = 0, by Newton from 1."""
    p = np.maximum(np.asarray(pressure_pa, dtype=float), 0.0)
    mu = float(shear_modulus_pa)
    if not (np.isfinite(mu) and mu > 0):
        raise ValueError(f"sensor.skin.modulus_kpa: the shear modulus {mu} Pa must be finite and > 0")
    if not np.isfinite(p).all():
        raise ValueError("thin layer: the contact pressure must be finite")
    # f(l) = mu l^3 + p l^2 - mu is increasing and convex on (0, inf), f(1) = p >= 0: from l = 1 Newton
    # stays right of the root and falls onto it monotonically
    lam = np.ones_like(p)
    for _ in range(60):
        f = mu * lam**3 + p * lam**2 - mu
        step = f / (3 * mu * lam**2 + 2 * p * lam)
        lam = lam - step
        if np.all(np.abs(step) <= 1e-15 * np.abs(lam)):
            break
    return lam


def layer_displacement(nodes, base_z_m: float, thickness_m: float, traction_pa, shear_modulus_pa: float):
    """Displacements (V, 3) m of the layer's nodes (V, 3) m under the traction on its top, traction_pa
    (V, 3) Pa evaluated at each node's (x, y) (tau_x, tau_y, normal; normal < 0 presses)."""
    x = np.asarray(nodes, dtype=float)
    tr = np.asarray(traction_pa, dtype=float)
    if tr.shape != x.shape:
        raise ValueError(f"thin layer: traction {tr.shape} must match the nodes {x.shape}")
    zeta = x[:, 2] - base_z_m
    if np.any(zeta < -1e-12 * thickness_m) or np.any(zeta > thickness_m * (1 + 1e-12)):
        raise ValueError("thin layer: every node must lie within the layer (base <= z <= base + thickness)")
    pressing = tr[:, 2] < 0
    lam = compressive_stretch(np.where(pressing, -tr[:, 2], 0.0), shear_modulus_pa)
    shear = np.where(pressing[:, None], tr[:, :2] / shear_modulus_pa, 0.0)
    return np.column_stack([shear * zeta[:, None], (lam - 1.0) * zeta])
