"""The DLLM on synthetic frames: calibration recovers analytic disks in row-major order; features
recover blobs at known offsets (l within 0.5 px, omega within 1 deg); the gates fire exactly when
the sums cross alpha D and beta B_n; thresholds recover after a lasting change; bad input is refused
with the field named."""

from __future__ import annotations

import copy
import math

import numpy as np
import pytest

from dllm.calibration import Calibration, CalibrationError, calibrate
from dllm.detector import Dllm, DllmParams
from dllm.features import taxel_features, taxel_index, taxel_sums

H = W = 350


def _grid(rows=5, cols=5, pitch=67.0, jitter=0.0, seed=0):
    rng = np.random.default_rng(seed)
    c = np.array([[W / 2 + (j - (cols - 1) / 2) * pitch, H / 2 + (i - (rows - 1) / 2) * pitch] for i in range(rows) for j in range(cols)])
    return c + rng.uniform(-jitter, jitter, c.shape)


def _disks(centres, radius, inside=200.0, outside=40.0, ss=4):
    """An anti-aliased frame of bright disks (ss x ss supersampling per pixel)."""
    o = (np.arange(ss) + 0.5) / ss - 0.5
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    cover = np.zeros((H, W))
    for dy in o:
        for dx in o:
            d2 = np.min([(xx + dx - cx) ** 2 + (yy + dy - cy) ** 2 for cx, cy in centres], axis=0)
            cover += d2 <= radius**2
    img = outside + (inside - outside) * cover / ss**2
    return np.repeat(np.round(img).astype(np.uint8)[..., None], 3, axis=2)


def test_calibration_recovers_the_disks_row_major():
    centres = _grid(jitter=3.0, seed=2)
    cal = calibrate(_disks(centres, 17.0))
    assert cal.n_taxels == 25 and cal.shape_hw == (H, W)
    # row-major: the same order as built; Hough's accumulator (dp = 1) puts centres on a half-pixel grid
    assert np.abs(cal.centres_px - centres).max() < 0.75
    assert cal.radius_px == pytest.approx(17.0, abs=1.0)


def test_calibration_round_trip(tmp_path):
    cal = Calibration(_grid(), 17.25, (H, W))
    back = Calibration.load(cal.save(tmp_path / "cal.json"))
    assert np.array_equal(back.centres_px, cal.centres_px) and back.radius_px == 17.25 and back.shape_hw == (H, W)


def test_a_frame_without_circles_is_refused_with_the_count_and_an_overlay(tmp_path):
    with pytest.raises(CalibrationError, match=r"found no circles, expected 5 x 5 = 25") as info:
        calibrate(np.full((H, W, 3), 30, np.uint8), debug_path=tmp_path / "overlay.png")
    assert info.value.debug_image.is_file()
    with pytest.raises(CalibrationError, match=r"found 24 circles"):
        calibrate(_disks(_grid()[:24], 17.0))


def _blob_frame(cal, offsets_px, angles_deg, sigma=2.5, peak=200.0, background=0.0):
    """Gaussian blobs at c_n + l (cos w, -sin w) (image rows run down), sampled at pixel centres."""
    yy, xx = np.mgrid[0:H, 0:W].astype(float)
    img = np.full((H, W), background)
    for (cx, cy), l, w in zip(cal.centres_px, offsets_px, angles_deg):
        bx, by = cx + l * math.cos(math.radians(w)), cy - l * math.sin(math.radians(w))
        img += peak * np.exp(-((xx - bx) ** 2 + (yy - by) ** 2) / (2 * sigma**2))
    return img


def test_features_recover_known_offsets_and_angles():
    cal = Calibration(_grid(), 20.0, (H, W))
    rng = np.random.default_rng(5)
    l = rng.uniform(2.0, 8.0, 25)
    w = np.arange(25) * 15.0  # 0 to 360 deg, the full circle
    idx = taxel_index(cal)
    img = np.round(_blob_frame(cal, l, w)).astype(np.uint8)  # an 8-bit frame, as the camera gives
    Hs, Sx, Sy = taxel_sums(img, idx)
    z = taxel_features(Hs, Sx, Sy, idx.centres_px, np.ones(25, bool))
    assert np.abs(z[:, 1] - l).max() < 0.5
    dw = (z[:, 2] - w % 360 + 180) % 360 - 180
    assert np.abs(dw).max() < 1.0
    assert np.all((z[:, 2] >= 0) & (z[:, 2] < 360))
    # only the disks' pixels count: N pi R^2 of them
    assert len(idx.pixels) == pytest.approx(25 * math.pi * 20**2, rel=0.01)
    assert np.array_equal(taxel_features(Hs, Sx, Sy, idx.centres_px, np.zeros(25, bool)), np.zeros((25, 3)))


