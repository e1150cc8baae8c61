"""The ``nonlinear`` tier on the 2 x 2 tiny sensor (fem.finite_strain): agreement with the linear
tier at small load, neo-Hookean stiffening at large compression, equilibrium, Coulomb slip."""

from __future__ import annotations

import numpy as np
import pytest

from fem import quasistatic as qs
from fem.finite_strain import run_nonlinear_episode
from mlsim.scene import scene_from_dict


def _scene(tiny_scene, segments, friction=0.0, diameter_mm=40.0, substeps=1):
    data = tiny_scene.model_dump(mode="json", exclude_none=True)
    data["load"] = {"indenter": {"shape": "flat", "diameter_mm": diameter_mm}, "start_xy_mm": [0.0, 0.0], "start_gap_mm": 0.5,
                    "friction_coefficient": friction, "segments": segments}
    data["fidelity"]["solve"] = {"tier": "nonlinear", "gravity": False, "substeps": substeps}
    return scene_from_dict(data)


def _linear(scene, mesh):
    return qs.run_episode(scene, mesh, settings=qs.SolveSettings(tier="linear", gravity=False, substeps=scene.fidelity.solve.substeps))


def test_small_press_agrees_with_the_linear_tier(tiny_mesh):
    """A 0.05 mm press (0.5 % strain): the finite-strain answer is the linear one to within 1 %."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 0.55, "speed_mm_s": 5.5}])
    nl = run_nonlinear_episode(scene, mesh)
    lin = _linear(scene, mesh)
    assert lin.normal_force_n[-1] > 0.1
    assert nl.normal_force_n[-1] == pytest.approx(lin.normal_force_n[-1], rel=0.01)
    assert nl.von_mises[-1].mean() == pytest.approx(lin.von_mises[-1].mean(), rel=0.01)
    np.testing.assert_allclose(nl.frames("displacement")[-1], lin.frames("displacement")[-1], atol=0.01 * np.abs(lin.displacement).max())
    # no gravity: the clamp balances the contact force
    # (to the Newton tolerance: the free DOFs' residual, 1e-8 of the load, sums over ~10^4 DOFs)
    np.testing.assert_allclose(nl.reaction_n + nl.contact_force_n, 0.0, atol=1e-5 * nl.normal_force_n.max())
    assert nl.tier == "nonlinear" and np.all(nl.iterations[nl.normal_force_n > 0] <= 10)


def test_deep_press_stiffens_as_a_neo_hookean_solid(tiny_mesh):
    """A 3 mm press on rods 9 mm tall on a 2 mm base: nominal strain e = 3 / 11. Under uniaxial
    compression an incompressible neo-Hookean solid carries mu (s - s^-2) at stretch s = 1 - e, the
    linear solid 3 mu (s - 1): the ratio 1.42 at this strain. The rods are neither free nor uniaxial
    (bonded base, bulging), so the force ratio nonlinear / linear is asserted within 10 % of that."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 3.5, "speed_mm_s": 35.0}])
    nl = run_nonlinear_episode(scene, mesh)
    lin = _linear(scene, mesh)
    s = 1.0 - 3.0 / 11.0
    expected = (s - s**-2) / (3.0 * (s - 1.0))
    assert nl.normal_force_n[-1] / lin.normal_force_n[-1] == pytest.approx(expected, rel=0.10)
    for name in ("stress", "von_mises", "sed", "displacement"):
        assert np.all(np.isfinite(getattr(nl, name)))
    assert np.all(nl.sed >= 0.0)  # an energy density is not negative


def test_friction_slip_on_the_nonlinear_tier(tiny_mesh):
    """As the linear tier's test: a probe pressed on the tips and slid ends in gross slip with
    the tangential force mu times the normal force (within 2 %).

    mu = 0.3 and a 2 mm slide: the tips slip from the first sliding step (stick fraction 0, ratio
    0.287 then 0.3000 after 0.67 mm) and the probe drags them 1.3 mm further in gross slip. At
    mu = 0.5 (this test's earlier value) the tips stick and the rods tilt for 5.3 mm, the normal
    force rising from 2.7 to 4.5 N, before gross slip: an 8 mm slide of up to 46 Newton iterations a
    step for the same Coulomb law at its end (225 s against 26 s now, on the loaded 2-core machine)."""
    scene0, _, mesh, _ = tiny_mesh
    mu = 0.3
    segs = [{"kind": "press", "depth_mm": 0.7, "speed_mm_s": 7.0}, {"kind": "slide", "distance_mm": 2.0, "speed_mm_s": 40.0}]
    nl = run_nonlinear_episode(_scene(scene0, segs, friction=mu, substeps=2), mesh)
    ratio = np.hypot(nl.contact_force_n[:, 0], nl.contact_force_n[:, 1]) / np.maximum(nl.normal_force_n, 1e-12)
    end = np.argmin(abs(nl.t_s - 0.15))  # the slide's last step (the probe stops there)
    assert nl.normal_force_n[end] > 1.0
    assert ratio[end] == pytest.approx(mu, rel=0.02)
    assert nl.stick_fraction[end] == 0.0
    assert nl.contact_force_n[end, 0] > 0


