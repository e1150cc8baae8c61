"""The CLS kind's stages: ``cls_signals`` (trajectory -> the pairs' voltages, with the pairs' true
coefficients), ``cls_calibrate`` (batch calibration of the coefficients from a 37 s trajectory of
measured poses) and ``cls_estimate`` (voltages -> motion detection, LM pose estimates with the
chosen coefficients, errors against the reference poses, force through the foam law). Heavy
imports (numba kernels, matplotlib) happen inside the stages' functions."""

from __future__ import annotations

import io
import json
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.stage import Stage, pickle_load, pickle_save

__all__ = ["SIGNALS", "CALIBRATE", "ESTIMATE", "layout_of", "true_layout_of", "clean_voltages", "measured_voltages", "foam_of",
           "settings_of", "DEFLECTION_BINS_MM", "TRUTH_NOTES",
           "deflection", "error_table", "error_table_markdown", "error_table_csv", "SPEC_NOTE"]

# Deflection ranges (mm, the largest displacement of an LED from rest: :func:`deflection`) the error
# table is split by: the seed's hardware table's (D < 5, 5-10, 10-15, > 15 mm).
DEFLECTION_BINS_MM = (0.0, 5.0, 10.0, 15.0, float("inf"))


def layout_of(sensor):
    """The layout with the nominal coefficients (what a designer knows)."""
    from other_sensors.cls.ltv import default_layout

    p = sensor.pairs
    return default_layout(p.n, p.pitch_mm, p.stagger_mm, p.gap_mm, p.coefficients)


def true_layout_of(sensor, seed: int):
    """The layout as built: each pair's true coefficients, the nominal ones with the part-to-part
    spread (``sensor.pairs.coefficient_spread``, the scene's seed, stream 2), and its LED's and LTV's
    true mounting poses, the designed ones with the mounting spread (``position_spread_mm``,
    ``tilt_spread_deg``, stream 5)."""
    import numpy as np

    from other_sensors.cls.calibration import mount_params, with_mounts

    nominal = layout_of(sensor)
    rng = np.random.default_rng([seed, 2])
    scale = np.abs(nominal.coeffs)
    scale[:, 1] = 20.0  # c2 is nominally 0 mm: its spread is relative to 20 mm
    spread = sensor.pairs.coefficient_spread * rng.standard_normal(nominal.coeffs.shape)
    params = mount_params(nominal, nominal)
    params[:, :7] += spread * scale
    mount = np.random.default_rng([seed, 5]).standard_normal((nominal.n_pairs, 10))
    sd = np.r_[np.full(3, sensor.pairs.position_spread_mm), np.full(2, np.tan(np.radians(sensor.pairs.tilt_spread_deg)))]
    params[:, 7:] += mount * np.r_[sd, sd]
    return with_mounts(nominal, params)


def clean_voltages(sensor, pose3, built):
    """Noise-free voltages (N, P) V of planar poses (N, 3) on the as-built layout ``built``: the
    optical truth when the sensor has an ``optics`` section, else the estimator's own law."""
    from other_sensors.cls.ltv import planar_voltages

    if sensor.optics is None:
        return planar_voltages(pose3, built)
    from other_sensors.cls.optics import optical_voltages

    return optical_voltages(pose3, built, layout_of(sensor), sensor.optics.optics())


def measured_voltages(sensor, pose3, built, rng):
    """(readings, clean) (N, P) V: :func:`clean_voltages` with the scene's noise and ADC (``rng``)."""
    from other_sensors.cls.shell import digitise

    clean = clean_voltages(sensor, pose3, built)
    return digitise(clean, sensor.noise.rms_mv, rng, sensor.noise.adc_bits, sensor.noise.adc_range_v), clean


def foam_of(sensor):
    from other_sensors.cls.shell import Foam

    f = sensor.foam
    return Foam(f.height_mm, f.section_mm2, f.young_kpa, f.stiffening_strain, tuple(f.pillar_y_mm))


def settings_of(sensor):
    from other_sensors.cls.estimator import LmSettings

    return LmSettings(**sensor.estimator.model_dump(exclude={"coefficients"}))


