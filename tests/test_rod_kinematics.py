"""Second-order rod kinematics of the linear tiers (fem.rod_kinematics): the cantilever's tip drop,
q's quadratic scaling, the P-delta load, the field's correction, the option's plumbing, and the tiny
scene's slide against the nonlinear tier."""

from __future__ import annotations

import numpy as np
import pytest

from fem import condensed, contact_admm
from fem import quasistatic as qs
from fem import rod_kinematics as rk


@pytest.fixture(scope="module")
def body(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    lame, rho, _ = qs.layer_materials(scene)
    return qs.LinearBody(mesh, lame, rho, "P2P1", gravity=False)


@pytest.fixture(scope="module")
def rod0_tip(tiny_mesh, body):
    """Rod 0's tip-face contact points, its sections and their kinematics (no gravity), and a lateral
    tip load of 0.05 N along x spread by area."""
    scene, _, mesh, _ = tiny_mesh
    tip_z = qs.tip_height_m(mesh)
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, 2e-3))
    points = points.subset(np.flatnonzero((points.rod == 0) & (points.X[:, 2] >= tip_z - 1e-9)))
    sections = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], scene.sensor.base.thickness_mm * 1e-3, tip_z)
    O = qs._on_dofs(sections.O, body)
    C, A = qs.compliance(body, points.W, observe=O)
    kin = rk.RodKinematics(sections, A, np.zeros(A.shape[0]), points.X, points.rod)
    f = np.zeros((points.m, 3))
    f[:, 0] = 0.05 * points.area_m2 / points.area_m2.sum()
    return kin, points, C, f


def test_a_bent_rods_tip_drops_by_the_cantilevers_second_order_result(rod0_tip):
    kin, _, _, f = rod0_tip
    sec = kin.sections
    theta, tip_h = kin.observe(f)
    drop = rk.axis_drop(theta[:, :-1], sec.dz)[0]
    # the tip centre (r = 0) drops by the axis' shortening alone
    centre_q = rk.second_order_points(theta, sec, sec.centre[:1], np.array([0]))
    np.testing.assert_allclose(centre_q[0], [0.0, 0.0, -drop], atol=1e-15)
    # Euler-Bernoulli cantilever under a tip load: shortening (3/5) d^2 / L, with d the deflection the
    # sections' rotations make (int theta dz). The rod is stubby (L / D = 1.8): 9 % of its tip
    # deflection is shear, which turns no section, so against the whole deflection the drop is lower.
    d_bend = float(np.sum(theta[0, :-1, 1] * sec.dz))
    d_tip = float(tip_h[0, 0])
    assert 0.3e-3 < d_bend < d_tip  # about 0.32 of 0.35 mm at 0.05 N
    assert drop == pytest.approx(0.6 * d_bend**2 / sec.length_m, rel=0.10)
    assert 0.7 < drop / (0.6 * d_tip**2 / sec.length_m) < 0.9
    # the tip face tilts the way it is pushed: about +y for a push along +x
    assert theta[0, -1, 1] > 0.5 * d_tip / sec.length_m


def test_q_vanishes_without_force_and_is_quadratic_in_it(rod0_tip):
    kin, points, _, f = rod0_tip
    np.testing.assert_array_equal(kin.q(np.zeros_like(f)), 0.0)
    q1, q2 = kin.q(f), kin.q(2.5 * f)
    assert np.abs(q1).max() > 1e-6  # a few um at 0.05 N
    np.testing.assert_allclose(q2, 6.25 * q1, rtol=1e-10, atol=1e-18)
    # a lateral push drops every tip point (the axis' shortening outweighs the face's tilt at this load)
    assert np.all(q1[:, 2] < 0)


