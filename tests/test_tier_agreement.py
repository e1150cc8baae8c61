"""The solve tiers against each other (issue 15): at 1 % of the demo load, where every tier is in its
small-strain regime, reduced, linear and nonlinear agree to 1 % on per-rod contact force and ML-layer
peak stress; at full load, where the indenter's rim crosses the rod tips, the reduced tier (each rod's
own point compliance, the rods coupled through their resultants) stays within 2 % of the linear tier."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from fem import quasistatic as qs
from mlsim.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "scenes"


def _demo_load(fraction: float) -> dict:
    """The default demo's load with its path scaled: the indentation beyond first contact, the slide
    and the rotation (the forces scale with them while the body stays linear)."""
    load = load_scene(SCENES / "mavig_default.toml").model_dump(mode="json", exclude_none=True)["load"]
    gap = load["start_gap_mm"]
    for seg in load["segments"]:
        if seg["kind"] == "press":
            seg["depth_mm"] = gap + fraction * (seg["depth_mm"] - gap)
        elif seg["kind"] == "slide":
            seg["distance_mm"] *= fraction
        elif seg["kind"] == "rotate":
            seg["angle_deg"] *= fraction
    return load


def _rel(a, b) -> float:
    a, b = np.asarray(a), np.asarray(b)
    return float(np.abs(a - b).max() / np.abs(b).max())


def _agreement(mesh_fixture):
    scene0, _, mesh, _ = mesh_fixture
    scene = scene0.with_values({"load": _demo_load(0.01)})
    settings = qs.SolveSettings.from_scene(scene)
    logs: list[str] = []
    eps = {tier: qs.run_episode(scene, mesh, settings=dataclasses.replace(settings, tier=tier), log=logs.append)
           for tier in ("nonlinear", "linear", "reduced")}
    ref = eps["nonlinear"]
    assert ref.normal_force_n.max() > 0 and ref.rod_peaks()["ml_von_mises_kpa"]
    for tier in ("linear", "reduced"):
        ep = eps[tier]
        assert _rel(ep.rod_force_n, ref.rod_force_n) <= 0.01, tier  # per-rod contact force, every step
        assert _rel(ep.rod_peaks()["ml_von_mises_kpa"], ref.rod_peaks()["ml_von_mises_kpa"]) <= 0.01, tier
    assert not any("reduced tier" in m for m in logs)


def test_three_tiers_agree_at_one_percent_of_the_demo_load(tiny_mesh):
    """The tiny sensor (2 x 2 rods, 2.5 mm mesh) under the demo's flat punch and path at 1 %."""
    _agreement(tiny_mesh)


@pytest.mark.slow
def test_three_tiers_agree_at_one_percent_of_the_demo_load_on_the_default_sensor(default_mesh):
    """The default sensor: its punch's rim crosses the outer rods' tips."""
    scene0, _, mesh, _ = default_mesh
    scene = scene0.with_values({"load": _demo_load(0.01)})
    settings = qs.SolveSettings.from_scene(scene)
    eps = {tier: qs.run_episode(scene, mesh, settings=dataclasses.replace(settings, tier=tier)) for tier in ("nonlinear", "linear", "reduced")}
    ref = eps["nonlinear"]
    for tier in ("linear", "reduced"):
        assert _rel(eps[tier].rod_force_n, ref.rod_force_n) <= 0.01, tier
        assert _rel(eps[tier].rod_peaks()["ml_von_mises_kpa"], ref.rod_peaks()["ml_von_mises_kpa"]) <= 0.01, tier


@pytest.mark.parametrize("kinematics", ["first_order", "second_order"])
def test_the_reduced_tier_follows_the_linear_tier_where_the_indenters_rim_crosses_the_tips(tiny_mesh, kinematics):
    """The tiny scene's own load, a sphere pressed 1 mm and slid across the rods: its rim crosses the
    tips, where rigid patches were 15-63 % off the linear tier (issue 15). Each rod's own point
    compliance resolves the rim; the rods' coupling through their resultants and the fields from patch
    resultants away from the loaded rod cost under 2 % (measured 0.7 %, 0.8 % on the default demo).
    With second-order rod kinematics the rods' sections are observed as the linear tier observes them
    (measured 0.4 %)."""
    scene, _, mesh, _ = tiny_mesh
    settings = dataclasses.replace(qs.SolveSettings.from_scene(scene), rod_kinematics=kinematics)
    lame, rho, _ = qs.layer_materials(scene)
    body = qs.LinearBody(mesh, lame, rho, settings.element, settings.gravity)
    lin = qs.run_episode(scene, mesh, body=body, settings=dataclasses.replace(settings, tier="linear"))
    red = qs.run_episode(scene, mesh, body=body, settings=dataclasses.replace(settings, tier="reduced"))
    assert lin.normal_force_n.max() > 0.1  # a load, not a touch
    assert _rel(red.rod_force_n, lin.rod_force_n) <= 0.02
    for measure in ("normal_force_n", "ml_von_mises_kpa", "von_mises_kpa"):
        assert _rel(red.rod_peaks()[measure], lin.rod_peaks()[measure]) <= 0.02, measure
