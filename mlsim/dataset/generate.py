"""Generate an interaction dataset: every episode of a spec through the pipeline, in parallel.

``mlsim dataset SPEC --out DIR --workers N [--executor ray --address HOST:PORT]``:

1. the plan: the spec's people (:func:`mlsim.interactions.draw_people`) and, for each action, its
   samples spread evenly over the people, each drawn from its own seeded stream, with its own camera
   noise seed. Everything follows from ``spec.seed``; an episode's draws depend only on (seed,
   action, sample index), so a larger dataset extends a smaller one of the same seed;
2. the episodes already stored in ``DIR`` are skipped (a rerun after a kill resumes);
3. the driver runs the sensor's precomputes once (mesh, reduced model, transport matrix, calibration
   frame; cached on disk, and listed there for the next run of the same sensor and interaction, which
   then skips this step while they are all still cached), then the workers run the episodes (:func:`run_episode_job`: the pipeline
   to the DLLM at the base scene's tiers, single-threaded; with the spec's ``chain = "batched"``,
   :func:`run_batch_job`: ``batch_episodes`` episodes solved one by one, then the chain after the
   solve for all of them at once on the spec's ``device``, :mod:`mlsim.dataset.batched`), and the
   driver writes each episode as it arrives, atomically (:mod:`mlsim.dataset.store`), with a
   progress bar (rate and ETA);
4. an episode that raises (a refused load, a ``SolverError``) or whose worker process is killed (the
   kernel's out-of-memory killer, any signal) is recorded in ``DIR/failures.json`` with its reason
   (:func:`mlsim.dataset.store.write_failures`) and the others go on; nothing of it is stored, so
   a rerun of the same command retries only the failed episodes and leaves the stored ones as they are;
5. ``DIR/dataset.json`` (counts, timings, versions, the failures), once complete the per-frame features and labels
   as Parquet (``DIR/dllm_frames.parquet``, :mod:`mlsim.dataset.parquet`) and the dataset card ``DIR/README.md``.

Same spec and seed, same features: the workers run one thread each (BLAS reductions keep their
order) and every random draw is seeded. The mesh is part of the sensor's cache: fTetWild does not
give the same mesh twice, so two machines with separately built meshes give datasets that differ
in the last bits; ``dataset.json`` records the mesh's cache key and the card says so.
"""

from __future__ import annotations

import functools
import hashlib
import json
import time
from pathlib import Path
from typing import Callable

import numpy as np

from mlsim.dataset import store
from mlsim.dataset.randomize import RANDOMIZE_STREAM, draw_randomized
from mlsim.dataset.spec import DatasetSpec
from mlsim.io import atomic_bytes
from mlsim.interactions import ACTION_TO_4, ACTIONS, InteractionSpec, Sample, draw_people, draw_sample, frame_labels, interaction_scene
from mlsim.scene import Scene, scene_from_dict

__all__ = ["plan_episodes", "run_episode_job", "run_batch_job", "episode_record", "generate", "failures_line", "CACHE_KEEP"]

#: The stages a dataset keeps in the cache: the sensor's, shared by every episode (each episode's
#: own intermediate results are not written to disk).
CACHE_KEEP = ("geometry", "mesh", "calibration", "reduced_model", "transport_matrix", "direct_raster", "ml_patches", "ml_patches_in_mesh",
              "ml_channel_factors")


def _seed_int(*parts: int) -> int:
    """A 63-bit seed from integer parts (numpy's SeedSequence mixing)."""
    a, b = np.random.SeedSequence([int(p) for p in parts]).generate_state(2, dtype=np.uint32)
    return int((int(a) << 31) ^ int(b)) & (2**63 - 1)


def plan_episodes(spec: DatasetSpec) -> tuple[list[dict], list[dict]]:
    """(episodes, people): one small dict per episode (its id, action, label, person, sample,
    noise seed) and the people's typical values. Pure: the same spec gives the same plan."""
    people = draw_people(spec.people, spec.interaction, np.random.default_rng([spec.seed, 1]))
    width = max(5, len(str(spec.samples_per_action - 1)))
    jobs = []
    for action in spec.actions:
        a = ACTIONS.index(action)
        for k in range(spec.samples_per_action):
            person = people[k % spec.people]
            sample = draw_sample(action, person, spec.interaction, np.random.default_rng([spec.seed, 2, a, k]))
            jobs.append({"episode_id": f"{action}_{k:0{width}d}", "action": action, "label": a, "label_4": ACTION_TO_4[action],
                         "person": person.index, "sample_index": k, "sample": sample.as_dict(), "noise_seed": _seed_int(spec.seed, 3, a, k)})
            if spec.randomize:  # the sensor's spread (mlsim.dataset.randomize), from its own stream
                jobs[-1]["randomized"] = draw_randomized(spec.randomize, np.random.default_rng([spec.seed, RANDOMIZE_STREAM, a, k]))
    return jobs, [vars(p) for p in people]


