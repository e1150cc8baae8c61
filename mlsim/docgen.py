"""The documentation's generated pages: what the code knows, written out (orchestration layer).

``make docs`` builds the site with MkDocs; its hook (``docs/hooks.py``) adds the pages made here so
that they never drift from the code:

- :func:`scene_reference` - every field of the scene and of every sensor kind's ``[sensor]``
  section, from the pydantic models: dotted path, type, unit (:func:`mlsim.units.unit_of`), default,
  allowed range or choices, and the comment written beside the field in the source;
- :func:`outputs_reference` - per sensor kind, the products ``outputs`` may name (its stages with a
  writer), what each reads and needs;
- :func:`cli_reference` - every ``mlsim`` verb's ``--help``, examples included;
- the dataset schema, the validation page (the test modules) and the benchmarks page (the scripts);
- :func:`expand_measured` - measured figures on the stage pages as tables made from a command's
  recorded output in ``docs/data/`` (:data:`RECORDINGS`: the file, the command, when), not typed.

:func:`scene_fields` is the list the scene reference is made of; ``tests/test_docs.py`` checks that
it covers every field of every model, recursively.
"""

from __future__ import annotations

import inspect
import io
import re
import textwrap
import tokenize
import types
import typing
from dataclasses import dataclass
from functools import cache

from pydantic import BaseModel
from pydantic_core import PydanticUndefined

from mlsim.units import DIMENSIONLESS, UNIT_OF_KEYS, unit_of

__all__ = ["FieldDoc", "scene_fields", "scene_reference", "outputs_reference", "cli_reference", "dataset_reference", "validation_reference",
           "benchmarks_reference", "fast_benchmarks", "field_comments", "SLOW_BENCHMARKS", "Recording", "RECORDINGS", "measured",
           "expand_measured", "accuracy_solve_table"]


@dataclass(frozen=True)
class FieldDoc:
    """One documented leaf field: ``path`` is dotted (``sensor.rod.height_mm``; ``[]`` marks a list
    of tables, ``<kind>`` a variant of a tagged union)."""

    path: str
    type: str
    unit: str
    default: str
    allowed: str
    doc: str


def field_comments(model: type) -> dict[str, str]:
    """``{field: comment}`` from the model's source and its bases': the ``#`` comment on the field's
    line and the comment lines right above it (the project writes a field's reason there, not in
    ``Field()``)."""
    out: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if cls is not model and issubclass(cls, BaseModel) and cls is not BaseModel:
            out.update(_own_comments(cls, frozenset(model.model_fields)))
    return out | _own_comments(model, frozenset(model.model_fields))


@cache
def _own_comments(model: type, fields) -> dict[str, str]:
    try:
        source = textwrap.dedent(inspect.getsource(model))
    except (OSError, TypeError):
        return {}
    comments = {tok.start[0]: tok.string.lstrip("#").strip()
                for tok in tokenize.generate_tokens(io.StringIO(source).readline) if tok.type == tokenize.COMMENT}
    out: dict[str, str] = {}
    pending: list[str] = []
    for number, line in enumerate(source.splitlines(), start=1):
        body = line[4:] if line.startswith("    ") else None
        if body is None or body[:1] in (" ", ""):  # the class line, a blank line, a method's body
            pending = []
            continue
        if body.startswith("#"):
            pending.append(comments.get(number, ""))
            continue
        name = body.split(":", 1)[0].strip()
        if ":" in body and name in fields:
            parts = [*pending, comments.get(number, "")]
            if any(parts):
                out[name] = " ".join(p for p in parts if p)
        pending = []
    return out


