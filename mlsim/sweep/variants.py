"""The variants of a sweep: ``--vary PATH=V1,V2,...`` fields combined on a grid or zipped (pure).

A variant is the base scene with some dotted fields changed (:meth:`mlsim.scene.Scene.with_values`).
One that the scene model refuses (rods that touch, a layer thicker than the rod radius, an unknown
material) is kept, with the refusal as its reason: it appears in the sweep's table and never stops
the sweep.

>>> varies = parse_vary(["sensor.rod.height_mm=6,9,12"])
>>> [v.label for v in variants(base, varies)]
['height_mm=6', 'height_mm=9', 'height_mm=12']
"""

from __future__ import annotations

import hashlib
import itertools
import json
import tomllib
from dataclasses import dataclass, field
from typing import Any

from mlsim.errors import Problem, SceneError

__all__ = ["Vary", "Variant", "parse_vary", "variants"]


@dataclass(frozen=True)
class Vary:
    """One varied field: its dotted path and its values (parsed as TOML; a bare word is a string)."""

    path: str
    values: tuple

    @property
    def name(self) -> str:
        """The path's last part (the column name in tables and plots)."""
        return self.path.rsplit(".", 1)[-1]


@dataclass
class Variant:
    """One point of the sweep: its index, the changed fields and the scene they give, or the reason
    the scene model refused them (``scene`` is then None)."""

    index: int
    values: dict[str, Any]
    scene: Any = None
    reason: str | None = None
    label: str = field(default="")

    @property
    def variant_id(self) -> str:
        """A file-safe id: the index and a short hash of the values (stable across runs)."""
        digest = hashlib.sha256(json.dumps(self.values, sort_keys=True).encode()).hexdigest()[:8]
        return f"v{self.index:03d}_{digest}"


def _value(raw: str):
    try:
        return tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        return raw.strip()  # a bare word: a string (a material's name)


def parse_vary(items: list[str] | None) -> list[Vary]:
    """``["sensor.rod.height_mm=6,7.5,9"]`` -> [Vary("sensor.rod.height_mm", (6, 7.5, 9))].

    Raises a :class:`SceneError` naming the ``--vary`` item that is malformed or names a field twice."""
    out: list[Vary] = []
    for item in items or []:
        path, sep, raw = item.partition("=")
        path = path.strip()
        values = tuple(_value(v) for v in raw.split(",") if v.strip())
        if not sep or not path or not values:
            raise SceneError([Problem("--vary", item, "expected DOTTED.PATH=V1,V2,..., e.g. sensor.rod.height_mm=6,7.5,9")])
        if any(v.path == path for v in out):
            raise SceneError([Problem("--vary", item, f"{path} is varied twice; give all its values in one --vary")])
        out.append(Vary(path, values))
    return out


def variants(base, varies: list[Vary], mode: str = "grid") -> list[Variant]:
    """Every combination of the varied values (``mode="grid"``) or the i-th value of each
    (``"zip"``, equal counts), each as a validated scene or with the reason it is refused.

    A path the scene does not have is an error of the whole sweep (a :class:`SceneError` naming it),
    not a refused variant: no variant could take it."""
    if mode not in ("grid", "zip"):
        raise SceneError([Problem("--mode", mode, "choose grid (every combination) or zip (the i-th values together)")])
    for v in varies:
        try:
            base.get(v.path)
        except (KeyError, AttributeError, IndexError, TypeError) as exc:
            raise SceneError([Problem("--vary", v.path, f"no such field in the scene ({exc}); `mlsim check SCENE` lists them")]) from None
    if mode == "zip" and len({len(v.values) for v in varies}) > 1:
        counts = ", ".join(f"{v.path}: {len(v.values)}" for v in varies)
        raise SceneError([Problem("--vary", counts, "--zip needs the same number of values in every --vary (or use --grid)")])
    combos = zip(*(v.values for v in varies)) if mode == "zip" else itertools.product(*(v.values for v in varies))
    out = []
    for i, combo in enumerate(combos):
        values = {v.path: value for v, value in zip(varies, combo)}
        label = " ".join(f"{v.name}={value:g}" if isinstance(value, float) else f"{v.name}={value}" for v, value in zip(varies, combo))
        try:
            scene = base.with_values(values)
        except SceneError as exc:
            out.append(Variant(i, values, None, "; ".join(str(p) for p in exc.problems), label))
            continue
        out.append(Variant(i, values, scene, None, label))
    return out
