"""The AnySkin helmet (issue 19, physics half; SPEC 2): dipole fields against analytic values, the
geomagnetic reading's rotation invariance, the permanent-set drift on a step load, noise and
quantisation, the plate-force split, and the kind through ``mlsim run``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import other_sensors.anyskin.kind  # noqa: F401  (registers the anyskin kind)
from mlsim.cli import main
from mlsim.scene import SceneError, load_scene
from other_sensors.anyskin.contact_state import ONSET, RELEASE, REBASELINE_SAMPLES, ThresholdStandIn, track_contacts, window_slope_weights
from other_sensors.anyskin.dipoles import MU0, dipole_field, dipole_field_jacobian
from other_sensors.anyskin.helmet import head_rotations, helmet_layout, plate_forces, push_profile, rotation
from other_sensors.anyskin.schema import AnySkinSensor
from other_sensors.anyskin.signals import simulate_helmet, skin_of
from other_sensors.anyskin.skin import contact_displacement, geomagnetic_reading, permanent_set, read_out, skin_field

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "anyskin" / "headon_push.toml"


# ------------------------------------------------------------------------------------- dipoles
def test_dipole_field_on_axis_and_in_the_equatorial_plane_is_analytic():
    m, z, r = 0.3, 0.012, 0.017  # A m^2, m, m
    on_axis = dipole_field([[0.0, 0.0, z]], [[0.0, 0.0, 0.0]], [[0.0, 0.0, m]])[0]
    np.testing.assert_allclose(on_axis, [0.0, 0.0, MU0 * m / (2 * np.pi * z**3)], rtol=1e-13, atol=1e-20)
    # equatorial, in an arbitrary direction in the plane, and from an offset dipole
    p = np.array([0.004, -0.002, 0.001])
    direction = np.array([np.cos(0.7), np.sin(0.7), 0.0])
    equatorial = dipole_field([p + r * direction], [p], [[0.0, 0.0, m]])[0]
    np.testing.assert_allclose(equatorial, [0.0, 0.0, -MU0 * m / (4 * np.pi * r**3)], rtol=1e-13, atol=1e-20)
    # the field of a tilted moment is the tilted field (the formula is frame-free)
    q = rotation(0.3, -0.5, 1.1)
    tilted = dipole_field([q @ [0.0, 0.0, z]], [[0.0, 0.0, 0.0]], [q @ [0.0, 0.0, m]])[0]
    np.testing.assert_allclose(tilted, q @ on_axis, rtol=1e-12)


def test_dipole_fields_superpose_linearly_and_fall_as_r_cubed():
    rng = np.random.default_rng(3)
    points, pos = rng.normal(0, 0.05, (7, 3)), rng.normal(0, 0.01, (4, 3)) + [0, 0, 0.2]
    m1, m2 = rng.normal(size=(4, 3)), rng.normal(size=(4, 3))
    both = dipole_field(points, pos, 2.0 * m1 - 0.5 * m2)
    np.testing.assert_allclose(both, 2.0 * dipole_field(points, pos, m1) - 0.5 * dipole_field(points, pos, m2), rtol=1e-12, atol=1e-18)
    np.testing.assert_allclose(dipole_field(points, pos, m1), sum(dipole_field(points, pos[k:k + 1], m1[k:k + 1]) for k in range(4)),
                               rtol=1e-12, atol=1e-18)
    # far field of the whole group: log-log slope of |B| against distance is -3
    distances = np.geomspace(2.0, 16.0, 6)  # m, from the group's centre, >> its 1 cm spread
    direction = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    centre = pos.mean(axis=0)
    magnitude = np.linalg.norm(dipole_field(centre + distances[:, None] * direction, pos, m1), axis=1)
    slope = np.polyfit(np.log(distances), np.log(magnitude), 1)[0]
    assert slope == pytest.approx(-3.0, abs=0.02)


def test_dipole_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    points, pos, mom = rng.normal(0, 0.01, (3, 3)), rng.normal(0, 0.01, (2, 3)) + [0, 0, 0.03], rng.normal(size=(2, 3))
    jac = dipole_field_jacobian(points, pos, mom)
    assert jac.shape == (3, 3, 2, 3)
    h = 1e-7
    for n in range(2):
        for j in range(3):
            step = np.zeros_like(pos)
            step[n, j] = h
            fd = (dipole_field(points, pos + step, mom) - dipole_field(points, pos - step, mom)) / (2 * h)
            np.testing.assert_allclose(jac[:, :, n, j], fd, rtol=1e-6, atol=1e-9 * np.abs(fd).max())
    with pytest.raises(ValueError, match="end in 3"):
        dipole_field(np.zeros((2, 2)), pos, mom)


# ------------------------------------------------------------------------------------ the skin
def test_pressing_moves_the_dipoles_towards_the_chips_and_changes_the_field():
    geometry = skin_of(AnySkinSensor())
    force = np.array([[0.0, 0.0, -20.0], [0.0, 0.0, 5.0], [3.0, 0.0, -20.0]])
    u = contact_displacement(geometry, force, (0.0, 0.0), 8e-3, 5e5, 0.6)
    assert u.shape == (3, len(geometry.dipoles), 3)
    assert (u[0, :, 2] < 0).all() and np.abs(u[1]).max() == 0.0  # pulling is no contact
    # small load: u_z = h p / E at the patch's peak; G = E / 3 for the shear
    small = contact_displacement(geometry, [[0.0, 0.0, -1e-3]], (0.0, 0.0), 8e-3, 5e5, 0.6)[0]
    weight = np.exp(-(geometry.dipoles[:, :2] ** 2).sum(axis=1) / (2 * 8e-3**2)) / (2 * np.pi * 8e-3**2)
    np.testing.assert_allclose(small[:, 2], -geometry.height_in_layer * 1e-3 * weight / 5e5, rtol=1e-6)
    assert (u[2, :, 0] > 0).all()
    rest = skin_field(geometry)
    pressed = skin_field(geometry, u)
    assert rest.shape == (5, 3) and pressed.shape == (3, 5, 3)
    np.testing.assert_array_equal(pressed[1], rest)
    assert np.abs(pressed[0] - rest).max() > 10.0  # uT, far above the chips' noise


def test_geomagnetic_reading_rotates_with_the_head_and_keeps_its_magnitude():
    b = np.array([19.5, 0.0, -43.9])
    rng = np.random.default_rng(2)
    rots = rotation(*rng.uniform(-np.pi, np.pi, (3, 50)))
    reading = geomagnetic_reading(rots, b)
    np.testing.assert_allclose(np.linalg.norm(reading, axis=1), np.linalg.norm(b), rtol=1e-12)
    np.testing.assert_allclose(reading, np.einsum("tji,j->ti", rots, b), rtol=1e-12)
    # invariance: turning the head and the Earth's field by the same rotation changes no reading
    q = rotation(0.4, -0.2, 2.0)
    np.testing.assert_allclose(geomagnetic_reading(q @ rots, q @ b), reading, rtol=1e-12, atol=1e-12)
    # turning the head by q reads the field turned by q^T
    np.testing.assert_allclose(geomagnetic_reading(q, b), q.T @ b, rtol=1e-12)


def test_permanent_set_follows_a_step_load_and_relaxes_with_its_time_constants():
    dt, n_on, n_off = 1 / 150, 1500, 3000
    load = np.zeros((n_on + n_off, 2))
    load[:n_on] = [0.5, -0.2]
    s = permanent_set(load, dt, 0.25, 10.0, 120.0)
    t = np.arange(n_on + n_off) * dt
    on = t[:n_on]
    np.testing.assert_allclose(s[:n_on], 0.25 * load[:n_on] * (1 - np.exp(-on / 10.0))[:, None], rtol=1e-10, atol=1e-15)
    s_release = 0.25 * load[0] * (1 - np.exp(-n_on * dt / 10.0))
    off = t[n_on:] - n_on * dt
    np.testing.assert_allclose(s[n_on:], s_release * np.exp(-off / 120.0)[:, None], rtol=1e-10)
    # repeated pushes ratchet the set up: the set after each rest grows with the cycle count
    period, push = 375, 225  # samples: 2.5 s cycles, 1.5 s on
    cycles = np.zeros((period * 8, 1))
    for k in range(8):
        cycles[k * period:k * period + push] = 1.0
    ends = permanent_set(cycles, dt, 0.25, 10.0, 120.0)[period - 1::period, 0]
    assert (np.diff(ends) > 0).all() and ends[-1] > 3 * ends[0]
    with pytest.raises(ValueError, match="tau_set_s"):
        permanent_set(cycles, dt, 0.25, 0.0, 120.0)


def test_noise_rms_and_quantisation_step_are_as_set():
    clean = np.full((20000, 3), 123.456)
    noisy = read_out(clean, 2.0, 0.0, np.random.default_rng(0))
    rms = np.sqrt(((noisy - clean) ** 2).mean())
    # the sample variance's relative standard error is sqrt(2 / n): 4 sigma
    assert rms == pytest.approx(2.0, rel=4 * np.sqrt(2 / noisy.size) / 2)
    q = read_out(clean, 2.0, 0.15, np.random.default_rng(0))
    codes = q / 0.15
    np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)
    assert np.abs(q - noisy).max() <= 0.075 + 1e-12  # rounding moves a reading by at most half a step
    np.testing.assert_array_equal(read_out(clean, 0.0, 0.0, np.random.default_rng(0)), clean)


# ------------------------------------------------------------------------------------ the helmet
def test_plate_forces_carry_the_push_and_split_it_by_reach():
    flat = helmet_layout(0.0, 0.04, 0.03, 0.15)
    head = np.repeat(np.eye(3)[None], 3, axis=0)
    normal, local = plate_forces(flat, head, np.array([0.0, 40.0, 100.0]), 5e3)
    np.testing.assert_allclose(normal, [[0.0] * 4, [10.0] * 4, [25.0] * 4], rtol=1e-12)  # an unpitched face: equal shares
    np.testing.assert_allclose(local[2], [[0.0, 0.0, -25.0]] * 4, atol=1e-12)  # pressing along each skin's normal
    # a pitched face: the upper pads reach 2 h sin(theta) further; light pushes load only them
    pitched = helmet_layout(np.radians(15.0), 0.04, 0.03, 0.15)
    normal, local = plate_forces(pitched, head[:2], np.array([50.0, 400.0]), 5e3)
    np.testing.assert_allclose(normal.sum(axis=1), [50.0, 400.0], rtol=1e-12)
    np.testing.assert_allclose(normal[0], [25.0, 25.0, 0.0, 0.0], rtol=1e-12)
    gap = 2 * 0.03 * np.sin(np.radians(15.0))
    np.testing.assert_allclose(normal[1, 0] - normal[1, 2], 5e3 * gap, rtol=1e-10)
    np.testing.assert_allclose(local[1, 0], normal[1, 0] * np.array([-np.sin(np.radians(15.0)), 0.0, -np.cos(np.radians(15.0))]),
                               rtol=1e-12, atol=1e-12)


def test_head_rates_stay_under_180_deg_s_and_pushes_have_their_peaks():
    t = np.arange(1500) / 150
    rots = head_rotations(t, 2.0, np.radians([6.0, 8.0, 6.0]), 0.3, np.random.default_rng(0))
    rel = np.einsum("tji,tjk->tik", rots[:-1], rots[1:])
    rate = np.degrees(np.arccos(np.clip((np.trace(rel, axis1=1, axis2=2) - 1) / 2, -1, 1))) * 150
    assert 60.0 < rate.max() < 180.0
    push = push_profile(t, 1.0, 1.5, 1.0, 150.0, 0.0, np.random.default_rng(0))
    assert push[t < 1.0].max() == 0.0 and push.max() == pytest.approx(150.0, rel=1e-3)


def _quiet(**changes) -> AnySkinSensor:
    base = {"trajectory": {"duration_s": 3.0}, "drift": {"enabled": False},
            "noise": {"rms_ut": 0.0, "rms_z_ut": 0.0, "lsb_ut": 0.0, "lsb_z_ut": 0.0, "offset_ut": 0.0, "gain_error_pct": 0.0, "cross_axis_pct": 0.0},
            "ambient": {"geomagnetic_ut": (0.0, 0.0, 0.0), "motor_ut": 0.0}}
    base.update(changes)
    return AnySkinSensor(**base)


def test_no_force_reads_the_baseline_exactly_and_parts_add_up():
    r = simulate_helmet(_quiet(push={"peak_n": 0.0}), seed=4)
    assert r.readings.shape == (450, 4, 5, 3) and np.isfinite(r.readings).all()
    np.testing.assert_array_equal(r.readings, np.broadcast_to(r.baseline, r.readings.shape))
    # with the Earth's and the motors' fields, no noise: the reading is the baseline plus both
    r = simulate_helmet(_quiet(push={"peak_n": 0.0}, ambient={}), seed=4)
    np.testing.assert_allclose(r.readings, r.baseline + r.geomagnetic + r.motor, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(r.geomagnetic, axis=-1), np.linalg.norm([19.5, 0.0, -43.9]), rtol=1e-12)
    # pushes change the readings of the loaded skins only; the same seed gives the same output
    pushed = simulate_helmet(_quiet(), seed=4)
    loaded = pushed.normal_n.max(axis=0) > 0
    change = np.abs(pushed.readings - pushed.baseline).max(axis=(0, 2, 3))
    assert (change[loaded] > 10.0).all() and (change[~loaded] == 0.0).all()
    np.testing.assert_array_equal(simulate_helmet(_quiet(), seed=4).readings, pushed.readings)


def test_drift_leaves_a_set_after_the_pushes():
    r = simulate_helmet(_quiet(drift={"enabled": True}, trajectory={"duration_s": 6.0}, push={"first_s": 0.5, "jitter": 0.0}), seed=1)
    rest = r.total_n == 0
    after = np.nonzero(rest & (r.t > 2.5))[0]
    assert r.set_mm[-1].max() > 0.0
    offset = np.abs(r.readings[after] - r.baseline).max()
    assert offset > 1.0  # uT: the skin no longer reads its baseline at rest


# ---------------------------------------------------------------------------- contact pipeline
def test_window_slope_is_the_least_squares_slope():
    w = window_slope_weights(50, 150.0)
    t = np.arange(50) / 150.0
    assert w @ (3.0 + 7.5 * t) == pytest.approx(7.5, rel=1e-12) and abs(w @ np.full(50, 4.0)) < 1e-12
    y = np.random.default_rng(0).normal(size=50)
    assert w @ y == pytest.approx(np.polyfit(t, y, 1)[0], rel=1e-10)


def _press(offset_ut: float) -> np.ndarray:
    """One channel pressed (0 -> 300 uT over 0.5 s at 2 s, held 1 s, back over 0.5 s) that keeps offset_ut after."""
    t = np.arange(900) / 150.0
    level = np.interp(t, [0, 2.0, 2.5, 3.5, 4.0, 6.0], [0, 0, 300, 300, offset_ut, offset_ut])
    readings = np.zeros((900, 2, 3))
    readings[:, 0, 2] = 500.0 + level  # channel 0 carries a rest field and the press; channel 1 stays still
    return readings


def test_the_contact_state_machine_rebaselines_on_the_falling_edge():
    args = (150.0, 1.0, 5, 10.0, 50, ThresholdStandIn(60.0, 60.0))
    tracked = track_contacts(_press(20.0), *args, rebaseline=True)
    commit = int(np.argmax(tracked.rebaselines[:, 0]))
    assert (tracked.event[:, 0] == ONSET).sum() == 1 and (tracked.event[:commit + 1, 0] == RELEASE).sum() == 1
    onset, release = np.argmax(tracked.event[:, 0] == ONSET), np.argmax(tracked.event[:, 0] == RELEASE)
    # the release ends the fall (3.5 s .. 4.0 s), a slope window (1/3 s) late at most
    assert 2.0 < onset / 150 < 2.5 and 4.0 < release / 150 < 4.0 + 1 / 3
    assert tracked.state[onset:release, 0].all() and not tracked.state[release:, 0].any() and not tracked.event[:, 1].any()
    # O commits at the end of the first quiet span of R samples after the edge (the reading is flat from 4.0 s on)
    assert tracked.rebaselines[:, 0].sum() == 1 and commit == release + REBASELINE_SAMPLES
    np.testing.assert_allclose(tracked.offsets[-1, 0], [0.0, 0.0, 20.0], atol=1e-9)  # O: the set left by the press
    assert not tracked.offsets[: commit + 1].any()
    assert abs(tracked.signal[-1, 0, 2]) < 0.5  # back at zero after the re-baseline
    static = track_contacts(_press(20.0), *args, rebaseline=False)
    assert static.signal[-1, 0, 2] == pytest.approx(20.0, abs=0.5) and not static.offsets.any()
    with pytest.raises(ValueError, match="calibration_s"):
        track_contacts(_press(0.0), 150.0, 10.0, 5, 10.0, 50, ThresholdStandIn(60.0, 60.0))


# ------------------------------------------------------------------------------------- the kind
def test_the_kind_runs_through_mlsim_run_and_loads_from_the_cache(tmp_path):
    scene_file = tmp_path / "short.toml"
    scene_file.write_text(SCENE.read_text().replace("duration_s = 12.0", "duration_s = 4.0"))
    out, cache = tmp_path / "out", tmp_path / "cache"
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    assert (out / "anyskin_signals.png").stat().st_size > 1000
    csv = np.loadtxt(out / "anyskin_signals.csv", delimiter=",", skiprows=1)
    assert csv.shape == (600, 2 + 4 + 12 + 60)
    summary = json.loads((out / "summary.json").read_text())["stages"]["anyskin_signals"]
    assert summary["action"] == "run" and summary["summary"]["samples"] == 600
    assert summary["summary"]["peak_push_n"] == pytest.approx(csv[:, 1].max(), rel=1e-5)
    np.testing.assert_allclose(csv[:, 2:6].sum(axis=1), csv[:, 1], rtol=1e-4, atol=1e-3)
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    again = json.loads((out / "summary.json").read_text())["stages"]["anyskin_signals"]
    assert again["action"] == "load" and again["key"] == summary["key"]
    contact = json.loads((out / "summary.json").read_text())["stages"]["anyskin_contact"]["summary"]
    assert 0.0 < contact["mae_rebaselined_n"] < 10.0 and 0.0 < contact["mae_static_n"] < 10.0  # N, pushes peak at 150 N
    assert sum(contact["onsets_per_sensor"]) > 0
    assert np.loadtxt(out / "anyskin_contact.csv", delimiter=",", skiprows=1).shape == (600, 1 + 4 * 9 + 4)


def test_the_shipped_scene_loads_and_bad_input_names_its_field(tmp_path):
    scene = load_scene(SCENE)
    assert scene.sensor.kind == "anyskin" and scene.sensor.helmet.face_pitch_deg == 15.0
    fast = tmp_path / "fast.toml"
    fast.write_text(SCENE.read_text().replace("gait_hz = 2.0", "gait_hz = 4.0"))
    with pytest.raises(SceneError, match="sensor.trajectory.gait_hz"):
        load_scene(fast)
    bad = tmp_path / "bad.toml"
    bad.write_text(SCENE.read_text().replace("rms_ut = 1.5", "rms_ut = -1.0"))
    with pytest.raises(SceneError, match="sensor.noise.rms_ut"):
        load_scene(bad)