def _idle_detector(alpha=1.25, beta=1.5, level=10):
    cal = Calibration(_grid(), 20.0, (H, W))
    det = Dllm(cal, DllmParams(alpha=alpha, beta=beta, init_frames=4))
    base = np.full((H, W), level, np.uint8)
    for _ in range(4):
        r = det.step(base)
        assert r.initialising and not r.event
    return det, base


def test_global_gate_fires_exactly_above_alpha_D():
    det, base = _idle_detector()
    D = det.D
    assert D == H * W * 10 and det.ready
    need = int(round(0.25 * D))  # alpha D - D, an integer here
    for extra, fires in ((need, False), (need + 1, True)):
        d = copy.deepcopy(det)
        img = base.astype(np.int64).ravel()
        _add(img, np.arange(img.size), extra)
        frame = img.reshape(H, W).astype(np.uint8)
        assert frame.astype(np.int64).sum() == D + extra
        assert d.step(frame).event is fires
    assert det.counts == {"frames": 4, "initialising": 4, "discarded": 0, "events": 0}


def _add(flat, pixels, amount):
    """Add an integer amount of intensity to a frame's pixels, at most 245 per pixel (base 10)."""
    full, rest = divmod(int(amount), 245)
    flat[pixels[:full]] += 245
    flat[pixels[full]] += rest


def test_taxel_gate_fires_exactly_above_beta_B():
    det, base = _idle_detector(alpha=1.0001, beta=1.5)
    B, idx = det.B.copy(), det.index
    extra = 0.5 * B  # beta B - B: an integer here (B = 10 x the disk's pixel count)
    assert np.all(extra == np.round(extra))
    flat = base.astype(np.int64).ravel()
    for n in range(25):  # odd taxels one unit above their threshold, even ones exactly on it
        _add(flat, idx.pixels[idx.starts[n]:], extra[n] + n % 2)
    r = copy.deepcopy(det).step(flat.reshape(H, W).astype(np.uint8))
    assert r.event
    assert np.array_equal(r.taxel_sums, B + extra + np.arange(25) % 2)
    assert (r.features[:, 0] > 0).tolist() == [bool(n % 2) for n in range(25)]


def test_discarded_frames_do_no_feature_work(monkeypatch):
    import dllm.detector as detector

    det, base = _idle_detector()
    calls = []
    monkeypatch.setattr(detector, "taxel_sums", lambda *a: calls.append(1) or taxel_sums(*a))
    for _ in range(10):
        assert not det.step(base).event
    assert calls == [] and det.counts["discarded"] == 10


def test_thresholds_recover_after_the_lights_go_on():
    """A lasting rise of every pixel from 10 to 30: events at first, then absorbed as the update rule
    says (tau ln(dM / ((alpha - 1) D)), 3.5 recover_s here); afterwards a local press still fires
    its taxel, and only it."""
    det, base = _idle_detector(alpha=1.02, beta=1.3, level=10)
    lit = np.full((H, W), 30, np.uint8)
    events = [det.step(lit).event for _ in range(int(30 * 4 * det.params.recover_s))]
    assert events[0] and not events[-1]
    # D follows M with tau = recover_s while the frames are events: exactly j* of them, the first j
    # with D_j = M - (M - D_0)(1 - a)^j >= M / alpha
    a = 1 - math.exp(-1 / (30.0 * det.params.recover_s))
    M, D0 = 30.0 * H * W, 10.0 * H * W
    j_star = math.ceil(math.log((M - M / 1.02) / (M - D0)) / math.log(1 - a))
    assert sum(events) == j_star and not any(events[j_star:])
    assert det.D == pytest.approx(30 * H * W, rel=0.03)
    pressed = lit.copy()
    cx, cy = det.calibration.centres_px[12]
    yy, xx = np.mgrid[0:H, 0:W]
    pressed[((xx - cx) ** 2 + (yy - cy) ** 2 <= 20**2) & (xx > cx)] = 255  # the disk's right half
    r = det.step(pressed)
    assert r.event and r.features[12, 0] > 0 and np.count_nonzero(r.features[:, 0]) == 1
    assert r.features[12, 2] == pytest.approx(0.0, abs=1.0) or r.features[12, 2] == pytest.approx(360.0, abs=1.0)
    # a half disk at 255 against a half at 30: the centroid 4 R / (3 pi) x (255 - 30) / (255 + 30)
    assert r.features[12, 1] == pytest.approx(4 * 20 / (3 * math.pi) * 225 / 285, rel=0.05)


