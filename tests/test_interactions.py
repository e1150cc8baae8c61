"""The interactions of SPEC 1.5 (mlsim.interactions): strokes, labels, people, the clamp that locks."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fem import trajectory
from mlsim import interactions as ia
from mlsim.scene import SceneError, load_scene

ROOT = Path(__file__).resolve().parents[1]
FPS = 30.0


def _walk(scene):
    """The indenter's states at every frame, walked like the solver walks them (force 0 from the solver)."""
    load = scene.load
    grid = trajectory.time_grid(load, FPS)
    state = trajectory.initial_state(load, 0.0)
    out = []
    for t in grid.frame_times_s:
        state = trajectory.advance(load, state, float(t), 0.0)
        out.append(state)
    return out


def _sample(action, **kw):
    spec = ia.InteractionSpec()
    person = ia.draw_people(1, spec, np.random.default_rng(3))[0]
    s = ia.draw_sample(action, person, spec, np.random.default_rng(4))
    return spec, s.__class__(**(s.as_dict() | kw))


def test_minimum_jerk_profile():
    tau = np.linspace(0, 1, 1001)
    s = ia.minimum_jerk(tau)
    v = np.gradient(s, tau)
    assert s[0] == 0 and s[-1] == pytest.approx(1.0, abs=1e-15)
    assert s[500] == pytest.approx(0.5, abs=1e-12)  # symmetric
    assert v.max() == pytest.approx(1.875, rel=1e-3)  # peak speed 15/8 of the mean (Flash & Hogan)
    assert abs(v[0]) < 1e-5 and abs(v[-1]) < 1e-5  # rest to rest
    assert np.all(np.diff(s) >= 0)


@pytest.mark.parametrize("action", [a for a in ia.ACTIONS if not a.startswith("rotation")])
def test_translation_strokes_end_where_drawn(action):
    """Walking the segments moves the screw by stroke_mm along direction_deg (tremor ends at zero)."""
    spec, s = _sample(action)
    base = load_scene(ROOT / "scenes" / "interactions" / "screw.toml")
    scene = ia.interaction_scene(base, s, spec, noise_seed=1)
    states = _walk(scene)
    x0, y0 = states[0].position_m[:2]
    x1, y1 = states[-1].position_m[:2]
    d = np.array([x1 - x0, y1 - y0]) * 1e3
    a = math.radians(s.direction_deg)
    assert np.hypot(*d) == pytest.approx(s.stroke_mm, rel=1e-9)
    assert d @ np.array([math.cos(a), math.sin(a)]) == pytest.approx(s.stroke_mm, rel=1e-9)
    assert states[-1].yaw_rad == pytest.approx(0.0, abs=1e-15)
    assert y0 * 1e3 == pytest.approx(s.grip_offset_mm)


def test_nominal_directions():
    spec = ia.InteractionSpec(direction_bias_deg_range=(0.0, 0.0), direction_sd_deg=0.0, oblique_deg_range=(45.0, 45.0))
    person = ia.draw_people(1, spec, np.random.default_rng(0))[0]
    got = {a: ia.draw_sample(a, person, spec, np.random.default_rng(1)).direction_deg for a in ia.ACTIONS[:6]}
    assert got == {"push": 0.0, "pull": 180.0, "oblique_push": 45.0, "oblique_pull": 225.0, "sliding_left": 90.0, "sliding_right": -90.0}


@pytest.mark.parametrize("action,sign", [("rotation_cw", -1.0), ("rotation_ccw", 1.0)])
def test_rotations_turn_by_the_twist(action, sign):
    spec, s = _sample(action)
    base = load_scene(ROOT / "scenes" / "interactions" / "screw.toml")
    states = _walk(ia.interaction_scene(base, s, spec, noise_seed=1))
    turn = math.degrees(states[-1].yaw_rad - states[0].yaw_rad)
    assert turn == pytest.approx(s.twist_deg, rel=1e-9)
    assert math.copysign(1.0, turn) == sign
    # the tremor of a rotation is across the screw (y) and ends at zero
    assert states[-1].position_m[0] == pytest.approx(states[0].position_m[0], abs=1e-15)
    assert states[-1].position_m[1] == pytest.approx(states[0].position_m[1], abs=1e-12)


