"""The discrete Cosserat rod (fem.cosserat_rod, issue 38's geometrically exact rod) against closed forms:
its derivatives against the energy's, the linear cantilever (Timoshenko), the elastica at large
deflection with second-order convergence, pure torsion, Engesser's buckling load, the post-buckled
column (Euler's elastica), objectivity, and refused input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq
from scipy.special import ellipk

from fem import cosserat_rod as cr
from fem.beam_theory import circular_shear_coefficient
from fem.elastica import cantilever_tip, engesser_load_n, haringx_load_n

LENGTH_M = 0.02
EI = 1e-6  # N m^2
#: a slender rod in the elastica's sense: axial and shear stiffness 1e6 E I / L^2 (stretch and shear 1e-6 of bending)
SLENDER = cr.RodSection(LENGTH_M, 1e6 * EI / LENGTH_M**2, 1e6 * EI / LENGTH_M**2, (EI, EI), EI / 1.3)
CLAMP = np.array([1.0, 0.0, 0.0, 0.0])


def _additive(state: cr.RodState, d: np.ndarray) -> cr.RodState:
    """The state moved by d in the Hessian's own coordinates: frames q cay(psi), nodes x + dx."""
    blocks = d.reshape(-1, 6)
    x = state.x.copy()
    x[1:] += blocks[:, 3:]
    return cr.RodState(x, cr.qmul(state.q, cr.cayley(blocks[:, :3])))


def _assert_exact_derivatives(state, n: int, g_and_H, energy_of) -> None:
    """g and H (the solver's) against central differences of the energy energy_of(state), steps 1e-4 rad
    and 1e-7 m, to 1e-6 of their largest entry; H symmetric."""
    g, H = g_and_H
    h = 1e-4 * np.tile([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3], n)

    def E(d):
        return energy_of(_additive(state, d))

    eye = np.diag(h)
    g_fd = np.array([(E(eye[j]) - E(-eye[j])) / (2 * h[j]) for j in range(6 * n)])
    H_fd = np.array([[(E(eye[j] + eye[k]) - E(eye[j] - eye[k]) - E(-eye[j] + eye[k]) + E(-eye[j] - eye[k])) / (4 * h[j] * h[k])
                      for k in range(6 * n)] for j in range(6 * n)])
    assert np.abs(g - g_fd).max() < 1e-6 * np.abs(g).max()
    assert np.abs(H - H_fd).max() < 1e-6 * np.abs(H).max()
    np.testing.assert_allclose(H, H.T, atol=1e-14 * np.abs(H).max())


def test_gradient_and_hessian_are_the_energys_derivatives():
    """At a bent, twisted, stretched state: central differences of the energy give g and H."""
    rng = np.random.default_rng(3)
    section = cr.RodSection.circular(0.01, 1e-3, 1e6, 0.45)
    n = 5
    state = _additive(cr.straight_rod(section, n), 0.3 * rng.standard_normal(6 * n) * np.tile([1, 1, 1, 1e-3, 1e-3, 1e-3], n))
    force = np.array([0.01, -0.02, 0.005])
    _assert_exact_derivatives(state, n, cr.gradient_and_hessian(state, section, CLAMP, force),
                              lambda s_: cr.energy(s_, section, CLAMP, force))


def test_small_load_gives_timoshenkos_cantilever():
    """P L^3 / 3 E I + P L / (kappa G A) for a stubby circular rod (L / r = 5, shear 13 % of the bending)."""
    radius, young, nu = 2e-3, 1e6, 0.45
    section = cr.RodSection.circular(0.01, radius, young, nu)
    force = 1e-6
    tip = cr.solve_static(section, 32, tip_force_n=(force, 0.0, 0.0)).x[-1]
    area, inertia = math.pi * radius**2, math.pi * radius**4 / 4
    shear = circular_shear_coefficient(nu) * young / (2 * (1 + nu)) * area
    expected = force * 0.01**3 / (3 * young * inertia) + force * 0.01 / shear
    assert tip[0] == pytest.approx(expected, rel=2e-3)


