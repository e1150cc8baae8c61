"""The plantar sole (issue 21, SPEC 4): cell layout, Winkler contact against analytic values, the
skin's estimators, the step-feasibility rules on the four obstacles, and the kind through ``mlsim run``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import other_sensors.sole.kind  # noqa: F401  (registers the plantar_sole kind)
from mlsim.cli import main
from mlsim.scene import SceneError, load_scene
from other_sensors.sole import estimators as est
from other_sensors.sole.cells import cell_quadrature, hexagon_side, sole_layout
from other_sensors.sole.contact import FootPose, barycentric_weights, height_for_load, sole_contact
from other_sensors.sole.feasibility import ft_rule, skin_rule
from other_sensors.sole.stages import assessment_of, contact_of_scene
from other_sensors.sole.terrain import Box, Flat, HeightField, Sphere, Step, terrain_height

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes" / "sole"
K = 1.0e8  # N/m^3
LAYOUT = sole_layout()


# ------------------------------------------------------------------------------------------ cells
def test_the_default_sole_has_42_cells_of_6_9_cm2_with_three_sensors_inside_each():
    assert LAYOUT.n_cells == 42 and LAYOUT.cell_area == pytest.approx(6.9e-4, rel=1e-12)
    assert 1.5 * np.sqrt(3) * hexagon_side(6.9e-4) ** 2 == pytest.approx(6.9e-4)
    np.testing.assert_allclose(LAYOUT.centres.mean(axis=0), 0.0, atol=1e-15)  # the ankle over the cells' centroid
    assert LAYOUT.corners.shape == (42, 6, 2) and LAYOUT.sensors.shape == (42, 3, 2)
    # neighbouring hexagons share edges: the closest centres are sqrt(3) s apart, never closer
    d = np.linalg.norm(LAYOUT.centres[:, None] - LAYOUT.centres[None], axis=-1) + np.eye(42)
    assert d.min() == pytest.approx(np.sqrt(3) * LAYOUT.side, rel=1e-12)
    # the three sensors sit inside their hexagon, around its centre
    r = np.linalg.norm(LAYOUT.sensors - LAYOUT.centres[:, None], axis=-1)
    assert r.max() < np.sqrt(3) / 2 * LAYOUT.side
    np.testing.assert_allclose(LAYOUT.sensors.mean(axis=1), LAYOUT.centres, atol=1e-15)
    points, weights = cell_quadrature(LAYOUT.side, 4)
    assert weights.sum() == pytest.approx(LAYOUT.cell_area) and np.abs(points.mean(axis=0)).max() < 1e-15
    with pytest.raises(ValueError, match="parity"):
        sole_layout((4, 4))


def test_barycentric_split_keeps_force_and_moment():
    tri = LAYOUT.sensors[0] - LAYOUT.centres[0]
    pts = np.random.default_rng(1).uniform(-0.01, 0.01, (50, 2))
    w = barycentric_weights(pts, tri)
    np.testing.assert_allclose(w.sum(axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(w @ tri, pts, atol=1e-15)


# ------------------------------------------------------------------------------------- terrain
def test_terrain_primitives_give_their_heights():
    xy = np.array([[0.0, 0.0], [0.05, 0.0], [0.3, 0.0]])
    np.testing.assert_allclose(terrain_height([Flat(0.01)], xy), 0.01)
    np.testing.assert_allclose(terrain_height([Box((0, 0), (0.2, 0.1), 0.02)], xy), [0.02, 0.02, -np.inf])
    np.testing.assert_allclose(terrain_height([Sphere((0, 0, 0), 0.1)], xy), [0.1, np.sqrt(0.01 - 0.0025), -np.inf])
    np.testing.assert_allclose(terrain_height([Step((0.04, 0), 0.0, 0.03)], xy), [-np.inf, 0.03, 0.03])
    field = HeightField((0.0, -0.1), 0.1, np.array([[0.0, 0.1], [0.0, 0.1], [0.0, 0.1]]))  # a ramp along x
    np.testing.assert_allclose(terrain_height([field], xy[:2]), [0.0, 0.05])
    np.testing.assert_allclose(terrain_height([Flat(0.0), Box((0, 0), (0.2, 0.1), 0.02)], xy), [0.02, 0.02, 0.0])


# ---------------------------------------------------------------------------------------- CoP
def test_cop_of_a_uniform_and_of_a_ramp_load_is_the_analytic_centre():
    pts = LAYOUT.centres
    np.testing.assert_allclose(est.centre_of_pressure(pts, np.full(42, 3.0)), pts.mean(axis=0), atol=1e-15)
    a, b = 10.0, 40.0  # N, N/m: F_j = a + b x_j
    f = a + b * pts[:, 0]
    # the centres' sums are 0 (origin at their centroid) and the layout is symmetric in y:
    # CoP = (b sum x^2 / (N a), 0)
    expected = np.array([b * (pts[:, 0] ** 2).sum() / (42 * a), 0.0])
    np.testing.assert_allclose(est.centre_of_pressure(pts, f), expected, rtol=1e-12, atol=1e-15)
    assert np.isnan(est.centre_of_pressure(pts, np.zeros(42))).all()
    with pytest.raises(ValueError, match="points"):
        est.centre_of_pressure(pts, np.ones(3))
    with pytest.raises(ValueError, match="sensor, cell"):
        est.sole_cop(LAYOUT, np.ones((42, 3)), by="taxel")


# ------------------------------------------------------------------------------------- Winkler
def test_winkler_force_on_flat_ground_is_k_d_a():
    d = 0.4e-3
    c = sole_contact(LAYOUT, FootPose((0.1, -0.2, -d), yaw=0.7), [Flat(0.0)], K)
    area = 42 * LAYOUT.cell_area
    assert c.wrench[2] == pytest.approx(K * d * area, rel=1e-12) and c.cell_forces.sum() == pytest.approx(K * d * area, rel=1e-12)
    np.testing.assert_allclose(c.cell_forces, K * d * LAYOUT.cell_area, rtol=1e-12)  # uniform
    assert c.ankle_moment < 1e-9 * K * d * area
    # lowered until it carries a load: the sink is load / (k A)
    z = height_for_load(LAYOUT, FootPose((0, 0, 0.5)), [Flat(0.0)], K, 844.0)
    assert -z == pytest.approx(844.0 / (K * area), rel=1e-9)


@pytest.mark.parametrize("axis", ["pitch", "roll"])
def test_tilt_moves_the_cop_the_analytic_way(axis):
    d0, angle = 0.5e-3, np.radians(0.15)  # small enough that the whole sole stays in contact
    pose = FootPose((0, 0, -d0), **{axis: angle})
    c = sole_contact(LAYOUT, pose, [Flat(0.0)], K, subdivisions=8)
    # depth d0 + x sin(pitch) or d0 - y sin(roll): CoP = sin(angle) I / (d0 A), I the sole's second moment of area
    i_hex = 5 * np.sqrt(3) / 16 * LAYOUT.side**4  # a regular hexagon's, about any centroidal axis
    coord = LAYOUT.centres[:, 0] if axis == "pitch" else LAYOUT.centres[:, 1]
    inertia = LAYOUT.cell_area * (coord**2).sum() + 42 * i_hex
    area = 42 * LAYOUT.cell_area
    expected = np.sin(angle) * inertia / (d0 * area) * (1 if axis == "pitch" else -1)
    cop = est.sole_cop(LAYOUT, c.sensor_forces)
    k = 0 if axis == "pitch" else 1
    assert c.cell_forces.min() > 0
    assert cop[k] == pytest.approx(expected, rel=2e-3) and abs(cop[1 - k]) < 1e-12
    assert c.wrench[2] == pytest.approx(K * d0 * area, rel=1e-9)  # a tilt about the centroid keeps the force


def test_ankle_moment_equals_the_moment_of_the_cell_sensors():
    terrain = [Flat(0.0), Box((0.06, 0.03), (0.05, 0.07), 0.015, 0.3), Sphere((-0.07, -0.02, 0.0), 0.018)]
    pose = FootPose((0.005, -0.004, 0.0), roll=np.radians(2.0), pitch=np.radians(-3.0), yaw=np.radians(10))
    z = height_for_load(LAYOUT, pose, terrain, K, 300.0)
    c = sole_contact(LAYOUT, pose.with_height(z), terrain, K)
    f, s = c.sensor_forces, LAYOUT.sensors
    assert f.sum() == pytest.approx(300.0, rel=1e-8) == c.wrench[2]
    np.testing.assert_allclose([(s[..., 1] * f).sum(), -(s[..., 0] * f).sum()], c.wrench[3:5], rtol=1e-10)
    np.testing.assert_allclose(est.sole_cop(LAYOUT, f), [-c.wrench[4] / c.wrench[2], c.wrench[3] / c.wrench[2]], rtol=1e-10)


# ------------------------------------------------------------------------------------- polygons
def test_full_flat_contact_polygon_is_the_sole_outline_and_area_counts_cells():
    c = sole_contact(LAYOUT, FootPose((0, 0, -0.3e-3)), [Flat(0.0)], K)
    active = est.active_cells(c.cell_forces, 0.15 * est.G)
    assert active.all()
    poly = est.support_polygon(LAYOUT.corners, active)
    outline = LAYOUT.outline()
    assert {tuple(np.round(p, 12)) for p in poly} == {tuple(np.round(p, 12)) for p in outline}
    assert est.polygon_area(poly) == pytest.approx(LAYOUT.sole_area(), rel=1e-12)
    assert est.contact_area(active, LAYOUT.cell_area) == pytest.approx(42 * 6.9e-4)
    assert est.contact_area(active[:10] & False, LAYOUT.cell_area) == 0.0
    assert len(est.support_polygon(LAYOUT.corners, np.zeros(42, bool))) == 0
    # hovering 5 mm over the floor: no force, and the whole sole in pre-touch
    hover = sole_contact(LAYOUT, FootPose((0, 0, 0.005)), [Flat(0.0)], K)
    assert hover.cell_forces.max() == 0.0
    np.testing.assert_allclose(hover.gaps, 0.005, rtol=1e-12)
    assert est.polygon_area(est.pretouch_polygon(LAYOUT.corners, hover.gaps, 0.01)) == pytest.approx(LAYOUT.sole_area())
    assert len(est.pretouch_polygon(LAYOUT.corners, hover.gaps, 0.004)) == 0


def test_double_support_hull_of_a_known_stance():
    # both soles flat, side by side 0.2 m apart: hull = sole + a band of the sole's length times 0.2 m
    left, right = FootPose((0.0, 0.1, 0.0)), FootPose((0.0, -0.1, 0.0))
    on = np.ones(42, bool)
    hull = est.double_support_polygon(LAYOUT.corners, on, left, LAYOUT.corners, on, right)
    xs = LAYOUT.corners[..., 0]
    assert est.polygon_area(hull) == pytest.approx(LAYOUT.sole_area() + 0.2 * (xs.max() - xs.min()), rel=1e-12)
    # one sole turned by 90 deg about its origin: the hull holds both soles' corners in the world
    turned = FootPose((0.0, -0.3, 0.0), yaw=np.pi / 2)
    hull = est.double_support_polygon(LAYOUT.corners, on, left, LAYOUT.corners, on, turned)
    world = turned.to_world(LAYOUT.corners.reshape(-1, 2))[:, :2]
    assert hull[:, 1].min() == pytest.approx(world[:, 1].min()) and hull[:, 1].max() == pytest.approx(0.1 + LAYOUT.corners[..., 1].max())
    # the combined CoP weighs each sole's CoP by its force
    np.testing.assert_allclose(est.combined_cop([[0, 0.1], [0, -0.1]], [300.0, 100.0]), [0, 0.05])
    np.testing.assert_allclose(est.combined_cop([[0, 0.1], [np.nan, np.nan]], [300.0, 0.0]), [0, 0.1])


# ---------------------------------------------------------------------------------- feasibility
def test_the_rules_and_their_thresholds():
    assert ft_rule(8.0) and not ft_rule(7.99)
    assert skin_rule(0.8, 1.0) and not skin_rule(0.81, 1.0)
    with pytest.raises(ValueError, match="sole area"):
        skin_rule(0.1, 0.0)
    square = np.array([[0.0, 0.02], [0.04, 0.02], [0.04, 0.07], [0.0, 0.07]])  # 5 cm wide, left of centre
    assert est.sidestep(square, 0.03) == pytest.approx(-0.08)
    assert est.sidestep(square * [1, -1], 0.03) == pytest.approx(0.08)
    assert est.sidestep(np.zeros((0, 2)), 0.03) == 0.0


def _cells_over_box(centre, half):
    """The cells whose hexagon meets the square box of ``centre`` (2,) m and half-size ``half`` m:
    only they can touch it, so their hull bounds the support polygon."""
    from matplotlib.path import Path as MplPath

    g = np.linspace(-half, half, 81)
    pts = np.column_stack([a.ravel() for a in np.meshgrid(g, g)]) + centre
    return np.array([MplPath(c).contains_points(pts).any() for c in LAYOUT.corners])


@pytest.mark.parametrize("name", ["large_flat", "small_flat_border", "small_flat_ankle", "three_spheres"])
def test_the_four_obstacles_decide_as_their_statics_say(name):
    """The static placements (250 N, normal pressure only): each decision derived from statics and
    the obstacle's geometry, not from the code's own output."""
    scene = load_scene(SCENES / f"{name}.toml")
    contact = contact_of_scene(scene.sensor, scene.seed)
    a = assessment_of(scene.sensor, contact)
    load = scene.sensor.foot.load_n
    if name == "large_flat":  # level on a flat top: uniform pressure over every cell
        assert a.ankle_moment < 0.05 and a.area_ratio == pytest.approx(1.0) and not (a.ft_replan or a.skin_replan)
    elif name == "three_spheres":  # three equal caps under the sole: equal forces, the CoP at the centres' mean, (20, 0) mm
        assert a.ankle_moment == pytest.approx(load * np.linalg.norm(np.mean([[70, 40], [70, -40], [-80, 0]], axis=0)) * 1e-3,
                                               rel=0.02)
        assert not a.ft_replan and a.skin_replan
    else:
        centre = np.array([0.095, 0.05]) if name == "small_flat_border" else np.zeros(2)
        low, high = centre - 0.02, centre + 0.02
        near = np.linalg.norm(np.clip(0.0, low, high))  # the box's nearest and farthest points from the ankle
        far = np.linalg.norm(np.maximum(np.abs(low), np.abs(high)))
        # the CoP lies over the box: load x near <= M_s <= load x far
        assert load * near - 0.05 <= a.ankle_moment <= load * far + 0.05
        # so under the ankle M_s <= 250 N x 28.3 mm = 7.1 N m < 8 (keep); at the border >= 250 N x 80.8 mm = 20.2 (re-plan)
        assert a.ft_replan == (name == "small_flat_border")
        bound = est.polygon_area(est.support_polygon(LAYOUT.corners, _cells_over_box(centre, 0.02)))
        assert a.polygon_area <= bound * (1 + 1e-9) and bound / a.sole_area < 0.8 and a.skin_replan
    # the F/T moment is the load times the CoP's lever arm; the skin CoP agrees with the F/T ZMP to 1 mm
    assert contact.wrench[2] == pytest.approx(scene.sensor.foot.load_n, rel=1e-8)
    assert a.ankle_moment == pytest.approx(contact.wrench[2] * np.linalg.norm(a.cop_ft), rel=1e-9, abs=1e-9)
    assert np.linalg.norm(a.cop - a.cop_ft) < 1e-3
    assert a.contact_area == pytest.approx(a.active.sum() * 6.9e-4)
    assert (a.sidestep_skin != 0.0) == a.skin_replan and (a.sidestep_ft != 0.0) == a.ft_replan
    if a.skin_replan:  # the sidestep clears the polygon's width plus the clearance, away from it
        low, high = est.bounding_box(a.polygon)
        assert abs(a.sidestep_skin) == pytest.approx(high[1] - low[1] + 0.03)
    # pre-touch: the cells whose face comes within the proximity range (10 mm) of the terrain; every
    # touching cell sees what it touches, so the pre-touch polygon holds the support polygon
    near = contact.gaps < 0.01
    assert est.polygon_area(a.pretouch) == pytest.approx(est.polygon_area(est.support_polygon(LAYOUT.corners, near)))
    assert np.all(near[a.active]) and est.polygon_area(a.pretouch) >= est.polygon_area(a.polygon) * (1 - 1e-12)
    if name == "large_flat":
        assert near.all() and est.polygon_area(a.pretouch) == pytest.approx(a.sole_area)


def test_the_same_seed_gives_the_same_readings_and_another_seed_other_noise():
    scene = load_scene(SCENES / "small_flat_ankle.toml")
    one, two = contact_of_scene(scene.sensor, 3), contact_of_scene(scene.sensor, 3)
    np.testing.assert_array_equal(one.sensor_forces, two.sensor_forces)
    other = contact_of_scene(scene.sensor, 4)
    assert not np.array_equal(one.sensor_forces, other.sensor_forces)
    noise = (one.sensor_forces - other.sensor_forces).ravel() / np.sqrt(2)
    assert 0.015 < noise.std() < 0.025  # 0.02 N per sensor


# ----------------------------------------------------------------------------------- the kind
def test_bad_sole_scenes_are_refused_naming_the_field(tmp_path):
    base = (SCENES / "large_flat.toml").read_text()
    cases = {
        "load_n = 250.0": ("load_n = 250.0\nweight_kg = 3", "sensor.foot.weight_kg"),
        'shape = "box"': ('shape = "cone"', "sensor.terrain.primitives"),
        "top_mm = 20.0": ("top_mm = 20.0\n\n[sensor.cells]\nrow_counts = [4, 6]", "sensor.cells.row_counts"),
    }
    for old, (new, field) in cases.items():
        path = tmp_path / "bad.toml"
        path.write_text(base.replace(old, new, 1))
        with pytest.raises(SceneError, match=field.replace(".", r"\.")):
            load_scene(path)
    path.write_text(base.replace("load_n = 250.0", "load_n = -5.0"))
    with pytest.raises(SceneError, match="sensor.foot.load_n"):
        load_scene(path)


def test_the_kind_runs_through_mlsim_run_and_loads_from_the_cache(tmp_path):
    scene_file, out, cache = SCENES / "small_flat_ankle.toml", tmp_path / "out", tmp_path / "cache"
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    for name in ("sole_feasibility.csv", "sole_feasibility.json", "sole_feasibility.png"):
        assert (out / name).stat().st_size > 0
    result = json.loads((out / "sole_feasibility.json").read_text())
    assert result["ft_replan"] is False and result["skin_replan"] is True
    # the cells over the 40 mm box round the ankle bound the polygon; the CoP over the box bounds M_s (250 N x 28.3 mm)
    bound = est.polygon_area(est.support_polygon(LAYOUT.corners, _cells_over_box(np.zeros(2), 0.02)))
    assert result["area_ratio"] <= bound / LAYOUT.sole_area() + 1e-9 and result["active_cells"] >= 4
    summary = json.loads((out / "summary.json").read_text())["stages"]
    assert summary["sole_feasibility"]["action"] == "run" and summary["sole_contact"]["action"] == "run"
    assert summary["sole_feasibility"]["summary"]["ankle_moment_nm"] <= 250.0 * np.hypot(0.02, 0.02)
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    again = json.loads((out / "summary.json").read_text())["stages"]
    assert list(again) == ["sole_feasibility"] and again["sole_feasibility"]["action"] == "load"
    assert again["sole_feasibility"]["key"] == summary["sole_feasibility"]["key"]


# ------------------------------------------------------------------------------------- balance
def test_a_rigid_plate_on_the_winkler_layer_carries_the_force_at_the_asked_cop():
    from other_sensors.sole.balance import plate_depths
    from other_sensors.sole.contact import cell_sampling

    s = cell_sampling(LAYOUT, 3)
    pts, w = s.points.reshape(-1, 2), np.tile(s.weights, 42)
    for cop, lifts in (([0.01, -0.005], False), ([0.085, 0.03], True)):
        d = plate_depths(pts, w, K, 844.0, np.array(cop))
        f = K * d * w
        assert f.sum() == pytest.approx(844.0, rel=1e-9)
        np.testing.assert_allclose(f @ pts / f.sum(), cop, atol=1e-9)
        assert (d == 0).any() == lifts  # far from the middle, the heel lifts off
    # no lift-off: the plane is the linear solution d = F/(kA) + a x + b y with a = c_x F/(k I_xx), ...
    d = plate_depths(pts, w, K, 844.0, np.array([0.01, 0.0]))
    slope = np.polyfit(pts[:, 0], d, 1)[0]
    assert slope == pytest.approx(0.01 * 844.0 / (K * (w * pts[:, 0] ** 2).sum()), rel=1e-9)


def test_the_cp_zmp_regulator_recovers_from_a_push_and_the_skin_zmp_follows_the_ft_zmp(tmp_path):
    scene_file, out = SCENES / "balance_push.toml", tmp_path / "out"
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(tmp_path / "cache"), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())["stages"]["sole_balance"]["summary"]
    # SPEC 4's reference: skin ZMP within about 1 cm of the F/T ZMP while pushes moved it up to 10 cm
    assert 50.0 < summary["zmp_excursion_mm"] < 100.0 and summary["skin_ft_zmp_gap_mm"] < 10.0
    assert abs(summary["final_com_mm"][0]) < 1.0 and summary["max_com_mm"] < 20.0  # back over the ankle
    rows = np.loadtxt(out / "sole_balance.csv", delimiter=",", skiprows=1)
    assert rows.shape == (1000, 12) and (out / "sole_balance.png").stat().st_size > 0
    # fed by the F/T's ZMP instead, the loop behaves the same to within the skin's few millimetres
    from other_sensors.sole.balance import simulate_balance

    scene = load_scene(scene_file)
    ft = simulate_balance(LAYOUT, scene.sensor.balance.model_copy(update={"zmp_source": "ft"}), K, np.random.default_rng(0))
    np.testing.assert_allclose(ft.com[:, 0], rows[:, 2], atol=1e-3)


def test_the_compiled_hull_is_qhulls():
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(5)
    for points in (rng.normal(size=(200, 2)), LAYOUT.corners.reshape(-1, 2), np.round(rng.uniform(size=(60, 2)), 1)):
        hull = est.convex_hull(points)
        ref = points[ConvexHull(points).vertices]
        assert {tuple(v) for v in hull} == {tuple(v) for v in ref}
        assert est.polygon_area(hull) == pytest.approx(ConvexHull(points).volume, rel=1e-12)
    assert len(est.convex_hull(np.array([[0.0, 0.0], [1.0, 1.0], [2.0, 2.0], [1.0, 1.0]]))) == 0  # on a line
    assert len(est.convex_hull(np.zeros((2, 2)))) == 0