# ------------------------------------------------------------------------------------ cls_signals
def _signals(scene, inputs, ctx):
    import numpy as np

    from other_sensors.cls.shell import trajectory

    s = scene.sensor
    tr, noise = s.trajectory, s.noise
    layout = true_layout_of(s, scene.seed)
    n = int(round(tr.duration_s * tr.rate_hz))
    t = np.arange(n) / tr.rate_hz
    # independent streams for the motion and the noise, both from the scene's seed
    motion_rng, noise_rng = (np.random.default_rng([scene.seed, k]) for k in (0, 1))
    pose = trajectory(tr.shape, t, tr.rest_s, s.pairs.gap_mm, tr.compression_mm, tr.shear_mm, tr.rotation_deg,
                      tr.frequency_hz, motion_rng)
    volts, clean = measured_voltages(s, pose, layout, noise_rng)
    ctx.log(f"cls_signals: {n} samples of {layout.n_pairs} pairs at {tr.rate_hz:g} Hz ({tr.shape})")
    return {"t_s": t, "pose": pose, "voltages": volts, "clean": clean, "n_rest": int(tr.rest_s * tr.rate_hz),
            "rate_hz": float(tr.rate_hz), "reference_every": max(1, int(round(tr.rate_hz / tr.reference_rate_hz)))}


def _csv(header: list[str], columns, fmt: str = "%.6g") -> bytes:
    import numpy as np

    buf = io.StringIO()
    np.savetxt(buf, np.column_stack(columns), delimiter=",", header=",".join(header), comments="", fmt=fmt)
    return buf.getvalue().encode()


def _write_signals(result, out_dir: Path, ctx) -> list[Path]:
    import numpy as np

    v = result["voltages"]
    header = ["t_s", "y_mm", "z_mm", "rx_deg"] + [f"v{i + 1}_V" for i in range(v.shape[1])]
    pose = result["pose"]
    cols = [result["t_s"], pose[:, 0], pose[:, 1], np.degrees(pose[:, 2]), *v.T]
    return [atomic_bytes(out_dir / "cls_signals.csv", _csv(header, cols, "%.7g"))]


def _summarize_signals(result) -> dict:
    import numpy as np

    n = result["n_rest"]
    rest_noise = result["voltages"][:n] - result["clean"][:n]
    return {"samples": int(len(result["t_s"])), "pairs": int(result["voltages"].shape[1]),
            "rest_noise_rms_mv": float(np.sqrt(np.mean(rest_noise ** 2)) * 1e3),
            "v_min_V": float(result["voltages"].min()), "v_max_V": float(result["voltages"].max())}


SIGNALS = Stage(name="cls_signals", version="3", doc="the shell's trajectory and the pairs' voltages (noise, ADC)",
                reads=("sensor.pairs", "sensor.trajectory", "sensor.noise", "sensor.optics", "seed"),
                needs=(), run=_signals,
                save=pickle_save, load=pickle_load, write=_write_signals, summarize=_summarize_signals)


# ---------------------------------------------------------------------------------- cls_calibrate
def _calibrate(scene, inputs, ctx):
    import numpy as np

    from other_sensors.cls.calibration import CalibrationSettings, calibrate, mount_params, tolerances
    from other_sensors.cls.shell import trajectory

    s = scene.sensor
    cal, tr, noise = s.calibration, s.trajectory, s.noise
    true = true_layout_of(s, scene.seed)
    t = np.arange(int(round(cal.duration_s * cal.rate_hz))) / cal.rate_hz
    # the calibration run's own streams (3: motion, 4: noise); the reference poses are taken as exact
    poses = trajectory("general", t, min(0.25, cal.duration_s / 10), s.pairs.gap_mm, tr.compression_mm, tr.shear_mm,
                       tr.rotation_deg, tr.frequency_hz, np.random.default_rng([scene.seed, 3]))
    volts, _ = measured_voltages(s, poses, true, np.random.default_rng([scene.seed, 4]))
    # what the motion capture reports: the poses with its own noise (stream 6)
    mocap = np.random.default_rng([scene.seed, 6]).standard_normal(poses.shape)
    poses = poses + mocap * [cal.mocap_noise_mm, cal.mocap_noise_mm, np.radians(cal.mocap_noise_deg)]
    settings = CalibrationSettings(tau=cal.tau, theta_max_deg=cal.theta_max_deg, r_min_mm=cal.r_min_mm,
                                   r_max_mm=s.estimator.r_max_mm, v_max_v=cal.v_max_v, fit_mounting=cal.fit_mounting,
                                   noise_rms_mv=max(noise.rms_mv, 1e-3))
    nominal = layout_of(s)
    fit = calibrate(poses, volts, nominal, settings)
    result = {"layout": fit.layout, "coeffs": fit.coeffs, "params": fit.params, "true": mount_params(true, nominal),
              "nominal": mount_params(nominal, nominal), "tolerance": tolerances(nominal.coeffs.mean(axis=0), settings),
              "iterations": fit.iterations, "rms_mv": fit.rms_mv, "used": fit.used, "singular": fit.singular,
              "crlb": fit.crlb, "weak": fit.weak, "directions": fit.directions}
    report = _calibration_report(result)
    ctx.log(f"cls_calibrate: {len(t)} poses; residual {np.round(fit.rms_mv, 3).tolist()} mV RMS per pair")
    ctx.log(_identifiability_text(report))
    return result


