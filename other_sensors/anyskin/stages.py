"""The AnySkin helmet's stages: ``anyskin_signals`` (the 150 Hz magnetometer traces and each sensor's
ground-truth plate force), ``anyskin_contact`` (SPEC 2's causal estimator, the CNN and LSTM-MLP when
the scene names their files, with force estimates with and without re-baselining, scored per axis and
per push cycle), ``anyskin_drift`` (force error against the skin's drift rate), ``anyskin_pitch``
(SPEC 2's face-pitch criteria B and SNR_xy over 0-30 deg) and ``anyskin_bench`` (issue 43: the LSTM-MLP
trained on the simulated calibration bench and scored on the helmet's pushes, for each truth model).

``anyskin_contact``, ``anyskin_drift`` and ``anyskin_bench`` are not cached: they read model files that a retraining
changes under the same name (as the classify stage); they take seconds."""

from __future__ import annotations

import io
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.plots import save_png
from mlsim.stage import Stage, pickle_load, pickle_save

__all__ = ["SIGNALS", "CONTACT", "DRIFT", "PITCH", "BENCH", "CONTACT_FORCE_N"]

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
    needs=(), run=_signals, save=pickle_save, load=pickle_load, write=_write_signals, summarize=_summarize_signals,
    version="2")  # 2: issue 43's truth models and chip read-out


def _contact(scene, inputs, ctx):
    from .estimate import estimate_contacts

    result = estimate_contacts(scene.sensor, inputs["anyskin_signals"], scene.seed)
    ctx.log(f"anyskin ({result.estimator}): force MAE {result.mae('rebaselined'):.2f} N with re-baselining, "
            f"{result.mae('static'):.2f} N without")
    return result


def _summarize_contact(result) -> dict:
    cycles_rb, cycles_st = result.cycle_mae("rebaselined"), result.cycle_mae("static")
    return {
        "estimator": result.estimator,
        "mae_rebaselined_n": result.mae("rebaselined"), "mae_static_n": result.mae("static"),
        "mae_xyz_rebaselined_n": [result.mae("rebaselined", a) for a in range(3)],
        "mae_xyz_static_n": [result.mae("static", a) for a in range(3)],
        "mae_z_rebaselined_n": result.mae("rebaselined", 2), "mae_z_static_n": result.mae("static", 2),
        "cycle_mae_z_rebaselined_n": [float(v) for v in cycles_rb[:, 2]],
        "cycle_mae_z_static_n": [float(v) for v in cycles_st[:, 2]],
        "onsets_per_sensor": [int(v) for v in result.onsets], "releases_per_sensor": [int(v) for v in result.releases],
        "rebaselines_per_sensor": [int(v) for v in result.rebaselines],
    }


def _table(head, rows, fmt="{:.3f}") -> tuple[str, str]:
    """(CSV, Markdown) of rows of numbers and strings."""
    show = lambda v: fmt.format(v) if isinstance(v, float) else str(v)  # noqa: E731
    csv = ",".join(head) + "\n" + "".join(",".join(show(v) for v in r) + "\n" for r in rows)
    md = "| " + " | ".join(head) + " |\n|" + "---|" * len(head) + "\n"
    md += "".join("| " + " | ".join(show(v) for v in r) + " |\n" for r in rows)
    return csv, md


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

    rb, st = result.cycle_mae("rebaselined"), result.cycle_mae("static")
    rows = [[k, float(result.t[lo]), *map(float, rb[k]), *map(float, st[k])] for k, lo in enumerate(result.cycles[:-1])]
    rows.append(["all", float(result.t[result.start]), *[result.mae("rebaselined", a) for a in range(3)],
                 *[result.mae("static", a) for a in range(3)]])
    csv, md = _table(["cycle", "from_s", "mae_x_rebaselined_n", "mae_y_rebaselined_n", "mae_z_rebaselined_n",
                      "mae_x_static_n", "mae_y_static_n", "mae_z_static_n"], rows, "{:.2f}")
    files.append(atomic_bytes(out_dir / "anyskin_push_cycles.csv", csv.encode()))
    md = (f"# Force MAE per push cycle and axis ({result.estimator}), with and without re-baselining\n\n"
          "MAE in N over each cycle's scored samples and the four sensors (sensor frames; z is the normal).\n\n" + md)
    files.append(atomic_bytes(out_dir / "anyskin_push_cycles.md", md.encode()))

    fig, axes = plt.subplots(n_s + 1, 1, figsize=(9.0, 2.0 * (n_s + 1)), sharex=False)
    for i, ax in enumerate(axes[:n_s]):
        ax.plot(result.t, -result.truth[:, i, 2], "k", lw=1.0, label="truth")
        ax.plot(result.t, -result.rebaselined[:, i, 2], lw=0.8, label="re-baselined")
        ax.plot(result.t, -result.static[:, i, 2], lw=0.8, ls="--", label="static baseline")
        ax.fill_between(result.t, 0, result.state[:, i].any(axis=1) * max(1.0, -result.truth[:, i, 2].min()), color="0.9",
                        step="post", label="contact (any chip)")
        ax.set_ylabel(f"sensor {i}\n-F_z (N)", fontsize=7)
    axes[0].legend(fontsize=6, ncol=4, loc="upper left")
    axes[n_s - 1].set_xlabel("t (s)")
    k = np.arange(len(rb))
    axes[-1].plot(k, rb[:, 2], "o-", label="re-baselined")
    axes[-1].plot(k, st[:, 2], "s--", label="static baseline")
    axes[-1].set(xlabel="push cycle", ylabel="MAE z (N)")
    axes[-1].legend(fontsize=7)
    fig.suptitle(f"normal force ({result.estimator}): MAE {result.mae('rebaselined'):.2f} N re-baselined, "
                 f"{result.mae('static'):.2f} N static", fontsize=8)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "anyskin_contact.png", dpi=100))
    return files


