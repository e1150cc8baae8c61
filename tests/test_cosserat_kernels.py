"""The compiled Cosserat rod kernels (fem.cosserat_kernels) against the numpy reference (fem.cosserat_rod):
energy, gradient and block-tridiagonal Hessian to round-off, the block Cholesky solve against a dense
solve, the update, and whole solves (compiled Newton, numpy trust region where a rod leaves the
common case) against the numpy path."""

from __future__ import annotations

import math

import numpy as np
import pytest

from fem import cosserat_kernels as ck
from fem import cosserat_rod as cr

LENGTH_M = 0.02
EI = 1e-6  # N m^2
SLENDER = cr.RodSection(LENGTH_M, 1e6 * EI / LENGTH_M**2, 1e6 * EI / LENGTH_M**2, (EI, EI), EI / 1.3)
STUBBY = cr.RodSection.circular(0.01, 1e-3, 1e6, 0.45)
ROD_SCALE = np.array([1.0, 1.0, 1.0, 1e-3, 1e-3, 1e-3])


def _clamps(rng, rods):
    q = rng.standard_normal((rods, 4))
    q[0] = [1.0, 0.0, 0.0, 0.0]
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def _bent(section, n, clamps, rng, size=0.3):
    """Straight rods from their clamps moved by random increments (turns ~size rad, node moves ~size mm)."""
    state = cr.straight_rod(section, n, np.zeros((len(clamps), 3)), clamps)
    d = size * rng.standard_normal((len(clamps), n, 6)) * ROD_SCALE
    x = state.x.copy()
    x[:, 1:] += d[..., 3:]
    return cr.RodState(x, cr.qmul(state.q, cr.cayley(d[..., :3])))


def _loads(n, rods, k, rng, force_n):
    return cr.PointLoads(rng.integers(0, n, (rods, k)), rng.uniform(0.0, 1.0, (rods, k)), 1e-3 * rng.standard_normal((rods, k, 3)),
                         force_n * rng.standard_normal((rods, k, 3)))


def _assemble(D, O):
    """The dense Hessians (B, 6N, 6N) of the kernels' blocks."""
    nb, n = D.shape[:2]
    H = np.zeros((nb, n, n, 6, 6))
    idx = np.arange(n)
    H[:, idx, idx] = D
    H[:, idx[:-1], idx[1:]] = O[:, 1:]
    H[:, idx[1:], idx[:-1]] = np.swapaxes(O[:, 1:], -1, -2)
    return np.swapaxes(H, 2, 3).reshape(nb, 6 * n, 6 * n)


@pytest.mark.parametrize("with_loads", [False, True, "springs", "neo_hookean"])
def test_kernel_energy_gradient_and_hessian_are_numpys(with_loads):
    """Bent, twisted, stretched rods (4 clamps, tip forces and moments, 7 point loads each, held by springs
    to anchors or not): E, g and H equal fem.cosserat_rod.energy and gradient_and_hessian to 1e-10 of their size."""
    rng = np.random.default_rng(5)
    n, rods = 6, 4
    clamps = _clamps(rng, rods)
    state = _bent(STUBBY, n, clamps, rng)
    F, M = 0.01 * rng.standard_normal((rods, 3)), 1e-4 * rng.standard_normal((rods, 3))
    loads = _loads(n, rods, 7, rng, 0.02) if with_loads else None
    if with_loads == "springs":
        a = rng.standard_normal((rods, 7, 3, 3))
        loads = cr.PointLoads(loads.segment, loads.along, loads.offset_m, loads.force_n, 20.0 * a @ np.swapaxes(a, -1, -2),
                              loads.positions(state) + 1e-3 * rng.standard_normal((rods, 7, 3)))
    section = STUBBY if with_loads != "neo_hookean" else cr.RodSection(STUBBY.length_m, STUBBY.axial_n, STUBBY.shear_n, STUBBY.bending_n_m2,
                                                                       STUBBY.torsion_n_m2, "neo_hookean")
    g_np, H_np = cr.gradient_and_hessian(state, section, clamps, F, M, loads=loads)
    E_np = cr.energy(state, section, clamps, F, loads)
    args = ck.flatten_problem(state, section, clamps, F, M, loads, (rods,))
    E, g, D, O = ck.evaluate(*args[:3], section.length_m, section.S, section.B, *args[3:], section.axial_code)
    np.testing.assert_allclose(E, E_np, rtol=1e-10, atol=1e-10 * np.abs(E_np).max())
    np.testing.assert_allclose(g, g_np, rtol=0, atol=1e-10 * np.abs(g_np).max())
    np.testing.assert_allclose(_assemble(D, O), H_np, rtol=0, atol=1e-10 * np.abs(H_np).max())