def test_the_pdelta_load_is_the_axial_force_times_the_tip_offset_over_the_height():
    f = np.array([[0.0, 0.0, -0.3], [0.0, 0.0, -0.1], [0.0, 0.0, 0.2], [1.0, 0.0, -0.5]])
    rod = np.array([0, 0, 1, -1])
    tip_h = np.array([[1e-4, -2e-4], [3e-4, 0.0]])
    load = rk.pdelta_load(f, tip_h, rod, 9e-3)
    # rod 0: F_z = -0.4 N, load 0.4 x (1e-4, -2e-4) / 9e-3, shared 3:1; rod 1 is pulled (no load); base: none
    total = 0.4 * np.array([1e-4, -2e-4]) / 9e-3
    np.testing.assert_allclose(load[0, :2], 0.75 * total, rtol=1e-12)
    np.testing.assert_allclose(load[1, :2], 0.25 * total, rtol=1e-12)
    np.testing.assert_array_equal(load[2:], 0.0)
    np.testing.assert_array_equal(load[:, 2], 0.0)


def test_the_first_order_force_error_estimate_of_a_tilted_compressed_rod(tiny_mesh):
    """fem.rod_kinematics.first_order_force_error on a field it must read exactly: rod 0 compressed by
    c and tilted rigidly by phi about its base centre (a linear field: every section turns by phi, the
    tip face's mean vertical displacement is -c). The missed drop is 1/2 phi^2 (L + a), so the force
    error is F_z 1/2 phi^2 (L + a) / c; the estimate's norm is that over the rod's force; a rod with no
    force, or a step with no tilt, adds nothing; weights count steps as frames."""
    scene, _, mesh, _ = tiny_mesh
    base_z, tip_z = scene.sensor.base.thickness_mm * 1e-3, qs.tip_height_m(mesh)
    sec = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0, 1], base_z, tip_z)
    L, a = sec.length_m, 2.5e-3
    phi, c = 0.03, 0.4e-3
    base_centre = np.array([*sec.centre[0, :2], base_z])
    du = np.zeros((2, mesh.n_points, 3))
    on_rod = np.zeros(mesh.n_points, bool)
    on_rod[sec.vertices[0]] = True
    r = mesh.points[on_rod] - base_centre
    w = np.array([phi, 0.0, 0.0])  # a small rotation about x: u = w x r (linear in the vertices)
    du[0, on_rod] = np.cross(w, r)
    du[0, on_rod, 2] -= c * (mesh.points[on_rod, 2] - base_z) / L  # a uniform axial strain, -c at the tip
    du[1, on_rod, 2] = -c * (mesh.points[on_rod, 2] - base_z) / L  # step 1: the same compression, no tilt
    F = np.zeros((2, int(mesh.tet_rod.max()) + 1, 3))
    F[:, 0] = [0.2, 0.0, -3.0]  # rod 0 pressed with 3 N (and a little shear)
    theta, _ = sec.split(sec.O @ du[0].ravel())
    np.testing.assert_allclose(theta[0], np.tile(w, (sec.n_slabs + 1, 1)), atol=1e-9)
    expected_dF = 3.0 * 0.5 * phi**2 * (L + a) / c
    norm_F = np.hypot(0.2, 3.0)
    assert rk.first_order_force_error(sec, mesh.points, du[:1], F[:1], a) == pytest.approx(expected_dF / norm_F, rel=1e-6)
    # the untilted step adds its force to the norm and no error; weights are frames per step
    both = rk.first_order_force_error(sec, mesh.points, du, F, a, weights=np.array([1.0, 3.0]))
    assert both == pytest.approx(expected_dF / (norm_F * 2.0), rel=1e-6)
    assert rk.first_order_force_error(sec, mesh.points, du, np.zeros_like(F), a) == 0.0


