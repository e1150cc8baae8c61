"""A dataset spec: which episodes a synthetic interaction dataset holds, typed and validated.

A spec is a TOML file (``scenes/interactions/paper.toml``)::

    name = "interactions_paper"
    scene = "screw.toml"            # the base scene (sensor, camera, fidelity), relative to this file
    seed = 0                        # people, samples and camera noise all follow from it
    people = 10
    samples_per_action = 100        # spread evenly over the people
    actions = ["push", "pull", ...] # default: the eight of SPEC 1.5
    store_frames = false            # the camera frames too (chunked, compressed); large
    rod_kinematics = "first_order"  # the episodes' rods; "scene": the base scene's own (below)

    [interaction]                   # mlsim.interactions.InteractionSpec: the screw, the clamp, the people's ranges
    grip_force_n = 3.0

    [randomize]                     # optional: scene fields drawn per episode (mlsim.dataset.randomize)
    "camera.gain_db" = [0.0, 6.0]

The chain after the solve (``docs/uses/datasets.md``, the batched chain)::

    chain = "per_episode"           # the default and the reference; "batched": mlsim.dataset.batched
    device = "auto"                 # the batched chain's: "auto" (CUDA where torch finds it, else the CPU), "cpu", "cuda"
    batch_episodes = 16             # the batched chain's episodes per batch (one sensor's)

The episodes' rods: ``rod_kinematics = "first_order"`` (the default) solves them as the base scene's
tier with first-order rods (``fidelity.solve.rod_kinematics = "first_order"``, ``rod_coupling = "dead"``),
whatever the base scene says: the datasets' rate. The screw scene ships held Cosserat rods, 2.8 / 2.3 /
4.8 / 2.2 % off the nonlinear tier (rod-base von Mises / per-rod force / tip displacement / photons;
docs/stages/solve.md) at 15 x the first-order solve's cost a frame; first order is 4.3 / 3.9 / 1.1 /
3.1 % off, and the datasets' whole chain costs about 8 ms a frame. ``"scene"``: the base scene's own
rods, at their cost.

Unknown keys and bad values are refused with the dotted path, the value and what is valid, as
scenes are (:mod:`mlsim.scene`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Annotated, Any, Literal

from pydantic import Field, Strict, ValidationError, field_validator, model_serializer, model_validator

from mlsim.errors import Problem, SceneError
from mlsim.interactions import ACTIONS, InteractionSpec
from mlsim.scene import Bool, Scene, _Model, _problems_from_pydantic, load_scene, read_toml

__all__ = ["DatasetSpec", "load_dataset_spec", "dataset_spec_from_dict", "with_the_specs_rods"]

# The chain's and the rods' fields at their defaults are left out of the spec's dump and hash (the
# datasets made before they existed keep theirs)
_CHAIN_DEFAULTS = {"chain": "per_episode", "device": "auto", "batch_episodes": 16, "rod_kinematics": "first_order"}

#: the base scene's solve fields a spec's ``rod_kinematics = "first_order"`` sets (the datasets' rate)
FIRST_ORDER_RODS = {"fidelity.solve.rod_kinematics": "first_order", "fidelity.solve.rod_coupling": "dead"}


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
    # the stages after the solve: each episode's one after the other (the default and the reference),
    # or a batch of episodes of the sensor at once as tensor operations (mlsim.dataset.batched: the
    # deformed render tier, no [randomize]; the camera noise from torch's generator, the same model)
    chain: Literal["per_episode", "batched"] = "per_episode"
    # the batched chain's torch device, picked as fidelity.render.device: "auto" is CUDA where torch finds it, else the CPU
    device: Literal["auto", "cpu", "cuda"] = "auto"
    # the batched chain's episodes per batch (a GPU wants many: 100 on an H200 took 31 GiB)
    batch_episodes: Annotated[int, Strict(), Field(ge=1, le=10_000)] = 16
    # the episodes' rods: first order whatever the base scene says (the datasets' rate), or the base scene's own
    rod_kinematics: Literal["first_order", "scene"] = "first_order"

    @field_validator("randomize", mode="before")
    @classmethod
    def _ranges(cls, ranges):
        from mlsim.dataset.randomize import check_ranges

        return None if ranges is None else check_ranges(ranges) if isinstance(ranges, dict) else ranges

    @model_serializer(mode="wrap")
    def _without_absent_randomize(self, handler):
        # a spec without [randomize], or at the default chain, dumps (and hashes) as before these
        # existed: its dataset stays byte-identical
        data = handler(self)
        if data.get("randomize", 0) is None:
            del data["randomize"]
        for name, default in _CHAIN_DEFAULTS.items():
            if data.get(name) == default:
                del data[name]
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
        spec = DatasetSpec.model_validate(data)
    except ValidationError as exc:
        raise SceneError(_problems_from_pydantic(exc), source=source) from None
    problems = _chain_problems(spec)
    if problems:
        raise SceneError(problems, source=source)
    return spec


def _chain_problems(spec: DatasetSpec) -> list[Problem]:
    """The chain's settings that do not fit together, each naming its field and the fix."""
    problems = []
    if spec.chain == "per_episode" and spec.device == "cuda":
        problems.append(Problem("device", spec.device, 'the batched chain\'s device: set chain = "batched" (or device = "auto")'))
    if spec.chain == "batched" and spec.randomize:
        problems.append(Problem("chain", spec.chain, "runs batches of one sensor, and [randomize] draws a sensor per episode: "
                                'set chain = "per_episode" or remove [randomize]'))
    return problems


