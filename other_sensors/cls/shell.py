"""The CLS shell on its foam pillars: the foam law, the wrench a pose needs, trajectories and the pairs' signals (SPEC 3).

Foam (documented simplification; the SPEC says only "three pillars, 1.5 in tall, 1.5 in^2 section,
soft then stiffening"): each pillar is a column of foam clamped to the base and to the shell. Its
axial stress follows a stiffening law of the engineering strain eps = compression / height,

    sigma(eps) = E0 eps (1 + (eps / eps_s)^2)

(odd in eps, so tension mirrors compression), and its shear stress is linear, tau = G gamma with
G = E0 / 3 and gamma = lateral offset / height. Bending of the pillars is neglected: the shell's
rotational stiffness comes from the pillars' axial forces at their lever arms. The contact wrench
that holds the shell at a pose is minus the sum of the pillars' forces and moments about the shell
origin (statics; the shell's inertia is neglected at these speeds).

Trajectories are given in pose space (y, z, rx) at the voltage rate (2 kHz), each starting with
``rest_s`` of rest: rest, compression (z down and back), shear (y), rotation (rx) and general
motion (a seeded sum of sines in all three). The reference poses are the same trajectory sampled at
the reference rate (80 Hz, the motion-capture rate of SPEC 3). :func:`trajectory6` gives the same five
kinds as full 6-DoF poses (x, y, z, rotation vector) for a shell read by pairs off a line
(:func:`ltv.ring_layout`); the foam law and the scenes stay planar (SPEC 3's prototype).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from other_sensors.cls.ltv import PairLayout, pair_voltages, planar_voltages, pose6_to_pose

__all__ = ["Foam", "foam_stress", "pillar_strains", "pose_wrench", "pose_from_wrench", "trajectory", "trajectory6", "measure", "measure6",
           "TRAJECTORIES", "digitise",
           "ADC_BITS", "ADC_RANGE_V"]

# A choice: the foam's small-strain modulus (a soft polyurethane foam, ~30 kPa) and the strain at
# which it has stiffened to twice its small-strain tangent (~ 1/3 of the height).
FOAM_E0_KPA = 30.0
FOAM_STIFFENING_STRAIN = 0.3
PILLAR_HEIGHT_MM = 38.1  # 1.5 in (SPEC 3)
PILLAR_SECTION_MM2 = 967.7  # 1.5 in^2 (SPEC 3)
PILLAR_Y_MM = (-45.0, 0.0, 45.0)  # a choice: evenly along the 80 mm line of pairs, slightly beyond it
# A choice: a 16-bit ADC over 0-5 V (LSB 76 uV, so quantisation adds ~22 uV RMS to the 0.7 mV rest
# noise); a 12-bit one over 3.3 V would have a 0.8 mV LSB and hide the noise it should measure.
ADC_BITS = 16
ADC_RANGE_V = 5.0

TRAJECTORIES = ("rest", "compression", "shear", "rotation", "general")


@dataclass(frozen=True)
class Foam:
    """The pillars: height mm, section mm^2, E0 kPa, stiffening strain, y positions mm (shell frame)."""

    height_mm: float = PILLAR_HEIGHT_MM
    section_mm2: float = PILLAR_SECTION_MM2
    e0_kpa: float = FOAM_E0_KPA
    stiffening_strain: float = FOAM_STIFFENING_STRAIN
    pillar_y_mm: tuple = PILLAR_Y_MM


def foam_stress(strain, e0_kpa: float, stiffening_strain: float):
    """Axial stress (kPa) of the foam at engineering compressive strain (any shape)."""
    strain = np.asarray(strain, float)
    return e0_kpa * strain * (1.0 + (strain / stiffening_strain) ** 2)


def pillar_strains(pose3, foam: Foam, layout: PairLayout):
    """Each pillar's engineering strains at planar poses (..., 3) = (y mm, z mm, rx rad): axial
    compression / height and shear offset / height, each (..., 3); and its top's offset (wy, wz) (..., 3)
    mm from the shell origin in the base frame (the lever arms of :func:`pose_wrench`)."""
    pose3 = np.asarray(pose3, float)
    y, z, rx = (pose3[..., k, None] for k in range(3))
    gap = layout.rest_p[2]
    py = np.asarray(foam.pillar_y_mm, float)
    top_z = gap - foam.height_mm  # the pillar tops sit this far below the shell origin (mounts)
    # each pillar's top, (0, py, -top_z) in the shell frame, in the base frame
    ay, az = py, -np.full_like(py, top_z)
    c, s = np.cos(rx), np.sin(rx)
    wy, wz = c * ay - s * az, s * ay + c * az
    ty, tz = y + wy, z + wz
    compression = foam.height_mm - tz  # the pillar's base is at z = 0 below its rest top
    return compression / foam.height_mm, (ty - py) / foam.height_mm, wy, wz


def pose_wrench(pose3, foam: Foam, layout: PairLayout, extra_axial_kpa=None, extra_shear_kpa=None):
    """The contact wrench (..., 3) = (F_y N, F_z N, M_x N m) about the shell origin that holds the
    shell at planar poses (..., 3) = (y mm, z mm, rx rad) on the pillars (see the module).
    extra_axial_kpa, extra_shear_kpa (..., 3): stresses added to each pillar's elastic ones (a
    viscoelastic arm's, :mod:`other_sensors.cls.foam_viscoelastic`); None: the elastic foam alone."""
    strain, gamma, wy, wz = pillar_strains(pose3, foam, layout)
    sigma = foam_stress(strain, foam.e0_kpa, foam.stiffening_strain) + (0.0 if extra_axial_kpa is None else extra_axial_kpa)
    tau = (foam.e0_kpa / 3.0) * gamma + (0.0 if extra_shear_kpa is None else extra_shear_kpa)
    area_m2 = foam.section_mm2 * 1e-6
    fz = sigma * 1e3 * area_m2  # N, up on the shell
    fy = -tau * 1e3 * area_m2
    mx = (wy * fz - wz * fy) * 1e-3  # N m about the shell origin
    return -np.stack([fy.sum(-1), fz.sum(-1), mx.sum(-1)], axis=-1)


