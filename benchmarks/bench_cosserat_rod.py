"""The discrete Cosserat rod's cost per frame (fem.cosserat_rod, issue 38's fast tier, first part): the
default sensor's 25 rods (5 mm x 9 mm, SC37-like E = 1.5 MPa, nu = 0.49) as one batch, each step a new
tip load from the last step's equilibrium, as the tier will solve a frame. Prints the median and worst
milliseconds per step and Newton iterations, at 4, 8 and 16 segments per rod, and the tip's deflection
against the 16-segment answer (the discretisation's error at that load); then numpy against the
compiled kernels (fem.cosserat_kernels, ``solve_static(compiled=True)``) per load step and per Newton
iteration, on 25 rods under tip loads and on 9 rods under 40 point loads each (the contact forces of
fem.rod_exact), at 8 and 16 segments.

    .venv/bin/python benchmarks/bench_cosserat_rod.py

Measured 2026-11-27 on the 2-core machine, loaded (a sweep and a test run beside it): 16 / 8 / 4
segments, median 97.6 / 48.9 / 19.2 ms a step (worst 199 / 69 / 100 ms), tip within 0.6 % (8) and
2.9 % (4) of 16 segments' answer. numpy's per-call overhead over small arrays dominates: the tier's
300 frames/s asks for compiled kernels (numba, as fem.residual_kernels) over this reference.

Measured 2026-11-28 on the same 2-core machine (Intel Xeon, 2 vCPUs), loaded (load average 3.8-4.5
from other jobs), medians of 3 x 20 steps, ms a load step / ms a Newton iteration, numpy -> compiled:

    25 rods, tip loads,       N = 8:   29.2 -> 0.96  /  6.43 -> 0.30 (kernel 0.22), 3.5 iterations a step
    25 rods, tip loads,       N = 16: 114   -> 1.79  / 22.6  -> 0.41 (kernel 0.37), 4
    9 rods, 40 point loads,   N = 8:   12.8 -> 0.40  /  3.20 -> 0.14 (kernel 0.07), 3
    9 rods, 40 point loads,   N = 16:  35.0 -> 1.14  /  7.11 -> 0.29 (kernel 0.18), 4

no rod fell back to the numpy trust region, the answers equal to 1e-15 of L. What is left over the
kernel (~0.1 ms a call) is solve_static's Python: its checks, tolerances and the flattening.
"""

from __future__ import annotations

import os
import time

import numpy as np

from fem import cosserat_kernels as ck
from fem import cosserat_rod as cr

RODS, STEPS, REPEATS = 25, 20, 3


def _tip_loads(section, rods, rng):
    """A press then a shear: up to 0.6 of the rods' Euler load down, up to alpha = 2 sideways, in STEPS ramps (STEPS, rods, 3)."""
    p_euler = np.pi**2 * section.B[0] / (4 * section.length_m**2)
    ramp = np.linspace(0.05, 1.0, STEPS)[:, None, None]
    base = np.stack([2.0 * section.B[0] / section.length_m**2 * rng.uniform(0.2, 1.0, rods),
                     0.5 * section.B[0] / section.length_m**2 * rng.uniform(-1, 1, rods), -0.6 * p_euler * rng.uniform(0.2, 1.0, rods)], axis=-1)
    return ramp * base


def _roots(rods):
    side = int(np.ceil(np.sqrt(rods)))
    roots = np.stack(np.meshgrid(np.arange(side) * 7.2e-3, np.arange(side) * 7.2e-3), -1).reshape(-1, 2)[:rods]
    return np.concatenate([roots, np.zeros((rods, 1))], axis=-1)


