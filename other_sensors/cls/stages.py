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

__all__ = ["SIGNALS", "CALIBRATE", "ESTIMATE", "layout_of", "true_layout_of", "foam_of", "settings_of", "DEFLECTION_BINS_MM"]

# Deflection ranges (mm, |(y, z) - rest|) the error table is split by: a choice spanning rest, small
# contact and deep compression of the 38 mm pillars.
DEFLECTION_BINS_MM = (0.0, 2.0, 5.0, 10.0, float("inf"))


def layout_of(sensor):
    """The layout with the nominal coefficients (what a designer knows)."""
    from other_sensors.cls.ltv import default_layout

    p = sensor.pairs
    return default_layout(p.n, p.pitch_mm, p.stagger_mm, p.gap_mm, p.coefficients)


def true_layout_of(sensor, seed: int):
    """The layout with each pair's true coefficients: the nominal ones with the part-to-part spread
    (``sensor.pairs.coefficient_spread``) drawn from the scene's seed (stream 2)."""
    import numpy as np

    nominal = layout_of(sensor)
    rng = np.random.default_rng([seed, 2])
    scale = np.abs(nominal.coeffs)
    scale[:, 1] = 20.0  # c2 is nominally 0 mm: its spread is relative to 20 mm
    spread = sensor.pairs.coefficient_spread * rng.standard_normal(nominal.coeffs.shape)
    return nominal.with_coeffs(nominal.coeffs + spread * scale)


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

    from other_sensors.cls.shell import measure, trajectory

    s = scene.sensor
    tr, noise = s.trajectory, s.noise
    layout = true_layout_of(s, scene.seed)
    n = int(round(tr.duration_s * tr.rate_hz))
    t = np.arange(n) / tr.rate_hz
    # independent streams for the motion and the noise, both from the scene's seed
    motion_rng, noise_rng = (np.random.default_rng([scene.seed, k]) for k in (0, 1))
    pose = trajectory(tr.shape, t, tr.rest_s, s.pairs.gap_mm, tr.compression_mm, tr.shear_mm, tr.rotation_deg,
                      tr.frequency_hz, motion_rng)
    volts, clean = measure(pose, layout, noise.rms_mv, noise_rng, noise.adc_bits, noise.adc_range_v)
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


SIGNALS = Stage(name="cls_signals", doc="the shell's trajectory and the pairs' voltages (noise, ADC)",
                reads=("sensor.pairs", "sensor.trajectory", "sensor.noise", "seed"), needs=(), run=_signals,
                save=pickle_save, load=pickle_load, write=_write_signals, summarize=_summarize_signals)


# ---------------------------------------------------------------------------------- cls_calibrate
def _calibrate(scene, inputs, ctx):
    import numpy as np

    from other_sensors.cls.calibration import CalibrationSettings, calibrate
    from other_sensors.cls.shell import measure, trajectory

    s = scene.sensor
    cal, tr, noise = s.calibration, s.trajectory, s.noise
    true = true_layout_of(s, scene.seed)
    t = np.arange(int(round(cal.duration_s * cal.rate_hz))) / cal.rate_hz
    # the calibration run's own streams (3: motion, 4: noise); the reference poses are taken as exact
    poses = trajectory("general", t, min(0.25, cal.duration_s / 10), s.pairs.gap_mm, tr.compression_mm, tr.shear_mm,
                       tr.rotation_deg, tr.frequency_hz, np.random.default_rng([scene.seed, 3]))
    volts, _ = measure(poses, true, noise.rms_mv, np.random.default_rng([scene.seed, 4]), noise.adc_bits, noise.adc_range_v)
    settings = CalibrationSettings(tau=cal.tau, theta_max_deg=cal.theta_max_deg, r_min_mm=cal.r_min_mm,
                                   r_max_mm=s.estimator.r_max_mm, v_max_v=cal.v_max_v)
    fit = calibrate(poses, volts, layout_of(s), settings)
    ctx.log(f"cls_calibrate: {len(t)} poses; residual {np.round(fit.rms_mv, 3).tolist()} mV RMS per pair; "
            f"weakly identifiable: {sorted({c for w in fit.weak for c in w})}")
    return {"coeffs": fit.coeffs, "true": true.coeffs, "nominal": layout_of(s).coeffs, "iterations": fit.iterations,
            "rms_mv": fit.rms_mv, "used": fit.used, "singular": fit.singular, "weak": fit.weak}


