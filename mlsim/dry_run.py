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
          f"seed {spec.seed}, base scene {base.name} (solve tier {base.fidelity.solve.tier}, render tier {base.fidelity.render.tier})")
    print(f"  {len(done)} already stored in {out}, {len(todo)} to run on {workers} {executor} worker(s); frames stored: {spec.store_frames}")
    return 0


def sweep_plan(scene, variants, out: Path, loads, wanted, workers: int) -> int:
    """A sweep's variants (refused ones with the reason), the loads and metrics, what ``out`` holds."""
    from mlsim.sweep.run import stored_records

    stored = stored_records(out)
    print(f"sweep of {scene.name}: {len(variants)} variant(s) into {out}, {len(stored)} already stored; metrics {', '.join(wanted)}; "
          f"loads {', '.join(l.name for l in loads) if loads else 'scenes/press.toml, scenes/swipe.toml'}; {workers} worker(s)")
    for v in variants:
        state = "stored" if v.variant_id in stored else ("refused: " + v.reason if v.reason else "to run")
        print(f"  {v.variant_id}  {v.label:<40} {state}")
    return 0