def _first_order_force_error_per_step(sections, points, du, rod_force_n, radius_m, weights):
    """first_order_force_error as it was before issue 40 (each step's tip means one by one): the reference."""
    du, F, w_u = np.asarray(du, dtype=float), np.asarray(rod_force_n, dtype=float), np.asarray(weights, dtype=float)
    tip_z = sections.base_z_m + sections.length_m
    tops = [v[points[v, 2] >= tip_z - 1e-9] for v in sections.vertices]
    num = 0.0
    for u in range(len(du)):
        Fz = -F[u, sections.rods, 2]
        if not np.any(Fz > 0) or w_u[u] == 0:
            continue
        theta, _ = sections.split(sections.O @ du[u].ravel())
        missed = rk.axis_drop(theta[:, :-1], sections.dz) + 0.5 * (theta[:, -1, 0] ** 2 + theta[:, -1, 1] ** 2) * radius_m
        c = np.array([-du[u, t, 2].mean() for t in tops])
        dF = np.where((Fz > 0) & (c > 0), Fz * missed / np.where(c > 0, c, 1.0), 0.0)
        num += w_u[u] * float(np.sum(dF**2))
    den = float(np.einsum("u,urc->", w_u, F**2))
    return float(np.sqrt(num / den)) if den > 0 else 0.0


def test_the_first_order_force_error_is_its_per_step_form_bit_for_bit(tiny_mesh):
    """The tips' means taken over all steps at once (issue 40) give the estimate's bits."""
    scene, _, mesh, _ = tiny_mesh
    base_z, tip_z = scene.sensor.base.thickness_mm * 1e-3, qs.tip_height_m(mesh)
    n_rods = int(mesh.tet_rod.max()) + 1
    sec = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, np.arange(n_rods), base_z, tip_z)
    rng = np.random.default_rng(3)
    du = rng.standard_normal((7, mesh.n_points, 3)) * 1e-4
    F = rng.standard_normal((7, n_rods, 3))
    F[..., 2] -= 0.5  # most rods pressed
    w = rng.integers(0, 4, 7).astype(float)
    got = rk.first_order_force_error(sec, mesh.points, du, F, 1e-3, w)
    assert got > 0 and got == _first_order_force_error_per_step(sec, mesh.points, du, F, 1e-3, w)


def test_the_fields_correction_is_q_at_the_tip_face(tiny_mesh, body, rod0_tip):
    _, _, mesh, _ = tiny_mesh
    kin, points, _, f = rod0_tip
    sec = kin.sections
    x = body.solve(points.W @ f.ravel())
    U = x[body.vertex_dofs.ravel()].reshape(-1, 3)
    top = sec.vertices[0][mesh.points[sec.vertices[0], 2] >= qs.tip_height_m(mesh) - 1e-9]
    at_vertices = rk.RodKinematics(sec, np.zeros((sec.O.shape[0], 3)), sec.O @ U.ravel(), mesh.points[top], np.zeros(len(top), int))
    np.testing.assert_allclose(kin.vertex_correction(U, mesh.points)[top], at_vertices.q(np.zeros((1, 3))), rtol=1e-9, atol=1e-15)
    # off the rod nothing moves
    off = np.setdiff1d(np.arange(mesh.n_points), sec.vertices[0])
    assert np.all(kin.vertex_correction(U, mesh.points)[off] == 0.0)