def _models_in(annotation) -> list[type]:
    """The pydantic models an annotation holds (through Optional, Union, tuple, Annotated, dict values)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    found: list[type] = []
    for arg in typing.get_args(annotation):
        found += _models_in(arg)
    return found


def _type_name(annotation) -> str:
    origin = typing.get_origin(annotation)
    if origin is typing.Annotated:
        return _type_name(typing.get_args(annotation)[0])
    if origin is typing.Literal:
        return "choice"
    if origin in (typing.Union, types.UnionType):
        names = [_type_name(a) for a in typing.get_args(annotation) if a is not type(None)]
        return " or ".join(dict.fromkeys(names)) + (" (optional)" if type(None) in typing.get_args(annotation) else "")
    if origin in (tuple, list):
        args = [a for a in typing.get_args(annotation) if a is not Ellipsis]
        inner = " or ".join(dict.fromkeys(_type_name(a) for a in args)) if args else "value"
        return f"list of {inner}"
    if origin is dict:
        return "table"
    if isinstance(annotation, type):
        return {"float": "number", "int": "integer", "bool": "true/false", "str": "text"}.get(annotation.__name__, annotation.__name__)
    return str(annotation)


def _literals(annotation) -> list:
    if typing.get_origin(annotation) is typing.Literal:
        return list(typing.get_args(annotation))
    out: list = []
    for arg in typing.get_args(annotation):
        out += _literals(arg)
    return out


def _bounds(annotation, metadata) -> str:
    """"> 0", ">= 20, <= 60" from the field's and its type's constraints."""
    items = list(metadata)
    stack = [annotation]
    while stack:
        a = stack.pop()
        if typing.get_origin(a) is typing.Annotated:
            items += list(typing.get_args(a)[1:])
            stack.append(typing.get_args(a)[0])
        elif typing.get_origin(a) in (typing.Union, types.UnionType, tuple):
            stack += list(typing.get_args(a))
    parts = []
    for item in items:
        for sub in [item, *getattr(item, "metadata", [])]:
            for attr, sign in (("gt", ">"), ("ge", ">="), ("lt", "<"), ("le", "<="), ("min_length", "items >="), ("max_length", "items <=")):
                value = getattr(sub, attr, None)
                if value is not None and f"{sign} {value:g}" not in parts:
                    parts.append(f"{sign} {value:g}")
    return ", ".join(parts)


def _default(field) -> str:
    if field.is_required():
        return "required"
    value = field.default
    if value is PydanticUndefined:
        return "-"
    if isinstance(value, BaseModel):
        return "(table)"
    if value is None:
        return "none"
    if isinstance(value, tuple):
        return "[" + ", ".join(_fmt(v) for v in value) + "]"
    return _fmt(value)


def _fmt(value) -> str:
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _tag_of(model: type) -> str | None:
    """The tag (``shape``, ``kind``) value of a tagged-union member, e.g. ``"flat"``."""
    for tag in ("shape", "kind"):
        f = model.model_fields.get(tag)
        if f is not None and typing.get_origin(f.annotation) is typing.Literal and len(typing.get_args(f.annotation)) == 1:
            return typing.get_args(f.annotation)[0]
    return None


def scene_fields(model: type, prefix: str = "") -> list[FieldDoc]:
    """Every leaf field of ``model``, recursively (see :class:`FieldDoc`)."""
    rows: list[FieldDoc] = []
    comments = field_comments(model)
    for name, field in model.model_fields.items():
        annotation = field.annotation
        path = f"{prefix}{name}"
        nested = _models_in(annotation)
        doc = field.description or comments.get(name, "")
        if nested:
            is_list = typing.get_origin(annotation) in (tuple, list)
            is_map = typing.get_origin(annotation) is dict
            for sub in nested:
                tag = _tag_of(sub) if len(nested) > 1 else None
                sub_prefix = path + ("[]" if is_list else "") + (".NAME" if is_map else "") + (f"<{tag}>" if tag else "") + "."
                rows += scene_fields(sub, sub_prefix)
            continue
        choices = _literals(annotation)
        allowed = ", ".join(_fmt(c) for c in choices) if choices else _bounds(annotation, field.metadata)
        unit = unit_of(name)
        if not unit and name in DIMENSIONLESS:
            unit = f"1 ({DIMENSIONLESS[name]})"
        elif not unit and name in UNIT_OF_KEYS:
            unit = UNIT_OF_KEYS[name]
        rows.append(FieldDoc(path, _type_name(annotation), unit, _default(field), allowed, doc))
    return rows


def _table(rows: list[FieldDoc]) -> str:
    def cell(text: str) -> str:
        return text.replace("|", "\\|").replace("\n", " ")

    lines = ["| field | type | unit | default | allowed | notes |", "|---|---|---|---|---|---|"]
    lines += [f"| `{r.path}` | {cell(r.type)} | {cell(r.unit)} | {cell(r.default)} | {cell(r.allowed)} | {cell(r.doc)} |" for r in rows]
    return "\n".join(lines)


def _model_doc(model: type) -> str:
    return inspect.cleandoc(model.__doc__ or "").split("\n\n")[0].replace("\n", " ")


def scene_reference() -> str:
    """The scene reference page (Markdown): the scene's sections, then each sensor kind's ``[sensor]``."""
    from mlsim.scene import Scene
    from mlsim.stage import kind, kinds

    out = ["# Scene reference", "",
           "Generated from the scene's pydantic models (`mlsim/scene.py`, each kind's schema) by `mlsim.docgen` when the site is "
           "built: every field, its unit (read from its name, `mlsim.units`), default, allowed values and the note written beside it "
           "in the source. Unknown keys are refused; `mlsim check SCENE` prints a scene resolved with units. `[]` marks a list of "
           "tables (`[[load.segments]]`), `<flat>` the variant a tag selects (`shape = \"flat\"`), `NAME` a key you choose.", ""]
    sections: dict[str, list[FieldDoc]] = {}
    for row in scene_fields(Scene):
        top = row.path.split(".", 1)[0].split("[")[0]
        sections.setdefault(top if "." in row.path or "[" in row.path else "(top level)", []).append(row)
    for name, rows in sections.items():
        if name == "sensor":
            continue
        out += [f"## `{name}`" if name != "(top level)" else "## Top level", "", _table(rows), ""]
    for kind_name in kinds():
        model = kind(kind_name).sensor_model
        out += [f"## `[sensor]` of kind `{kind_name}`", "", _model_doc(model), "", _table(scene_fields(model, "sensor.")), ""]
    return "\n".join(out)


def outputs_reference() -> str:
    """The outputs page (Markdown): per sensor kind, each stage, whether ``outputs`` may name it, what it reads."""
    from mlsim.stage import kind, kinds

    out = ["# Outputs reference", "",
           "Generated from the stage registry (`mlsim.stage`). A scene's `outputs` (or `mlsim run --outputs`) names the products "
           "to write; the planner runs only the stages they need and loads the rest from the cache. A stage without a writer is "
           "computed and cached but writes no file.", ""]
    for kind_name in kinds():
        k = kind(kind_name)
        out += [f"## Kind `{kind_name}`", "", "| output | what | needs | reads (scene fields) |", "|---|---|---|---|"]
        for s in k.stages:
            name = f"`{s.name}`" if s.write is not None else f"{s.name} (no files)"
            reads = ", ".join(f"`{r}`" for r in s.reads)
            out.append(f"| {name} | {s.doc.replace('|', '/')} | {', '.join(s.needs) or '-'} | {reads} |")
        out.append("")
    return "\n".join(out)


def cli_reference() -> str:
    """The command-line page (Markdown): ``mlsim --help`` and every verb's ``--help``."""
    import argparse

    from mlsim.cli import build_parser

    parser = build_parser()
    out = ["# Command line", "", "Generated from `mlsim`'s parser (`mlsim/cli.py`). Exit codes: 0 success, 2 bad input (the "
           "message names the field and the fix), 1 a stage could not finish.", "", "```text", parser.format_help().rstrip(), "```", ""]
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for verb, sub in action.choices.items():
                out += [f"## `mlsim {verb}`", "", "```text", sub.format_help().rstrip(), "```", ""]
    return "\n".join(out)


