"""Compile the suite's numba kernels once, before pytest-xdist's workers start (``pytest --warm-kernels``,
which ``make test`` passes).

Why: the kernels are ``cache=True``, but a fresh clone's cache is empty, and each xdist worker that meets a
kernel before the other has cached it compiles it again. The Cosserat rods' Newton takes 45 s to compile and
the contact's ADMM 40 s (2-vCPU EPYC), so the two workers spent minutes compiling the same code twice. Here
each group compiles in its own process, the two at once, into numba's cache that the workers then load.

Each group runs the package's own entry points on small inputs, so that the kernels are compiled for the
argument types the tests and the scenes pass:

- ``rods``: a Cosserat cantilever (:func:`fem.cosserat_rod.solve_static`: the batched Newton and its trust
  region) and the kernels' own pieces that tests/test_cosserat_kernels.py checks one by one; the compliant limb
  shell's pose estimators on a short series (planar and 6-DoF); the plantar skin's 250 Hz tick, a series and
  double support (87 s cold on a 2-vCPU EPYC, the ``chain`` group 121 s: the two end about together);
- ``chain``: the tiny scene (``scenes/mavig_tiny.toml``) to the camera, on the session's cache
  (``MLSIM_CACHE_DIR``), so that its precomputes are the tests' too: the indenters' distance, the contact's
  ADMM, the fields, the emission, the render's raster and transport, the camera.

Usage: ``python tests/warm_kernels.py GROUP`` (``rods`` or ``chain``); the conftest runs one process a group.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
GROUPS = ("rods", "chain")


def rods() -> None:
    import numpy as np

    from fem import cosserat_kernels as ck
    from fem import cosserat_rod as cr
    from other_sensors.cls import ltv
    from other_sensors.cls.estimator import LmSettings, estimate_poses, estimate_poses6
    from other_sensors.cls.shell import ADC_RANGE_V, measure, measure6, trajectory, trajectory6
    from other_sensors.sole.cells import sole_layout
    from other_sensors.sole.contact import FootPose
    from other_sensors.sole.estimators import convex_hull
    from other_sensors.sole.tick import SkinEstimator, double_support, estimate_series

    section = cr.RodSection.circular(0.009, 2.5e-3, 1e6, 0.45)
    state = cr.solve_static(section, 4, tip_force_n=(1e-3, 0.0, -1e-3))
    args = ck.flatten_problem(state, section, np.array([1.0, 0.0, 0.0, 0.0]), np.array([1e-3, 0.0, 0.0]), np.zeros(3), None, (1,))
    ck.evaluate(*args[:3], section.length_m, section.S, section.B, *args[3:], section.axial_code)
    _, g, D, O = ck.evaluate(*args[:3], section.length_m, section.S, section.B, *args[3:])  # the linear axial law's default
    L, C, _ = ck.block_cholesky(D, O)
    step = ck.block_solve(L, C, g)
    ck.update(state.x[None], state.q[None], 1e-3 * step)

    rate, rest_s = 2000.0, 0.1
    t = np.arange(int(0.2 * rate)) / rate
    motion = (rest_s, 40.0, 10.0, 6.0, 6.0, 1.0)
    for layout, make, measure_, estimate in ((ltv.default_layout(), trajectory, measure, estimate_poses),
                                             (ltv.ring_layout(), trajectory6, measure6, estimate_poses6)):
        _, clean = measure_(make("general", t, *motion, np.random.default_rng(0)), layout, 0.0, np.random.default_rng(0))
        estimate(clean, layout, LmSettings(), int(rest_s * rate), ADC_RANGE_V)
    for jacobian in (False, True):
        ltv.planar_voltages(np.array([0.0, 40.0, 0.0]), ltv.default_layout(), jacobian=jacobian)

    rng = np.random.default_rng(0)
    skin = SkinEstimator(sole_layout(), 1.5, 0.01)
    forces = rng.uniform(0.0, 8.0, (3, 42, 3))
    gaps = rng.uniform(0.0, 0.02, (3, 42))
    wrench = np.concatenate([np.zeros((3, 2)), forces.sum(axis=(1, 2))[:, None], rng.normal(0.0, 6.0, (3, 2)), np.zeros((3, 1))], axis=1)
    one = skin(forces[0], gaps[0], wrench[0])
    estimate_series(skin, forces, gaps, wrench)
    convex_hull(rng.uniform(size=(10, 2)))
    double_support(one, FootPose((0.0, 0.0, 0.0)), one, FootPose((0.0, 0.2, 0.0)))


def chain() -> None:
    import os

    from mlsim import pipeline
    from mlsim.scene import load_scene

    cache = pipeline.Cache(os.environ["MLSIM_CACHE_DIR"])
    scene = load_scene(ROOT / "scenes" / "mavig_tiny.toml")
    pipeline.run(scene, cache=cache, outputs=("camera",), progress=False, log=lambda m: None)


def main(group: str) -> None:
    if group not in GROUPS:
        raise SystemExit(f"unknown group {group!r}: one of {', '.join(GROUPS)}")
    sys.path.insert(0, str(ROOT))
    start = time.perf_counter()
    globals()[group]()
    print(f"{group}: {time.perf_counter() - start:.1f} s")


if __name__ == "__main__":
    main(sys.argv[1])
