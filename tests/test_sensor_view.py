"""The camera's view from the calibration photo (mlsim.sensor_view): the similarity fit recovers a
known transform exactly and states honest uncertainties (the z-scores of 400 noisy fits have unit
spread); the focal length that reproduces a paraxial image is recovered; three simulated sensors'
calibration frames with perturbed lenses are fitted back within the stated uncertainty, and so are
their cameras' roll and offset when the photos are turned and shifted."""

from __future__ import annotations

import numpy as np
import pytest

from mlsim.sensor_view import fit_similarity, fit_view


def _transform(m, a, b, t):
    return np.column_stack([t[0] + a * m[:, 0] - b * m[:, 1], t[1] + b * m[:, 0] + a * m[:, 1]])


def test_similarity_fit_is_exact_without_noise_and_honest_with_it():
    rng = np.random.default_rng(11)
    m = np.array([[i, j] for i in range(-2, 3) for j in range(-2, 3)], float) * 7.2e-3
    a, b, t = 8000.0 * np.cos(0.03), 8000.0 * np.sin(0.03), (174.0, 176.5)
    p, cov, res = fit_similarity(m, _transform(m, a, b, t))
    np.testing.assert_allclose(p, [a, b, *t], rtol=1e-12)
    assert np.abs(res).max() < 1e-9
    z = []
    for _ in range(400):
        p, cov, _ = fit_similarity(m, _transform(m, a, b, t) + rng.normal(0.0, 0.3, (25, 2)))
        z.append((p - [a, b, *t]) / np.sqrt(np.diag(cov)))
    z = np.array(z)
    # Student-t with 46 degrees of freedom: spread 1.02; 400 fits give it within about 4 %
    assert np.all(np.abs(z.std(axis=0) - 1.0) < 0.12) and np.all(np.abs(z.mean(axis=0)) < 0.2)
    with pytest.raises(ValueError, match="need N >= 3"):
        fit_similarity(m[:2], m[:2])


def test_the_focal_length_of_a_paraxial_image_is_recovered():
    from mlsim.render import rod_disks_px
    from mlsim.render.optics import camera_params
    from mlsim.scene import Scene

    scene = Scene()
    f0 = camera_params(scene).focal_length_m * 1e3
    for k in (0.9, 1.0, 1.12):
        centres, radius = rod_disks_px(scene.with_values({"camera.focal_length_mm": f0 * k}))
        v = fit_view(centres, radius, scene)
        assert v.focal_length_mm == pytest.approx(f0 * k, rel=1e-7)
        assert abs(v.roll_deg) < 1e-9 and np.abs(v.offset_px).max() < 1e-9 and v.rms_residual_px < 1e-9
        assert v.predicted_radius_px == pytest.approx(radius, rel=1e-6)
    shifted = centres[::-1]  # the same disks in another order: matched to their rods all the same
    assert fit_view(shifted, radius, scene).focal_length_mm == pytest.approx(f0 * 1.12, rel=1e-7)
    with pytest.raises(ValueError, match="24 centres for a sensor of 25 rods"):
        fit_view(centres[:24], radius, scene)


# the default sensor at 160 px with a cheaper bounce trace: three lenses other than the scene's own
PX = 160
SPP = 32
LENS_FACTORS = (0.95, 1.03, 1.06)


@pytest.fixture(scope="module")
def perturbed(cache, tmp_path_factory):
    """(base scene file, [(true focal length mm, calibration photo PNG)]) of three simulated sensors."""
    from pathlib import Path

    from mlsim import pipeline
    from mlsim.render.optics import camera_params
    from mlsim.render.output import write_png
    from mlsim.scene import load_scene

    root = Path(__file__).resolve().parents[1]
    tmp = tmp_path_factory.mktemp("lenses")
    base_file = tmp / "base.toml"
    base_file.write_text(f'scene = "{root / "scenes" / "mavig_default.toml"}"\n[camera]\nwidth_px = {PX}\nheight_px = {PX}\n'
                         f"[fidelity.render]\ntransport_spp = {SPP}\n")
    base = load_scene(base_file)
    f0 = camera_params(base).focal_length_m * 1e3
    out = []
    for k in LENS_FACTORS:
        f = round(f0 * k, 5)
        res = pipeline.run(base.with_values({"camera.focal_length_mm": f}), out_dir=None, cache=cache, outputs=("calibration",),
                           progress=False, log=lambda m: None)
        out.append((f, write_png(tmp / f"photo_{k}.png", res.results["calibration"].rgb)))
    return base_file, out