def pose_from_wrench(wrench, foam: Foam, layout: PairLayout, tol: float = 1e-10, max_iter: int = 50):
    """The planar pose (3,) at which the pillars balance a contact wrench (3,) = (F_y N, F_z N,
    M_x N m): Newton's method from the rest pose with a central-difference Jacobian."""
    wrench = np.asarray(wrench, float)
    mu = np.array([0.0, layout.rest_p[2], 0.0])
    h = np.array([1e-4, 1e-4, 1e-6])
    for _ in range(max_iter):
        res = pose_wrench(mu, foam, layout) - wrench
        J = np.stack([(pose_wrench(mu + np.eye(3)[k] * h[k], foam, layout) - pose_wrench(mu - np.eye(3)[k] * h[k], foam, layout))
                      / (2 * h[k]) for k in range(3)], axis=1)
        step = np.linalg.solve(J, res)
        mu = mu - step
        if np.max(np.abs(step / np.array([1.0, 1.0, 1e-2]))) < tol:
            return mu
    raise ValueError(f"wrench = {wrench.tolist()}: the foam found no balance in {max_iter} Newton steps; is it beyond the pillars' range?")


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)


def trajectory(shape: str, t, rest_s: float, rest_z_mm: float, compression_mm: float, shear_mm: float,
               rotation_deg: float, frequency_hz: float, rng: np.random.Generator):
    """Planar poses (N, 3) = (y mm, z mm, rx rad) at times t (N,) s: rest until ``rest_s``, then the
    motion ``shape`` (one of TRAJECTORIES). ``rng`` draws the general motion's sines."""
    if shape not in TRAJECTORIES:
        raise ValueError(f'sensor.trajectory.shape = "{shape}": not a trajectory; choose one of: {", ".join(TRAJECTORIES)}')
    t = np.asarray(t, float)
    tau = np.maximum(t - rest_s, 0.0)
    phase = 2 * np.pi * frequency_hz * tau
    y, dz, rx = np.zeros_like(t), np.zeros_like(t), np.zeros_like(t)
    rot = np.radians(rotation_deg)
    if shape == "compression":
        dz = -compression_mm * (1 - np.cos(phase)) / 2
    elif shape == "shear":
        y = shear_mm * np.sin(phase)
    elif shape == "rotation":
        rx = rot * np.sin(phase)
    elif shape == "general":
        ramp = _smoothstep(tau / 0.25)  # a smooth start: the motion grows over 0.25 s

        def sines():
            f = frequency_hz * rng.uniform(0.5, 3.0, size=4)
            ph = rng.uniform(0, 2 * np.pi, size=4)
            a = rng.uniform(0.5, 1.0, size=4)
            s = (a[:, None] * np.sin(2 * np.pi * f[:, None] * tau[None, :] + ph[:, None])).sum(0)
            return s / a.sum()  # in [-1, 1]

        y = shear_mm * ramp * sines()
        dz = -compression_mm * ramp * (1 + sines()) / 2
        rx = rot * ramp * sines()
    return np.stack([y, rest_z_mm + dz, rx], axis=1)


