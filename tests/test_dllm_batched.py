"""The batched DLLM (dllm.batched) against the streaming one (dllm.detector): grey levels bit-exact
against OpenCV on every 8-bit colour; events identical and features within 1e-6 relative (taxel
sums exactly equal) on synthetic episodes that take every branch of the threshold update, several
episodes at once, and on an episode rendered by the pipeline; results independent of the chunking;
bad input refused with the argument named."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from dllm.batched import BatchedDllm, dllm_batched, frame_statistics, rgb_to_grey
from dllm.calibration import Calibration
from dllm.detector import Dllm, DllmParams
from dllm.features import taxel_index, taxel_sums

ROOT = Path(__file__).resolve().parents[1]

# a small 5 x 5 sensor keeps the streaming reference fast: 30 px pitch, 11 px disks
H = W = 160
PITCH, RADIUS = 30.0, 11.0
DARK_DN = 12  # the camera's black level at 8 bits (tests/test_render.py)


def _calibration() -> Calibration:
    c = [[W / 2 + (j - 2) * PITCH, H / 2 + (i - 2) * PITCH] for i in range(5) for j in range(5)]
    return Calibration(np.array(c), RADIUS, (H, W))


def _idle(rng, n, level=DARK_DN, noise=1.0):
    """n dark RGB frames with read noise."""
    return np.clip(np.round(level + noise * rng.standard_normal((n, H, W, 3))), 0, 255).astype(np.uint8)


def _press(frame, cal, taxels, offset_px, angle_deg, peak):
    """The frame with a Gaussian glow (sigma 3 px, green-dominant) in each of ``taxels``, offset
    from the disk centre by offset_px towards angle_deg (image rows run down)."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    glow = np.zeros((H, W))
    for n in taxels:
        cx, cy = cal.centres_px[n]
        bx, by = cx + offset_px * math.cos(math.radians(angle_deg)), cy - offset_px * math.sin(math.radians(angle_deg))
        glow += peak * np.exp(-((xx - bx) ** 2 + (yy - by) ** 2) / (2 * 3.0**2))
    out = frame.astype(float) + glow[..., None] * np.array([0.35, 1.0, 0.45])
    return np.clip(np.round(out), 0, 255).astype(np.uint8)