# ------------------------------------------------------------------------------------ the worker
@functools.lru_cache(maxsize=1)  # a worker runs one dataset: its base scene is validated once
def _base_scene(canonical_json: str) -> Scene:
    return scene_from_dict(json.loads(canonical_json), source="dataset base scene")


def _episode(job: dict) -> tuple[Scene, Sample, InteractionSpec]:
    sample, spec = Sample(**job["sample"]), InteractionSpec(**job["interaction"])
    base = _base_scene(json.dumps(job["base_scene"], sort_keys=True))
    scene = interaction_scene(base, sample, spec, noise_seed=job["noise_seed"], name=job["episode_id"])
    return (scene.with_values(job["randomized"]) if job.get("randomized") else scene), sample, spec


def episode_scene(job: dict) -> Scene:
    """The scene of one planned episode (``job`` from :func:`plan_episodes` plus the base scene,
    the interaction spec)."""
    return _episode(job)[0]


def run_episode_job(job: dict) -> dict:
    """One episode through the pipeline to the DLLM; returns {"arrays": ..., "attrs": ...} for the store.

    ``job``: a plan entry plus ``base_scene`` (a scene dict), ``interaction`` (an InteractionSpec dict),
    ``cache_dir`` and ``store_frames``."""
    from mlsim import pipeline

    scene, sample, spec = _episode(job)
    t0 = time.perf_counter()
    # the sensor's stages stay in memory after the worker's first episode (the mesh was read anew each time)
    cache = pipeline.Cache(job["cache_dir"], keep=CACHE_KEEP, in_memory=CACHE_KEEP)
    result = pipeline.run(scene, cache=cache, outputs=("dllm",), progress=False, log=lambda _m: None)
    seconds = time.perf_counter() - t0
    ep, dllm, camera, render = (result.results[k] for k in ("solve", "dllm", "camera", "render"))
    return episode_record(job, scene, sample, spec, ep, dllm.features, dllm.events, dllm.rod_of_taxel, camera.rod_signal_e, camera.frames,
                          max(render.info.get("sheet_displacement_mm", [0.0])), seconds, result.seconds)


def episode_record(job: dict, scene: Scene, sample: Sample, spec: InteractionSpec, ep, features_deg, events, rod_of_taxel, rod_signal_e,
                   frames, max_sheet_displacement_mm: float, seconds: float, stage_seconds: dict) -> dict:
    """The store's {"arrays", "attrs"} of one episode from its solve (``ep``, a :class:`fem.episode.Episode`)
    and the chain after it: the DLLM's features (F, N, 3) (omega in degrees) and events (F,), the
    taxels' rods (N,), the rods' noiseless signal (F, R) e-, the camera frames (F, H, W, 3) uint8
    (stored when the job asks), the sheet's largest displacement (mm) and the timings (s)."""
    from dllm.features import with_omega_rad
    from fem.geometry import RodArray

    k = ep.frame_step
    features = with_omega_rad(features_deg)  # the detector gives degrees in [0, 360); the dataset stores rad in (-pi, pi]
    rods = RodArray.from_sensor(scene.sensor)
    rod_force = ep.rod_force_n[k][:, : rods.n_rods].astype(np.float32)
    lever = np.zeros((rods.n_rods, 3))
    lever[:, :2] = rods.centres_m[:, :2] - rods.centres_m[:, :2].mean(axis=0)
    moment = np.cross(lever[None], rod_force.astype(np.float64)).sum(axis=1)
    arrays = {
        "dllm_features": features,
        "dllm_event": np.asarray(events, dtype=bool),
        "frame_label": frame_labels(sample, spec, ep.n_frames, scene.camera.fps, job["label"]),
        "rod_force_n": rod_force,
        "wrench": np.concatenate([rod_force.sum(axis=1), moment], axis=1).astype(np.float32),
        "screw_pose": ep.pose[k].astype(np.float32),
        "rod_signal_e": np.asarray(rod_signal_e).astype(np.float32),
    }
    if job["store_frames"]:
        arrays["frames"] = frames
    attrs = {key: job[key] for key in ("episode_id", "action", "label", "label_4", "person", "sample_index", "noise_seed", "sample", "randomized")
             if key in job}
    attrs.update(n_frames=int(ep.n_frames), fps=float(scene.camera.fps), rod_of_taxel=[int(v) for v in rod_of_taxel],
                 max_sheet_displacement_mm=float(max_sheet_displacement_mm),
                 peak_normal_force_n=float(ep.normal_force_n.max()), seconds=round(seconds, 4),
                 stage_seconds={s: round(v, 4) for s, v in stage_seconds.items()})
    return {"arrays": arrays, "attrs": attrs}


