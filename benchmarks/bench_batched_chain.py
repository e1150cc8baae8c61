"""The chain after the solve, batched over episodes (mlsim.dataset.batched) against the per-episode chain.

    .venv/bin/python benchmarks/bench_batched_chain.py cpu [--spec scenes/interactions/paper.toml] [--episodes 4] [--rounds 3]
    .venv/bin/python benchmarks/bench_batched_chain.py export --out DIR [--episodes 2]
    python3 benchmarks/bench_batched_chain.py gpu --inputs DIR --out OUT [--episodes 1000] [--batch 50] [--direct host|resident]
        # needs torch, numpy, scipy and opencv only
    .venv/bin/python benchmarks/bench_batched_chain.py compare --inputs DIR --gpu OUT

``cpu``: the spec's first episodes solved (cached), then, in alternating rounds, the per-episode
chain (each stage's own ``run`` after the solve: emission, render, camera, DLLM, the way
``bench_episode_stages.py`` times a stage alone) and the batched chain on the same episodes
(``BatchedChain.run``, device cpu, one batch). Prints medians of frames per second over the
rounds and the batched chain's seconds per part. Both sides on one thread per library, as a
dataset worker runs (``mlsim.dataset.executors``).

``export``: what a GPU machine without the project's dependencies needs (no pydantic, Mitsuba,
numba there): the sensor's arrays (bounces' matrix, patch areas, camera constants, the DLLM's
taxels) and, per exported episode, its stress at the emitting patches' tets, step times and the
direct light of its frames, rasterised here by the numba rasteriser on the batched chain's
radiance (the part of the render that stays on the host). About 16 MB per episode and 21 MB
for the matrix on the screw sensor.

``gpu``: the batched chain on ``--device`` (cuda) for ``--episodes`` episodes, the exported ones
repeated with their own noise seeds, ``--batch`` at a time, after one untimed batch; the direct
light of each batch copied from the host (timed). Writes ``batched_chain_gpu.json`` (frames per
second, seconds per part, the device, agreement of the device with the same torch functions on
that machine's CPU) and ``gpu_outputs.npz`` (the exported episodes' radiance images and
noiseless frames, events and features of the first episodes) under ``--out``.

``compare``: here, the per-episode chain of this checkout (the stages' own ``run``, numpy and
numba) on the exported episodes, against the GPU's outputs: radiance and noiseless frames per
pixel, and the noisy frames and DLLM features in distribution.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import time
from pathlib import Path

if __name__ == "__main__" and sys.argv[1:2] != ["gpu"]:
    # a dataset worker's threads (mlsim.dataset.executors), before numpy and numba load: one per
    # library. On this shared machine torch's two OpenMP threads cost about 8 ms per element-wise op
    # on a frame (their wake-ups under the CPU quota), against 0.2 ms on one.
    for _name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS", "NUMBA_NUM_THREADS"):
        os.environ[_name] = "1"

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


# ------------------------------------------------------------------------------------- episodes
def _episodes(spec_path: str, n: int):
    """[(scene, pipeline result to the DLLM)] of the spec's first n episodes (the solve cached)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import bench_episode_stages as b

    from mlsim import pipeline
    from mlsim.dataset import generate as gen

    out = []
    for job in b._jobs(spec_path, n):
        scene = gen.episode_scene(job)
        cache = pipeline.Cache(job["cache_dir"], keep=gen.CACHE_KEEP, in_memory=gen.CACHE_KEEP)
        out.append((scene, pipeline.run(scene, cache=cache, outputs=("dllm",), progress=False, log=lambda _m: None), cache))
    return out


def _per_episode_chain(scene, res, cache):
    """The stages after the solve, one episode, each stage's own run (no plan, no cache look-up)."""
    from mlsim import pipeline

    ctx = pipeline.RunContext(scene, cache, None, False, lambda _m: None)
    results = dict(res.results)
    for step in res.steps:
        st = step.stage
        if st.name in ("emission", "render", "camera", "dllm"):
            results[st.name] = st.run(scene, {k: results[k] for k in st.needs}, ctx)
    return results