def test_block_cholesky_solves_the_assembled_system_and_flags_an_indefinite_one():
    """Rods bent to equilibrium by tip forces (stable: positive definite): H^-1 r backward stable (relative
    residual |H x - r| / (|H| |x|) below 1e-15, as numpy's dense solve's) and within the forward error bound
    cond(H) eps of numpy's; a straight column at 1.5 x its Euler load (a saddle) is flagged.

    Why not a fixed forward tolerance: the slender rods' Hessian has cond about 4e11 (axial against bending
    stiffness), so two exact-to-rounding solves may differ by up to about 5e-5 of the answer; on an AMD EPYC
    the two differed by 1.2e-10, past the 1e-10 this test held them to before, at backward errors of 5e-19."""
    rng = np.random.default_rng(8)
    n, rods = 8, 3
    clamps = _clamps(rng, rods)
    F = 2.0 * EI / LENGTH_M**2 * rng.standard_normal((rods, 3))
    state = cr.solve_static(SLENDER, n, tip_force_n=F, clamp=clamps, increments=2, compiled=False)
    args = ck.flatten_problem(state, SLENDER, clamps, F, np.zeros(3), None, (rods,))
    _, g, D, O = ck.evaluate(*args[:3], SLENDER.length_m, SLENDER.S, SLENDER.B, *args[3:])
    L, C, ok = ck.block_cholesky(D, O)
    assert ok.all()
    r = rng.standard_normal((rods, 6 * n))
    H = _assemble(D, O)
    x = ck.block_solve(L, C, r)
    expected = np.linalg.solve(H, r[..., None])[..., 0]
    for b in range(rods):
        assert np.linalg.norm(H[b] @ x[b] - r[b]) <= 1e-15 * np.linalg.norm(H[b], 2) * np.linalg.norm(x[b])
        bound = np.linalg.cond(H[b]) * np.finfo(float).eps * np.abs(expected[b]).max()
        np.testing.assert_allclose(x[b], expected[b], rtol=0, atol=bound)

    column = cr.straight_rod(SLENDER, n)
    load = 1.5 * math.pi**2 * EI / (4 * LENGTH_M**2)
    column.x[:, 2] *= 1.0 - load / SLENDER.axial_n
    args = ck.flatten_problem(column, SLENDER, np.array([1.0, 0, 0, 0]), np.array([0.0, 0.0, -load]), np.zeros(3), None, (1,))
    _, _, D, O = ck.evaluate(*args[:3], SLENDER.length_m, SLENDER.S, SLENDER.B, *args[3:])
    assert not ck.block_cholesky(D, O)[2][0]


def test_boundary_step_is_numpys_trust_region_step():
    """Where Newton's step leaves the trust region (radius 0.3 of it), More and Sorensen's iteration on the
    block factors gives numpy's eigen-bisection step (fem.cosserat_rod._trust_region_step) to 1e-9."""
    rng = np.random.default_rng(4)
    n = 8
    l = LENGTH_M / n
    F = 2.0 * EI / LENGTH_M**2 * np.array([1.0, -0.5, 0.3])
    state = cr.solve_static(SLENDER, n, tip_force_n=F, compiled=False)
    args = ck.flatten_problem(state, SLENDER, np.array([1.0, 0, 0, 0]), F, np.zeros(3), None, (1,))
    _, _, D, O = ck.evaluate(*args[:3], SLENDER.length_m, SLENDER.S, SLENDER.B, *args[3:])
    g = 1e-3 * rng.standard_normal(6 * n) * np.tile([1e-3, 1e-3, 1e-3, 1.0, 1.0, 1.0], n)
    L, C, ok = ck.block_cholesky(D, O)
    newton = -ck.block_solve(L, C, g[None])[0]
    scale = np.tile([1.0, 1.0, 1.0, 1.0 / l, 1.0 / l, 1.0 / l], n)
    radius = 0.3 * np.linalg.norm(newton * scale)
    step = newton.reshape(n, 6).copy()
    found, mu = ck._boundary_step(D[0], O[0], g.reshape(n, 6), l, radius, L[0], C[0], step)
    expected, _ = cr._trust_region_step(g / scale, _assemble(D, O)[0] / np.outer(scale, scale), np.array(radius))
    assert found and mu > 0.0
    np.testing.assert_allclose(step.reshape(-1) * scale, expected, rtol=0, atol=1e-9 * radius)


