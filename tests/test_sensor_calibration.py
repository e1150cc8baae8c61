"""``mlsim calibrate`` end to end (issue 41): three simulated sensors, each with its lens, black level,
read noise and phosphor brightness perturbed at once, recorded as a real sensor would be (a lit
calibration photo, an idle video, a press of known force, PNG frames with their own camera noise),
are fitted back by the command; every parameter the recordings determine comes back within 3 of its
stated standard uncertainties, and the overlay it writes runs with ``mlsim run`` and shows the
recorded press's light.

The sensor is the tiny scene's 2 x 2 corner at 96 px (the shipped mesh; a press and the lens's
reprojection cost seconds). Its camera runs at 30 dB: at the default 0 dB every idle pixel is the
same 8-bit code and the read noise cannot be seen (tests/test_photon_transfer.py), and its phosphor
is dimmed by the same 30 dB so that the press stays far from clipping. The lens is the loosest fit
(4 disks on 96 px: 2-3 %), and the brightness's uncertainty carries it (the light grows with the
magnification: mlsim.press_brightness, "The lens"): without it the first sensor's brightness was
7.3 % off, 7.6 of the light's sigma; with it 1.4 sigma."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
GAIN_DB = 30.0
FORCE_N = 0.3
# (lens factor, black level DN, read noise e-, brightness factor): each sensor differs from the
# scene in all four, in both directions
SENSORS = ((0.96, 44.0, 2.2, 0.75), (1.03, 61.0, 3.0, 1.3), (1.06, 72.0, 1.5, 1.6))


def _base_text(brightness: float) -> str:
    return (f'scene = "{ROOT / "scenes" / "mavig_tiny.toml"}"\noutputs = ["camera"]\n[camera]\nwidth_px = 96\nheight_px = 96\n'
            f"gain_db = {GAIN_DB}\n[emission]\nbrightness_photons_per_m2 = {brightness:.6g}\n[fidelity.render]\ntransport_spp = 8\n"
            "[load]\nstart_gap_mm = 0.1\nstart_xy_mm = [3.6, 3.6]\n[load.indenter]\nshape = \"sphere\"\ndiameter_mm = 6.0\n"
            f'[[load.segments]]\nkind = "press"\nforce_n = {FORCE_N}\nduration_s = 0.15\n'
            '[[load.segments]]\nkind = "hold"\nduration_s = 0.1\n')


@pytest.fixture(scope="module")
def recordings(cache, tmp_path_factory):
    """(base scene file, [(true values {field: value}, photo PNG, idle folder, press folder)])."""
    from mlsim import pipeline
    from mlsim.press_brightness import simulated_light
    from mlsim.render.optics import camera_params
    from mlsim.render.output import write_png
    from mlsim.scene import load_scene

    tmp = tmp_path_factory.mktemp("sensors")
    nominal = load_scene(ROOT / "scenes" / "mavig_tiny.toml").emission.brightness_photons_per_m2
    base_file = tmp / "base.toml"
    base_file.write_text(_base_text(nominal / 10.0 ** (GAIN_DB / 20.0)))
    base = load_scene(base_file)
    f0, b0 = camera_params(base).focal_length_m * 1e3, base.emission.brightness_photons_per_m2
    out = []
    for k, (lens, black, read_e, bright) in enumerate(SENSORS):
        true = {"camera.focal_length_mm": round(f0 * lens, 5), "camera.black_level_dn": black, "camera.read_noise_e": read_e,
                "emission.brightness_photons_per_m2": b0 * bright}
        real = base.with_values(true | {"noise_seed": 200 + k})
        photo = write_png(tmp / f"photo{k}.png", pipeline.run(real, out_dir=None, cache=cache, outputs=("calibration",), progress=False,
                                                              log=lambda m: None).results["calibration"].rgb)
        _, _, frames = simulated_light(real, cache)  # the idle second, then the press
        folders = []
        for name, part in (("idle", frames[:30]), ("press", frames)):
            folder = tmp / f"{name}{k}"
            folder.mkdir()
            for j, f in enumerate(part):
                write_png(folder / f"{j:03d}.png", f)
            folders.append(folder)
        out.append((true, photo, *folders))
    return base_file, out


@pytest.mark.parametrize("k", range(len(SENSORS)))
def test_each_determinable_parameter_is_recovered_and_the_overlay_runs(recordings, cache, tmp_path, k):
    from mlsim.cli import main
    from mlsim.detect import read_image
    from mlsim.press_brightness import _dn10_per_e, light_sum
    from mlsim.scene import load_scene

    base_file, sensors = recordings
    true, photo, idle, press = sensors[k]
    assert main(["calibrate", str(base_file), "--photo", str(photo), "--idle", str(idle), "--press", str(press), "--force-n", str(FORCE_N),
                 "--out", str(tmp_path / "cal"), "--cache", str(cache.root), "--quiet"]) == 0
    fit = json.loads((tmp_path / "cal" / "calibration_fit.json").read_text())
    dark, bright = fit["dark"], fit["brightness"]
    assert dark["determinable"], dark["why"]
    measured = {"camera.focal_length_mm": (fit["focal_length_mm"], fit["focal_length_sigma_mm"]),
                "camera.black_level_dn": (dark["black_level_dn"], dark["black_level_sigma"]),
                "camera.read_noise_e": (dark["read_noise_e"], dark["read_noise_sigma"]),
                "emission.brightness_photons_per_m2": (bright["brightness_photons_per_m2"], bright["sigma"])}
    for field, (value, sigma) in measured.items():
        assert 0 < sigma and abs(value - true[field]) < 3.0 * sigma, (field, value, sigma, true[field])
    # the uncertainties are those of these recordings, not blanket ones: the lens to a few per cent
    # (4 disks on 96 px), the dark parameters to a fraction of a per cent (30 frames of 96 x 96 px)
    assert fit["focal_length_sigma_mm"] < 0.05 * true["camera.focal_length_mm"]
    assert dark["read_noise_sigma"] < 0.01 * true["camera.read_noise_e"] and dark["black_level_sigma"] < 0.05
    assert 0 < bright["sigma_lens"] and bright["sigma"] < 0.1 * true["emission.brightness_photons_per_m2"]
    # the overlay holds every fitted value and runs: its press shows the recorded light
    overlay = load_scene(tmp_path / "cal" / "sensor.toml")
    for field, (value, sigma) in measured.items():
        assert overlay.get(field) == pytest.approx(value, rel=1e-5), field
    assert main(["run", str(tmp_path / "cal" / "sensor.toml"), "--outputs", "camera", "--out", str(tmp_path / "run"), "--quiet",
                 "--cache", str(cache.root)]) == 0
    recorded = np.stack([read_image(f) for f in sorted(press.iterdir())])
    ran = np.stack([read_image(f) for f in sorted((tmp_path / "run" / "frames").iterdir())])
    assert ran.shape == recorded[30:].shape
    L_rec, s_rec = light_sum(recorded, 30, _dn10_per_e(overlay))
    L_run, s_run = light_sum(np.concatenate([recorded[:30], ran]), 30, _dn10_per_e(overlay))  # above the recorded idle level
    assert abs(L_run - L_rec) < 3.0 * np.hypot(s_rec, s_run), (L_run, L_rec, s_rec, s_run)
