"""The swing foot's landing (issue 43, SPEC 4's early contact): the heave against the damped
oscillator's closed form, energy and momentum balances, the quasi-static limit (the static
placement), the LIPM's periodic gait, the friction's lever at the ankle, and the obstacles'
decisions derived from statics and geometry rather than from the code's own output."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import other_sensors.sole.kind  # noqa: F401  (registers the plantar_sole kind)
from mlsim.scene import SceneError, load_scene
from other_sensors.sole import estimators as est
from other_sensors.sole.cells import sole_layout
from other_sensors.sole.contact import FootPose, height_for_load, sole_contact
from other_sensors.sole.estimators import G
from other_sensors.sole.landing import LandingParams, first_contact_height, lipm_com, simulate_landing, swing_speed, touchdown_com
from other_sensors.sole.stages import assessment_of, contact_of_scene, landing_of_foot
from other_sensors.sole.terrain import Box, Flat, Sphere
from scene_helpers import assert_edits_refused

SCENES = Path(__file__).resolve().parents[1] / "scenes" / "sole"
LAYOUT = sole_layout()
K = 1.0e8  # N/m^3
AREA = 42 * LAYOUT.cell_area


def _params(**kw) -> LandingParams:
    base = dict(mass_kg=13.8, speed_m_s=0.05, load_n=250.0, stiffness_n_m3=K, damping_s=2e-3, com_m=(-0.1, -0.1),
                com_velocity_m_s=(0.4, 0.2), z_com_m=0.8, ankle_height_m=0.1, window_s=0.04)
    base.update(kw)
    return LandingParams(**base)


def _oscillator(t, m, k, c, force, u0, v0):
    """m u'' + c u' + k u = force, u(0) = u0, u'(0) = v0 (underdamped): u(t), u'(t)."""
    wn, zeta = np.sqrt(k / m), c / (2 * np.sqrt(k * m))
    wd, us = wn * np.sqrt(1 - zeta**2), force / k
    a, b = u0 - us, (v0 + zeta * wn * (u0 - us)) / wd
    e = np.exp(-zeta * wn * t)
    u = us + e * (a * np.cos(wd * t) + b * np.sin(wd * t))
    v = e * ((-zeta * wn * a + wd * b) * np.cos(wd * t) + (-zeta * wn * b - wd * a) * np.sin(wd * t))
    return u, v


# ------------------------------------------------------------------------------- closed forms
def test_a_flat_landing_is_the_damped_oscillator_and_the_ankle_reads_the_friction_lever():
    p = _params()
    landing = simulate_landing(LAYOUT, FootPose((0.0, 0.0, 0.0)), [Flat(0.0)], p, subdivisions=3)
    u, v = _oscillator(landing.t, p.mass_kg, K * AREA, K * p.damping_s * AREA, p.load_n, 0.0, p.speed_m_s)
    stays = np.all((u[1:] > 0) & (u[1:] + p.damping_s * v[1:] > 0))  # no lift-off, no clamped tension
    assert stays
    np.testing.assert_allclose(landing.sink, u, rtol=1e-7, atol=1e-12)
    np.testing.assert_allclose(landing.force_n[1:], K * AREA * (u + p.damping_s * v)[1:], rtol=1e-6)
    # a level sole on a flat floor: uniform pressure, no normal moment; the F/T reads only the lever
    # of the reaction's horizontal part, F_z |x_c| h / z_com, with x_c on the LIPM's closed form
    w = landing.wrench
    assert np.abs(w[:, 3:5]).max() < 1e-9 * w[:, 2].max()
    com = lipm_com(landing.ticks, p.com_m, p.com_velocity_m_s, p.z_com_m)
    np.testing.assert_allclose(np.hypot(*landing.ankle_moment.T), w[:, 2] * np.linalg.norm(com, axis=1) * 0.1 / 0.8, rtol=1e-9)
    np.testing.assert_allclose(w[:, :2], w[:, 2:3] * com / 0.8, rtol=1e-12)
    # at impact: the tick of the largest force; an F/T at the sole (h = 0) reads no moment
    assert landing.impact == int(np.argmax(w[:, 2]))
    flat_ft = simulate_landing(LAYOUT, FootPose((0.0, 0.0, 0.0)), [Flat(0.0)], _params(ankle_height_m=0.0), subdivisions=3)
    assert np.abs(flat_ft.ankle_moment).max() < 1e-9 * w[:, 2].max()