def cpu(args) -> int:
    import torch

    from mlsim.dataset.batched import BatchedChain

    torch.set_num_threads(1)

    eps = _episodes(args.spec, args.episodes)
    scene0, res0, cache0 = eps[0]
    chain = BatchedChain.from_scene(scene0, res0.results["solve"], cache0)
    solved = [r.results["solve"] for _, r, _ in eps]
    seeds = [int(s.noise_seed or 0) for s, _, _ in eps]
    frames = sum(e.n_frames for e in solved)
    _per_episode_chain(*eps[0])  # the memos and JIT caches, untimed
    chain.run(solved[:1], seeds[:1])
    per, bat, parts = [], [], []
    for rnd in range(args.rounds):
        for side in (("per", "bat") if rnd % 2 == 0 else ("bat", "per")):
            t0 = time.perf_counter()
            if side == "per":
                for e in eps:
                    _per_episode_chain(*e)
                per.append(frames / (time.perf_counter() - t0))
            else:
                out = chain.run(solved, seeds)
                bat.append(frames / (time.perf_counter() - t0))
                parts.append(out.seconds)
    print(f"{platform.machine()}, {os.cpu_count()} CPUs (shared with other work: timings noisy), torch {torch.__version__} "
          f"on {torch.get_num_threads()} threads, load average {os.getloadavg()[0]:.1f}")
    print(f"{len(eps)} episodes of {Path(args.spec).name}, {frames} frames (+ {chain.n_idle} idle frames each for the DLLM), {args.rounds} rounds")
    print(f"per-episode chain (emission, render, camera, DLLM stages): median {np.median(per):.1f} frames/s  {np.round(per, 1).tolist()}")
    print(f"batched chain, device cpu, one batch:                      median {np.median(bat):.1f} frames/s  {np.round(bat, 1).tolist()}")
    med = {k: float(np.median([p[k] for p in parts])) for k in parts[0]}
    print("batched chain, ms per frame by part: " + ", ".join(f"{k} {1e3 * v / frames:.2f}" for k, v in med.items()))
    return 0


# --------------------------------------------------------------------------------------- export
def export(args) -> int:
    from mlsim.dataset.batched import BatchedChain
    from mlsim.render import deformed_vertices

    eps = _episodes(args.spec, args.episodes)
    scene0, res0, cache0 = eps[0]
    chain = BatchedChain.from_scene(scene0, res0.results["solve"], cache0)
    tet = chain.tet.numpy()
    used, local = np.unique(tet, return_inverse=True)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    T = chain.T.to_sparse_csr()
    c = chain.camera
    sensor = dict(indptr=T.crow_indices().numpy().astype(np.int32), indices=T.col_indices().numpy().astype(np.int32),
                  data=T.values().numpy(), shape=np.array([T.shape[0], T.shape[1]]), hw=np.array([chain.height_px, chain.width_px]),
                  tet_local=local.astype(np.int64), area_m2=chain.area.numpy(), k_ml=chain.k_ml.numpy(),
                  emission=np.array([chain.params.detrapping_per_pa, getattr(chain.params, "recovery_time_s", 1.0), chain.brightness,
                                     chain.scale, chain.fps, chain.exposure_s]), model=np.array(chain.model),
                  camera=np.array([c.electrons_per_radiance, c.dark_electrons, c.read_noise_e, c.full_well_e, c.gain_dn_per_e,
                                   c.black_level_dn, c.adc_bits, float(c.bayer)]),
                  taxel_pixels=chain.taxels.pixels, taxel_starts=chain.taxels.starts, taxel_x=chain.taxels.x, taxel_y=chain.taxels.y,
                  taxel_centres=chain.taxels.centres_px, dllm=np.array([chain.dllm_params.alpha, chain.dllm_params.beta,
                                                                        chain.dllm_params.init_frames, chain.dllm_params.fps,
                                                                        chain.dllm_params.adapt_s, chain.dllm_params.recover_s]))
    if c.relative_illumination is not None or chain.ambient is not None:
        raise SystemExit("export: the GPU script carries no relative illumination map or ambient lamp; use a scene without them")
    np.savez(out / "sensor.npz", **sensor)
    for k, (scene, res, cache) in enumerate(eps):
        ep = res.results["solve"]
        stress = np.ascontiguousarray(ep.stress[:, :, used])
        rad32 = chain.radiance([stress[:, :, local]], [ep.t_s], [chain.windows(ep.n_frames)])[0].numpy()
        direct = chain.direct(rad32, deformed_vertices(ep, chain.vertices_m, chain.located))
        np.savez_compressed(out / f"episode{k}.npz", stress=stress, t_s=ep.t_s, n_frames=np.array(ep.n_frames), direct=direct,
                            noise_seed=np.array(int(scene.noise_seed or 0)))
    print(f"exported {len(eps)} episodes and the sensor to {out}: " + ", ".join(f"{p.name} {p.stat().st_size / 2**20:.1f} MiB"
                                                                            for p in sorted(out.iterdir())))
    return 0


