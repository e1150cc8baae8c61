"""The cells' accelerometers and temperature sensors (SPEC 4 lists both per cell; simplified models:
other_sensors/sole/accelerometer.py, temperature.py) against rigid-body and first-order references."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.sole.accelerometer import cell_accelerations
from other_sensors.sole.cells import sole_layout
from other_sensors.sole.contact import FootPose
from other_sensors.sole.temperature import cell_temperatures

LAYOUT = sole_layout()


def test_a_foot_at_rest_reads_gravity_along_its_tilted_normal():
    np.testing.assert_allclose(cell_accelerations(LAYOUT, FootPose((0.0, 0.0, 0.0))), np.tile([0.0, 0.0, 9.81], (42, 1)), atol=1e-12)
    pitch = np.radians(20.0)
    reading = cell_accelerations(LAYOUT, FootPose((0.3, 0.1, 0.0), pitch=pitch, yaw=0.5))
    # R^T (0, 0, g) with R = Rz Ry: the yaw leaves it, the pitch tips g toward the sole's -x
    np.testing.assert_allclose(reading, np.tile([-9.81 * np.sin(pitch), 0.0, 9.81 * np.cos(pitch)], (42, 1)), atol=1e-12)
    assert np.allclose(np.linalg.norm(reading, axis=1), 9.81)


def test_a_spinning_foot_reads_the_centripetal_and_tangential_accelerations():
    w, alpha = 3.0, 2.0  # rad/s, rad/s^2 about the vertical
    reading = cell_accelerations(LAYOUT, FootPose((0.0, 0.0, 0.0)), linear_acc=(1.0, 0.0, 0.0), angular_vel=(0, 0, w), angular_acc=(0, 0, alpha))
    c = LAYOUT.centres
    expected_xy = np.array([1.0, 0.0]) - w**2 * c + alpha * np.column_stack([-c[:, 1], c[:, 0]])
    np.testing.assert_allclose(reading[:, :2], expected_xy, atol=1e-12)
    np.testing.assert_allclose(reading[:, 2], 9.81, atol=1e-12)
    with pytest.raises(ValueError, match="finite"):
        cell_accelerations(LAYOUT, FootPose((0.0, 0.0, 0.0)), angular_vel=(0, 0, np.nan))


def test_temperatures_relax_exponentially_toward_what_each_cell_touches():
    active = np.zeros(42, bool)
    active[:10] = True
    t = np.full(42, 30.0)
    for _ in range(100):  # 100 steps of 0.1 s = tau / 2
        t = cell_temperatures(t, active, 0.1, air_c=25.0, ground_c=15.0, time_constant_s=20.0)
    decay = np.exp(-0.5)
    np.testing.assert_allclose(t[:10], 15.0 + 15.0 * decay, rtol=1e-12)
    np.testing.assert_allclose(t[10:], 25.0 + 5.0 * decay, rtol=1e-12)
    np.testing.assert_array_equal(cell_temperatures(t, active, 0.0, 25.0, 15.0), t)
    with pytest.raises(ValueError, match="time_constant_s"):
        cell_temperatures(t, active, 0.1, 25.0, 15.0, time_constant_s=0.0)
