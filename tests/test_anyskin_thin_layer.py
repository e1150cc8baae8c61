"""The skin's thin hyperelastic layer (issue 43, SPEC 2): the neo-Hookean column's uniaxial stretch
against its stress, its small- and large-load limits, simple shear, and the pressed slab's field
against the cuboid's closed form at the compressed thickness; a pressed skin never inverts."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.anyskin.dipoles import MU0
from other_sensors.anyskin.magnet_volume import body_field, element_moments, slab_body
from other_sensors.anyskin.thin_layer import compressive_stretch, layer_displacement

MU = 1.0e5  # Pa


def test_the_column_stretch_balances_the_neo_hookean_stress():
    p = np.array([0.0, 1e2, 1e4, 1e5, 1e6, 1e8])
    lam = compressive_stretch(p, MU)
    np.testing.assert_allclose(MU * (lam**-2 - lam), p, rtol=1e-10, atol=1e-9)  # -P = mu (l^-2 - l) = p
    assert np.all(np.diff(lam) < 0) and lam[0] == 1.0 and np.all(lam > 0)
    assert 1 - compressive_stretch(10.0, MU) == pytest.approx(10.0 / (3 * MU), rel=1e-4)  # E = 3 mu
    assert compressive_stretch(1e10, MU) == pytest.approx(np.sqrt(MU / 1e10), rel=1e-4)
    assert compressive_stretch(-5e3, MU) == 1.0  # pulling: no contact


def test_shear_is_linear_and_the_base_holds():
    nodes = np.array([[0.0, 0.0, 0.001], [0.0, 0.0, 0.002], [0.0, 0.0, 0.003]])
    traction = np.tile([2e3, -1e3, -3e4], (3, 1))
    u = layer_displacement(nodes, 0.001, 0.002, traction, MU)
    np.testing.assert_array_equal(u[0], 0.0)  # the base is held
    np.testing.assert_allclose(u[2, :2], [2e3 / MU * 0.002, -1e3 / MU * 0.002], rtol=1e-12)  # gamma = tau / mu
    assert u[1, 2] == pytest.approx(0.5 * u[2, 2], rel=1e-12) and u[2, 2] < 0
    lifted = layer_displacement(nodes, 0.001, 0.002, traction * [1, 1, -1], MU)
    np.testing.assert_array_equal(lifted, 0.0)
    with pytest.raises(ValueError, match="within the layer"):
        layer_displacement(nodes + [0, 0, 0.01], 0.001, 0.002, traction, MU)
    with pytest.raises(ValueError, match="sensor.skin.modulus_kpa"):
        compressive_stretch(1.0, -MU)


def test_a_uniformly_pressed_slab_reads_the_cuboid_of_its_compressed_thickness():
    """Pressed uniformly, each column shortens by lambda and its moments by lambda (m = F M~ dV0): a
    cuboid of thickness lambda t with the same magnetisation per current volume (closed form)."""
    a, t, gap, m = 0.02, 0.003, 0.0015, 2e4
    body = slab_body(a, a, t, gap, (32, 32, 2), (0.0, 0.0, m))
    traction = np.tile([0.0, 0.0, -5e4], (len(body.nodes), 1))
    moved = body.nodes + layer_displacement(body.nodes, gap, t, traction, MU)
    lam = compressive_stretch(5e4, MU)

    def cuboid(thick):
        def term(z):
            return np.arctan(a * a / (2 * z * np.sqrt(4 * z * z + 2 * a * a)))
        return MU0 * m / np.pi * (term(gap) - term(gap + thick))

    bz = body_field(body, np.zeros((1, 3)), moved)[0, 2]
    assert bz == pytest.approx(cuboid(lam * t), rel=2e-3) and bz < body_field(body, np.zeros((1, 3)))[0, 2]
    # a pressure far past the modulus still leaves every element right side out
    crushed = body.nodes + layer_displacement(body.nodes, gap, t, traction * 1e4, MU)
    element_moments(body, crushed)
