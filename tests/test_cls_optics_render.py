"""The CLS optical truth against Mitsuba's path tracer (issue 43; :mod:`other_sensors.cls.optics_render`).

First the set-up against a closed form it must reproduce (the integrating sphere's diffuse wall
irradiance, Goebel 1967: the beam's flux and the meter's normalisation), then the cavity: the optics
model's LED -> LTV coupling (direct radiometry plus the uniform-cavity diffuse term) against the
direct path plus the path-traced diffuse light, at rest and deep in compression. The full table
(six poses, five pairs, 2^20 samples) is in docs/uses/sibling-sensors.md; ``-m slow`` runs it.
"""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.cls.ltv import default_layout, pair_geometry, planar_to_pose
from other_sensors.cls.optics import Optics, cavity_irradiance, direct_irradiance, lambert_order
from other_sensors.cls.optics_render import rendered_diffuse_irradiance, sphere_irradiance, spot_texture

LAYOUT = default_layout()
OPTICS = Optics(n_pillars=0)  # the render has no pillars (optics_render's docstring)
M = lambert_order(OPTICS.half_angle_deg)
#: stated tolerances on the model's coupling against the render (measured: 0.87 % and 0.52 % at 2^20
#: samples over six poses and five pairs, docs/uses/sibling-sensors.md)
TOTAL_RTOL = 0.01
REST_NORMALISED_RTOL = 0.006


def _coupling(pose, pairs, spp):
    """(model, rendered) LED -> LTV irradiance per unit I0 (1/mm^2) of ``pairs`` at a planar pose."""
    pose = np.asarray(pose, float)
    r, theta, psi = pair_geometry(*planar_to_pose(pose), LAYOUT)
    direct = direct_irradiance(r, theta, psi, M)[list(pairs)]
    diffuse = rendered_diffuse_irradiance(pose, LAYOUT, OPTICS, pairs=pairs, spp=spp)
    return direct + cavity_irradiance(pose[1], OPTICS, M), direct + diffuse, diffuse


def test_the_spot_texture_holds_the_beam():
    tex = spot_texture(M, n=5)
    assert tex[2, 2] == pytest.approx(1.0)  # on the axis
    t = 0.8 * np.tan(np.radians(85.0))  # the last pixel centre: (4.5 / 5 * 2 - 1) tan(cutoff)
    assert tex[2, 4] == pytest.approx((1 + t * t) ** (-M / 2), rel=1e-12) and tex[4, 2] == tex[2, 4]


def test_the_integrating_sphere_reproduces_goebel():
    rho, radius = 0.6, 20.0
    closed = 2 * np.pi / (M + 1) * rho / (4 * np.pi * radius**2 * (1 - rho))
    assert sphere_irradiance(radius, rho, OPTICS.half_angle_deg, spp=1 << 16) == pytest.approx(closed, rel=0.02)


def test_the_optics_coupling_is_within_its_stated_tolerance_of_the_render():
    pairs = (0, 2)
    rest_model, rest_render, rest_diffuse = _coupling([0.0, 40.0, 0.0], pairs, 1 << 16)
    deep_model, deep_render, deep_diffuse = _coupling([0.0, 22.0, 0.0], pairs, 1 << 16)
    np.testing.assert_allclose(rest_model, rest_render, rtol=TOTAL_RTOL)
    np.testing.assert_allclose(deep_model, deep_render, rtol=TOTAL_RTOL)
    # the voltages' gain is set at rest (optics.optical_voltages), so what the pose estimate sees is the ratio to rest
    np.testing.assert_allclose(deep_model / rest_model, deep_render / rest_render, rtol=REST_NORMALISED_RTOL)
    # the diffuse light brightens as the cavity closes (less leaves by the sides) and stays a small part of the signal
    assert np.all(deep_diffuse > 2 * rest_diffuse) and np.all(rest_diffuse < 0.01 * rest_render)


def test_a_cavity_with_pillars_is_refused():
    with pytest.raises(ValueError, match="n_pillars"):
        rendered_diffuse_irradiance([0.0, 40.0, 0.0], LAYOUT, Optics(), spp=16)


@pytest.mark.slow
def test_the_full_table():
    """Six poses, five pairs, 2^20 samples (about 30 s on 2 shared cores): the figures of the docs."""
    poses = [(0, 40, 0), (0, 30, 0), (0, 22, 0), (6, 40, 0), (0, 40, np.radians(6)), (3, 28, np.radians(4))]
    rest = None
    for pose in poses:
        model, render, _ = _coupling(pose, range(5), 1 << 20)
        rest = rest or (model, render)
        np.testing.assert_allclose(model, render, rtol=TOTAL_RTOL)
        np.testing.assert_allclose(model / rest[0], render / rest[1], rtol=REST_NORMALISED_RTOL)
