"""The documentation (issue 42): the README fits on two screens; every command of the README and of the
docs' pages runs as written (``$ mlsim ...`` lines of ``console`` fences: the tiny scene, or ``--dry-run``
where the real run is long; the README table's commands with ``--dry-run`` added) and the Python
examples run; the scene reference covers every field of every sensor kind's models; the generated
pages name what they must; the site's navigation names only pages that exist.

The site itself is built by ``make docs`` (``mkdocs build --strict``, about 15 s): the build is not
repeated here.
"""

from __future__ import annotations

import re
import shlex
import typing
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
GETTING_STARTED = ROOT / "docs" / "getting-started.md"
API_PAGE = ROOT / "docs" / "reference" / "api.md"
README_MAX_LINES = 120


def fenced(text: str, language: str) -> list[str]:
    """The bodies of the ```language fences of a Markdown text."""
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.S | re.M)


def console_commands(path: Path) -> list[str]:
    """The ``$ mlsim ...`` lines of a page's ``console`` fences."""
    return [line[2:].strip() for block in fenced(path.read_text(), "console") for line in block.splitlines() if line.startswith("$ ")]


def table_commands(path: Path) -> list[str]:
    """The backticked ``mlsim ...`` commands in a page's tables."""
    return [m for line in path.read_text().splitlines() if line.startswith("|") for m in re.findall(r"`(mlsim [^`]+)`", line)]


def run_cli(command: str, capsys) -> tuple[int, str]:
    from mlsim.cli import main

    argv = shlex.split(command)
    assert argv[0] == "mlsim", command
    try:
        code = main(argv[1:])
    except SystemExit as exc:  # --version and --help exit
        code = int(exc.code or 0)
    captured = capsys.readouterr()
    return code, captured.out + captured.err


@pytest.fixture
def in_tmp(tmp_path, monkeypatch):
    """A working folder with the repository's scenes: commands' default out/ folders land in it. The
    real-sensor commands (``mlsim calibrate``, ``mlsim detect``, issue 41) read recordings, which the
    docs run with ``--dry-run`` on what is made here: ``photo.png`` and the frame folders ``idle/``
    and ``recording/``, 160 x 120 px (dark frames: the dry runs read and size them, nothing more)."""
    import cv2
    import numpy as np

    (tmp_path / "scenes").symlink_to(ROOT / "scenes")
    frame = np.full((120, 160, 3), 12, np.uint8)
    cv2.imwrite(str(tmp_path / "photo.png"), frame)
    for folder in ("idle", "recording"):
        (tmp_path / folder).mkdir()
        for k in range(3):
            cv2.imwrite(str(tmp_path / folder / f"frame_{k}.png"), frame)
    monkeypatch.chdir(tmp_path)
    return tmp_path


def test_readme_fits_on_two_screens():
    n = len(README.read_text().splitlines())
    assert n <= README_MAX_LINES, f"README.md has {n} lines; move detail into docs/"


def test_the_pages_hold_commands_to_run():
    """The extraction itself: a guard against a fence renamed so that nothing is run."""
    assert len(console_commands(README)) >= 3 and len(table_commands(README)) >= 6
    assert len(console_commands(GETTING_STARTED)) >= 5 and len(PAGES_WITH_COMMANDS) >= 8
    assert fenced(README.read_text(), "python") and fenced(GETTING_STARTED.read_text(), "python")


PAGES_WITH_COMMANDS = [README] + sorted(p for p in (ROOT / "docs").rglob("*.md") if "```console" in p.read_text())


@pytest.mark.parametrize("page", PAGES_WITH_COMMANDS, ids=[str(p.relative_to(ROOT)) for p in PAGES_WITH_COMMANDS])
def test_every_console_command_runs_as_written(page, in_tmp, capsys):
    for command in console_commands(page):
        code, output = run_cli(command, capsys)
        assert code == 0, f"{page.name}: `{command}` exited {code}:\n{output}"
        if "--dry-run" in command and " run " in f" {command} ":
            assert "plan for" in output and "(* = requested output)" in output, output
        if command.startswith("mlsim run") and "--out" in command and "--dry-run" not in command:
            out = in_tmp / shlex.split(command)[shlex.split(command).index("--out") + 1]
            assert (out / "summary.json").is_file(), f"`{command}` wrote no summary.json"


