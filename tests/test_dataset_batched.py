"""A dataset through the batched chain (spec ``chain = "batched"``, mlsim.dataset.generate's
run_batch_job) against the same spec through the per-episode chain, on a tiny sensor.

The sensor: scenes/mavig_tiny.toml (2 x 2 rods, its shipped 2.5 mm mesh) at a dataset's tiers
(reduced solve, deformed render at 8 spp), a 96 x 96 px camera; two episodes (push, sliding left),
one worker. Tolerances (docs/uses/datasets.md, the batched chain; tests/test_batched_chain.py for
each stage):
- noiseless camera: the stored frames, DLLM events and features byte for byte, the rods' signal
  (from the radiance, float32 sums in another order) within 1e-6 of each episode's peak, every
  other array and attribute but the timings equal;
- with noise: another generator (torch's), the same model: per channel, the noise (a frame minus
  the noiseless frame) has the same mean and variance in both datasets within 5 standard errors
  (x3 for the demosaic's correlation of neighbours), and the noise spans several 8-bit codes;
- the device: "cuda" without one fails before any episode, naming the fix; "auto" runs on the CPU
  and the run log says why.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import torch

from mlsim.dataset import generate as gen
from mlsim.dataset import store
from mlsim.dataset.batched import resolve_device
from mlsim.dataset.spec import load_dataset_spec
from mlsim.scene import SceneError

ROOT = Path(__file__).resolve().parents[1]
ARRAYS = ("dllm_features", "dllm_event", "frames", "frame_label", "rod_force_n", "wrench", "screw_pose")
TIMINGS = ("seconds", "stage_seconds")
RADIANCE_RTOL = 1e-6  # of the peak: float32 sums of the bounces in another order (observed 0 here, 2.1e-7 on the paper scene)


def write_tiny_spec(tmp: Path, extra_spec: str = "", extra_scene: str = "") -> Path:
    """A two-episode spec on mavig_tiny at a dataset's tiers, noiseless unless ``extra_scene`` says otherwise."""
    scene = (ROOT / "scenes" / "mavig_tiny.toml").read_text().replace('outputs = ["mesh"]', 'outputs = ["dllm"]')
    assert 'outputs = ["dllm"]' in scene and "[camera]" not in scene and "[fidelity.solve]" not in scene, \
        "scenes/mavig_tiny.toml changed: update write_tiny_spec"
    scene += ('\n[fidelity.solve]\ntier = "reduced"\n\n[fidelity.render]\ntier = "deformed"\ntransport_spp = 8\n\n'
              f'[camera]\nwidth_px = 96\nheight_px = 96\n{extra_scene or "noise = false"}\n')
    (tmp / "tiny.toml").write_text(scene)
    path = tmp / "spec.toml"
    path.write_text('name = "tiny_ds"\nscene = "tiny.toml"\nseed = 0\npeople = 1\nsamples_per_action = 1\n'
                    f'actions = ["push", "sliding_left"]\nstore_frames = true\n{extra_spec}')
    return path


def _generate(tmp: Path, name: str, extra_spec: str = "", extra_scene: str = "") -> tuple[Path, list[str]]:
    d = tmp / name
    d.mkdir()
    spec, base = load_dataset_spec(write_tiny_spec(d, extra_spec, extra_scene))
    lines: list[str] = []
    gen.generate(spec, base, d / "data", workers=1, progress=False, log=lines.append)
    return d / "data", lines


@pytest.fixture(scope="module")
def noiseless(tmp_path_factory):
    """(per-episode dataset, batched dataset, the batched run's log lines), noiseless camera."""
    tmp = tmp_path_factory.mktemp("batched_ds")
    per, _ = _generate(tmp, "per_episode")
    batched, log = _generate(tmp, "batched", 'chain = "batched"\n')
    return per, batched, log


def _episodes(out: Path) -> dict[str, dict]:
    return {e: store.read_episode(out, e) for e in sorted(store.complete_episodes(out))}