#: The batched chain of a worker, per (base scene, device, cache): its parts are the sensor's
#: (patches, matrices, calibration), made once (mlsim.dataset.batched)
_CHAINS: dict = {}


def run_batch_job(batch: dict) -> dict:
    """A batch of episodes of one sensor: each one's solve through the pipeline, then the chain after
    it for all of them at once (:class:`mlsim.dataset.batched.BatchedChain` on ``batch["device"]``).

    ``batch``: {"jobs": [jobs as :func:`run_episode_job` takes them], "device": "cpu" | "cuda"}.
    Returns {"results": {episode id: {"arrays", "attrs"}}, "failures": {episode id: {"error_type",
    "message"}}}: an episode whose solve raises is a failure of its own, the others go on; one that
    raises in the chain fails the batch (the driver records each of its episodes)."""
    from mlsim import pipeline
    from mlsim.dataset.batched import BatchedChain
    from mlsim.render import deformed_vertices
    from mlsim.render.kernels import largest_displacement
    from mlsim.render.optics import ml_channel_factors
    from mlsim.render.output import rod_masks, rod_signal_of

    jobs, device = batch["jobs"], batch["device"]
    cache = pipeline.Cache(jobs[0]["cache_dir"], keep=CACHE_KEEP, in_memory=CACHE_KEEP)
    solved, failures = [], {}
    for job in jobs:
        scene, sample, spec = _episode(job)
        t0 = time.perf_counter()
        try:
            res = pipeline.run(scene, cache=cache, outputs=("solve",), progress=False, log=lambda _m: None)
        except Exception as exc:  # this episode's load refused: recorded, the batch goes on
            failures[job["episode_id"]] = {"error_type": type(exc).__name__, "message": str(exc)[:2000]}
            continue
        solved.append((job, scene, sample, spec, res.results["solve"], time.perf_counter() - t0))
    out = {"results": {}, "failures": failures}
    if not solved:
        return out
    scene0 = solved[0][1]
    key = (json.dumps(jobs[0]["base_scene"], sort_keys=True), device, str(cache.root))
    if key not in _CHAINS:
        _CHAINS.clear()  # a worker runs one dataset
        _CHAINS[key] = BatchedChain.from_scene(scene0, solved[0][4], cache, device=device)
    chain = _CHAINS[key]
    eps = [s[4] for s in solved]
    moved_mm = []

    def direct(b, radiance):
        # the vertices once per episode: the direct light's and the record's sheet displacement
        vertices = deformed_vertices(eps[b], chain.vertices_m, chain.located)
        moved_mm.append(max(round(float(d) * 1e3, 4) for d in largest_displacement(vertices, np.asarray(chain.vertices_m, dtype=float))))
        return chain.direct(radiance, vertices)

    tet = chain.tet.cpu().numpy()
    t0 = time.perf_counter()
    chain_out = chain.run_arrays([ep.stress[:, :, tet] for ep in eps], [ep.t_s for ep in eps], [s[0]["noise_seed"] for s in solved], direct,
                                 keep_radiance=True, keep_frames=bool(jobs[0]["store_frames"]), noise=bool(scene0.camera.noise),
                                 n_frames=[ep.n_frames for ep in eps])
    chain_s = time.perf_counter() - t0
    k = ml_channel_factors(scene0).astype(np.float32)
    masks, per_radiance_e = rod_masks(scene0, chain.height_px, chain.width_px)
    frames_total = sum(ep.n_frames for ep in eps)
    sec = chain_out.seconds
    parts = {"emission": sec["emission"], "render": sec["raster"] + sec["bounces"], "camera": sec["camera"], "dllm": sec["dllm"]}
    for b, (job, scene, sample, spec, ep, solve_s) in enumerate(solved):
        share = ep.n_frames / frames_total  # the batch's parts split over its episodes by their frames
        stage_s = {"solve": solve_s} | {name: v * share for name, v in parts.items()}
        out["results"][job["episode_id"]] = episode_record(
            job, scene, sample, spec, ep, chain_out.features[b], chain_out.events[b], chain.rod_of_taxel,
            rod_signal_of(chain_out.radiance[b], masks, per_radiance_e, k), chain_out.frames[b] if chain_out.frames else None, moved_mm[b],
            solve_s + chain_s * share, stage_s)
    return out