def _calibration_report(result) -> dict:
    """The calibration as JSON: per pair and parameter the nominal, true and fitted values, the error
    and the Cramer-Rao bound in tolerance units, and what is not identifiable (see calibration.py)."""
    import numpy as np

    from other_sensors.cls.calibration import PARAM_NAMES

    tol = result["tolerance"]
    err = (result["params"] - result["true"]) / tol
    crlb = np.where(np.isfinite(result["crlb"]), result["crlb"], None)
    weak_all = sorted(set.intersection(*(set(w) for w in result["weak"])), key=PARAM_NAMES.index) if result["weak"] else []
    fitted = [name for k, name in enumerate(PARAM_NAMES) if not np.all(np.isnan(result["crlb"][:, k]))]
    return {"parameters": list(PARAM_NAMES), "fitted_parameters": fitted, "tolerance": tol.tolist(), "nominal": result["nominal"].tolist(),
            "true": result["true"].tolist(), "fitted": result["params"].tolist(),
            "error_over_tolerance": err.tolist(), "crlb_std_over_tolerance": crlb.tolist(),
            "error_over_crlb": np.where(np.isfinite(result["crlb"]), err / np.where(np.isfinite(result["crlb"]), result["crlb"], 1.0),
                                        None).tolist(),
            "residual_rms_mv": result["rms_mv"].tolist(), "iterations": result["iterations"].tolist(),
            "samples_used": result["used"].tolist(), "relative_singular_values": result["singular"].tolist(),
            "not_identifiable": result["weak"], "not_identifiable_in_every_pair": weak_all,
            "weak_directions": [[{"relative_singular_value": sv, "components": comp} for sv, comp in pair]
                                for pair in result["directions"]],
            "why": ("x positions and x tilts: the planar (y, z, theta_x) motion is mirror-symmetric in x, so the "
                    "voltages are even in them and their Jacobian columns vanish; the other entries of "
                    "not_identifiable have a Cramer-Rao std (at the noise) above their tolerance: they trade along "
                    "weak_directions (e.g. c2, c3, c7; c5, c6, c1)")}


def _identifiability_text(report) -> str:
    import numpy as np

    names = report["parameters"]
    crlb = np.array([[np.inf if c is None else c for c in row] for row in report["crlb_std_over_tolerance"]])
    err = np.abs(np.array(report["error_over_tolerance"]))
    lines = ["cls_calibrate: identifiability (Cramer-Rao std at the noise, and |fitted - true|, over the tolerance; max over pairs;",
             "  identifiable: std <= tolerance; x parameters: zero Jacobian columns, planar motion is mirror-symmetric in x)",
             f"  {'parameter':<12}{'tolerance':>10}{'crlb/tol':>10}{'|err|/tol':>10}  identifiable"]
    for k, name in enumerate(names):
        if name not in report["fitted_parameters"]:
            continue
        c = crlb[:, k].max()
        lines.append(f"  {name:<12}{report['tolerance'][k]:>10.4g}{c:>10.3g}{err[:, k].max():>10.3g}  {'yes' if c <= 1 else 'NO'}")
    for i, sv in enumerate(report["relative_singular_values"]):
        sv = np.asarray(sv)
        lines.append(f"  pair {i + 1}: rank {int(np.sum(sv > 1e-12))} of {len(sv)}; singular values / largest: "
                     + " ".join(f"{x:.1e}" for x in sv))
    for sv_comp in report["weak_directions"][0]:
        lines.append(f"  weak direction (pair 1): singular value {sv_comp['relative_singular_value']:.2e} of the largest, "
                     f"{sv_comp['components']}")
    return "\n".join(lines)