# A choice: the directions of the 6-DoF trajectories' shear (in the xy plane) and rotation axis,
# away from the axes so that every component of the pose moves.
SHEAR_DIRECTION_6 = np.array([np.cos(np.radians(30.0)), np.sin(np.radians(30.0)), 0.0])
ROTATION_AXIS_6 = np.array([1.0, 0.6, 0.4]) / np.linalg.norm([1.0, 0.6, 0.4])


def trajectory6(shape: str, t, rest_s: float, rest_z_mm: float, compression_mm: float, shear_mm: float,
                rotation_deg: float, frequency_hz: float, rng: np.random.Generator):
    """6-DoF poses (N, 6) = (x, y, z mm, rotation vector rad) at times t (N,) s: the counterparts of
    :func:`trajectory` for a shell read by pairs off a line. Compression along z; shear along
    :data:`SHEAR_DIRECTION_6`; rotation about :data:`ROTATION_AXIS_6`; general: a seeded sum of
    sines in each of the six components (``rng``), growing over 0.25 s."""
    if shape not in TRAJECTORIES:
        raise ValueError(f'sensor.trajectory.shape = "{shape}": not a trajectory; choose one of: {", ".join(TRAJECTORIES)}')
    t = np.asarray(t, float)
    tau = np.maximum(t - rest_s, 0.0)
    phase = 2 * np.pi * frequency_hz * tau
    out = np.zeros((len(t), 6))
    out[:, 2] = rest_z_mm
    rot = np.radians(rotation_deg)
    if shape == "compression":
        out[:, 2] -= compression_mm * (1 - np.cos(phase)) / 2
    elif shape == "shear":
        out[:, :3] += shear_mm * np.sin(phase)[:, None] * SHEAR_DIRECTION_6
    elif shape == "rotation":
        out[:, 3:] = rot * np.sin(phase)[:, None] * ROTATION_AXIS_6
    elif shape == "general":
        ramp = _smoothstep(tau / 0.25)

        def sines():
            f = frequency_hz * rng.uniform(0.5, 3.0, size=4)
            ph = rng.uniform(0, 2 * np.pi, size=4)
            a = rng.uniform(0.5, 1.0, size=4)
            return (a[:, None] * np.sin(2 * np.pi * f[:, None] * tau[None, :] + ph[:, None])).sum(0) / a.sum()

        out[:, 0] = shear_mm * ramp * sines()
        out[:, 1] = shear_mm * ramp * sines()
        out[:, 2] -= compression_mm * ramp * (1 + sines()) / 2
        for k in range(3, 6):
            out[:, k] = rot * ramp * sines()
    return out


def measure6(pose6, layout: PairLayout, noise_rms_mv: float, rng: np.random.Generator, adc_bits: int = ADC_BITS,
             adc_range_v: float = ADC_RANGE_V):
    """:func:`measure` for 6-DoF poses (N, 6) = (x, y, z mm, rotation vector rad)."""
    clean = pair_voltages(*pose6_to_pose(pose6), layout)
    return digitise(clean, noise_rms_mv, rng, adc_bits, adc_range_v), clean


def digitise(clean, noise_rms_mv, rng, adc_bits=ADC_BITS, adc_range_v=ADC_RANGE_V):
    """Readings (shape of ``clean``) V: ``clean`` V plus white Gaussian noise of ``noise_rms_mv`` (``rng``),
    quantised by an ``adc_bits`` ADC over 0..``adc_range_v`` and clipped at its rails."""
    noisy = clean + rng.normal(0.0, noise_rms_mv * 1e-3, size=clean.shape)
    lsb = adc_range_v / (2 ** adc_bits - 1)
    return np.clip(np.round(noisy / lsb), 0, 2 ** adc_bits - 1) * lsb


def measure(pose3, layout: PairLayout, noise_rms_mv: float, rng: np.random.Generator, adc_bits: int = ADC_BITS,
            adc_range_v: float = ADC_RANGE_V):
    """The pairs' readings (N, P) V of poses (N, 3): the model's voltage plus white Gaussian noise of
    ``noise_rms_mv`` per sample and pair, quantised by an ``adc_bits`` ADC over 0..``adc_range_v``
    (clipped at its rails)."""
    clean = planar_voltages(pose3, layout)
    return digitise(clean, noise_rms_mv, rng, adc_bits, adc_range_v), clean