_READS = ("sensor.skin", "sensor.magnetometers", "sensor.helmet", "sensor.trajectory", "sensor.push", "sensor.ambient",
          "sensor.noise", "sensor.estimator", "seed")

CONTACT = Stage(
    name="anyskin_contact", doc="SPEC 2's causal estimator (the CNN and LSTM-MLP, or stand-ins without trained files): contact "
                                "states, re-baselining, force estimates with and without it, MAE per axis and per push cycle",
    reads=_READS, needs=("anyskin_signals",), run=_contact, version="2", write=_write_contact, summarize=_summarize_contact)


def _drift(scene, inputs, ctx):
    from .estimate import make_estimator
    from .study import drift_sweep

    rows = drift_sweep(scene.sensor, scene.seed, make_estimator(scene.sensor, scene.seed))
    for r in rows:
        ctx.log(f"anyskin drift: set fraction {r.set_fraction:.3f}: MAE z {r.mae_rebaselined[2]:.2f} N re-baselined, "
                f"{r.mae_static[2]:.2f} N static")
    return rows


def _summarize_drift(rows) -> dict:
    return {"set_fraction": [r.set_fraction for r in rows], "final_set_um": [r.final_set_um for r in rows],
            "mae_z_rebaselined_n": [float(r.mae_rebaselined[2]) for r in rows], "mae_z_static_n": [float(r.mae_static[2]) for r in rows],
            "tail_mae_z_rebaselined_n": [r.tail_z_rebaselined for r in rows], "tail_mae_z_static_n": [r.tail_z_static for r in rows]}


def _write_drift(rows, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    table = [[r.set_fraction, r.rate_per_s * 1e3, r.final_set_um, *map(float, r.mae_rebaselined), *map(float, r.mae_static),
              r.tail_z_rebaselined, r.tail_z_static, r.rebaselines] for r in rows]
    csv, md = _table(["set_fraction", "rate_per_ks", "final_set_um", "mae_x_rebaselined_n", "mae_y_rebaselined_n",
                      "mae_z_rebaselined_n", "mae_x_static_n", "mae_y_static_n", "mae_z_static_n", "last5_mae_z_rebaselined_n",
                      "last5_mae_z_static_n", "rebaselines"], table, "{:.2f}")
    md = ("# Force MAE against the skin's drift rate (permanent-set fraction / tau_set)\n\n"
          "rate_per_ks: set fraction / tau_set in 1/(1000 s); MAE in N over all scored samples; last5: z over the last cycles.\n\n" + md)
    files = [atomic_bytes(out_dir / "anyskin_drift.csv", csv.encode()), atomic_bytes(out_dir / "anyskin_drift.md", md.encode())]
    fig, ax = plt.subplots(figsize=(6.0, 4.0))
    rate = [r.rate_per_s * 1e3 for r in rows]
    ax.plot(rate, [r.mae_rebaselined[2] for r in rows], "o-", label="re-baselined, all cycles")
    ax.plot(rate, [r.mae_static[2] for r in rows], "s--", label="static, all cycles")
    ax.plot(rate, [r.tail_z_rebaselined for r in rows], "o:", label="re-baselined, last cycles")
    ax.plot(rate, [r.tail_z_static for r in rows], "s:", label="static, last cycles")
    ax.set(xlabel="permanent-set rate, fraction / tau_set (1/ks)", ylabel="MAE z (N)", title="force error against drift rate")
    ax.legend(fontsize=7)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "anyskin_drift.png", dpi=100))
    return files


DRIFT = Stage(
    name="anyskin_drift", doc="force MAE with and without re-baselining against the skin's permanent-set rate (a sweep)",
    reads=_READS + ("sensor.drift",), needs=(), run=_drift, write=_write_drift, summarize=_summarize_drift)


def _pitch(scene, inputs, ctx):
    from .study import pitch_criteria

    return pitch_criteria(scene.sensor, scene.seed)


