"""The sibling kinds' cost before a run (issue 39 item 2): each kind prices its stages through its
``cost`` hook (:class:`mlsim.stage.SensorKind`, ``other_sensors/<kind>/plausibility.py``'s
``stage_cost``, from the bytes and seconds per sample or tick measured there), so ``mlsim run
--dry-run`` prints a time and memory for each modelled stage; the estimate is linear in the samples
that drive it and agrees with the plausibility checks' own totals. The estimate against measured runs
is benchmarks/bench_cost_model.py --siblings (no timing here)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from mlsim import cost_model, pipeline, run_budget
from mlsim.cli import main
from mlsim.scene import load_scene
from mlsim.stage import kind, register_kind, unregister_kind
from other_sensors.anyskin import plausibility as anyskin
from other_sensors.cls import plausibility as cls
from other_sensors.sole import plausibility as sole

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"
ROW = re.compile(r"^  (\w+)\s+([\d.]+ (?:MB|GB))\s+([\d.]+ (?:s|min|h))\s+\S")


@pytest.mark.parametrize("scene, modelled, unmodelled", [
    ("cls/general.toml", {"cls_signals", "cls_calibrate", "cls_estimate"}, set()),
    ("sole/balance_sweep.toml", {"sole_balance_sweep"}, set()),
    ("sole/balance_push.toml", {"sole_balance"}, set()),
    ("anyskin/headon_push.toml", {"anyskin_signals"}, {"anyskin_contact"}),
    ("anyskin/push_study.toml", {"anyskin_signals", "anyskin_drift", "anyskin_pitch", "anyskin_bench"}, {"anyskin_contact"}),
])
def test_sibling_dry_run_prints_each_modelled_stages_time_and_memory(scene, modelled, unmodelled, tmp_path, capsys):
    assert main(["run", str(SCENES / scene), "--dry-run", "--cache", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert out.count("estimate:") == 1
    rows = {m.group(1): m.groups()[1:] for m in map(ROW.match, out.splitlines()) if m}
    assert modelled <= set(rows), out
    unpriced = {line.split()[0] for line in out.splitlines() if line.endswith("no cost model")}
    assert unpriced == unmodelled
    assert re.search(r"estimate: [\d.]+ (s|min|h) and [\d.]+ GB peak", out)


def _scaled(path: str, field: str, *factors: float):
    scene = load_scene(SCENES / path)
    value = scene.model_dump()
    for part in field.split("."):
        value = value[part]
    return scene, *(scene.with_values({field: value * f}) for f in factors)


@pytest.mark.parametrize("path, field, driven", [
    ("cls/general.toml", "sensor.trajectory.duration_s", ("cls_signals", "cls_estimate")),
    ("cls/general.toml", "sensor.calibration.duration_s", ("cls_calibrate",)),
    ("sole/balance_push.toml", "sensor.balance.duration_s", ("sole_balance", "sole_balance_sweep")),
    ("sole/balance_sweep.toml", "sensor.balance.rate_hz", ("sole_balance", "sole_balance_sweep")),
    ("anyskin/push_study.toml", "sensor.trajectory.duration_s",
     ("anyskin_signals", "anyskin_pitch", "anyskin_drift", "anyskin_bench")),
    ("anyskin/headon_push.toml", "sensor.magnetometers.rate_hz", ("anyskin_signals", "anyskin_pitch", "anyskin_drift", "anyskin_bench")),
])
def test_sibling_estimate_is_linear_in_the_samples_that_drive_it(path, field, driven):
    """Doubling the field that sets the samples doubles the memory, and each added share costs the same time."""
    scene, doubled, tripled = _scaled(path, field, 2.0, 3.0)
    for name in driven:
        a, b, c = (cost_model.stage_cost(s, name) for s in (scene, doubled, tripled))
        assert b.memory_bytes + b.transient_bytes == pytest.approx(2 * (a.memory_bytes + a.transient_bytes))
        # the time: a fixed part (a stage's set-up, measured) and a part per sample
        assert c.seconds - b.seconds == pytest.approx(b.seconds - a.seconds) and b.seconds > a.seconds > 0
    # a stage the field does not drive keeps its estimate
    for name in pipeline.stages_of(scene):
        if name not in driven and (c := cost_model.stage_cost(scene, name)) is not None:
            assert cost_model.stage_cost(doubled, name) == c


def test_balance_sweep_scales_with_its_pushes_and_the_anyskin_grid_squared():
    scene = load_scene(SCENES / "sole/balance_sweep.toml")
    pushes = list(scene.sensor.balance_sweep.push_n)
    more = scene.with_values({"sensor.balance_sweep.push_n": pushes * 3})
    assert cost_model.stage_cost(more, "sole_balance_sweep").seconds == pytest.approx(3 * cost_model.stage_cost(scene, "sole_balance_sweep").seconds)
    skin = load_scene(SCENES / "anyskin/headon_push.toml")
    finer = skin.with_values({"sensor.skin.grid": 2 * skin.sensor.skin.grid})
    assert cost_model.stage_cost(finer, "anyskin_signals").memory_bytes == pytest.approx(4 * cost_model.stage_cost(skin, "anyskin_signals").memory_bytes)


def test_stage_estimates_add_up_to_the_plausibility_checks_totals():
    """The dry run's stages and the check's warnings price the same run alike (one set of measurements)."""
    scene = load_scene(SCENES / "cls/general.toml")
    n, nbytes, seconds = cls.run_cost(scene)["signals"]
    sig, est = cost_model.stage_cost(scene, "cls_signals"), cost_model.stage_cost(scene, "cls_estimate")
    assert sig.seconds + est.seconds - cls.SIGNALS_STAGE_FIXED_S - cls.ESTIMATE_STAGE_FIXED_S <= seconds  # the warnings' bound
    assert sig.memory_bytes + est.memory_bytes == pytest.approx(nbytes, rel=0.01)  # 561 + 436 B against 200 B x 5 pairs
    assert cost_model.stage_cost(scene, "cls_calibrate").seconds <= cls.run_cost(scene)["calibration"][2]
    assert cost_model.stage_cost(scene, "cls_calibrate").memory_bytes == pytest.approx(cls.run_cost(scene)["calibration"][1])

    study = load_scene(SCENES / "anyskin/push_study.toml")
    est = run_budget.estimate(study, pipeline.plan(study, None, None))
    _, held, seconds = anyskin.run_cost(study)
    assert est.seconds <= seconds  # the warnings' bound: the larger truth's per-column time
    assert est.memory_bytes == pytest.approx(cost_model.INTERPRETER_BYTES + held)  # the cached trace and one study's beside it

    balance = load_scene(SCENES / "sole/balance_sweep.toml")
    ticks = sole.balance_ticks(balance)
    c = cost_model.stage_cost(balance, "sole_balance_sweep")
    assert (c.seconds, c.memory_bytes) == pytest.approx((ticks * sole.SECONDS_PER_TICK, ticks * sole.BYTES_PER_TICK))


def test_the_cost_hook_is_the_kinds_and_survives_re_registration():
    for name, module in (("cls", cls), ("anyskin", anyskin), ("plantar_sole", sole)):
        assert kind(name).cost is module.stage_cost
    k = kind("cls")
    try:
        register_kind("cls_priced", k.sensor_model, k.stages, k.check, k.warnings, cost=lambda scene, stage: None)
        assert kind("cls_priced").cost is not None
        register_kind("cls_unpriced", k.sensor_model, k.stages)
        assert kind("cls_unpriced").cost is None
    finally:
        unregister_kind("cls_priced")
        unregister_kind("cls_unpriced")
