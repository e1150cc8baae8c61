"""``mlsim detect``: recordings through the same DLLM as a simulated run.

A simulated episode of the tiny scene, written as a recording (its idle second, then its frames),
comes back through ``mlsim detect``: as lossless PNG frames the features are the simulated run's
bit for bit; as a lossy MP4 (OpenCV's MPEG-4 part 2) the same frames are events and the same
taxels fire, with H within 3 DN per disk pixel plus 2 % (the codec shifts dark levels by about
2 DN) and the offsets l within 0.5 px, and every rule of dllm.round_trip's stated tolerance holds;
behind -m slow, the MP4 that ``make demo`` writes holds to the same tolerance. Each bad input exits 2 with the
argument named and no traceback. The idle check: the run of leading frames within alpha of the darkest."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from mlsim.cli import main
from mlsim.detect import RecordingError, detect_recording, idle_run, open_recording

ROOT = Path(__file__).resolve().parents[1]
# the scene of tests/test_dllm.py's pipeline test: the same cache entries in one session
TINY = {"outputs": ["dllm", "camera"], "camera.width_px": 96, "camera.height_px": 96, "fidelity.render.transport_spp": 8}
SETS = ["--set", "camera.width_px=96", "--set", "camera.height_px=96"]


@pytest.fixture(scope="module")
def simulated(cache, tmp_path_factory):
    """(scene, the simulated DllmEpisode, a folder with recording.mp4, frames/ (PNG) and calibration.png)."""
    from dllm.stage import idle_before
    from mlsim import pipeline
    from mlsim.render.output import write_mp4, write_png
    from mlsim.scene import load_scene

    scene = load_scene(ROOT / "scenes" / "mavig_tiny.toml", TINY)
    # every result read below is asked for: the planner leaves out a stage whose dependants are
    # cached (test_dllm's run of this scene caches the camera, so the render would be skipped)
    res = pipeline.run(scene, out_dir=None, cache=cache, outputs=("dllm", "camera", "render", "calibration"), progress=False,
                       log=lambda m: None)
    cam = res.results["camera"]
    recording = np.concatenate([idle_before(scene, res.results["render"]), cam.frames])
    d = tmp_path_factory.mktemp("recording")
    write_mp4(d / "recording.mp4", recording, cam.fps)
    (d / "frames").mkdir()
    for k, f in enumerate(recording):
        write_png(d / "frames" / f"f{k}.png", f)  # unpadded names: read in natural order
    write_png(d / "calibration.png", res.results["calibration"].rgb)
    np.save(d / "lossless.npy", recording)
    return scene, res.results["dllm"], d


def _features(out: Path) -> tuple[np.ndarray, np.ndarray]:
    table = np.loadtxt(out / "dllm_features.csv", delimiter=",", skiprows=1, ndmin=2)
    return table[:, 2].astype(bool), table[:, 3:].reshape(len(table), -1, 3)


def test_lossless_frames_give_the_simulated_features_exactly(simulated, tmp_path):
    scene, sim, d = simulated
    assert main(["detect", str(d / "frames"), "--calibration", str(d / "calibration.png"), "--scene",
                 str(ROOT / "scenes" / "mavig_tiny.toml"), *SETS, "--out", str(tmp_path), "--quiet"]) == 0
    events, features = _features(tmp_path)
    assert sim.events.sum() >= 2  # the episode glows
    assert np.array_equal(events, sim.events)
    np.testing.assert_allclose(features, sim.features, rtol=1e-8, atol=1e-6)  # the CSV's 9 significant digits
    taxels = np.loadtxt(tmp_path / "dllm_taxels.csv", delimiter=",", skiprows=1, usecols=1).astype(int)
    assert np.array_equal(taxels, sim.rod_of_taxel)
    for name in ("dllm_events.csv", "dllm_calibration.json", "dllm_heatmap.png", "detect.json"):
        assert (tmp_path / name).is_file()


def test_a_lossy_mp4_gives_the_same_events_within_tolerance(simulated, tmp_path):
    scene, sim, d = simulated
    s = detect_recording(d / "recording.mp4", d / "calibration.png", tmp_path, scene=scene, progress=False, log=lambda m: None)
    assert s["fps"] == 30.0 and s["fps_from"] == "the container" and s["idle_frames"] == 30
    events, features = _features(tmp_path)
    assert np.array_equal(events, sim.events)
    fired, fired_sim = features[..., 0] > 0, sim.features[..., 0] > 0
    assert np.array_equal(fired, fired_sim)
    H, H_sim = features[..., 0][fired], sim.features[..., 0][fired]
    # the codec's YUV round trip shifts dark levels by about 2 DN (test below): 3 DN per disk pixel plus 2 % of H
    disk_px = np.pi * sim.calibration.radius_px**2
    assert np.all(np.abs(H - H_sim) <= 3.0 * disk_px + 0.02 * H_sim)
    assert np.abs(features[..., 1][fired] - sim.features[..., 1][fired]).max() < 0.5
    # the stated tolerance of every feature (dllm.round_trip), the DLLM replayed on the decoded frames
    # giving what mlsim detect wrote
    from dllm.detector import DllmParams
    from dllm.round_trip import agreement, replay

    reference = replay(np.load(d / "lossless.npy"), sim.calibration, DllmParams.from_scene(scene))
    assert np.array_equal(reference.events, sim.events) and np.array_equal(reference.features, sim.features)
    r = agreement(reference, events, features, sim.calibration)
    assert r["event_frames_agree"] == len(events) and all(v <= 1.0 for v in r["worst"].values()), r


@pytest.mark.slow
def test_the_demo_mp4_is_read_within_the_stated_tolerance(cache, tmp_path):
    """The MP4 that ``make demo`` writes (``mlsim run scenes/mavig_default.toml``: camera.mp4, lossy)
    and its calibration frame through ``mlsim detect``, the idle second given as an MP4 of its own
    (the demo's video starts with the episode): every event frame, firing taxel and feature within
    dllm.round_trip's tolerance of the simulated run. 2026-11-27: 22 of 22 frames agree, firing
    Jaccard 0.974, worst over tolerance H 0.71, l 0.26, omega 0.07, a taxel's flip 0.19; about 4 min
    on 2 shared cores from the shipped meshes."""
    from dllm.detector import DllmParams
    from dllm.round_trip import agreement, replay
    from dllm.stage import idle_before
    from mlsim import pipeline
    from mlsim.render.output import write_mp4
    from mlsim.scene import load_scene

    demo = ROOT / "scenes" / "mavig_default.toml"
    assert main(["run", str(demo), "--out", str(tmp_path / "demo"), "--quiet", "--cache", str(cache.root)]) == 0
    scene = load_scene(demo)
    res = pipeline.run(scene, out_dir=None, cache=cache, outputs=("render", "camera", "calibration", "dllm"), progress=False,
                       log=lambda m: None)  # the demo's results, from the cache
    idle = idle_before(scene, res.results["render"])
    write_mp4(tmp_path / "idle.mp4", idle, res.results["camera"].fps)
    assert main(["detect", str(tmp_path / "demo" / "camera.mp4"), "--calibration", str(tmp_path / "demo" / "calibration_frame.png"),
                 "--idle", str(tmp_path / "idle.mp4"), "--scene", str(demo), "--out", str(tmp_path / "detect"), "--quiet"]) == 0
    events, features = _features(tmp_path / "detect")
    sim = res.results["dllm"]
    reference = replay(np.concatenate([idle, res.results["camera"].frames]), sim.calibration, DllmParams.from_scene(scene))
    assert np.array_equal(reference.events, sim.events) and sim.events.sum() >= 5
    r = agreement(reference, events, features, sim.calibration)
    assert all(v <= 1.0 for v in r["worst"].values()), r
    assert r["firing_jaccard"] > 0.9, r


def test_an_idle_recording_may_be_given_apart(simulated, tmp_path):
    """--idle: the thresholds from another recording; every frame of the recording is the episode."""
    scene, sim, d = simulated
    frames = sorted((d / "frames").iterdir(), key=lambda f: int(f.stem[1:]))
    episode, idle = tmp_path / "episode", tmp_path / "idle"
    for folder, files in ((idle, frames[:30]), (episode, frames[30:])):
        folder.mkdir()
        for f in files:
            (folder / f.name).write_bytes(f.read_bytes())
    s = detect_recording(episode, d / "calibration.png", tmp_path / "out", scene=scene, idle=idle, progress=False, log=lambda m: None)
    assert s["frames"] == len(sim.events) and s["fps_from"] == "the scene's camera"
    assert np.array_equal(_features(tmp_path / "out")[0], sim.events)


def test_idle_run_counts_the_frames_before_the_light():
    m = np.full(30, 1000.0)
    assert idle_run(m, 1.05) == 30
    m[17:] = 1051.0  # just over alpha x the darkest
    assert idle_run(m, 1.05) == 17
    m[17:] = 1049.0
    assert idle_run(m, 1.05) == 30
    m[5:] = 3000.0  # most of the window glows: the darkest frame is still the reference
    assert idle_run(m, 1.05) == 5
    assert idle_run([], 1.05) == 0


def test_a_folder_is_read_in_natural_order_and_videos_by_opencv(tmp_path):
    from mlsim.render.output import write_mp4, write_png

    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (12, 48, 64, 3), dtype=np.uint8)
    for k, f in enumerate(frames):
        write_png(tmp_path / f"frame_{k}.png", f)
    rec = open_recording(tmp_path)
    assert rec.kind == "folder" and rec.n_frames == 12 and rec.shape_hw == (48, 64)
    assert np.array_equal(np.stack(list(rec.frames())), frames)  # frame_10 after frame_9
    smooth = np.repeat(np.linspace(20, 200, 64).astype(np.uint8)[None, None, :, None], 48, axis=1).repeat(3, axis=3).repeat(12, axis=0)
    write_mp4(tmp_path / "v.mp4", smooth, 25.0)
    video = open_recording(tmp_path / "v.mp4")
    back = np.stack(list(video.frames()))
    assert video.fps == 25.0 and back.shape == smooth.shape
    # lossy: MPEG-4 part 2 in YUV 4:2:0 shifts the grey ramp by 1-5 DN (colour conversion), but keeps it
    assert np.abs(back.astype(int) - smooth).mean() < 4.0


# --------------------------------------------------------------------------------- bad input
def _grid_photo(n_disks=25, size=350, pitch=67.0, radius=17.0):
    yy, xx = np.mgrid[0:size, 0:size]
    img = np.full((size, size), 40.0)
    centres = [(size / 2 + (j - 2) * pitch, size / 2 + (i - 2) * pitch) for i in range(5) for j in range(5)][:n_disks]
    for cx, cy in centres:
        img[(xx - cx) ** 2 + (yy - cy) ** 2 <= radius**2] = 200.0
    return np.repeat(img.astype(np.uint8)[..., None], 3, axis=2)


def _write_folder(path: Path, frames) -> Path:
    from mlsim.render.output import write_png

    path.mkdir(parents=True, exist_ok=True)
    for k, f in enumerate(frames):
        write_png(path / f"{k:04d}.png", f)
    return path


@pytest.fixture
def inputs(tmp_path):
    """A 5 x 5 calibration photo and 40 dark frames with noise (350 x 350), as files."""
    from mlsim.render.output import write_png

    rng = np.random.default_rng(3)
    photo = write_png(tmp_path / "photo.png", _grid_photo())
    dark = rng.integers(10, 14, (40, 350, 350, 3), dtype=np.uint8)
    return tmp_path, photo, dark


def _run_cli(capsys, *argv) -> tuple[int, str]:
    code = main(["detect", *map(str, argv), "--quiet"])
    err = capsys.readouterr().err
    assert "Traceback" not in err
    return code, err


def test_synthetic_recording_without_a_scene_runs_with_the_defaults(inputs, capsys):
    tmp, photo, dark = inputs
    frames = dark.copy()
    frames[35, 150:200, 150:200] = 250  # a glow on the centre taxel in one frame
    code, _ = _run_cli(capsys, _write_folder(tmp / "rec", frames), "--calibration", photo, "--out", tmp / "out")
    assert code == 0
    events, features = _features(tmp / "out")
    assert events.tolist() == [k == 5 for k in range(10)]
    assert np.flatnonzero(features[5, :, 0]).tolist() == [12]  # row-major: the centre of 5 x 5


def test_an_unreadable_video_exits_2(inputs, capsys):
    tmp, photo, _ = inputs
    bad = tmp / "broken.mp4"
    bad.write_bytes(b"not a video at all" * 100)
    code, err = _run_cli(capsys, bad, "--calibration", photo)
    assert code == 2 and "RECORDING" in err and "cannot decode" in err
    code, err = _run_cli(capsys, tmp / "missing.mp4", "--calibration", photo)
    assert code == 2 and "no such file" in err
    code, err = _run_cli(capsys, _write_folder(tmp / "rec", []), "--calibration", tmp / "nophoto.png")
    assert code == 2 and "without frames" in err


def test_a_frame_size_other_than_the_photo_exits_2(inputs, capsys):
    tmp, photo, dark = inputs
    code, err = _run_cli(capsys, _write_folder(tmp / "rec", dark[:, :300]), "--calibration", photo, "--out", tmp / "out")
    assert code == 2 and "frame 0: 350 x 300 px" in err and "calibration photo" in err


def test_a_photo_without_the_grid_exits_2_with_the_overlay(inputs, capsys):
    from mlsim.render.output import write_png

    tmp, _, dark = inputs
    photo = write_png(tmp / "24.png", _grid_photo(n_disks=24))
    code, err = _run_cli(capsys, _write_folder(tmp / "rec", dark), "--calibration", photo, "--out", tmp / "out")
    assert code == 2 and "found 24 circles, expected 5 x 5 = 25" in err
    assert (tmp / "out" / "calibration_overlay.png").is_file() and "calibration_overlay.png" in err


@pytest.mark.parametrize("case", ["short", "glowing"])
def test_too_few_idle_frames_exit_2(inputs, capsys, case):
    tmp, photo, dark = inputs
    frames = dark[:20] if case == "short" else dark.copy()
    if case == "glowing":
        frames[12:, 100:250, 100:250] = 200  # the press starts at frame 12, inside the first second
    code, err = _run_cli(capsys, _write_folder(tmp / "rec", frames), "--calibration", photo, "--out", tmp / "out")
    assert code == 2 and "too few idle frames" in err
    assert ("it has 20 frames" if case == "short" else "frame 12 is") in err


def test_recording_error_is_a_bad_input():
    from mlsim.errors import SceneError

    err = RecordingError("--fps", -1, "must be a number > 0")
    assert isinstance(err, SceneError) and str(err) == "invalid input: --fps = -1: must be a number > 0"


def test_with_a_model_the_loop_classifies_the_recording_as_the_closed_loop_does(inputs, capsys):
    """--model: classify.csv holds the SPEC 1.7 loop's decisions on the recording's frames after
    its idle second, the same as :func:`classifiers.closed_loop.run_loop` on those frames; windows
    without an event are idle. A file that is not a model exits 2."""
    import csv

    import torch

    from classifiers.closed_loop import run_loop
    from classifiers.interaction_cnn import InteractionCNN
    from classifiers.train import TrainResult, save_model
    from classifiers.windows import DEFAULT_FEATURE_SET, Standardizer, class_names
    from dllm.calibration import calibrate
    from dllm.detector import DllmParams

    tmp, photo, dark = inputs
    frames = dark.copy()
    frames[38:40, 150:200, 140:200] = 250  # the centre taxel glows off-centre in the episode's frames 8 and 9
    net = InteractionCNN(50, 8, generator=torch.Generator().manual_seed(0))  # untrained: the decisions need only be the loop's
    result = TrainResult(net.state_dict(), {"n_channels": 50, "n_classes": 8, "window": 8}, Standardizer(np.zeros(50, np.float32),
                         np.ones(50, np.float32)), DEFAULT_FEATURE_SET, 8, tuple(class_names(8)), 8, 1, {}, 0, 0.0, 0)
    model = save_model(result, tmp / "m.pt")
    code, _ = _run_cli(capsys, _write_folder(tmp / "rec", frames), "--calibration", photo, "--model", model, "--out", tmp / "out")
    assert code == 0
    rows = list(csv.DictReader(open(tmp / "out" / "classify.csv")))
    ref = run_loop(frames[30:], frames[:30], calibrate(_grid_photo()), DllmParams(), result, 30.0)
    assert len(rows) == 10 - 7 == len(ref.classes)  # windows of 8 frames ending at frames 7, 8 and 9
    assert [int(r["class_id"]) for r in rows] == ref.classes.tolist()
    assert [r["class"] == "idle" for r in rows] == [True, False, False]
    (tmp / "bad.pt").write_bytes(b"no model")
    code, err = _run_cli(capsys, tmp / "rec", "--calibration", photo, "--model", tmp / "bad.pt", "--out", tmp / "out2")
    assert code == 2 and "--model" in err