def test_rk4_converges_at_fourth_order_on_the_flat_landing():
    p = dict(speed_m_s=0.05, window_s=0.01)
    u_exact = _oscillator(np.array([0.01]), 13.8, K * AREA, K * 2e-3 * AREA, 250.0, 0.0, 0.05)[0][0]
    errors = [abs(simulate_landing(LAYOUT, FootPose((0, 0, 0)), [Flat(0.0)], _params(dt_s=dt, **p), 2).sink[-1] - u_exact)
              for dt in (4e-4, 2e-4, 1e-4)]
    slopes = np.diff(np.log(errors)) / np.log(0.5)
    assert np.all(slopes > 3.7), (errors, slopes)


def test_undamped_landing_on_spheres_conserves_energy_and_momentum_balances_the_impulse():
    terrain = [Sphere((0.05, 0.03, -0.01), 0.05)]  # a nonlinear (Hertz-like) patch on the layer
    p = _params(damping_s=0.0, speed_m_s=0.3, window_s=0.04)
    landing = simulate_landing(LAYOUT, FootPose((0, 0, 0)), terrain, p, subdivisions=4)
    from other_sensors.sole.contact import _sample_clearance, cell_sampling

    s = cell_sampling(LAYOUT, 4)
    touch = first_contact_height(LAYOUT, FootPose((0, 0, 0)), terrain, 4)
    clear = _sample_clearance(s, FootPose((0, 0, touch)), terrain)
    depth = np.maximum(landing.sink[:, None, None] - clear[None], 0.0)
    elastic = 0.5 * K * (depth**2 * s.weights).sum(axis=(1, 2))
    energy = 0.5 * p.mass_kg * landing.sink_rate**2 + elastic - p.load_n * landing.sink
    assert landing.force_n.max() > 3 * p.load_n  # a real impact
    assert np.abs(energy - energy[0]).max() < 1e-6 * energy[0]
    # impulse = change of momentum (trapezoid over the fine steps), with damping too
    damped = simulate_landing(LAYOUT, FootPose((0, 0, 0)), terrain, _params(speed_m_s=0.3, window_s=0.04), subdivisions=4)
    impulse = np.trapezoid(p.load_n - damped.force_n, damped.t)
    assert p.mass_kg * (damped.sink_rate[-1] - 0.3) == pytest.approx(impulse, rel=1e-4, abs=1e-6)


def test_a_slow_landing_settles_on_the_static_placement():
    terrain = [Flat(0.0), Box((0.06, 0.02), (0.08, 0.06), 0.015)]
    pose = FootPose((0.0, 0.0, 0.0), pitch=np.radians(1.0))
    landing = simulate_landing(LAYOUT, pose, terrain, _params(speed_m_s=0.0, damping_s=0.01, window_s=0.6, dt_s=1e-4), 2)
    z_static = height_for_load(LAYOUT, pose, terrain, K, 250.0, 2)
    assert landing.force_n[-1] == pytest.approx(250.0, rel=1e-4)
    assert landing.pose.position[2] - landing.sink[-1] == pytest.approx(z_static, abs=1e-8)
    static = sole_contact(LAYOUT, pose.with_height(z_static), terrain, K, 2)
    np.testing.assert_allclose(landing.tick_forces[-1], static.sensor_forces, rtol=1e-4, atol=1e-6)


def test_the_periodic_lipm_gait_and_the_swing_speed():
    z, length, width, single = 0.8, 0.2, 0.2, 0.8
    com, vel = touchdown_com(length, width, single, z, "left")
    omega = np.sqrt(G / z)
    # sagittal: from -L/2 to +L/2 in T with the same speed (a periodic gait)
    x = lipm_com(np.array([0.0, single]), com, vel, z)
    np.testing.assert_allclose(x[:, 0], [-length / 2, length / 2], rtol=1e-12)
    speed_end = com[0] * omega * np.sinh(omega * single) + vel[0] * np.cosh(omega * single)
    assert speed_end == pytest.approx(vel[0], rel=1e-12)
    # lateral: from W/2 on the right back to W/2 on the right, turning at T/2
    assert x[1, 1] == pytest.approx(-width / 2, rel=1e-12) and com[1] == -width / 2
    turn = com[1] * omega * np.sinh(omega * single / 2) + vel[1] * np.cosh(omega * single / 2)
    assert abs(turn) < 1e-12
    right = touchdown_com(length, width, single, z, "right")
    np.testing.assert_allclose(right[0] * [1, -1], com) and np.testing.assert_allclose(right[1] * [1, -1], vel)
    # the cosine swing: at rest at the ground and at the apex, pi H / (2 T) half-way
    assert swing_speed(0.0, 0.05, 0.25) == 0.0 and swing_speed(0.05, 0.05, 0.25) == 0.0
    assert swing_speed(0.025, 0.05, 0.25) == pytest.approx(np.pi * 0.05 / 0.5)
    assert swing_speed(-0.01, 0.05, 0.25) == 0.0  # terrain below the plan: arrives at rest
    with pytest.raises(ValueError, match="swing_height_mm"):
        swing_speed(0.06, 0.05, 0.25)