@pytest.mark.parametrize("alpha", [1.0, 3.0, 5.0])
def test_cantilever_against_the_elastica_converges_at_second_order(alpha):
    """Bisshopp and Drucker's tip deflection and tip position along the axis, dead load P = alpha E I / L^2:
    within 0.1 % at 32 segments, the error falling about 4x per halving of the segments (observed order
    1.89-1.94 from 8 to 32)."""
    d_ref, x_ref, _ = cantilever_tip(alpha)
    errors = []
    for n in (8, 16, 32):
        tip = cr.solve_static(SLENDER, n, tip_force_n=(alpha * EI / LENGTH_M**2, 0.0, 0.0), increments=3).x[-1] / LENGTH_M
        errors.append((abs(tip[0] / d_ref - 1.0), abs(tip[2] / x_ref - 1.0)))
    errors = np.array(errors)
    assert np.all(errors[-1] < 1e-3), errors
    order = np.log2(errors[:-1] / errors[1:])
    assert np.all(order > 1.85), order


def test_pure_torsion():
    """A dead axial tip moment T twists the rod uniformly: each joint turns by theta_j with
    G J sin(theta_j) / l_j = T (the discrete measure 2 sin(theta / 2) / l_j, its moment's arm cos(theta / 2)),
    so the last frame (at s = L - l / 2) by the sum, to round-off; that is T (L - l / 2) / G J to
    theta_j^2 / 6 (90 deg over 16 segments: 0.16 %), and the rod stays straight."""
    n, twist = 16, 0.5 * math.pi
    l, gj = LENGTH_M / n, SLENDER.torsion_n_m2
    torque = twist * gj / LENGTH_M
    state = cr.solve_static(SLENDER, n, tip_moment_n_m=(0.0, 0.0, torque))
    q = state.q[-1]
    angle = 2.0 * math.atan2(q[3], q[0])
    assert angle == pytest.approx(math.asin(torque * 0.5 * l / gj) + (n - 1) * math.asin(torque * l / gj), rel=1e-9)
    assert angle == pytest.approx(torque * (LENGTH_M - 0.5 * l) / gj, rel=2e-3)
    np.testing.assert_allclose(state.x[:, :2], 0.0, atol=1e-12)


def _lowest_eigenvalue(section, n, load_n):
    """The lowest eigenvalue of the Jacobi-scaled Hessian (the same inertia as H's, by Sylvester's law,
    and well conditioned) at the straight column shortened by P / E A: its equilibrium under the axial
    load P, exactly (a solve past the buckling load may leave the saddle for the bent state)."""
    state = cr.straight_rod(section, n)
    state.x[:, 2] *= 1.0 - load_n / section.axial_n
    _, H = cr.gradient_and_hessian(state, section, CLAMP, (0.0, 0.0, -load_n))
    d = 1.0 / np.sqrt(np.diag(H))
    return float(np.linalg.eigvalsh(H * np.outer(d, d))[0])


def test_buckling_load_is_haringxs():
    """The straight column's stiffness loses definiteness at Haringx's shear-corrected load (the Cosserat
    rod measures shear in the section's frame), here a stubby rod (L / r = 5) whose shear lowers Euler's
    load by 7 %, with an axial stiffness 1e3 x its own (its shortening would raise the load by 2.6 %):
    0.073, 0.017 % low at 16 and 32 segments (0.003 % at 64). Engesser's load is 0.5 % lower."""
    circle = cr.RodSection.circular(0.01, 2e-3, 1e6, 0.45)
    section = cr.RodSection(circle.length_m, 1e3 * circle.axial_n, circle.shear_n, circle.bending_n_m2, circle.torsion_n_m2)
    expected = haringx_load_n(section.B[0], section.shear_n, section.length_m)
    errors = [abs(brentq(lambda p: _lowest_eigenvalue(section, n, p), 0.8 * expected, 1.2 * expected, xtol=1e-12) / expected - 1.0)
              for n in (16, 32)]
    assert errors[1] < 3e-4 and errors[0] / errors[1] > 3.0, errors
    assert engesser_load_n(section.B[0], section.shear_n, section.length_m) < 0.996 * expected
    assert expected < 0.95 * math.pi**2 * section.B[0] / (4 * section.length_m**2)  # shear matters in this case


