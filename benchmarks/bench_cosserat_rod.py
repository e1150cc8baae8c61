"""The discrete Cosserat rod's cost per frame (fem.cosserat_rod, issue 38's fast tier, first part): the
default sensor's 25 rods (5 mm x 9 mm, SC37-like E = 1.5 MPa, nu = 0.49) as one batch, each step a new
tip load from the last step's equilibrium, as the tier will solve a frame. Prints the median and worst
milliseconds per step and Newton iterations, at 4, 8 and 16 segments per rod, and the tip's deflection
against the 16-segment answer (the discretisation's error at that load).

    .venv/bin/python benchmarks/bench_cosserat_rod.py

Measured 2026-11-27 on the 2-core machine, loaded (a sweep and a test run beside it): 16 / 8 / 4
segments, median 97.6 / 48.9 / 19.2 ms a step (worst 199 / 69 / 100 ms), tip within 0.6 % (8) and
2.9 % (4) of 16 segments' answer. numpy's per-call overhead over small arrays dominates: the tier's
300 frames/s asks for compiled kernels (numba, as fem.residual_kernels) over this reference.
"""

from __future__ import annotations

import time

import numpy as np

from fem import cosserat_rod as cr

RODS, STEPS = 25, 20


def main() -> None:
    section = cr.RodSection.circular(9e-3, 2.5e-3, 1.5e6, 0.49)
    rng = np.random.default_rng(0)
    # a press then a shear: up to 0.6 of the rods' Euler load down, up to alpha = 2 sideways
    p_euler = np.pi**2 * section.B[0] / (4 * section.length_m**2)
    ramp = np.linspace(0.05, 1.0, STEPS)[:, None, None]
    base = np.stack([2.0 * section.B[0] / section.length_m**2 * rng.uniform(0.2, 1.0, RODS),
                     0.5 * section.B[0] / section.length_m**2 * rng.uniform(-1, 1, RODS), -0.6 * p_euler * rng.uniform(0.2, 1.0, RODS)], axis=-1)
    loads = ramp * base
    roots = np.stack(np.meshgrid(np.arange(5) * 7.2e-3, np.arange(5) * 7.2e-3), -1).reshape(-1, 2)
    roots = np.concatenate([roots, np.zeros((RODS, 1))], axis=-1)
    tips = {}
    print(f"{RODS} rods, {STEPS} load steps from the last equilibrium (one frame each)")
    print(f"{'segments':>8} {'median ms':>10} {'worst ms':>9} {'tip error':>10}")
    for n in (16, 8, 4):
        state = cr.straight_rod(section, n, roots)
        times = []
        for step in range(STEPS):
            t0 = time.perf_counter()
            state = cr.solve_static(section, n, tip_force_n=loads[step], root_m=roots, start=state)
            times.append(time.perf_counter() - t0)
        tips[n] = state.x[:, -1] - roots
        err = float(np.abs(tips[n] - tips[16]).max() / np.abs(tips[16] - np.array([0, 0, section.length_m])).max())
        print(f"{n:8d} {1e3 * np.median(times):10.2f} {1e3 * max(times):9.2f} {err:10.2e}")


if __name__ == "__main__":
    main()