def with_the_specs_rods(spec: DatasetSpec, base: Scene) -> Scene:
    """The base scene with the rods the spec's episodes have: first order (:data:`FIRST_ORDER_RODS`, the datasets'
    rate) unless ``rod_kinematics = "scene"``. Idempotent: :func:`load_dataset_spec` returns it so, and
    :func:`mlsim.dataset.generate.generate` applies it to whatever base it is given."""
    return base.with_values(FIRST_ORDER_RODS) if spec.rod_kinematics == "first_order" else base


def load_dataset_spec(path: str | Path, overrides: dict[str, Any] | None = None) -> tuple[DatasetSpec, Scene]:
    """Read and validate a dataset spec and its base scene; returns (spec, base scene), the base scene with
    the spec's rods (``rod_kinematics``: first order, :data:`FIRST_ORDER_RODS`, unless ``"scene"``).

    ``overrides``: top-level fields to change (e.g. ``{"samples_per_action": 16}``)."""
    path = Path(path)
    data = read_toml(path, "dataset spec")
    data.update(overrides or {})
    spec = dataset_spec_from_dict(data, source=str(path))
    scene_path = (path.parent / spec.scene).resolve()
    if not scene_path.is_file():
        raise SceneError([Problem("scene", spec.scene, f"no such scene file (looked for {scene_path})")], source=str(path))
    base = with_the_specs_rods(spec, load_scene(scene_path))
    if base.load is None:
        raise SceneError([Problem("scene", spec.scene, "the base scene needs a [load] (its friction is the screw's)")], source=str(path))
    if spec.chain == "batched":  # what mlsim.dataset.batched runs (BatchedChain.from_scene would refuse it in every worker)
        tier, stress = base.fidelity.render.tier, base.emission.equivalent_stress
        if tier != "deformed" or stress != "von_mises":
            field, value, need = (("fidelity.render.tier", tier, "deformed") if tier != "deformed" else
                                  ("emission.equivalent_stress", stress, "von_mises"))
            raise SceneError([Problem("chain", "batched", f'the batched chain runs {field} = "{need}" only, and the base scene has '
                                      f'{field} = "{value}": set chain = "per_episode" or {field} = "{need}" in {spec.scene}')],
                             source=str(path))
    for field, ends in (spec.randomize or {}).items():  # both ends of a range must make a valid scene
        for value in ends:
            try:
                base.with_values({field: value})
            except SceneError as exc:
                raise SceneError([Problem(f"randomize.{field}", list(ends), f"{value:g} gives an invalid scene: {exc.problems[0].message}")],
                                 source=str(path)) from None
    return spec, base