def test_column_past_its_euler_load_follows_the_elastica():
    """At 1.5 x Euler's load, nudged sideways by 1e-4 of it, the column bends over to Euler's post-buckled
    elastica: L sqrt(P / E I) = K(p), p = sin(alpha / 2), tip deflection 2 p sqrt(E I / P) (Timoshenko and
    Gere sec. 2.7). Tip angle within 0.5 %, deflection within 0.5 % at 32 segments."""
    p_euler = math.pi**2 * EI / (4 * LENGTH_M**2)
    load = 1.5 * p_euler
    k_l = LENGTH_M * math.sqrt(load / EI)
    p = brentq(lambda s: ellipk(s * s) - k_l, 1e-9, 1.0 - 1e-12)
    state = cr.solve_static(SLENDER, 32, tip_force_n=(1e-4 * load, 0.0, -load), increments=4)
    q = state.q[-1]
    # the last frame sits l / 2 below the tip: its turn differs from the tip's by kappa l / 2 = 0 at the free end (no moment)
    tilt = 2.0 * math.atan2(math.hypot(q[1], q[2]), q[0])
    assert tilt == pytest.approx(2.0 * math.asin(p), rel=5e-3)
    assert state.x[-1, 0] == pytest.approx(2.0 * p * math.sqrt(EI / load), rel=5e-3)


def test_a_rotated_clamp_and_load_give_the_rotated_answer():
    """Objectivity: the whole problem turned by a rotation Q gives Q times the answer (to the solver's tolerance, 1e-8 of L)."""
    axis = np.array([1.0, 2.0, -0.5]) / np.linalg.norm([1.0, 2.0, -0.5])
    turn = np.concatenate([[math.cos(0.6)], math.sin(0.6) * axis])
    Q = cr.rotation_matrix(turn)
    force = np.array([2.0, 1.0, -0.5]) * EI / LENGTH_M**2
    plain = cr.solve_static(SLENDER, 12, tip_force_n=force, increments=2)
    turned = cr.solve_static(SLENDER, 12, tip_force_n=Q @ force, clamp=turn, increments=2)
    np.testing.assert_allclose(turned.x, plain.x @ Q.T, rtol=0, atol=1e-8 * LENGTH_M)
    frames = cr.rotation_matrix(turned.q)
    np.testing.assert_allclose(frames, Q @ cr.rotation_matrix(plain.q), rtol=0, atol=1e-8)


@pytest.mark.parametrize("field, value", [("axial_n", -1.0), ("shear_n", 0.0), ("torsion_n_m2", float("nan")), ("length_m", float("inf"))])
def test_a_bad_section_is_refused_naming_the_field(field, value):
    kwargs = dict(length_m=0.01, axial_n=1.0, shear_n=1.0, bending_n_m2=(1e-6, 1e-6), torsion_n_m2=1e-6)
    kwargs[field] = value
    with pytest.raises(ValueError, match=f"RodSection.{field}"):
        cr.RodSection(**kwargs)


def test_a_non_finite_load_is_refused():
    with pytest.raises(ValueError, match="tip_force_n"):
        cr.solve_static(SLENDER, 4, tip_force_n=(float("nan"), 0.0, 0.0))


