"""The foam pillars' hysteresis and rate dependence: a Maxwell arm beside the elastic law (SPEC 3's foam).

SPEC 3 says only "soft then stiffening" foam, and its estimator turns an estimated pose into a
force through the elastic law of :mod:`other_sensors.cls.shell`. Real polyurethane foam is
viscoelastic (Mills, *Polymer Foams Handbook*, 2007, ch. 10: its loss factor is 0.1-0.5 over
0.1-10 Hz). The truth here is the generalised Zener (standard linear) solid: each pillar's axial
stress is the elastic law's plus a Maxwell arm's,

    sigma = sigma_e(eps) + sigma_v,   d sigma_v / dt = E1 d eps / dt - sigma_v / tau,

(Findley, Lai & Onaran, *Creep and Relaxation of Nonlinear Viscoelastic Materials*, 1976, ch. 5)
and its shear stress likewise with E1 / 3 (the elastic law's G = E0 / 3). Under a sinusoidal
strain of angular frequency w the arm stores E1 (w tau)^2 / (1 + (w tau)^2) and loses
E1 w tau / (1 + (w tau)^2) (the loss modulus): the force leads the pose and the loop's area is
pi eps0^2 E'' per cycle. A simplification: one relaxation time, a linear arm on the nonlinear
spring. The integration is exact for strain linear between samples.
"""

from __future__ import annotations

import numpy as np

from other_sensors.cls.ltv import PairLayout
from other_sensors.cls.shell import Foam, pillar_strains, pose_wrench

__all__ = ["maxwell_stress", "viscoelastic_wrench"]


def maxwell_stress(strain, t_s, modulus_kpa: float, relaxation_s: float):
    """The Maxwell arm's stress (T, ...) kPa under a strain history (T, ...) sampled at times t_s (T,) s,
    from rest (sigma_v = 0 before the first sample): sigma_v[k+1] = a sigma_v[k] + E1 (d eps / dt) tau (1 - a),
    a = exp(-dt / tau), exact for strain linear between samples."""
    strain, t = np.asarray(strain, float), np.asarray(t_s, float)
    if not (np.isfinite(modulus_kpa) and modulus_kpa >= 0):
        raise ValueError(f"sensor.foam.maxwell_kpa = {modulus_kpa}: must be finite and >= 0")
    if not (np.isfinite(relaxation_s) and relaxation_s > 0):
        raise ValueError(f"sensor.foam.relaxation_s = {relaxation_s}: must be finite and > 0")
    if len(t) != len(strain) or np.any(np.diff(t) <= 0):
        raise ValueError("maxwell_stress: give one strain per time, times increasing")
    out = np.zeros_like(strain)
    dt = np.diff(t)
    a = np.exp(-dt / relaxation_s)
    gain = modulus_kpa * relaxation_s * (1.0 - a) / dt
    for k in range(len(t) - 1):
        out[k + 1] = a[k] * out[k] + gain[k] * (strain[k + 1] - strain[k])
    return out


def viscoelastic_wrench(pose3, t_s, foam: Foam, layout: PairLayout, maxwell_kpa: float, relaxation_s: float):
    """The contact wrench (T, 3) = (F_y N, F_z N, M_x N m) holding the shell on the viscoelastic
    pillars along a trajectory of planar poses (T, 3) at times t_s (T,) s (the module's law)."""
    strain, gamma, _, _ = pillar_strains(pose3, foam, layout)
    axial = maxwell_stress(strain, t_s, maxwell_kpa, relaxation_s)
    shear = maxwell_stress(gamma, t_s, maxwell_kpa / 3.0, relaxation_s)
    return pose_wrench(pose3, foam, layout, axial, shear)
