"""The CLS cavity's two-surface radiosity (issue 43; :mod:`other_sensors.cls.cavity_radiosity`).

The quadrature against view factors' closed forms (Modest, *Radiative Heat Transfer*, App. D;
Howell's catalogue), the bounce series against its first term, invariances (mirror, linearity in
rho_base), convergence in the panels, the interpolated table against the direct evaluation, bad
input. The model against Mitsuba's path tracer: ``tests/test_cls_optics_render.py``.
"""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.cls.cavity_radiosity import _kernel, diffuse_irradiance, diffuse_irradiance_table, rectangle_rule
from other_sensors.cls.ltv import default_layout
from other_sensors.cls.optics import lambert_order

LAYOUT = default_layout()
M = lambert_order(30.0)
FOOT = (130.0, 50.0)


def _diffuse(pose, layout=LAYOUT, rho=(0.1, 0.3), **kw):
    return diffuse_irradiance(np.asarray(pose, float), layout, *FOOT, *rho, M, **kw)


def _corner_view(a, b, c):
    """A differential element's view factor to a parallel a x b rectangle at distance c, the element
    on the normal through a corner (Modest App. D; Howell's catalogue B-3)."""
    x, y = a / c, b / c
    return (x / np.hypot(1, x) * np.arctan(y / np.hypot(1, x)) + y / np.hypot(1, y) * np.arctan(x / np.hypot(1, y))) / (2 * np.pi)


def _opposed_view(a, b, c):
    """The view factor between directly opposed parallel a x b rectangles at distance c (Howell's catalogue C-11)."""
    x, y = a / c, b / c
    hx, hy = np.hypot(1, x), np.hypot(1, y)
    return 2 / (np.pi * x * y) * (0.5 * np.log(hx**2 * hy**2 / (1 + x * x + y * y)) + x * hy * np.arctan(x / hy)
                                  + y * hx * np.arctan(y / hx) - x * np.arctan(x) - y * np.arctan(y))


def test_the_rule_integrates_cubics_exactly():
    nodes, w = rectangle_rule(*FOOT, panels=(3, 2))
    assert w.sum() == pytest.approx(FOOT[0] * FOOT[1], rel=1e-12)
    assert np.sum(w * nodes[:, 1] ** 2) == pytest.approx(FOOT[1] * FOOT[0] ** 3 / 12, rel=1e-12)
    assert np.sum(w * nodes[:, 0] ** 3 * nodes[:, 1]) == pytest.approx(0.0, abs=1e-6)


@pytest.mark.parametrize("gap", [18.0, 30.0, 50.0])
def test_the_quadrature_reproduces_the_view_factors_closed_forms(gap):
    nodes, w = rectangle_rule(*FOOT)
    up, down = np.array([0.0, 0.0, 1.0]), np.array([0.0, 0.0, -1.0])
    shell = np.c_[nodes, np.full(len(nodes), gap)]
    # an LTV at the base's centre sees the shell: four corner rectangles
    k = _kernel(np.zeros((1, 3)), up, shell, down)[0]
    assert np.sum(w * k) == pytest.approx(4 * _corner_view(FOOT[0] / 2, FOOT[1] / 2, gap), rel=2e-3)
    # the base sees the shell: directly opposed rectangles, F = (1 / A) sum sum w w K
    base = np.c_[nodes, np.zeros(len(nodes))]
    f = w @ _kernel(base, up, shell, down) @ w / w.sum()
    assert f == pytest.approx(_opposed_view(*FOOT, gap), rel=2e-3)


def test_the_bounces_add_what_the_first_leaves_and_scale_with_the_reflectances():
    pose = [2.0, 22.0, np.radians(3.0)]
    full = _diffuse(pose)
    assert np.all(_diffuse(pose, rho=(0.0, 0.3)) == 0.0) and np.all(_diffuse(pose, rho=(0.1, 0.0)) == 0.0)
    # to first order the light is rho_b rho_s times the geometry; the later bounces add about
    # rho_b rho_s F^2 (F ~ 0.5 at 22 mm: under 1 %)
    faint = _diffuse(pose, rho=(1e-4, 1e-4))
    ratio = full / (faint * 0.1 * 0.3 / 1e-8)
    assert np.all(ratio > 1.0) and np.all(ratio < 1.01)
    doubled = _diffuse(pose, rho=(0.2, 0.3))
    assert np.all(doubled > 2 * full) and np.all(doubled < 2.05 * full)


def test_a_mirrored_pose_reads_the_mirrored_pairs():
    mirrored = default_layout(stagger_mm=-6.0)
    pose = np.array([3.0, 30.0, np.radians(4.0)])
    np.testing.assert_allclose(_diffuse(pose * [-1, 1, -1], mirrored)[::-1], _diffuse(pose), rtol=1e-10)


def test_the_light_grows_as_the_cavity_closes_and_the_panels_have_converged():
    gaps = np.array([[0.0, z, 0.0] for z in (50.0, 40.0, 30.0, 22.0, 18.0)])
    e = _diffuse(gaps)
    assert np.all(np.diff(e, axis=0) > 0)
    assert np.all(e[3] / e[1] > 4.0)  # 22 against 40 mm: the render's 4.4-5.2x (docs/uses/sibling-sensors.md)
    deep = np.array([[0.0, 18.0, 0.0], [6.0, 20.0, np.radians(6.0)]])
    np.testing.assert_allclose(_diffuse(deep), _diffuse(deep, panels=(26, 10)), rtol=3e-3)


def test_the_table_interpolates_within_its_stated_error():
    t = np.linspace(0.0, 1.0, 400)
    poses = np.stack([5 * np.sin(7 * t), 30 + 8 * np.cos(5 * t), np.radians(5) * np.sin(11 * t)], axis=1)
    table = diffuse_irradiance_table(poses, LAYOUT, *FOOT, 0.1, 0.3, M)
    np.testing.assert_allclose(table[::10], _diffuse(poses[::10]), rtol=3e-3)
    # few poses are evaluated, not interpolated
    np.testing.assert_array_equal(diffuse_irradiance_table(poses[:3], LAYOUT, *FOOT, 0.1, 0.3, M), _diffuse(poses[:3]))


def test_bad_poses_are_refused():
    with pytest.raises(ValueError, match="NaN"):
        diffuse_irradiance_table(np.array([[0.0, np.nan, 0.0]]), LAYOUT, *FOOT, 0.1, 0.3, M)