def _first_paragraph(path) -> str:
    import ast

    doc = ast.get_docstring(ast.parse(path.read_text(), str(path))) or ""
    return inspect.cleandoc(doc).split("\n\n")[0].replace("\n", " ")


def _root():
    from pathlib import Path

    return Path(__file__).resolve().parents[1]


VALIDATION_INTRO = """# Validation

Every verification of the simulator is a test that can fail for the right reason: a closed form, a
convergence order, a conservation law, an invariance, a statistical test of noise, a published set-up
or an independent code. This page lists them, generated from the test modules' docstrings
(`mlsim.docgen`); each line's command reruns it (`-m slow` adds the long validation runs).

The published FEM set-up of SPEC 1.4 is also a scene: `mlsim run scenes/verify_fem_s2.toml` (a rod
against a bonded steel block on a slab under the same lateral force: profiles CSV and plot, the
sliding/pressing ratios in `summary.json`, and per force the PDMS volume strained beyond its elongation
at break; SPEC 1.4's 1-16 N all tear some, so the run log says those ratios are not a physical
prediction). The solve and render tiers' errors against their references come from `mlsim accuracy`
(the [solve](stages/solve.md) and [render](stages/render.md) pages).
"""


def validation_reference() -> str:
    """The validation page (Markdown): each test module, what it verifies, the command that reruns it."""
    lines = [VALIDATION_INTRO, "| test module | what it checks | command |", "|---|---|---|"]
    for path in sorted((_root() / "tests").glob("test_*.py")):
        what = _first_paragraph(path).replace("|", "/")
        lines.append(f"| `{path.name}` | {what} | `python -m pytest tests/{path.name}` |")
    return "\n".join(lines) + "\n"


