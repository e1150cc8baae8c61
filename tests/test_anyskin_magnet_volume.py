"""The magnetised skin as a finite volume (issue 43, SPEC 2): a cuboid magnet's on-axis field in
closed form and the quadrature's convergence to it, the far field of its total moment, rigid
motions moving the field with them, the moment following the deformation gradient, and an
inverted element refused."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.anyskin.dipoles import MU0, dipole_field
from other_sensors.anyskin.magnet_volume import body_field, element_moments, slab_body

M = 5.0e4  # A/m along z


def _cuboid_axis_bz(a, b, t, d, m):
    """B_z on the axis of an a x b x t cuboid magnetised along its thickness, at d from a face (T)."""
    def term(z):
        return np.arctan(a * b / (2 * z * np.sqrt(4 * z * z + a * a + b * b)))

    return MU0 * m / np.pi * (term(d) - term(d + t))


def test_the_slab_converges_to_the_cuboids_closed_form_at_fourth_order():
    a, b, t, gap = 0.02, 0.016, 0.002, 0.002
    exact = _cuboid_axis_bz(a, b, t, gap, M)
    errors = []
    for n in (4, 8, 16):
        body = slab_body(a, b, t, gap, (n, n, 1), (0.0, 0.0, M))
        bz = body_field(body, np.zeros((1, 3)))[0]
        assert abs(bz[0]) < 1e-12 * abs(exact) and abs(bz[1]) < 1e-12 * abs(exact)  # on the axis of symmetry
        errors.append(abs(bz[2] - exact) / abs(exact))
    slopes = np.diff(np.log(errors)) / np.log(0.5)
    assert errors[-1] < 2e-3 and np.all(slopes > 3.0), (errors, slopes)
    assert body.volume == pytest.approx(a * b * t, rel=1e-12)


def test_far_away_the_slab_is_a_dipole_of_its_whole_moment():
    body = slab_body(0.02, 0.02, 0.002, 0.0, (4, 4, 1), (1e4, -2e4, 5e4))
    # the next term of the multipole expansion is O((L / r)^2) of the dipole's: 1e-3 at 0.6 m, 4e-5 at 3 m
    points = np.array([[2.5, 1.0, 1.5], [0.0, 0.0, -3.0]])
    dipole = dipole_field(points, np.array([[0.0, 0.0, 0.001]]), body.magnetisation[None] * 0.02 * 0.02 * 0.002)
    np.testing.assert_allclose(body_field(body, points), dipole, rtol=1e-4)


def test_a_rigid_motion_carries_the_field_and_the_moment_follows_f():
    body = slab_body(0.02, 0.02, 0.002, 0.003, (6, 6, 2), (0.0, 0.0, M))
    angle = np.radians(25.0)
    rot = np.array([[1, 0, 0], [0, np.cos(angle), -np.sin(angle)], [0, np.sin(angle), np.cos(angle)]]) @ \
        np.array([[np.cos(0.4), -np.sin(0.4), 0], [np.sin(0.4), np.cos(0.4), 0], [0, 0, 1]])
    shift = np.array([0.001, -0.002, 0.0005])
    points = np.array([[0.0, 0.0, 0.0], [0.005, 0.0, 0.0], [0.0, -0.005, -0.001]])
    moved = body_field(body, points @ rot.T + shift, body.nodes @ rot.T + shift)
    np.testing.assert_allclose(moved, body_field(body, points) @ rot.T, rtol=1e-10, atol=1e-18)
    # a uniform stretch F = diag(1, 1, 1.2) of a z-magnetised slab: every Gauss moment grows by 1.2 along z
    stretched = body.nodes * [1.0, 1.0, 1.2]
    _, m0 = element_moments(body)
    _, m1 = element_moments(body, stretched)
    np.testing.assert_allclose(m1, m0 * [1.0, 1.0, 1.2], rtol=1e-12)
    # a simple shear x += 0.3 z tilts the moments: F M~ = (0.3 M, 0, M) per undeformed volume
    sheared = body.nodes + np.column_stack([0.3 * (body.nodes[:, 2] - 0.003), 0 * body.nodes[:, :2]])
    _, m2 = element_moments(body, sheared)
    np.testing.assert_allclose(m2[:, 0], 0.3 * m0[:, 2], rtol=1e-12)


def test_an_inverted_or_non_finite_skin_is_refused():
    body = slab_body(0.02, 0.02, 0.002, 0.003, (2, 2, 1), (0.0, 0.0, M))
    folded = body.nodes.copy()
    folded[:, 2] = 2 * 0.004 - folded[:, 2]  # mirrored through its mid-plane: every element inside out
    with pytest.raises(ValueError, match=r"sensor\.skin: the magnet volume inverts"):
        body_field(body, np.zeros((1, 3)), folded)
    bad = body.nodes.copy()
    bad[0, 0] = np.nan
    with pytest.raises(ValueError, match="finite"):
        body_field(body, np.zeros((1, 3)), bad)
    with pytest.raises(ValueError, match="divisions"):
        slab_body(0.02, 0.02, 0.002, 0.0, (0, 2, 1), (0.0, 0.0, M))
