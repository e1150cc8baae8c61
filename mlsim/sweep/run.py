"""``mlsim sweep``: every variant of a scene through the loads, the calibration frame and a short
direction study, in parallel, resumable, into one folder (orchestration layer).

1. The variants (:mod:`mlsim.sweep.variants`); one the scene model refuses is stored at once with
   its reason.
2. The variants already stored in ``DIR/variants/`` are skipped: a rerun after a kill resumes.
3. Each variant runs on a worker (:func:`run_variant_job`): for each load (by default the press of
   ``scenes/press.toml`` and the swipe of ``scenes/swipe.toml``) the pipeline to the camera; the
   calibration frame and the DLLM's Hough circles; the direction study of
   ``scenes/direction_test.toml`` at a few angles. Every stage goes through the shared cache by its
   key, so variants share the stages they do not change (a material sweep meshes once). A load that
   fails (a solve the tier refuses, a mesh that fails) is recorded with its reason; the sweep goes on.
4. The driver stores each variant's record as it arrives (``DIR/variants/<id>.json``, atomically),
   with a progress bar (ETA), then writes the report (:mod:`mlsim.sweep.report`).

A load is a scene file whose ``[load]`` replaces the variant's load, with the way it must be stepped
(``fidelity.solve.substeps`` and ``rod_kinematics``, where the file gives them; the swipe needs both) unless
the variant's scene already steps finer or with richer rod kinematics (:meth:`Load.apply`).
"""

from __future__ import annotations

import json
import os
import time
import tomllib
import traceback
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from mlsim.errors import Problem, SceneError
from mlsim.io import atomic_bytes
from mlsim.sweep import metrics
from mlsim.sweep.variants import Variant, Vary

__all__ = ["Load", "read_load", "check_metrics", "escalated_scene", "beyond_its_estimate", "SCENES", "DEFAULT_LOADS", "DEFAULT_DIRECTION", "DEFAULT_ANGLES", "METRICS",
           "run_variant_job", "variant_record", "sweep", "stored_records"]

SCENES = Path(__file__).resolve().parents[2] / "scenes"
DEFAULT_LOADS = (SCENES / "press.toml", SCENES / "swipe.toml")
DEFAULT_DIRECTION = SCENES / "direction_test.toml"
DEFAULT_ANGLES = (0.0, 45.0, 90.0)
#: what a sweep can measure; each costs its own stages (``--metrics``)
METRICS = ("brightness", "tear", "separation", "direction")
#: the tier that answers a load the variant's fast tier refuses as beyond its model (rods near buckling in
#: the swipe over 10.5-12 mm heights and 3-4 mm diameters): the nonlinear tier with backward-Euler dynamics
#: (:func:`escalated_scene`): a quasi-static Newton has no unique answer where a rod buckles under the rim or
#: snaps back behind it (the 10.5 mm swipe, quasi-static, still halved its step 11 after 15 min)
ESCALATE_TO = "nonlinear"
#: a fast tier's answer is escalated too where its own per-rod force error estimate is above this
#: (:func:`beyond_its_estimate`): the Cosserat tier answers rods near and past buckling without refusing
#: them, and says how far off it is (the sweep's 12 x 3 mm swipe: 13608 %, no answer); the estimate
#: came within 2-4 x of the measured error where it holds (docs/stages/solve.md), so 20 % is a tier that
#: cannot meet 5 %, not a close call
ESCALATE_ESTIMATE = 0.2
#: the fields of ``fidelity.solve`` a load file carries along (how the load must be stepped); ``rod_coupling``
#: goes with ``rod_kinematics`` (where the load's kinematics are applied, its rods' coupling is too)
LOAD_SOLVE_FIELDS = ("substeps", "rod_kinematics", "rod_coupling")


@dataclass(frozen=True)
class Load:
    """A named load: the ``[load]`` section and the solve settings it needs (dicts, as in TOML)."""

    name: str
    load: dict
    solve: dict

    def apply(self, scene, outputs: tuple[str, ...]):
        """The scene under this load. The load's solve settings are what it needs at the least: a scene
        that steps finer (more ``substeps``) or with rod kinematics as rich (``rod_kinematics``, in the
        order of :data:`fem.rod_kinematics.ROD_KINEMATICS`) keeps its own, and its rods' coupling with them; a
        scene with poorer kinematics gets the load's and its ``rod_coupling`` (the swipe's held Cosserat rods)."""
        from fem.rod_kinematics import ROD_KINEMATICS

        own = scene.fidelity.solve
        values = {"load": self.load, "outputs": list(outputs)}
        richer = ("rod_kinematics" in self.solve and self.solve["rod_kinematics"] in ROD_KINEMATICS
                  and ROD_KINEMATICS.index(own.rod_kinematics) >= ROD_KINEMATICS.index(self.solve["rod_kinematics"]))
        for k, v in self.solve.items():
            if k == "substeps" and isinstance(v, int) and own.substeps >= v:
                continue
            if k in ("rod_kinematics", "rod_coupling") and richer:  # the scene's own rods, coupled as it says
                continue
            values[f"fidelity.solve.{k}"] = v  # (a value the scene cannot take is refused by with_values, naming the field)
        return scene.with_values(values)


