"""The elastica: large deflection of a cantilever under an end load, and its Euler buckling load.

A clamped inextensible Euler-Bernoulli rod of length L and bending stiffness EI carries a dead
force P at its free end, perpendicular to the undeformed axis (the force keeps its direction as the
rod bends). With theta0 the angle through which the tip turns and the load parameter

    alpha = P L^2 / (E I),

the exact solution is written with incomplete elliptic integrals of the first and second kind,
F(phi, k) and E(phi, k), with modulus k = sqrt((1 + sin theta0) / 2) and
phi1 = arcsin(1 / (k sqrt 2)) [BisshoppDrucker1945]_:

    sqrt(alpha)      = F(pi/2, k) - F(phi1, k)                      (fixes theta0 for a given alpha)
    delta / L        = 1 - 2 / sqrt(alpha) (E(pi/2, k) - E(phi1, k))  (tip deflection along P)
    (L - Delta) / L  = sqrt(2 sin theta0 / alpha)                    (tip position along the axis)

At small alpha, delta / L -> alpha / 3 (the linear cantilever). The rod buckles under an axial end
load at P_E = pi^2 E I / (4 L^2) (clamped-free), lowered by shear to Engesser's
P_E / (1 + P_E / (kappa G A)) [Engesser1891]_ ([TimoshenkoGere1961]_ sec. 2.17).

This is the beam model the nonlinear tier is verified against (tests/test_nonlinear_large_deflection.py):
it neglects axial stretch and shear in the deflection formulas (a slender rod), and the material is
linear in moment against curvature (a neo-Hookean rod's moment deviates by about its peak strain
squared).

References
----------
.. [BisshoppDrucker1945] K. E. Bisshopp, D. C. Drucker, "Large deflection of cantilever beams",
   Quarterly of Applied Mathematics 3 (1945) 272-275.
.. [Engesser1891] F. Engesser, "Die Knickfestigkeit gerader Staebe", Zentralblatt der
   Bauverwaltung 11 (1891) 483-486.
.. [TimoshenkoGere1961] S. P. Timoshenko, J. M. Gere, "Theory of Elastic Stability", 2nd ed.,
   McGraw-Hill (1961), sec. 2.7 (clamped-free column), 2.17 (shear).
"""

from __future__ import annotations

import math

import numpy as np
# scipy's integrator, root finder and elliptic integrals are imported where they are used: the buckling loads are
# read by every Cosserat solve (fem.rod_error), whose workers need not load scipy.integrate

__all__ = ["cantilever_tip", "cantilever_inclined_end", "centreline_under_point_load", "euler_load_clamped_free_n", "engesser_load_n",
           "haringx_load_n"]


def _alpha_of_tip_angle(theta0: float) -> tuple[float, float, float]:
    """(sqrt alpha, k^2, phi1) of the elastica whose tip angle is theta0 (rad, 0 < theta0 < pi/2)."""
    from scipy.special import ellipkinc

    k2 = 0.5 * (1.0 + math.sin(theta0))
    phi1 = math.asin(min(1.0, 1.0 / math.sqrt(2.0 * k2)))
    return float(ellipkinc(0.5 * math.pi, k2) - ellipkinc(phi1, k2)), k2, phi1


def cantilever_tip(alpha: float) -> tuple[float, float, float]:
    """The tip of a cantilever under a dead end load perpendicular to its axis.

    alpha: P L^2 / (E I) >= 0. Returns (delta / L, (L - Delta) / L, theta0): the deflection along the
    load, the tip's position along the undeformed axis (both over L), and the tip angle (rad).
    """
    if not (np.isfinite(alpha) and alpha >= 0.0):
        raise ValueError(f"alpha = {alpha}: must be a finite P L^2 / EI >= 0")
    if alpha == 0.0:
        return 0.0, 1.0, 0.0
    from scipy.optimize import brentq
    from scipy.special import ellipeinc

    root = math.sqrt(alpha)
    # sqrt(alpha) rises monotonically from 0 to infinity as theta0 goes from 0 to pi/2
    hi = 0.5 * math.pi - 1e-12
    theta0 = brentq(lambda t: _alpha_of_tip_angle(t)[0] - root, 1e-12, hi, xtol=1e-14, rtol=1e-14)
    _, k2, phi1 = _alpha_of_tip_angle(theta0)
    delta = 1.0 - 2.0 / root * (ellipeinc(0.5 * math.pi, k2) - ellipeinc(phi1, k2))
    along = math.sqrt(2.0 * math.sin(theta0) / alpha)
    return float(delta), float(along), float(theta0)