def test_a_noiseless_batched_dataset_is_the_per_episode_dataset(noiseless):
    per, batched, log = noiseless
    a, b = _episodes(per), _episodes(batched)
    assert sorted(a) == sorted(b) == ["push_00000", "sliding_left_00000"]
    for e in a:
        assert a[e]["dllm_event"].any() and a[e]["rod_signal_e"].max() > 0  # light reached the rods, the DLLM fired
        for k in ARRAYS:
            assert a[e][k].dtype == b[e][k].dtype and a[e][k].tobytes() == b[e][k].tobytes(), (e, k)
        peak = float(a[e]["rod_signal_e"].max())
        assert float(np.abs(a[e]["rod_signal_e"] - b[e]["rod_signal_e"]).max()) <= RADIANCE_RTOL * peak
        assert {k: v for k, v in a[e].items() if k not in store.EPISODE_ARRAYS and k not in TIMINGS} == \
            {k: v for k, v in b[e].items() if k not in store.EPISODE_ARRAYS and k not in TIMINGS}
        assert set(b[e]["stage_seconds"]) == {"solve", "emission", "render", "camera", "dllm"}  # the per-episode stages' names
    # the store's schema: the same arrays, the same dataset attributes but the spec's chain
    assert set(store.read_attrs(per)) == set(store.read_attrs(batched))
    assert store.read_attrs(batched)["spec"]["chain"] == "batched" and "chain" not in store.read_attrs(per)["spec"]
    assert any("chain: batched" in m and "on cpu" in m and "no CUDA device" in m for m in log) or torch.cuda.is_available(), log


def test_noisy_frames_have_the_per_episode_noise_statistics(tmp_path):
    """Camera noise at 30 dB gain (the noise, mostly read and dark noise on dark frames, spans codes): the
    batched dataset's noise and the per-episode dataset's have the same mean and variance."""
    noisy = {}
    for chain in ("per_episode", "batched"):
        out, _ = _generate(tmp_path, chain, f'chain = "{chain}"\n', "noise = true\ngain_db = 30.0")
        noisy[chain] = _episodes(out)
    out, _ = _generate(tmp_path, "quiet", "", "noise = false\ngain_db = 30.0")  # the noiseless mean frames at this gain
    quiet = _episodes(out)
    for e in quiet:
        ra = noisy["per_episode"][e]["frames"].astype(float) - quiet[e]["frames"]
        rb = noisy["batched"][e]["frames"].astype(float) - quiet[e]["frames"]
        assert not np.array_equal(ra, rb)  # another generator: other draws
        for ch in range(3):
            x, y = ra[..., ch].ravel(), rb[..., ch].ravel()
            assert x.std() > 1.0  # several codes: a real comparison of distributions
            se = 3 * math.sqrt(x.var() / x.size + y.var() / y.size)
            assert abs(x.mean() - y.mean()) < 5 * se, (e, ch, x.mean(), y.mean())
            # the variance ratio's standard error: 2 / n per variance (Gaussian), n / 9 independent values (the demosaic)
            assert abs(y.var() / x.var() - 1) < 5 * math.sqrt(2 * 2 * 9 / x.size), (e, ch, x.var(), y.var())


def test_the_device_is_resolved_as_the_renders():
    assert resolve_device("cpu") == ("cpu", "device = cpu")
    device, why = resolve_device("auto", cuda_available=False)
    assert device == "cpu" and "no CUDA device" in why
    assert resolve_device("auto", cuda_available=True)[0] == "cuda"
    with pytest.raises(RuntimeError, match='torch finds no CUDA device here .* set device = "auto" .* or device = "cpu"'):
        resolve_device("cuda", cuda_available=False)
    with pytest.raises(ValueError, match='device = "gpu": choose "auto", "cpu" or "cuda"'):
        resolve_device("gpu")


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device: the no-CUDA error cannot happen here")
def test_cuda_without_a_device_fails_before_any_episode(tmp_path):
    spec, base = load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "batched"\ndevice = "cuda"\n'))
    with pytest.raises(RuntimeError, match="torch finds no CUDA device here"):
        gen.generate(spec, base, tmp_path / "data", workers=1, progress=False, log=lambda m: None)
    assert not (tmp_path / "data").exists()  # nothing written


@pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device: the batched chain's GPU path runs only where torch finds one "
                    "(benchmarks/bench_batched_chain.py gpu on a GPU machine)")
def test_a_noiseless_cuda_dataset_is_the_per_episode_dataset(noiseless, tmp_path):
    per, _, _ = noiseless
    cuda, _ = _generate(tmp_path, "cuda", 'chain = "batched"\ndevice = "cuda"\n')
    a, b = _episodes(per), _episodes(cuda)
    for e in a:
        for k in ("dllm_features", "dllm_event", "frames"):
            assert a[e][k].tobytes() == b[e][k].tobytes(), (e, k)
        assert float(np.abs(a[e]["rod_signal_e"] - b[e]["rod_signal_e"]).max()) <= RADIANCE_RTOL * float(a[e]["rod_signal_e"].max())