def test_a_batch_of_rods_is_each_rod_alone():
    """Four rods in one call (different loads, clamps and roots, one past its buckling load) give what
    each gives alone, to the solver's tolerance (1e-6 of L: the post-buckled rod is soft), the batch
    being how the fast tier solves a sensor's rods."""
    p_euler = math.pi**2 * EI / (4 * LENGTH_M**2)
    forces = np.array([[1.0, 0.0, 0.0], [0.0, 3.0, -1.0], [0.2, -0.1, 0.0], [1e-4, 0.0, -1.5]]) * np.array([[EI / LENGTH_M**2]] * 3 + [[p_euler]])
    turn = np.array([math.cos(0.2), 0.0, math.sin(0.2), 0.0])
    clamps = np.array([CLAMP, turn, CLAMP, CLAMP])
    roots = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.01, 0.01, 0.0]])
    together = cr.solve_static(SLENDER, 12, tip_force_n=forces, clamp=clamps, root_m=roots, increments=4)
    assert together.x.shape == (4, 13, 3) and together.q.shape == (4, 12, 4)
    for k in range(4):
        alone = cr.solve_static(SLENDER, 12, tip_force_n=forces[k], clamp=clamps[k], root_m=roots[k], increments=4)
        np.testing.assert_allclose(together.x[k], alone.x, rtol=0, atol=1e-6 * LENGTH_M)
    assert together.x[3, -1, 0] > 0.3 * LENGTH_M  # the fourth bent over past its Euler load


# --- point loads (the contact forces on a rod's tip face and sides) ------------------------------------

def _some_loads(n: int, rng) -> cr.PointLoads:
    segment = np.array([0, 2, n - 1, n - 1])
    along = np.array([0.3, 0.5, 1.0, 0.0])
    offset = 1e-3 * rng.standard_normal((4, 3))
    force = 0.02 * rng.standard_normal((4, 3))
    return cr.PointLoads(segment, along, offset, force)


def test_point_loads_gradient_and_hessian_are_the_energys_derivatives():
    """Dead forces on offset points of several segments (the root's segment included): central
    differences of the energy give g and H, the load stiffness of a force on a turning offset in H."""
    rng = np.random.default_rng(7)
    section = cr.RodSection.circular(0.01, 1e-3, 1e6, 0.45)
    n = 5
    state = _additive(cr.straight_rod(section, n), 0.3 * rng.standard_normal(6 * n) * np.tile([1, 1, 1, 1e-3, 1e-3, 1e-3], n))
    loads = _some_loads(n, rng)
    _assert_exact_derivatives(state, n, cr.gradient_and_hessian(state, section, CLAMP, loads=loads),
                              lambda s_: cr.energy(s_, section, CLAMP, loads=loads))


def test_a_point_load_on_the_tips_axis_is_the_tip_force():
    """A force on the last segment's far end, on its axis, is the dead tip force (to the solver's tolerance)."""
    force = np.array([2.0, -1.0, -0.5]) * EI / LENGTH_M**2
    tip = cr.solve_static(SLENDER, 12, tip_force_n=force, increments=2)
    loads = cr.PointLoads(np.array([11]), np.array([1.0]), np.zeros((1, 3)), force[None])
    point = cr.solve_static(SLENDER, 12, loads=loads, increments=2)
    np.testing.assert_allclose(point.x, tip.x, rtol=0, atol=1e-8 * LENGTH_M)


def test_an_offset_couple_on_the_tip_face_bends_the_rod_into_a_circle():
    """Two equal and opposite axial forces on the tip face, offset +-a along d1, are a couple 2 a F about d2.
    Re-aimed along the face's d3 until they turn with it (a follower couple), they bend the inextensible
    rod into a circle of radius EI / M; here the tip turns by M L / EI = 1 rad. Checks the offsets'
    moment arm in a turned frame."""
    a, n = 1e-3, 24
    M = EI / LENGTH_M
    F = M / (2 * a)
    segment, along, offset = np.array([n - 1, n - 1]), np.array([1.0, 1.0]), np.array([[a, 0.0, 0.0], [-a, 0.0, 0.0]])
    state, d3 = None, np.array([0.0, 0.0, 1.0])
    for k in list(range(1, 11)) + [10] * 10:  # ten increments, then the direction settled
        state = cr.solve_static(SLENDER, n, loads=cr.PointLoads(segment, along, offset, np.stack([-F * k / 10 * d3, F * k / 10 * d3])), start=state)
        d3 = cr.rotation_matrix(state.q[-1])[:, 2]
    radius, angle = EI / M, LENGTH_M * M / EI
    np.testing.assert_allclose(state.x[-1], [radius * (1 - math.cos(angle)), 0.0, radius * math.sin(angle)], rtol=0, atol=1e-3 * LENGTH_M)