def test_every_readme_table_command_parses_and_plans(in_tmp, capsys):
    """The uses table's commands are long runs: each is run with ``--dry-run`` (its plan, nothing else)."""
    for command in table_commands(README):
        code, output = run_cli(f"{command} --dry-run", capsys)
        assert code == 0, f"`{command} --dry-run` exited {code}:\n{output}"
        assert output.strip(), f"`{command} --dry-run` printed nothing"


@pytest.mark.parametrize("page", [README, GETTING_STARTED, API_PAGE], ids=["README", "getting-started", "api"])
def test_python_examples_run(page, in_tmp, capsys):
    for block in fenced(page.read_text(), "python"):
        exec(compile(block, f"{page.name} example", "exec"), {"__name__": "__docs__"})
    printed = capsys.readouterr().out
    assert "geometry" in printed or "surface" in printed, printed
    assert list(in_tmp.glob("out/tiny_py/*.ply")), "the example wrote no surface"


def test_getting_started_version_line(capsys):
    from mlsim import __version__

    code, output = run_cli("mlsim --version", capsys)
    assert code == 0 and output.strip() == f"mlsim {__version__}"


def test_make_targets_named_in_the_docs_exist():
    targets = set(re.findall(r"^([a-z][\w-]*):", (ROOT / "Makefile").read_text(), flags=re.M))
    named = set(re.findall(r"^\s+make ([a-z][\w-]*)|`make ([a-z][\w-]*)`", README.read_text() + GETTING_STARTED.read_text(), flags=re.M))
    named = {a or b for a, b in named}
    assert named >= {"demo", "test", "docs"} and named <= targets, named - targets


# --- the generated references -------------------------------------------------------------------
def _leaf_paths(model, prefix: str = "") -> list[str]:
    """Every leaf field of a pydantic model, walked independently of mlsim.docgen (through optional,
    union, tuple and dict annotations): a leaf once per place it can appear."""
    from pydantic import BaseModel

    def models(annotation):
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            return [annotation]
        return [m for arg in typing.get_args(annotation) for m in models(arg)]

    out = []
    for name, field in model.model_fields.items():
        inner = models(field.annotation)
        out += [p for sub in inner for p in _leaf_paths(sub, f"{prefix}{name}.")] if inner else [prefix + name]
    return out


def test_scene_reference_covers_every_field_of_every_kind():
    from mlsim.docgen import scene_fields, scene_reference
    from mlsim.scene import Scene
    from mlsim.stage import kind, kinds

    page = scene_reference()
    models = [("", Scene)] + [("sensor.", kind(k).sensor_model) for k in kinds()]
    for prefix, model in models:
        rows = scene_fields(model, prefix)
        # as many documented rows as the model has leaves (each leaf once per place it can appear)
        assert len(rows) == len(_leaf_paths(model)), model.__name__
        for row in rows:
            if not row.path.startswith("sensor.") or prefix:  # the default kind's [sensor] is the kind's own table
                assert f"| `{row.path}` |" in page, row.path
    assert len(kinds()) >= 4 and all(f"of kind `{k}`" in page for k in kinds())


def test_scene_reference_reads_units_ranges_defaults_and_notes():
    from mlsim.docgen import scene_fields
    from mlsim.scene import Scene

    rows = {r.path: r for r in scene_fields(Scene)}
    height = rows["sensor.rod.height_mm"]
    assert (height.unit, height.default, height.allowed, height.type) == ("mm", "9", "> 0", "number")
    loading = rows["sensor.phosphor.loading_wt_pct"]
    assert (loading.unit, loading.allowed) == ("wt%", ">= 20, <= 60") and "SPEC 1.2" in loading.doc
    assert rows["fidelity.solve.tier"].allowed == '"reduced", "linear", "nonlinear"'
    assert rows["load.indenter<flat>.yaw_deg"].doc.startswith("rotation of the indenter")  # a base class's comment
    assert rows["load.segments[]<press>.force_n"].unit == "N"
    assert rows["camera.fps"].unit == "frames/s" and rows["dllm.alpha"].unit.startswith("1 (")
    assert "buckling" in rows["fidelity.solve.buckling_limit"].doc  # the comment lines above a field