def test_kernel_update_is_numpys():
    rng = np.random.default_rng(9)
    n, rods = 7, 3
    state = _bent(STUBBY, n, _clamps(rng, rods), rng)
    step = 0.2 * rng.standard_normal((rods, n, 6)) * ROD_SCALE
    expected = cr._update(state, step.reshape(rods, 6 * n))
    x, q = ck.update(state.x, state.q, step.reshape(rods, 6 * n))
    np.testing.assert_allclose(x, expected.x, rtol=0, atol=1e-15 * LENGTH_M)
    np.testing.assert_allclose(q, expected.q, rtol=0, atol=1e-15)


@pytest.mark.parametrize("moment", [False, True])
def test_compiled_solve_with_point_loads_is_numpys(moment, monkeypatch):
    """A batch of 6 rods (L / r = 10, different clamps and roots), 12 point loads each and a tip force, two
    load steps then one from the last answer: the compiled and numpy solves agree to 1e-9 of the rod's
    length. Without a tip moment numpy's trust region cuts some steps to its radius (the kernel's
    boundary step); with one (not conservative) it is Newton's step with a turn limit and backtracking."""
    rng = np.random.default_rng(12)
    n, rods = 8, 6
    section = cr.RodSection.circular(LENGTH_M, 2e-3, 1e6, 0.45)
    ei = section.B[0]
    clamps = _clamps(rng, rods)
    roots = 0.01 * rng.standard_normal((rods, 3))
    loads = _loads(n, rods, 12, rng, 0.3 * ei / LENGTH_M**2)
    F = 0.5 * ei / LENGTH_M**2 * rng.standard_normal((rods, 3))
    M = 0.1 * ei / LENGTH_M * rng.standard_normal((rods, 3)) if moment else np.zeros(3)
    boundary_steps = []
    eigh = np.linalg.eigh

    def counting(a, *args, **kwargs):  # numpy's trust region leaves Newton's step for H's eigenvalues
        boundary_steps.append(1)
        return eigh(a, *args, **kwargs)

    monkeypatch.setattr(np.linalg, "eigh", counting)
    answers = {}
    for compiled in (True, False):
        state = cr.solve_static(section, n, tip_force_n=F, tip_moment_n_m=M, clamp=clamps, root_m=roots, loads=loads, increments=2,
                                compiled=compiled)
        again = cr.PointLoads(loads.segment, loads.along, loads.offset_m, 1.2 * loads.force_n)
        answers[compiled] = (state, cr.solve_static(section, n, tip_force_n=F, tip_moment_n_m=M, clamp=clamps, root_m=roots, loads=again,
                                                    start=state, compiled=compiled))
        if compiled:
            assert not boundary_steps  # no fallback
    assert bool(boundary_steps) != moment
    assert np.abs(answers[True][0].x - roots[:, None]).max() > 0.1 * LENGTH_M  # bent well away from linear
    for a, b in zip(answers[True], answers[False]):
        np.testing.assert_allclose(a.x, b.x, rtol=0, atol=1e-9 * LENGTH_M)
        np.testing.assert_allclose(cr.rotation_matrix(a.q), cr.rotation_matrix(b.q), rtol=0, atol=1e-9)


def test_a_buckled_rod_in_a_batch_goes_on_in_the_compiled_trust_region(monkeypatch):
    """Past its Euler load the straight column's Hessian is indefinite: that rod goes on in numpy's trust region
    compiled (fem.cosserat_kernels._eigen_step), not in numpy, and bends over as in the numpy solve, to 1e-9 of
    its length; its neighbour stays in Newton's method. Out of its iterations it raises numpy's error."""
    p_euler = math.pi**2 * EI / (4 * LENGTH_M**2)
    forces = np.array([[1e-4 * 1.5 * p_euler, 0.0, -1.5 * p_euler], [0.05 * EI / LENGTH_M**2, 0.0, 0.0]])
    roots = np.array([[0.0, 0.0, 0.0], [0.01, 0.0, 0.0]])
    sizes = []
    plain_newton = cr._newton

    def counting(state, *args, **kwargs):
        sizes.append(state.q.shape[0])
        return plain_newton(state, *args, **kwargs)

    monkeypatch.setattr(cr, "_newton", counting)
    fast = cr.solve_static(SLENDER, 12, tip_force_n=forces, root_m=roots, increments=2)
    assert not sizes
    with pytest.raises(cr.SolverError, match=r"did not converge in 3 iterations at load step 1/1; unbalanced force"):
        cr.solve_static(SLENDER, 12, tip_force_n=forces, root_m=roots, max_iterations=3)
    monkeypatch.setattr(cr, "_newton", plain_newton)
    reference = cr.solve_static(SLENDER, 12, tip_force_n=forces, root_m=roots, increments=2, compiled=False)
    assert fast.x[0, -1, 0] > 0.3 * LENGTH_M
    np.testing.assert_allclose(fast.x, reference.x, rtol=0, atol=1e-9 * LENGTH_M)
