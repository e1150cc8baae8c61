"""``--dry-run`` of every verb (orchestration layer): what a command would run, and what is already
done, printed without running it. Each function returns the exit code (0)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["print_plan", "study_plan", "dataset_plan", "sweep_plan"]


def print_plan(scene, cache, outputs, label: str, steps=None, estimate=None) -> int:
    """The pipeline's plan for ``scene``: each stage, cached or to run, its key and what it reads;
    given ``estimate`` (:func:`mlsim.run_budget.estimate`, ``mlsim run`` and ``mesh``), then the cost of
    each stage to run: frames, steps, tets, memory and time. ``steps``: the plan, if already made."""
    from mlsim import pipeline

    if steps is None:
        steps = pipeline.plan(scene, cache, outputs)
    print(f"plan for {label} (cache: {cache.root}):")
    for s in steps:
        what = "cached  " if s.action == "load" else "to run  "
        mark = "*" if s.requested else " "
        print(f"  {mark} {s.stage.name:<10} {what} key {s.key[:12]}  reads {', '.join(s.stage.reads)}")
    print("  (* = requested output)")
    if estimate is not None:
        print("\n".join([estimate.headline(), *estimate.table()]))
    return 0


def study_plan(verb: str, label: str, out_dir: Path, runs: list[str], scene=None, cache=None, outputs=None) -> int:
    """A study's grid (one line per run it would make), its output folder and, given a scene, the
    pipeline plan of its base scene."""
    print(f"mlsim {verb} {label}: {len(runs)} run(s) into {out_dir}")
    for r in runs:
        print(f"  {r}")
    if scene is not None:
        print_plan(scene, cache, outputs, f"the base scene {scene.name}")
    return 0


def dataset_plan(spec, base, out: Path, workers: int, executor: str) -> int:
    """The episodes a dataset spec plans, how many ``out`` already holds, the workers."""
    from collections import Counter

    from mlsim.dataset.generate import plan_episodes
    from mlsim.dataset.store import complete_episodes

    jobs, people = plan_episodes(spec)
    done = complete_episodes(out)
    todo = [j for j in jobs if j["episode_id"] not in done]
    per_action = Counter(j["action"] for j in jobs)
    print(f"dataset {spec.name}: {len(jobs)} episodes ({', '.join(f'{a} {n}' for a, n in per_action.items())}) by {len(people)} people, "
          f"seed {spec.seed}, base scene {base.name} (solve tier {base.fidelity.solve.tier} with {_rods(spec, base)}, render tier "
          f"{base.fidelity.render.tier})")
    print(f"  {len(done)} already stored in {out}, {len(todo)} to run on {workers} {executor} worker(s); frames stored: {spec.store_frames}")
    if spec.chain == "batched":  # the device as the run would resolve it here ("cuda" without one raises, as the run would)
        from mlsim.dataset.batched import resolve_device

        device, why = resolve_device(spec.device)
        print(f"  chain: batched, {spec.batch_episodes} episodes per batch, on {device} ({why})")
    else:
        print("  chain: per_episode on the CPU (the default and the reference)")
    return 0


def _rods(spec, base) -> str:
    """The episodes' rods as the dataset runs them: the spec's first order (the datasets' rate) or the base scene's own."""
    kinematics = base.fidelity.solve.rod_kinematics.replace("_", "-")
    return (f"{kinematics} rods by the spec's rod_kinematics" if spec.rod_kinematics == "first_order" else f"the base scene's {kinematics} rods")


def sweep_plan(scene, variants, out: Path, loads, wanted, workers: int, cache=None, direction=None, angles=None,
               escalate_to: str | None = "nonlinear") -> int:
    """A sweep's variants (refused ones with the reason), the loads and metrics, what ``out`` holds, and
    each variant's cost to run (:mod:`mlsim.sweep.cost`): per load, the calibration frame and the
    direction study the time and peak memory expected, per load the nonlinear tier's solve "if
    escalated" with the proxy's flag, and the sweep's total on ``workers``."""
    from mlsim.run_budget import bytes_text, duration_text
    from mlsim.sweep.cost import ESCALATING_SLENDERNESS, NOMINAL_SLENDERNESS, slenderness, sweep_cost, sweep_wall_s
    from mlsim.sweep.run import DEFAULT_ANGLES, DEFAULT_LOADS, read_load, stored_records

    stored = stored_records(out)
    loads = [read_load(p) for p in DEFAULT_LOADS] if loads is None else loads
    angles = DEFAULT_ANGLES if angles is None else angles
    print(f"sweep of {scene.name}: {len(variants)} variant(s) into {out}, {len(stored)} already stored; metrics {', '.join(wanted)}; "
          f"loads {', '.join(l.name for l in loads)}; {workers} worker(s)")
    costs = {c.variant.variant_id: c for c in sweep_cost(variants, loads, wanted, direction, angles, cache, escalate_to, skip=set(stored))}
    for v in variants:
        state = "stored" if v.variant_id in stored else ("refused: " + v.reason if v.reason else "to run")
        c = costs.get(v.variant_id)
        cost = f"; {duration_text(c.seconds)}, {bytes_text(c.memory_bytes)} peak" if c is not None else ""
        print(f"  {v.variant_id}  {v.label:<40} {state}{cost}")
        for p in c.parts if c is not None else ():
            modelled, unmodelled = p.stages()
            what = ", ".join(modelled) or "nothing new to run"
            runs = sum(1 for r in p.runs if r.rows)
            print(f"      {p.name:<22} {duration_text(p.seconds):>9} {bytes_text(p.memory_bytes):>9}  {f'{runs} runs of ' if runs > 1 else ''}{what}"
                  + (f" ({', '.join(unmodelled)}: not modelled)" if unmodelled else ""))
            if p.escalated is not None:
                e = p.escalated
                flag = {"likely": f"LIKELY to escalate: rods {v.scene.sensor.rod.height_mm:g} x {v.scene.sensor.rod.diameter_mm:g} mm, "
                                  f"slenderness {slenderness(v.scene):.3g} >= {ESCALATING_SLENDERNESS:.3g}",
                        "possible": f"may escalate: slenderness {slenderness(v.scene):.3g} > the published rods' {NOMINAL_SLENDERNESS:.3g}",
                        }.get(p.risk, "not expected to escalate")
                print(f"      {'':<22} if escalated: +{duration_text(e.seconds)}, {bytes_text(p.escalated_memory_bytes)} peak "
                      f"(nonlinear, backward Euler, {p.substeps} substeps: {e.steps} steps, {e.tets} tets); {flag}")
    if costs:
        vc = list(costs.values())
        wall = sweep_wall_s([c.seconds for c in vc], workers)
        wall_esc = sweep_wall_s([c.escalated_seconds for c in vc], workers)
        busy = min(max(int(workers), 1), len(vc))
        peak = busy * max(c.memory_bytes for c in vc)
        peak_esc = busy * max(c.escalated_memory_bytes for c in vc)
        flagged = sum(1 for c in vc for p in c.parts if p.risk)
        print(f"  total: {duration_text(sum(c.seconds for c in vc))} of work, {duration_text(wall)} on {workers} worker(s), "
              f"{bytes_text(peak)} peak ({busy} variant(s) at once)"
              + (f"; with the {flagged} flagged load(s) escalated: {duration_text(wall_esc)}, {bytes_text(peak_esc)} peak" if flagged else ""))
        print("  (estimates: mlsim.cost_model, 2 cores, within 2x; stages cached or shared by an earlier variant counted once. "
              "Escalation flag: an estimate from the rods' slenderness against the swipe of scenes/swipe.toml (9 x 5 mm rods: "
              "0.28 x their Euler load, 10.5 x 5 mm: 0.7-2.0 x); an escalated swipe in contact can take up to 5x its estimate, "
              "mlsim.sweep.cost)")
    return 0
