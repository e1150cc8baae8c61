"""The nonlinear tier's implicit dynamics in an episode (fidelity.solve.dynamics, issue #37 item 2): slow
loading gives the quasi-static answer; a step too coarse for the rods' first mode and a negative loss
factor are refused naming the field."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fem import finite_strain
from fem import quasistatic as qs
from mlsim.errors import SceneError

# a sphere pressed straight down onto rods 2 and 3 of the tiny sensor (centres at x = +-3.6 mm, y = 3.6 mm)
PRESS = {
    "start_xy_mm": [0.0, 3.6],
    "start_gap_mm": 0.1,
    "indenter": {"shape": "sphere", "diameter_mm": 6.0},
    "segments": [{"kind": "press", "depth_mm": 0.35, "speed_mm_s": 40.0}],
}


def _scene(tiny_mesh, **solve):
    scene0, _, mesh, _ = tiny_mesh
    values = {"load": PRESS, "camera.fps": 400.0, "camera.exposure_ms": 2.5, "fidelity.solve.tier": "nonlinear"}
    values.update({f"fidelity.solve.{k}": v for k, v in solve.items()})
    return scene0.with_values(values), mesh


def test_a_slow_press_with_dynamics_is_the_quasi_static_press(tiny_mesh):
    """At 40 mm/s (the press lasts 8.75 ms, three periods of the rods' 323 Hz first mode) inertia and
    damping change the rods' forces by under 2 % of the largest (measured 0.5 % at the end of the press;
    1.2 % at the end of a 0.6 mm, 15 ms press, where the rods overshoot; equal to 1e-4 once held);
    every frame, per rod."""
    scene, mesh = _scene(tiny_mesh, dynamics="backward_euler", substeps=4)
    dyn = finite_strain.run_nonlinear_episode(scene, mesh)
    assert dyn.seconds["rod_first_mode_hz"] == pytest.approx(323.0, rel=0.02)
    static_scene, _ = _scene(tiny_mesh, substeps=4)
    static = finite_strain.run_nonlinear_episode(static_scene, mesh)
    frames = dyn.frame_step
    f_dyn, f_static = dyn.rod_force_n[frames][:, :, 2], static.rod_force_n[frames][:, :, 2]
    assert np.abs(f_static).max() > 0.02  # the rods are pressed (N)
    assert np.abs(f_dyn - f_static).max() <= 0.02 * np.abs(f_static).max()
    assert np.all(np.isfinite(dyn.stress))


def test_a_step_too_coarse_for_the_rods_first_mode_is_refused(tiny_mesh):
    """By the scene's check (``mlsim check``, and on load), before any solve."""
    with pytest.raises(SceneError, match=r"fidelity.solve.substeps = 2: a 1.25 ms step cannot resolve the rods' first bending mode "
                                         r"\(323 Hz, 3.1 ms; fidelity.solve.steps_per_period = 4\): set substeps to 4 or more"):
        _scene(tiny_mesh, dynamics="backward_euler", substeps=2)
    with pytest.raises(SceneError, match=r"fidelity.solve.substeps = 4: a 0.625 ms step .* set substeps to 7 or more"):
        _scene(tiny_mesh, dynamics="backward_euler", substeps=4, steps_per_period=8.0)
    _scene(tiny_mesh, dynamics="backward_euler", substeps=4)  # 0.625 ms: 5 steps a period


def test_a_negative_loss_factor_is_refused_by_name(tiny_mesh):
    with pytest.raises(SceneError, match="fidelity.solve.loss_factor"):
        _scene(tiny_mesh, dynamics="backward_euler", loss_factor=-0.1)
    with pytest.raises(SceneError, match="fidelity.solve.dynamics"):
        _scene(tiny_mesh, dynamics="leapfrog")


def test_the_settings_carry_the_scene_dynamics(tiny_mesh):
    scene, _ = _scene(tiny_mesh, dynamics="backward_euler", loss_factor=0.2, steps_per_period=8.0, substeps=8)
    settings = qs.SolveSettings.from_scene(scene)
    assert (settings.dynamics, settings.loss_factor, settings.steps_per_period) == ("backward_euler", 0.2, 8.0)
    assert dataclasses.replace(settings, dynamics="quasi_static").dynamics == "quasi_static"
