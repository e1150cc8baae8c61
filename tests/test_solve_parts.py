"""Building blocks of the time-stepped solve: the factorised solver, stress recovery, the indenter's
path, and the rounded indenter edges."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem

from fem import fields, trajectory
from fem.elasticity import assemble, discretise, dof_components
from fem.indenters import IndenterShape, Pose, gap_and_normal, rigid_motion, signed_distance_local
from fem.linsolve import available_backends, factorise
from fem.nonlinear import SolverError
from mlsim.scene import scene_from_dict

LAM, MU = 2.0e6, 0.5e6


def _cube(element, n=2):
    m = skfem.MeshTet.init_tensor(*(np.linspace(0, 1e-2, n + 1),) * 3)
    return discretise(m if element == "P1" else skfem.MeshTet2.from_mesh(m), element)


# ---------------------------------------------------------------------------------- linsolve
@pytest.mark.parametrize("backend", available_backends())
@pytest.mark.parametrize("element", ["P2", "P2P1"])
def test_factorised_solve_matches_spsolve(backend, element):
    d = _cube(element)
    K = assemble(d, LAM, MU)
    fixed = np.flatnonzero(d.u.doflocs[2][: d.n_u] < 1e-9)
    free = np.setdiff1d(np.arange(d.n_dofs), fixed)
    Kff = K[free][:, free]
    rng = np.random.default_rng(0)
    B = rng.normal(size=(len(free), 3))
    f = factorise(Kff, definite=d.p is None, backend=backend)
    X = f.solve(B)
    ref = spla.spsolve(Kff.tocsc(), B)
    np.testing.assert_allclose(X, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    np.testing.assert_allclose(f.solve(B[:, 1]), ref[:, 1], rtol=1e-9, atol=1e-9 * np.abs(ref).max())


@pytest.mark.parametrize("backend", available_backends())
def test_solving_into_a_kept_block_gives_the_solves_bits(backend):
    """solve_into (the reduced tier's precompute: column-major blocks it keeps) writes what solve
    returns, bit for bit, whatever the block held before, and refuses a row-major or mismatched one."""
    d = _cube("P2P1")
    K = assemble(d, LAM, MU)
    free = np.setdiff1d(np.arange(d.n_dofs), np.flatnonzero(d.u.doflocs[2][: d.n_u] < 1e-9))
    f = factorise(K[free][:, free], definite=False, backend=backend)
    rng = np.random.default_rng(3)
    B = np.asfortranarray(rng.normal(size=(len(free), 5)))
    out = np.asfortranarray(rng.normal(size=B.shape))  # stale values: overwritten, never read
    assert f.solve_into(B, out) is out
    assert out.tobytes(order="F") == np.asfortranarray(f.solve(B)).tobytes(order="F")
    with pytest.raises(ValueError, match="column-major"):
        f.solve_into(np.ascontiguousarray(B), out)
    with pytest.raises(ValueError, match="must both be"):
        f.solve_into(B, out[:, :4])


@pytest.mark.parametrize("backend", available_backends())
def test_factorised_general_matrix_matches_spsolve(backend):
    """A non-symmetric matrix (the frictional tangent's kind: P2P1 stiffness plus a non-symmetric
    sparse coupling) through the general LU (symmetric=False)."""
    d = _cube("P2P1")
    K = assemble(d, LAM, MU)
    fixed = np.flatnonzero(d.u.doflocs[2][: d.n_u] < 1e-9)
    free = np.setdiff1d(np.arange(d.n_dofs), fixed)
    rng = np.random.default_rng(1)
    n = len(free)
    coupling = sp.random(n, n, density=5.0 / n, random_state=2, format="csr") * (0.1 * abs(K).max())
    A = (K[free][:, free] + coupling).tocsr()
    assert abs(A - A.T).max() > 1e-3 * abs(A).max()  # not symmetric
    B = rng.normal(size=(n, 2))
    X = factorise(A, definite=False, backend=backend, symmetric=False).solve(B)
    ref = spla.spsolve(A.tocsc(), B)
    np.testing.assert_allclose(X, ref, rtol=1e-8, atol=1e-8 * np.abs(ref).max())


@pytest.mark.parametrize("backend", available_backends())
def test_factorised_solve_of_a_free_body_raises(backend):
    d = _cube("P1")
    K = assemble(d, LAM, MU)  # no support: six rigid modes
    with pytest.raises((SolverError,)) as e:
        f = factorise(K, definite=True, backend=backend)
        f.solve(np.ones(K.shape[0]))
    assert "rigid" in str(e.value) or "singular" in str(e.value) or "PARDISO" in str(e.value)


@pytest.mark.skipif("pardiso" not in available_backends(), reason="MKL PARDISO (pypardiso) is not installed on this machine")
def test_pardiso_runs_in_mkls_reproducible_mode():
    """Without MKL's conditional numerical reproducibility its threaded PARDISO rounds differently
    from one process to the next (the default sensor's gravity state: 1 process in 6), so the same
    scene gave different contact iterations; fem.linsolve switches the mode on (AUTO) unless the user
    set MKL_CBWR. A race shows too seldom to test here directly: the mode is checked, and that two
    factorisations in one process give the same bits."""
    import ctypes
    import os

    from fem import linsolve

    if os.environ.get("MKL_CBWR"):
        pytest.skip("MKL_CBWR is set in the environment: the user's choice of mode stands")
    lib = linsolve._pardiso_library().libmkl
    lib.MKL_CBWR_Get.restype, lib.MKL_CBWR_Get.argtypes = ctypes.c_int, [ctypes.c_int]
    assert lib.MKL_CBWR_Get(1) == linsolve.MKL_CBWR_AUTO  # 1: MKL_CBWR_BRANCH, the code path chosen
    d = _cube("P2", n=4)
    K = assemble(d, LAM, MU)
    free = np.setdiff1d(np.arange(d.n_dofs), np.flatnonzero(d.u.doflocs[2][: d.n_u] < 1e-9))
    Kff = K[free][:, free]
    B = np.random.default_rng(3).normal(size=(Kff.shape[0], 3))
    first, second = (factorise(Kff, definite=True, backend="pardiso").solve(B) for _ in range(2))
    assert first.tobytes() == second.tobytes()


@pytest.mark.skipif("pardiso" not in available_backends(), reason="MKL PARDISO (pypardiso) is not installed on this machine")
def test_pypardiso_is_pointed_at_the_library_its_own_search_finds(monkeypatch):
    """fem.linsolve sets PYPARDISO_MKL_RT (pypardiso's search: 0.9 s in every new process) to the
    mkl_rt pypardiso's recursive glob of sys.prefix would load first; a value the user set stays."""
    import glob
    import os
    import sys

    from fem import linsolve

    monkeypatch.delenv("PYPARDISO_MKL_RT", raising=False)
    linsolve._point_pypardiso_at_mkl()
    theirs = sorted(glob.glob(f"{sys.prefix}/[Ll]ib*/**/*mkl_rt*", recursive=True), key=len)
    if theirs:  # an MKL found by pypardiso's find_library instead (a system one) is left to pypardiso
        assert os.environ["PYPARDISO_MKL_RT"] == theirs[0]
    monkeypatch.setenv("PYPARDISO_MKL_RT", "/elsewhere/libmkl_rt.so")
    linsolve._point_pypardiso_at_mkl()
    assert os.environ["PYPARDISO_MKL_RT"] == "/elsewhere/libmkl_rt.so"


# ---------------------------------------------------------------------------------- stress
@pytest.mark.parametrize("element", ["P1", "P2", "P2P1"])
def test_stress_operator_is_exact_for_a_linear_field(element):
    """A linear displacement u = A x has the constant strain sym(A): every tet's centroid stress
    must equal Hooke's law of it (P2P1: with the pressure field p = lambda tr(eps))."""
    d = _cube(element)
    A = np.array([[1.0, 0.3, -0.2], [0.1, -0.5, 0.4], [0.2, 0.0, 0.7]]) * 1e-3
    comp = dof_components(d.u)
    x = np.zeros(d.n_dofs)
    x[: d.n_u] = np.einsum("ij,jn->in", A, d.u.doflocs)[comp, np.arange(d.n_u)]
    eps = 0.5 * (A + A.T)
    if d.p is not None:
        assemble(d, LAM, MU)  # sets the pressure scale
        x[d.n_u :] = LAM * np.trace(eps) / d.pressure_scale
    S = fields.stress_operator(d, np.full(d.u.mesh.nelements, LAM), np.full(d.u.mesh.nelements, MU))
    sigma = (S @ x).reshape(6, -1)
    ref = LAM * np.trace(eps) * np.eye(3) + 2 * MU * eps
    for r, (a, b) in enumerate(fields.VOIGT):
        np.testing.assert_allclose(sigma[r], ref[a, b], rtol=1e-10, atol=1e-10 * np.abs(ref).max())


def test_von_mises_and_energy_reference_values():
    E, nu = 1.5e6, 0.3
    lam, mu = E * nu / ((1 + nu) * (1 - 2 * nu)), E / (2 * (1 + nu))
    uniaxial = np.array([2e5, 0, 0, 0, 0, 0.0])
    assert fields.von_mises(uniaxial) == pytest.approx(2e5)
    assert fields.strain_energy_density(uniaxial, lam, mu) == pytest.approx(2e5**2 / (2 * E), rel=1e-12)  # sigma^2 / 2E
    shear = np.array([0, 0, 0, 0, 0, 1e5])
    assert fields.von_mises(shear) == pytest.approx(math.sqrt(3) * 1e5)
    assert fields.strain_energy_density(shear, lam, mu) == pytest.approx(1e5**2 / (2 * mu), rel=1e-12)  # tau^2 / 2G
    # the complementary form stays finite as lambda -> infinity: hydrostatic stress stores nothing
    assert fields.strain_energy_density(np.array([1e5, 1e5, 1e5, 0, 0, 0.0]), 1e20, mu) == pytest.approx(0.0, abs=1e-9)


def test_von_mises_from_voigt_equals_the_tensor_form():
    from fem.materials import linear_elastic

    sigma = np.random.default_rng(3).standard_normal((6, 4, 5)) * 1e5
    np.testing.assert_allclose(fields.von_mises(sigma), linear_elastic.von_mises(fields.voigt_to_tensor(sigma)), rtol=1e-12)


# ---------------------------------------------------------------------------------- trajectory
def _load_scene(segments, indenter=None):
    return scene_from_dict({
        "load": {
            "indenter": indenter or {"shape": "flat", "diameter_mm": 10.0},
            "start_xy_mm": [1.0, 2.0],
            "start_gap_mm": 0.5,
            "segments": segments,
        }
    })


def test_path_positions_at_segment_ends():
    scene = _load_scene([
        {"kind": "press", "depth_mm": 1.5, "speed_mm_s": 10.0},  # 0.15 s
        {"kind": "hold", "duration_s": 0.1},
        {"kind": "slide", "distance_mm": 4.0, "speed_mm_s": 40.0, "direction_deg": 90.0},  # 0.1 s
        {"kind": "rotate", "angle_deg": -30.0, "rate_deg_s": 300.0},  # 0.1 s
        {"kind": "release", "distance_mm": 2.0, "speed_mm_s": 20.0},  # 0.1 s
    ])
    load = scene.load
    tip = 0.011
    s0 = trajectory.initial_state(load, tip)
    assert s0.position_m == pytest.approx((1e-3, 2e-3, tip + 0.5e-3))

    def at(t):
        return trajectory.advance(load, s0, t)

    assert at(0.075).position_m[2] == pytest.approx(tip + 0.5e-3 - 0.75e-3)  # half the press
    assert at(0.25).position_m == pytest.approx((1e-3, 2e-3, tip - 1.0e-3))  # pressed and held
    assert at(0.35).position_m == pytest.approx((1e-3, 6e-3, tip - 1.0e-3))  # slid +y by 4 mm
    assert at(0.45).yaw_rad == pytest.approx(math.radians(-30.0))
    assert at(0.55).position_m[2] == pytest.approx(tip + 1.0e-3)
    assert at(1.0).position_m == at(0.55).position_m  # after the end it stays
    # walking in small steps lands where one big step does
    s = s0
    for t in np.linspace(0, 0.55, 57)[1:]:
        s = trajectory.advance(load, s, t)
    assert s.position_m == pytest.approx(at(0.55).position_m, abs=1e-12)
    grid = trajectory.time_grid(load, 30.0, substeps=3)
    assert grid.n_frames == math.ceil(0.55 * 30) + 2
    np.testing.assert_allclose(grid.step_times_s[grid.frame_step], grid.frame_times_s)


def test_force_ramp_targets():
    scene = _load_scene([
        {"kind": "press", "force_n": 8.0, "duration_s": 0.2},
        {"kind": "slide", "distance_mm": 2.0, "speed_mm_s": 20.0},
        {"kind": "release", "distance_mm": 1.0, "speed_mm_s": 10.0},
    ])
    load = scene.load
    s0 = trajectory.initial_state(load, 0.011)
    assert trajectory.advance(load, s0, 0.05).force_target_n == pytest.approx(2.0)  # linear ramp from 0
    s = s0
    for t in (0.05, 0.1, 0.15):
        s = trajectory.advance(load, s, t, force_now_n=0.0)
    assert s.force_target_n == pytest.approx(6.0)
    held = trajectory.advance(load, s, 0.25)
    assert held.force_target_n == pytest.approx(8.0)  # the slide keeps the force
    assert held.position_m[0] == pytest.approx(1e-3 + 1e-3)
    assert trajectory.advance(load, held, 0.35).force_target_n is None  # release: displacement control


# ---------------------------------------------------------------------------------- indenters
def test_rounded_flat_punch_distances():
    a, h, re = 5e-3, 4e-3, 0.5e-3
    shape = IndenterShape("flat", (a, h), re)
    pts = np.array([
        [0.0, 0.0, -1e-3],  # under the face: 1 mm
        [a + 1e-3, 0.0, 2e-3],  # beside the side wall: 1 mm
        [a - re, 0.0, -1e-3],  # under the rim's start: still the flat face
    ])
    np.testing.assert_allclose(signed_distance_local(shape, pts), [1e-3, 1e-3, 1e-3], rtol=1e-12)
    # diagonally off the rounded corner: distance to the rim's torus
    c = np.array([a - re, 0.0, re])
    p = c + (re + 1e-3) * np.array([1, 0, -1]) / np.sqrt(2)
    assert signed_distance_local(shape, p[None])[0] == pytest.approx(1e-3, rel=1e-12)
    with pytest.raises(ValueError, match="edge_radius"):
        IndenterShape("flat", (a, h), 3e-3)


def test_rigid_motion_of_a_turning_indenter():
    old, new = Pose((0.0, 0.0, 0.0), 0.0), Pose((1e-3, 0.0, 0.0), math.pi / 2)
    X = np.array([[1e-3, 0.0, 0.0]])
    # a point 1 mm along x of the old pose sits 1 mm along y of the new one
    np.testing.assert_allclose(rigid_motion(old, new, X)[0], [0.0, 1e-3, 0.0], atol=1e-15)
    gap, n = gap_and_normal(IndenterShape("sphere", (1e-3,)), Pose((0, 0, 0)), np.array([[0, 0, -0.5e-3]]))
    assert gap[0] == pytest.approx(0.5e-3) and n[:, 0] == pytest.approx([0, 0, -1])