def test_three_perturbed_lenses_are_fitted_back_within_their_uncertainty(perturbed, cache, tmp_path):
    """Each sensor's focal length within 3 sigma of the stated uncertainty (the Hough centres'
    scatter in the photo's fit and the scene's own frame's), and within 1 %; no roll."""
    from mlsim.sensor_calibration import calibrate_sensor

    base_file, photos = perturbed
    for k, (f_true, photo) in enumerate(photos):
        fit = calibrate_sensor(photo, base_file, tmp_path / str(k), cache=cache, log=lambda m: None)
        assert abs(fit["focal_length_mm"] - f_true) < 3.0 * fit["focal_length_sigma_mm"], (f_true, fit)
        assert abs(fit["focal_length_mm"] / f_true - 1.0) < 0.01
        assert abs(fit["fit"]["roll_deg"]) < 3.0 * fit["fit"]["roll_sigma_deg"] + 1e-6


# the camera's pose: each sensor's photo turned about the image's centre by a roll (deg, OpenCV's
# sense: anticlockwise on screen, so the fitted roll is its negative) and shifted (col, row px)
POSES = ((2.0, (3.0, -2.0)), (-3.0, (-4.0, 1.5)), (1.0, (0.0, 5.0)))


def test_three_turned_and_shifted_cameras_give_back_their_pose(perturbed, cache, tmp_path):
    """The camera's roll and lateral offset (measured, reported in calibration_fit.json; the scene's
    camera has no field for them): the three sensors' photos turned and shifted as a camera mounted
    askew would see them come back within 3 sigma of the applied pose (2026-11-27: 0.2-1.1 sigma,
    roll to 0.07-0.17 deg, offset to 0.07-0.19 px), their focal length unchanged within its sigma."""
    import cv2

    from mlsim.detect import read_image
    from mlsim.render.output import write_png
    from mlsim.sensor_calibration import calibrate_sensor

    base_file, photos = perturbed
    centre = ((PX - 1) / 2.0, (PX - 1) / 2.0)
    for k, ((f_true, photo), (angle, shift)) in enumerate(zip(photos, POSES)):
        M = cv2.getRotationMatrix2D(centre, angle, 1.0)
        M[:, 2] += shift
        turned = cv2.warpAffine(read_image(photo), M, (PX, PX), flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
        png = write_png(tmp_path / f"turned_{k}.png", turned)
        fit = calibrate_sensor(png, base_file, tmp_path / str(k), cache=cache, log=lambda m: None)
        view = fit["fit"]
        assert abs(view["roll_deg"] + angle) < 3.0 * view["roll_sigma_deg"], (angle, view)
        assert np.all(np.abs(np.array(view["offset_px"]) - shift) < 3.0 * view["offset_sigma_px"]), (shift, view)
        assert abs(fit["focal_length_mm"] - f_true) < 3.0 * fit["focal_length_sigma_mm"], (f_true, fit)


def test_the_overlay_loads_and_runs(perturbed, cache, tmp_path, capsys):
    """mlsim calibrate writes an overlay that mlsim run renders: its calibration frame's disks where
    the photo's are (Hough's scatter) at the photo's scale (within the fits' uncertainty)."""
    from dllm.calibration import calibrate
    from mlsim.cli import main
    from mlsim.detect import read_image
    from mlsim.scene import load_scene
    from mlsim.sensor_calibration import hough_params

    base_file, photos = perturbed
    f_true, photo = photos[2]
    assert main(["calibrate", str(base_file), "--photo", str(photo), "--out", str(tmp_path / "cal"), "--cache", str(cache.root)]) == 0
    overlay = tmp_path / "cal" / "sensor.toml"
    scene = load_scene(overlay)
    assert scene.camera.width_px == PX and scene.camera.focal_length_mm == pytest.approx(f_true, rel=0.01)
    assert "not determined" in overlay.read_text().lower()
    assert main(["run", str(overlay), "--outputs", "calibration", "--out", str(tmp_path / "run"), "--quiet", "--cache", str(cache.root)]) == 0
    again = read_image(tmp_path / "run" / "calibration_frame.png")
    params = hough_params(scene)
    first, second = calibrate(read_image(photo), 5, 5, params), calibrate(again, 5, 5, params)
    # Hough's centres sit on a half-pixel grid and scatter by a pixel or so (one of 25 by 3 px once):
    # the median disk within 1 px, and the two frames' fitted scales within their uncertainty
    assert np.median(np.abs(second.centres_px - first.centres_px)) <= 1.0
    s1, s2 = fit_view(first.centres_px, first.radius_px, scene), fit_view(second.centres_px, second.radius_px, scene)
    assert abs(s1.scale_px_per_m - s2.scale_px_per_m) < 3.0 * np.hypot(s1.scale_sigma, s2.scale_sigma)
    assert main(["calibrate", str(base_file), "--photo", str(tmp_path / "none.png")]) == 2
    assert "--photo" in capsys.readouterr().err


def test_a_scene_may_start_from_another(tmp_path):
    """scene = "base.toml": the base's fields, tables merged, this file's values over them; a
    circle of scenes is refused with the field named."""
    from mlsim.scene import SceneError, load_scene

    (tmp_path / "base.toml").write_text('name = "base"\nseed = 3\n[camera]\nwidth_px = 120\ngain_db = 6.0\n[sensor.rod]\nheight_mm = 8.0\n')
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "over.toml").write_text('scene = "../base.toml"\nname = "over"\n[camera]\ngain_db = 3.0\n')
    s = load_scene(tmp_path / "sub" / "over.toml")
    assert (s.name, s.seed, s.camera.width_px, s.camera.gain_db, s.sensor.rod.height_mm) == ("over", 3, 120, 3.0, 8.0)
    (tmp_path / "a.toml").write_text('scene = "b.toml"\n')
    (tmp_path / "b.toml").write_text('scene = "a.toml"\n')
    with pytest.raises(SceneError, match="scene = .*circle"):
        load_scene(tmp_path / "a.toml")
    with pytest.raises(SceneError, match="no such scene file"):
        (tmp_path / "c.toml").write_text('scene = "missing.toml"\n')
        load_scene(tmp_path / "c.toml")