def _point_loads(section, n, rods, k, rng):
    """k contact points a rod on its side and tip face (radius 2.5 mm), the forces (STEPS, rods, k, 3)
    ramping to a shear of alpha ~ 1.5 and a press of 0.3 of the Euler load in all."""
    segment = rng.integers(n // 2, n, (rods, k))
    along = rng.uniform(0.0, 1.0, (rods, k))
    angle = rng.uniform(0.0, 2 * np.pi, (rods, k))
    offset = 2.5e-3 * np.stack([np.cos(angle), np.sin(angle), np.zeros_like(angle)], -1)
    p_euler = np.pi**2 * section.B[0] / (4 * section.length_m**2)
    total = np.array([1.5 * section.B[0] / section.length_m**2, 0.4 * section.B[0] / section.length_m**2, -0.3 * p_euler])
    share = rng.uniform(0.5, 1.5, (rods, k, 1)) / k
    force = total * share * rng.uniform(0.5, 1.0, (rods, 1, 1))
    ramp = np.linspace(0.05, 1.0, STEPS)[:, None, None, None]
    return segment, along, offset, ramp * force


class _Counter:
    """Newton iterations of the last solve: numpy's (Hessians made by cr._newton) and the compiled
    kernel's (the most any rod took), wrapped around the module functions for this benchmark only."""

    def __init__(self):
        self.numpy = self.compiled = self.fallbacks = 0
        self.kernel_s = 0.0  # time in newton_batch itself (without solve_static's and the flattening's Python)
        self._gh, self._nb = cr.gradient_and_hessian, ck.newton_batch

        def gh(*args, **kwargs):
            if kwargs.get("hessian", True):
                self.numpy += 1
            return self._gh(*args, **kwargs)

        def nb(*args):
            t0 = time.perf_counter()
            status, iterations = self._nb(*args)
            self.kernel_s += time.perf_counter() - t0
            self.compiled += int(iterations.max(initial=0))
            self.fallbacks += int(np.count_nonzero(status))
            return status, iterations

        cr.gradient_and_hessian, ck.newton_batch = gh, nb

    def take(self):
        out = (self.numpy + self.compiled, self.fallbacks, 1e3 * self.kernel_s)
        self.numpy = self.compiled = self.fallbacks = 0
        self.kernel_s = 0.0
        return out


def _run(section, n, roots, steps, compiled, counter):
    """Per load step: (ms, Newton iterations, rods that fell back, ms in the kernel), over REPEATS runs of the
    steps; the answer."""
    out = []
    for _ in range(REPEATS):
        state = cr.straight_rod(section, n, roots)
        counter.take()
        for kwargs in steps:
            t0 = time.perf_counter()
            state = cr.solve_static(section, n, root_m=roots, start=state, compiled=compiled, **kwargs)
            ms = 1e3 * (time.perf_counter() - t0)
            out.append((ms,) + counter.take())
    return np.array(out), state


def _machine() -> str:
    """The processor's name and count, for the printed figures (timings on a shared machine move 2x with its load)."""
    try:
        with open("/proc/cpuinfo") as f:
            name = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        import platform

        name = platform.processor() or "unknown processor"
    return f"{name}, {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.2f}"


def compare() -> None:
    """numpy against compiled on the tip-loaded batch of 25 and the point-loaded batch of 9."""
    section = cr.RodSection.circular(9e-3, 2.5e-3, 1.5e6, 0.49)
    rng = np.random.default_rng(0)
    counter = _Counter()
    cr.solve_static(section, 8, tip_force_n=(1e-3, 0.0, 0.0), loads=cr.PointLoads(np.array([7]), np.array([1.0]), np.zeros((1, 3)),
                                                                                  np.zeros((1, 3))))  # numba's compile (or cache load)
    print(f"\nnumpy against compiled (fem.cosserat_kernels), {STEPS} load steps x {REPEATS} repeats, medians; {_machine()}")
    print(f"{'case':>22} {'N':>3} {'numpy ms/step':>13} {'compiled':>9} {'numpy ms/it':>12} {'compiled':>9} {'kernel':>7} "
          f"{'its/step':>9} {'fallbacks':>9} {'|dx|/L':>8}")
    for label, rods, k in (("25 rods, tip loads", 25, 0), ("9 rods, 40 point loads", 9, 40)):
        for n in (8, 16):
            roots = _roots(rods)
            if k:
                segment, along, offset, force = _point_loads(section, n, rods, k, rng)
                steps = [dict(loads=cr.PointLoads(segment, along, offset, f)) for f in force]
            else:
                steps = [dict(tip_force_n=f) for f in _tip_loads(section, rods, rng)]
            rows = {}
            for compiled in (False, True):
                rows[compiled] = _run(section, n, roots, steps, compiled, counter)
            (a, sa), (b, sb) = rows[False], rows[True]
            diff = np.abs(sa.x - sb.x).max() / section.length_m
            print(f"{label:>22} {n:3d} {np.median(a[:, 0]):13.2f} {np.median(b[:, 0]):9.3f} {np.median(a[:, 0] / a[:, 1]):12.2f} "
                  f"{np.median(b[:, 0] / np.maximum(b[:, 1], 1)):9.3f} {np.median(b[:, 3] / np.maximum(b[:, 1], 1)):7.3f} "
                  f"{np.median(b[:, 1]):9.1f} {b[:, 2].sum() / REPEATS:9.0f} {diff:8.1e}")
    print(f"(ms/it: a step's time over its Newton iterations, the batch's (numpy) or its slowest rod's (compiled); kernel: "
          f"newton_batch's own time, without solve_static's Python; fallbacks: rods handed to the numpy trust region in the "
          f"{STEPS} steps, a repeat; |dx|/L: the last answers' difference; load average {os.getloadavg()[0]:.2f})")


def main() -> None:
    section = cr.RodSection.circular(9e-3, 2.5e-3, 1.5e6, 0.49)
    rng = np.random.default_rng(0)
    loads = _tip_loads(section, RODS, rng)
    roots = _roots(RODS)
    tips = {}
    print(f"{RODS} rods, {STEPS} load steps from the last equilibrium (one frame each), numpy")
    print(f"{'segments':>8} {'median ms':>10} {'worst ms':>9} {'tip error':>10}")
    for n in (16, 8, 4):
        state = cr.straight_rod(section, n, roots)
        times = []
        for step in range(STEPS):
            t0 = time.perf_counter()
            state = cr.solve_static(section, n, tip_force_n=loads[step], root_m=roots, start=state, compiled=False)
            times.append(time.perf_counter() - t0)
        tips[n] = state.x[:, -1] - roots
        err = float(np.abs(tips[n] - tips[16]).max() / np.abs(tips[16] - np.array([0, 0, section.length_m])).max())
        print(f"{n:8d} {1e3 * np.median(times):10.2f} {1e3 * max(times):9.2f} {err:10.2e}")
    compare()


if __name__ == "__main__":
    main()