def _write_calibration(result, out_dir: Path, ctx) -> list[Path]:
    report = _calibration_report(result)
    return [atomic_bytes(out_dir / "cls_calibration.json", json.dumps(report, indent=2).encode()),
            atomic_bytes(out_dir / "cls_identifiability.txt", (_identifiability_text(report) + "\n").encode())]


def _summarize_calibration(result) -> dict:
    report = _calibration_report(result)
    return {k: report[k] for k in ("residual_rms_mv", "iterations", "not_identifiable_in_every_pair")}


CALIBRATE = Stage(name="cls_calibrate", version="3", doc="batch LM calibration of each pair's coefficients and mounting poses from a 37 s trajectory of measured poses",
                  reads=("sensor.pairs", "sensor.calibration", "sensor.noise", "sensor.optics", "sensor.estimator.r_max_mm", "sensor.trajectory.compression_mm",
                         "sensor.trajectory.shear_mm", "sensor.trajectory.rotation_deg", "sensor.trajectory.frequency_hz", "seed"),
                  needs=(), run=_calibrate, save=pickle_save, load=pickle_load, write=_write_calibration, summarize=_summarize_calibration)


# ----------------------------------------------------------------------------------- cls_estimate
# SPEC 3's reference figures (the hardware's, not per deflection range): printed beside the table,
# never used as outputs (SPEC: reference numbers are comparison points, not constants).
SPEC_POSITION_MM = "1-3"
SPEC_ANGLE_DEG = "< ~1"
SPEC_NOTE = ("SPEC 3 reference (the real hardware, over whole trajectories, not per range): pose errors of the order "
             "of 1-3 mm and under about 1 deg; 7.02 iterations and ~0.125 ms per estimate at 2 kHz")


def deflection(pose3, rest_pose, points_yz):
    """The shell's deflection (n,) mm at planar poses (n, 3): the largest displacement from rest of
    any of ``points_yz`` (K, 2) mm (shell frame; the LEDs), so that a rotation counts as much as the
    translation it causes at the shell's ends (a choice: the SPEC does not define its ranges)."""
    import numpy as np

    y, z, rx = (np.asarray(pose3, float)[:, k, None] for k in range(3))
    a, b = points_yz[None, :, 0], points_yz[None, :, 1]
    c, s = np.cos(rx), np.sin(rx)
    dy = y + c * a - s * b - (rest_pose[0] + a)
    dz = z + s * a + c * b - (rest_pose[1] + b)
    return np.max(np.hypot(dy, dz), axis=1)


def error_table(true, est, rest_pose, points_yz, bins=DEFLECTION_BINS_MM) -> list[dict]:
    """RMS errors of planar estimates by deflection range.

    Parameters
    ----------
    true, est : (n, 3) planar poses (y mm, z mm, rx rad); est may hold NaN (no estimate: left out).
    rest_pose : (3,) the rest pose. points_yz : (K, 2) mm, where :func:`deflection` is measured.
    bins : the ranges' edges, mm.

    Returns
    -------
    One row per range, then one over all samples (``from_mm`` None): {from_mm, to_mm, n, y_rms_mm,
    z_rms_mm, position_rms_mm (of the (y, z) error's length), rx_rms_deg, max_mm}, None where n = 0.
    SPEC 3 gives only whole-trajectory reference figures (:data:`SPEC_NOTE`).
    """
    import numpy as np

    defl = deflection(true, rest_pose, points_yz)
    err = est - true
    finite = np.all(np.isfinite(est), axis=1)
    rows = []
    ranges = list(zip(bins[:-1], bins[1:])) + [(None, None)]
    for lo, hi in ranges:
        sel = finite & ((defl >= lo) & (defl < hi) if lo is not None else True)
        e = err[sel]
        have = len(e) > 0
        rows.append({"from_mm": lo, "to_mm": hi if hi is None or np.isfinite(hi) else None, "n": int(sel.sum()),
                     "y_rms_mm": float(np.sqrt(np.mean(e[:, 0] ** 2))) if have else None,
                     "z_rms_mm": float(np.sqrt(np.mean(e[:, 1] ** 2))) if have else None,
                     "position_rms_mm": float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2))) if have else None,
                     "rx_rms_deg": float(np.degrees(np.sqrt(np.mean(e[:, 2] ** 2)))) if have else None,
                     "max_mm": float(np.max(np.hypot(e[:, 0], e[:, 1]))) if have else None})
    return rows