# ------------------------------------------------------------------------------------ the driver
#: Episodes the driver tries to run the sensor's precomputes through before it leaves them to the workers.
_PRECOMPUTE_TRIES = 3


def failures_line(failures: dict[str, dict]) -> str:
    """``"2 episodes failed: push_00001 (SolverError: ...), pull_00000 (killed: SIGKILL)"`` (the first five)."""
    items = sorted(failures.items())
    named = ", ".join(f"{k} ({v['error_type'] if v['kind'] == 'killed' else v['error_type'] + ': ' + v['message'][:120]})"
                      for k, v in items[:5])
    more = f" and {len(items) - 5} more" if len(items) > 5 else ""
    return f"{len(items)} episode{'s' if len(items) != 1 else ''} failed: {named}{more}"


def _code_version() -> str:
    """SHA-256 of the simulator's source (mlsim, fem, dllm): a cached precompute's key holds its own code
    version, which the list of an earlier run cannot know (fem.stages' reduced model: "version" in its payload)."""
    root = Path(__file__).resolve().parents[2]
    digest = hashlib.sha256()
    for package in ("mlsim", "fem", "dllm"):
        for path in sorted((root / package).rglob("*.py")):
            digest.update(str(path.relative_to(root)).encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def _precomputes_path(cache, base: Scene, spec: DatasetSpec) -> Path:
    """Where the driver lists the sensor's cached results its episode took (per base scene, interaction and
    code: after a change of the code the list names the old precomputes, which are still in the cache, and the
    driver skipped its episode, so that every worker built the new ones itself)."""
    ident = json.dumps({"base": base.content_hash(), "interaction": spec.interaction.model_dump(mode="json"), "keep": CACHE_KEEP,
                        "code": _code_version()}, sort_keys=True)
    return Path(cache.root) / "dataset_precomputes" / f"{hashlib.sha256(ident.encode()).hexdigest()}.json"


def _list_precomputes(cache, base: Scene, spec: DatasetSpec) -> None:
    """After the driver's episode: the (stage, key) of each kept result it used, for the next run."""
    import os
    import tempfile

    entries = sorted([s, k] for s, k in cache.used if s in CACHE_KEEP)
    path = _precomputes_path(cache, base, spec)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)  # two drivers on one cache may both write it
    with os.fdopen(fd, "wb") as f:
        f.write(json.dumps(entries).encode())
    os.replace(tmp, path)


def _precomputes_listed(cache, base: Scene, spec: DatasetSpec) -> list | None:
    """The listed results, if a list exists and every one of them is still in the cache; else None."""
    path = _precomputes_path(cache, base, spec)
    try:
        entries = json.loads(path.read_text())
    except (OSError, ValueError):
        return None
    return entries if entries and all(cache.has(s, k) for s, k in entries) else None


def _machine() -> str:
    """The driver's hardware in words (the dataset card's throughput is of it and its workers)."""
    import os
    import platform

    return f"{platform.machine()} {platform.processor() or platform.system()}, {os.cpu_count()} CPUs, {platform.system()} {platform.release()}"