def _episodes(cal, seed=0):
    """Three episodes of T = 100 frames, each beginning with the idle frames of the initialisation:
    0: a press spreading over more taxels, then a slide across two taxels; 1: the lights go on
    (+20 DN) for good, then a press; 2: a camera that starts black (D = 0 after the
    initialisation), light and a press, then dimmer light and a press."""
    rng, T = np.random.default_rng(seed), 100
    eps = _idle(rng, 3 * T).reshape(3, T, H, W, 3)
    for k, t in enumerate(range(35, 55)):  # 0: a press that spreads to more taxels, moving round
        eps[0, t] = _press(eps[0, t], cal, range(1 + k), 1.0 + 0.2 * k, 15.0 * k, 60.0 + 6 * k)
    for k, t in enumerate(range(85, 100)):  # 0: a slide along the middle row
        eps[0, t] = _press(eps[0, t], cal, [10 + k // 3], 4.0, 180.0 * (k % 2), 255.0)
    eps[1, 40:] = np.clip(eps[1, 40:].astype(int) + 20, 0, 255).astype(np.uint8)
    for t in range(80, 90):
        eps[1, t] = _press(eps[1, t], cal, [6, 7, 18], 3.0, 135.0, 120.0)
    eps[2, :50] = 0
    eps[2, 60:80] = _idle(rng, 20, level=30)
    for t in range(70, 75):
        eps[2, t] = _press(eps[2, t], cal, [0, 24], 2.0, 300.0, 200.0)
    eps[2, 80:] = _idle(rng, T - 80, level=15)  # dimmer: discarded frames scale B down with D
    for t in range(95, 100):
        eps[2, t] = _press(eps[2, t], cal, range(25), 2.0, 45.0, 120.0)
    return eps


# short time constants, so that the lights-on step is absorbed within the episode
PARAMS = DllmParams(alpha=1.01, beta=1.3, init_frames=30, fps=30.0, adapt_s=0.3, recover_s=0.2)


def _streaming(cal, episodes, params):
    out = [Dllm(cal, params).run(ep) for ep in episodes]
    return np.stack([e for e, _ in out]), np.stack([f for _, f in out])


def _assert_same(batched, streaming):
    (ev_b, z_b), (ev_s, z_s) = batched, streaming
    assert ev_b.dtype == bool and z_b.dtype == np.float64 and z_b.shape == z_s.shape
    assert np.array_equal(ev_b, ev_s)
    assert np.array_equal(z_b[..., 0], z_s[..., 0])  # H_n: integer sums, exact on both paths
    np.testing.assert_allclose(z_b, z_s, rtol=1e-6, atol=0)


# ---------------------------------------------------------------------------------- grey levels
def test_grey_is_opencvs_on_every_8_bit_colour():
    """All 2^24 colours, and random frames of odd sizes (OpenCV's SIMD body and scalar tail)."""
    v = np.arange(256, dtype=np.uint8)
    r, g, b = np.meshgrid(v, v, v, indexing="ij")
    rgb = np.stack([r, g, b], -1).reshape(4096, 4096, 3)
    for rows in np.array_split(np.arange(4096), 8):  # 8 slices: bounded int32 temporaries
        assert np.array_equal(rgb_to_grey(torch.from_numpy(rgb[rows])).numpy(), cv2.cvtColor(rgb[rows], cv2.COLOR_RGB2GRAY))
    rng = np.random.default_rng(1)
    for shape in [(1, 1), (3, 17), (37, 53), (350, 350)]:
        f = rng.integers(0, 256, shape + (3,), dtype=np.uint8)
        assert np.array_equal(rgb_to_grey(torch.from_numpy(f)).numpy(), cv2.cvtColor(f, cv2.COLOR_RGB2GRAY))
    batch = rng.integers(0, 256, (2, 3, 9, 11, 3), dtype=np.uint8)  # leading dimensions
    assert rgb_to_grey(torch.from_numpy(batch)).shape == (2, 3, 9, 11) and rgb_to_grey(torch.from_numpy(batch)).dtype == torch.uint8


def test_grey_refuses_what_is_not_an_8_bit_rgb_tensor():
    with pytest.raises(ValueError, match="frames: expected a"):
        rgb_to_grey(torch.zeros(4, 4, 3))
    with pytest.raises(ValueError, match="frames: expected a"):
        rgb_to_grey(np.zeros((4, 4, 3), np.uint8))


def test_frame_statistics_are_the_streaming_sums_through_opencv_or_torch():
    cal = _calibration()
    idx = taxel_index(cal)
    frames = np.random.default_rng(2).integers(0, 256, (5, H, W, 3), dtype=np.uint8)
    grey = [cv2.cvtColor(f, cv2.COLOR_RGB2GRAY) for f in frames]
    ref_M = np.array([cv2.sumElems(g)[0] for g in grey])
    ref_S = np.stack([np.stack(taxel_sums(g, idx), axis=-1) for g in grey])
    for opencv in (True, False):
        M, S = frame_statistics(frames, idx, chunk_frames=2, opencv=opencv)
        assert M.shape == (5,) and S.shape == (5, 25, 3)
        assert np.array_equal(M, ref_M) and np.array_equal(S, ref_S)


# ----------------------------------------------------------------------- batched == streaming
def test_batched_equals_streaming_on_synthetic_episodes():
    cal = _calibration()
    eps = _episodes(cal)
    ref = _streaming(cal, eps, PARAMS)
    ev, z = ref
    # the episodes take every branch: initialisation, discarded frames, events on which some taxels
    # fire and others do not, the lights-on events absorbed, and the camera with D = 0
    assert not ev[:, :PARAMS.init_frames].any()
    n_firing = (z[..., 0] > 0).sum(axis=-1)
    assert ev[0, 36] and not ev[0, 60:85].any() and ev[0, 85]  # the press, idle, the slide
    assert (n_firing[0][ev[0]] == 1).any() and (n_firing[0][ev[0]] > 1).any() and (n_firing[0][ev[0]] < 25).all()
    assert ev[1, 40] and n_firing[1, 40] == 25 and not ev[1, 65:80].any()  # the lights: absorbed
    assert set(np.flatnonzero(z[1, 80, :, 0])) == {6, 7, 18}  # then the press is seen
    assert not ev[2, 30:50].any() and ev[2, 50] and n_firing[2, 50] == 25 and (n_firing[2, 70:75] == 2).all()
    assert not ev[2, 80:95].any() and n_firing[2, 95] == 25  # fires against the B scaled down with D
    _assert_same(dllm_batched(eps, taxel_index(cal), PARAMS), ref)


def _rgb(grey_flat):
    """An RGB frame whose grey level is grey_flat (R = G = B: the weights sum to 2^15, Y = g)."""
    return np.repeat(np.asarray(grey_flat).reshape(H, W).astype(np.uint8)[..., None], 3, axis=2)


def _add(flat, pixels, amount):
    """Add an integer amount of intensity to the frame's pixels, at most 245 per pixel (base 10)."""
    full, rest = divmod(int(amount), 245)
    flat[pixels[:full]] += 245
    flat[pixels[full]] += rest


def test_gates_at_their_exact_thresholds_as_streaming():
    """Initialisation frames of 6, 10, 14 and 10 DN: D = 10 DN x pixels and B_n = 10 DN x the
    disk's pixels, exactly. A frame summing to exactly alpha D is discarded, one unit more is an
    event; on an event, taxels exactly at beta B_n stay silent and those one unit above fire."""
    cal = _calibration()
    idx = taxel_index(cal)
    params = DllmParams(alpha=1.25, beta=1.5, init_frames=4)
    init = [_rgb(np.full(H * W, level)) for level in (6, 10, 14, 10)]
    D = 10 * H * W
    outside = np.flatnonzero(~cal.masks().any(axis=0))  # pixels of no disk
    frames = []
    for extra in (D // 4, D // 4 + 1):  # alpha D - D = D / 4, an integer here
        flat = np.full(H * W, 10)
        _add(flat, outside, extra)
        frames.append(flat)
    flat = np.full(H * W, 10)
    _add(flat, outside, D // 4 + 1)  # an event whatever the taxels do
    B = 10 * np.diff(np.r_[idx.starts, len(idx.pixels)])
    for n in range(25):  # beta B_n - B_n = B_n / 2, an integer; odd taxels one unit more
        _add(flat, idx.pixels[idx.starts[n]:], B[n] // 2 + n % 2)
    frames.append(flat)
    eps = np.stack([np.stack(init + [_rgb(f)]) for f in frames])
    ev, z = ref = _streaming(cal, eps, params)
    assert ev[:, 4].tolist() == [False, True, True]
    assert (z[2, 4, :, 0] > 0).tolist() == [bool(n % 2) for n in range(25)]
    _assert_same(dllm_batched(eps, idx, params), ref)


def test_one_episode_a_tensor_and_the_wrapper_agree_with_streaming():
    cal = _calibration()
    eps = _episodes(cal, seed=3)[:, :90]
    ref = _streaming(cal, eps[:1], PARAMS)
    ev, z = BatchedDllm(cal, PARAMS).run(eps[0])  # (T, H, W, 3): one episode, shaped as Dllm.run's
    assert ev.shape == (90,) and z.shape == (90, 25, 3)
    _assert_same((ev[None], z[None]), ref)
    _assert_same(dllm_batched(torch.from_numpy(eps[:1]), taxel_index(cal), PARAMS, opencv=False), ref)


def test_the_result_does_not_depend_on_the_chunking():
    cal = _calibration()
    idx = taxel_index(cal)
    eps = _episodes(cal, seed=4)
    ev, z = dllm_batched(eps, idx, PARAMS, chunk_frames=64)
    for chunk in (1, 7, 1000):
        ev_c, z_c = dllm_batched(eps, idx, PARAMS, chunk_frames=chunk)
        assert np.array_equal(ev_c, ev) and np.array_equal(z_c, z)
    # a non-contiguous batch (every other frame) is read as it is
    _assert_same(dllm_batched(eps[:, ::2], idx, PARAMS, chunk_frames=5), _streaming(cal, eps[:, ::2], PARAMS))


@pytest.mark.parametrize("T", [0, 1, 29, 30, 31])
def test_short_episodes_are_all_initialisation(T):
    cal = _calibration()
    eps = _idle(np.random.default_rng(5), 2 * T).reshape(2, T, H, W, 3)
    ev, z = dllm_batched(eps, taxel_index(cal), PARAMS)
    assert ev.shape == (2, T) and z.shape == (2, T, 25, 3) and not ev.any() and not z.any()
    ev1, z1 = dllm_batched(eps[0], taxel_index(cal), PARAMS)
    s_ev, s_z = Dllm(cal, PARAMS).run(eps[0])
    assert np.array_equal(ev1, s_ev) and np.array_equal(z1, s_z)


def test_batched_equals_streaming_on_a_rendered_episode(cache):
    """The pipeline's 2 x 2 tiny scene at 96 x 96 px: its 8 frames after 30 copies of one of its
    dark frames (the initialisation); the press makes events in which some taxels fire."""
    from dllm.calibration import calibrate
    from mlsim import pipeline
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "mavig_tiny.toml", {"outputs": ["camera", "calibration"], "camera.width_px": 96,
                                                             "camera.height_px": 96, "fidelity.render.transport_spp": 8})
    res = pipeline.run(scene, out_dir=None, cache=cache, progress=False, log=lambda m: None)
    cam = res.results["camera"]
    cal = calibrate(res.results["calibration"].rgb, rows=2, cols=2)
    assert cal.shape_hw == (96, 96) and (~cam.rendered).any()
    params = DllmParams(fps=scene.camera.fps)
    episode = np.concatenate([np.repeat(cam.frames[~cam.rendered][:1], params.init_frames, axis=0), cam.frames])
    ref = Dllm(cal, params).run(episode)
    ev, z = ref
    firing = z[ev][..., 0] > 0
    assert ev.any() and firing.any() and not firing.all()
    got = BatchedDllm(cal, params).run(episode)
    _assert_same((got[0][None], got[1][None]), (ev[None], z[None]))
    # and as one of several episodes, next to one that never fires
    idle = np.repeat(episode[:1], len(episode), axis=0)
    _assert_same(dllm_batched(np.stack([idle, episode]), taxel_index(cal), params),
                 (np.stack([np.zeros_like(ev), ev]), np.stack([np.zeros_like(z), z])))


# ------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("bad, match", [
    (np.zeros((2, 3, H, W, 3), np.float32), "frames has dtype float32"),
    (np.full((3, H, W, 3), np.nan), r"frames has dtype float64 \(NaN values\)"),
    (torch.full((3, H, W, 3), float("nan")), r"frames has dtype torch.float32 \(NaN values\)"),
    (np.zeros((H, W, 3), np.uint8), r"frames has shape \(160, 160, 3\): must be \(E, T, H, W, 3\)"),
    (np.zeros((2, 3, H, W, 4), np.uint8), r"frames has shape \(2, 3, 160, 160, 4\)"),
    (np.zeros((2, 3, H, W), np.uint8), "grey frames: np.repeat"),
    (np.zeros((2, 3, 100, 100, 3), np.uint8), r"frames are of \(100, 100\) pixels, but the calibration is of \(160, 160\)"),
])
def test_bad_frames_are_refused_with_the_argument_named(bad, match):
    with pytest.raises(ValueError, match=match):
        dllm_batched(bad, taxel_index(_calibration()), PARAMS)


def test_bad_chunk_size_is_refused():
    with pytest.raises(ValueError, match="chunk_frames = 0"):
        dllm_batched(np.zeros((1, 2, H, W, 3), np.uint8), taxel_index(_calibration()), PARAMS, chunk_frames=0)
