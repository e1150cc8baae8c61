"""The helmet's 150 Hz magnetometer traces and ground-truth forces for a scene's AnySkin sensor.

Per sample and sensor: the plate force (:mod:`other_sensors.anyskin.helmet`) deforms the skin, plus
its permanent set, in the scene's truth model (``sensor.skin.truth``, :mod:`other_sensors.anyskin.truth`:
the finite magnet volume over a neo-Hookean thin layer, or point dipoles over a Winkler layer); the
chips read the skin's field, the Earth's field in the sensor's frame and the motors' field through
their offsets, gains and cross-axis sensitivities, then noise and quantisation
(:mod:`other_sensors.anyskin.magnetometer`). Random streams: one ``numpy.random.SeedSequence(seed)``
spawns independent generators for the head's phases, the pushes, the motor directions, the noise and
the chips' errors, so changing one model does not reshuffle the others.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .helmet import N_SENSORS, head_rotations, helmet_layout, plate_forces, push_profile
from .magnetometer import chip_errors, read_chips
from .skin import N_MAGNETOMETERS, geomagnetic_reading, motor_field, skin_geometry
from .truth import skin_fields

__all__ = ["HelmetSignals", "simulate_helmet", "skin_of"]


@dataclass(frozen=True)
class HelmetSignals:
    """t (T,) s; readings (T, 4, 5, 3) uT (sensor, chip, axis in the sensor frame); baseline (4, 5, 3) uT,
    the undeformed skin's field; its parts skin, geomagnetic, motor (T, 4, 5, 3) uT, before noise;
    normal_n (T, 4) N plate force per sensor; force_n (T, 4, 3) N the force on each skin, sensor frame;
    total_n (T,) N the push; head (T, 3, 3) head-to-world; set_mm (T, 4) the largest permanent
    set of each skin, mm; chip_offsets (4, 5, 3) uT and chip_sensitivity (4, 5, 3, 3), each chip's
    read-out errors (:mod:`other_sensors.anyskin.magnetometer`)."""

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
    chip_offsets: np.ndarray = None
    chip_sensitivity: np.ndarray = None

    @property
    def clean(self) -> np.ndarray:
        return self.skin + self.geomagnetic + self.motor


def skin_of(sensor):
    """The point-dipole :class:`other_sensors.anyskin.skin.SkinGeometry` of an :class:`AnySkinSensor`."""
    s = sensor.skin
    return skin_geometry(s.side_mm * 1e-3, s.thickness_mm * 1e-3, s.gap_mm * 1e-3, s.grid, s.magnetisation_ka_m * 1e3,
                         sensor.magnetometers.pitch_mm * 1e-3)


def simulate_helmet(sensor, seed: int) -> HelmetSignals:
    """Simulate the scene's helmet; see the module docstring."""
    head_rng, push_rng, motor_rng, noise_rng, chip_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(5))
    dt = 1.0 / sensor.magnetometers.rate_hz
    traj, push = sensor.trajectory, sensor.push
    t = np.arange(int(round(traj.duration_s / dt))) * dt
    heading = head_rng.uniform(-np.pi, np.pi)
    head = head_rotations(t, traj.gait_hz, np.radians([traj.roll_amp_deg, traj.pitch_amp_deg, traj.yaw_amp_deg]), heading, head_rng)
    h = sensor.helmet
    layout = helmet_layout(np.radians(h.face_pitch_deg), h.half_width_mm * 1e-3, h.half_height_mm * 1e-3, h.face_forward_mm * 1e-3)
    total = push_profile(t, push.first_s, push.push_s, push.rest_s, push.peak_n, push.jitter, push_rng)
    normal, force = plate_forces(layout, head, total, h.pad_stiffness_n_mm * 1e3, heading)

    fields = skin_fields(sensor, force, dt)
    skin, set_mm = fields.skin, fields.set_mm
    baseline = np.broadcast_to(fields.baseline, (N_SENSORS, N_MAGNETOMETERS, 3)).copy()

    sensor_to_world = head[:, None] @ layout.frames[None]  # (T, 4, 3, 3); the chips share their board's frame
    geo = np.repeat(geomagnetic_reading(sensor_to_world, sensor.ambient.geomagnetic_ut)[:, :, None], N_MAGNETOMETERS, axis=2)
    directions = motor_rng.normal(size=(N_SENSORS * N_MAGNETOMETERS, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    motor = motor_field(t, traj.gait_hz, directions, sensor.ambient.motor_ut).reshape(len(t), N_SENSORS, N_MAGNETOMETERS, 3)

    offsets, sensitivity = chip_errors_of(sensor, N_SENSORS * N_MAGNETOMETERS, chip_rng)
    readings = read_chips_of(sensor, (skin + geo + motor).reshape(len(t), -1, 3), offsets, sensitivity, noise_rng)
    return HelmetSignals(t, readings.reshape(skin.shape), baseline, skin, geo, motor, normal, force, total, head, set_mm,
                         offsets.reshape(N_SENSORS, N_MAGNETOMETERS, 3), sensitivity.reshape(N_SENSORS, N_MAGNETOMETERS, 3, 3))


def chip_errors_of(sensor, n_chips: int, rng: np.random.Generator):
    """The scene's chips' offsets (C, 3) uT and sensitivity matrices (C, 3, 3), drawn from rng."""
    n = sensor.noise
    return chip_errors(n_chips, n.offset_ut, n.gain_error_pct, n.cross_axis_pct, rng)


def read_chips_of(sensor, clean_ut, offsets, sensitivity, rng: np.random.Generator) -> np.ndarray:
    """The scene's chips' readings (T, C, 3) uT of clean_ut (T, C, 3) uT: its noise and LSBs per axis."""
    n = sensor.noise
    return read_chips(clean_ut, offsets, sensitivity, (n.rms_ut, n.rms_ut, n.rms_z_ut), (n.lsb_ut, n.lsb_ut, n.lsb_z_ut), rng)
