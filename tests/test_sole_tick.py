"""The compiled 250 Hz estimators (other_sensors/sole/tick.py) give the reference formulas' numbers
(other_sensors/sole/estimators.py, feasibility.py; SPEC 4) on random loads, tick by tick, over a
recording at once, and in double support."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.sole import estimators as est
from other_sensors.sole.cells import sole_layout
from other_sensors.sole.contact import FootPose, height_for_load, sole_contact
from other_sensors.sole.feasibility import assess_step, skin_rule
from other_sensors.sole.terrain import Box, Flat, Sphere
from other_sensors.sole.tick import SkinEstimator, double_support, estimate_series

LAYOUT = sole_layout()
EPS_F, RANGE = 0.15 * est.G, 0.01


class _Contact:  # the fields assess_step reads
    def __init__(self, forces, gaps, wrench):
        self.sensor_forces, self.cell_forces, self.gaps, self.wrench = forces, forces.sum(axis=1), gaps, wrench
        self.ankle_moment = float(np.hypot(wrench[3], wrench[4]))


def _random_tick(rng):
    """Forces on a random patch of cells (some under eps_F), gaps, a wrench with M_s around eps_t."""
    forces = rng.uniform(0.0, 8.0, (42, 3)) * (rng.uniform(size=(42, 1)) < rng.uniform(0.05, 1.0))
    gaps = rng.uniform(0.0, 0.02, 42) * (rng.uniform(size=42) < 0.7)
    wrench = np.concatenate([[0.0, 0.0, forces.sum()], rng.normal(0.0, 6.0, 2), [0.0]])
    return forces, gaps, wrench


def _same_polygon(a, b):
    assert a.shape == b.shape
    if len(a):  # the same vertices, counter-clockwise from the same one (both chains start at the least x, y)
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-15)


def test_one_tick_equals_the_reference_on_random_loads():
    rng = np.random.default_rng(21)
    fast = SkinEstimator(LAYOUT, EPS_F, RANGE)
    decisions = set()
    for _ in range(300):
        forces, gaps, wrench = _random_tick(rng)
        ref, got = assess_step(LAYOUT, _Contact(forces, gaps, wrench), EPS_F, proximity_range_m=RANGE), fast(forces, gaps, wrench)
        np.testing.assert_array_equal(got.active, ref.active)
        assert (got.ft_replan, got.skin_replan) == (ref.ft_replan, ref.skin_replan)
        decisions.add((got.ft_replan, got.skin_replan))
        _same_polygon(got.polygon, ref.polygon)
        _same_polygon(got.pretouch, ref.pretouch)
        assert got.polygon_area == pytest.approx(ref.polygon_area, rel=1e-12, abs=1e-18)
        assert got.pretouch_area == pytest.approx(est.polygon_area(ref.pretouch), rel=1e-12, abs=1e-18)
        assert got.contact_area == ref.contact_area and got.ankle_moment == ref.ankle_moment
        np.testing.assert_allclose(got.cop, ref.cop, rtol=1e-12, atol=1e-16)
        np.testing.assert_allclose(got.cop_cells, ref.cop_cells, rtol=1e-12, atol=1e-16)
        assert got.force_n == pytest.approx(forces.sum(), rel=1e-13)
        expected_step = est.sidestep(ref.polygon, 0.03) if (ref.ft_replan or ref.skin_replan) else 0.0
        assert got.sidestep == pytest.approx(expected_step, rel=1e-12, abs=1e-15)
    assert len(decisions) == 4  # the loads reached every combination of the two rules
    # an A_p / A_s tie with eps_A (here 20 cells' hull: exactly 0.8 of the sole) re-plans on both paths, whatever the round-off
    assert skin_rule(0.8 * (1 + 1e-13), 1.0) and not skin_rule(0.8 * (1 + 1e-6), 1.0)
    # no contact: NaN CoP, no polygon, no area, both rules as the reference (the skin rule re-plans)
    none = fast(np.zeros((42, 3)), np.full(42, np.inf), np.zeros(6))
    assert np.isnan(none.cop).all() and len(none.polygon) == 0 and none.polygon_area == 0.0 and none.skin_replan
    with pytest.raises(ValueError, match="shape"):
        fast(np.zeros((41, 3)), np.zeros(41), np.zeros(6))


def test_a_recording_at_once_equals_tick_by_tick():
    rng = np.random.default_rng(3)
    fast = SkinEstimator(LAYOUT, EPS_F, RANGE)
    ticks = [_random_tick(rng) for _ in range(60)]
    series = estimate_series(fast, *(np.stack(a) for a in zip(*ticks)))
    for t, tick in enumerate(ticks):
        one = fast(*tick)
        np.testing.assert_array_equal(series.active[t], one.active)
        np.testing.assert_array_equal(series.polygons[t, :series.polygon_count[t]], one.polygon)
        assert (series.polygon_area[t], series.pretouch_area[t], series.sidestep[t]) == (one.polygon_area, one.pretouch_area, one.sidestep)
        assert (series.ft_replan[t], series.skin_replan[t]) == (one.ft_replan, one.skin_replan)
        np.testing.assert_array_equal(series.cop[t], one.cop)
    with pytest.raises(ValueError, match="expected"):
        estimate_series(fast, np.zeros((5, 42, 3)), np.zeros((5, 41)), np.zeros((5, 6)))


def test_double_support_equals_the_reference_hull_and_combined_cop():
    fast = SkinEstimator(LAYOUT, EPS_F, RANGE)
    rng = np.random.default_rng(8)
    poses = [FootPose((0.02, 0.11, 0.0), yaw=0.2, pitch=0.03), FootPose((-0.05, -0.1, 0.01), yaw=-0.4, roll=-0.02)]
    for _ in range(100):
        ticks = [_random_tick(rng), _random_tick(rng)]
        est_l, est_r = (fast(*t) for t in ticks)
        hull, cop = double_support(est_l, poses[0], est_r, poses[1])
        actives = [est.active_cells(t[0].sum(axis=1), EPS_F) for t in ticks]
        ref = est.double_support_polygon(LAYOUT.corners, actives[0], poses[0], LAYOUT.corners, actives[1], poses[1])
        assert len(hull) == len(ref)
        np.testing.assert_allclose(hull, ref, rtol=0, atol=1e-14)  # rotations by another route: round-off
        assert est.polygon_area(hull) == pytest.approx(est.polygon_area(ref), rel=1e-12)
        cops = [p.to_world(est.sole_cop(LAYOUT, t[0]))[:2] for p, t in zip(poses, ticks)]
        np.testing.assert_allclose(cop, est.combined_cop(cops, [t[0].sum() for t in ticks]), rtol=1e-12, atol=1e-15)


def test_on_real_contacts_the_fast_path_reads_the_obstacles_as_the_reference():
    fast = SkinEstimator(LAYOUT, EPS_F, RANGE)
    for terrain in ([Flat(0.0), Box((0.0, 0.0), (0.04, 0.04), 0.02)], [Flat(0.0), Sphere((0.07, 0.04, 0.0), 0.02)]):
        pose = FootPose((0.0, 0.0, 0.0))
        c = sole_contact(LAYOUT, pose.with_height(height_for_load(LAYOUT, pose, terrain, 1e8, 250.0)), terrain, 1e8)
        ref, got = assess_step(LAYOUT, c, EPS_F, proximity_range_m=RANGE), fast(c.sensor_forces, c.gaps, c.wrench)
        assert got.skin_replan and ref.skin_replan and got.polygon_area == pytest.approx(ref.polygon_area, rel=1e-12)
        np.testing.assert_allclose(got.cop, [-c.wrench[4] / c.wrench[2], c.wrench[3] / c.wrench[2]], rtol=1e-9, atol=1e-12)
