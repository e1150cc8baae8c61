"""Sensor kinds (issue 17): a kind defined here, in the test alone, registers its [sensor] schema and
two stages, and runs through ``mlsim run`` with caching and ``--dry-run`` and through ``mlsim check``,
touching no file of the planner; an unknown kind is refused naming the field; the ML rod array's
scenes keep their hashes and stage keys (its kind is the default and is not written out)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Literal

import pytest
from pydantic import BaseModel, ConfigDict, Field

from mlsim import stage as registry
from mlsim.cli import main
from mlsim.io import atomic_bytes
from mlsim.scene import SceneError, load_scene

ROOT = Path(__file__).resolve().parents[1]
CALLS: list[str] = []  # which stages ran (not loaded from the cache)


class CounterSensor(BaseModel):
    """A toy sensor: ``n`` cells that each count to ``per_cell``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    kind: Literal["toy_counter"] = "toy_counter"
    n: int = Field(3, ge=1)
    per_cell: int = 2


def _json_io(filename: str):
    def save(result, directory: Path) -> None:
        (directory / filename).write_text(json.dumps(result))

    def load(directory: Path):
        return json.loads((directory / filename).read_text())

    def write(result, out_dir: Path, ctx) -> list[Path]:
        return [atomic_bytes(out_dir / filename, json.dumps(result).encode())]

    return save, load, write


def _count(scene, inputs, ctx):
    CALLS.append("count")
    return {"counts": [scene.sensor.per_cell] * scene.sensor.n}


def _total(scene, inputs, ctx):
    CALLS.append("total")
    return {"total": sum(inputs["count"]["counts"])}


_count_io, _total_io = _json_io("count.json"), _json_io("total.json")
COUNT = registry.Stage(name="count", doc="each cell's count", reads=("sensor.n", "sensor.per_cell"), needs=(), run=_count,
                       save=_count_io[0], load=_count_io[1], write=_count_io[2], summarize=lambda r: {"cells": len(r["counts"])})
TOTAL = registry.Stage(name="total", doc="the sum of the counts", reads=(), needs=("count",), run=_total,
                       save=_total_io[0], load=_total_io[1], write=_total_io[2], summarize=lambda r: r)


def _check(scene) -> list:
    return [("sensor.per_cell", scene.sensor.per_cell, "must be even")] if scene.sensor.per_cell % 2 else []


@pytest.fixture
def toy_kind():
    registry.register_kind("toy_counter", CounterSensor, [COUNT, TOTAL], check=_check)
    CALLS.clear()
    yield
    registry.unregister_kind("toy_counter")


def _scene_file(tmp_path: Path, n: int = 4, per_cell: int = 2) -> Path:
    path = tmp_path / "toy.toml"
    path.write_text(f'name = "toy"\noutputs = ["total"]\n\n[sensor]\nkind = "toy_counter"\nn = {n}\nper_cell = {per_cell}\n')
    return path


def test_a_kind_defined_in_a_test_runs_through_the_command_line_with_caching(toy_kind, tmp_path, capsys):
    scene_file, cache, out = _scene_file(tmp_path), tmp_path / "cache", tmp_path / "out"
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    assert json.loads((out / "total.json").read_text()) == {"total": 8}
    assert CALLS == ["count", "total"]
    summary = json.loads((out / "summary.json").read_text())
    assert summary["stages"]["total"]["summary"] == {"total": 8} and summary["stages"]["count"]["action"] == "run"
    # again: the total comes from the cache and nothing runs
    assert main(["run", str(scene_file), "--out", str(out), "--cache", str(cache), "--quiet"]) == 0
    assert CALLS == ["count", "total"]
    again = json.loads((out / "summary.json").read_text())["stages"]
    assert list(again) == ["total"] and again["total"]["action"] == "load" and again["total"]["key"] == summary["stages"]["total"]["key"]
    capsys.readouterr()
    assert main(["run", str(scene_file), "--dry-run", "--cache", str(cache)]) == 0
    plan = capsys.readouterr().out
    assert "total      cached" in plan and "count" not in plan  # a cached total needs no count
    # a field the count reads changes both keys; the dry run says both will run
    assert main(["run", str(_scene_file(tmp_path, n=5)), "--dry-run", "--cache", str(cache)]) == 0
    plan = capsys.readouterr().out
    assert "total      to run" in plan and "count      to run" in plan
    assert main(["check", str(scene_file)]) == 0
    assert "sensor.n" in capsys.readouterr().out


def test_a_kinds_schema_and_checks_apply(toy_kind, tmp_path):
    with pytest.raises(SceneError, match="sensor.per_cell"):
        load_scene(_scene_file(tmp_path, per_cell=3))
    bad = tmp_path / "bad.toml"
    bad.write_text('outputs = ["mesh"]\n[sensor]\nkind = "toy_counter"\nrows = 5\n')
    with pytest.raises(SceneError) as err:
        load_scene(bad)
    text = str(err.value)
    assert "sensor.rows" in text  # the ML sensor's field is not the toy's: refused, named


def test_an_unknown_kind_is_refused_naming_the_field(tmp_path):
    path = tmp_path / "nope.toml"
    path.write_text('[sensor]\nkind = "no_such_sensor"\n')
    with pytest.raises(SceneError, match=r"sensor.*no_such_sensor.*ml_rod_array"):
        load_scene(path)


def test_the_ml_rod_array_is_the_default_kind_and_its_hashes_did_not_move():
    scene = load_scene(ROOT / "scenes" / "mavig_tiny.toml")
    assert scene.kind == "ml_rod_array" and scene.sensor.kind == "ml_rod_array"
    assert "kind" not in scene.model_dump()["sensor"]  # not written out: the hashes of older scenes stand
    explicit = scene.with_values({"sensor.kind": "ml_rod_array"})
    assert explicit.content_hash() == scene.content_hash()
    assert registry.outputs("ml_rod_array")[:3] == ("geometry", "mesh", "solve")


@pytest.mark.parametrize("kind, section, field", [("cls", "noise", "rms_mv"), ("plantar_sole", "foundation", "stiffness_n_m3"),
                                                  ("anyskin", "noise", "rms_ut")])
def test_the_sibling_kinds_refuse_nan_as_the_scene_does(tmp_path, kind, section, field):
    """Every [sensor] schema is built on mlsim.scene.SpecModel: a NaN is refused, naming the field."""
    path = tmp_path / f"{kind}.toml"
    path.write_text(f'[sensor]\nkind = "{kind}"\n\n[sensor.{section}]\n{field} = nan\n')
    with pytest.raises(SceneError, match=rf"sensor\.{section}\.{field}"):
        load_scene(path)