#: benchmarks that ``make bench`` leaves out (each over ~10 minutes on 2 cores, or needs a GPU): run them by name.
SLOW_BENCHMARKS: dict[str, str] = {
    "bench_dataset.py": "the paper-sized dataset (800 episodes; its target is under 15 min on 2 cores) and the CNNs' training; "
                        "--set samples_per_action=4 --set people=2 --no-train --alone 8: the per-stage table in about 2 min",
    "bench_sweep.py": "the 5-point height sweep from an empty cache: 9-15 min on 2 cores, mostly fTetWild",
    "direction_scatter.py": "the direction study rerun once per cause of scatter (each a full study)",
    "bench_solvers.py": "every sparse solver on the default sensor's matrices, each in its own process: about 6.5 min",
    "bench_render_device.py": "the path tier on an NVIDIA GPU against the CPU (benchmarks/device/)",
    "calibrate_brightness.py": "reproduces emission.brightness_photons_per_m2 (a calibration, not a timing)",
    "bench_cost_model.py": "the tiny, demo and screw scenes each run whole from an empty cache in a fresh process: about 19 min on 2 shared cores",
    "bench_elastica_pyelastica.py": "needs PyElastica (the `bench` extra); an explicit Cosserat rod to rest, minutes per load",
}


def fast_benchmarks() -> list[str]:
    """The scripts ``make bench`` runs: every ``benchmarks/*.py`` not in :data:`SLOW_BENCHMARKS`."""
    return [p.name for p in sorted((_root() / "benchmarks").glob("*.py")) if p.name not in SLOW_BENCHMARKS]


def benchmarks_reference() -> str:
    """The benchmarks page (Markdown): every script in ``benchmarks/``, what it measures, whether ``make bench`` runs it."""
    lines = ["# Benchmarks", "",
             "Timed runs that are not tests (a timing is never asserted in the suite). Each script prints medians; figures quoted "
             "in these pages were taken on 2 shared cores and say so. `make bench` runs every benchmark below except the slow ones, "
             "which it lists; run one by name: `python benchmarks/NAME.py` (each has `--help`). Generated from the scripts' "
             "docstrings (`mlsim.docgen`).", "", "| script | what it measures | `make bench` |", "|---|---|---|"]
    for path in sorted((_root() / "benchmarks").glob("*.py")):
        slow = SLOW_BENCHMARKS.get(path.name)
        lines.append(f"| `{path.name}` | {_first_paragraph(path).replace('|', '/')} | {'slow: ' + slow if slow else 'yes'} |")
    return "\n".join(lines) + "\n"