def _range_label(row) -> str:
    if row["from_mm"] is None:
        return "all"
    return f"{row['from_mm']:g}-{row['to_mm']:g}" if row["to_mm"] is not None else f">= {row['from_mm']:g}"


def _fmt(x, spec="{:.4f}") -> str:
    return "-" if x is None else spec.format(x)


TABLE_COLUMNS = ("deflection_mm", "n", "y_rms_mm", "z_rms_mm", "position_rms_mm", "rx_rms_deg", "max_mm",
                 "spec3_position_mm", "spec3_angle_deg")


TRUTH_NOTES = {
    "law": ("The simulated voltages follow the same model the estimator fits (after calibration), so only the noise, the ADC "
            "and the calibration's residual remain; the hardware's errors also hold model error, motion-capture error and "
            "foam hysteresis."),
    "optics": ("The simulated voltages come from optics (other_sensors.cls.optics: the LED's beam, the LTV's acceptance, the "
               "cavity's diffuse light as two-surface radiosity between base and shell) and the calibration fits the "
               "seven-coefficient law to them from motion-capture poses with their own noise: the errors hold the law's "
               "model error and the calibration's; run the same scene without [sensor.optics] for the noise alone. "
               "With sensor.foam.maxwell_kpa > 0 the true force holds the foam's hysteresis "
               "(other_sensors.cls.foam_viscoelastic), which the elastic law's force misses."),
}