@pytest.mark.parametrize("bad, match", [
    (np.zeros((H, W, 3), np.float32), "dtype float32"),
    (np.full((H, W, 3), np.nan), "NaN"),
    (np.zeros((H, W, 4), np.uint8), r"shape \(350, 350, 4\)"),
    (np.zeros((100, 100, 3), np.uint8), "calibration is of"),
])
def test_bad_frames_are_refused(bad, match):
    det, _ = _idle_detector()
    with pytest.raises(ValueError, match=match):
        det.step(bad)


def test_bad_params_name_the_field():
    with pytest.raises(ValueError, match="DllmParams.alpha"):
        DllmParams(alpha=float("nan"))
    with pytest.raises(ValueError, match="init_frames"):
        DllmParams(init_frames=0)


def test_pipeline_runs_the_detector_on_the_episode_and_writes_its_files(tmp_path, cache):
    """The tiny scene end to end: calibration on its calibration frame finds its 2 x 2 rods near the
    paraxial centres; 1 s of idle frames initialise the thresholds; frames that glow give events and
    the dark ones none; the CSVs and the heatmap are written; the same scene gives the same features."""
    import csv
    from pathlib import Path

    from mlsim import pipeline
    from mlsim.render import rod_disks_px
    from mlsim.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml",
                       {"outputs": ["dllm", "camera"], "camera.width_px": 96, "camera.height_px": 96, "fidelity.render.transport_spp": 8})
    res = pipeline.run(scene, out_dir=tmp_path, cache=cache, progress=False, log=lambda m: None)
    d, cam = res.results["dllm"], res.results["camera"]
    centres, radius = rod_disks_px(scene)
    # taxels are numbered row-major in the image; rods in the sensor's order (mirrored: seen from below)
    dist = np.linalg.norm(d.calibration.centres_px[:, None] - centres[None], axis=2)
    assert dist.min(axis=1).max() < 0.25 * radius
    assert sorted(d.rod_of_taxel.tolist()) == [0, 1, 2, 3] and np.array_equal(d.rod_of_taxel, dist.argmin(axis=1))
    assert d.idle_frames == 30 and d.counts["initialising"] == 30
    assert d.counts["events"] + d.counts["discarded"] == len(cam.frames)
    signal = cam.rod_signal_e.sum(axis=1)
    assert d.events[np.argmax(signal)] and not d.events[signal == 0].any()
    rows = list(csv.DictReader(open(tmp_path / "dllm_features.csv")))
    assert len(rows) == len(cam.frames) and "taxel3_omega_deg" in rows[0]
    assert len(list(csv.DictReader(open(tmp_path / "dllm_events.csv")))) == int(d.events.sum())
    assert (tmp_path / "dllm_heatmap.png").stat().st_size > 10_000
    # the same scene and seed from the same mesh (fTetWild's are not reproducible): the same features
    fresh = pipeline.Cache(tmp_path / "c2")
    mesh_key = pipeline.stage_key(scene, "mesh")
    fresh.store(pipeline.STAGES["mesh"], mesh_key, cache.fetch(pipeline.STAGES["mesh"], mesh_key))
    again = pipeline.run(scene.with_values({"outputs": ["dllm"]}), out_dir=None, cache=fresh, progress=False, log=lambda m: None)
    assert np.array_equal(again.results["dllm"].features, d.features)