# ------------------------------------------------------------------------------------------ gpu
def _chain_from_export(d: Path, device: str):
    """A BatchedChain from the exported arrays (no scene, no Mitsuba, no numba)."""
    from types import SimpleNamespace

    import scipy.sparse as sp

    from dllm.detector import DllmParams
    from dllm.features import TaxelIndex
    from mlsim.camera_batched import CameraConstants
    from mlsim.dataset.batched import BatchedChain

    s = np.load(d / "sensor.npz")
    H, W = (int(v) for v in s["hw"])
    m = sp.csr_matrix((s["data"], s["indices"], s["indptr"]), shape=tuple(int(v) for v in s["shape"]))
    k, tau, bright, scale, fps, exposure = (float(v) for v in s["emission"])
    model = str(s["model"])
    params = SimpleNamespace(detrapping_per_pa=k, recovery_time_s=tau)
    cam = s["camera"]
    camera = CameraConstants(*(float(v) for v in cam[:6]), int(cam[6]), bool(cam[7]))
    a, b, init, dfps, adapt, recover = s["dllm"]
    dp = DllmParams(float(a), float(b), int(init), float(dfps), float(adapt), float(recover))
    taxels = TaxelIndex(s["taxel_pixels"], s["taxel_starts"], s["taxel_x"], s["taxel_y"], s["taxel_centres"], (H, W))
    chain = BatchedChain(tet=np.arange(len(s["tet_local"])), area_m2=s["area_m2"], vertices_m=None, located=None, model=model,
                         params=params, brightness=bright, scale=scale, fps=fps, exposure_s=exposure,
                         transport=SimpleNamespace(matrix=m, height_px=H, width_px=W), raster=None, camera=camera, k_ml=s["k_ml"],
                         ambient=None, ambient_level=None, k_ambient=np.zeros(3, np.float32), taxels=taxels, dllm_params=dp,
                         n_idle=dp.init_frames, device=device)
    eps = []
    for p in sorted(d.glob("episode*.npz"), key=lambda p: int(p.stem[7:])):
        z = np.load(p)
        eps.append({"stress": z["stress"][:, :, s["tet_local"]], "t_s": z["t_s"], "n": int(z["n_frames"]), "direct": z["direct"],
                    "seed": int(z["noise_seed"])})
    return chain, eps


def _rel(a, b) -> float:
    return float(np.abs(np.asarray(a, np.float64) - np.asarray(b, np.float64)).max() / max(np.abs(np.asarray(b, np.float64)).max(), 1e-300))