def test_kinematics_that_add_nothing_leave_the_contact_step_as_it_was(tiny_mesh, body):
    """A frictionless press (a unique answer) of a sphere on rod 0: with kinematics whose q and P-delta
    vanish, solve_step's forces are the first-order ones (and first order is the scene's default)."""
    scene, _, mesh, _ = tiny_mesh
    from fem.indenters import Pose, shape_from_scene

    assert qs.SolveSettings().rod_kinematics == "first_order" == scene.fidelity.solve.rod_kinematics
    shape = shape_from_scene(scene.load.indenter)
    tip_z = qs.tip_height_m(mesh)
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, 2e-3))
    sections = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], scene.sensor.base.thickness_mm * 1e-3, tip_z)
    x, y = sections.centre[0, :2] + 1e-3  # the sphere's lowest point, 1.4 mm off rod 0's axis: it presses the tip face
    points = points.subset(np.flatnonzero(np.hypot(points.X[:, 0] - x, points.X[:, 1] - y) < 4e-3))
    C = qs.compliance(body, points.W)
    k = np.full(points.m, 5e3)
    G = contact_admm.DenseDelassus(C, k)
    nothing = rk.RodKinematics(sections, np.zeros((sections.O.shape[0], 3 * points.m)), np.zeros(sections.O.shape[0]), points.X, points.rod)
    pose_old, pose = Pose((x, y, tip_z + 1e-4), 0.0), Pose((x, y, tip_z - 3e-4), 0.0)
    out = []
    for kin in (None, nothing):
        state = condensed.PointState.zero(points.m)
        u, law, info = contact_admm.solve_step(G, np.zeros((points.m, 3)), points.X, shape, pose, pose_old, state, 0.0, k,
                                               contact_admm.WarmStart(kinematics=kin), rtol=1e-8, max_iterations=20000, f_floor_n=1e-12,
                                               max_linearisations=30)
        assert info.linearised and info.converged
        out.append(law.f)
    assert -out[0][:, 2].sum() > 0.05  # the sphere presses rod 0's tip
    # the same solution to the ADMM's accuracy (its stopping test bounds residuals, not the error: 1e-5 of the largest force)
    np.testing.assert_allclose(out[1], out[0], rtol=0, atol=1e-4 * np.abs(out[0]).max())
    np.testing.assert_allclose(out[1].sum(axis=0), out[0].sum(axis=0), rtol=0, atol=1e-5 * np.abs(out[0][:, 2]).sum())


def test_the_scene_switch_is_validated(tiny_mesh):
    scene, _, mesh, _ = tiny_mesh
    with pytest.raises(Exception, match="rod_kinematics"):
        scene.with_values({"fidelity.solve.rod_kinematics": "third_order"})
    newton = scene.with_values({"fidelity.solve.rod_kinematics": "second_order", "fidelity.solve.contact_solver": "newton"})
    assert qs.SolveSettings.from_scene(newton).rod_kinematics == "second_order"
    with pytest.raises(ValueError, match='contact_solver = "admm"'):
        qs.run_episode(newton, mesh)


@pytest.mark.slow
def test_second_order_brings_the_tiny_slide_to_the_nonlinear_tier(tiny_mesh):
    """The tiny scene's sphere slide (rods tilt 10-15 deg): first order is 40-75 % off the nonlinear
    tier, second order (rotation terms and P-delta) about 7-11 % (measured: base von Mises 7.4 %,
    per-rod force 11 %, tip displacement 7.1 %; first order 43 %, 76 %, 40 %). The nonlinear tier
    takes about 45 s."""
    from mlsim.studies.accuracy import relative_error, rod_measures

    scene, _, mesh, _ = tiny_mesh
    base = scene.sensor.base.thickness_mm * 1e-3
    ref = rod_measures(qs.run_episode(scene.with_values({"fidelity.solve.tier": "nonlinear"}), mesh), base)
    err = {}
    for kinematics in ("first_order", "second_order"):
        ep = qs.run_episode(scene.with_values({"fidelity.solve.rod_kinematics": kinematics}), mesh)
        m = rod_measures(ep, base)
        err[kinematics] = {k: relative_error(m[k], ref[k]) for k in m}
    assert err["first_order"]["rod_contact_force"] > 0.5
    assert err["second_order"]["rod_base_von_mises"] < 0.10
    assert err["second_order"]["rod_contact_force"] < 0.15
    assert err["second_order"]["tip_displacement"] < 0.10


def test_sections_take_fewer_slabs_where_the_mesh_is_too_coarse(tiny_mesh):
    """A short stretch of rod on the tiny mesh's 2.5 mm edges cannot hold 8 slabs of 3 vertices: the
    default count falls back to the most that it can (a 6 mm rod on the 2 mm default mesh did this in a
    height sweep), an explicit count keeps the error."""
    scene, _, mesh, _ = tiny_mesh
    base_z = scene.sensor.base.thickness_mm * 1e-3
    short_tip = base_z + 2.0e-3
    with pytest.raises(rk.ThinSlabError, match="use fewer slabs"):
        rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], base_z, short_tip, n_slabs=rk.N_SLABS)
    sec = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], base_z, short_tip)
    assert 1 <= sec.n_slabs < rk.N_SLABS
    assert sec.dz.sum() == pytest.approx(2.0e-3)
    full = rk.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, [0], base_z, qs.tip_height_m(mesh))
    assert full.n_slabs == rk.N_SLABS  # where 8 fit, nothing changes