def test_contact_woodbury_directions_solve_the_frictional_tangent():
    """fem.finite_strain.ContactWoodbury: with the body tangent just factorised, Woodbury's identity on
    the touching points solves A = K - W D W^T exactly (non-symmetric D, points out of contact left
    out); after the body tangent has moved on, GMRES preconditioned by the old factor reaches the
    forcing term without a new factorisation, and the contact set changing costs none either."""
    import scipy.sparse as sp

    from fem.finite_strain import INNER_RTOL, ContactWoodbury

    rng = np.random.default_rng(3)
    n, m = 400, 30
    L = sp.random(n, n, density=0.01, random_state=4) + sp.identity(n) * 5.0
    K = (L @ L.T).tocsr()  # symmetric positive definite, sparse
    W = sp.random(n, 3 * m, density=0.02, random_state=5).tocsr()
    D = -rng.uniform(0.5, 2.0, (m, 3, 3)) * 40.0  # stiff and not symmetric, like a frictional law's
    D[::3] = 0.0  # a third of the points out of contact
    Dm = sp.block_diag(list(D), format="csr")
    b = rng.standard_normal(n)
    woodbury = ContactWoodbury(W)
    A = (K - W @ Dm @ W.T).tocsr()
    x = woodbury.direction(A, K, D, b)
    assert woodbury.factorisations == 1
    assert np.linalg.norm(A @ x - b) <= 1e-10 * np.linalg.norm(b)
    # the body stiffens by 5 % and more points touch: no new factorisation, the forcing term met
    K2 = (1.05 * K).tocsr()
    D2 = D.copy()
    D2[::3] = -40.0 * np.eye(3)
    A2 = (K2 - W @ sp.block_diag(list(D2), format="csr") @ W.T).tocsr()
    x2 = woodbury.direction(A2, K2, D2, b)
    assert woodbury.factorisations == 1
    assert np.linalg.norm(A2 @ x2 - b) <= INNER_RTOL * np.linalg.norm(b)
    # and the exact answer's: to the forcing term times A's conditioning, far from the undamped guess
    exact = np.linalg.solve(A2.toarray(), b)
    assert np.linalg.norm(x2 - exact) <= 1e-2 * np.linalg.norm(exact)



def test_condensed_newton_gives_the_penalty_newtons_answer_on_a_press(tiny_mesh):
    """The nonlinear tier's two step solvers solve the same equations: the condensed Newton (the
    default: ADMM on the body linearised once and condensed onto the contact points) and the penalty
    Newton with contact inside its loop. A flat probe pressed 0.4 mm into the tips with mu = 0.8:
    per-rod contact forces within 1 % of the peak at every step (the penalty Newton rounds the return
    map's corner: fem.condensed._contact_law)."""
    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 0.9, "speed_mm_s": 9.0}], friction=0.8)
    condensed_ep = run_nonlinear_episode(scene, mesh)
    data = scene.model_dump(mode="json", exclude_none=True)
    data["fidelity"]["solve"]["nonlinear_newton"] = "penalty"
    penalty = run_nonlinear_episode(scene_from_dict(data), mesh)
    peak = np.abs(penalty.rod_force_n).max()
    assert peak > 0.5
    np.testing.assert_allclose(condensed_ep.rod_force_n, penalty.rod_force_n, rtol=0, atol=0.01 * peak)
    assert condensed_ep.seconds["penalty_newton_steps"] == 0  # every step converged condensed


