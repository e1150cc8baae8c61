"""The planner: a minimal plan of stages per scene, and a content-hash cache (orchestration layer).

The planner knows stages only through the registry (:mod:`mlsim.stage`): a scene's sensor kind
(``sensor.kind``) names its stages. Each stage declares the dotted scene fields it ``reads`` and the
stages it ``needs``. Its cache key is the SHA-256 of its name, its version, exactly those fields'
values and the keys of the stages it needs; so changing ``camera.gain_db`` leaves the mesh's key,
and the cached mesh, untouched.

:func:`plan` returns the stages a scene's ``outputs`` require, in order, each with an action:

- ``load``: its result is in the cache (the stages it needs are then not required for it);
- ``run``: it must be computed (the stages it needs are then required);
- a stage whose result nobody needs does not appear at all.

Stage code imports its heavy dependencies inside its functions, so a run imports only what its
plan touches: a scene that asks for the mesh never imports Mitsuba.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from mlsim import stage as registry
from mlsim.io import atomic_bytes
from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage, stage_key

__all__ = ["Stage", "PlanStep", "Cache", "plan", "run", "stage_key", "default_cache_dir", "invalidated", "atomic_bytes",
           "RunContext", "stages_of"]


def stages_of(scene: Scene) -> dict[str, Stage]:
    """The stages of the scene's sensor kind, by name, each after the stages it needs."""
    return registry.stages(scene.kind)


def __getattr__(name: str):
    # STAGES and OUTPUTS of the default kind, looked up in the registry when first asked for
    if name == "STAGES":
        return registry.stages(registry.DEFAULT_KIND)
    if name == "OUTPUTS":
        return registry.outputs(registry.DEFAULT_KIND)
    raise AttributeError(f"module 'mlsim.pipeline' has no attribute {name!r}")


