"""The AnySkin helmet's stages: ``anyskin_signals`` (the 150 Hz magnetometer traces and each sensor's
ground-truth plate force) and ``anyskin_contact`` (SPEC 2's causal contact pipeline with a threshold
detector standing in for the CNN, and force estimates with and without re-baselining)."""

from __future__ import annotations

import io
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.plots import save_png
from mlsim.stage import Stage, pickle_load, pickle_save

__all__ = ["SIGNALS", "CONTACT", "CONTACT_FORCE_N"]

CONTACT_FORCE_N = 50.0  # SPEC 2's criterion B counts contact forces above 50 N


def _signals(scene, inputs, ctx):
    from .signals import simulate_helmet

    result = simulate_helmet(scene.sensor, scene.seed)
    ctx.log(f"anyskin: {len(result.t)} samples at {scene.sensor.magnetometers.rate_hz:g} Hz, "
            f"peak plate force {result.total_n.max():.1f} N")
    return result


def _summarize_signals(result) -> dict:
    import numpy as np

    change = np.linalg.norm(result.skin - result.baseline, axis=-1)  # (T, 4, 5)
    return {
        "samples": int(len(result.t)), "duration_s": float(len(result.t) * (result.t[1] - result.t[0])) if len(result.t) > 1 else 0.0,
        "peak_push_n": float(result.total_n.max()),
        "peak_force_per_sensor_n": [float(v) for v in result.normal_n.max(axis=0)],
        "samples_above_50n_per_sensor": [int(v) for v in (result.normal_n > CONTACT_FORCE_N).sum(axis=0)],
        "max_skin_change_ut": float(change.max()),
        "final_set_um": [1e3 * float(v) for v in result.set_mm[-1]],
        "geomagnetic_span_ut": float(np.ptp(result.geomagnetic, axis=0).max()),
    }


def _write_signals(result, out_dir: Path, ctx) -> list[Path]:
    import numpy as np

    n_t, n_s, n_c, _ = result.readings.shape
    head = ["t_s", "push_n"] + [f"s{i}_normal_n" for i in range(n_s)]
    head += [f"s{i}_f{a}_n" for i in range(n_s) for a in "xyz"]
    head += [f"s{i}_m{j}_b{a}_ut" for i in range(n_s) for j in range(n_c) for a in "xyz"]
    table = np.column_stack([result.t, result.total_n, result.normal_n, result.force_n.reshape(n_t, -1), result.readings.reshape(n_t, -1)])
    buf = io.StringIO()
    np.savetxt(buf, table, delimiter=",", fmt="%.6g", header=",".join(head), comments="")
    files = [atomic_bytes(out_dir / "anyskin_signals.csv", buf.getvalue().encode())]
    files.append(_plot(result, out_dir / "anyskin_signals.png"))
    return files