def read_load(path: str | Path, flag: str = "--load") -> Load:
    """The load of a scene file: its ``[load]``, named by the file's stem. ``flag``: the option that
    named the file, for the error of a file that is missing, not TOML or has no ``[load]``."""
    path = Path(path)
    # the whole path in the message: the error shows the value cut at 60 characters, the file's name with it
    if not path.is_file():
        raise SceneError([Problem(flag, str(path), f"no such scene file (looked for {path.resolve()})")])
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except tomllib.TOMLDecodeError as exc:
        raise SceneError([Problem(flag, str(path), f"{path.resolve()} is not a TOML scene file: {exc}")]) from None
    if "load" not in data:
        raise SceneError([Problem(flag, str(path), "the file has no [load] section to apply to the variants")])
    solve = data.get("fidelity", {}).get("solve", {})
    return Load(path.stem, data["load"], {k: solve[k] for k in LOAD_SOLVE_FIELDS if k in solve})


def check_metrics(wanted) -> None:
    """Refuse a ``--metrics`` list with a name not in :data:`METRICS`, or none at all, before anything
    runs (a dry run would price the rest and a sweep would measure nothing)."""
    bad = [m for m in wanted if m not in METRICS]
    if bad:
        raise SceneError([Problem("--metrics", ",".join(bad), f"unknown metric; choose from: {', '.join(METRICS)}")])
    if not wanted:
        raise SceneError([Problem("--metrics", "", f"no metric given; choose from: {', '.join(METRICS)}")])


# ------------------------------------------------------------------------------------ the worker
def beyond_its_estimate(summary: dict, limit: float = ESCALATE_ESTIMATE) -> str | None:
    """Why a fast tier's episode is no answer by its own account (its ``geometric_error_estimate`` above
    ``limit``; inf is), or None: also where it made no estimate (None, or NaN: second-order rod kinematics
    have none, fem.quasistatic). Where the estimate does not hold (releases, rods dragged over near buckling) the
    answer is kept and the report says so: escalating those would send most swipes over 9-12 mm rods to the
    nonlinear tier, 8-21 min each. ``summary``: :meth:`fem.quasistatic.Episode.summary`."""
    est = summary.get("geometric_error_estimate")
    if summary.get("tier") == "nonlinear" or est is None or np.isnan(est) or est <= limit:
        return None
    releases = summary.get("geometric_error_releases") or []
    after = f"; bent rods let go in steps {list(releases)}" if len(releases) else ""
    said = f"{est:.0%}" if np.isfinite(est) else str(est)
    return (f"its own per-rod force error estimate is {said}, above {limit:.0%} "
            f"(mlsim.sweep.run.ESCALATE_ESTIMATE){after}")