def cantilever_inclined_end(alpha: float, phi_rad: float) -> tuple[float, float, float]:
    """The end of a cantilever under a dead end load inclined by ``phi_rad`` from the perpendicular
    to its axis towards its base (phi = 0: :func:`cantilever_tip`'s load; phi = pi / 2: an axial
    compression), by shooting from the clamp.

    With s over L, theta the rod's angle from its undeformed axis and P the load's magnitude,
    E I theta' = (moment of P about the point s) gives theta'' = -alpha cos(theta - phi),
    theta(0) = 0, theta'(1) = 0 [FrischFay1962]_; the end is at (x, z) = int (sin theta, cos theta) ds.
    The initial curvature theta'(0) is found by bracketing in [0, 2 alpha] (the end moment vanishes
    at one curvature there while cos(theta - phi) > 0 along the rod: the branch that starts from
    the unloaded rod, below the inclined load's buckling). A frictionless contact on the rod's side
    is this load with phi equal to the end angle (the contact force is normal to the rod).

    alpha: P L^2 / (E I) >= 0. Returns (x / L across, z / L along the undeformed axis, theta_end rad).

    References
    ----------
    .. [FrischFay1962] R. Frisch-Fay, "Flexible Bars", Butterworths (1962), ch. 2 (the cantilever
       under an inclined end load).
    """
    if not (np.isfinite(alpha) and alpha >= 0.0):
        raise ValueError(f"alpha = {alpha}: must be a finite P L^2 / EI >= 0")
    if not (np.isfinite(phi_rad) and -0.5 * math.pi < phi_rad <= 0.5 * math.pi):
        raise ValueError(f"phi_rad = {phi_rad}: must be in (-pi/2, pi/2]")
    if alpha == 0.0:
        return 0.0, 1.0, 0.0
    from scipy.integrate import solve_ivp
    from scipy.optimize import brentq

    def rhs(_, y):
        return [y[1], -alpha * math.cos(y[0] - phi_rad), math.sin(y[0]), math.cos(y[0])]

    def end(curvature0):
        return solve_ivp(rhs, (0.0, 1.0), [0.0, curvature0, 0.0, 0.0], rtol=1e-11, atol=1e-12).y[:, -1]

    lo, hi = 0.0, 2.0 * alpha
    if not (end(lo)[1] <= 0.0 <= end(hi)[1]):
        raise ValueError(f"alpha = {alpha}, phi = {phi_rad} rad: no equilibrium on the branch from the unloaded rod "
                         "(past the inclined load's buckling)")
    c0 = brentq(lambda c: end(c)[1], lo, hi, xtol=1e-13, rtol=1e-13)
    y = end(c0)
    return float(y[2]), float(y[3]), float(y[0])


def centreline_under_point_load(force_n: tuple[float, float], through_m: tuple[float, float], bending_stiffness_n_m2: float,
                                 s_m: float, small_rotation: bool = False) -> tuple[float, float, float]:
    """The centreline of a clamped rod (base at the origin, axis along z) at arc length ``s_m`` below a
    point load ``force_n`` = (F_x, F_z) whose line of action passes through ``through_m`` = (A_x, A_z), by
    integrating from the clamp.

    Below the loaded section the bending moment about the centreline point X(s) is that of the load,
    M(s) = F_x (A_z - z(s)) - F_z (A_x - x(s)), and E I theta' = M with x' = sin theta, z' = cos theta,
    theta(0) = 0: an initial value problem, so neither the section where the load acts nor the rod above
    it is needed (a frictionless contact on a rod's side acts along the common normal through the
    indenter's axis, a point every step knows). ``small_rotation``: the moment from the undeformed
    geometry, M(s) = F_x (A_z - s) - F_z A_x, and x'' = M / E I (the linear beam), for comparison.

    Returns (x, z, theta) at s: m, m, rad. Euler's elastica as in [FrischFay1962]_, ch. 1.
    """
    fx, fz = (float(v) for v in force_n)
    ax, az = (float(v) for v in through_m)
    if not (np.isfinite(bending_stiffness_n_m2) and bending_stiffness_n_m2 > 0.0):
        raise ValueError(f"bending_stiffness_n_m2 = {bending_stiffness_n_m2}: must be a finite E I > 0")
    if not (np.isfinite(s_m) and s_m >= 0.0) or not np.all(np.isfinite([fx, fz, ax, az])):
        raise ValueError(f"s_m = {s_m}, force_n = {force_n}, through_m = {through_m}: must be finite, s_m >= 0")
    from scipy.integrate import solve_ivp

    def rhs(s, y):
        theta, x, z = y
        if small_rotation:
            return [(fx * (az - s) - fz * ax) / bending_stiffness_n_m2, theta, 1.0]
        return [(fx * (az - z) - fz * (ax - x)) / bending_stiffness_n_m2, math.sin(theta), math.cos(theta)]

    theta, x, z = solve_ivp(rhs, (0.0, s_m), [0.0, 0.0, 0.0], rtol=1e-10, atol=1e-14).y[:, -1]
    return float(x), float(z), float(theta)


def euler_load_clamped_free_n(bending_stiffness_n_m2: float, length_m: float) -> float:
    """P_E = pi^2 E I / (4 L^2): the buckling load (N) of a column clamped at its base, free at its tip."""
    return math.pi**2 * bending_stiffness_n_m2 / (4.0 * length_m**2)


def engesser_load_n(bending_stiffness_n_m2: float, shear_stiffness_n: float, length_m: float) -> float:
    """Engesser's shear-corrected buckling load P_E / (1 + P_E / (kappa G A)) (N), clamped-free.

    shear_stiffness_n: kappa G A (N)."""
    pe = euler_load_clamped_free_n(bending_stiffness_n_m2, length_m)
    return pe / (1.0 + pe / shear_stiffness_n)


def haringx_load_n(bending_stiffness_n_m2: float, shear_stiffness_n: float, length_m: float) -> float:
    """Haringx's shear-corrected buckling load (kappa G A / 2) (sqrt(1 + 4 P_E / (kappa G A)) - 1) (N),
    clamped-free [Haringx1948]_: the load of a rod whose shear strain is measured in the section's own
    (rotated) frame, as a Cosserat (Reissner) rod's is (fem.cosserat_rod), where Engesser's measures it
    against the undeformed axis. The two agree to first order in P_E / (kappa G A) and differ by about
    (P_E / kappa G A)^2 / 2 of P_E (0.3 % at P_E = 0.08 kappa G A).

    shear_stiffness_n: kappa G A (N).

    References
    ----------
    .. [Haringx1948] J. A. Haringx, "On highly compressible helical springs and rubber rods, and their
       application for vibration-free mountings", Philips Research Reports 3 (1948) 401-449.
    """
    pe = euler_load_clamped_free_n(bending_stiffness_n_m2, length_m)
    return 0.5 * shear_stiffness_n * (math.sqrt(1.0 + 4.0 * pe / shear_stiffness_n) - 1.0)
