"""The helmet's 150 Hz magnetometer traces and ground-truth forces for a scene's AnySkin sensor.

Per sample and sensor: the plate force (:mod:`other_sensors.anyskin.helmet`) deforms the skin
(:func:`other_sensors.anyskin.skin.contact_displacement`), plus its permanent set; the chips read the
displaced skin's field, the Earth's field in the sensor's frame, the motors' field, then noise and
quantisation. Random streams: one ``numpy.random.SeedSequence(seed)`` spawns independent generators
for the head's phases, the pushes, the motor directions and the noise, so changing one model does
not reshuffle the others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .helmet import N_SENSORS, head_rotations, helmet_layout, plate_forces, push_profile
from .skin import (N_MAGNETOMETERS, contact_displacement, geomagnetic_reading, motor_field, permanent_set, read_out, skin_field,
                   skin_geometry)

__all__ = ["HelmetSignals", "simulate_helmet", "skin_of"]


@dataclass(frozen=True)
class HelmetSignals:
    """t (T,) s; readings (T, 4, 5, 3) uT (sensor, chip, axis in the sensor frame); baseline (4, 5, 3) uT,
    the undeformed skin's field; its parts skin, geomagnetic, motor (T, 4, 5, 3) uT, before noise;
    normal_n (T, 4) N plate force per sensor; force_n (T, 4, 3) N the force on each skin, sensor frame;
    total_n (T,) N the push; head (T, 3, 3) head-to-world; set_mm (T, 4) the largest permanent
    set of each skin's dipoles, mm."""

    t: np.ndarray
    readings: np.ndarray
    baseline: np.ndarray
    skin: np.ndarray
    geomagnetic: np.ndarray
    motor: np.ndarray
    normal_n: np.ndarray
    force_n: np.ndarray
    total_n: np.ndarray
    head: np.ndarray
    set_mm: np.ndarray

    @property
    def clean(self) -> np.ndarray:
        return self.skin + self.geomagnetic + self.motor


def skin_of(sensor):
    """The :class:`other_sensors.anyskin.skin.SkinGeometry` of an :class:`AnySkinSensor`."""
    s = sensor.skin
    return skin_geometry(s.side_mm * 1e-3, s.thickness_mm * 1e-3, s.gap_mm * 1e-3, s.grid, s.magnetisation_ka_m * 1e3,
                         sensor.magnetometers.pitch_mm * 1e-3)


def simulate_helmet(sensor, seed: int) -> HelmetSignals:
    """Simulate the scene's helmet; see the module docstring."""
    head_rng, push_rng, motor_rng, noise_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4))
    dt = 1.0 / sensor.magnetometers.rate_hz
    traj, push = sensor.trajectory, sensor.push
    t = np.arange(int(round(traj.duration_s / dt))) * dt
    heading = head_rng.uniform(-np.pi, np.pi)
    head = head_rotations(t, traj.gait_hz, np.radians([traj.roll_amp_deg, traj.pitch_amp_deg, traj.yaw_amp_deg]), heading, head_rng)
    h = sensor.helmet
    layout = helmet_layout(np.radians(h.face_pitch_deg), h.half_width_mm * 1e-3, h.half_height_mm * 1e-3, h.face_forward_mm * 1e-3)
    total = push_profile(t, push.first_s, push.push_s, push.rest_s, push.peak_n, push.jitter, push_rng)
    normal, force = plate_forces(layout, head, total, h.pad_stiffness_n_mm * 1e3, heading)

    geometry, sk, drift = skin_of(sensor), sensor.skin, sensor.drift
    skin = np.empty((len(t), N_SENSORS, N_MAGNETOMETERS, 3))
    set_mm = np.zeros((len(t), N_SENSORS))
    for i in range(N_SENSORS):
        u = contact_displacement(geometry, force[:, i], (0.0, 0.0), sk.contact_radius_mm * 1e-3, sk.modulus_kpa * 1e3, sk.max_strain)
        if drift.enabled and drift.set_fraction > 0:
            s = permanent_set(u, dt, drift.set_fraction, drift.tau_set_s, drift.tau_relax_s)
            u = u + s
            set_mm[:, i] = 1e3 * np.linalg.norm(s, axis=-1).max(axis=-1)
        skin[:, i] = skin_field(geometry, u)
    baseline = np.broadcast_to(skin_field(geometry), (N_SENSORS, N_MAGNETOMETERS, 3)).copy()

    sensor_to_world = head[:, None] @ layout.frames[None]  # (T, 4, 3, 3); the chips share their board's frame
    geo = np.repeat(geomagnetic_reading(sensor_to_world, sensor.ambient.geomagnetic_ut)[:, :, None], N_MAGNETOMETERS, axis=2)
    directions = motor_rng.normal(size=(N_SENSORS * N_MAGNETOMETERS, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    motor = motor_field(t, traj.gait_hz, directions, sensor.ambient.motor_ut).reshape(len(t), N_SENSORS, N_MAGNETOMETERS, 3)

    readings = read_out(skin + geo + motor, sensor.noise.rms_ut, sensor.noise.lsb_ut, noise_rng)
    return HelmetSignals(t, readings, baseline, skin, geo, motor, normal, force, total, head, set_mm)
