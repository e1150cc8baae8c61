"""The plantar sole's stages: ``sole_contact`` (what the cells and the ankle F/T read for the scene's
foot over its terrain) and ``sole_feasibility`` (CoP, polygons and both step-feasibility rules)."""

from __future__ import annotations

import json
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.plots import save_png
from mlsim.stage import Stage, pickle_load, pickle_save

__all__ = ["CONTACT", "FEASIBILITY", "BALANCE", "contact_of_scene", "assessment_of"]


def contact_of_scene(sensor, seed: int):
    """The :class:`other_sensors.sole.contact.SoleContact` of a :class:`SoleSensor`, with each force
    sensor's noise drawn from a generator seeded by ``seed``."""
    import numpy as np

    from .contact import SoleContact, height_for_load, sole_contact

    layout, terrain = sensor.cells.layout(), sensor.terrain.to_terrain()
    pose = sensor.foot.pose()
    k, n = sensor.foundation.stiffness_n_m3, sensor.cells.quadrature
    z = sensor.foot.height_mm * 1e-3 if sensor.foot.height_mm is not None else height_for_load(layout, pose, terrain, k, sensor.foot.load_n, n)
    exact = sole_contact(layout, pose.with_height(z), terrain, k, n)
    rng = np.random.default_rng(seed)
    noisy = exact.sensor_forces + rng.normal(0.0, sensor.cells.force_noise_n, exact.sensor_forces.shape)
    return SoleContact(noisy, noisy.sum(axis=1), exact.wrench, exact.gaps, exact.pose)


def _contact(scene, inputs, ctx):
    return contact_of_scene(scene.sensor, scene.seed)


def _write_contact(result, out_dir: Path, ctx) -> list[Path]:
    lines = ["cell,f1_n,f2_n,f3_n,f_n,gap_mm"]
    for j, (f, g) in enumerate(zip(result.sensor_forces, result.gaps)):
        lines.append(f"{j},{f[0]:.6g},{f[1]:.6g},{f[2]:.6g},{f.sum():.6g},{g * 1e3:.6g}")
    return [atomic_bytes(out_dir / "sole_cells.csv", ("\n".join(lines) + "\n").encode())]


def _summarize_contact(result) -> dict:
    fz, mx, my = (float(v) for v in result.wrench[2:5])
    return {"fz_n": fz, "mx_nm": mx, "my_nm": my, "foot_height_mm": 1e3 * float(result.pose.position[2])}


CONTACT = Stage(
    name="sole_contact", doc="cell force readings, proximity gaps and the ankle wrench of the foot on the terrain",
    reads=("sensor.cells", "sensor.foundation", "sensor.terrain", "sensor.foot", "seed"), needs=(), run=_contact,
    version="2",  # 2: proximity is the least gap under the cell's face, not at its centre
    save=pickle_save, load=pickle_load, write=_write_contact, summarize=_summarize_contact)


def assessment_of(sensor, contact):
    """The :class:`other_sensors.sole.feasibility.StepAssessment` of a contact under the sensor's rules."""
    from .estimators import G
    from .feasibility import assess_step

    f = sensor.feasibility
    return assess_step(sensor.cells.layout(), contact, eps_force_n=f.eps_force_kg * G, eps_torque_nm=f.eps_torque_nm,
                       eps_area=f.eps_area, clearance_m=f.clearance_mm * 1e-3, proximity_range_m=sensor.proximity.range_mm * 1e-3)


def _feasibility(scene, inputs, ctx):
    result = assessment_of(scene.sensor, inputs["sole_contact"])
    ctx.log(f"sole: M_s = {result.ankle_moment:.2f} N m, A_p/A_s = {result.area_ratio:.3f}; "
            f"F/T {'re-plan' if result.ft_replan else 'safe'}, skin {'re-plan' if result.skin_replan else 'safe'}")
    return result


def _summarize_feasibility(result) -> dict:
    return {
        "ankle_moment_nm": float(result.ankle_moment), "area_ratio": float(result.area_ratio),
        "polygon_area_cm2": 1e4 * result.polygon_area, "sole_area_cm2": 1e4 * result.sole_area,
        "active_cells": int(result.active.sum()), "contact_area_cm2": 1e4 * result.contact_area,
        "cop_mm": [1e3 * float(v) for v in result.cop], "cop_ft_mm": [1e3 * float(v) for v in result.cop_ft],
        "ft_replan": result.ft_replan, "skin_replan": result.skin_replan,
        "sidestep_ft_mm": 1e3 * result.sidestep_ft, "sidestep_skin_mm": 1e3 * result.sidestep_skin,
    }


def _write_feasibility(result, out_dir: Path, ctx) -> list[Path]:
    summary = _summarize_feasibility(result)
    rows = ["quantity,value"] + [f"{k},{v}" for k, v in summary.items() if not isinstance(v, list)]
    rows += [f"{k}_{axis},{v[i]}" for k, v in summary.items() if isinstance(v, list) for i, axis in enumerate("xy")]
    files = [atomic_bytes(out_dir / "sole_feasibility.csv", ("\n".join(rows) + "\n").encode()),
             atomic_bytes(out_dir / "sole_feasibility.json", json.dumps(summary, indent=2).encode())]
    files.append(_plot(result, out_dir / "sole_feasibility.png", ctx))
    return files