def test_an_idle_video_gives_the_black_level_and_read_noise(perturbed, cache, tmp_path):
    """--idle: an idle recording (PNG frames) of a camera with a perturbed black level and read noise
    at the scene's 30 dB gives them back within 3 stated sigma into the overlay, which loads; at 0 dB
    the overlay says why they are not determined."""
    from mlsim.camera import Camera
    from mlsim.render.optics import camera_params
    from mlsim.render.output import write_png
    from mlsim.scene import load_scene
    from mlsim.sensor_calibration import calibrate_sensor

    base_file, photos = perturbed
    gain30 = tmp_path / "gain30.toml"
    gain30.write_text(f'scene = "{base_file}"\n[camera]\ngain_db = 30.0\n')
    true = load_scene(gain30).with_values({"camera.black_level_dn": 61.0, "camera.read_noise_e": 3.0})
    idle = tmp_path / "idle"
    idle.mkdir()
    frames = Camera(camera_params(true))(np.zeros((30, PX, PX, 3), np.float32), np.random.default_rng(5))
    for k, f in enumerate(frames):
        write_png(idle / f"{k:03d}.png", f)
    fit = calibrate_sensor(photos[0][1], gain30, tmp_path / "out", idle=idle, cache=cache, log=lambda m: None)["dark"]
    assert fit["determinable"]
    assert abs(fit["black_level_dn"] - 61.0) < 3.0 * fit["black_level_sigma"] + 0.05
    assert abs(fit["read_noise_e"] - 3.0) < 3.0 * fit["read_noise_sigma"]
    scene = load_scene(tmp_path / "out" / "sensor.toml")
    assert scene.camera.black_level_dn == pytest.approx(fit["black_level_dn"], abs=1e-3) and scene.camera.gain_db == 30.0
    dark0 = calibrate_sensor(photos[0][1], base_file, tmp_path / "out0", idle=idle, cache=cache, log=lambda m: None)["dark"]
    assert dark0["determinable"]  # the frames are noisy whatever the scene says; at 0 dB they read as more read noise
    still = tmp_path / "still"
    still.mkdir()
    for k, f in enumerate(Camera(camera_params(load_scene(base_file)))(np.zeros((4, PX, PX, 3), np.float32), np.random.default_rng(5))):
        write_png(still / f"{k:03d}.png", f)
    calibrate_sensor(photos[0][1], base_file, tmp_path / "out1", idle=still, cache=cache, log=lambda m: None)
    assert "not determined from 4 idle frames" in (tmp_path / "out1" / "sensor.toml").read_text()