def test_clamp_locks_its_height():
    """keep = "height": the force target holds until the ramp ends, then displacement control."""
    spec, s = _sample("push")
    base = load_scene(ROOT / "scenes" / "interactions" / "screw.toml")
    load = ia.interaction_scene(base, s, spec, noise_seed=1).load
    state = trajectory.initial_state(load, 0.0)
    n_ramp = int(round(spec.grip_s * FPS))
    targets = []
    for k in range(1, n_ramp + 3):
        state = trajectory.advance(load, state, k / FPS, 0.0)
        targets.append(state.force_target_n)
    assert targets[n_ramp - 1] == pytest.approx(spec.grip_force_n)
    assert targets[n_ramp] is None and targets[n_ramp + 1] is None
    keep_force = load.model_copy(update={"segments": (load.segments[0].model_copy(update={"keep": "force"}),) + load.segments[1:]})
    state = trajectory.initial_state(keep_force, 0.0)
    state = trajectory.advance(keep_force, state, (n_ramp + 2) / FPS, 0.0)
    assert state.force_target_n == pytest.approx(spec.grip_force_n)


def test_keep_only_on_a_force_ramp():
    base = load_scene(ROOT / "scenes" / "interactions" / "screw.toml")
    with pytest.raises(SceneError, match="keep applies to a force ramp"):
        base.with_values({"load.segments": [{"kind": "press", "depth_mm": 1.0, "speed_mm_s": 1.0, "keep": "height"}]})


def test_frame_labels_cover_the_stroke():
    spec, s = _sample("push", onset_s=0.3, duration_s=0.5)
    labels = ia.frame_labels(s, spec, 40, FPS, 3)
    start = spec.grip_s + 0.3
    t = np.arange(40) / FPS
    inside = (t > start + 1e-9) & (t <= start + 0.5 + 1 / FPS + 1e-9)
    assert np.array_equal(labels >= 0, inside)
    assert set(labels[inside]) == {3}
    assert inside.sum() == 16  # frames 13..28 at 30 FPS: t in (0.4, 0.9333]


def test_people_within_ranges_and_seeded():
    spec = ia.InteractionSpec()
    a = ia.draw_people(10, spec, np.random.default_rng(7))
    b = ia.draw_people(10, spec, np.random.default_rng(7))
    c = ia.draw_people(10, spec, np.random.default_rng(8))
    assert a == b and a != c
    for p in a:
        assert spec.stroke_mm_range[0] <= p.stroke_mm <= spec.stroke_mm_range[1]
        assert spec.tremor_hz_range[0] <= p.tremor_hz <= spec.tremor_hz_range[1]
        assert spec.direction_bias_deg_range[0] <= p.direction_bias_deg <= spec.direction_bias_deg_range[1]


def test_sample_scatter_has_the_spec_variability():
    """log(stroke / typical) is normal with sigma = sqrt(log(1 + cv^2)) (a KS test on 2000 draws)."""
    from scipy import stats

    spec = ia.InteractionSpec(variability=0.2)
    person = ia.draw_people(1, spec, np.random.default_rng(0))[0]
    rng = np.random.default_rng(1)
    z = np.log([ia.draw_sample("push", person, spec, rng).stroke_mm / person.stroke_mm for _ in range(2000)])
    sigma = math.sqrt(math.log1p(0.04))
    assert stats.kstest(z / sigma, "norm").pvalue > 1e-3
    assert np.std(z) == pytest.approx(sigma, rel=0.08)


def test_bad_interaction_input():
    with pytest.raises(ValueError, match="is not an action"):
        ia.draw_sample("wave", ia.draw_people(1, ia.InteractionSpec(), np.random.default_rng(0))[0], ia.InteractionSpec(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="people = 0"):
        ia.draw_people(0, ia.InteractionSpec(), np.random.default_rng(0))
    with pytest.raises(ValueError, match="stroke_mm_range"):
        ia.InteractionSpec(stroke_mm_range=(1.0, 0.5))