def _calibration_report(result) -> dict:
    import numpy as np

    from other_sensors.cls.calibration import COEFF_NAMES

    rel = (result["coeffs"] - result["true"]) / np.maximum(np.abs(result["true"]), 1.0)
    return {"coefficients": list(COEFF_NAMES), "fitted": result["coeffs"].tolist(), "true": result["true"].tolist(),
            "nominal": result["nominal"].tolist(), "error_relative_to_max_abs_true_or_1": rel.tolist(),
            "residual_rms_mv": result["rms_mv"].tolist(), "iterations": result["iterations"].tolist(),
            "samples_used": result["used"].tolist(), "relative_singular_values": result["singular"].tolist(),
            "not_identifiable": result["weak"]}


def _write_calibration(result, out_dir: Path, ctx) -> list[Path]:
    return [atomic_bytes(out_dir / "cls_calibration.json", json.dumps(_calibration_report(result), indent=2).encode())]


def _summarize_calibration(result) -> dict:
    report = _calibration_report(result)
    return {k: report[k] for k in ("residual_rms_mv", "iterations", "not_identifiable")}


CALIBRATE = Stage(name="cls_calibrate", doc="batch LM calibration of each pair's coefficients from a 37 s trajectory of measured poses",
                  reads=("sensor.pairs", "sensor.calibration", "sensor.noise", "sensor.estimator.r_max_mm", "sensor.trajectory.compression_mm",
                         "sensor.trajectory.shear_mm", "sensor.trajectory.rotation_deg", "sensor.trajectory.frequency_hz", "seed"),
                  needs=(), run=_calibrate, save=pickle_save, load=pickle_load, write=_write_calibration, summarize=_summarize_calibration)


# ----------------------------------------------------------------------------------- cls_estimate
def error_table(true, est, rest_pose, bins=DEFLECTION_BINS_MM) -> list[dict]:
    """RMS errors of planar estimates (n, 3) against true poses (n, 3) by deflection range
    (|(y, z) - rest| mm): rows of {from_mm, to_mm, n, y_rms_mm, z_rms_mm, rx_rms_deg, max_mm}."""
    import numpy as np

    defl = np.hypot(true[:, 0] - rest_pose[0], true[:, 1] - rest_pose[1])
    err = est - true
    rows = []
    for lo, hi in zip(bins[:-1], bins[1:]):
        sel = (defl >= lo) & (defl < hi) & np.all(np.isfinite(est), axis=1)
        e = err[sel]
        rows.append({"from_mm": lo, "to_mm": hi if np.isfinite(hi) else None, "n": int(sel.sum()),
                     "y_rms_mm": float(np.sqrt(np.mean(e[:, 0] ** 2))) if len(e) else None,
                     "z_rms_mm": float(np.sqrt(np.mean(e[:, 1] ** 2))) if len(e) else None,
                     "rx_rms_deg": float(np.degrees(np.sqrt(np.mean(e[:, 2] ** 2)))) if len(e) else None,
                     "max_mm": float(np.max(np.hypot(e[:, 0], e[:, 1]))) if len(e) else None})
    return rows


