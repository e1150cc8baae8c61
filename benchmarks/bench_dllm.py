"""Throughput of the DLLM at 350 x 350 RGB uint8 with the default 5 x 5 taxels (SPEC 1.6).

The calibration is synthetic: centres on a 67 px grid centred in the frame, radius 17 px. Frames are
distinct (as a camera hands them over, so nothing stays cache-hot): idle frames at the camera's dark
level (12 DN, read noise 1 DN) and frames on which every taxel fires (a green-dominant glow of
sigma 5 px, 180 DN peak, 5 px off each centre). Prints the machine, then the median over repeats of

- the streaming detector (``dllm.detector.Dllm.step``) on idle frames (all discarded) and on
  all-firing frames (every frame an event, every taxel firing: checked, not assumed);
- where a streaming step's time goes (its parts timed alone on the all-firing frames);
- the batched detector (``dllm.batched``) and the streaming one (reset between episodes) on E
  episodes of T frames, three mixes (30 idle frames of initialisation, then 30 all-firing and idle,
  all idle, or all firing); the results must agree (events identical, features within 1e-6
  relative); then the batched path's stages alone.

Targets (the issue): streaming >= 5000 frames/s idle and >= 1000 frames/s all-firing. Usage:

    .venv/bin/python benchmarks/bench_dllm.py [--repeats 7] [--frames 90] [--episodes 8]
        [--torch-threads N] [--json PATH]
"""

from __future__ import annotations

import argparse
import copy
import json
import math
import os
import platform
import statistics
import time
from pathlib import Path

import cv2
import numpy as np
import torch

from dllm.batched import BatchedDllm, batched_features, frame_statistics, threshold_gates
from dllm.calibration import Calibration, _check_frame, grey
from dllm.detector import Dllm, DllmParams, frame_sum
from dllm.features import taxel_features, taxel_sums

H = W = 350
PITCH_PX, RADIUS_PX = 67.0, 17.0
DARK_DN, READ_NOISE_DN = 12.0, 1.0
TARGET_IDLE_FPS, TARGET_FIRING_FPS = 5000.0, 1000.0


def default_calibration() -> Calibration:
    c = [[(W - 1) / 2 + (j - 2) * PITCH_PX, (H - 1) / 2 + (i - 2) * PITCH_PX] for i in range(5) for j in range(5)]
    return Calibration(np.array(c), RADIUS_PX, (H, W))


def idle_frames(n: int, rng: np.random.Generator) -> np.ndarray:
    """(n, H, W, 3) uint8: the dark level with read noise."""
    return np.clip(np.round(DARK_DN + READ_NOISE_DN * rng.standard_normal((n, H, W, 3))), 0, 255).astype(np.uint8)


def firing_frames(n: int, cal: Calibration, rng: np.random.Generator) -> np.ndarray:
    """(n, H, W, 3) uint8: idle frames plus a glow in every taxel, its offset turning frame by frame."""
    colour = np.array([0.35, 1.0, 0.45], np.float32)  # ZnS:Cu is green; R and B see its tails
    out = idle_frames(n, rng).astype(np.float32)
    half = 25  # the glow is computed on a window of +-5 sigma around its centre
    yy, xx = np.mgrid[-half:half + 1, -half:half + 1].astype(np.float32)
    for t in range(n):
        for k, (cx, cy) in enumerate(cal.centres_px):
            a = math.radians(15.0 * k + 7.0 * t)
            bx, by = cx + 5.0 * math.cos(a), cy - 5.0 * math.sin(a)
            r0, c0 = int(round(by)), int(round(bx))
            glow = 180.0 * np.exp(-((xx + c0 - bx) ** 2 + (yy + r0 - by) ** 2) / (2 * 5.0**2))
            out[t, r0 - half:r0 + half + 1, c0 - half:c0 + half + 1] += glow[..., None] * colour
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def median_seconds(fn, repeats: int) -> float:
    fn()  # warm up
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def streaming_case(ready: Dllm, frames: np.ndarray, repeats: int) -> tuple[float, Dllm]:
    """Median seconds per frame of ``step`` from the same initialised state; the last detector."""
    last = {}

    def go():
        det = copy.deepcopy(ready)
        t0 = time.perf_counter()
        for f in frames:
            det.step(f)
        last["det"], last["dt"] = det, time.perf_counter() - t0

    ts = []
    go()
    for _ in range(repeats):
        go()
        ts.append(last["dt"])
    return statistics.median(ts) / len(frames), last["det"]