def _plot(result, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n_s = result.readings.shape[1]
    fig, axes = plt.subplots(n_s, 1, figsize=(8.0, 2.0 * n_s), sharex=True)
    for i, ax in enumerate(np.atleast_1d(axes)):
        delta = np.linalg.norm(result.readings[:, i] - result.readings[0, i], axis=-1)  # (T, 5)
        for j in range(delta.shape[1]):
            ax.plot(result.t, delta[:, j], lw=0.7, label=f"chip {j}")
        twin = ax.twinx()
        twin.plot(result.t, result.normal_n[:, i], "k--", lw=0.8)
        twin.set_ylabel("force (N)", fontsize=7)
        ax.set_ylabel(f"sensor {i}\n|B - B0| (uT)", fontsize=7)
    np.atleast_1d(axes)[0].legend(fontsize=6, ncol=5, loc="upper left")
    np.atleast_1d(axes)[-1].set_xlabel("t (s)")
    fig.suptitle("AnySkin helmet: change of each chip's field from the first sample; dashed: plate force")
    fig.tight_layout()
    return save_png(fig, path, dpi=100)


SIGNALS = Stage(
    name="anyskin_signals", doc="150 Hz magnetometer traces of the four helmet skins and each sensor's ground-truth plate force",
    reads=("sensor.skin", "sensor.magnetometers", "sensor.helmet", "sensor.trajectory", "sensor.push", "sensor.ambient",
           "sensor.drift", "sensor.noise", "seed"),
    needs=(), run=_signals, save=pickle_save, load=pickle_load, write=_write_signals, summarize=_summarize_signals)


def _contact(scene, inputs, ctx):
    from .estimate import estimate_contacts

    result = estimate_contacts(scene.sensor, inputs["anyskin_signals"], scene.seed)
    ctx.log(f"anyskin: force MAE {result.mae('rebaselined'):.2f} N with re-baselining, {result.mae('static'):.2f} N without")
    return result


def _summarize_contact(result) -> dict:
    return {
        "mae_rebaselined_n": result.mae("rebaselined"), "mae_static_n": result.mae("static"),
        "mae_z_rebaselined_n": result.mae("rebaselined", 2), "mae_z_static_n": result.mae("static", 2),
        "onsets_per_sensor": [int(v) for v in result.onsets], "releases_per_sensor": [int(v) for v in result.releases],
        "detector": "threshold on window slopes (stand-in for the causal CNN)",
    }


def _write_contact(result, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n_t, n_s = result.truth.shape[:2]
    head = ["t_s"] + [f"s{i}_{what}_f{a}_n" for i in range(n_s) for what in ("truth", "rebaselined", "static") for a in "xyz"]
    head += [f"s{i}_contact_chips" for i in range(n_s)]
    cols = [result.t[:, None]]
    for i in range(n_s):
        cols += [result.truth[:, i], result.rebaselined[:, i], result.static[:, i]]
    cols.append(result.state.sum(axis=2))
    buf = io.StringIO()
    np.savetxt(buf, np.column_stack(cols), delimiter=",", fmt="%.6g", header=",".join(head), comments="")
    files = [atomic_bytes(out_dir / "anyskin_contact.csv", buf.getvalue().encode())]
    fig, axes = plt.subplots(n_s, 1, figsize=(8.0, 2.0 * n_s), sharex=True)
    for i, ax in enumerate(np.atleast_1d(axes)):
        ax.plot(result.t, -result.truth[:, i, 2], "k", lw=1.0, label="truth")
        ax.plot(result.t, -result.rebaselined[:, i, 2], lw=0.8, label="re-baselined")
        ax.plot(result.t, -result.static[:, i, 2], lw=0.8, ls="--", label="static baseline")
        ax.fill_between(result.t, 0, result.state[:, i].any(axis=1) * max(1.0, -result.truth[:, i, 2].min()), color="0.9",
                        step="post", label="contact (any chip)")
        ax.set_ylabel(f"sensor {i}\n-F_z (N)", fontsize=7)
    np.atleast_1d(axes)[0].legend(fontsize=6, ncol=4, loc="upper left")
    np.atleast_1d(axes)[-1].set_xlabel("t (s)")
    fig.suptitle(f"normal force: MAE {result.mae('rebaselined'):.2f} N re-baselined, {result.mae('static'):.2f} N static "
                 "(threshold detector for the CNN, quadratic map for the LSTM)", fontsize=8)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "anyskin_contact.png", dpi=100))
    return files


CONTACT = Stage(
    name="anyskin_contact", doc="causal contact states (threshold detector for the CNN), re-baselining, force estimates and their MAE",
    reads=("sensor.skin", "sensor.magnetometers", "sensor.helmet", "sensor.trajectory", "sensor.push", "sensor.ambient",
           "sensor.noise", "sensor.estimator", "seed"),
    needs=("anyskin_signals",), run=_contact, save=pickle_save, load=pickle_load, write=_write_contact, summarize=_summarize_contact)
