"""A sweep's cost before it runs (``mlsim sweep --dry-run``; orchestration layer): per variant and
load, the time and peak memory of the stages the sweep runs (:mod:`mlsim.cost_model`'s estimates of
the variant's scene under the load, as :func:`mlsim.sweep.run.Load.apply` and ``_load_metrics`` make
it), the calibration frame and the direction study, and the sweep's total on its workers.

Stages are priced once per content key across the whole sweep: a stage the cache holds, or one an
earlier load or variant of the sweep already runs (the mesh of a variant's second load, a material
sweep's one mesh), costs nothing again.

**Escalation.** A load the variant's fast tier refuses as beyond its model is solved again by the
nonlinear tier with backward-Euler dynamics (:func:`mlsim.sweep.run.escalated_scene`, at
:func:`fem.finite_strain.dynamics_substeps`). Every load is priced both ways: its fast-tier run, and
"if escalated" the nonlinear tier's solve of the escalated scene (its steps at the escalated
substeps x the cost model's nonlinear step, ``SOLVE_STEP_S["nonlinear"]``). Whether a load escalates
is known only once solved: the load one rod carries against its Euler load depends on where the
probe's rim meets it. The flag here is a proxy, :func:`escalation_risk`, from the rods' slenderness
(height over diameter) against what was measured under the swipe of ``scenes/swipe.toml``: the
published 9 mm x 5 mm rods (slenderness 1.8) carry 0.28 x their Euler load, 10.5 mm x 5 mm rods (2.1)
0.7-2.0 x, past the linear tiers' ``buckling_limit`` (0.5), and are refused. Slenderness and not the
Euler load itself, since under a probe that moves the tips by a given distance the rod's axial load
(E A dz / L) and its Euler load (pi^2 E I / 4 L^2) both scale with the modulus: their ratio goes as
dz L / d^2, a stiffer or softer material alone does not move it. Conservative: rods more slender than
the published ones are flagged "possible" (no measurement between 1.8 and 2.1), from 2.1 "likely".
Only loads with a slide are flagged: the press (the probe straight down) was not seen to escalate.

The measured escalated swipe (10.5 mm rods, 2 shared cores, 2026-11-27) took about 2.5 s a
nonlinear step out of contact and 20-80 s a step in contact with 455 contact points: the cost model's
step (0.5 s + 0.9 ms a tet, 15.8 s on the default mesh) sits between, so an escalated swipe that
spends most steps in contact can take up to 5x the estimate.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from mlsim.cost_model import StageCost, stage_cost
from mlsim.run_budget import RunEstimate

__all__ = ["LoadCost", "VariantCost", "escalation_risk", "slenderness", "variant_cost", "sweep_cost", "sweep_wall_s",
           "NOMINAL_SLENDERNESS", "ESCALATING_SLENDERNESS"]

#: the published rods (9 mm tall, 5 mm across) carry 0.28 x their Euler load under scenes/swipe.toml
NOMINAL_SLENDERNESS = 9.0 / 5.0
#: 10.5 mm x 5 mm rods carry 0.7-2.0 x under it and the linear tier refuses the swipe (scenes/swipe.toml)
ESCALATING_SLENDERNESS = 10.5 / 5.0


@dataclass(frozen=True)
class LoadCost:
    """One part of a variant's work (a load, the calibration frame, the direction study): its runs
    (``runs``, one a pipeline run: the direction study's one an angle; the stages already priced in
    the sweep left out) and, for a load, the nonlinear tier's solve if it escalates (``escalated``,
    None where it cannot, at ``substeps``) and the proxy's flag (``risk``, :func:`escalation_risk`)."""

    name: str
    runs: tuple[RunEstimate, ...]
    escalated: StageCost | None = None
    substeps: int | None = None
    risk: str = ""

    @property
    def seconds(self) -> float:
        return sum(r.seconds for r in self.runs)

    @property
    def memory_bytes(self) -> float:
        """The largest of its runs' peaks (each run keeps its stages' results, plus the interpreter)."""
        return max((r.memory_bytes for r in self.runs if r.rows), default=0.0)

    @property
    def escalated_memory_bytes(self) -> float:
        """The run's peak if escalated: the nonlinear solve's memory beside its fast-tier stages'."""
        return self.memory_bytes + (self.escalated.memory_bytes if self.escalated is not None else 0.0)

    def stages(self) -> tuple[list[str], list[str]]:
        """The modelled and the unmodelled stages of its first run that runs anything."""
        rows = next((r.rows for r in self.runs if r.rows), ())
        return [n for n, c in rows if c is not None], [n for n, c in rows if c is None]