def test_image_angles_turn_into_sensor_directions_through_the_optics():
    """A light offset towards a rod's +x side in the sensor appears towards image -x (the camera looks
    up: mirrored columns), so omega = 180 deg there and the sensor direction is 0; +y is image up."""
    from pathlib import Path

    from dllm.direction import sensor_angle_deg, wrap_deg
    from mlsim.render import rod_disks_px
    from mlsim.render.optics import view_of
    from mlsim.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_default.toml")
    centres, _ = rod_disks_px(scene)
    # rods 0 and 1 are neighbours along +x in the sensor; rods 0 and 5 along +y
    dx_img = centres[1] - centres[0]
    dy_img = centres[5] - centres[0]
    omega_x = math.degrees(math.atan2(-dx_img[1], dx_img[0])) % 360
    omega_y = math.degrees(math.atan2(-dy_img[1], dy_img[0])) % 360
    assert sensor_angle_deg(omega_x) == pytest.approx(0.0, abs=1e-9) or sensor_angle_deg(omega_x) == pytest.approx(360.0)
    assert sensor_angle_deg(omega_y) == pytest.approx(90.0, abs=1e-9)
    assert wrap_deg([190.0, -190.0, 180.0]).tolist() == [-170.0, 170.0, 180.0]
    assert view_of(scene).width_px == 350


def test_direction_study_turns_with_the_push(tmp_path, cache):
    """Invariance on the symmetric 2 x 2 sensor pushed at its centre: pushing the opposite way turns
    the DLLM's direction over every firing taxel by 180 deg (within 30); the sphere, sliding from the
    centre, pushes the two rods it moves towards (the other two in the opposite push); the study
    writes its table (with the approach bearing, applied + 180) and plot."""
    from pathlib import Path

    from dllm.direction import wrap_deg
    from mlsim.scene import load_scene
    from mlsim.studies.direction import direction_study

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml",
                       {"camera.width_px": 96, "camera.height_px": 96, "fidelity.render.transport_spp": 8})
    rows = direction_study(scene, [90.0, 270.0], tmp_path, cache, progress=False, log=lambda m: None)
    assert all(r.events > 0 and r.push_events > 0 and r.samples > 0 for r in rows)
    assert [r.approach_deg for r in rows] == [270.0, 90.0]
    assert len(rows[0].taxels) == 2 and sorted(rows[0].taxels + rows[1].taxels) == [0, 1, 2, 3]
    assert abs(wrap_deg(rows[1].measured_all_deg - rows[0].measured_all_deg)) == pytest.approx(180.0, abs=30.0)
    assert (tmp_path / "direction.png").stat().st_size > 10_000
    lines = (tmp_path / "direction.csv").read_text().splitlines()
    assert len(lines) == 3 and lines[0].startswith("applied_deg,approach_deg,measured_deg,error_deg")


def test_the_direction_estimate_reads_the_pushed_taxels_in_the_push_frames():
    """dllm.direction's pieces on made-up features: frames overlap the push by their exposure
    windows; a rod is pushed at half the largest rod's force; the H l-weighted circular mean of
    the chosen samples (across 0/360), and the approach bearing is the motion's opposite."""
    from dllm.direction import approach_deg, episode_direction, push_frames, pushed_taxels, sensor_angle_deg, wrap_deg

    windows = np.array([[0.0, 0.033], [0.033, 0.066], [0.066, 0.099], [0.099, 0.132]])
    assert push_frames(windows, 0.05, 0.1).tolist() == [False, True, True, True]
    assert push_frames(windows, 0.033, 0.066).tolist() == [False, True, False, False]  # touching ends do not count
    force = np.zeros((4, 3, 3))
    force[1:, 0, 2] = [1.0, 2.0, 2.0]  # rod 0 pushed
    force[1:, 1, 0] = [0.0, 0.9, 1.1]  # rod 1: 0.55 of it -> pushed
    force[0, 2, 2] = 5.0  # rod 2: only outside the push frames
    assert pushed_taxels(force, [False, True, True, True], rod_of_taxel=np.array([2, 0, 1])).tolist() == [1, 2]
    assert pushed_taxels(force, [False, True, True, True], rod_of_taxel=np.array([2, 0, 1]), share=0.6).tolist() == [1]
    assert pushed_taxels(np.zeros((2, 3, 3)), [True, True], np.arange(3)).size == 0
    # sensor directions 350 and 10 deg on taxel 0 (equal weights) average to 0; taxel 1 is left out
    omega = lambda theta: (180.0 - theta) % 360.0  # noqa: E731 (the inverse of sensor_angle_deg)
    features = np.zeros((3, 2, 3))
    features[0, 0] = [1.0, 2.0, omega(350.0)]
    features[1, 0] = [2.0, 1.0, omega(10.0)]
    features[1, 1] = [9.0, 9.0, omega(90.0)]
    features[2, 0] = [9.0, 9.0, omega(180.0)]  # not an event frame
    mean, theta, w = episode_direction(features, np.array([True, True, False]), taxels=[0])
    assert wrap_deg(mean) == pytest.approx(0.0, abs=1e-9) and sorted(np.round(theta, 9) % 360) == [10.0, 350.0]
    assert np.all(sensor_angle_deg(omega(np.array([0.0, 90.0, 271.0]))) == [0.0, 90.0, 271.0])
    assert approach_deg([0.0, 90.0, 270.0]).tolist() == [180.0, 270.0, 90.0]
    assert np.isnan(episode_direction(features, np.zeros(3, bool))[0])