def test_tips_nanometres_apart_are_one_tip_face(tiny_mesh):
    """The snapped tip vertices of one rod 1.3 nm above the others' (seen on a 6 mm rod's mesh): every
    rod keeps its tip face."""
    scene, _, mesh, _ = tiny_mesh
    base_z, tip_z = scene.sensor.base.thickness_mm * 1e-3, qs.tip_height_m(mesh)
    points = mesh.points.copy()
    on_tip_1 = np.isin(np.arange(len(points)), mesh.tets[mesh.tet_rod == 1]) & (points[:, 2] >= tip_z - 1e-9)
    points[on_tip_1, 2] += 1.3e-9
    sec = rk.rod_sections(points, mesh.tets, mesh.tet_rod, [0, 1], base_z, tip_z + 1.3e-9)
    assert sec.n_slabs == rk.N_SLABS and len(sec.rods) == 2


def test_the_euler_load_of_a_layered_rod():
    """pi^2 EI / (4 L^2): a homogeneous rod's pi^3 E r^4 / (16 L^2); layers of the core's modulus change
    nothing; a stiffer skin adds its annulus' share; bad sizes are refused."""
    r, L, E = 2.5e-3, 9e-3, 1.51e6
    homogeneous = np.pi ** 3 * E * r ** 4 / (16 * L ** 2)
    assert rk.euler_load_n(r, L, [E], []) == pytest.approx(homogeneous, rel=1e-12)
    assert rk.euler_load_n(r, L, [E, E, E], [0.3e-3, 0.5e-3]) == pytest.approx(homogeneous, rel=1e-12)
    skin = rk.euler_load_n(r, L, [10 * E, E], [0.3e-3])
    annulus = np.pi ** 2 * 9 * E * np.pi / 4 * (r ** 4 - (r - 0.3e-3) ** 4) / (4 * L ** 2)
    assert skin == pytest.approx(homogeneous + annulus, rel=1e-12)
    assert rk.euler_load_n(r, 2 * L, [E], []) == pytest.approx(homogeneous / 4, rel=1e-12)
    with pytest.raises(ValueError, match="one thickness per layer"):
        rk.euler_load_n(r, L, [E, E], [])


def test_second_order_kinematics_refuse_a_rod_near_buckling(tiny_mesh):
    """The check counts each rod's axial contact load against its Euler load, and the tiny scene's
    slide (second order) is refused with the limit's name when the limit is below what its rods carry."""
    f = np.array([[0.0, 0.1, -0.2], [0.05, 0.0, -0.4], [0.0, 0.0, -5.0], [0.0, 0.0, 0.1]])
    rod = np.array([1, 1, -1, 0])  # rod 1 carries 0.6 N; the base's 5 N is no rod's
    qs._check_buckling(f, rod, 2, 1.0, 0.61, "step 3", "linear")
    with pytest.raises(qs.SolverError, match=r"step 3: rod 1 carries 0.6 N along its axis, 0.60 x its Euler buckling load"):
        qs._check_buckling(f, rod, 2, 1.0, 0.59, "step 3", "linear")
    scene, _, mesh, _ = tiny_mesh
    second = scene.with_values({"fidelity.solve.rod_kinematics": "second_order"})
    ep = qs.run_episode(second, mesh)
    carried = (-ep.rod_force_n[..., 2]).max() / qs._euler_load_n(second)
    assert 0.0 < carried < 0.5  # the default limit lets the tiny slide through
    with pytest.raises(qs.SolverError, match="fidelity.solve.buckling_limit"):
        qs.run_episode(second.with_values({"fidelity.solve.buckling_limit": 0.5 * carried}), mesh)
