"""Stages and sensor kinds: the registry the planner (:mod:`mlsim.pipeline`) knows them through (base layer).

A stage is one step of the flow of data (:class:`Stage`): the scene fields it ``reads``, the stages
it ``needs``, how it runs, caches, writes and summarises its result. Each stage is declared next to
its code (``fem/stages.py``, ``mlsim/emission/stage.py``, ``mlsim/render/stage.py``,
``dllm/stage.py``, ``classifiers/stage.py``). A sensor kind (``sensor.kind`` in the scene) is a
name, the schema of its ``[sensor]`` section and its stages in an order where each follows the
stages it needs (:func:`register_kind`). The built-in kinds are registered by the modules of
:data:`BUILTIN_KINDS`, imported on first use (with the stages that studies add to them,
:data:`BUILTIN_STUDY_STAGES`), so that importing the registry imports no stage
code (and a run imports only the stages its plan touches, each importing its heavy dependencies
inside its functions).

Also here, for the stages' own use: the stage key (:func:`stage_key`, the content hash a result is
cached under), the context a stage runs in (:class:`RunContext`), an in-process memo of per-sensor
objects (:func:`memo`) and load-independent precomputes cached beside the stages' results
(:func:`cached_precompute`).
"""

from __future__ import annotations

import hashlib
import importlib
import json
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

__all__ = ["Stage", "SensorKind", "RunContext", "BUILTIN_KINDS", "BUILTIN_STUDY_STAGES", "DEFAULT_KIND", "register_kind", "unregister_kind", "kind",
           "kinds", "stages", "outputs", "stage_key", "memo", "cached_precompute", "npz_io", "pickle_save", "pickle_load"]


@dataclass(frozen=True)
class Stage:
    """One step of the flow of data.

    run(scene, inputs, ctx) -> result, where inputs maps each needed stage's name to its result.
    save(result, dir) / load(dir) -> result: how the result is cached (None: never cached, for cheap
    stages). write(result, out_dir, ctx) -> list of files: the user-facing output when requested.
    summarize(result) -> dict: what goes into the run's JSON summary.
    """

    name: str
    doc: str
    reads: tuple[str, ...]
    needs: tuple[str, ...]
    run: Callable[..., Any]
    version: str = "1"
    save: Callable[[Any, Path], None] | None = None
    load: Callable[[Path], Any] | None = None
    write: Callable[..., list[Path]] | None = None
    summarize: Callable[[Any], dict] | None = None
    #: ignores(scene) -> dotted fields inside ``reads`` that this scene's run does not read (the nonlinear tier
    #: does not read the linear tiers' rod kinematics): left out of the key, so that setting them does not
    #: recompute a cached result that they cannot change
    ignores: Callable[[Any], tuple[str, ...]] | None = None


@dataclass(frozen=True)
class SensorKind:
    """A sensor kind: its name (``sensor.kind``), the pydantic model of its ``[sensor]`` section, its
    stages (each after the stages it needs) and an optional ``check(scene) -> [(field, value,
    reason)]`` of the scene's consistency beyond the schema (run by ``mlsim check`` and on load), an
    optional ``warnings(scene) -> [str]`` of what is plausible but expensive (printed by ``mlsim check``),
    and an optional ``cost(scene, stage_name) -> StageCost | None``, the expected cost of running one of
    its stages (:func:`mlsim.cost_model.stage_cost`, printed by ``mlsim run --dry-run``; None: not modelled)."""

    name: str
    sensor_model: type
    stages: tuple[Stage, ...]
    check: Callable[[Any], list] | None = None
    warnings: Callable[[Any], list] | None = None
    cost: Callable[[Any, str], Any] | None = None

    @property
    def stage_map(self) -> dict[str, Stage]:
        return {s.name: s for s in self.stages}

    @property
    def outputs(self) -> tuple[str, ...]:
        """What a scene of this kind may list in ``outputs``: the stages that write files."""
        return tuple(s.name for s in self.stages if s.write is not None)


#: The built-in kinds and the modules that register them (imported on first use).
BUILTIN_KINDS: dict[str, str] = {"ml_rod_array": "mlsim.ml_rod_array", "cls": "other_sensors.cls.kind",
                                 "plantar_sole": "other_sensors.sole.kind", "anyskin": "other_sensors.anyskin.kind"}
#: The stages that studies (orchestration) add to a built-in kind, as "module:NAME", imported with the
#: kind on first use and placed after its own stages: a study run as one of the kind's outputs, found
#: here so that the kind's module (a stage package) never imports a study.
BUILTIN_STUDY_STAGES: dict[str, tuple[str, ...]] = {"ml_rod_array": ("mlsim.studies.stages:VERIFY_S2",)}
DEFAULT_KIND = "ml_rod_array"
_KINDS: dict[str, SensorKind] = {}


def register_kind(name: str, sensor_model: type, stages, check: Callable[[Any], list] | None = None,
                  warnings: Callable[[Any], list] | None = None, cost: Callable[[Any, str], Any] | None = None) -> SensorKind:
    """Register (or replace) a sensor kind. The stages' ``needs`` must name earlier stages of the
    kind, and stage names must be unique: a ``ValueError`` says which is wrong."""
    stages = tuple(stages)
    seen: set[str] = set()
    for s in stages:
        if s.name in seen:
            raise ValueError(f"sensor kind {name!r}: two stages are named {s.name!r}")
        missing = [n for n in s.needs if n not in seen]
        if missing:
            raise ValueError(f"sensor kind {name!r}: stage {s.name!r} needs {missing}, which must be registered before it")
        seen.add(s.name)
    _KINDS[name] = SensorKind(name, sensor_model, stages, check, warnings, cost)
    return _KINDS[name]