def generate(spec: DatasetSpec, base: Scene, out_dir: str | Path, *, workers: int = 1, executor: str = "local", address: str | None = None,
             cache_dir: str | Path | None = None, progress: bool = True, log: Callable[[str], None] = print,
             limit: int | None = None) -> dict:
    """Generate (or complete) the dataset of ``spec`` in ``out_dir``; returns the run's summary.

    ``base``: the spec's base scene; its rods are the spec's (:func:`mlsim.dataset.spec.with_the_specs_rods`).
    ``limit``: stop after this many new episodes (for tests and trials; a rerun continues)."""
    from tqdm.auto import tqdm

    from mlsim import pipeline
    from mlsim.dataset.executors import map_unordered
    from mlsim.dataset.failures import JobFailed
    from mlsim.dataset.spec import with_the_specs_rods

    out = Path(out_dir)
    base = with_the_specs_rods(spec, base)  # (a base from load_dataset_spec has them already)
    # the chain after the solve: its device resolved first, so that a "cuda" without one fails before anything is written
    device, why = "cpu", "chain = per_episode"
    if spec.chain == "batched":
        from mlsim.dataset.batched import resolve_device

        device, why = resolve_device(spec.device)
    jobs, people = plan_episodes(spec)
    cache = pipeline.Cache(cache_dir, keep=CACHE_KEEP)
    attrs = {"spec": spec.model_dump(mode="json"), "base_scene": base.model_dump(mode="json"), "base_scene_hash": base.content_hash(),
             "people": people, "n_episodes": len(jobs), "actions": list(spec.actions), "class_names": list(ACTIONS),
             "versions": pipeline.package_versions(), "mesh_key": pipeline.stage_key(base, "mesh"),
             # each stage's code version: a resumed dataset refuses another (mlsim.dataset.store.create_or_open)
             "stage_versions": {name: st.version for name, st in pipeline.stages_of(base).items()}}
    store.create_or_open(out, attrs, spec.content_hash())
    done = store.complete_episodes(out)
    todo = [j for j in jobs if j["episode_id"] not in done]
    if limit is not None:
        todo = todo[: max(int(limit), 0)]
    earlier_failures = store.read_failures(out)
    retried = sum(j["episode_id"] in earlier_failures for j in todo)
    log(f"[dataset] {spec.name}: {len(jobs)} episodes, {len(done)} already stored, {len(todo)} to run"
        + (f" ({retried} that failed before)" if retried else "") + f" on {workers} {executor} worker(s)")
    common = {"base_scene": base.model_dump(mode="json"), "interaction": spec.interaction.model_dump(mode="json"),
              "cache_dir": str(cache.root), "store_frames": spec.store_frames}
    # on the CPU the batched chain runs slower than the per-episode one (docs/uses/datasets.md): the log says so
    slower = "; on the CPU it is slower than chain = per_episode" if device == "cpu" else ""
    log(f"[dataset] chain: batched, {spec.batch_episodes} episodes per batch, on {device} ({why}){slower}" if spec.chain == "batched" else
        "[dataset] chain: per_episode on the CPU (chain = per_episode, the default and the reference)")
    t_start = time.perf_counter()
    precompute_s = 0.0
    t0 = time.perf_counter()
    # the sensor's precomputes once, here, so the workers load them instead of each building them;
    # through an episode, which may itself fail (its worker then records why): the next one is tried.
    # Not again when an earlier run of this sensor and interaction listed what its episode took from
    # the cache and all of it is still there: a resume or a rerun after failures ran a whole episode
    # in the driver for nothing (in a fresh process ~10 s: the imports and the per-mesh set-up)
    listed = _precomputes_listed(cache, base, spec) if todo and not spec.randomize else None
    if listed:
        log(f"[dataset] the sensor's precomputes are in the cache ({len(listed)} results an earlier run listed): no driver episode")
        todo_warm = []
    else:
        todo_warm = todo[:_PRECOMPUTE_TRIES]
    for job in todo_warm:
        try:
            pipeline.run(episode_scene(job | common), cache=cache, outputs=("dllm",), progress=False,
                         log=lambda m: log(m) if "precomput" in m or "tracing" in m else None)
            if not spec.randomize:  # a randomised sensor's precomputes are the episode's own
                _list_precomputes(cache, base, spec)
            break
        except Exception as exc:
            log(f"[dataset] precomputing through {job['episode_id']} failed ({type(exc).__name__}: {exc}); trying the next episode")
    precompute_s = time.perf_counter() - t0 if todo else 0.0
    t_run = time.perf_counter()
    bar = tqdm(total=len(jobs), initial=len(done), unit="episode", desc=f"dataset {spec.name}", disable=None if progress else True,
               smoothing=0.05)
    n_new = n_frames = 0
    worker_seconds = []
    attempted = {j["episode_id"] for j in todo}
    # the failures of earlier runs that this run does not retry (a --limit) stay recorded
    failures = {k: v for k, v in earlier_failures.items() if k not in attempted}

    def record_failure(episode_id: str, kind: str, error_type: str, message: str, reason: str) -> None:
        failures[episode_id] = {"kind": kind, "error_type": error_type, "message": message[:2000]}
        log(f"[dataset] episode {episode_id} failed: {reason[:300]}")
        bar.update(1)

    def store_result(episode_id: str, result: dict) -> None:
        nonlocal n_new, n_frames
        store.write_episode(out, episode_id, result["arrays"], result["attrs"])
        worker_seconds.append(result["attrs"]["seconds"])
        n_new += 1
        n_frames += int(result["attrs"]["n_frames"])
        bar.update(1)

    try:
        if spec.chain == "batched":
            size = spec.batch_episodes
            # "episode_id": how the executor names a failed item in its messages (the batch's first and last)
            batches = ({"episode_id": f"{todo[i]['episode_id']}..{todo[min(i + size, len(todo)) - 1]['episode_id']}", "device": device,
                        "jobs": [j | common for j in todo[i: i + size]]} for i in range(0, len(todo), size))
            for batch, result in map_unordered(run_batch_job, batches, executor=executor, workers=workers, address=address,
                                               on_failure="record"):
                if isinstance(result, JobFailed):  # the chain raised, or the worker died: every episode of the batch
                    for job in batch["jobs"]:
                        record_failure(job["episode_id"], result.kind, result.error_type, result.message,
                                       f"(its batch {batch['episode_id']}) {result.reason}")
                    continue
                for episode_id, f in result["failures"].items():
                    record_failure(episode_id, "error", f["error_type"], f["message"], f"{f['error_type']}: {f['message']}")
                for episode_id, r in result["results"].items():
                    store_result(episode_id, r)
        else:
            for job, result in map_unordered(run_episode_job, (j | common for j in todo), executor=executor, workers=workers, address=address,
                                             on_failure="record"):
                if isinstance(result, JobFailed):
                    record_failure(job["episode_id"], result.kind, result.error_type, result.message, result.reason)
                else:
                    store_result(job["episode_id"], result)
    finally:
        bar.close()
        failures = {k: v for k, v in failures.items() if k not in store.complete_episodes(out)}
        store.write_failures(out, failures)  # also after a Ctrl-C: what failed so far stays recorded
    wall = time.perf_counter() - t_run
    stored = store.complete_episodes(out)
    summary = {
        "name": spec.name, "out": str(out), "episodes_planned": len(jobs), "episodes_stored": len(stored), "episodes_run_now": n_new,
        "complete": len(stored) == len(jobs), "workers": workers, "executor": executor, "chain": spec.chain, "device": device,
        "precompute_s": round(precompute_s, 2), "episodes_wall_s": round(wall, 2),
        "episodes_per_s": round(n_new / wall, 3) if wall > 0 and n_new else None,
        "frames_per_s": round(n_frames / wall, 1) if wall > 0 and n_new else None, "machine": _machine(),
        "worker_s_per_episode_median": round(float(np.median(worker_seconds)), 3) if worker_seconds else None,
        "total_wall_s": round(time.perf_counter() - t_start, 2), "spec_hash": spec.content_hash(), "mesh_key": attrs["mesh_key"],
        "versions": attrs["versions"], "episodes_failed": len(failures),
        "failures": failures,  # episode id -> {"kind": "error" | "killed", "error_type", "message"}; a rerun retries them
    }
    atomic_bytes(out / "dataset.json", json.dumps(summary, indent=2).encode())
    if summary["complete"] or failures:
        from mlsim.dataset.card import write_card
        from mlsim.dataset.parquet import export_parquet

        if summary["complete"]:
            export_parquet(out)  # the per-frame table for tools that read Parquet (issue 41)
        write_card(out, spec, base, summary)  # with failures: the card says which episodes are missing and why
    log(f"[dataset] {n_new} episodes in {wall:.1f} s ({summary['episodes_per_s']} episodes/s); {len(stored)}/{len(jobs)} stored in {out}")
    if failures:
        log(f"[dataset] {failures_line(failures)}; listed in {out / store.FAILURES_NAME}; rerun the same command to retry only them")
    return summary

