"""Fuzzing the scene model (issue 39): every numeric field of a shipped scene of each sensor kind, one
or two drawn at a time from wide ranges (0, tiny, huge, negative, NaN, inf and ordinary numbers), set
with ``--set`` and run through ``mlsim run --dry-run`` (validation, plausibility, the plan and its
cost estimate). Each draw either passes and prints its estimate, or exits 2 naming a field; no
traceback (an exception escaping ``mlsim.cli.main`` fails the test with the draw). Draws on the
scenes cheap enough to run (``RUN_SCENES``: the sole's feasibility and balance loop) run for real.

The draws are seeded (hypothesis ``derandomize``): the same draws on every run. ``make test`` takes
``FAST_DRAWS``; ``-m slow`` takes ``SLOW_DRAWS``. Draws that once failed are kept in
``tests/data/fuzz_corpus.json`` and replayed on every run.
"""

from __future__ import annotations

import json
import math
import re
from functools import cache
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mlsim.cli import main

ROOT = Path(__file__).resolve().parents[1]
# a shipped scene of each sensor kind (the ml_rod_array's default demo: every stage, a full load)
# and, for the sibling kinds' plausibility (other_sensors/<kind>/plausibility.py), the scenes whose
# sections the first leaves at their defaults: the balance loops, two feet, the point-dipole skin
KIND_SCENES = {"ml_rod_array": "scenes/mavig_default.toml", "cls": "scenes/cls/general.toml", "plantar_sole": "scenes/sole/obstacles.toml",
               "anyskin": "scenes/anyskin/push_study.toml", "plantar_sole/balance": "scenes/sole/balance_sweep.toml",
               "plantar_sole/double_support": "scenes/sole/double_support.toml", "anyskin/point_dipole": "scenes/anyskin/headon_push.toml"}
CORPUS = ROOT / "tests" / "data" / "fuzz_corpus.json"
FAST_DRAWS = 600  # about 11 s on 2 shared cores (7 scenes: ml_rod_array about 86 of them)
SLOW_DRAWS = 3000

SPECIAL = [0, 0.0, -0.0, -1, -1.0, 1e-300, 5e-324, 1e-9, 1e-3, 0.5, 1.0, 2, 3.7, 100, 1e6, 1e9, 1e300, 1.7976931348623157e308,
           -1e9, -1e300, 2**31, 2**63, -(2**63), math.nan, math.inf, -math.inf]


@cache
def numeric_fields(scene_file: str) -> tuple[str, ...]:
    """The dotted paths of every numeric leaf of the scene as resolved (defaults included), list
    elements by index (``load.start_xy_mm[0]``)."""
    from mlsim.scene import load_scene

    out = []
    for path, value in load_scene(ROOT / scene_file).to_dotted().items():
        if isinstance(value, bool):
            continue
        if isinstance(value, (int, float)):
            out.append(path)
        elif isinstance(value, list) and value and all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
            out.extend(f"{path}[{i}]" for i in range(len(value)))
    return tuple(out)


def toml_value(value) -> str:
    """A number as TOML writes it (nan, inf, -inf; Python's float repr is valid TOML)."""
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
    return repr(value)


values = st.one_of(st.sampled_from(SPECIAL), st.floats(allow_nan=True, allow_infinity=True), st.integers(min_value=-(2**70), max_value=2**70),
                   st.floats(min_value=-10.0, max_value=100.0))


@st.composite
def draws(draw):
    kind = draw(st.sampled_from(sorted(KIND_SCENES)))
    fields = numeric_fields(KIND_SCENES[kind])
    chosen = draw(st.lists(st.sampled_from(fields), min_size=1, max_size=2, unique=True))
    return KIND_SCENES[kind], {f: draw(values) for f in chosen}


def check_draw(scene_file: str, changes: dict, capsys, tmp_path, dry_run: bool = True) -> int:
    """Run the draw through ``mlsim run --dry-run`` (or, ``dry_run=False``, the run itself into
    ``tmp_path``); assert its outcome; return the exit code."""
    argv = ["run", str(ROOT / scene_file), "--cache", str(tmp_path / "cache")]
    argv += ["--dry-run"] if dry_run else ["--out", str(tmp_path / "out")]
    for path, value in changes.items():
        argv += ["--set", f"{path}={toml_value(value)}"]
    code = main(argv)
    out, err = capsys.readouterr()
    assert "Traceback" not in err, (changes, err)
    if code == 0 and dry_run:
        assert "estimate:" in out, (changes, out)
    elif code == 0:
        assert any((tmp_path / "out").rglob("*")), (changes, out)
    else:
        assert code == 2, (changes, code, err)
        # every problem line names a dotted field (or a command-line flag) and what is valid
        lines = [line for line in err.splitlines() if line.startswith("  ")]
        assert lines and all(re.match(r"\s+([A-Za-z_<-][\w.\[\]<>-]*) = ", line) for line in lines), (changes, err)
    return code


