"""Shipped scenes say what they are for, and fields carry their units (issue 42).

- Every TOML file under ``scenes/`` opens with a comment of at least two lines (what it runs, what to
  look at), and every section of it that is not a self-explaining list of segments has a comment or
  its fields have trailing ones; the sibling sensors' scenes (cls, anyskin, sole) included, no folder
  is a known gap any more (``KNOWN_GAPS`` is empty).
- Every numeric field of the scene's models and of every sensor kind's ``[sensor]`` model carries a
  unit in its name (``mlsim.units.unit_of``) or is a pure number listed in ``mlsim.units.DIMENSIONLESS``;
  so every numeric key a scene file can hold does.
"""

from __future__ import annotations

import typing
from pathlib import Path

import pytest

from mlsim.units import DIMENSIONLESS, UNIT_OF_KEYS, unit_of

ROOT = Path(__file__).resolve().parents[1]

#: scene folders whose header comments are not written yet: folder -> why (skipped, not failed). Empty: every
#: shipped scene, the sibling sensors' included, opens with one.
KNOWN_GAPS: dict[str, str] = {}
#: numeric fields whose unit is not in their name yet: (model, field) -> why.
KNOWN_UNITLESS = {("PairsSpec", "coefficients"): "c1..c7 have seven units (V mm^2, mm, mm^2, -, -, -, V), named in the field's comment"}

SCENES = sorted(ROOT.glob("scenes/**/*.toml"))


def header_comment(text: str) -> list[str]:
    lines = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        lines.append(line)
    return lines


def gap(path: Path) -> str | None:
    rel = path.relative_to(ROOT).as_posix()
    return next((why for folder, why in KNOWN_GAPS.items() if rel.startswith(folder + "/")), None)


@pytest.mark.parametrize("path", SCENES, ids=[p.relative_to(ROOT).as_posix() for p in SCENES])
def test_every_scene_opens_with_a_comment(path):
    if gap(path):
        pytest.skip(gap(path))
    head = header_comment(path.read_text())
    assert len(head) >= 2 and sum(len(line) for line in head) > 120, f"{path.name}: say in a comment what this scene runs and why"


def test_the_checks_catch_an_uncommented_scene():
    assert header_comment('name = "x"\n# late\n') == []
    assert header_comment("# what\n# and why\nname = 'x'\n") == ["# what", "# and why"]


def _numeric_fields(model, seen=None):
    """(model name, field name) of every int/float (or tuple of them) field, recursively."""
    from pydantic import BaseModel

    seen = set() if seen is None else seen
    if model in seen:
        return
    seen.add(model)

    def inner(annotation):
        if isinstance(annotation, type) and issubclass(annotation, BaseModel):
            return [annotation]
        return [m for a in typing.get_args(annotation) for m in inner(a)]

    def numeric(annotation) -> bool:
        if annotation in (int, float):
            return True
        return any(numeric(a) for a in typing.get_args(annotation) if a is not type(None))

    for name, field in model.model_fields.items():
        models = inner(field.annotation)
        if models:
            for m in models:
                yield from _numeric_fields(m, seen)
        elif numeric(field.annotation) and field.annotation is not bool:
            yield model.__name__, name


def test_every_numeric_field_has_a_unit_or_is_dimensionless():
    from mlsim.dataset.spec import DatasetSpec
    from mlsim.scene import Scene
    from mlsim.stage import kind, kinds

    fields = list(_numeric_fields(Scene)) + list(_numeric_fields(DatasetSpec))
    for k in kinds():
        fields += list(_numeric_fields(kind(k).sensor_model))
    assert len(fields) > 150
    missing = [f"{m}.{f}" for m, f in fields
               if not unit_of(f) and f not in DIMENSIONLESS and f not in UNIT_OF_KEYS and (m, f) not in KNOWN_UNITLESS]
    assert missing == [], "give these a unit suffix (mlsim.units.UNIT_SUFFIXES) or list them in mlsim.units.DIMENSIONLESS"
    assert set(KNOWN_UNITLESS) <= set(fields), "a known gap was fixed: remove it from KNOWN_UNITLESS"


def test_fields_keyed_by_scene_fields_take_their_keys_units():
    """A dataset spec's [randomize] ranges are in the units of the scene fields that key them: every
    field it accepts carries a unit in its name or is dimensionless."""
    from mlsim.dataset.randomize import RANDOMIZABLE

    assert set(UNIT_OF_KEYS) == {"randomize"}
    missing = [p for p in RANDOMIZABLE if not unit_of(p) and p.rsplit(".", 1)[-1] not in DIMENSIONLESS]
    assert missing == [], "a randomisable field without a unit: give it a unit suffix or list it in mlsim.units.DIMENSIONLESS"


def test_unit_of_reads_the_longest_suffix():
    assert unit_of("speed_mm_s") == "mm/s" and unit_of("duration_s") == "s" and unit_of("sensor.rod.height_mm") == "mm"
    assert unit_of("loading_wt_pct") == "wt%" and unit_of("load.segments[0].force_n") == "N" and unit_of("fps") == "frames/s"
    assert unit_of("dark_current_e_per_s") == "e-/s" and unit_of("stiffness_n_m3") == "N/m^3" and unit_of("alpha") == ""
