"""A run's cost before it starts, and its budget (orchestration layer).

:func:`estimate` prices the stages a plan will run (those it loads from the cache cost nothing) with
:mod:`mlsim.cost_model`; ``mlsim run --dry-run`` prints the table and every run's log starts with
its one-line total. :func:`enforce` refuses a run past its budget before anything runs: the memory
budget (``--max-memory-gb``, by default ``MEMORY_FRACTION`` of this machine's memory) and, when
given, a frame budget (``--max-frames``); ``--over-budget`` runs it anyway.

The run keeps every stage's result until it ends (:func:`mlsim.pipeline.run`), so its expected peak
is the sum of the stages' memory (and the largest a stage holds only while it runs), plus the
interpreter and the libraries it imports (:func:`mlsim.cost_model.process_bytes`: ``BASE_BYTES`` for
the ml_rod_array kind, less for the sibling kinds).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from mlsim.cost_model import GB, ML_PROCESS_BYTES, StageCost, process_bytes, stage_cost
from mlsim.errors import Problem, SceneError

__all__ = ["RunEstimate", "estimate", "enforce", "machine_memory_bytes", "default_max_memory_gb", "MEMORY_FRACTION", "BASE_BYTES",
           "bytes_text", "duration_text"]

# Half the machine by default: a run shares it (the other agents of a shared machine, the other
# workers of a sweep or a dataset, each its own run), and the estimate is good to a factor of two.
MEMORY_FRACTION = 0.5
# python, numpy, scipy, pydantic and the project's modules imported: about 0.3 GB resident (the ML kind's run)
BASE_BYTES = ML_PROCESS_BYTES


def machine_memory_bytes() -> float:
    """This machine's physical memory (bytes)."""
    return float(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))


def default_max_memory_gb() -> float:
    """The default memory budget of a run: ``MEMORY_FRACTION`` of the machine's memory, GB."""
    return MEMORY_FRACTION * machine_memory_bytes() / GB


@dataclass(frozen=True)
class RunEstimate:
    """The stages to run with their costs (None: no cost model for that stage) and the totals;
    ``base_bytes``: the process before any stage's result."""

    rows: tuple[tuple[str, StageCost | None], ...]
    base_bytes: float = BASE_BYTES

    @property
    def memory_bytes(self) -> float:
        costs = [c for _, c in self.rows if c is not None]
        return self.base_bytes + sum(c.memory_bytes for c in costs) + max((c.transient_bytes for c in costs), default=0.0)

    @property
    def seconds(self) -> float:
        return sum(c.seconds for _, c in self.rows if c is not None)

    @property
    def frames(self) -> int:
        return max((c.frames or 0 for _, c in self.rows if c is not None), default=0)

    def headline(self) -> str:
        unmodelled = [name for name, c in self.rows if c is None]
        return (f"estimate: {duration_text(self.seconds)} and {self.memory_bytes / GB:.2g} GB peak for {len(self.rows)} stage(s) to run"
                + (f" ({', '.join(unmodelled)}: not modelled)" if unmodelled else "") + " (mlsim.cost_model, 2 cores; within 2x)")

    def table(self) -> list[str]:
        w = max([12, *(len(name) for name, _ in self.rows)])
        lines = [f"  {'stage':<{w}} {'frames':>8} {'steps':>8} {'tets':>9} {'memory':>10} {'time':>10}  note"]
        for name, c in self.rows:
            if c is None:
                lines.append(f"  {name:<{w}} {'':>8} {'':>8} {'':>9} {'-':>10} {'-':>10}  no cost model")
                continue
            lines.append(f"  {name:<{w}} {_n(c.frames):>8} {_n(c.steps):>8} {_n(c.tets):>9} {bytes_text(c.memory_bytes + c.transient_bytes):>10} "
                         f"{duration_text(c.seconds):>10}  {c.note}".rstrip())
        lines.append(f"  {'total':<{w}} {_n(self.frames or None):>8} {'':>8} {'':>9} {bytes_text(self.memory_bytes):>10} {duration_text(self.seconds):>10}"
                     "  (memory: every stage's result is kept, plus the interpreter)")
        return lines


