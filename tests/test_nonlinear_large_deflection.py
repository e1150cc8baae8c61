"""The nonlinear tier at large deflection, against closed forms (issue #37, item 1).

A slender square cantilever (20:1, 2 x 2 x 20 hexahedra split into tetrahedra, P2P1, the elastomer's
nu = 0.49) under a dead end load is compared with the elastica of Bisshopp and Drucker
(:mod:`fem.elastica`) up to P L^2 / EI = 5, and its clamped-free buckling load with Engesser's
shear-corrected Euler load. The mesh's own linear bending error is taken out first: the bending
stiffness EI of the comparisons is the one this mesh shows under a small end load
(EI = P L^3 / 3 delta; 2.1 % above E h^4 / 12 here), so what is left is the large-deflection answer.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from beam_helpers import buckling_load, square_beam
from scipy.integrate import solve_ivp
from scipy.optimize import brentq

from fem.elastica import cantilever_inclined_end, cantilever_tip, centreline_under_point_load, engesser_load_n, euler_load_clamped_free_n
from fem.elasticity import assemble, solve_static
from fem.materials.linear_elastic import lame_parameters
from fem.nonlinear import solve_nonlinear

SIDE, LENGTH = 1e-3, 20e-3
YOUNG, POISSON = 1.5e6, 0.49
LAM, MU = lame_parameters(YOUNG, POISSON)


@pytest.fixture(scope="module")
def beam():
    d, fixed, lateral, axial, tip = square_beam(SIDE, LENGTH, 2, 20)
    linear = solve_static(assemble(d, LAM, MU), lateral, fixed)
    bending_stiffness = LENGTH**3 / (3.0 * tip(linear)[0])  # this mesh's EI (N m^2)
    return d, fixed, lateral, axial, tip, bending_stiffness


def _shooting(alpha: float) -> tuple[float, float]:
    """The elastica by shooting on EI theta'' = -P cos theta, theta(0) = 0, theta'(L) = 0 (s over L):
    (delta / L, tip position along the axis / L). Independent of the elliptic-integral closed form."""

    def rhs(_, y):
        return [y[1], -alpha * math.cos(y[0]), math.sin(y[0]), math.cos(y[0])]

    def end(curvature0):
        return solve_ivp(rhs, (0.0, 1.0), [0.0, curvature0, 0.0, 0.0], rtol=1e-11, atol=1e-12).y[:, -1]

    c0 = brentq(lambda c: end(c)[1], 0.0, 1.0001 * alpha)
    y = end(c0)
    return float(y[2]), float(y[3])


def test_the_elastica_closed_form():
    # the small-load limit is the linear cantilever, delta / L = alpha / 3
    delta, along, theta0 = cantilever_tip(1e-4)
    assert delta == pytest.approx(1e-4 / 3, rel=1e-3) and along == pytest.approx(1.0, abs=1e-8)
    # Bisshopp and Drucker's table: alpha = 1 -> 0.3017, alpha = 10 -> 0.8106 (four figures)
    assert cantilever_tip(1.0)[0] == pytest.approx(0.3017, abs=1e-4)
    assert cantilever_tip(10.0)[0] == pytest.approx(0.8106, abs=1e-4)
    # and the ODE shot from the clamp, an independent solution of the same problem
    for alpha in (0.5, 2.0, 5.0):
        delta, along, _ = cantilever_tip(alpha)
        ode_delta, ode_along = _shooting(alpha)
        assert delta == pytest.approx(ode_delta, abs=1e-7) and along == pytest.approx(ode_along, abs=1e-7)
    assert cantilever_tip(0.0) == (0.0, 1.0, 0.0)
    with pytest.raises(ValueError, match="alpha = -1"):
        cantilever_tip(-1.0)
    with pytest.raises(ValueError, match="alpha = nan"):
        cantilever_tip(float("nan"))


def test_the_centreline_below_a_point_load():
    """fem.elastica.centreline_under_point_load, integrated from the clamp: a horizontal load through the
    end's deformed height is Bisshopp and Drucker's cantilever; small-rotation, P L^3 / 3 E I; an axial
    load alone leaves the rod straight; bad input refused."""
    for alpha in (0.5, 2.0, 5.0):
        delta, along, theta0 = cantilever_tip(alpha)
        x, z, theta = centreline_under_point_load((alpha, 0.0), (delta, along), 1.0, 1.0)  # L = 1, E I = 1, P = alpha
        assert (x, z) == pytest.approx((delta, along), abs=1e-7)
        assert theta == pytest.approx(theta0, abs=1e-6)  # the end's rotation
    assert centreline_under_point_load((0.3, 0.0), (0.0, 1.0), 1.0, 1.0, small_rotation=True)[0] == pytest.approx(0.1, rel=1e-9)
    assert centreline_under_point_load((0.0, -0.5), (0.0, 1.0), 1.0, 1.0) == pytest.approx((0.0, 1.0, 0.0), abs=1e-12)
    with pytest.raises(ValueError, match="bending_stiffness_n_m2 = 0"):
        centreline_under_point_load((1.0, 0.0), (0.0, 1.0), 0.0, 1.0)
    with pytest.raises(ValueError, match="s_m = nan"):
        centreline_under_point_load((1.0, 0.0), (0.0, 1.0), 1.0, float("nan"))


def test_the_inclined_end_load_elastica():
    """fem.elastica.cantilever_inclined_end: the perpendicular load is Bisshopp and Drucker's closed form;
    a small inclined load bends the rod as its perpendicular part alone (alpha cos phi / 3); an axial
    load below buckling leaves it straight; an added axial part on the same perpendicular
    component deflects it more (P-delta); bad input is refused."""
    for alpha in (1.0, 3.0, 5.0):
        delta, along, theta = cantilever_tip(alpha)
        x, z, theta_end = cantilever_inclined_end(alpha, 0.0)
        assert (x, z, theta_end) == pytest.approx((delta, along, theta), abs=1e-8)
    for phi in (0.3, 1.0):
        x, z, _ = cantilever_inclined_end(1e-3, phi)
        assert x == pytest.approx(1e-3 * math.cos(phi) / 3.0, rel=2e-3) and z == pytest.approx(1.0, abs=1e-6)
    assert cantilever_inclined_end(2.0, 0.5 * math.pi) == pytest.approx((0.0, 1.0, 0.0), abs=1e-10)  # 2 < pi^2 / 4
    # a load tilted towards the base compresses the rod as it bends it: at alpha = 2 the tilted rod's
    # moment arm grows with its deflection (P-delta), so its deflection per unit perpendicular load is larger
    x0, _, _ = cantilever_inclined_end(2.0, 0.0)
    x1, _, _ = cantilever_inclined_end(2.0 / math.cos(0.4), 0.4)  # the same perpendicular component
    assert x1 > x0
    with pytest.raises(ValueError, match="alpha = -1"):
        cantilever_inclined_end(-1.0, 0.0)
    with pytest.raises(ValueError, match="phi_rad = 2"):
        cantilever_inclined_end(1.0, 2.0)


def test_a_cantilever_under_a_dead_end_load_follows_the_elastica(beam):
    """Tip deflection and tip position along the axis within 1 % of the elastica up to alpha = 5 (tip
    rotated 70 deg; measured 0.07-0.22 % and 0.02-0.11 %), and Newton's quadratic tail in every
    increment (the full-step Newton; backtracking on the residual stalled here)."""
    d, fixed, lateral, _, tip, ei = beam
    x, before = None, 0.0
    for alpha in (1.0, 3.0, 5.0):
        force = alpha * ei / LENGTH**2  # continued from the last answer: the load from `before` to `force`
        x, report = solve_nonlinear(d, LAM, MU, lambda t, a=before, b=force: (a + t * (b - a)) * lateral, fixed, increments=2, x0=x,
                                    max_iterations=20)
        before = force
        delta, along, _ = cantilever_tip(alpha)
        u = tip(x)
        assert u[0] / LENGTH == pytest.approx(delta, rel=0.01), alpha
        assert 1.0 + u[2] / LENGTH == pytest.approx(along, rel=0.01), alpha
        # out of the load's plane only what the tetrahedra's split of each hexahedron leaves (not mirror
        # symmetric in y: 1.4e-4 L measured at alpha = 1)
        assert abs(u[1]) <= 1e-3 * LENGTH
        for history in report.residuals:
            assert history[-1] <= 1e-8 * history[0]
            assert len(history) <= 12
        assert report.cuts == 0
    # the large-deflection answer is not the linear one: at alpha = 5 the linear tip is 2.3x too far
    assert tip(x)[0] / LENGTH < 0.5 * (5.0 / 3.0)


def test_the_clamped_free_buckling_load_is_engessers(beam):
    """Within 1 % of pi^2 EI / 4 L^2 / (1 + P_E / kappa G A) (measured 0.35 %), the same in both
    bending planes of the square (to 0.1 %), and above it by the shear term's share."""
    d, fixed, _, axial, _, ei = beam
    load, factors = buckling_load(d, fixed, axial, ei, LENGTH, LAM, MU)
    shear = 10.0 * (1.0 + POISSON) / (12.0 + 11.0 * POISSON) * YOUNG / (2.0 * (1.0 + POISSON)) * SIDE**2  # Cowper's kappa G A
    assert load == pytest.approx(engesser_load_n(ei, shear, LENGTH), rel=0.01)
    assert factors[1] == pytest.approx(factors[0], rel=1e-3)
    assert load < euler_load_clamped_free_n(ei, LENGTH)
