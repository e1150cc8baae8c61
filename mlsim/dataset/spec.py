"""A dataset spec: which episodes a synthetic interaction dataset holds, typed and validated.

A spec is a TOML file (``scenes/interactions/paper.toml``)::

    name = "interactions_paper"
    scene = "screw.toml"            # the base scene (sensor, camera, fidelity), relative to this file
    seed = 0                        # people, samples and camera noise all follow from it
    people = 10
    samples_per_action = 100        # spread evenly over the people
    actions = ["push", "pull", ...] # default: the eight of SPEC 1.5
    store_frames = false            # the camera frames too (chunked, compressed); large

    [interaction]                   # mlsim.interactions.InteractionSpec: the screw, the clamp, the people's ranges
    grip_force_n = 3.0

    [randomize]                     # optional: scene fields drawn per episode (mlsim.dataset.randomize)
    "camera.gain_db" = [0.0, 6.0]

Unknown keys and bad values are refused with the dotted path, the value and what is valid, as
scenes are (:mod:`mlsim.scene`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any

from pydantic import Field, Strict, ValidationError, field_validator, model_serializer, model_validator

from mlsim.errors import Problem, SceneError
from mlsim.interactions import ACTIONS, InteractionSpec
from mlsim.scene import Bool, Scene, _Model, _problems_from_pydantic, load_scene, read_toml

__all__ = ["DatasetSpec", "load_dataset_spec", "dataset_spec_from_dict"]


class DatasetSpec(_Model):
    """The episodes of an interaction dataset (see the module docstring)."""

    name: str = "interactions"
    description: str = ""
    scene: str  # the base scene's TOML path, relative to the spec's file
    seed: Annotated[int, Strict(), Field(ge=0, lt=2**63)] = 0
    people: Annotated[int, Strict(), Field(ge=1, le=10_000)] = 10
    samples_per_action: Annotated[int, Strict(), Field(ge=1, le=1_000_000)] = 100
    actions: Annotated[tuple[str, ...], Field(min_length=1)] = ACTIONS
    store_frames: Bool = False
    interaction: InteractionSpec = InteractionSpec()
    # domain randomisation (mlsim.dataset.randomize): scene field -> [low, high], drawn per episode
    randomize: dict[str, tuple[float, float]] | None = None

    @field_validator("randomize", mode="before")
    @classmethod
    def _ranges(cls, ranges):
        from mlsim.dataset.randomize import check_ranges

        return None if ranges is None else check_ranges(ranges) if isinstance(ranges, dict) else ranges

    @model_serializer(mode="wrap")
    def _without_absent_randomize(self, handler):
        # a spec without [randomize] dumps (and hashes) as before it existed: its dataset stays byte-identical
        data = handler(self)
        if data.get("randomize", 0) is None:
            del data["randomize"]
        return data

    @field_validator("actions")
    @classmethod
    def _known(cls, actions):
        bad = [a for a in actions if a not in ACTIONS]
        if bad:
            raise ValueError(f'{", ".join(repr(a) for a in bad)} not an action; choose from: {", ".join(ACTIONS)}')
        if len(set(actions)) != len(actions):
            raise ValueError("an action is listed twice")
        return actions

    @model_validator(mode="after")
    def _spread(self):
        if self.samples_per_action < self.people:
            raise ValueError(f"samples_per_action = {self.samples_per_action} is below people = {self.people}: every person needs a sample "
                             "of every action (raise samples_per_action or lower people)")
        return self

    @property
    def n_episodes(self) -> int:
        return len(self.actions) * self.samples_per_action

    def content_hash(self) -> str:
        return hashlib.sha256(json.dumps(self.model_dump(mode="json"), sort_keys=True).encode()).hexdigest()


def dataset_spec_from_dict(data: dict, source: str | None = None) -> DatasetSpec:
    try:
        return DatasetSpec.model_validate(data)
    except ValidationError as exc:
        raise SceneError(_problems_from_pydantic(exc), source=source) from None


def load_dataset_spec(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[DatasetSpec, Scene]:
    """Read and validate a dataset spec and its base scene; returns (spec, base scene).

    ``overrides``: top-level fields to change (e.g. ``{"samples_per_action": 16}``)."""
    path = Path(path)
    data = read_toml(path, "dataset spec")
    data.update(overrides or {})
    spec = dataset_spec_from_dict(data, source=str(path))
    scene_path = (path.parent / spec.scene).resolve()
    if not scene_path.is_file():
        raise SceneError([Problem("scene", spec.scene, f"no such scene file (looked for {scene_path})")], source=str(path))
    base = load_scene(scene_path)
    if base.load is None:
        raise SceneError([Problem("scene", spec.scene, "the base scene needs a [load] (its friction is the screw's)")], source=str(path))
    for field, ends in (spec.randomize or {}).items():  # both ends of a range must make a valid scene
        for value in ends:
            try:
                base.with_values({field: value})
            except SceneError as exc:
                raise SceneError([Problem(f"randomize.{field}", list(ends), f"{value:g} gives an invalid scene: {exc.problems[0].message}")],
                                 source=str(path)) from None
    return spec, base