def _reason(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return f"{type(exc).__name__}: {' '.join(t.strip() for t in text)[:600]}"


def _run(scene, cache_dir, outputs):
    from mlsim import pipeline

    return pipeline.run(scene, cache=pipeline.Cache(cache_dir), outputs=outputs, progress=False, log=lambda _m: None)


def _stage_record(res) -> dict:
    return {"actions": {s.stage.name: s.action for s in res.steps}, "seconds": {k: round(v, 3) for k, v in res.seconds.items()}}


def escalated_scene(scene, tier: str):
    """The scene as the escalation ``tier`` solves it. The nonlinear tier steps it with backward-Euler
    dynamics (the elastomer's inertia and loss factor; :mod:`fem.dynamics`) at the least substeps that
    resolve the rods' first bending mode (:func:`fem.finite_strain.dynamics_substeps`; the scene's own if
    finer): the rods that buckle under the probe's rim and snap back behind it have an answer, and the
    snap-back's stress history (hence its light) is followed. The load and contact are the scene's."""
    if tier != "nonlinear":
        return scene.with_values({"fidelity.solve.tier": tier})
    from fem.finite_strain import dynamics_substeps

    substeps = max(scene.fidelity.solve.substeps, dynamics_substeps(scene))  # of the scene's rods and camera, whatever its tier
    return scene.with_values({"fidelity.solve.tier": tier, "fidelity.solve.dynamics": "backward_euler", "fidelity.solve.substeps": substeps})


def _load_metrics(scene, load: Load, cache_dir, wanted, escalate_to: str | None = ESCALATE_TO) -> dict:
    """One load on one variant: brightness (camera) and tear risk (solve). A load the variant's fast
    tier refuses as beyond its model (:class:`mlsim.errors.OutOfRangeError`) is solved again by
    ``escalate_to`` (None: recorded as failed); one under which its rods collapse
    (:class:`mlsim.errors.RodCollapseError`) is recorded with the load they collapse at, not escalated."""
    from dllm.calibration import grey
    from mlsim.render import rod_disks_px
    from mlsim.render.optics import disk_masks

    from mlsim.errors import OutOfRangeError, RodCollapseError

    # the solve asked for by name: a cached camera result alone would leave it out of the plan
    outputs = ("solve", "camera") if "brightness" in wanted else ("solve",)
    s = load.apply(scene, outputs)
    escalated = None
    can_escalate = escalate_to is not None and s.fidelity.solve.tier != escalate_to
    try:
        res = _run(s, cache_dir, outputs)
        # an answer the tier itself says is no answer (a rod past collapse) is escalated as a refusal is
        why = beyond_its_estimate(res.results["solve"].summary())
    except RodCollapseError as exc:
        # the rods collapse under the load (held Cosserat rods past their clamped-guided load): the load they collapse at
        # is the variant's answer to it, a design figure; past it a dead load snaps through, which only the nonlinear
        # tier with dynamics follows, at hours a load (the 12 x 3 mm press: not escalated)
        return {"ok": False, "reason": _reason(exc), "collapse_force_n": exc.force_n, "collapse_step": exc.step,
                "solve_tier": s.fidelity.solve.tier, "escalated": None}
    except OutOfRangeError as exc:
        # a load past the fast tier's model (a rod near buckling, a contact point past small strain)
        if not can_escalate:
            raise
        why = _reason(exc)
    if why is not None and can_escalate:
        # the reference tier answers it, and the record says which tier did and why
        escalated = {"from_tier": s.fidelity.solve.tier, "reason": why}
        s = escalated_scene(s, escalate_to)
        escalated.update(dynamics=s.fidelity.solve.dynamics, substeps=s.fidelity.solve.substeps)
        res = _run(s, cache_dir, outputs)
    ep = res.results["solve"]
    out = {"ok": True, **_stage_record(res), "escalated": escalated}
    if "tear" in wanted:
        out.update(metrics.tear_risk(ep, s))
    out["peak_normal_force_n"] = float(np.max(ep.normal_force_n))
    summary = ep.summary()
    out["solve_tier"] = summary["tier"]
    out["solve_error_estimate"] = summary.get("geometric_error_estimate")
    out["solve_error_releases"] = summary.get("geometric_error_releases")  # Cosserat rods: where the estimate does not hold
    out["solve_error_bent"] = summary.get("geometric_error_bent")  # and their rods dragged over near buckling
    if "brightness" in wanted:
        cam = res.results["camera"]
        frames = np.stack([grey(f) for f in cam.frames]) if len(cam.frames) else np.zeros((0, 1, 1), np.uint8)
        centres, radius = rod_disks_px(s)
        masks = disk_masks(frames.shape[1], frames.shape[2], centres, radius)
        out.update(metrics.brightness(cam, frames, masks))
        force = out["peak_normal_force_n"]
        out["photons_per_newton"] = out["total_photons"] / force if force > 0 else None
        out["render_tier"] = s.fidelity.render.tier
    return out


def _separation(scene, cache_dir) -> dict:
    from dllm.calibration import CalibrationError, grey
    from dllm.episode import calibrate_scene
    from mlsim.render import rod_disks_px

    s = scene.with_values({"outputs": ["calibration"]})
    res = _run(s, cache_dir, ("calibration",))
    rgb = res.results["calibration"].rgb
    centres, radius = rod_disks_px(s)
    out = {"ok": True, **_stage_record(res), **metrics.separation(grey(rgb), centres, radius, s.sensor.rows, s.sensor.cols)}
    try:
        cal, _ = calibrate_scene(s, rgb)
    except CalibrationError as exc:
        out.update(hough_ok=False, hough_reason=str(exc).split(";")[0], hough_max_offset_px=None)
    else:
        offset = np.linalg.norm(cal.centres_px[:, None] - centres[None], axis=2).min(axis=1)
        out.update(hough_ok=True, hough_reason=None, hough_max_offset_px=float(offset.max()))
    return out


def _direction(scene, load: Load, angles, cache_dir) -> dict:
    from mlsim.studies.direction import direction_study, summary
    from mlsim import pipeline

    s = load.apply(scene, ("dllm",))
    t0 = time.perf_counter()
    rows = direction_study(s, angles, None, pipeline.Cache(cache_dir), progress=False, log=lambda _m: None)
    figures = summary(rows)
    return {"ok": True, "mean_abs_error_deg": figures["mean_abs_error_deg"], "angles_deg": [float(a) for a in angles],
            "errors_deg": [r.error_deg for r in rows], "without_events": figures["episodes_without_events"],
            "seconds": {"total": round(time.perf_counter() - t0, 3)}}


def _guarded(fn, *args) -> dict:
    """``fn(*args)``, or the reason it failed: a failing part never stops the variant or the sweep."""
    try:
        return fn(*args)
    except Exception as exc:  # noqa: BLE001 (a variant's failure is a result of the sweep, reported with its type)
        return {"ok": False, "reason": _reason(exc), "traceback": traceback.format_exc(limit=6)}


def run_variant_job(job: dict) -> dict:
    """One variant in a process of its own (:mod:`mlsim.sweep.isolated`; ``job["isolated"] = False``:
    in this one): its record, or, when that process is killed (out of memory, a signal), a record
    with the reason that a rerun retries."""
    if not job.get("isolated", True):
        return variant_record(job)
    from mlsim.sweep.isolated import run_isolated

    return run_isolated("mlsim.sweep.run:variant_record", job, label=f"sweep variant {job['variant_id']} {job['episode_id']}")


def variant_record(job: dict) -> dict:
    """One variant: ``job`` holds ``scene`` (a scene dict), ``loads`` and ``direction`` (Load dicts),
    ``angles``, ``metrics``, ``cache_dir``. Returns the variant's record (JSON-ready)."""
    from mlsim.scene import scene_from_dict

    t0 = time.perf_counter()
    scene = scene_from_dict(job["scene"], source=f"sweep variant {job['variant_id']}")
    wanted = set(job["metrics"])
    core = scene.material("core").young_modulus_pa.value
    record = {"loads": {}, "beam_strain_per_n": metrics.beam_strain_per_newton(scene.sensor.rod.height_mm, scene.sensor.rod.diameter_mm, core)}
    if wanted & {"brightness", "tear"}:
        for ld in job["loads"]:
            record["loads"][ld["name"]] = _guarded(_load_metrics, scene, Load(**ld), job["cache_dir"], wanted, job.get("escalate_to", ESCALATE_TO))
    if "separation" in wanted:
        record["separation"] = _guarded(_separation, scene, job["cache_dir"])
    if "direction" in wanted and job["direction"] is not None:
        record["direction"] = _guarded(_direction, scene, Load(**job["direction"]), job["angles"], job["cache_dir"])
    record["seconds"] = round(time.perf_counter() - t0, 3)
    return record


# ------------------------------------------------------------------------------------ the driver
def _record_path(out: Path, variant_id: str) -> Path:
    return out / "variants" / f"{variant_id}.json"


def stored_records(out_dir: str | Path) -> dict[str, dict]:
    """The variants' records stored in a sweep folder, by variant id."""
    folder = Path(out_dir) / "variants"
    return {p.stem: json.loads(p.read_text()) for p in sorted(folder.glob("v*.json"))} if folder.is_dir() else {}


def _store(out: Path, variant: Variant, record: dict, base_hash: str) -> None:
    full = {"variant_id": variant.variant_id, "index": variant.index, "label": variant.label, "values": variant.values,
            "base_scene_hash": base_hash, "scene_hash": variant.scene.content_hash() if variant.scene is not None else None,
            "buildable": variant.scene is not None, "reason": variant.reason, **record}
    path = _record_path(out, variant.variant_id)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_bytes(path, json.dumps(full, indent=1, default=_json_default).encode())


def _json_default(value):
    if isinstance(value, (np.floating, np.integer)):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return str(value)


def sweep(base, varies: list[Vary], out_dir: str | Path, *, mode: str = "grid", loads: list[Load] | None = None,
          direction: Load | None = None, angles=DEFAULT_ANGLES, wanted=METRICS, workers: int = 1, executor: str = "local",
          address: str | None = None, cache_dir: str | Path | None = None, progress: bool = True,
          log: Callable[[str], None] = print, limit: int | None = None, escalate_to: str | None = ESCALATE_TO) -> dict:
    """Run (or complete) a sweep into ``out_dir``; returns its summary and writes the report.

    ``escalate_to``: the tier that solves a load the variant's fast tier refuses as beyond its model
    (None: the refusal is recorded). ``limit``: stop after this many new variants (for tests; a rerun
    continues)."""
    from tqdm.auto import tqdm

    from mlsim import pipeline
    from mlsim.dataset.executors import map_unordered
    from mlsim.sweep.report import write_report
    from mlsim.sweep.variants import variants as make_variants

    check_metrics(wanted)  # before the folder is made
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    loads = [read_load(p) for p in DEFAULT_LOADS] if loads is None else loads
    if direction is None and "direction" in wanted:
        direction = read_load(DEFAULT_DIRECTION)
    cache = pipeline.Cache(cache_dir)
    vs = make_variants(base, varies, mode)
    base_hash = base.content_hash()
    meta = {"base_scene": base.model_dump(mode="json"), "base_scene_hash": base_hash, "mode": mode,
            "varies": [{"path": v.path, "values": list(v.values)} for v in varies], "loads": [vars(ld) for ld in loads],
            "direction": None if direction is None else vars(direction), "angles_deg": [float(a) for a in angles],
            "metrics": list(wanted), "versions": pipeline.package_versions()}
    meta_path = out / "sweep.json"
    if meta_path.is_file():
        old = json.loads(meta_path.read_text())
        same = {k: old.get(k) for k in ("base_scene_hash", "mode", "varies", "loads", "direction", "angles_deg", "metrics")}
        if same != {k: json.loads(json.dumps(meta[k])) for k in same}:
            raise SceneError([Problem("--out", str(out), "holds a different sweep (scene, --vary, loads or metrics differ); "
                                      "choose another folder or delete it")])
    atomic_bytes(meta_path, json.dumps(meta, indent=1).encode())
    done = stored_records(out)
    for v in vs:
        if v.scene is None and v.variant_id not in done:
            _store(out, v, {"loads": {}, "seconds": 0.0}, base_hash)
    done = {k: r for k, r in stored_records(out).items() if not r.get("retry")}  # a killed variant runs again
    todo = [v for v in vs if v.variant_id not in done]
    if limit is not None:
        todo = todo[: max(int(limit), 0)]
    refused = sum(v.scene is None for v in vs)
    log(f"[sweep] {len(vs)} variants ({refused} refused by the scene model), {len(vs) - len(todo) - refused} already stored, "
        f"{len(todo)} to run on {workers} {executor} worker(s)")
    common = {"loads": [vars(ld) for ld in loads], "direction": None if direction is None else vars(direction),
              "angles": [float(a) for a in angles], "metrics": list(wanted), "cache_dir": str(cache.root), "escalate_to": escalate_to}
    by_id = {v.variant_id: v for v in todo}
    jobs = ({"variant_id": v.variant_id, "episode_id": v.label, "scene": v.scene.model_dump(mode="json"), **common} for v in todo)
    threads = max(1, (os.cpu_count() or 1) // max(workers, 1))
    bar = tqdm(total=len(vs), initial=len(vs) - len(todo), unit="variant", desc="sweep", disable=None if progress else True, smoothing=0.0)
    t0 = time.perf_counter()
    try:
        for job, record in map_unordered(run_variant_job, jobs, executor=executor, workers=workers, address=address,
                                         threads_per_worker=threads):
            v = by_id[job["variant_id"]]
            _store(out, v, record, base_hash)
            failed = [f"{name}: {r['reason']}" for name, r in _parts(record) if not r.get("ok", True)]
            failed += [record["reason"]] if record.get("retry") else []
            log(f"[sweep] {v.label}: {record['seconds']:.0f} s" + (f"; failed {'; '.join(failed)}" if failed else ""))
            bar.update(1)
    finally:
        bar.close()
    wall = time.perf_counter() - t0
    records = stored_records(out)
    order = {v.variant_id: v.index for v in vs}
    records = [records[k] for k in sorted(records, key=lambda k: order.get(k, 1 << 30)) if k in order]
    killed = [r["variant_id"] for r in records if r.get("retry")]
    summary = {"variants": len(vs), "stored": len(records), "complete": len(records) == len(vs) and not killed, "killed": killed,
               "wall_s": round(wall, 2),
               "run_now": len(todo), "workers": workers, "executor": executor}
    files = write_report(out, records, varies, meta, summary)
    summary["files"] = [str(f) for f in files]
    atomic_bytes(out / "summary.json", json.dumps(summary, indent=1).encode())
    log(f"[sweep] {len(todo)} variants in {wall:.0f} s; report in {out}")
    return summary


def _parts(record: dict):
    for name, r in record.get("loads", {}).items():
        yield name, r
    for name in ("separation", "direction"):
        if name in record:
            yield name, record[name]
