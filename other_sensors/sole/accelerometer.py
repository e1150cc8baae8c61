"""The cells' 3-axis accelerometers on a rigid foot (SPEC 4: each cell carries one).

SPEC 4 lists a 3-axis accelerometer per cell and gives no model of it. The simplification here:
the foot is a rigid body and each cell's accelerometer sits at the cell's centre on the sole plane,
its axes along the sole frame (:mod:`other_sensors.sole.contact`), ideal (no bias, scale error,
noise or bandwidth limit; the skin's compliance, which would let a cell move against the foot, is
ignored). It reads the specific force of its point in its own axes (rigid-body kinematics):

    f_j = R^T (a_o + alpha x r_j + omega x (omega x r_j) - g),   r_j = R [c_j, 0],  g = (0, 0, -9.81) m/s^2,

a_o the sole origin's acceleration, omega and alpha the foot's angular velocity and acceleration
(world frame), R the foot's orientation and c_j (2,) the cell's centre. A foot at rest reads
R^T (0, 0, 9.81): +9.81 m/s^2 along the sole's normal when level.
"""

from __future__ import annotations

import numpy as np

__all__ = ["GRAVITY", "cell_accelerations"]

GRAVITY = np.array([0.0, 0.0, -9.81])  # m/s^2, world


def cell_accelerations(layout, pose, linear_acc=(0.0, 0.0, 0.0), angular_vel=(0.0, 0.0, 0.0), angular_acc=(0.0, 0.0, 0.0)) -> np.ndarray:
    """Each cell's accelerometer reading (N, 3) m/s^2 in the sole frame.

    layout: :class:`other_sensors.sole.cells.SoleLayout`. pose: :class:`other_sensors.sole.contact.FootPose`.
    linear_acc (3,) m/s^2: the sole origin's acceleration; angular_vel (3,) rad/s and angular_acc
    (3,) rad/s^2: the foot's, all in the world frame.
    """
    a_o, w, alpha = (np.asarray(v, dtype=float).reshape(3) for v in (linear_acc, angular_vel, angular_acc))
    if not (np.isfinite(a_o).all() and np.isfinite(w).all() and np.isfinite(alpha).all()):
        raise ValueError("cell_accelerations: the foot's accelerations and angular velocity must be finite")
    rot = pose.matrix()
    r = np.column_stack([layout.centres, np.zeros(layout.n_cells)]) @ rot.T  # (N, 3) world offsets
    world = a_o + np.cross(alpha, r) + np.cross(w, np.cross(w, r)) - GRAVITY
    return world @ rot  # R^T f for each row