def step_breakdown(ready: Dllm, frames: np.ndarray, repeats: int) -> dict[str, float]:
    """Microseconds per frame of each part of an event step, timed alone over the frames."""
    idx, det = ready.index, ready
    g = [grey(f) for f in frames]
    s = [taxel_sums(x, idx) for x in g]
    firing = [h > det.params.beta * det.B for h, _, _ in s]
    B = det.B.copy()
    parts = {
        "_check_frame": lambda: [_check_frame(f, "frame") for f in frames],
        "grey (cv2.cvtColor)": lambda: [grey(f) for f in frames],
        "frame_sum (cv2.sumElems)": lambda: [frame_sum(x) for x in g],
        "taxel_sums": lambda: [taxel_sums(x, idx) for x in g],
        "taxel_features": lambda: [taxel_features(h, sx, sy, idx.centres_px, fi) for (h, sx, sy), fi in zip(s, firing)],
        "threshold update": lambda: [B + (h - B) * np.where(fi, det.a_recover, det.a_adapt) for (h, _, _), fi in zip(s, firing)],
    }
    out = {k: median_seconds(fn, repeats) / len(frames) * 1e6 for k, fn in parts.items()}
    out["whole step"] = streaming_case(ready, frames, repeats)[0] * 1e6
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--frames", type=int, default=90, help="frames per streaming case and per episode")
    ap.add_argument("--episodes", type=int, default=8)
    ap.add_argument("--chunk-frames", type=int, default=16)
    ap.add_argument("--torch-threads", type=int, default=None, help="torch.set_num_threads (default: torch's own)")
    ap.add_argument("--json", default=None, help="also write the results to this JSON file")
    args = ap.parse_args()
    if args.frames < 61:
        ap.error("--frames must be >= 61 (30 initialisation, 30 firing, then idle)")
    if args.torch_threads:
        torch.set_num_threads(args.torch_threads)

    rng = np.random.default_rng(0)
    cal = default_calibration()
    params = DllmParams()
    machine = {"platform": platform.platform(), "processor": platform.processor() or platform.machine(), "cores": os.cpu_count(),
               "python": platform.python_version(), "numpy": np.__version__, "opencv": cv2.__version__,
               "opencv_threads": cv2.getNumThreads(), "torch": torch.__version__, "torch_threads": torch.get_num_threads(),
               "load_average": [round(v, 2) for v in os.getloadavg()]}  # another job on the machine shows here
    print(f"DLLM benchmark, {H} x {W} RGB uint8, 5 x 5 taxels (pitch {PITCH_PX:g} px, radius {RADIUS_PX:g} px), medians of {args.repeats}")
    print("machine: " + ", ".join(f"{k} {v}" for k, v in machine.items()))

    n = args.frames
    init, idle, lit = idle_frames(params.init_frames, rng), idle_frames(n, rng), firing_frames(n, cal, rng)
    ready = Dllm(cal, params)
    ready.run(init)
    s_idle, d_idle = streaming_case(ready, idle, args.repeats)
    s_lit, d_lit = streaming_case(ready, lit, args.repeats)
    ev_lit, z_lit = copy.deepcopy(ready).run(lit)
    all_firing = bool(ev_lit.all() and (z_lit[..., 0] > 0).all())
    if d_idle.counts["discarded"] != n or not all_firing:
        raise SystemExit(f"the frames are not what the cases say: idle {d_idle.counts}, firing {d_lit.counts}, "
                         f"every taxel fired: {all_firing}")
    fps_idle, fps_lit = 1 / s_idle, 1 / s_lit
    print("\n| streaming case | us/frame | frames/s | target | |")
    print("|---|---|---|---|---|")
    print(f"| idle (all {n} discarded) | {s_idle * 1e6:.1f} | {fps_idle:.0f} | >= {TARGET_IDLE_FPS:.0f} | "
          f"{'met' if fps_idle >= TARGET_IDLE_FPS else 'NOT met'} |")
    print(f"| every taxel fires ({n} events x 25) | {s_lit * 1e6:.1f} | {fps_lit:.0f} | >= {TARGET_FIRING_FPS:.0f} | "
          f"{'met' if fps_lit >= TARGET_FIRING_FPS else 'NOT met'} |")

    parts = step_breakdown(ready, lit, args.repeats)
    print("\nstreaming event step, parts alone (us/frame): " + ", ".join(f"{k} {v:.1f}" for k, v in parts.items()))

    # batched, on E episodes of T frames each, three mixes of idle and firing frames
    E, T = args.episodes, n
    bd = BatchedDllm(cal, params, chunk_frames=args.chunk_frames)
    det = Dllm(cal, params)  # built once: its taxel index is per calibration, not per episode

    def stream(eps):
        for ep in eps:
            det.reset()
            det.run(ep)

    mixes = {"mixed: 30 init, 30 firing, idle": (30, 60), "idle: 30 init, idle": (30, 30), "firing: 30 init, firing": (30, T)}
    batched = {}
    print(f"\n| {E} episodes x {T} frames | events | batched us/frame | batched frames/s | streaming us/frame | streaming frames/s |")
    print("|---|---|---|---|---|---|")
    for name, (a, b) in mixes.items():
        eps = np.empty((E, T, H, W, 3), np.uint8)
        for e in range(E):
            eps[e, :a], eps[e, b:] = idle_frames(a, rng), idle_frames(T - b, rng)
            eps[e, a:b] = firing_frames(b - a, cal, rng)
        s_batch = median_seconds(lambda: bd.run(eps), args.repeats) / (E * T)
        s_stream = median_seconds(lambda: stream(eps), args.repeats) / (E * T)
        ev_b, z_b = bd.run(eps)
        ref = [Dllm(cal, params).run(ep) for ep in eps]
        ev_s, z_s = np.stack([r[0] for r in ref]), np.stack([r[1] for r in ref])
        if not (np.array_equal(ev_b, ev_s) and np.allclose(z_b, z_s, rtol=1e-6, atol=0)):
            raise SystemExit(f"{name}: batched and streaming results differ")
        batched[name] = {"fps": 1 / s_batch, "streaming_fps": 1 / s_stream, "events": int(ev_s.sum())}
        print(f"| {name} | {int(ev_s.sum())} | {s_batch * 1e6:.1f} | {1 / s_batch:.0f} | {s_stream * 1e6:.1f} | {1 / s_stream:.0f} |")
    # the batched path's stages, on the last mix
    per = E * T / 1e6
    t_stats = median_seconds(lambda: [frame_statistics(ep, bd.index, args.chunk_frames) for ep in eps], args.repeats) / per
    M, S = (np.stack(a) for a in zip(*[frame_statistics(ep, bd.index, args.chunk_frames) for ep in eps]))
    t_gates = median_seconds(lambda: threshold_gates(M, S[..., 0], params), args.repeats) / per
    _, firing = threshold_gates(M, S[..., 0], params)
    t_feat = median_seconds(lambda: batched_features(S[..., 0], S[..., 1], S[..., 2], bd.index.centres_px, firing), args.repeats) / per
    stages = {"frame_statistics": t_stats, "threshold_gates": t_gates, "batched_features": t_feat}
    print(f"batched: chunks of {args.chunk_frames} frames, torch threads {torch.get_num_threads()}; results equal to streaming's "
          "(events identical, features within 1e-6); stages (us/frame): " + ", ".join(f"{k} {v:.1f}" for k, v in stages.items()))

    if args.json:
        result = {"machine": machine, "frame": [H, W, 3], "repeats": args.repeats, "frames": n,
                  "streaming": {"idle_fps": fps_idle, "firing_fps": fps_lit, "targets_fps": [TARGET_IDLE_FPS, TARGET_FIRING_FPS],
                                "targets_met": [fps_idle >= TARGET_IDLE_FPS, fps_lit >= TARGET_FIRING_FPS], "event_step_us": parts},
                  "batched": {"episodes": E, "frames": T, "chunk_frames": args.chunk_frames, "mixes": batched,
                              "stages_us_per_frame": stages}}
        path = Path(args.json)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(json.dumps(result, indent=2))
        tmp.replace(path)  # atomic: no half-written file
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