def _corpus() -> list:
    return [pytest.param(case["scene"], case["set"], id=case["why"][:60]) for case in json.loads(CORPUS.read_text())]


@pytest.mark.parametrize("scene_file, changes", _corpus())
def test_corpus_of_draws_that_once_failed(scene_file, changes, capsys, tmp_path):
    values = {k: float(v) if isinstance(v, str) else v for k, v in changes.items()}  # "nan", "inf" are stored as strings
    check_draw(scene_file, values, capsys, tmp_path)


def test_every_kind_has_numeric_fields_to_draw():
    counts = {kind: len(numeric_fields(f)) for kind, f in KIND_SCENES.items()}
    assert all(n >= 10 for n in counts.values()), counts


def _fuzz(max_examples: int):
    """A seeded hypothesis test of ``max_examples`` draws through :func:`check_draw`."""

    @settings(max_examples=max_examples, derandomize=True, database=None, deadline=None,
              suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
    @given(draw=draws())
    def fuzz(draw, capsys, tmp_path):
        scene_file, changes = draw
        check_draw(scene_file, changes, capsys, tmp_path)

    return fuzz


test_fuzzed_scenes_pass_or_name_a_field = _fuzz(FAST_DRAWS)
test_fuzzed_scenes_many_draws = pytest.mark.slow(_fuzz(SLOW_DRAWS))


# Scenes cheap enough to run for real (milliseconds to a second a run): a draw that passes check runs
# to its outputs, so the plausibility checks are shown to keep the stages from a traceback, not only
# the plan (60 draws of each: about 10 s)
RUN_SCENES = ("scenes/sole/three_spheres.toml", "scenes/sole/balance_push.toml")
RUN_DRAWS = 60


@st.composite
def run_draws(draw):
    scene_file = draw(st.sampled_from(RUN_SCENES))
    chosen = draw(st.lists(st.sampled_from(numeric_fields(scene_file)), min_size=1, max_size=2, unique=True))
    return scene_file, {f: draw(values) for f in chosen}


@settings(max_examples=RUN_DRAWS, derandomize=True, database=None, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])
@given(draw=run_draws())
def test_fuzzed_cheap_scenes_run_to_their_outputs_or_name_a_field(draw, capsys, tmp_path_factory):
    scene_file, changes = draw
    check_draw(scene_file, changes, capsys, tmp_path_factory.mktemp("run"), dry_run=False)


EXTREMES = (0, -1, 1e-300, 1e300, math.nan, math.inf, -math.inf)


@pytest.mark.parametrize("kind", sorted(KIND_SCENES))
def test_every_numeric_field_at_each_extreme(kind):
    """Every numeric field of the kind's scene, one at a time, at each of ``EXTREMES``: the scene model
    refuses it naming fields, or the plan and its estimate are made (in process: the CLI's path
    without its parsing, so that all 467 fields x 7 values take seconds)."""
    from mlsim import pipeline, run_budget
    from mlsim.errors import SceneError
    from mlsim.scene import _set_path, _split_path, read_toml, scene_from_dict

    data = read_toml(ROOT / KIND_SCENES[kind])
    refused = passed = 0
    for path in numeric_fields(KIND_SCENES[kind]):
        for value in EXTREMES:
            changed = json.loads(json.dumps(data))
            try:
                _set_path(changed, _split_path(path), value, path)
                scene = scene_from_dict(changed)
            except SceneError as exc:
                assert exc.problems and all(p.path and p.message for p in exc.problems), (path, value, str(exc))
                refused += 1
                continue
            est = run_budget.estimate(scene, pipeline.plan(scene, None))
            assert math.isfinite(est.seconds) and math.isfinite(est.memory_bytes), (path, value, est)
            passed += 1
    assert refused > passed > 0  # most extremes are refused; some (0 for a non-negative, 1e300 for an unbounded count) pass