def test_point_loads_on_a_batch_are_each_rod_alone():
    rng = np.random.default_rng(11)
    n = 8
    loads = [cr.PointLoads(np.array([3, 7, 7]), np.array([0.5, 1.0, 1.0]), 1e-3 * rng.standard_normal((3, 3)),
                           EI / LENGTH_M**2 * rng.standard_normal((3, 3))) for _ in range(3)]
    batch = cr.PointLoads(np.stack([l.segment for l in loads]), np.stack([l.along for l in loads]), np.stack([l.offset_m for l in loads]),
                          np.stack([l.force_n for l in loads]))
    together = cr.solve_static(SLENDER, n, loads=batch, root_m=np.zeros((3, 3)), increments=2)
    for k in range(3):
        alone = cr.solve_static(SLENDER, n, loads=loads[k], increments=2)
        np.testing.assert_allclose(together.x[k], alone.x, rtol=0, atol=1e-7 * LENGTH_M)


# --- points held by springs (the Robin coupling of fem.rod_exact) --------------------------------------

def _springs(rng, k: int, stiffness_n_m: float) -> tuple[np.ndarray, np.ndarray]:
    """k random symmetric positive semi-definite 3 x 3 stiffnesses (rank 1 to 3) of size ~stiffness_n_m."""
    a = rng.standard_normal((k, 3, 3)) * (rng.uniform(size=(k, 1, 3)) > 0.3)
    return stiffness_n_m * a @ np.swapaxes(a, -1, -2), rng.standard_normal((k, 3))


def test_springs_gradient_and_hessian_are_the_energys_derivatives():
    """Points held by springs to anchors (with dead forces, on offsets of several segments): central
    differences of the energy give g and H, J^T K J and the spring force's load stiffness included."""
    rng = np.random.default_rng(17)
    section = cr.RodSection.circular(0.01, 1e-3, 1e6, 0.45)
    n = 5
    state = _additive(cr.straight_rod(section, n), 0.3 * rng.standard_normal(6 * n) * np.tile([1, 1, 1, 1e-3, 1e-3, 1e-3], n))
    base = _some_loads(n, rng)
    K, a = _springs(rng, 4, 5.0)
    anchor = base.positions(state) + 1e-3 * a
    loads = cr.PointLoads(base.segment, base.along, base.offset_m, base.force_n, K, anchor)
    _assert_exact_derivatives(state, n, cr.gradient_and_hessian(state, section, CLAMP, loads=loads),
                              lambda s_: cr.energy(s_, section, CLAMP, loads=loads))


def test_a_spring_anchored_at_the_answer_changes_nothing():
    """The Robin coupling's fixed point: a rod bent far by dead point loads, then solved again under the same
    loads with each point held by a stiff spring anchored where it sat, from the straight rod: the same
    answer (the springs carry nothing there), to 1e-7 of the length."""
    n = 12
    force = np.array([[1.5, -0.5, -0.8], [0.3, 0.2, 0.0]]) * EI / LENGTH_M**2
    segment, along, offset = np.array([n - 1, 6]), np.array([1.0, 0.5]), np.array([[3e-4, 0.0, 0.0], [0.0, 2e-4, 0.0]])
    dead = cr.PointLoads(segment, along, offset, force)
    bent = cr.solve_static(SLENDER, n, loads=dead, increments=4)
    K = 1e3 * EI / LENGTH_M**3 * np.broadcast_to(np.eye(3), (2, 3, 3))
    held = cr.solve_static(SLENDER, n, loads=cr.PointLoads(segment, along, offset, force, K, dead.positions(bent)), increments=4)
    assert np.linalg.norm(bent.x[-1] - bent.x[0] - [0, 0, LENGTH_M]) > 0.3 * LENGTH_M  # bent far
    np.testing.assert_allclose(held.x, bent.x, rtol=0, atol=1e-7 * LENGTH_M)


