"""The batched chain after the solve (mlsim.emission.batched, mlsim.render.batched,
mlsim.camera_batched, mlsim.dataset.batched) against the per-episode chain on the same inputs, on
the CPU (the same functions run on a GPU: benchmarks/bench_batched_chain.py's gpu mode).

Tolerances and why:
- emission: float64, the same operations in the same order except libm's exp/expm1 and the
  cumulative sum: relative 1e-12 (observed below 1e-14);
- render: float32 sums of non-negative products in another order: relative 1e-5 per pixel (a few
  float32 roundings of the pixel's own value);
- camera without noise: the same bytes (the same float32 operations and OpenCV's demosaic
  reproduced bit for bit);
- camera with noise: another generator, so statistics: the electrons' mean and variance against
  the model (Poisson + read noise) within 5 standard errors, and the 8-bit means against the CPU
  camera's within 5 standard errors; the same seed gives the same bytes whatever else is in the
  batch;
- DLLM: on the same frames, the streaming detector's events and features (equal);
- the whole chain (BatchedChain) on a solved mavig_tiny episode, noiseless, in the dark and
  under a flickering lamp: the pipeline's radiance within 1e-6 of its peak, its frames byte for
  byte and its DLLM output equal.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import scipy.sparse as sp
import torch

from mlsim.camera import EXACT_POISSON_BELOW_E2, EXACT_POISSON_READ_NOISE_BELOW_E, CameraParams, capture
from mlsim.camera_batched import (CameraConstants, capture_batched, capture_mono_batched, channel_radiance_batched, demosaic_rggb_batched,
                                  expose_batched)
from mlsim.camera_batched import EXACT_POISSON_BELOW_E2 as B_E2, EXACT_POISSON_READ_NOISE_BELOW_E as B_READ
from mlsim.emission import photon_rates
from mlsim.emission.batched import fraction_batched, merged_grids, photon_radiance_batched, von_mises_batched
from mlsim.emission.detrapping import DetrappingParams
from mlsim.emission.patches import MLPatches
from mlsim.emission.stress_rate import StressRateParams
from mlsim.render.batched import transport_batched, transport_operator
from mlsim.render.sensor_scene import radiance_of
from mlsim.render.transport import TransportMatrix

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------ emission
def _stress_episodes(rng, n_tets=40, n_patch=25):
    """Three episodes with different step counts, irregular steps (sub-steps) and frame counts:
    a press and release, so the rate is positive and negative and the traps deplete."""
    eps = []
    for S, F in ((31, 7), (18, 5), (44, 9)):
        t = np.cumsum(rng.uniform(0.2, 1.8, S)) / 30.0
        t -= t[0]
        load = np.sin(np.linspace(0, 1.7 * np.pi, S)) ** 2
        stress = (rng.normal(0, 1, (1, 6, n_tets)) * 3e5 * load[:, None, None] + rng.normal(0, 2e4, (S, 6, n_tets))).astype(np.float32)
        windows = np.stack([np.arange(F) / 30.0, np.arange(F) / 30.0 + 0.025], axis=1)
        eps.append((t, stress, windows))
    tet = rng.integers(0, n_tets, n_patch)
    area = rng.uniform(1e-8, 3e-8, n_patch)
    return eps, tet, area


def _patches(tet, area):
    n = len(tet)
    return MLPatches(np.zeros((n, 3)), np.zeros((0, 3), np.int64), np.zeros((n, 3)), area, np.zeros(n, np.int64), np.zeros((n, 3)), tet)


FLOAT32_ROUND_OFF = 1e-6  # a few float32 ulps (6e-8) of the stress the light is made from


@pytest.mark.parametrize("model, params", [("detrapping", DetrappingParams(4e-6, 0.3)), ("stress_rate", StressRateParams(4e-6))])
def test_emission_batched_equals_per_episode(model, params):
    rng = np.random.default_rng(3)
    eps, tet, area = _stress_episodes(rng)
    B_ph, scale = 2.5e12, 0.7
    grids = merged_grids([e[0] for e in eps], [e[2] for e in eps])
    S = max(len(e[0]) for e in eps)
    stress = torch.zeros(len(eps), S, 6, len(tet), dtype=torch.float32)
    for b, (_, s, _) in enumerate(eps):
        stress[b, : len(s)] = torch.from_numpy(s[:, :, tet])
        stress[b, len(s):] = torch.from_numpy(s[-1][:, tet])
    sigma = von_mises_batched(stress, torch.arange(len(tet)))
    fraction, filled = fraction_batched(sigma, grids, model, params.detrapping_per_pa, getattr(params, "recovery_time_s", 1.0))
    rad = photon_radiance_batched(fraction, grids, torch.from_numpy(area), B_ph, scale).numpy()
    worst = 0.0
    for b, (t, s, win) in enumerate(eps):
        ref = photon_rates(t, s, win, _patches(tet, area), model, params, "von_mises", B_ph, scale)
        expected = radiance_of(ref.photons_per_s, area)
        assert expected.max() > 0
        # the same to float32 round-off: the von Mises stress is float32 in both paths, and a reduction's order
        # may follow the threads a loaded machine gives it (8e-9 relative once on a clean clone's make test,
        # identical in every rerun)
        np.testing.assert_allclose(rad[b, : len(win)], expected, rtol=FLOAT32_ROUND_OFF, atol=FLOAT32_ROUND_OFF * expected.max())
        worst = max(worst, float(np.abs(rad[b, : len(win)] - expected).max() / expected.max()))
        assert np.all(rad[b, len(win):] == 0)  # padded frames: no light
        if model == "detrapping":
            np.testing.assert_allclose(filled[b].numpy(), ref.filled_fraction, rtol=FLOAT32_ROUND_OFF)
            assert ref.filled_fraction.min() < 0.99  # the traps did deplete: the recurrence was exercised
    assert worst < FLOAT32_ROUND_OFF


def test_von_mises_batched_is_the_compiled_kernels():
    from mlsim.emission.kernels import von_mises_at

    rng = np.random.default_rng(0)
    stress = rng.normal(0, 1e5, (5, 6, 30)).astype(np.float32)
    tet = rng.integers(0, 30, 12)
    ref = np.empty((5, 12))
    von_mises_at(stress, tet.astype(np.int64), ref)
    got = von_mises_batched(torch.from_numpy(stress)[None], torch.from_numpy(tet))[0].numpy()
    np.testing.assert_allclose(got, ref, rtol=1e-15)


def test_emission_refuses_non_finite_input_naming_it():
    rng = np.random.default_rng(1)
    eps, tet, area = _stress_episodes(rng)
    grids = merged_grids([e[0] for e in eps], [e[2] for e in eps])
    sigma = torch.ones(3, 44, len(tet), dtype=torch.float64)
    sigma[1, 3, 2] = float("nan")
    with pytest.raises(ValueError, match="sigma_eq_pa: contains NaN or Inf"):
        fraction_batched(sigma, grids)
    with pytest.raises(ValueError, match=r"t_s\[1\]: must be a 1-D array of finite"):
        merged_grids([eps[0][0], np.array([0.0, np.nan, 0.2])], [eps[0][2], eps[1][2]])
    with pytest.raises(ValueError, match='"foo" is not an emission model of the batched chain; choose one of: detrapping, stress_rate'):
        fraction_batched(torch.zeros(3, 44, len(tet), dtype=torch.float64), grids, "foo")


# -------------------------------------------------------------------------------------- render
def test_transport_batched_equals_the_matrix_product_plus_direct():
    rng = np.random.default_rng(2)
    H, W, N = 12, 14, 60
    m = sp.random(H * W, N, density=0.08, random_state=4, format="csr", dtype=np.float32)
    m.data[:] = rng.uniform(0.1, 2.0, m.nnz).astype(np.float32)
    tm = TransportMatrix(m, H, W, 8, 0.0, 0.0, first_depth=3)
    e = rng.uniform(0, 5e12, (2, 3, N)).astype(np.float32)
    e[0, 1] = 0.0  # a dark frame
    direct = rng.uniform(0, 1e12, (2, 3, H, W)).astype(np.float32)
    T = transport_operator(m.indptr, m.indices, m.data, m.shape)
    got = transport_batched(T, torch.from_numpy(e), H, W, torch.from_numpy(direct)).numpy()
    for b in range(2):
        ref = tm.apply(e[b], add_to=direct[b].copy())
        np.testing.assert_allclose(got[b], ref, rtol=1e-5)
    assert np.array_equal(got[0, 1], direct[0, 1])  # no light through the matrix on a dark frame
    bad = torch.from_numpy(e.copy())
    bad[1, 2, 5] = float("inf")
    with pytest.raises(ValueError, match=r"radiance \(\.\.\., vertices\) into the transport matrix's product: contains NaN or Inf"):
        transport_batched(T, bad, H, W)


# -------------------------------------------------------------------------------------- camera
def test_poisson_thresholds_are_the_cpu_cameras():
    assert (B_E2, B_READ) == (EXACT_POISSON_BELOW_E2, EXACT_POISSON_READ_NOISE_BELOW_E)


def test_demosaic_is_opencvs_bit_for_bit():
    rng = np.random.default_rng(0)
    for shape in ((3, 9, 12), (2, 10, 7), (2, 8, 12), (1, 350, 350)):  # odd sizes: the general path; even: the planes
        raw = rng.integers(0, 256, shape, dtype=np.uint8)
        ref = np.stack([cv2.cvtColor(r, cv2.COLOR_BayerBG2RGB) for r in raw])
        assert np.array_equal(demosaic_rggb_batched(torch.from_numpy(raw)).numpy(), ref)


@pytest.mark.parametrize("overrides", [{}, {"cos4_falloff": True, "gain_db": 6.0}, {"read_noise_e": 0.3, "gain_db": 30.0, "adc_bits": 12}])
def test_noiseless_frames_are_the_cpu_cameras_bytes(overrides):
    rng = np.random.default_rng(5)
    p = CameraParams(**overrides)
    # up to past the full well (80 ke- effective at the default binning)
    top = 1.5 * p.effective_full_well_e / p.electrons_per_radiance_m2_sr_s
    rad = (rng.random((2, 2, 64, 80, 3)) ** 2 * top).astype(np.float32)
    ref = capture(rad.reshape(-1, 64, 80, 3), np.random.default_rng(0), CameraParams(**(overrides | {"width_px": 80, "height_px": 64})),
                  noise=False)
    got = capture_batched(torch.from_numpy(rad), CameraConstants.of(CameraParams(**(overrides | {"width_px": 80, "height_px": 64}))),
                          noise=False).numpy()
    assert np.array_equal(got.reshape(ref.shape), ref)
    assert len(np.unique(ref)) > 100  # the whole 8-bit range was exercised, not one code


def test_ambient_leak_is_added_as_expose_adds_it():
    rng = np.random.default_rng(6)
    rad = rng.uniform(0, 1e14, (2, 3, 8, 10)).astype(np.float32)
    amb = rng.uniform(0, 1e13, (8, 10)).astype(np.float32)
    k, k_amb = np.array([0.2, 0.5, 0.1], np.float32), np.array([0.3, 0.3, 0.2], np.float32)
    level = np.array([[0.0, 0.5, 1.3], [1.0, 0.0, 0.7]])
    got = channel_radiance_batched(torch.from_numpy(rad), torch.from_numpy(k), torch.from_numpy(amb), torch.from_numpy(level),
                                   torch.from_numpy(k_amb)).numpy()
    for b in range(2):
        for f in range(3):
            ref = rad[b, f][..., None] * k  # mlsim.render.output.expose's loop
            if level[b, f] > 0:
                ref += (level[b, f] * amb)[..., None] * k_amb
            assert np.array_equal(got[b, f], ref)


def _constant_frames(mu_e, c: CameraConstants, shape=(2, 2, 120, 120)):
    """Channel radiance (shape + (3,)) whose every photosite's mean is mu_e electrons (dark included)."""
    level = (mu_e - c.dark_electrons) / c.electrons_per_radiance
    return torch.full(shape + (3,), level, dtype=torch.float32)