def gpu(args) -> int:
    import torch

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    dev = torch.device(args.device)
    chain, eps = _chain_from_export(Path(args.inputs), args.device)
    K = len(eps)
    info = {"device": args.device, "torch": torch.__version__, "episodes": args.episodes, "batch": args.batch, "exported_episodes": K,
            "direct_light": args.direct,
            "frames_per_episode": [e["n"] for e in eps], "idle_frames_per_episode": chain.n_idle}
    if dev.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(dev)

    resident = [torch.as_tensor(e["direct"], device=dev) for e in eps] if args.direct == "resident" else None

    def batch(idx, noise=True, keep=False, ch=chain):
        e = [eps[i % K] for i in idx]
        if resident is not None and ch is chain:
            def direct(b, _rad):
                return resident[idx[b] % K]
        else:
            def direct(b, _rad):
                return e[b]["direct"]
        return ch.run_arrays([x["stress"] for x in e], [x["t_s"] for x in e], [x["seed"] + 7919 * (i // K) for x, i in zip(e, idx)],
                             direct, keep_radiance=keep, keep_frames=keep, noise=noise, n_frames=[x["n"] for x in e])

    t0 = time.perf_counter()
    batch(list(range(min(args.batch, args.episodes))))  # warm-up: kernels, cuSPARSE handles, the allocator's pool
    info["warmup_s"] = time.perf_counter() - t0
    parts: dict = {}
    frames = 0
    t0 = time.perf_counter()
    for i0 in range(0, args.episodes, args.batch):
        idx = list(range(i0, min(args.episodes, i0 + args.batch)))
        o = batch(idx)
        frames += sum(eps[i % K]["n"] for i in idx)
        for k, v in o.seconds.items():
            parts[k] = parts.get(k, 0.0) + v
    total = time.perf_counter() - t0
    info.update(frames=frames, seconds=total, frames_per_s=frames / total, seconds_by_part=parts,
                ms_per_frame_by_part={k: 1e3 * v / frames for k, v in parts.items()})
    if dev.type == "cuda":
        info["max_memory_gib"] = torch.cuda.max_memory_allocated(dev) / 2**30
    print(json.dumps({k: info[k] for k in ("direct_light", "batch", "frames", "seconds", "frames_per_s", "ms_per_frame_by_part")}), flush=True)
    name = "batched_chain_gpu.json" if args.direct == "host" else f"batched_chain_gpu_{args.direct}_b{args.batch}.json"
    if args.no_agreement:
        (out / name).write_text(json.dumps(info, indent=2))
        return 0
    # agreement with the same torch functions on this machine's CPU, on the exported episodes
    cpu_chain, _ = _chain_from_export(Path(args.inputs), "cpu")
    idx = list(range(K))
    agree = {}
    g_nl, c_nl = batch(idx, noise=False, keep=True), batch(idx, noise=False, keep=True, ch=cpu_chain)
    agree["radiance_max_abs_diff_over_max"] = max(_rel(g, c) for g, c in zip(g_nl.radiance, c_nl.radiance))
    agree["noiseless_frames_bytes_differing"] = int(sum((g != c).sum() for g, c in zip(g_nl.frames, c_nl.frames)))
    agree["noiseless_frames_bytes"] = int(sum(g.size for g in g_nl.frames))
    agree["noiseless_events_equal"] = all(np.array_equal(g, c) for g, c in zip(g_nl.events, c_nl.events))
    seeds_idx = list(range(4 * K))
    g_n, c_n = batch(seeds_idx, keep=True), batch(seeds_idx, keep=True, ch=cpu_chain)
    gm = np.array([f.reshape(len(f), -1).mean(axis=1) for f in g_n.frames])
    cm = np.array([f.reshape(len(f), -1).mean(axis=1) for f in c_n.frames])
    agree["noisy_frame_mean_dn"] = {"device": float(gm.mean()), "cpu": float(cm.mean()), "max_abs_diff_per_frame": float(np.abs(gm - cm).max())}
    agree["noisy_frame_std_dn"] = {"device": float(np.mean([f.std() for f in g_n.frames])), "cpu": float(np.mean([f.std() for f in c_n.frames]))}
    agree["noisy_events"] = {"device": int(sum(e.sum() for e in g_n.events)), "cpu": int(sum(e.sum() for e in c_n.events))}
    info["agreement_with_this_machines_cpu"] = agree
    (out / name).write_text(json.dumps(info, indent=2))
    # one file per exported episode's radiance (a file comes back from the device machine up to 16 MiB)
    for k, r in enumerate(g_nl.radiance):
        np.savez_compressed(out / f"gpu_radiance{k}.npz", radiance=r)
    np.savez_compressed(out / "gpu_outputs.npz", **{f"noiseless{k}": f for k, f in enumerate(g_nl.frames)},
                        **{f"events{k}": e for k, e in enumerate(g_n.events)}, **{f"features{k}": f for k, f in enumerate(g_n.features)},
                        **{f"frame_mean{k}": m for k, m in enumerate(gm)}, seeds=np.array([eps[i % K]["seed"] + 7919 * (i // K) for i in seeds_idx]))
    print(json.dumps(agree, indent=1))
    return 0


# -------------------------------------------------------------------------------------- compare
def compare(args) -> int:
    """The per-episode chain here against the GPU's outputs, on the exported episodes."""
    g = np.load(Path(args.gpu) / "gpu_outputs.npz")
    info = json.loads((Path(args.gpu) / "batched_chain_gpu.json").read_text())
    K = info["exported_episodes"]
    eps = _episodes(args.spec, K)
    rows = []
    for k, (scene, res, cache) in enumerate(eps):
        ref = _per_episode_chain(scene, res, cache)
        quiet = scene.with_values({"camera.noise": False})
        from mlsim import pipeline
        from mlsim.render.stage import CAMERA

        nl = CAMERA.run(quiet, {"render": ref["render"], "emission": ref["emission"]}, pipeline.RunContext(quiet, cache, None, False, print))
        rad = ref["render"].radiance
        gf = g[f"noiseless{k}"]
        # noisy: the GPU's four seeds of this episode against the CPU's own seed, per frame mean DN
        g_means = np.array([g[f"frame_mean{j}"] for j in range(k, 4 * K, K)])
        c_mean = ref["camera"].frames.reshape(len(rad), -1).mean(axis=1)
        ev_cpu = ref["dllm"].events
        ev_gpu = np.array([g[f"events{j}"] for j in range(k, 4 * K, K)])
        z_cpu = ref["dllm"].features
        z_gpu = np.array([g[f"features{j}"] for j in range(k, 4 * K, K)])
        fire = (z_cpu[..., 0] > 0) & (z_gpu[0][..., 0] > 0)
        rows.append({
            "episode": k, "frames": len(rad),
            "radiance_max_abs_diff_over_max": _rel(np.load(Path(args.gpu) / f"gpu_radiance{k}.npz")["radiance"], rad),
            "noiseless_bytes_differing": int((gf != nl.frames).sum()), "noiseless_bytes": int(gf.size),
            "noiseless_max_abs_diff_dn": int(np.abs(gf.astype(int) - nl.frames.astype(int)).max()),
            "noisy_frame_mean_dn_gpu_minus_cpu": float((g_means.mean(axis=0) - c_mean).mean()),
            "noisy_frame_mean_dn_spread_gpu_seeds": float(g_means.std(axis=0).mean()),
            "events_cpu": int(ev_cpu.sum()), "events_gpu_per_seed": ev_gpu.sum(axis=1).tolist(),
            "events_same_frames_fraction": float((ev_gpu == ev_cpu[None]).mean()),
            "l_px_median_abs_diff_on_taxels_firing_in_both": float(np.median(np.abs(z_gpu[0][..., 1] - z_cpu[..., 1])[fire])) if fire.any() else None,
            "omega_deg_median_abs_diff_on_taxels_firing_in_both": float(np.median(np.abs((z_gpu[0][..., 2] - z_cpu[..., 2] + 180) % 360 - 180)[fire])) if fire.any() else None,
        })
    print(json.dumps({"gpu": info.get("gpu"), "frames_per_s": info["frames_per_s"], "episodes": rows}, indent=1))
    return 0


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="mode")
    for name in ("cpu", "export", "gpu", "compare"):
        p = sub.add_parser(name)
        p.add_argument("--spec", default=str(ROOT / "scenes" / "interactions" / "paper.toml"))
        p.add_argument("--episodes", type=int, default={"cpu": 4, "export": 2, "gpu": 1000, "compare": 2}[name])
        p.add_argument("--rounds", type=int, default=3)
        p.add_argument("--out", default="out/batched_chain")
        p.add_argument("--inputs", default=".b40/data")
        p.add_argument("--gpu", default="out/batched_chain")
        p.add_argument("--batch", type=int, default=50)
        p.add_argument("--device", default="cuda")
        p.add_argument("--direct", choices=("host", "resident"), default="host",
                       help="gpu: the direct light copied from the host each batch (as the rasteriser gives it), or resident on the device "
                            "(the device chain's own rate)")
        p.add_argument("--no-agreement", action="store_true", help="gpu: time only")
    args = ap.parse_args(argv)
    return {"cpu": cpu, "export": export, "gpu": gpu, "compare": compare}[args.mode or "cpu"](args)


if __name__ == "__main__":
    sys.exit(main())