def test_a_step_whose_first_tries_fail_is_finished_by_following_its_iterates(tiny_mesh, monkeypatch):
    """_Problem.path's retry before the penalty Newton: the condensed Newton with every contact solve
    linearised at its last iterate's points. With the first try and the fresh linearisation made to fail
    at every step, the press is done by that retry alone (no penalty Newton) and lands on the default's
    answer: a press has one equilibrium (per-rod forces within 1e-4 of the peak)."""
    from fem import finite_strain
    from mlsim.errors import SolverError

    scene0, _, mesh, _ = tiny_mesh
    scene = _scene(scene0, [{"kind": "press", "depth_mm": 0.9, "speed_mm_s": 9.0}], friction=0.8)
    default = run_nonlinear_episode(scene, mesh)
    step = finite_strain._Problem.condensed_step

    def failing_first(self, x0, pose, pose_old, state, case, follow_iterates=False):
        if not follow_iterates:
            raise SolverError(f"{case}: made to fail")
        return step(self, x0, pose, pose_old, state, case, follow_iterates=True)

    monkeypatch.setattr(finite_strain._Problem, "condensed_step", failing_first)
    lines = []
    followed = run_nonlinear_episode(scene, mesh, log=lines.append)
    peak = np.abs(default.rod_force_n).max()
    assert peak > 0.5
    np.testing.assert_allclose(followed.rod_force_n, default.rod_force_n, rtol=0, atol=1e-4 * peak)
    assert followed.seconds["penalty_newton_steps"] == 0
    assert followed.seconds["followed_iterates_steps"] == len(followed.rod_force_n)  # every step, the first at rest too
    assert default.seconds["followed_iterates_steps"] == 0
    # the run log names the steps and the dynamics that follow a snap
    assert len(lines) == 1 and f"steps {list(range(len(followed.rod_force_n)))}" in lines[0] and "backward_euler" in lines[0]


class _LoggedSteps:
    """A stand-in for :class:`fem.finite_strain._Problem` that records where each condensed step starts:
    a move longer than 0.6 (in x) fails, a shorter one lands at the start plus the move."""

    contact_solver, _fresh_first, _condensed, fallbacks, followed_steps, max_penetration_m, k_n = "admm", False, None, 0, 0, 1.0, 1.0
    _adopts = False  # quasi-static: a fresh linearisation serves its step only

    def __init__(self):
        self.starts = []

    def condensed_step(self, x, pose, pose_old, state, case, follow_iterates=False):
        from fem.nonlinear import SolverError

        move = pose.position_m[0] - pose_old.position_m[0]
        self.starts.append((float(x[0]), pose_old.position_m[0]))
        if move > 0.6:
            raise SolverError(f"{case}: too far")
        law = qs.condensed._Law(np.zeros((1, 3)), None, np.zeros(1), np.zeros(1, bool), np.zeros(1, bool), np.zeros((1, 3)))
        return x + move, law, 1

    def newton(self, x, pose, pose_old, state, case):
        from fem.nonlinear import SolverError

        raise SolverError(f"{case}: the penalty Newton is not under test")

    def jumps(self, pose, state):
        return False

    def point_u(self, x):
        return np.zeros((1, 3))


def test_a_half_step_starts_from_the_state_it_continues_not_from_the_whole_moves_guess(monkeypatch):
    """_Problem.path with an extrapolated ``guess``: the whole move may start there, each half starts from the
    converged state at its own start (a guess made for the whole move, on a rod bent far, can be far from a
    half's answer: every halving of a failed sideways push began from it and failed in turn)."""
    from fem import finite_strain
    from fem.condensed import PointState
    from fem.indenters import Pose

    monkeypatch.setattr(finite_strain, "CondensedBody", lambda problem, x: None)  # the re-linearisation: a no-op here
    monkeypatch.setattr(_LoggedSteps, "_step_linearised_at", finite_strain._Problem._step_linearised_at, raising=False)
    problem = _LoggedSteps()
    x0, guess = np.array([0.0]), np.array([5.0])
    state = PointState(np.zeros((1, 3)), np.zeros((1, 3)))
    x, _ = finite_strain._Problem.path(problem, x0, Pose((1.0, 0.0, 0.0), 0.0), Pose((0.0, 0.0, 0.0), 0.0), state, "move", guess=guess)
    # the whole move from the guess (three times: the kept linearisation, the kept one following its iterates,
    # the re-made one), then two halves chained
    assert problem.starts == [(5.0, 0.0), (5.0, 0.0), (5.0, 0.0), (0.0, 0.0), (0.5, 0.5)]
    assert x[0] == pytest.approx(1.0)