@pytest.mark.parametrize("mu, read", [(400.0, 8.0), (3.0, 0.5), (60.0, 0.5)])
def test_electrons_have_the_models_mean_and_variance(mu, read):
    """Poisson(mu) + N(0, read^2): mean mu, variance mu + read^2, third cumulant mu; the normal
    branch (8 e- read noise, or 0.5 e- above the exact branch's 20 e-^2) and the exact Poisson branch."""
    c = CameraConstants(1e-13, 0.0, read, math.inf, 0.0125, 50.0, 10, True)
    rad = _constant_frames(mu, c)
    e = expose_batched(rad, c, [torch.Generator().manual_seed(s) for s in (1, 2)]).double().ravel()
    n = e.numel()
    var = mu + read ** 2
    mean_e, var_e = float(e.mean()), float(e.var())
    assert abs(mean_e - mu) < 5 * math.sqrt(var / n)
    assert abs(var_e / var - 1) < 5 * math.sqrt(2.0 / n) * 1.5  # 1.5: the kurtosis of Poisson at small mu
    k3 = float(((e - mean_e) ** 3).mean())
    assert abs(k3 - mu) < 5 * math.sqrt(15 * var ** 3 / n)  # var of the third-moment estimator ~ 15 sigma^6 / n
    if var < EXACT_POISSON_BELOW_E2 and read < EXACT_POISSON_READ_NOISE_BELOW_E:
        # the exact branch: counts plus read noise, so e - read z is an integer
        assert float(e.min()) > -5 * read - 1