def estimate(scene, steps, cache=None) -> RunEstimate:
    """The cost of the plan ``steps`` (:func:`mlsim.pipeline.plan`): the stages it runs. ``cache``
    (:class:`mlsim.pipeline.Cache`, or None): where a stage's load-independent precompute is already
    cached (the solve's reduced-tier model, the render's matrix), it is not priced."""
    def cached(stage: str) -> bool:
        ask = {"solve": _reduced_model_cached, "render": _render_matrix_cached}.get(stage)
        return cache is not None and ask is not None and ask(scene, cache)

    rows = tuple((s.stage.name, stage_cost(scene, s.stage.name, precompute_cached=cached(s.stage.name))) for s in steps if s.action == "run")
    return RunEstimate(rows, process_bytes(scene))


def _reduced_model_cached(scene, cache) -> bool:
    """Whether the cache holds the reduced tier's precompute of this scene's sensor (ml_rod_array scenes on the
    reduced tier only)."""
    if scene.kind != "ml_rod_array" or scene.load is None or scene.fidelity.solve.tier != "reduced":
        return False
    from fem.stages import REDUCED_MODEL, reduced_model_payload
    from mlsim.stage import precompute_key

    return bool(cache.has(REDUCED_MODEL.name, precompute_key(reduced_model_payload(scene))))


def _render_matrix_cached(scene, cache) -> bool:
    """Whether the cache holds the render's matrix of this sensor and view (the transport tier's light-transport
    matrix, the deformed tier's bounces; ml_rod_array scenes only)."""
    if scene.kind != "ml_rod_array" or scene.fidelity.render.tier not in ("transport", "deformed"):
        return False
    from mlsim.render.stage import TRANSPORT, transport_payload
    from mlsim.stage import precompute_key

    return bool(cache.has(TRANSPORT.name, precompute_key(transport_payload(scene, bounces=scene.fidelity.render.tier == "deformed"))))


def enforce(est: RunEstimate, max_memory_gb: float | None = None, max_frames: int | None = None, over_budget: bool = False) -> None:
    """Refuse (a :class:`SceneError`, exit code 2) a run expected to pass its budget, unless ``over_budget``."""
    for flag, value in (("--max-memory-gb", max_memory_gb), ("--max-frames", max_frames)):
        if value is not None and not value > 0:
            raise SceneError([Problem(flag, value, "must be > 0")])
    budget_gb = default_max_memory_gb() if max_memory_gb is None else float(max_memory_gb)
    problems = []
    if est.memory_bytes > budget_gb * GB:
        worst = max((c for _, c in est.rows if c is not None), key=lambda c: c.memory_bytes, default=None)
        most = f"most for the {worst.stage} stage: {worst.memory_bytes / GB:.3g} GB" if worst is not None else "the interpreter alone"
        problems.append(Problem("--max-memory-gb", round(budget_gb, 3),
                                f"the run is expected to need {est.memory_bytes / GB:.3g} GB ({most}) within a budget of {budget_gb:.3g} GB"
                                f"{' (default: ' + format(MEMORY_FRACTION, 'g') + ' of this machine)' if max_memory_gb is None else ''}; "
                                "shorten the load, coarsen the mesh or shrink the camera, or raise --max-memory-gb, or run it anyway "
                                "with --over-budget"))
    if max_frames is not None and est.frames > max_frames:
        problems.append(Problem("--max-frames", max_frames, f"the run has {est.frames} frames; shorten the load, raise --max-frames "
                                "or run it anyway with --over-budget"))
    if problems and not over_budget:
        raise SceneError(problems, source="(run budget)")


def _n(value) -> str:
    return "" if value is None else f"{value:,}"


def bytes_text(value: float) -> str:
    """``value`` bytes as MB or GB (3 figures)."""
    return f"{value / GB:.3g} GB" if value >= 0.1 * GB else f"{value / 1024**2:.3g} MB"


def duration_text(seconds: float) -> str:
    """``seconds`` as s, min or h (3 figures)."""
    if seconds < 120:
        return f"{seconds:.3g} s"
    if seconds < 7200:
        return f"{seconds / 60:.3g} min"
    return f"{seconds / 3600:.3g} h"