# ---------------------------------------------------------------- the obstacles, from statics
def _landing_scene(name: str):
    scene = load_scene(SCENES / "obstacles.toml")
    case = {c.name: c for c in scene.sensor.obstacles}[name]
    return scene.sensor.model_copy(update={"terrain": case.terrain, "foot": case.foot}), scene.seed


def _lever(sensor, landing):
    """h |x_c| / z_com at the impact tick: the friction's lever per newton of normal force."""
    p = sensor.landing.params(250.0, 1e8, sensor.balance, 0.0)
    com = lipm_com(landing.ticks[[landing.impact]], p.com_m, p.com_velocity_m_s, p.z_com_m)[0]
    return p.ankle_height_m * com / p.z_com_m


def _cells_over(footprint_points):
    """The cells whose hexagon holds any of the footprint's points (M, 2) m: a bound on who can touch."""
    from matplotlib.path import Path as MplPath

    return np.array([MplPath(c).contains_points(footprint_points).any() for c in LAYOUT.corners])


def _grid(low, high, n=81):
    xs, ys = np.meshgrid(np.linspace(low[0], high[0], n), np.linspace(low[1], high[1], n))
    return np.column_stack([xs.ravel(), ys.ravel()])


@pytest.mark.parametrize("name", ["large_flat", "small_flat_border", "small_flat_ankle", "three_spheres"])
def test_the_landing_obstacles_decide_as_their_statics_say(name):
    sensor, seed = _landing_scene(name)
    landing = landing_of_foot(sensor, sensor.foot, sensor.terrain)
    contact = contact_of_scene(sensor, seed)
    a = assessment_of(sensor, contact)
    fz = landing.wrench[landing.impact, 2]
    lever = _lever(sensor, landing)
    friction = np.array([lever[1], -lever[0]]) * fz  # (h f_y, -h f_x)
    # every obstacle is 20 mm up (the spheres' tops to the quadrature's resolution): met at the swing
    # profile's speed there, (pi / T) sqrt(z (H - z))
    z0 = landing.pose.position[2]
    assert z0 == pytest.approx(0.02, abs=1e-4)
    assert landing.speed_m_s == pytest.approx(np.pi / 0.25 * np.sqrt(z0 * (0.05 - z0)), rel=1e-12)
    assert fz == landing.wrench[:, 2].max() and contact.wrench[2] == pytest.approx(fz, abs=42 * 3 * 0.2)
    sole = a.sole_area
    if name == "large_flat":
        # all cells sink alike: uniform pressure, the whole sole, and only the friction's lever
        assert a.area_ratio == pytest.approx(1.0) and not a.skin_replan
        np.testing.assert_allclose(contact.ankle_wrench[3:5], friction, rtol=1e-3, atol=0.05)
        footprint = None
    elif name == "three_spheres":
        # three equal caps, all under the sole: equal forces, the normal CoP at the centres' mean (20, 0) mm
        # (to the quadrature's resolution of the ~6 mm patches: 2.7 mm between samples)
        normal = fz * np.array([0.0, -0.02])
        np.testing.assert_allclose(landing.wrench[landing.impact, 3:5], normal, atol=0.03 * np.linalg.norm(normal))
        np.testing.assert_allclose(landing.ankle_moment[landing.impact] - landing.wrench[landing.impact, 3:5], friction, rtol=1e-9)
        # each cap touches within a = sqrt(2 R d - d^2) of its top, d the sink at impact
        d = float(np.interp(landing.ticks[landing.impact], landing.t, landing.sink))
        a_m = np.sqrt(2 * 0.02 * d - d * d)
        disk = _grid((-a_m, -a_m), (a_m, a_m))
        disk = disk[np.linalg.norm(disk, axis=1) <= a_m]
        footprint = np.vstack([disk + c for c in ((0.07, 0.04), (0.07, -0.04), (-0.08, 0.0))])
    else:
        centre = (0.095, 0.05) if name == "small_flat_border" else (0.0, 0.0)
        low, high = np.subtract(centre, 0.02), np.add(centre, 0.02)
        footprint = _grid(low, high)
        # the normal CoP lies over the box: the moment's normal part is F_z |CoP| within the box's reach from the ankle
        corners = np.array([[x, y] for x in (low[0], high[0]) for y in (low[1], high[1])])
        near = 0.0 if np.all(low <= 0) and np.all(high >= 0) else np.linalg.norm(np.clip(0.0, low, high))
        far = np.linalg.norm(corners, axis=1).max()
        normal = np.hypot(*landing.wrench[landing.impact, 3:5])
        assert fz * near - 1e-9 <= normal <= fz * far + 1e-9
        m_low, m_high = fz * max(near - np.linalg.norm(lever), 0.0), fz * (far + np.linalg.norm(lever))
        assert m_low - 0.05 <= a.ankle_moment <= m_high + 0.05
        if m_low >= 8.0:  # the statics alone decide the F/T rule
            assert a.ft_replan
        if m_high < 8.0:
            assert not a.ft_replan
    if footprint is not None:
        # the support polygon holds only cells over the obstacle: its hull bounds A_p
        bound = est.polygon_area(est.support_polygon(LAYOUT.corners, _cells_over(footprint)))
        assert a.polygon_area <= bound * (1 + 1e-9)
        assert bound / sole < 0.8 and a.skin_replan  # the skin rule sees every small obstacle
    assert a.ft_replan == (a.ankle_moment >= 8.0)