def test_a_column_past_its_free_euler_load_stays_up_when_its_tip_is_held():
    """A column pressed at 1.5 x its free (clamped-free) Euler load P_E = pi^2 EI / 4 L^2 buckles under the dead
    load alone; with its tip held sideways by a spring of 1e3 x its bending stiffness 3 EI / L^3 (a face that
    holds the tip by friction: clamped-pinned, 8.2 P_E) it stays straight and shortens by P L / E A."""
    n = 12
    load = 1.5 * math.pi**2 * EI / (4 * LENGTH_M**2)
    tip = cr.PointLoads(np.array([n - 1]), np.array([1.0]), np.zeros((1, 3)), np.array([[0.0, 0.0, -load]]))
    imperfect = cr.solve_static(SLENDER, n, tip_force_n=(1e-4 * load, 0.0, 0.0), increments=1)  # a sideways nudge off the saddle
    free = cr.solve_static(SLENDER, n, loads=tip, start=imperfect)
    assert abs(free.x[-1, 0]) > 0.3 * LENGTH_M
    K = np.diag([1e3 * 3 * EI / LENGTH_M**3] * 2 + [0.0])[None]
    held = cr.solve_static(SLENDER, n, loads=cr.PointLoads(tip.segment, tip.along, tip.offset_m, tip.force_n, K, np.array([[0.0, 0.0, LENGTH_M]])),
                           start=imperfect)
    assert abs(held.x[-1, 0]) < 1e-6 * LENGTH_M
    np.testing.assert_allclose(held.x[-1, 2], LENGTH_M * (1.0 - load / SLENDER.axial_n), rtol=1e-9)


# --- the neo-Hookean axial law ------------------------------------------------------------------------

def test_neo_hookean_axial_law_derivatives_and_the_bar_in_compression():
    """RodSection(axial_law="neo_hookean"): central differences of the energy give g and H at a bent, stretched
    state; a bar pressed by P shortens to the stretch of (E A / 3) (lambda - lambda^-2) = -P (here lambda = 0.85,
    where the linear law's 1 - P / E A is 0.822), to 1e-8 of the length; the law is the linear one at small strain."""
    rng = np.random.default_rng(23)
    base = cr.RodSection.circular(0.01, 1e-3, 1e6, 0.45)
    neo = cr.RodSection(base.length_m, base.axial_n, base.shear_n, base.bending_n_m2, base.torsion_n_m2, "neo_hookean")
    n = 5
    state = _additive(cr.straight_rod(neo, n), 0.3 * rng.standard_normal(6 * n) * np.tile([1, 1, 1, 1e-3, 1e-3, 1e-3], n))
    force = np.array([0.01, -0.02, -0.05])
    _assert_exact_derivatives(state, n, cr.gradient_and_hessian(state, neo, CLAMP, force), lambda s_: cr.energy(s_, neo, CLAMP, force))
    lam = 0.85
    P = neo.axial_n / 3.0 * (lam**-2 - lam)
    stiff = cr.RodSection(neo.length_m, neo.axial_n, neo.shear_n, (1e3 * neo.axial_n * neo.length_m**2,) * 2, neo.torsion_n_m2, "neo_hookean")
    bar = cr.solve_static(stiff, 4, tip_force_n=(0.0, 0.0, -P), increments=2)  # (bending stiff enough not to buckle)
    np.testing.assert_allclose(bar.x[-1], [0.0, 0.0, lam * neo.length_m], rtol=0, atol=1e-8 * neo.length_m)
    n3, tangent, _ = cr.axial_force(np.array([1.0 - 1e-6]), neo.axial_n, "neo_hookean")
    np.testing.assert_allclose([n3[0] / -1e-6, tangent[0]], [neo.axial_n, neo.axial_n], rtol=1e-5)
    with pytest.raises(ValueError, match="axial_law = 'rubber'"):
        cr.RodSection(base.length_m, base.axial_n, base.shear_n, base.bending_n_m2, base.torsion_n_m2, "rubber")
