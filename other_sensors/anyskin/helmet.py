"""The Head-On helmet (SPEC 2): four AnySkin sensors in an X on a pitched face, a walking quadruped's
head, and fore-aft pushes against a force plate with each sensor's ground-truth force.

Frames: head x forward, y left, z up; world x north, z up; the robot heads at a seeded heading and the
force plate is a vertical wall across its path.
The face is a plane whose outward normal is pitched down by the face pitch theta,
n = (cos theta, 0, -sin theta); its in-plane axes are lateral y and up_face = (sin theta, 0, cos theta),
so the upper sensors reach 2 h sin theta further forward than the lower ones. Sensor i sits at
(u_i, v_i) = (+-w, +-h) in the face (the X: upper left, upper right, lower left, lower right); its
frame has z = n, x = up_face, y = lateral (right-handed).

Head motion: roll, pitch, yaw sinusoids at the gait frequency with seeded phases,
R_head = Rz(heading + yaw) Ry(pitch) Rx(roll); the peak angular rate is at most
2 pi f sqrt(A_roll^2 + A_pitch^2 + A_yaw^2) (SPEC 2: up to 180 deg/s while walking).

Contact: the plate meets each sensor's pad, a linear spring k (N/m) along the plate normal
(a Winkler pad, as in :mod:`other_sensors.anyskin.skin`); the plate's penetration is solved each
sample so that the pads carry the commanded push force, F_i = k max(0, e - (d_max - d_i)), d_i the
pad's reach along world x. Normal forces only (a frictionless plate): the force on sensor i is
F_i (-forward), seen in its own frame, where the face pitch and the head's rotation make it shear.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HelmetLayout", "helmet_layout", "head_rotations", "push_profile", "plate_forces", "peak_angular_rate_deg_s",
           "rotation"]

N_SENSORS = 4


def rotation(roll, pitch, yaw) -> np.ndarray:
    """R = Rz(yaw) Ry(pitch) Rx(roll), angles rad (arrays of shape (T,) or scalars); returns (..., 3, 3)."""
    roll, pitch, yaw = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (roll, pitch, yaw)))
    cr, sr, cp, sp, cy, sy = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch), np.cos(yaw), np.sin(yaw)
    one, zero = np.ones_like(roll), np.zeros_like(roll)
    rx = np.stack([np.stack([one, zero, zero], -1), np.stack([zero, cr, -sr], -1), np.stack([zero, sr, cr], -1)], -2)
    ry = np.stack([np.stack([cp, zero, sp], -1), np.stack([zero, one, zero], -1), np.stack([-sp, zero, cp], -1)], -2)
    rz = np.stack([np.stack([cy, -sy, zero], -1), np.stack([sy, cy, zero], -1), np.stack([zero, zero, one], -1)], -2)
    return rz @ ry @ rx


@dataclass(frozen=True)
class HelmetLayout:
    """Sensor origins (4, 3) m and frames (4, 3, 3) (columns: sensor x, y, z in head coordinates)."""

    origins: np.ndarray
    frames: np.ndarray


def helmet_layout(face_pitch_rad: float, half_width_m: float, half_height_m: float, face_forward_m: float) -> HelmetLayout:
    """The X layout on the pitched face; see the module docstring."""
    c, s = np.cos(face_pitch_rad), np.sin(face_pitch_rad)
    normal, up, lateral = np.array([c, 0.0, -s]), np.array([s, 0.0, c]), np.array([0.0, 1.0, 0.0])
    origins, frames = [], []
    for v in (half_height_m, -half_height_m):
        for u in (half_width_m, -half_width_m):
            origins.append(face_forward_m * np.array([1.0, 0.0, 0.0]) + u * lateral + v * up)
            frames.append(np.column_stack([up, np.cross(normal, up), normal]))
    return HelmetLayout(np.array(origins), np.array(frames))


def peak_angular_rate_deg_s(gait_hz: float, amplitudes_deg) -> float:
    """Upper bound on the head's angular rate for sinusoidal roll, pitch, yaw of these amplitudes."""
    return float(2 * np.pi * gait_hz * np.linalg.norm(amplitudes_deg))


def head_rotations(t_s, gait_hz: float, amplitudes_rad, heading_rad: float, rng: np.random.Generator) -> np.ndarray:
    """Head-to-world rotations (T, 3, 3) of a trotting head facing heading_rad (from world x): seeded phases."""
    t = np.asarray(t_s, dtype=float)
    phases = rng.uniform(0, 2 * np.pi, 3)
    heading = heading_rad
    angles = [a * np.sin(2 * np.pi * gait_hz * t + p) for a, p in zip(amplitudes_rad, phases)]
    return rotation(angles[0], angles[1], heading + angles[2])


def push_profile(t_s, first_s: float, push_s: float, rest_s: float, peak_n: float, jitter: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Total plate force (T,) N: sin^2 pulses of length push_s every push_s + rest_s from first_s, each
    peak scaled by a seeded factor in [1 - jitter, 1 + jitter]."""
    t = np.asarray(t_s, dtype=float)
    period = push_s + rest_s
    n_cycles = int(np.ceil(max(t[-1] - first_s, 0.0) / period)) + 1
    peaks = peak_n * (1 + jitter * rng.uniform(-1, 1, n_cycles))
    phase = t - first_s
    cycle = np.clip(np.floor(phase / period).astype(int), 0, n_cycles - 1)
    within = phase - cycle * period
    on = (phase >= 0) & (within < push_s)
    return np.where(on, peaks[cycle] * np.sin(np.pi * within / push_s) ** 2, 0.0)


def plate_forces(layout: HelmetLayout, head_to_world, total_n, pad_stiffness_n_m: float, heading_rad: float = 0.0):
    """Each sensor's plate force; the plate faces the robot, its normal -(cos heading, sin heading, 0).

    head_to_world: (T, 3, 3). total_n: (T,) N. Returns (normal (T, 4) N, force in each sensor frame
    (T, 4, 3) N, the force on the skin) with normal.sum(axis=1) == total_n.
    """
    total = np.asarray(total_n, dtype=float)
    forward = np.array([np.cos(heading_rad), np.sin(heading_rad), 0.0])
    reach = np.einsum("j,tjk,ik->ti", forward, head_to_world, layout.origins)  # each pad's reach towards the plate, (T, 4)
    gap = reach.max(axis=1, keepdims=True) - reach  # (T, 4) >= 0
    order = np.sort(gap, axis=1)
    # the pads nearest the plate engage first: with the `count` nearest engaged, e = (F / k + their gaps' sum) / count;
    # the solution takes the largest count whose e passes its last gap (as in projecting onto a simplex)
    e = np.zeros(len(total))
    for count in range(1, N_SENSORS + 1):
        cand = (total / pad_stiffness_n_m + order[:, :count].sum(axis=1)) / count
        e = np.where(cand > order[:, count - 1], cand, e)
    normal = np.where(total[:, None] > 0, pad_stiffness_n_m * np.maximum(e[:, None] - gap, 0.0), 0.0)
    sensor_to_world = head_to_world[:, None] @ layout.frames[None]  # (T, 4, 3, 3)
    world_force = -normal[..., None] * forward
    local = np.einsum("tikj,tik->tij", sensor_to_world, world_force)  # R^T f
    return normal, local