def unregister_kind(name: str) -> None:
    """Forget a registered kind (a built-in one registers itself again when next asked for)."""
    _KINDS.pop(name, None)


def kinds() -> tuple[str, ...]:
    """The names of the known kinds (built-in and registered)."""
    return tuple(dict.fromkeys([*BUILTIN_KINDS, *_KINDS]))


def kind(name: str) -> SensorKind:
    """The registered kind ``name`` (a built-in one is imported and registered on first use)."""
    if name not in _KINDS and name in BUILTIN_KINDS:
        importlib.import_module(BUILTIN_KINDS[name])
        studies = tuple(_attribute(ref) for ref in BUILTIN_STUDY_STAGES.get(name, ()))
        if studies and name in _KINDS:
            k = _KINDS[name]
            register_kind(name, k.sensor_model, k.stages + studies, k.check, k.warnings, k.cost)
    if name not in _KINDS:
        raise KeyError(f'sensor.kind = "{name}": unknown sensor kind; choose from: {", ".join(kinds())}')
    return _KINDS[name]


def _attribute(ref: str):
    """The object a "module:NAME" reference names (the module imported)."""
    module, attr = ref.split(":")
    return getattr(importlib.import_module(module), attr)


def stages(kind_name: str = DEFAULT_KIND) -> dict[str, Stage]:
    """A kind's stages by name, each after the stages it needs."""
    return kind(kind_name).stage_map


def outputs(kind_name: str = DEFAULT_KIND) -> tuple[str, ...]:
    """What a scene of the kind may list in ``outputs``."""
    return kind(kind_name).outputs


def stage_key(scene, name: str, _memo: dict | None = None) -> str:
    """Content hash of what a stage's result depends on: its code version, the scene fields it
    reads (less those it ``ignores`` for this scene) and, recursively, the keys of the stages it needs."""
    cache = {} if _memo is None else _memo
    if name in cache:
        return cache[name]
    stage = stages(scene.kind)[name]
    payload = {
        "stage": name,
        "version": stage.version,
        "reads": scene.content_hash(stage.reads, exclude=stage.ignores(scene) if stage.ignores is not None else ()),
        "needs": {n: stage_key(scene, n, cache) for n in stage.needs},
    }
    cache[name] = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
    return cache[name]


@dataclass
class RunContext:
    """What a stage runs with besides the scene and its inputs: the cache (``has``, ``fetch``,
    ``store``: :class:`mlsim.pipeline.Cache`), the output folder, progress bars on or off, the log."""

    scene: Any
    cache: Any
    out_dir: Path | None
    progress: bool = True
    log: Callable[[str], None] = print


# Per-sensor objects that episodes share (the ML sheet's patches and its Mitsuba scene, the reduced
# model, the transport matrix), kept in this process: a worker running a dataset's episodes on one
# sensor builds or loads each once instead of once per episode. Small: a few sensors' worth. One
# sensor's episodes use about ten entries (patches, their place in the mesh, the Mitsuba sheet, the
# raster, the reduced model, the bounces' matrix, the mesh and calibration frame kept by a dataset's
# Cache(in_memory=), the DLLM's calibration): the least recently used goes first, so fewer entries
# than one episode uses would evict every one of them, every episode. Not many more: a sweep's worker
# moves from sensor to sensor, and a sensor's reduced model and matrices are hundreds of MB.
_MEMO: OrderedDict = OrderedDict()
_MEMO_ENTRIES = 16


def memo(key: tuple, build: Callable[[], Any]):
    """``build()`` once per ``key`` in this process (the last few keys kept)."""
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return _MEMO[key]
    value = build()
    _MEMO[key] = value
    while len(_MEMO) > _MEMO_ENTRIES:
        _MEMO.popitem(last=False)
    return value


def precompute_key(payload: dict) -> str:
    """The cache key of a load-independent precompute (:func:`cached_precompute`) keyed on ``payload``."""
    return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()


def cached_precompute(ctx: RunContext, stage: Stage, payload: dict, build: Callable[[], Any], message: str):
    """A load-independent precompute (not a stage of the plan) from the cache by the hash of
    ``payload``, else ``build()`` and cache it: a dataset of episodes on one sensor pays once."""
    key = precompute_key(payload)
    used = getattr(ctx.cache, "used", None)
    if used is not None:  # also when this process's memo answers: the result is on disk all the same
        used.add((stage.name, key))

    def load_or_build():
        if ctx.cache.has(stage.name, key):
            return ctx.cache.fetch(stage, key)
        ctx.log(message)
        return ctx.cache.store(stage, key, build())  # another run's where it stored this key first

    return memo((stage.name, key, str(ctx.cache.root)), load_or_build)


def npz_io(filename: str, cls: str):
    """(save, load) of a result with ``result.save(path)`` and ``Cls.load(path)``; ``cls`` is
    "module:Name", imported when a cached result is loaded (heavy modules stay unimported)."""

    def save(result, directory: Path) -> None:
        result.save(directory / filename)

    def load(directory: Path):
        return _attribute(cls).load(directory / filename)

    return save, load


def pickle_save(result, directory: Path) -> None:
    import pickle

    (directory / "result.pkl").write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))


def pickle_load(directory: Path):
    import pickle

    return pickle.loads((directory / "result.pkl").read_bytes())
