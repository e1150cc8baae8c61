"""``mlsim accuracy SCENE --stage solve``: the error measures, the Pareto front, and an end-to-end study."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from mlsim.cli import main
from mlsim.scene import load_scene
from mlsim.studies import accuracy

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "scenes" / "mavig_tiny.toml"
# a frictionless flat punch pressed 0.1 mm onto all four tips: small strain, so the linear tiers
# must agree with the finite-strain reference up to the model error (about 1 %)
PRESS = {"indenter": {"shape": "flat", "diameter_mm": 40.0}, "start_xy_mm": [0.0, 0.0], "start_gap_mm": 0.5,
         "friction_coefficient": 0.0, "segments": [{"kind": "press", "depth_mm": 0.6, "speed_mm_s": 6.0}]}


def test_pareto_front_keeps_exactly_the_non_dominated_points():
    cost = np.array([1.0, 2.0, 3.0, 2.0, 5.0, 1.0])
    error = np.array([0.5, 0.2, 0.1, 0.3, 0.1, 0.5])
    # (2, 0.3) is beaten by (2, 0.2); (5, 0.1) by (3, 0.1); the duplicate (1, 0.5) ties and stays
    np.testing.assert_array_equal(accuracy.pareto_front(cost, error), [True, True, True, False, False, True])


def test_relative_error_is_a_normalised_frobenius_norm():
    ref = np.array([[3.0, 0.0], [0.0, 4.0]])
    assert accuracy.relative_error(ref, ref) == 0.0
    assert accuracy.relative_error(1.1 * ref, ref) == pytest.approx(0.1)
    assert accuracy.relative_error(np.zeros(2), np.zeros(2)) == 0.0
    assert accuracy.relative_error(np.ones(2), np.zeros(2)) == float("inf")


@pytest.fixture(scope="module")
def study(tmp_path_factory, cache, tiny_mesh):
    scene = load_scene(TINY).with_values({"load": PRESS, "fidelity.solve.gravity": False})
    out = tmp_path_factory.mktemp("accuracy")
    rows = accuracy.solve_accuracy(scene, [3.0, 2.5], orders=(2,), tiers=("reduced", "linear", "nonlinear"), out_dir=out,
                                   cache=cache, progress=False, log=lambda m: None)
    return scene, out, rows


def test_tip_displacement_measure_follows_the_frictionless_punch(study, cache):
    """Under a frictionless flat punch 0.1 mm below the tips, every tip moves down 0.1 mm, to 5 %:
    the penalty acts on each contact point's hat-weighted mean displacement, and the vertices of a
    coarse tip (2.5 mm edges on a 5 mm face) sink a few micrometres past it near the rim where the
    pressure peaks. The rod forces add up to the normal force."""
    from mlsim import pipeline

    scene, _, _ = study
    ep = pipeline.run(scene.with_values({"outputs": ["solve"]}), out_dir=None, cache=cache, progress=False, log=lambda m: None).results["solve"]
    m = accuracy.rod_measures(ep, scene.sensor.base.thickness_mm * 1e-3)
    np.testing.assert_allclose(m["tip_displacement"][-1, :, 2], -0.1e-3, rtol=0.05)
    np.testing.assert_allclose(-m["rod_contact_force"][-1, :, 2].sum(), ep.frames("normal_force_n")[-1], rtol=1e-12)
    assert np.all(m["rod_base_von_mises"][-1] > 0)


def test_study_errors_and_outputs(study):
    scene, out, rows = study
    by = {(r.edge_length_mm, r.element_order, r.tier): r for r in rows}
    ref = by[(2.5, 2, "nonlinear")]
    assert ref.reference and all(ref.errors[e] == 0.0 for e in accuracy.ERRORS)
    # same mesh, small strain: the linear tier differs from the finite-strain reference by the model
    # error only (about 1 % at 1 % strain)
    lin = by[(2.5, 2, "linear")]
    for e in accuracy.ERRORS:
        assert lin.errors[e] < 0.02, (e, lin.errors[e])
    # the reduced tier carries a uniform press as the linear tier does (tests/test_quasistatic)
    assert by[(2.5, 2, "reduced")].errors["rod_contact_force"] < 0.02
    assert all(not r.failed for r in rows)
    with open(out / "accuracy_solve.csv") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(rows) == 6
    # the linear tiers carry their own error estimate; a press bends no rod, so it is small, as measured
    for r in rows:
        if r.tier == "nonlinear":
            assert r.estimated_force_error != r.estimated_force_error  # NaN: the reference estimates nothing
        else:
            assert 0.0 <= r.estimated_force_error < 0.02
    assert all(row["estimated_rod_contact_force_error"] for row in table)
    for e in accuracy.ERRORS:  # the reference is always on the front (no error, cheaper rows have more)
        assert any(row[f"pareto_{e}"] == "True" for row in table)
    assert (out / "accuracy_solve.png").stat().st_size > 20_000


def test_cli_refuses_an_unknown_stage_by_name(capsys):
    assert main(["accuracy", str(TINY), "--stage", "camera"]) == 2
    assert "invalid choice: 'camera' (choose from 'solve', 'render')" in capsys.readouterr().err