@dataclass(frozen=True)
class VariantCost:
    variant: object
    parts: tuple[LoadCost, ...]

    @property
    def seconds(self) -> float:
        return sum(p.seconds for p in self.parts)

    @property
    def escalated_seconds(self) -> float:
        """With the flagged loads ("likely" or "possible") escalated."""
        return self.seconds + sum(p.escalated.seconds for p in self.parts if p.risk and p.escalated is not None)

    @property
    def memory_bytes(self) -> float:
        """The largest run of the variant (each load and study is a run of its own)."""
        return max((p.memory_bytes for p in self.parts), default=0.0)

    @property
    def escalated_memory_bytes(self) -> float:
        return max((p.escalated_memory_bytes if p.risk else p.memory_bytes for p in self.parts), default=0.0)


def slenderness(scene) -> float:
    """The rods' height over their diameter."""
    return scene.sensor.rod.height_mm / scene.sensor.rod.diameter_mm


def escalation_risk(scene) -> str:
    """How likely the fast tier refuses ``scene``'s load (module docstring; an estimate): "likely",
    "possible" or "" (not expected, or a load with no slide)."""
    if scene.load is None or not any(seg.kind == "slide" for seg in scene.load.segments):
        return ""
    s = slenderness(scene)
    if s >= ESCALATING_SLENDERNESS * (1 - 1e-9):
        return "likely"
    return "possible" if s > NOMINAL_SLENDERNESS * (1 + 1e-9) else ""


def _priced(scene, cache, outputs, seen: set) -> RunEstimate:
    """The stages of the plan that run and that the sweep has not priced yet (``seen``: (stage, key))."""
    from mlsim import pipeline

    rows = []
    for step in pipeline.plan(scene, cache, outputs):
        if step.action != "run" or (step.stage.name, step.key) in seen:
            continue
        seen.add((step.stage.name, step.key))
        rows.append((step.stage.name, stage_cost(scene, step.stage.name)))
    return RunEstimate(tuple(rows))


def variant_cost(variant, loads, wanted, direction, angles, cache, escalate_to: str | None = "nonlinear",
                 seen: set | None = None) -> VariantCost:
    """The cost of one variant's work in the sweep (:func:`mlsim.sweep.run.variant_record`)."""
    from mlsim.sweep.run import escalated_scene

    seen = set() if seen is None else seen
    scene, wanted, parts = variant.scene, set(wanted), []
    if wanted & {"brightness", "tear"}:
        outputs = ("solve", "camera") if "brightness" in wanted else ("solve",)  # as _load_metrics asks
        for load in loads:
            s = load.apply(scene, outputs)
            est = _priced(s, cache, outputs, seen)
            escalated = substeps = None
            if escalate_to is not None and s.fidelity.solve.tier != escalate_to:
                e = escalated_scene(s, escalate_to)
                escalated, substeps = stage_cost(e, "solve"), e.fidelity.solve.substeps
            parts.append(LoadCost(load.name, (est,), escalated, substeps, escalation_risk(s) if escalated is not None else ""))
    if "separation" in wanted:
        parts.append(LoadCost("separation", (_priced(scene.with_values({"outputs": ["calibration"]}), cache, ("calibration",), seen),)))
    if "direction" in wanted and direction is not None:
        s = direction.apply(scene, ("dllm",))
        slides = [i for i, seg in enumerate(s.load.segments) if seg.kind == "slide"] if s.load is not None else []
        runs = []
        for a in angles if slides else ():  # as mlsim.studies.direction.direction_study turns its first slide
            turned = s.with_values({f"load.segments[{slides[0]}].direction_deg": float(a), "outputs": ["dllm", "camera", "solve"]})
            runs.append(_priced(turned, cache, ("dllm", "camera", "solve"), seen))
        parts.append(LoadCost(f"direction ({len(runs)} angles)", tuple(runs)))
    return VariantCost(variant, tuple(parts))


def sweep_cost(variants, loads, wanted, direction, angles, cache, escalate_to: str | None = "nonlinear",
               skip=frozenset()) -> list[VariantCost]:
    """Each buildable variant's cost, in order (those in ``skip``, already stored, left out)."""
    seen: set = set()
    return [variant_cost(v, loads, wanted, direction, angles, cache, escalate_to, seen) for v in variants
            if v.scene is not None and v.variant_id not in skip]


def sweep_wall_s(seconds, workers: int) -> float:
    """The sweep's wall time with ``workers`` taking the variants as they free up (longest first)."""
    busy = [0.0] * max(int(workers), 1)
    for s in sorted(seconds, reverse=True):
        i = busy.index(min(busy))
        busy[i] += s
    return max(busy) if math.isfinite(sum(busy)) else math.inf