def test_noisy_frames_match_the_cpu_camera_in_distribution():
    p = CameraParams(gain_db=24.0)  # about 0.2 DN per e-: the shot noise spans several 8-bit codes
    c = CameraConstants.of(p)
    rng = np.random.default_rng(7)
    rad = np.repeat(rng.uniform(0.2, 1.0, (1, 1, 1, 1, 3)) * 1.5e3 / p.electrons_per_radiance_m2_sr_s, 1, axis=0)
    rad = np.broadcast_to(rad, (2, 4, 350, 350, 3)).astype(np.float32)
    got = capture_batched(torch.from_numpy(np.ascontiguousarray(rad)), c, [torch.Generator().manual_seed(s) for s in (3, 4)]).numpy()
    ref = capture(rad.reshape(-1, 350, 350, 3), np.random.default_rng(8), p)
    inner = (slice(None), slice(2, -2), slice(2, -2))
    for ch in range(3):
        a = got.reshape(-1, 350, 350, 3)[inner + (ch,)].astype(float)
        b = ref[inner + (ch,)].astype(float)
        se = math.sqrt(a.var() / a.size + b.var() / b.size) * 3  # x3: the demosaic correlates neighbours
        assert a.std() > 1.0  # the noise spans codes: a real comparison of distributions
        assert abs(a.mean() - b.mean()) < 5 * se
        assert abs(a.std() / b.std() - 1) < 0.02