def test_a_yawed_landing_turns_the_moment_with_it():
    terrain = [Flat(0.0), Box((0.06, 0.03), (0.04, 0.04), 0.01)]
    p = _params(com_m=(0.0, 0.0), com_velocity_m_s=(0.0, 0.0), speed_m_s=0.1)
    one = simulate_landing(LAYOUT, FootPose((0, 0, 0)), terrain, p, 3)
    # the same obstacle in the sole frame of a foot turned 60 deg: the same readings
    yaw = np.radians(60.0)
    rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
    centre = rot @ [0.06, 0.03]
    turned = simulate_landing(LAYOUT, FootPose((0, 0, 0), yaw=yaw), [Flat(0.0), Box(tuple(centre), (0.04, 0.04), 0.01, yaw)], p, 3)
    np.testing.assert_allclose(turned.tick_forces, one.tick_forces, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(turned.ankle_moment, one.ankle_moment, rtol=1e-9, atol=1e-9)


# -------------------------------------------------------------------------------- bad input
def test_bad_landings_are_refused_naming_the_field(tmp_path):
    assert_edits_refused(SCENES / "obstacles.toml",
                         (("[sensor.landing]", "[sensor.landing]\nspeed_mm_s = inf", "sensor.landing.speed_mm_s"),
                          ("[sensor.landing]", "[sensor.landing]\nspeed_mm_s = nan", "sensor.landing.speed_mm_s"),
                          ("[sensor.landing]", "[sensor.landing]\nspeed_mm_s = -5.0", "sensor.landing.speed_mm_s"),
                          ("damping_time_ms = 2.0", "damping_time_ms = -1.0", "sensor.landing.damping_time_ms"),
                          ('side = "left"', 'side = "middle"', "sensor.landing.side")), tmp_path)
    for field, value in (("speed_m_s", float("nan")), ("mass_kg", 0.0), ("load_n", float("inf")), ("dt_s", 1.0)):
        with pytest.raises(ValueError, match=field):
            _params(**{field: value})
    sensor, _ = _landing_scene("large_flat")
    low = sensor.model_copy(update={"landing": sensor.landing.model_copy(update={"swing_height_mm": 10.0})})
    with pytest.raises(ValueError, match="swing_height_mm"):
        landing_of_foot(low, low.foot, low.terrain)
    # and at the door, before any stage runs: the 20 mm obstacles stand above a 10 mm swing
    path = tmp_path / "low.toml"
    path.write_text((SCENES / "obstacles.toml").read_text().replace("swing_height_mm = 50.0", "swing_height_mm = 10.0", 1))
    with pytest.raises(SceneError, match=r"sensor\.landing\.swing_height_mm"):
        load_scene(path)
    from mlsim.cli import main

    assert main(["run", str(path), "--out", str(tmp_path / "out"), "--quiet"]) == 2