def test_chain_settings_are_validated_naming_the_field_and_the_fix(tmp_path):
    with pytest.raises(SceneError, match=r"chain.*'per_episode'.*'batched'"):
        load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "gpu"\n'))
    with pytest.raises(SceneError, match='device = \'cuda\': the batched chain\'s device: set chain = "batched"'):
        load_dataset_spec(write_tiny_spec(tmp_path, 'device = "cuda"\n'))
    with pytest.raises(SceneError, match=r"chain = 'batched': runs batches of one sensor.*remove \[randomize\]"):
        load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "batched"\n[randomize]\n"camera.gain_db" = [0.0, 6.0]\n'))
    path = write_tiny_spec(tmp_path, 'chain = "batched"\n')
    (tmp_path / "tiny.toml").write_text((tmp_path / "tiny.toml").read_text().replace('tier = "deformed"', 'tier = "transport"'))
    with pytest.raises(SceneError, match='chain.*the batched chain runs fidelity.render.tier = "deformed" only.*set chain = "per_episode"'):
        load_dataset_spec(path)


def test_a_spec_at_the_default_chain_hashes_as_before(tmp_path):
    """The chain's fields at their defaults stay out of the spec's dump: the datasets made before
    they existed keep their spec hash (a rerun resumes them) and their bytes."""
    spec, _ = load_dataset_spec(write_tiny_spec(tmp_path))
    explicit, _ = load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "per_episode"\ndevice = "auto"\nbatch_episodes = 16\n'))
    assert not {"chain", "device", "batch_episodes"} & set(spec.model_dump(mode="json"))
    assert spec.content_hash() == explicit.content_hash()
    batched, _ = load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "batched"\n'))
    assert batched.content_hash() != spec.content_hash()


REFUSED = "push_00000"
_REAL_BATCH_JOB = gen.run_batch_job


def _batch_with_a_refused_solve(batch: dict) -> dict:
    """The real batch job, with REFUSED's solve refused (as a SolverError would): patched inside the
    job, because the workers are spawned processes that import this module by name."""
    from mlsim import pipeline

    real_run = pipeline.run

    def run(scene, *args, **kwargs):
        if scene.name == REFUSED:
            raise ValueError(f"episode {REFUSED}: the load is refused (made to fail by the test)")
        return real_run(scene, *args, **kwargs)

    pipeline.run = run
    try:
        return _REAL_BATCH_JOB(batch)
    finally:
        pipeline.run = real_run


def test_an_episode_whose_solve_fails_is_recorded_and_its_batch_stored(noiseless, tmp_path, monkeypatch):
    """One batch of two episodes, one solve refused: the other episode is stored as the per-episode
    chain stores it, the refused one recorded with its reason; the rerun runs only it."""
    per, _, _ = noiseless
    spec, base = load_dataset_spec(write_tiny_spec(tmp_path, 'chain = "batched"\n'))
    out = tmp_path / "data"
    monkeypatch.setattr(gen, "run_batch_job", _batch_with_a_refused_solve)
    lines: list[str] = []
    summary = gen.generate(spec, base, out, workers=1, progress=False, log=lines.append)
    assert store.complete_episodes(out) == {"sliding_left_00000"} and summary["episodes_failed"] == 1
    assert store.read_failures(out)[REFUSED] == {"kind": "error", "error_type": "ValueError",
                                                 "message": f"episode {REFUSED}: the load is refused (made to fail by the test)"}
    assert any("1 episode failed" in m and REFUSED in m for m in lines)
    monkeypatch.setattr(gen, "run_batch_job", _REAL_BATCH_JOB)
    rerun = gen.generate(spec, base, out, workers=1, progress=False, log=lambda m: None)
    assert rerun["episodes_run_now"] == 1 and rerun["complete"] and not store.read_failures(out)
    for e in ("sliding_left_00000", REFUSED):
        a, b = store.read_episode(per, e), store.read_episode(out, e)
        assert a["dllm_features"].tobytes() == b["dllm_features"].tobytes() and a["frames"].tobytes() == b["frames"].tobytes(), e