def _plot(result, path: Path, ctx) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.patches import Polygon

    from .cells import sole_layout

    sensor = ctx.scene.sensor if ctx is not None and getattr(ctx, "scene", None) is not None else None
    layout = sensor.cells.layout() if sensor is not None else sole_layout()
    fig, ax = plt.subplots(figsize=(5.0, 6.0))
    for corners, on in zip(layout.corners, result.active):
        ax.add_patch(Polygon(corners[:, ::-1] * 1e3, closed=True, facecolor="tab:orange" if on else "0.92", edgecolor="0.5", lw=0.6))
    for poly, style, label in ((result.pretouch, "b:", "pre-touch polygon"), (result.polygon, "r-", "support polygon")):
        if len(poly):
            closed = np.vstack([poly, poly[:1]]) * 1e3
            ax.plot(closed[:, 1], closed[:, 0], style, lw=1.6, label=label)
    ax.plot(result.cop[1] * 1e3, result.cop[0] * 1e3, "k+", ms=12, mew=2, label="CoP (skin)")
    ax.plot(result.cop_ft[1] * 1e3, result.cop_ft[0] * 1e3, "gx", ms=10, mew=2, label="ZMP (ankle F/T)")
    ax.plot(0, 0, "ko", mfc="none", ms=8, label="ankle")
    ax.set(xlabel="y (mm, left)", ylabel="x (mm, forward)", aspect="equal",
           title=f"M_s {result.ankle_moment:.1f} N m: {'re-plan' if result.ft_replan else 'safe'}; "
                 f"A_p/A_s {result.area_ratio:.2f}: {'re-plan' if result.skin_replan else 'safe'}")
    ax.invert_xaxis()  # looking down on the sole from above: the left (+y) on the left
    ax.autoscale_view()
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", fontsize=7, ncol=3)
    fig.tight_layout(rect=(0.0, 0.08, 1.0, 1.0))
    return save_png(fig, path, dpi=110)


FEASIBILITY = Stage(
    name="sole_feasibility", doc="CoP, support and pre-touch polygons, and the F/T and skin step-feasibility rules",
    reads=("sensor.cells", "sensor.proximity", "sensor.feasibility"), needs=("sole_contact",), run=_feasibility,
    save=pickle_save, load=pickle_load, write=_write_feasibility, summarize=_summarize_feasibility)


def _balance(scene, inputs, ctx):
    import numpy as np

    from .balance import simulate_balance
    from .estimators import G

    sensor = scene.sensor
    return simulate_balance(sensor.cells.layout(), sensor.balance, sensor.foundation.stiffness_n_m3, np.random.default_rng(scene.seed),
                            force_noise_n=sensor.cells.force_noise_n, eps_force_n=sensor.feasibility.eps_force_kg * G)


def _summarize_balance(run) -> dict:
    import numpy as np

    return {"skin_ft_zmp_gap_mm": 1e3 * run.skin_ft_gap(), "zmp_excursion_mm": 1e3 * run.zmp_excursion(),
            "max_com_mm": 1e3 * float(np.abs(run.com).max()), "final_com_mm": [1e3 * float(v) for v in run.com[-1]]}


def _write_balance(run, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    lines = ["t_s,push_n,com_x_m,com_y_m,xi_x_m,xi_y_m,zmp_x_m,zmp_y_m,zmp_skin_x_m,zmp_skin_y_m,zmp_ft_x_m,zmp_ft_y_m"]
    for k in range(len(run.t)):
        values = [run.t[k], run.push[k], *run.com[k], *run.xi[k], *run.zmp[k], *run.zmp_skin[k], *run.zmp_ft[k]]
        lines.append(",".join(f"{v:.6g}" for v in values))
    files = [atomic_bytes(out_dir / "sole_balance.csv", ("\n".join(lines) + "\n").encode())]
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    ax.plot(run.t, run.zmp_ft[:, 0] * 1e3, label="ZMP, ankle F/T")
    ax.plot(run.t, run.zmp_skin[:, 0] * 1e3, "--", label="ZMP, skin")
    ax.plot(run.t, run.com[:, 0] * 1e3, label="CoM")
    ax.plot(run.t, run.xi[:, 0] * 1e3, ":", label="capture point")
    ax.axvspan(*(run.t[run.push != 0][[0, -1]] if (run.push != 0).any() else (0, 0)), color="0.9", label="push")
    ax.set(xlabel="t (s)", ylabel="x (mm)", title=f"skin vs F/T ZMP: max {1e3 * run.skin_ft_gap():.1f} mm")
    ax.legend(fontsize=8)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "sole_balance.png", dpi=110))
    return files


BALANCE = Stage(
    name="sole_balance", doc="the LIPM on one sole under the CP-ZMP regulator with a push, fed by the skin's or the F/T's ZMP",
    reads=("sensor.cells", "sensor.foundation", "sensor.feasibility.eps_force_kg", "sensor.balance", "seed"), needs=(),
    run=_balance, save=pickle_save, load=pickle_load, write=_write_balance, summarize=_summarize_balance)