def dataset_reference() -> str:
    """The dataset schema page (Markdown), from :data:`mlsim.dataset.store.EPISODE_ARRAYS` and the spec model."""
    from mlsim.dataset.spec import DatasetSpec
    from mlsim.dataset.store import EPISODE_ARRAYS, STORE_NAME

    lines = ["# Dataset schema", "",
             f"`mlsim dataset SPEC --out DIR` writes `DIR/{STORE_NAME}` (Zarr v3): the root group's attributes hold the spec, the "
             "base scene and its hash, the people, the actions and class names, the package versions and the mesh's cache key; "
             "`episodes/<action>_<k>/` holds one episode, written whole or not at all. `DIR/README.md` is the dataset card. "
             "Read it with `mlsim.dataset.reader.load_episodes(DIR)` or the torch `EpisodeDataset`. Generated from "
             "`mlsim.dataset.store.EPISODE_ARRAYS` and the spec's model.", "",
             "## Arrays of an episode (T frames, N taxels, R rods)", "", "| array | dtype | shape | meaning |", "|---|---|---|---|"]
    lines += [f"| `{name}` | {dtype} | {shape} | {what.replace('|', '/')} |" for name, (dtype, shape, what) in EPISODE_ARRAYS.items()]
    lines += ["", "Each episode's attributes: `episode_id`, `action`, `label` (8 classes), `label_4` (4 classes), `person`, "
              "`sample_index`, `noise_seed`, `sample` (the drawn stroke), `n_frames`, `fps`, `rod_of_taxel`, the largest sheet "
              "displacement, the peak normal force and the stages' seconds.", "",
              "## The dataset spec", "", _table(scene_fields(DatasetSpec)), ""]
    return "\n".join(lines)


# --- measured figures: tables made from recorded outputs, not typed by hand ---------------------
@dataclass(frozen=True)
class Recording:
    """An output file of a command, kept in ``docs/data/`` and shown on a page as a table."""

    file: str  # under docs/data/
    command: str  # the command that wrote it (its output folder renamed)
    measured: str  # when and on what, e.g. "2026-11-27, 2 shared cores"


#: name -> recording; a page shows one where it writes ``<!-- measured: NAME -->``.
RECORDINGS: dict[str, Recording] = {
    "accuracy_solve_tiny": Recording(
        "accuracy_solve_tiny.csv", "mlsim accuracy scenes/mavig_tiny.toml --stage solve --edges 3.0 2.5",
        "2026-11-27, 2 cores shared with other work (load average about 10): costs are upper bounds"),
}

_MARKER = re.compile(r"<!-- measured: ([\w-]+) -->")


def accuracy_solve_table(rows: list[dict]) -> str:
    """``accuracy_solve.csv`` rows (as read by :class:`csv.DictReader`) as a Markdown table: each
    configuration's cost and its errors against the reference (``*``: on the Pareto front)."""
    errors = [k[len("error_"):] for k in rows[0] if k.startswith("error_")] if rows else []
    head = ["edge mm", "order", "tier", "tets", "ms/frame", *[e.replace("_", " ") for e in errors]]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for r in rows:
        if r.get("failed"):
            lines.append(f"| {r['edge_length_mm']} | {r['element_order']} | {r['tier']} | failed: {r['failed']} |" + " |" * (len(head) - 4))
            continue
        errs = ["reference" if r["reference"] == "True" else f"{float(r['error_' + e]):.2e}{'*' if r['pareto_' + e] == 'True' else ''}"
                for e in errors]
        lines.append(f"| {r['edge_length_mm']} | {r['element_order']} | {r['tier']} | {r['n_tets']} | {float(r['per_frame_ms']):.3g} | "
                     + " | ".join(errs) + " |")
    return "\n".join(lines)


def measured(name: str, data_dir=None) -> str:
    """The Markdown a ``<!-- measured: NAME -->`` marker stands for: the recording's table, the command
    that reproduces it and when it was measured."""
    import csv

    rec = RECORDINGS[name]
    path = (data_dir or _root() / "docs" / "data") / rec.file
    with open(path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    return (f"{accuracy_solve_table(rows)}\n\n*Measured {rec.measured}; reproduce with `{rec.command}` "
            f"(`docs/data/{rec.file}` is its `accuracy_solve.csv`; `*`: on the Pareto front of cost against that error).*")


def expand_measured(markdown: str) -> str:
    """A page's Markdown with each ``<!-- measured: NAME -->`` replaced by :func:`measured`; an unknown
    name raises a ``KeyError`` that lists the known ones (a strict build must not show a stale marker)."""

    def one(match) -> str:
        if match.group(1) not in RECORDINGS:
            raise KeyError(f"<!-- measured: {match.group(1)} -->: no such recording; known: {', '.join(RECORDINGS)}")
        return measured(match.group(1))

    return _MARKER.sub(one, markdown)