def error_table_markdown(rows, shape: str, latency_ms, force_rms_n, moment_rms_nmm, mean_iterations, at_detection_mm=None,
                         truth: str = "law") -> str:
    """The error table by deflection range as Markdown, SPEC 3's reference figures in the last two
    columns, with the detection latency, the force and moment error through the foam law and the
    mean iteration count under it; ``truth`` ("law" or "optics") says what made the voltages."""
    lines = [f"# CLS pose errors by deflection range: {shape} trajectory", "",
             "| deflection (mm) | n | y RMS (mm) | z RMS (mm) | position RMS (mm) | rx RMS (deg) | max (mm) "
             "| SPEC 3 position (mm) | SPEC 3 angle (deg) |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for row in rows:
        lines.append(f"| {_range_label(row)} | {row['n']} | {_fmt(row['y_rms_mm'])} | {_fmt(row['z_rms_mm'])} | "
                     f"{_fmt(row['position_rms_mm'])} | {_fmt(row['rx_rms_deg'])} | {_fmt(row['max_mm'])} | "
                     f"{SPEC_POSITION_MM} | {SPEC_ANGLE_DEG} |")
    lines += ["", "Deflection: the largest displacement of an LED from rest (mm). " + TRUTH_NOTES[truth], "",
              f"- collision (motion) detection latency after the onset: {_fmt(latency_ms, '{:.1f}')} ms"
              + (" (no motion in this trajectory)" if latency_ms is None else
                 f", at a deflection of {_fmt(at_detection_mm, '{:.3f}')} mm"),
              f"- force RMS error through the foam law: {_fmt(force_rms_n)} N; moment RMS error: {_fmt(moment_rms_nmm)} N mm",
              f"- mean LM iterations per estimate (warm start): {mean_iterations:.2f}",
              f"- {SPEC_NOTE}", ""]
    return "\n".join(lines)


def error_table_csv(rows) -> bytes:
    """The error table as CSV (:data:`TABLE_COLUMNS`; empty cells where a range holds no sample)."""
    out = [",".join(TABLE_COLUMNS)]
    for row in rows:
        vals = [_range_label(row), str(row["n"])] + ["" if row[k] is None else f"{row[k]:.6g}" for k in
                                                     ("y_rms_mm", "z_rms_mm", "position_rms_mm", "rx_rms_deg", "max_mm")]
        out.append(",".join(vals + [SPEC_POSITION_MM, SPEC_ANGLE_DEG]))
    return ("\n".join(out) + "\n").encode()


def _estimate(scene, inputs, ctx):
    import time

    import numpy as np

    from other_sensors.cls.estimator import STATUS_NAMES, estimate_poses
    from other_sensors.cls.shell import pose_wrench

    sig = inputs["cls_signals"]
    s = scene.sensor
    layout, foam, settings = layout_of(s), foam_of(s), settings_of(s)
    if s.estimator.coefficients == "calibrated":
        layout = inputs["cls_calibrate"]["layout"]  # coefficients and mounting poses
    elif s.estimator.coefficients == "true":
        layout = true_layout_of(s, scene.seed)
    start = time.perf_counter()
    est = estimate_poses(sig["voltages"], layout, settings, sig["n_rest"], s.noise.adc_range_v)
    seconds = time.perf_counter() - start
    n_fit = int((est.iterations > 0).sum())
    ctx.log(f"cls_estimate: {n_fit} LM estimates, {1e3 * seconds / n_fit:.4f} ms each (with compilation on a first run)"
            if n_fit else "cls_estimate: no LM estimate (the detector saw no motion)")
    ref = np.arange(0, len(sig["t_s"]), sig["reference_every"])
    true, got = sig["pose"][ref], est.poses[ref]
    rest_pose = np.array([0.0, layout.rest_p[2], 0.0])
    onset = sig["n_rest"]
    detected = np.flatnonzero(est.moving[onset:])
    latency_ms = float(detected[0] / sig["rate_hz"] * 1e3) if len(detected) and not np.allclose(sig["pose"][onset:], rest_pose) else None
    if s.foam.maxwell_kpa > 0:  # the viscoelastic truth over the whole 2 kHz trajectory, read at the reference times
        from other_sensors.cls.foam_viscoelastic import viscoelastic_wrench

        wrench_true = viscoelastic_wrench(sig["pose"], sig["t_s"], foam, layout, s.foam.maxwell_kpa, s.foam.relaxation_s)[ref]
    else:
        wrench_true = pose_wrench(true, foam, layout)
    wrench_est = pose_wrench(got, foam, layout)
    ok = np.all(np.isfinite(got), axis=1)
    force_err = np.hypot(*(wrench_est[ok, :2] - wrench_true[ok, :2]).T)
    moment_err = (wrench_est[ok, 2] - wrench_true[ok, 2]) * 1e3  # N mm
    counts = {name: int((est.status == code).sum()) for code, name in STATUS_NAMES.items()}
    points = layout_of(s).led_pos[:, 1:]  # (y, z) of the LEDs on the shell, as designed
    table = error_table(true, got, rest_pose, points)
    at_detection = (float(deflection(sig["pose"][onset + detected[:1]], rest_pose, points)[0])
                    if latency_ms is not None else None)
    moment_rms = float(np.sqrt(np.mean(moment_err ** 2))) if len(moment_err) else None
    force_rms = float(np.sqrt(np.mean(force_err ** 2))) if len(force_err) else None
    mean_it = float(est.iterations[est.iterations > 0].mean()) if n_fit else 0.0
    ctx.log(error_table_markdown(table, s.trajectory.shape, latency_ms, force_rms, moment_rms, mean_it, at_detection))
    return {"t_s": sig["t_s"], "estimates": est.poses, "iterations": est.iterations, "status": est.status, "moving": est.moving,
            "reference": ref, "true": true, "wrench_true": wrench_true, "wrench_est": wrench_est,
            "table": table, "latency_ms": latency_ms, "deflection_at_detection_mm": at_detection, "shape": s.trajectory.shape,
            "truth": "law" if s.optics is None else "optics",
            "onset_s": float(onset / sig["rate_hz"]),
            "moment_rms_nmm": moment_rms,
            "false_alarms": int(est.moving[:onset].sum()), "status_counts": counts,
            "force_rms_n": force_rms, "mean_iterations": mean_it}


def _write_estimate(result, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    from mlsim.plots import save_png

    ref, true = result["reference"], result["true"]
    est = result["estimates"][ref]
    wt, we = result["wrench_true"], result["wrench_est"]
    header = ["t_s", "y_true_mm", "z_true_mm", "rx_true_deg", "y_est_mm", "z_est_mm", "rx_est_deg", "iterations", "status",
              "moving", "fy_true_N", "fz_true_N", "mx_true_Nm", "fy_est_N", "fz_est_N", "mx_est_Nm"]
    cols = [result["t_s"][ref], true[:, 0], true[:, 1], np.degrees(true[:, 2]), est[:, 0], est[:, 1], np.degrees(est[:, 2]),
            result["iterations"][ref], result["status"][ref], result["moving"][ref].astype(int), *wt.T, *we.T]
    files = [atomic_bytes(out_dir / "cls_estimate.csv", _csv(header, cols, "%.7g"))]
    report = {k: result[k] for k in ("table", "latency_ms", "deflection_at_detection_mm", "false_alarms", "status_counts",
                                     "force_rms_n", "moment_rms_nmm", "mean_iterations")}
    report["spec3_reference"] = {"position_mm": SPEC_POSITION_MM, "angle_deg": SPEC_ANGLE_DEG, "note": SPEC_NOTE}
    files.append(atomic_bytes(out_dir / "cls_errors.json", json.dumps(report, indent=2).encode()))
    files.append(atomic_bytes(out_dir / "cls_errors.md", error_table_markdown(
        result["table"], result["shape"], result["latency_ms"], result["force_rms_n"], result["moment_rms_nmm"],
        result["mean_iterations"], result["deflection_at_detection_mm"], result.get("truth", "law")).encode()))
    files.append(atomic_bytes(out_dir / "cls_errors.csv", error_table_csv(result["table"])))
    # three pose panels (estimate at 2 kHz over the 80 Hz reference) and the errors at the reference
    # times, which the pose panels' scale hides; the dashed line marks the motion detector's first alarm
    fig, axes = plt.subplots(4, 1, figsize=(8, 9), sharex=True, gridspec_kw={"height_ratios": (1, 1, 1, 1.2)})
    t = result["t_s"]
    detect = None if result["latency_ms"] is None else result["onset_s"] + result["latency_ms"] * 1e-3
    for k, (ax, label, scale) in enumerate(zip(axes, ("y (mm)", "z (mm)", "rx (deg)"), (1.0, 1.0, 180 / np.pi))):
        ax.plot(t, result["estimates"][:, k] * scale, lw=0.8, label="estimate (2 kHz)")
        ax.plot(t[ref], true[:, k] * scale, "k.", ms=2.5, label="reference (80 Hz)")
        ax.set_ylabel(label)
    err = est - true
    ax = axes[3]
    ax.plot(t[ref], err[:, 0] * 1e3, lw=0.8, label="y error (um)")
    ax.plot(t[ref], err[:, 1] * 1e3, lw=0.8, label="z error (um)")
    ax.plot(t[ref], np.degrees(err[:, 2]) * 1e3, lw=0.8, label="rx error (mdeg)")
    ax.axhline(0.0, color="0.6", lw=0.5)
    ax.set_ylabel("estimate - reference")
    ax.legend(loc="upper right", fontsize=7, ncol=3)
    for a in axes:
        if detect is not None:
            a.axvline(detect, color="r", ls="--", lw=0.7)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title(f"CLS shell pose ({result.get('shape', '')}): estimated vs reference"
                      + ("" if detect is None else f"; motion detected {result['latency_ms']:.1f} ms after onset (red)"), fontsize=10)
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "cls_pose.png"))
    return files


def _summarize_estimate(result) -> dict:
    return {"mean_iterations": result["mean_iterations"], "latency_ms": result["latency_ms"], "false_alarms": result["false_alarms"],
            "force_rms_n": result["force_rms_n"], "moment_rms_nmm": result["moment_rms_nmm"], "status_counts": result["status_counts"],
            "errors_by_deflection": result["table"]}


ESTIMATE = Stage(name="cls_estimate", version="2", doc="motion detection, LM pose estimates, errors by deflection, force via the foam law",
                 reads=("sensor.pairs", "sensor.foam", "sensor.estimator", "sensor.noise.adc_range_v", "sensor.optics", "seed"),
                 needs=("cls_signals", "cls_calibrate"),
                 run=_estimate, save=pickle_save, load=pickle_load, write=_write_estimate, summarize=_summarize_estimate)
