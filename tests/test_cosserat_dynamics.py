"""fem.cosserat_dynamics: the Cosserat rod's backward Euler inertia against closed forms."""

import numpy as np
import pytest

from fem import cosserat_dynamics as cd
from fem import cosserat_rod as cr
from fem.dynamics import cantilever_first_mode_rad_s

# a 12 x 5 mm silicone rod (the swipe's tallest), its shear made stiff where Euler-Bernoulli is the closed form
L, RADIUS, E, NU, RHO = 12e-3, 2.5e-3, 1.0e6, 0.45, 1100.0
AREA, I = np.pi * RADIUS**2, 0.25 * np.pi * RADIUS**4


def _section(shear_factor: float = 1.0) -> cr.RodSection:
    s = cr.RodSection.circular(L, RADIUS, E, NU)
    return cr.RodSection(s.length_m, s.axial_n, shear_factor * s.shear_n, s.bending_n_m2, s.torsion_n_m2)


def _inertia(dt: float, damping: float = 0.0) -> cd.RodInertia:
    return cd.RodInertia(RHO * AREA, dt, damping)


def test_the_discrete_rods_first_mode_converges_to_euler_bernoullis_at_second_order():
    section = _section(shear_factor=1e4)
    exact = cantilever_first_mode_rad_s(E * I, RHO * AREA, L)
    errors = [abs(cd.first_mode_rad_s(section, _inertia(1e-4), n) / exact - 1.0) for n in (8, 16, 32)]
    orders = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    assert errors[0] < 0.02  # the fast tier's 8 segments
    assert np.all(orders > 1.8), (errors, orders)


def _released(section, inertia, segments, tip_force_n, steps):
    """The tip's x (steps + 1,) m and the energies (elastic, kinetic) after releasing the rod bent by a tip force."""
    bent = cr.solve_static(section, segments, tip_force_n=tip_force_n, increments=4)
    state, v = bent, np.zeros_like(bent.x)
    tip, energy = [state.x[-1, 0]], []
    clamp = np.array([1.0, 0.0, 0.0, 0.0])
    for _ in range(steps):
        state, v = cd.step(section, inertia, state, v)
        tip.append(state.x[-1, 0])
        energy.append((float(cr.energy(state, section, clamp)), float(inertia.kinetic_energy_j(section, v))))
    return np.array(tip), np.array(energy)


def _one_mode_recurrence_roots(w: float, h: float, a: float) -> np.ndarray:
    """The roots of backward Euler's recurrence for x'' + a x' + w^2 x = 0: x_{k+1} (1 + a h + w^2 h^2) = x_k (2 + a h) - x_{k-1}."""
    return np.roots([1.0 + a * h + (w * h) ** 2, -(2.0 + a * h), 1.0])


def _fitted_roots(x: np.ndarray) -> np.ndarray:
    """The two roots of the linear recurrence x_{k+1} = c_1 x_k + c_2 x_{k-1} fitted by least squares."""
    A = np.column_stack([x[1:-1], x[:-2]])
    c, *_ = np.linalg.lstsq(A, x[2:], rcond=None)
    return np.roots([1.0, -c[0], -c[1]])


@pytest.mark.parametrize("damping_ratio", [0.0, 0.05])
def test_a_small_release_follows_backward_eulers_recurrence_of_the_first_mode(damping_ratio):
    section, segments = _section(), 8
    w = cd.first_mode_rad_s(section, _inertia(1e-4), segments)
    h = 2.0 * np.pi / w / 40.0  # 40 steps a period
    a = 2.0 * damping_ratio * w  # a_M = 2 zeta omega_1
    inertia = _inertia(h, a)
    tip, _ = _released(section, inertia, segments, (1e-4, 0.0, 0.0), 120)  # a 0.1 mN push: linear
    got, want = _fitted_roots(tip[10:]), _one_mode_recurrence_roots(w, h, a)  # after the higher modes died
    # each root's modulus (the decay a step) and angle (the period)
    np.testing.assert_allclose(np.sort(np.abs(got)), np.sort(np.abs(want)), rtol=2e-3)
    np.testing.assert_allclose(np.sort(np.abs(np.angle(got))), np.sort(np.abs(np.angle(want))), rtol=1e-2)
    # the recurrence's period is backward Euler's: longer than the mode's by about (w h)^2 / 3
    assert 2.0 * np.pi / np.abs(np.angle(want[0])) > 40.0


def test_a_large_release_never_gains_energy():
    section, segments = _section(), 8
    w = cd.first_mode_rad_s(section, _inertia(1e-4), segments)
    inertia = _inertia(2.0 * np.pi / w / 10.0)  # 10 steps a period
    load = 3.0 * E * I / L**2  # P L^2 / EI = 3: the tip turns by about 75 degrees
    tip, energy = _released(section, inertia, segments, (load, 0.0, 0.0), 40)
    total = energy.sum(axis=1)
    assert tip[0] > 0.5 * L
    assert np.all(np.diff(total) <= 1e-12 * total[0]), np.diff(total)
    assert tip.min() < -0.05 * L  # it swings through the straight state
    assert total[-1] < 0.5 * total[0]  # and backward Euler dissipates


def test_a_rod_at_rest_under_no_load_stays():
    section = _section()
    inertia = _inertia(1e-4, 10.0)
    rest = cr.straight_rod(section, 8, (1e-3, 2e-3, 0.0))
    state, v = cd.step(section, inertia, rest, np.zeros_like(rest.x))
    np.testing.assert_allclose(state.x, rest.x, atol=1e-15)
    np.testing.assert_allclose(v, 0.0, atol=1e-10)


def test_the_inertias_springs_hold_the_inertial_prediction():
    """A node's spring pulls it to x_n + h v_n (no damping) with m / h^2: the force at the prediction is zero."""
    section = _section()
    inertia = _inertia(1e-4)
    rest = cr.straight_rod(section, 8)
    v = np.zeros_like(rest.x)
    v[1:, 0] = np.linspace(0.1, 1.0, 8)
    springs = inertia.springs(section, rest.x, v)
    moved = cr.RodState(rest.x + inertia.time_step_s * v, rest.q)
    np.testing.assert_allclose(inertia.nodal_forces(springs, moved), 0.0, atol=1e-12)
    m = inertia.node_mass_kg(section, 8)
    assert m.sum() == pytest.approx(RHO * AREA * L)
    np.testing.assert_allclose(inertia.nodal_forces(springs, rest)[1:, 0], m[1:] * v[1:, 0] / inertia.time_step_s, rtol=1e-12)


@pytest.mark.parametrize("field, value", [("mass_per_length_kg_m", 0.0), ("time_step_s", -1.0), ("time_step_s", np.nan), ("damping_per_s", -1.0)])
def test_a_bad_inertia_is_refused_naming_the_field(field, value):
    kw = {"mass_per_length_kg_m": 1e-3, "time_step_s": 1e-4, "damping_per_s": 0.0, field: value}
    with pytest.raises(ValueError, match=field):
        cd.RodInertia(**kw)
