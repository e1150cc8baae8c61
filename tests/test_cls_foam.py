"""Force and moment from the CLS shell's pose through the foam law (SPEC 3, issue 20 item 4), against
two independent references: the analytic small-deflection stiffness matrix of the three pillars,
and the gradient of the pillars' stored energy (written here from the stress law's integral)."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.cls import ltv
from other_sensors.cls.shell import Foam, pose_wrench

LAYOUT = ltv.default_layout()
FOAM = Foam()
REST = np.array([0.0, LAYOUT.rest_p[2], 0.0])


def _wrench_nmm(pose):
    """(F_y N, F_z N, M_x N mm)."""
    return pose_wrench(pose, FOAM, LAYOUT) * np.array([1.0, 1.0, 1e3])


def _energy_nmm(pose):
    """The pillars' stored energy (N mm) at a planar pose: axial, A L integral of
    sigma = E0 eps (1 + (eps / eps_s)^2) d eps = A L E0 (eps^2 / 2 + eps^4 / (4 eps_s^2)), and shear,
    (G A / L) s^2 / 2 with G = E0 / 3, from each pillar top's position (pillar bending neglected,
    as in the model)."""
    y, z, rx = pose
    L, A, es = FOAM.height_mm, FOAM.section_mm2, FOAM.stiffening_strain
    e0 = FOAM.e0_kpa * 1e-3  # N / mm^2
    h0 = LAYOUT.rest_p[2] - L  # the tops sit h0 below the shell origin
    total = 0.0
    for py in FOAM.pillar_y_mm:
        ty = y + np.cos(rx) * py + np.sin(rx) * h0
        tz = z + np.sin(rx) * py - np.cos(rx) * h0
        eps = (L - tz) / L
        total += A * L * e0 * (eps ** 2 / 2 + eps ** 4 / (4 * es ** 2)) + 0.5 * (e0 / 3) * A / L * (ty - py) ** 2
    return total


def test_small_deflection_stiffness_is_the_pillars_analytic_one():
    k_a = FOAM.e0_kpa * 1e-3 * FOAM.section_mm2 / FOAM.height_mm  # N / mm, one pillar's axial stiffness E0 A / L
    k_s = k_a / 3  # shear: G A / L, G = E0 / 3
    h0 = LAYOUT.rest_p[2] - FOAM.height_mm  # the shear acts h0 below the shell origin: couples y and theta_x
    py = np.asarray(FOAM.pillar_y_mm)
    K = np.array([[3 * k_s, 0.0, 3 * k_s * h0],
                  [0.0, 3 * k_a, k_a * py.sum()],
                  [3 * k_s * h0, k_a * py.sum(), k_a * np.sum(py ** 2) + 3 * k_s * h0 ** 2]])
    h = np.array([1e-5, 1e-5, 1e-7])
    fd = np.stack([(_wrench_nmm(REST + np.eye(3)[k] * h[k]) - _wrench_nmm(REST - np.eye(3)[k] * h[k])) / (2 * h[k])
                   for k in range(3)], axis=1)
    np.testing.assert_allclose(fd, K, rtol=1e-6, atol=1e-9 * np.abs(K).max())
    assert K[2, 2] == pytest.approx(0.762 * 2 * 45.0 ** 2, rel=0.01)  # ~ k_a (2 x (45 mm)^2) = 3.1e3 N mm / rad


@pytest.mark.parametrize("pose", [[3.0, 31.0, 0.07], [-5.0, 28.0, -0.1], [1.0, 39.0, 0.02]])
def test_the_wrench_is_the_gradient_of_the_stored_energy(pose):
    pose = np.asarray(pose, float)
    h = np.array([1e-4, 1e-4, 1e-6])
    grad = np.array([(_energy_nmm(pose + np.eye(3)[k] * h[k]) - _energy_nmm(pose - np.eye(3)[k] * h[k])) / (2 * h[k])
                     for k in range(3)])
    np.testing.assert_allclose(_wrench_nmm(pose), grad, rtol=1e-7, atol=1e-9)
    # and it stiffens: at 9 mm of compression the vertical force is 1 + (9/38.1 / 0.3)^2 ~ 1.6 times linear
    if pose[1] < 32:
        linear = 3 * FOAM.e0_kpa * 1e-3 * FOAM.section_mm2 / FOAM.height_mm * (REST[1] - pose[1])
        assert -_wrench_nmm(pose)[1] > 1.2 * linear