def _summarize_pitch(rows) -> dict:
    import numpy as np

    return {"pitch_deg": [r.pitch_deg for r in rows], "b_mean": [r.b_mean for r in rows], "b_std": [r.b_std for r in rows],
            "snr_xy_mean": [float(np.nanmean(r.snr)) for r in rows]}


def _write_pitch(rows, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    n_s = len(rows[0].b)
    table = [[r.pitch_deg, *[int(v) for v in r.b], r.b_mean, r.b_std, *map(float, r.snr), float(np.nanmean(r.snr))] for r in rows]
    head = ["pitch_deg", *[f"b_s{i}" for i in range(n_s)], "b_mean", "b_std", *[f"snr_xy_s{i}" for i in range(n_s)], "snr_xy_mean"]
    csv, md = _table(head, table, "{:.2f}")
    md = ("# Face-pitch criteria (SPEC 2)\n\nB: samples with contact force > 50 N per sensor (high mean, low spread wanted); "
          "SNR_xy = |mean F_xy| / sqrt(trace Sigma_xy) of each sensor's planar force over its contact samples.\n\n" + md)
    files = [atomic_bytes(out_dir / "anyskin_pitch.csv", csv.encode()), atomic_bytes(out_dir / "anyskin_pitch.md", md.encode())]
    fig, (a1, a2) = plt.subplots(1, 2, figsize=(9.0, 3.6))
    p = [r.pitch_deg for r in rows]
    a1.errorbar(p, [r.b_mean for r in rows], yerr=[r.b_std for r in rows], fmt="o-", capsize=3)
    a1.set(xlabel="face pitch (deg)", ylabel="B: samples > 50 N (mean +- std over sensors)")
    for i in range(n_s):
        a2.plot(p, [r.snr[i] for r in rows], "o-", label=f"sensor {i}")
    a2.set(xlabel="face pitch (deg)", ylabel="SNR_xy")
    a2.legend(fontsize=7)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "anyskin_pitch.png", dpi=100))
    return files


PITCH = Stage(
    name="anyskin_pitch", doc="SPEC 2's face-pitch criteria B and SNR_xy over 0-30 deg, from the simulated ground truth",
    reads=("sensor.skin", "sensor.magnetometers", "sensor.helmet", "sensor.trajectory", "sensor.push", "sensor.ambient",
           "sensor.drift", "sensor.noise", "seed"),
    needs=(), run=_pitch, save=pickle_save, load=pickle_load, write=_write_pitch, summarize=_summarize_pitch,
    version="2")  # 2: issue 43's truth models and chip read-out


def _bench(scene, inputs, ctx):
    from .study import truth_comparison

    return truth_comparison(scene.sensor, scene.seed, log=ctx.log)


def _summarize_bench(rows) -> dict:
    return {"truth": [r.truth for r in rows], "bench_mae_xyz_n": [[float(v) for v in r.bench_mae] for r in rows],
            "mae_xyz_rebaselined_n": [[float(v) for v in r.mae_rebaselined] for r in rows],
            "mae_xyz_static_n": [[float(v) for v in r.mae_static] for r in rows], "rebaselines": [r.rebaselines for r in rows]}


def _write_bench(rows, out_dir: Path, ctx) -> list[Path]:
    table = [[r.truth, *map(float, r.bench_mae), *map(float, r.mae_rebaselined), *map(float, r.mae_static), r.rebaselines]
             for r in rows]
    csv, md = _table(["truth", "bench_mae_x_n", "bench_mae_y_n", "bench_mae_z_n", "mae_x_rebaselined_n", "mae_y_rebaselined_n",
                      "mae_z_rebaselined_n", "mae_x_static_n", "mae_y_static_n", "mae_z_static_n", "rebaselines"], table, "{:.2f}")
    md = ("# Force MAE per axis with the LSTM-MLP trained on the simulated calibration bench (issue 43)\n\n"
          "Per truth model (the world that generates the chips' field): bench_*: the held-out bench run (one skin pressed on a "
          "force plate); the rest: the helmet's pushes over all scored samples and the four sensors (sensor frames, z the "
          "normal), with and without re-baselining. Each row's network is trained on the bench in that row's world and "
          "scored on the helmet in the same world, with the same contact detector: the helmet's error holds what the bench "
          "does not show (other chips' offsets, gains and cross-axis terms, the head's motion and fields, the skin's set), "
          "not only the noise added.\n\n" + md)
    return [atomic_bytes(out_dir / "anyskin_bench.csv", csv.encode()), atomic_bytes(out_dir / "anyskin_bench.md", md.encode())]


BENCH = Stage(
    name="anyskin_bench", doc="the LSTM-MLP trained on the simulated calibration bench and scored on the helmet's pushes, "
                              "with and without re-baselining, for the magnet-volume and point-dipole truths",
    reads=_READS + ("sensor.drift",), needs=(), run=_bench, write=_write_bench, summarize=_summarize_bench)
