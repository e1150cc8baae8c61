"""``mlsim calibrate``: a scene overlay for a real sensor from its recordings (issue 41: the calibration
photo, an idle video, a press of known force).

``mlsim calibrate SCENE --photo PHOTO [--idle VIDEO] [--press VIDEO --force-n F] [--set PATH=VALUE] --out DIR``
finds the rods' disks on the calibration photo (SPEC 1.6's Hough calibration,
:func:`dllm.calibration.calibrate`), fits the camera's view to the rods' known layout
(:mod:`mlsim.sensor_view`), with ``--idle`` the camera's dark parameters to the idle recording
(:mod:`mlsim.photon_transfer`), with ``--press`` the ML brightness to the recorded press, simulated
through the fitted camera (:mod:`mlsim.press_brightness`), and writes

- ``DIR/sensor.toml``: a scene overlay, ``scene = "<SCENE>"`` plus the fields the recordings
  determine (the image size; the focal length that reproduces the fitted scale at the scene's
  camera distance; with ``--idle``, the black level and read noise where the 8-bit frames show the
  noise; with ``--press``, ``emission.brightness_photons_per_m2``, whose uncertainty includes the
  fitted focal length's: the light a press shows grows with the magnification), each with its
  uncertainty in a comment, and the list of what they cannot determine (left at the scene's
  values). ``mlsim run DIR/sensor.toml`` runs it;
- ``DIR/calibration_fit.json``: every fitted value, its uncertainty and the residuals per rod;
- ``DIR/calibration_overlay.png``: the circles Hough found on the photo.

The scale is fitted against the paraxial model; the simulator's rendered disks depart from it by a
scale of their own (refraction beyond the paraxial limit and where Hough puts a disk's outline: 0.4 %
on the default sensor at 160 px, 0.9 % with a noisier frame and Hough's threshold at 13 votes), so the
scene's own calibration frame is rendered (cached) and fitted the same way, and the focal length
written is the photo's over that ratio: what makes the overlay's render reproduce the photo. Its
uncertainty combines both fits' (the ratio changed by 0.06 % over lenses 6 % apart, within them).

Not determined, and left at the scene's values: the camera distance (one photo fixes the
magnification, i.e. focal length and distance together), the camera's roll and lateral offset
(measured and reported, but the scene's camera sits on the array's axis), the conversion gain and
dark current (an idle video at one exposure fixes two numbers: taken from the scene, the black level
and read noise follow), the emission model's shape (only the brightness scale is fitted).
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np

__all__ = ["calibrate_sensor", "plan_calibration", "hough_params", "NOT_DETERMINED"]

#: What the photo leaves at the scene's values, and why.
NOT_DETERMINED = {
    "camera.distance_mm": "one photo fixes the magnification (focal length and distance together); the distance is kept, the focal length fitted",
    "camera roll, lateral offset": "measured (calibration_fit.json) but the scene's camera sits on the array's axis: no field for them",
    "camera.conversion_gain_dn_per_e, dark_current_e_per_s": "an idle video at one exposure fixes two numbers (offset, noise): "
                                                              "these are taken from the scene, the black level and read noise fitted",
    "emission.brightness_photons_per_m2": "needs a press of known force (--press VIDEO --force-n F)",
}


def hough_params(scene):
    """Hough's parameters for a photo of the scene's size (:class:`dllm.calibration.HoughParams`)."""
    from dllm.calibration import hough_params_for
    from mlsim.render import rod_disks_px

    # tuned by the scene's paraxial disks (radii 0.6-1.6 times theirs: a lens tens of % off is found);
    # the accumulator threshold (20 votes, chosen on 350 px frames) at most a quarter of a disk's
    # circumference, so that the smaller disks of a smaller image are found (160 px: 11 votes; 9-13
    # find all 25 there, 15 misses one)
    expected = rod_disks_px(scene)
    g, cam = scene.sensor, scene.camera
    p = hough_params_for((cam.height_px, cam.width_px), g.rows, g.cols, scene.dllm.blur_sigma_px, expected=expected)
    return replace(p, accumulator=min(p.accumulator, 0.25 * 2.0 * np.pi * expected[1]))


def calibrate_sensor(photo, scene_path, out_dir, *, idle=None, press=None, force_n=None, cache=None, log=print,
                     overrides: dict | None = None) -> dict:
    """Fit what the calibration photo determines and write the overlay (module docstring); returns
    the fit as a dict (what ``calibration_fit.json`` holds). ``idle``: an idle recording (video or
    folder of frames) at the scene's camera settings. ``press``, ``force_n``: a recorded press (its
    first second idle) of the scene's [load] at this force (N) (:mod:`mlsim.press_brightness`).
    ``cache``: the pipeline's (the scene's own calibration frame and the press are simulated through it).
    ``overrides``: ``--set`` fields ({dotted path: value}) applied to the scene before the fit and
    written into the overlay (a fitted field of the same path wins)."""
    from dllm.calibration import CalibrationError, calibrate
    from mlsim import pipeline
    from mlsim.detect import RecordingError, read_image
    from mlsim.errors import MlsimError
    from mlsim.io import atomic_bytes
    from mlsim.render.optics import camera_params
    from mlsim.scene import load_scene
    from mlsim.sensor_view import fit_view

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    overrides = dict(overrides or {})
    scene = load_scene(scene_path, overrides=overrides)
    rgb = read_image(photo, "--photo")
    size = {"camera.width_px": int(rgb.shape[1]), "camera.height_px": int(rgb.shape[0])}
    view = scene.with_values(size)
    g = scene.sensor
    p = hough_params(view)
    try:
        cal = calibrate(rgb, g.rows, g.cols, p, debug_path=out / "calibration_overlay.png")
    except CalibrationError as exc:
        raise RecordingError("--photo", str(photo), str(exc)) from None
    try:
        fit = fit_view(cal.centres_px, cal.radius_px, view)
    except ValueError as exc:
        raise RecordingError("--photo", str(photo), str(exc)) from None
    # the simulator's own calibration frame of the scene, fitted the same way: the rendered disks
    # depart from the paraxial model by a scale (module docstring), which the focal length written
    # must include so that the overlay's render reproduces the photo
    sim = pipeline.run(view, out_dir=None, cache=cache if cache is not None else pipeline.Cache(), outputs=("calibration",),
                       progress=False, log=lambda m: None).results["calibration"].rgb
    try:
        own = fit_view(calibrate(sim, g.rows, g.cols, p).centres_px, 0.0, view)
    except (CalibrationError, ValueError) as exc:
        raise MlsimError(f"the scene's own calibration frame at {rgb.shape[1]} x {rgb.shape[0]} px: {exc}; render it larger "
                         "(a photo of more pixels) or with more fidelity.render.transport_spp") from None
    f_scene = camera_params(view).focal_length_m * 1e3
    ratio = own.focal_length_mm / f_scene
    f = fit.focal_length_mm / ratio
    f_sigma = f * float(np.hypot(fit.focal_length_sigma_mm / fit.focal_length_mm, own.focal_length_sigma_mm / own.focal_length_mm))
    dark = _dark(idle, view, rgb.shape[:2]) if idle is not None else None
    fitted = {"camera.focal_length_mm": f} | ({"camera.black_level_dn": dark["black_level_dn"], "camera.read_noise_e": dark["read_noise_e"]}
                                              if dark and dark["determinable"] else {})
    if (press is None) != (force_n is None):
        raise RecordingError("--force-n" if press is not None else "--press", force_n if press is not None else None,
                             "give the press recording and its force together: --press VIDEO --force-n F")
    brightness = _brightness(press, force_n, view.with_values(fitted), rgb.shape[:2], cache, f_sigma) if press is not None else None
    result = {"photo": str(photo), "idle": None if idle is None else str(idle), "dark": dark, "brightness": brightness,
              "scene": str(scene_path), "overrides": overrides, "disks": cal.n_taxels, "fit": fit.as_dict(),
              "paraxial_scale_ratio": ratio, "scene_focal_length_mm": f_scene, "focal_length_mm": f, "focal_length_sigma_mm": f_sigma,
              "not_determined": NOT_DETERMINED}
    atomic_bytes(out / "calibration_fit.json", (json.dumps(result, indent=2) + "\n").encode())
    base = os.path.relpath(Path(scene_path).resolve(), out.resolve())
    lines = [
        f"# Scene overlay of a real sensor, written by mlsim calibrate from {Path(photo).name}.",
        f"# {cal.n_taxels} disks; the view fitted to the rods' layout: scale {fit.scale_px_per_m:.6g} +- {fit.scale_sigma:.2g} px/m, "
        f"rms residual {fit.rms_residual_px:.3f} px,",
        f"# roll {fit.roll_deg:.3f} +- {fit.roll_sigma_deg:.3f} deg and offset ({fit.offset_px[0]:.2f}, {fit.offset_px[1]:.2f}) "
        f"+- {fit.offset_sigma_px:.2f} px (not scene fields); disk radius {fit.radius_px:.2f} px measured, "
        f"{fit.predicted_radius_px:.2f} px predicted.",
        "# Not determined here (left at the base scene's values):",
        *[f"#   {k}: {why}" for k, why in NOT_DETERMINED.items()],
        f'scene = "{base}"',
        "",
        "[camera]",
        f"width_px = {size['camera.width_px']}",
        f"height_px = {size['camera.height_px']}",
        f"focal_length_mm = {f:.6f}  # +- {f_sigma:.2g} mm (1 sigma) at distance_mm = {scene.camera.distance_mm:g}",
        *_dark_lines(dark),
        *([] if brightness is None else [
            "",
            "[emission]",
            f"brightness_photons_per_m2 = {brightness['brightness_photons_per_m2']:.6g}  # +- {brightness['sigma']:.2g} (the press of "
            f"{brightness['force_n']:g} N, {len(brightness['iterations'])} simulations, the lens's uncertainty included; "
            "the scene's [load] taken as that press)"]),
        "",
    ]
    lines = _with_overrides(lines, overrides, set(fitted) | set(size) | ({"emission.brightness_photons_per_m2"} if brightness else set()))
    if brightness is not None:
        lines.remove("#   emission.brightness_photons_per_m2: needs a press of known force (--press VIDEO --force-n F)")
    if dark is None:
        lines.insert(lines.index(f'scene = "{base}"'), "#   camera.black_level_dn, read_noise_e: need an idle video (--idle)")
    overlay = atomic_bytes(out / "sensor.toml", "\n".join(lines).encode())
    load_scene(overlay)  # what it wrote loads
    log(f"[calibrate] focal length {f:.4f} +- {f_sigma:.2g} mm, roll {fit.roll_deg:.2f} deg, "
        f"rms residual {fit.rms_residual_px:.2f} px; wrote {overlay}")
    return result


def _with_overrides(lines: list[str], overrides: dict, fitted: set[str]) -> list[str]:
    """The overlay's lines with the ``--set`` fields the fit did not write: top-level keys after
    ``scene = ...``, a field of a table the overlay already has ([camera], [emission]) inside it, the
    others in tables of their own (TOML allows a table once: so no dotted keys at the top)."""
    import json as _json

    def literal(value) -> str:
        if isinstance(value, bool):
            return "true" if value else "false"
        if isinstance(value, (list, tuple)):
            return "[" + ", ".join(literal(v) for v in value) + "]"
        if isinstance(value, dict):
            return "{" + ", ".join(f"{k} = {literal(v)}" for k, v in value.items()) + "}"
        return _json.dumps(value) if isinstance(value, str) else repr(value)

    tables: dict[str, list[str]] = {}
    lines = list(lines)
    for path, value in overrides.items():
        if path in fitted:
            continue
        table, _, leaf = path.rpartition(".")
        line = f"{leaf} = {literal(value)}  # --set"
        if not table:
            lines.insert(next(k for k, ln in enumerate(lines) if ln.startswith("scene = ")) + 1, line)
        elif f"[{table}]" in lines:
            at = lines.index(f"[{table}]") + 1
            while at < len(lines) and lines[at] and not lines[at].startswith("["):
                at += 1
            lines.insert(at, line)
        else:
            tables.setdefault(table, []).append(line)
    for table, body in tables.items():
        lines += [f"[{table}]", *body, ""]
    return lines


def plan_calibration(photo, scene_path, out_dir, *, idle=None, press=None, force_n=None, overrides: dict | None = None) -> str:
    """``mlsim calibrate --dry-run``: the scene loaded, the photo and recordings opened (their first
    frame, their sizes against the photo's), the fits that would run and the files written; runs
    neither Hough nor the render. Bad input raises :class:`mlsim.detect.RecordingError` as the run would."""
    from mlsim.detect import RecordingError, open_recording, read_image
    from mlsim.scene import load_scene

    scene = load_scene(scene_path, overrides=overrides)
    rgb = read_image(photo, "--photo")
    if (press is None) != (force_n is None):
        raise RecordingError("--force-n" if press is not None else "--press", force_n if press is not None else None,
                             "give the press recording and its force together: --press VIDEO --force-n F")
    if force_n is not None and not (np.isfinite(force_n) and force_n > 0):
        raise RecordingError("--force-n", force_n, "must be a force > 0 (N)")
    fits = [f"the camera's view: Hough for {scene.sensor.rows} x {scene.sensor.cols} disks on {photo} ({rgb.shape[1]} x {rgb.shape[0]} px), "
            "the focal length at the scene's camera distance (the scene's own calibration frame rendered at that size, through the stage cache)"]
    for argument, path, what in (("--idle", idle, "black level and read noise"), ("--press", press, f"the ML brightness at {force_n} N")):
        if path is None:
            continue
        rec = open_recording(path, argument)
        if rec.shape_hw != rgb.shape[:2]:
            raise RecordingError(argument, str(path), f"its frames are {rec.shape_hw[1]} x {rec.shape_hw[0]} px, the photo "
                                                      f"{rgb.shape[1]} x {rgb.shape[0]}: record both with the same camera and crop")
        fits.append(f"{what} from {argument} {path} ({rec.kind}, {'?' if rec.n_frames is None else rec.n_frames} frames)")
    return "\n".join([f"calibrate (dry run): scene {scene_path} ('{scene.name}')", *[f"  fit {f}" for f in fits],
                      f"  would write sensor.toml (scene = \"...\" plus the fitted fields), calibration_fit.json, calibration_overlay.png "
                      f"in {out_dir}", "  nothing run"])


def _dark(idle, view, shape_hw) -> dict:
    """The dark parameters of an idle recording (:func:`mlsim.photon_transfer.dark_parameters`)."""
    from mlsim.detect import RecordingError, open_recording
    from mlsim.photon_transfer import dark_parameters, dark_statistics
    from mlsim.render.optics import camera_params

    rec = open_recording(idle, "--idle")
    if rec.shape_hw != tuple(shape_hw):
        raise RecordingError("--idle", str(idle), f"its frames are {rec.shape_hw[1]} x {rec.shape_hw[0]} px, the photo "
                                                  f"{shape_hw[1]} x {shape_hw[0]}: record both with the same camera and crop")
    frames = np.stack(list(rec.frames()))
    if len(frames) < 2:
        raise RecordingError("--idle", str(idle), "fewer than 2 frames: the temporal noise needs at least 2 (1 s: 30)")
    stats = dark_statistics(frames)
    return {"frames": int(len(frames)), "mean_dn8": stats.mean_dn8, "temporal_var_dn8": stats.temporal_var_dn8,
            "temporal_var_sigma": stats.var_sigma} | dark_parameters(stats, camera_params(view))


def _dark_lines(dark) -> list[str]:
    """The overlay's lines of the dark fit: the fields, or why they are left at the scene's values."""
    if dark is None:
        return []
    if not dark["determinable"]:
        lo, hi = dark["black_level_range_dn"]
        return [f"# black_level_dn, read_noise_e not determined from {dark['frames']} idle frames: {dark['why']} "
                f"(black level within [{lo:g}, {hi:g}) DN)"]
    return [f"black_level_dn = {dark['black_level_dn']:.6g}  # +- {dark['black_level_sigma']:.2g} DN (idle video, {dark['frames']} frames)",
            f"read_noise_e = {dark['read_noise_e']:.6g}  # +- {dark['read_noise_sigma']:.2g} e- ({dark['why']})"]


def _brightness(press, force_n, scene, shape_hw, cache, focal_length_sigma_mm: float) -> dict:
    """The ML brightness fitted to a press recording (:func:`mlsim.press_brightness.fit_brightness`), its
    uncertainty including the fitted lens's (``focal_length_sigma_mm``)."""
    from mlsim import pipeline
    from mlsim.detect import RecordingError, open_recording
    from mlsim.press_brightness import fit_brightness

    if not (np.isfinite(force_n) and force_n > 0):
        raise RecordingError("--force-n", force_n, "must be a force > 0 (N)")
    rec = open_recording(press, "--press")
    if rec.shape_hw != tuple(shape_hw):
        raise RecordingError("--press", str(press), f"its frames are {rec.shape_hw[1]} x {rec.shape_hw[0]} px, the photo "
                                                    f"{shape_hw[1]} x {shape_hw[0]}: record both with the same camera and crop")
    try:
        return fit_brightness(np.stack(list(rec.frames())), scene, float(force_n), cache if cache is not None else pipeline.Cache(),
                              focal_length_sigma_mm=focal_length_sigma_mm)
    except ValueError as exc:
        raise RecordingError("--press", str(press), str(exc)) from None