def test_same_seed_same_bytes_whatever_the_batch():
    c = CameraConstants.of(CameraParams(gain_db=24.0))
    rad = _constant_frames(2e3, c, (3, 2, 32, 32))
    all3 = capture_batched(rad, c, [torch.Generator().manual_seed(s) for s in (11, 12, 13)]).numpy()
    again = capture_batched(rad[1:2], c, [torch.Generator().manual_seed(12)]).numpy()
    assert np.array_equal(all3[1], again[0])
    assert not np.array_equal(all3[0], all3[1])
    with pytest.raises(ValueError, match="generators: one torch.Generator per episode is needed"):
        capture_batched(rad, c, [torch.Generator()])


def test_camera_refuses_non_finite_radiance_naming_it():
    c = CameraConstants.of(CameraParams())
    rad = torch.zeros(1, 1, 8, 8)
    rad[0, 0, 3, 3] = float("nan")
    with pytest.raises(ValueError, match=r"radiance \(\.\.\., H, W\) into the camera has 1 NaN"):
        channel_radiance_batched(rad, torch.ones(3))
    ch = torch.zeros(1, 1, 8, 8, 3)
    ch[..., 0] = float("inf")
    with pytest.raises(ValueError, match=r"channel_radiance \(episodes, frames, H, W, 3\) has 0 NaN and 64 infinite"):
        capture_batched(ch, c, noise=False)