@pytest.mark.parametrize("adopts, order", [(False, ["kept", "follow", "fresh", "newton"]), (True, ["kept", "fresh", "follow", "newton"])])
def test_a_failed_step_follows_its_iterates_before_a_fresh_linearisation_unless_under_dynamics(adopts, order):
    """_Problem.path's retries after the kept linearisation's first try fails: a quasi-static step follows its
    own iterates first (on the default demo the fresh linearisation failed at both snap-back steps and cost
    10-30 s each), a dynamic one linearises afresh first (kept for the steps after it, which start near it);
    then the penalty Newton."""
    from fem import finite_strain
    from fem.condensed import PointState
    from fem.indenters import Pose
    from fem.nonlinear import SolverError

    problem, tries = _LoggedSteps(), []
    problem._adopts = adopts

    def condensed_step(x, pose, pose_old, state, case, follow_iterates=False):
        tries.append("follow" if follow_iterates else "kept")
        raise SolverError(f"{case}: made to fail")

    def fresh(x, pose, pose_old, state, case):
        tries.append("fresh")
        raise SolverError(f"{case}: made to fail")

    def newton(x, pose, pose_old, state, case):
        tries.append("newton")
        raise SolverError(f"{case}: made to fail")

    problem.condensed_step, problem._step_linearised_at, problem.newton = condensed_step, fresh, newton
    state = PointState(np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(SolverError):
        finite_strain._Problem.path(problem, np.array([0.0]), Pose((0.1, 0.0, 0.0), 0.0), Pose((0.0, 0.0, 0.0), 0.0), state, "move", depth=0)
    assert tries == order


def test_force_control_on_the_nonlinear_tier_is_the_press_to_the_height_it_found(tiny_mesh):
    """A flat probe ramped to 0.4 N on the four tips (frictionless, so the answer is path-free): every frame
    carries its target to the search's tolerance (1e-6), and a displacement-controlled press to the final
    height gives that force. (Each trial height starts its contact solve from the step's own warm start,
    _Problem.restart_contact; this press converges either way, so it checks the answer, not the order.)"""
    scene0, _, mesh, _ = tiny_mesh
    force = run_nonlinear_episode(_scene(scene0, [{"kind": "press", "force_n": 0.4, "duration_s": 0.1}]), mesh)
    frames = force.frame_step[1:]  # (the first frame is the start, before the ramp: no target)
    targets = force.force_target_n[frames]
    assert np.all(np.isfinite(targets)) and targets[-1] == pytest.approx(0.4)
    np.testing.assert_allclose(force.normal_force_n[frames], targets, rtol=1e-5, atol=1e-6)
    depth_mm = (force.pose[0, 2] - force.pose[-1, 2]) * 1e3
    assert 0.5 < depth_mm < 0.6  # past the 0.5 mm gap onto the tips
    press = run_nonlinear_episode(_scene(scene0, [{"kind": "press", "depth_mm": depth_mm, "speed_mm_s": depth_mm / 0.1}]), mesh)
    assert press.normal_force_n[-1] == pytest.approx(0.4, rel=1e-3)


def test_the_contact_solve_keeps_the_start_of_a_point_an_iterate_carried_off_the_indenter():
    """_Problem._linearise_at: each point at the last outer iterate's position, except one the iterate put
    off the indenter while the step's start carried by the indenter (anchor) has it inside: that one keeps
    its start (the branch the step continues). A point inside at both takes the iterate's even where the
    start lay deeper; one the iterate brought to the indenter takes the iterate's; one off at both too."""
    from types import SimpleNamespace

    from fem import finite_strain
    from fem.indenters import IndenterShape, Pose, gap

    punch = IndenterShape("flat", (5e-3, 2e-3), 0.5e-3)  # its flat face at z = 0, the body below it
    pose = Pose((0.0, 0.0, 0.0), 0.0)
    X = np.array([[0.0, 0.0, -1e-4], [1e-3, 0.0, -1e-4], [2e-3, 0.0, -1e-4], [4.8e-3, 0.0, -1e-4], [1e-3, 1e-3, -1e-4], [0.0, 1e-3, -3e-4]])
    problem = SimpleNamespace(shape=punch, points=SimpleNamespace(X=X))
    # anchors: points 0, 1, 3, 4 inside at the start, 2 and 5 outside
    anchor = np.array([[0.0, 0.0, 2e-4], [0.0, 0.0, 1.5e-4], [0.0, 0.0, 0.0], [0.0, 0.0, 2e-4], [0.0, 0.0, 3e-4], [0.0, 0.0, 0.0]])
    # iterates: 0 deeper, 1 off, 2 in, 3 off past the rim, 4 in but shallower than its start, 5 still off
    iterate = np.array([[0.0, 0.0, 3e-4], [0.0, 0.0, -1e-4], [0.0, 0.0, 2e-4], [3e-3, 0.0, 0.0], [0.0, 0.0, 1.2e-4], [0.0, 0.0, 1e-4]])
    assert np.array_equal(gap(punch, pose, X + anchor) < 0, [True, True, False, True, True, False])
    assert np.array_equal(gap(punch, pose, X + iterate) > 0, [False, True, False, True, False, True])
    chosen = finite_strain._Problem._linearise_at(problem, iterate, anchor, pose)
    kept = np.array([False, True, False, True, False, False])
    np.testing.assert_array_equal(chosen, np.where(kept[:, None], anchor, iterate))