def _estimate(scene, inputs, ctx):
    import time

    import numpy as np

    from other_sensors.cls.estimator import STATUS_NAMES, estimate_poses
    from other_sensors.cls.shell import pose_wrench

    sig = inputs["cls_signals"]
    s = scene.sensor
    layout, foam, settings = layout_of(s), foam_of(s), settings_of(s)
    if s.estimator.coefficients == "calibrated":
        layout = layout.with_coeffs(inputs["cls_calibrate"]["coeffs"])
    elif s.estimator.coefficients == "true":
        layout = true_layout_of(s, scene.seed)
    start = time.perf_counter()
    est = estimate_poses(sig["voltages"], layout, settings, sig["n_rest"], s.noise.adc_range_v)
    seconds = time.perf_counter() - start
    n_fit = int((est.iterations > 0).sum())
    ctx.log(f"cls_estimate: {n_fit} LM estimates, {1e3 * seconds / max(n_fit, 1):.4f} ms each (with compilation on a first run)")
    ref = np.arange(0, len(sig["t_s"]), sig["reference_every"])
    true, got = sig["pose"][ref], est.poses[ref]
    rest_pose = np.array([0.0, layout.rest_p[2], 0.0])
    onset = sig["n_rest"]
    detected = np.flatnonzero(est.moving[onset:])
    latency_ms = float(detected[0] / sig["rate_hz"] * 1e3) if len(detected) and not np.allclose(sig["pose"][onset:], rest_pose) else None
    wrench_true = pose_wrench(true, foam, layout)
    wrench_est = pose_wrench(got, foam, layout)
    ok = np.all(np.isfinite(got), axis=1)
    force_err = np.hypot(*(wrench_est[ok, :2] - wrench_true[ok, :2]).T)
    counts = {name: int((est.status == code).sum()) for code, name in STATUS_NAMES.items()}
    return {"t_s": sig["t_s"], "estimates": est.poses, "iterations": est.iterations, "status": est.status, "moving": est.moving,
            "reference": ref, "true": true, "wrench_true": wrench_true, "wrench_est": wrench_est,
            "table": error_table(true, got, rest_pose), "latency_ms": latency_ms,
            "false_alarms": int(est.moving[:onset].sum()), "status_counts": counts,
            "force_rms_n": float(np.sqrt(np.mean(force_err ** 2))) if len(force_err) else None,
            "mean_iterations": float(est.iterations[est.iterations > 0].mean()) if n_fit else 0.0}


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
    report = {k: result[k] for k in ("table", "latency_ms", "false_alarms", "status_counts", "force_rms_n", "mean_iterations")}
    files.append(atomic_bytes(out_dir / "cls_errors.json", json.dumps(report, indent=2).encode()))
    fig, axes = plt.subplots(3, 1, figsize=(8, 7), sharex=True)
    t = result["t_s"]
    for k, (ax, label, scale) in enumerate(zip(axes, ("y (mm)", "z (mm)", "rx (deg)"), (1.0, 1.0, 180 / np.pi))):
        ax.plot(t, result["estimates"][:, k] * scale, lw=0.8, label="estimate (2 kHz)")
        ax.plot(t[ref], true[:, k] * scale, "k.", ms=2.5, label="reference (80 Hz)")
        ax.set_ylabel(label)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[0].set_title("CLS shell pose: estimated vs reference")
    axes[-1].set_xlabel("time (s)")
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "cls_pose.png"))
    return files


def _summarize_estimate(result) -> dict:
    return {"mean_iterations": result["mean_iterations"], "latency_ms": result["latency_ms"], "false_alarms": result["false_alarms"],
            "force_rms_n": result["force_rms_n"], "status_counts": result["status_counts"], "errors_by_deflection": result["table"]}


ESTIMATE = Stage(name="cls_estimate", doc="motion detection, LM pose estimates, errors by deflection, force via the foam law",
                 reads=("sensor.pairs", "sensor.foam", "sensor.estimator", "sensor.noise.adc_range_v", "seed"),
                 needs=("cls_signals", "cls_calibrate"),
                 run=_estimate, save=pickle_save, load=pickle_load, write=_write_estimate, summarize=_summarize_estimate)
