"""The nonlinear tier's large-deflection answer against an independent code: PyElastica's Cosserat rod.

The same problem in both: a slender clamped rod (20:1) under a dead end load perpendicular to its axis,
at load parameters alpha = P L^2 / EI of 1, 3 and 5. mlsim's nonlinear tier solves the 3-D mixed
neo-Hookean solid (a square 1 x 1 x 20 mm beam, 2 x 2 x 20 hexahedra split into P2P1 tetrahedra,
nu = 0.49; EI the mesh's own, from a small linear bend); PyElastica (Gazzola et al., Royal Society
Open Science 5 (2018) 171628; `pyelastica` on PyPI) integrates a discrete Cosserat rod (shear and
stretch included) explicitly in time with linear damping until it is at rest. Both against the
elastica closed form (fem.elastica, Bisshopp and Drucker 1945). Prints each code's tip deflection and
tip position along the axis over L, and their differences.

PyElastica converges to the elastica at first order in its element count n, from the stiff side: its
clamp (`OneEndFixedBC` on the first node and the first element's director) holds the whole first element
straight, and the rod's curvature lives at the n - 1 interior nodes, so a small tip load bends it as a
clamped rod whose moment is sampled at the nodes, tip deflection (n - 1)(2n - 1) / (2 n^2) of the
continuum's (3 % short at n = 50). The benchmark therefore runs PyElastica at two element counts and
Richardson-extrapolates, d = 2 d(2n) - d(n), and compares mlsim with that limit. Measured (alpha = 1,
2 shared cores): n = 10 and 20 give 0.868 and 0.935 of the elastica, the limit 1.002 (PyElastica's
shear flexibility, 3 E I / (kappa G A L^2) = 0.15 % here, is in it; the elastica and mlsim's slender
beam have next to none). At alpha = 1, 3, 5 (2026-11-27, 2 loaded cores, 40 min): tip deflection over L,
elastica 0.30172 / 0.60325 / 0.71379, mlsim 0.30152 / 0.60202 / 0.71220, PyElastica's limit
0.30235 / 0.60526 / 0.71670: mlsim 0.27 / 0.54 / 0.63 % below PyElastica, each 0.07-0.41 % from the
elastica on either side; the tip along the axis within 0.2 %.

    .venv/bin/pip install pyelastica   # the `bench` extra: not needed by mlsim or its tests
    .venv/bin/python benchmarks/bench_elastica_pyelastica.py [--elements 10]   # 11-40 min
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

ALPHAS = (1.0, 3.0, 5.0)


def pyelastica_tip(alpha: float, elements: int) -> tuple[float, float, float]:
    """(delta / L, tip position along the axis / L, seconds) of PyElastica's rod at rest under the load."""
    import elastica as ea

    class Rod(ea.BaseSystemCollection, ea.Constraints, ea.Forcing, ea.Damping):
        pass

    length, radius, density, young, poisson = 1.0, 0.025, 1000.0, 1e6, 0.49
    sim = Rod()
    rod = ea.CosseratRod.straight_rod(elements, np.zeros(3), np.array([0.0, 0.0, 1.0]), np.array([1.0, 0.0, 0.0]), length, radius,
                                      density, youngs_modulus=young, shear_modulus=young / (2.0 * (1.0 + poisson)))
    sim.append(rod)
    sim.constrain(rod).using(ea.OneEndFixedBC, constrained_position_idx=(0,), constrained_director_idx=(0,))
    ei = young * np.pi * radius**4 / 4.0
    force = alpha * ei / length**2
    omega = 1.8751**2 * np.sqrt(ei / (density * np.pi * radius**2 * length**4))
    period = 2.0 * np.pi / omega
    sim.add_forcing_to(rod).using(ea.EndpointForces, np.zeros(3), np.array([force, 0.0, 0.0]), ramp_up_time=2.0 * period)
    dt = 0.02 * length / elements / np.sqrt(young / density)  # explicit: well inside the axial wave's limit
    sim.dampen(rod).using(ea.AnalyticalLinearDamper, damping_constant=2.0 * omega, time_step=dt)
    sim.finalize()
    t0 = time.perf_counter()
    final = 16.0 * period
    ea.integrate(ea.PositionVerlet(), sim, final, int(np.ceil(final / dt)), progress_bar=False)
    tip = rod.position_collection[:, -1]
    return float(tip[0] / length), float(tip[2] / length), time.perf_counter() - t0


def mlsim_tips() -> dict:
    """{alpha: (delta / L, tip position along the axis / L, seconds)} of the nonlinear tier."""
    from beam_helpers import square_beam

    from fem.elasticity import assemble, solve_static
    from fem.materials.linear_elastic import lame_parameters
    from fem.nonlinear import solve_nonlinear

    side, length = 1e-3, 20e-3
    lam, mu = lame_parameters(1.5e6, 0.49)
    d, fixed, lateral, _, tip = square_beam(side, length, 2, 20)
    ei = length**3 / (3.0 * tip(solve_static(assemble(d, lam, mu), lateral, fixed))[0])
    out, x, before = {}, None, 0.0
    for alpha in ALPHAS:
        t0 = time.perf_counter()
        force = alpha * ei / length**2
        x, _ = solve_nonlinear(d, lam, mu, lambda t, a=before, b=force: (a + t * (b - a)) * lateral, fixed, increments=2, x0=x)
        before = force
        u = tip(x)
        out[alpha] = (u[0] / length, 1.0 + u[2] / length, time.perf_counter() - t0)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--elements", type=int, default=10,
                        help="PyElastica's coarser rod (default 10); the finer has twice as many elements")
    args = parser.parse_args()
    from fem.elastica import cantilever_tip

    n = args.elements
    ours = mlsim_tips()
    print(f"PyElastica at n = {n} and {2 * n} elements, 'PyEl' their first-order Richardson limit 2 d({2 * n}) - d({n})")
    print(f"{'alpha':>5} | {'elastica d/L':>12} {'mlsim':>8} {f'PyEl n={n}':>10} {f'n={2 * n}':>8} {'PyEl':>8} {'mlsim-PyEl':>10} | "
          f"{'elastica x/L':>12} {'mlsim':>8} {'PyEl':>8} {'mlsim-PyEl':>10} | {'s mlsim':>7} {'s PyEl':>7}")
    for alpha in ALPHAS:
        d_ref, x_ref, _ = cantilever_tip(alpha)
        d_coarse, x_coarse, s_coarse = pyelastica_tip(alpha, n)
        d_fine, x_fine, s_fine = pyelastica_tip(alpha, 2 * n)
        d_pe, x_pe = 2.0 * d_fine - d_coarse, 2.0 * x_fine - x_coarse
        d_ml, x_ml, s_ml = ours[alpha]
        print(f"{alpha:5.1f} | {d_ref:12.5f} {d_ml:8.5f} {d_coarse:10.5f} {d_fine:8.5f} {d_pe:8.5f} {d_ml - d_pe:+10.5f} | "
              f"{x_ref:12.5f} {x_ml:8.5f} {x_pe:8.5f} {x_ml - x_pe:+10.5f} | {s_ml:7.1f} {s_coarse + s_fine:7.1f}", flush=True)


if __name__ == "__main__":
    main()