def test_ambient_study_false_triggers_follow_the_lights_on_jump(tmp_path, cache):
    """A strong lamp over a sensor without its absorber, switched on during the idle episode: the
    first lit frame raises M by a factor J over D; it is a false trigger exactly when alpha < J. The
    study's table, recommendation (no false trigger anywhere) and heatmaps follow."""
    from pathlib import Path

    from dllm.calibration import grey
    from mlsim.scene import load_scene
    from mlsim.studies.ambient import _frames, ambient_study

    scene = load_scene(Path(__file__).resolve().parents[1] / "scenes" / "mavig_tiny.toml",
                       {"camera.width_px": 96, "camera.height_px": 96, "fidelity.render.transport_spp": 8})
    lights_on = {"ambient.lamp": "white_led", "ambient.power_w": 100.0, "optics.absorber": "none", "ambient.switch_on_s": 0.1}
    settings = {"dark": {"ambient.lamp": "none"}, "lights on": lights_on}
    # the jump J of the first frame exposed after the switch, against the idle baseline D (pre-roll mean)
    cam, idle, pre, _ = _frames(scene.with_values(lights_on), cache, False)
    M = np.array([float(grey(f).astype(np.int64).sum()) for f in idle])
    D = np.mean([float(grey(f).astype(np.int64).sum()) for f in pre])
    first = int(np.flatnonzero(cam.windows_s[:, 0] >= 0.1)[0])
    J = M[first] / D
    assert 1.05 < J < 5.0, J
    alphas = (1.01, round(0.5 * (1 + J), 3), round(1.2 * J, 3))
    rows, rec = ambient_study(scene, settings, alphas=alphas, betas=(1.3,), out_dir=tmp_path, cache=cache, progress=False, log=lambda m: None)
    false = {r.alpha: r.false_rate for r in rows if r.setting == "lights on"}
    assert false[alphas[0]] > 0 and false[alphas[1]] > 0 and false[alphas[2]] == 0.0
    assert all(r.false_rate == 0.0 for r in rows if r.setting == "dark")
    assert rec["alpha"] == alphas[2] and rec["per_setting"]["lights on"]["false_rate"] == 0.0
    assert len((tmp_path / "ambient_study.csv").read_text().splitlines()) == 1 + 2 * 3
    assert (tmp_path / "ambient_lights_on.png").stat().st_size > 10_000


def test_ambient_settings_start_from_the_scenes_ambient_reset():
    """Each setting of the ambient study is exactly the lamp it names: a scene's own flicker and switching
    (scenes/ambient.toml) do not leak into the steady lamp's setting; the scene's own lamp comes first. On a
    scene without a lamp a setting's scene is the plain override (the same cache keys as before)."""
    from pathlib import Path

    from mlsim.scene import load_scene
    from mlsim.studies.ambient import DEFAULT_SETTINGS, SCENE_SETTING, setting_scenes

    scenes = Path(__file__).resolve().parents[1] / "scenes"
    lamp = load_scene(scenes / "ambient.toml")
    settings = setting_scenes(lamp)
    assert list(settings) == [SCENE_SETTING, *DEFAULT_SETTINGS] and settings[SCENE_SETTING] is lamp
    assert (lamp.ambient.flicker_hz, lamp.ambient.switch_on_s) == (100.0, 0.35)
    steady = settings["daylight 50 W"].ambient
    assert (steady.lamp, steady.power_w, steady.flicker_hz, steady.switch_on_s) == ("daylight", 50.0, 0.0, None)
    assert settings["dark"].ambient.lamp == "none" and settings["daylight 50 W switched on at 0.2 s"].ambient.switch_on_s == 0.2
    tiny = load_scene(scenes / "mavig_tiny.toml")
    plain = setting_scenes(tiny)
    assert SCENE_SETTING not in plain
    assert all(plain[n].content_hash() == tiny.with_values(o).content_hash() for n, o in DEFAULT_SETTINGS.items())