def test_the_fused_mono_path_and_the_chunking_give_the_same_bytes():
    """capture_mono_batched (mono radiance straight to the mosaic, chunk by chunk) is
    capture_batched of channel_radiance_batched, with and without the ambient leak and the noise,
    whatever the chunking and the padding of shorter episodes."""
    rng = np.random.default_rng(9)
    p = CameraParams(gain_db=18.0, cos4_falloff=True, width_px=40, height_px=30)
    c = CameraConstants.of(p)
    rad = torch.from_numpy((rng.random((3, 5, 30, 40)) * 3e3 / p.electrons_per_radiance_m2_sr_s).astype(np.float32))
    k = torch.tensor([0.3, 0.9, 0.4])
    amb = torch.from_numpy((rng.random((30, 40)) * 1e3 / p.electrons_per_radiance_m2_sr_s).astype(np.float32))
    level = torch.from_numpy(rng.choice([0.0, 0.4, 1.0], (3, 5)))
    ka = torch.tensor([0.5, 0.5, 0.2])
    n = [5, 3, 4]
    for noise in (False, True):
        for extra in ({}, {"ambient": amb, "level": level, "k_ambient": ka}):
            gens = (lambda: [torch.Generator().manual_seed(s) for s in (1, 2, 3)]) if noise else (lambda: None)
            ch = channel_radiance_batched(rad, k, extra.get("ambient"), extra.get("level"), extra.get("k_ambient"))
            ref = capture_batched(ch, c, gens(), noise, n_frames=n if noise else None)
            for chunk in (None, 2):
                got = capture_mono_batched(rad, k, c, gens(), n_frames=n if noise else None, noise=noise, chunk_frames=chunk, **extra)
                for b in range(3):
                    assert np.array_equal(got[b, : n[b]].numpy(), ref[b, : n[b]].numpy()), (noise, bool(extra), chunk, b)


@pytest.mark.parametrize("lamp", [{}, {"ambient.lamp": "daylight", "ambient.occlusion": False, "ambient.flicker_hz": 100.0}],
                         ids=["dark", "flickering-lamp"])
def test_the_chain_on_a_solved_episode_is_the_per_episode_chain(cache, lamp):
    """mavig_tiny (2 x 2 rods, 96 x 96 px, deformed tier), noiseless camera, in the dark and under a
    flickering lamp (its leak in the idle frames and the episode's): the batched chain on its
    solved episode (twice in one batch) gives the pipeline's radiance within 1e-6 of its peak
    (observed 1.5e-7), its 8-bit frames byte for byte, and the DLLM's events and features equal."""
    from mlsim import pipeline
    from mlsim.dataset.batched import BatchedChain
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "mavig_tiny.toml", {"outputs": ["dllm"], "camera.width_px": 96, "camera.height_px": 96,
                                                             "fidelity.render.transport_spp": 8, "camera.noise": False} | lamp)
    # every stage it reads asked for by name: a stage another test already cached is otherwise loaded only
    # if a later one needs it, and left out of the results (a clean clone's make test failed so)
    res = pipeline.run(scene, cache=cache, outputs=("solve", "render", "camera", "dllm"), progress=False, log=lambda m: None)
    ep, ref = res.results["solve"], res.results["render"].radiance
    chain = BatchedChain.from_scene(scene, ep, cache)
    out = chain.run([ep, ep], [1, 2], keep_radiance=True, keep_frames=True, noise=False)
    assert ref.max() > 0 and res.results["dllm"].events.any()
    if lamp:  # the leak reaches the camera in every frame, the idle ones included
        assert chain.ambient is not None and float(chain.ambient.max()) > 0
        assert float(chain.ambient_level(chain.windows(chain.n_idle, -chain.n_idle / chain.fps)).min()) > 0
    for b in range(2):
        assert np.abs(out.radiance[b] - ref).max() <= 1e-6 * ref.max()
        assert np.array_equal(out.frames[b], res.results["camera"].frames)
        assert np.array_equal(out.events[b], res.results["dllm"].events)
        assert np.array_equal(out.features[b], res.results["dllm"].features)
    bad = ep.stress.copy()
    bad[3, 0, int(chain.tet[0])] = np.nan
    with pytest.raises(ValueError, match="sigma_eq_pa: contains NaN or Inf"):
        chain.run_arrays([bad[:, :, chain.tet.numpy()]], [ep.t_s], [0], lambda b, r: np.zeros((len(r), 96, 96), np.float32),
                         n_frames=[ep.n_frames])