# ------------------------------------------------------------------------------------ the cache
def default_cache_dir() -> Path:
    """``$MLSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/mlsim``, else ``~/.cache/mlsim``."""
    if os.environ.get("MLSIM_CACHE_DIR"):
        return Path(os.environ["MLSIM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mlsim"


class Cache:
    """Stage results on disk, one directory per (stage, key), written atomically (rename)."""

    def __init__(self, root: str | Path | None = None, keep: tuple[str, ...] | None = None, in_memory: tuple[str, ...] = ()):
        """``keep``: store only these stages' results (None: all). A dataset keeps the per-sensor
        stages and precomputes and not each episode's intermediates. ``in_memory``: these stages'
        results, once fetched, stay in this process (:func:`mlsim.stage.memo`) and are handed out
        again, not read from disk again: a dataset worker loaded the mesh anew for every episode
        (0.1 s), and with a new mesh object the per-mesh memos (the rod sections of the solve's
        error estimate, 0.23 s) were made anew too. The results are shared, so nothing may change them."""
        self.root = Path(root) if root is not None else default_cache_dir()
        self.keep = None if keep is None else frozenset(keep)
        self.in_memory = frozenset(in_memory)
        #: (stage, key) of every result this object fetched or stored, the hidden precomputes'
        #: (:func:`mlsim.stage.cached_precompute`) included: what a run needed from the cache
        self.used: set[tuple[str, str]] = set()

    def keeps(self, stage: str) -> bool:
        return self.keep is None or stage in self.keep

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def has(self, stage: str, key: str) -> bool:
        return (self.path(stage, key) / "COMPLETE").is_file()

    def store(self, stage: Stage, key: str, result):
        """Save ``result`` as (stage, key) and return what the cache holds there: ``result``, or, where
        another process stored the same key while this one computed it, that result, loaded (the
        first to finish wins).

        Why the first: a key names a result's inputs, not its bits. fTetWild's meshes of one scene
        differ from run to run (its threads), and two runs building one sensor at once (a dataset's
        driver and an ``mlsim run`` on a fresh cache) each wrote its mesh over the other's: the
        precomputes one of them cached from its mesh were then read with the other's, and every
        episode of the dataset failed ("cannot reshape array of size 2863392 into shape
        (28,6,16188)"). A run that loses hands the winner's result to its later stages, so everything
        cached after it agrees with it."""
        self.used.add((stage.name, key))
        if self.has(stage.name, key):
            return self.fetch(stage, key)
        final = self.path(stage.name, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:12]}.", dir=final.parent))
        try:
            stage.save(result, tmp)
            (tmp / "COMPLETE").write_text(key)
            for _ in range(3):
                try:
                    os.rename(tmp, final)  # a directory onto a non-empty one fails (POSIX), atomically
                    return result
                except OSError:
                    if self.has(stage.name, key):  # another process's, complete: keep it
                        shutil.rmtree(tmp, ignore_errors=True)
                        return self.fetch(stage, key)
                    shutil.rmtree(final, ignore_errors=True)  # a leftover without its COMPLETE mark
            raise OSError(f"cache: could not move {tmp} to {final}; remove {final} and run again")
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise

    def fetch(self, stage: Stage, key: str):
        self.used.add((stage.name, key))
        if stage.name in self.in_memory:
            return registry.memo(("cached stage", stage.name, key, str(self.root)), lambda: stage.load(self.path(stage.name, key)))
        return stage.load(self.path(stage.name, key))


# ---------------------------------------------------------------------------------- the planner
@dataclass
class PlanStep:
    stage: Stage
    key: str
    action: str  # "run" or "load"
    requested: bool


def plan(scene: Scene, cache: Cache | None = None, outputs: tuple[str, ...] | None = None) -> list[PlanStep]:
    """The minimal ordered list of stages that produce ``outputs`` (default: the scene's)."""
    outputs = tuple(scene.outputs if outputs is None else outputs)
    stages = stages_of(scene)
    for name in outputs:
        if name not in stages:
            raise KeyError(f"unknown output {name!r}; choose from: {', '.join(registry.outputs(scene.kind))}")
    memo: dict = {}
    actions: dict[str, str] = {}

    def require(name: str) -> None:
        if name in actions:
            return
        key = stage_key(scene, name, memo)
        stage = stages[name]
        if cache is not None and stage.save is not None and cache.has(name, key):
            actions[name] = "load"
        else:
            actions[name] = "run"
            for need in stage.needs:
                require(need)

    for name in outputs:
        require(name)
    return [PlanStep(stages[n], stage_key(scene, n, memo), actions[n], n in outputs) for n in stages if n in actions]


def invalidated(old: Scene, new: Scene) -> list[str]:
    """Names of the stages whose results differ between two scenes (e.g. after ``with_values``)."""
    return [n for n in stages_of(new) if n not in stages_of(old) or stage_key(old, n) != stage_key(new, n)]


# ---------------------------------------------------------------------------------- the runner
@dataclass
class RunResult:
    steps: list[PlanStep]
    results: dict[str, Any]
    seconds: dict[str, float]
    files: dict[str, list[Path]] = field(default_factory=dict)
    scene: Scene | None = None
    scene_path: str | None = None
    _summary: dict | None = field(default=None, repr=False)

    @property
    def summary(self) -> dict:
        """The run's summary (scene, plan, each stage's key, action, time and summary, versions), made
        when first asked for: a dataset's episodes never ask, and making it cost 0.47 s an episode of
        the screw scene (the camera's per-rod summary, the package versions' metadata)."""
        if self._summary is None:
            self._summary = _summary(self.scene, self.steps, self.results, self.seconds, self.files, self.scene_path)
        return self._summary


def run(scene: Scene, out_dir: str | Path | None = None, cache: Cache | None = None, outputs: tuple[str, ...] | None = None,
        progress: bool = True, log: Callable[[str], None] = print, scene_path: str | None = None) -> RunResult:
    """Execute the plan: load cached results, run the rest (caching them), write requested outputs
    and a JSON summary to ``out_dir`` (nothing is written when it is None)."""
    cache = cache if cache is not None else Cache()
    steps = plan(scene, cache, outputs)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    ctx = RunContext(scene, cache, out, progress, log)
    results: dict[str, Any] = {}
    seconds: dict[str, float] = {}
    files: dict[str, list[Path]] = {}
    for step in steps:
        st = step.stage
        t0 = time.perf_counter()
        if step.action == "load":
            results[st.name] = cache.fetch(st, step.key)
        else:
            log(f"[{st.name}] running")
            results[st.name] = st.run(scene, {n: results[n] for n in st.needs}, ctx)
            if st.save is not None and cache.keeps(st.name):
                # the cache's result: another run's where it stored this key first (Cache.store)
                results[st.name] = cache.store(st, step.key, results[st.name])
        seconds[st.name] = time.perf_counter() - t0
        if step.requested and out is not None and st.write is not None:
            files[st.name] = st.write(results[st.name], out, ctx)
        log(f"[{st.name}] {'loaded from cache' if step.action == 'load' else 'done'} in {seconds[st.name]:.2f} s")
    result = RunResult(steps, results, seconds, files, scene, scene_path)
    if out is not None:
        path = out / "summary.json"
        atomic_bytes(path, json.dumps(result.summary, indent=2, default=str).encode())
        files["summary"] = [path]
    return result


def _summary(scene, steps, results, seconds, files, scene_path) -> dict:
    import mlsim

    return {
        "mlsim_version": mlsim.__version__,
        "scene": {"name": scene.name, "path": scene_path, "hash": scene.content_hash(), "seed": scene.seed},
        "outputs": {k: [p.name for p in v] for k, v in files.items()},
        "stages": {
            s.stage.name: {
                "key": s.key,
                "action": s.action,
                "seconds": seconds[s.stage.name],
                **({"summary": s.stage.summarize(results[s.stage.name])} if s.stage.summarize else {}),
            }
            for s in steps
        },
        "versions": package_versions(),
    }


def package_versions() -> dict:
    """The Python version and the versions of the packages results depend on (for run summaries
    and dataset metadata)."""
    import platform
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in ("mlsim", "numpy", "scipy", "pydantic", "trimesh", "manifold3d", "pytetwild", "meshio", "scikit-fem", "pypardiso", "mitsuba",
                "drjit", "colour-science", "opencv-contrib-python-headless", "torch", "zarr"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out