def test_generated_pages_name_what_they_must():
    from mlsim.docgen import SLOW_BENCHMARKS, benchmarks_reference, cli_reference, dataset_reference, outputs_reference, validation_reference
    from mlsim.stage import kinds, outputs

    out_page = outputs_reference()
    assert all(f"| `{o}` |" in out_page for k in kinds() for o in outputs(k))
    cli = cli_reference()
    assert all(f"## `mlsim {v}`" in cli for v in ("run", "check", "dataset", "sweep", "train", "anyskin-train"))
    tests = sorted(p.name for p in (ROOT / "tests").glob("test_*.py"))
    validation = validation_reference()
    assert all(f"`{t}`" in validation for t in tests)
    bench = benchmarks_reference()
    scripts = sorted(p.name for p in (ROOT / "benchmarks").glob("*.py"))
    assert all(f"`{s}`" in bench for s in scripts) and set(SLOW_BENCHMARKS) <= set(scripts)
    from mlsim.dataset.store import EPISODE_ARRAYS

    dataset = dataset_reference()
    assert all(f"| `{name}` |" in dataset for name in EPISODE_ARRAYS)


def test_site_navigation_names_pages_that_exist():
    text = (ROOT / "mkdocs.yml").read_text()
    pages = re.findall(r":\s+([\w/.-]+\.md)\s*$", text, flags=re.M)
    hooks = (ROOT / "docs" / "hooks.py").read_text()
    generated = set(re.findall(r'"([\w/.-]+\.md)"', hooks))
    missing = [p for p in pages if not (ROOT / "docs" / p).is_file() and p not in generated]
    assert len(pages) >= 20 and missing == []
    links = re.findall(r"\]\((docs/[^)#]+)", README.read_text())
    assert links and [link for link in links if not (ROOT / link).is_file()] == []


def test_measured_tables_come_from_recorded_outputs():
    """Figures on the stage pages are tables made from a command's recorded output (docs/data), each
    with the command that reproduces it: every marker names a recording, every recording is shown."""
    import csv

    from mlsim.docgen import RECORDINGS, accuracy_solve_table, expand_measured

    pages = "\n".join(p.read_text() for p in (ROOT / "docs").rglob("*.md"))
    markers = set(re.findall(r"<!-- measured: ([\w-]+) -->", pages))
    assert markers == set(RECORDINGS)
    for name, rec in RECORDINGS.items():
        with open(ROOT / "docs" / "data" / rec.file, newline="") as fh:
            rows = list(csv.DictReader(fh))
        text = expand_measured(f"<!-- measured: {name} -->")
        assert text.count("\n|") == len(rows) + 1 and rec.command in text  # header rule + one line per configuration
        assert sum(r["reference"] == "True" for r in rows) == 1 and " | reference |" in text
    with pytest.raises(KeyError, match="no such recording"):
        expand_measured("<!-- measured: nope -->")
    rows = [{"edge_length_mm": "3", "element_order": "2", "tier": "linear", "n_tets": "10", "per_frame_ms": "1.5", "reference": "False",
             "error_force": "0.0123", "pareto_force": "True", "failed": ""},
            {"edge_length_mm": "2", "element_order": "2", "tier": "nonlinear", "n_tets": "20", "per_frame_ms": "900", "reference": "True",
             "error_force": "0", "pareto_force": "False", "failed": ""}]
    table = accuracy_solve_table(rows).splitlines()
    assert table[2] == "| 3 | 2 | linear | 10 | 1.5 | 1.23e-02* |" and table[3].endswith("| 900 | reference |")
