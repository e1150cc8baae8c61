"""The plantar sole's stages (SPEC 4): ``sole_contact`` (what the cells and the ankle F/T read for the
scene's foot over its terrain), ``sole_feasibility`` (CoP, polygons and both step-feasibility
rules), ``sole_obstacle_table`` (the same for each case of ``sensor.obstacles``, as one table and
the sole plots), ``sole_double_support`` (both feet: the double-support polygon and combined CoP),
``sole_balance`` (the CP-ZMP loop with a push) and ``sole_balance_sweep`` (the balance study over
push magnitudes)."""

from __future__ import annotations

import json
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.plots import save_png
from mlsim.stage import Stage, pickle_load, pickle_save

__all__ = ["CONTACT", "FEASIBILITY", "OBSTACLE_TABLE", "DOUBLE_SUPPORT", "BALANCE", "BALANCE_SWEEP", "check",
           "contact_of_scene", "contact_of_foot", "assessment_of", "obstacle_rows"]


def contact_of_foot(sensor, foot, terrain_spec, rng, static: bool = False):
    """The :class:`other_sensors.sole.contact.SoleContact` of ``foot`` (:class:`FootSpec`) on
    ``terrain_spec`` (:class:`TerrainSpec`) with the sensor's cells and foundation, each force
    sensor's noise drawn from ``rng``: at the landing's impact when the sensor has a ``landing``
    section (and ``static`` is False), else placed statically under ``foot.load_n``."""
    from .contact import SoleContact, height_for_load, sole_contact

    layout, terrain = sensor.cells.layout(), terrain_spec.to_terrain()
    pose = foot.pose()
    k, n = sensor.foundation.stiffness_n_m3, sensor.cells.quadrature
    if sensor.landing is not None and not static:
        return landing_of_foot(sensor, foot, terrain_spec).contact_at_impact(
            rng.normal(0.0, sensor.cells.force_noise_n, (layout.n_cells, 3)))
    z = foot.height_mm * 1e-3 if foot.height_mm is not None else height_for_load(layout, pose, terrain, k, foot.load_n, n)
    exact = sole_contact(layout, pose.with_height(z), terrain, k, n)
    noisy = exact.sensor_forces + rng.normal(0.0, sensor.cells.force_noise_n, exact.sensor_forces.shape)
    return SoleContact(noisy, noisy.sum(axis=1), exact.wrench, exact.gaps, exact.pose)


def landing_of_foot(sensor, foot, terrain_spec):
    """The :class:`other_sensors.sole.landing.Landing` of ``foot`` on ``terrain_spec`` under
    ``sensor.landing`` (noise-free): first contact found at the foot's x, y and angles, the speed
    there from the swing profile, ``foot.load_n`` the weight share taken over."""
    from .landing import first_contact_height, simulate_landing

    layout, terrain, pose = sensor.cells.layout(), terrain_spec.to_terrain(), foot.pose()
    n = sensor.cells.quadrature
    params = sensor.landing.params(foot.load_n, sensor.foundation.stiffness_n_m3, sensor.balance,
                                   first_contact_height(layout, pose, terrain, n))
    return simulate_landing(layout, pose, terrain, params, n)


def contact_of_scene(sensor, seed: int):
    """The :class:`other_sensors.sole.contact.SoleContact` of a :class:`SoleSensor`'s ``foot``, with
    each force sensor's noise drawn from a generator seeded by ``seed``."""
    import numpy as np

    return contact_of_foot(sensor, sensor.foot, sensor.terrain, np.random.default_rng(seed))


def check(scene) -> list:
    """What the schema alone cannot see: an output whose section is missing (SPEC 4's double
    support needs a second foot, the obstacle table its cases)."""
    sensor, problems = scene.sensor, []
    if "sole_double_support" in scene.outputs and sensor.second_foot is None:
        problems.append(("sensor.second_foot", None, "the output sole_double_support needs the other foot: add a [sensor.second_foot] "
                                                     "section (x_mm, y_mm, yaw_deg, load_n)"))
    if "sole_obstacle_table" in scene.outputs and not sensor.obstacles:
        problems.append(("sensor.obstacles", [], "the output sole_obstacle_table needs one or more [[sensor.obstacles]] cases"))
    if sensor.landing is not None and sensor.landing.speed_mm_s is None:
        # the swing profile must reach down to where the foot first meets each terrain it lands on
        from .landing import first_contact_height

        cases = [(sensor.foot, sensor.terrain)] + [(c.foot, c.terrain) for c in sensor.obstacles]
        layout, n = sensor.cells.layout(), sensor.cells.quadrature
        try:
            top = max(first_contact_height(layout, f.pose(), t.to_terrain(), n) for f, t in cases)
        except ValueError:  # no terrain under a foot: the stages say so
            top = 0.0
        if 1e3 * top > sensor.landing.swing_height_mm:
            problems.append(("sensor.landing.swing_height_mm", sensor.landing.swing_height_mm,
                             f"the terrain meets the sole {1e3 * top:.1f} mm above the planned ground, above the swing's apex; "
                             "raise swing_height_mm or give sensor.landing.speed_mm_s"))
    if not problems:  # a consistent scene whose feet or size the contact model or no machine allows (issue 39)
        from .plausibility import problems as implausible

        problems = implausible(scene)
    return problems


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
    reads=("sensor.cells", "sensor.foundation", "sensor.terrain", "sensor.foot", "sensor.landing", "sensor.balance.mass_kg",
           "sensor.balance.z_com_m", "seed"), needs=(), run=_contact,
    version="3",  # 2: proximity is the least gap under the cell's face, not at its centre; 3: a landing when sensor.landing
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


def _layout_of(ctx):
    from .cells import sole_layout

    sensor = ctx.scene.sensor if ctx is not None and getattr(ctx, "scene", None) is not None else None
    return sensor.cells.layout() if sensor is not None else sole_layout()


def _plot(result, path: Path, ctx) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.0, 6.0))
    _draw_sole(ax, _layout_of(ctx), result)
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", fontsize=7, ncol=3)
    fig.tight_layout(rect=(0.0, 0.08, 1.0, 1.0))
    return save_png(fig, path, dpi=110)


def _draw_sole(ax, layout, result, title: str = "") -> None:
    """The sole seen from above (its frame; left +y on the left) with its active cells, support and
    pre-touch polygons, skin CoP and F/T ZMP, and both rules' decisions in the title."""
    import numpy as np
    from matplotlib.patches import Polygon

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
           title=(f"{title}\n" if title else "") + f"M_s {result.ankle_moment:.1f} N m: {'re-plan' if result.ft_replan else 'safe'}; "
                 f"A_p/A_s {result.area_ratio:.2f}: {'re-plan' if result.skin_replan else 'safe'}")
    ax.invert_xaxis()  # looking down on the sole from above: the left (+y) on the left
    ax.autoscale_view()


FEASIBILITY = Stage(
    name="sole_feasibility", doc="CoP, support and pre-touch polygons, and the F/T and skin step-feasibility rules",
    reads=("sensor.cells", "sensor.proximity", "sensor.feasibility"), needs=("sole_contact",), run=_feasibility,
    version="2",  # 2: the skin rule counts an A_p / A_s tie with eps_A within round-off as a tie (re-plan)
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
            "max_com_mm": 1e3 * float(np.abs(run.com).max()), "final_com_mm": [1e3 * float(v) for v in run.com[-1]],
            "upright": run.upright(), "fall_time_s": None if np.isnan(run.fall_time_s) else run.fall_time_s}


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
    run=_balance, save=pickle_save, load=pickle_load, write=_write_balance, summarize=_summarize_balance,
    version="2")  # 2: the ZMP reaches the sole's outline less 10 mm (was: the cells' centres' box); a fall ends the run


# ------------------------------------------------------------------------------ the obstacle table
def obstacle_rows(sensor, seed: int) -> list[tuple]:
    """(name, description, :class:`StepAssessment`, contact) per case of ``sensor.obstacles``: each
    case's foot on its terrain with the scene's cells, foundation, proximity and rules; case i's
    noise from a generator seeded by ``seed`` (as its own single-obstacle scene with that seed)."""
    rows = []
    for case in sensor.obstacles:
        single = sensor.model_copy(update={"terrain": case.terrain, "foot": case.foot})
        contact = contact_of_scene(single, seed)
        rows.append((case.name, case.description, assessment_of(single, contact), contact))
    return rows


def _obstacle_table(scene, inputs, ctx):
    rows = obstacle_rows(scene.sensor, scene.seed)
    for name, _, a, c in rows:
        ctx.log(f"sole obstacle {name}: F_z = {c.wrench[2]:.0f} N, M_s = {a.ankle_moment:.2f} N m ({'re-plan' if a.ft_replan else 'safe'}), "
                f"A_p/A_s = {a.area_ratio:.3f} ({'re-plan' if a.skin_replan else 'safe'})")
    return [(name, description, a, float(c.wrench[2])) for name, description, a, c in rows]


_TABLE_COLUMNS = ("obstacle", "fz_n", "ankle_moment_nm", "ft_rule", "polygon_area_cm2", "sole_area_cm2", "area_ratio", "skin_rule",
                  "active_cells", "sidestep_mm", "skin_cop_x_mm", "skin_cop_y_mm", "ft_zmp_x_mm", "ft_zmp_y_mm")


def _table_values(name, a, fz) -> list:
    step = a.sidestep_skin if a.skin_replan else a.sidestep_ft
    return [name, fz, a.ankle_moment, "re-plan" if a.ft_replan else "keep", 1e4 * a.polygon_area, 1e4 * a.sole_area, a.area_ratio,
            "re-plan" if a.skin_replan else "keep", int(a.active.sum()), 1e3 * step, *(1e3 * a.cop), *(1e3 * a.cop_ft)]


def _write_obstacle_table(rows, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    def fmt(v):
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    table = [_table_values(name, a, fz) for name, _, a, fz in rows]
    csv = [",".join(_TABLE_COLUMNS)] + [",".join(fmt(v) for v in r) for r in table]
    landing = ctx is not None and getattr(ctx, "scene", None) is not None and ctx.scene.sensor.landing is not None
    md = ["Step feasibility on early contact (SPEC 4): ankle F/T rule M_s >= eps_t, skin rule A_p / A_s <= eps_A; "
          + ("at the landing's impact (other_sensors.sole.landing)." if landing else "the foot placed statically under its load."), "",
          "| obstacle | F_z (N) | M_s (N m) | F/T rule | A_p (cm^2) | A_s (cm^2) | A_p / A_s | skin rule | active cells | sidestep (mm) |",
          "|---|---:|---:|---|---:|---:|---:|---|---:|---:|"]
    md += [f"| {r[0]} | {r[1]:.0f} | {r[2]:.2f} | {r[3]} | {r[4]:.1f} | {r[5]:.1f} | {r[6]:.3f} | {r[7]} | {r[8]} | {r[9]:.0f} |"
           for r in table]
    md += [""] + [f"- {name}: {description}" for name, description, *_ in rows if description]
    files = [atomic_bytes(out_dir / "sole_obstacles.csv", ("\n".join(csv) + "\n").encode()),
             atomic_bytes(out_dir / "sole_obstacles.md", ("\n".join(md) + "\n").encode())]
    layout = _layout_of(ctx)
    fig, axes = plt.subplots(1, len(rows), figsize=(4.2 * len(rows), 6.0), squeeze=False)
    for ax, (name, _, a, _) in zip(axes[0], rows):
        _draw_sole(ax, layout, a, title=name)
        ax.title.set_fontsize(8)
    fig.legend(*axes[0, 0].get_legend_handles_labels(), loc="lower center", fontsize=8, ncol=5)
    fig.tight_layout(rect=(0.0, 0.06, 1.0, 1.0))
    files.append(save_png(fig, out_dir / "sole_obstacles.png", dpi=100))
    for name, _, a, _ in rows:
        files.append(_plot(a, out_dir / f"sole_obstacle_{name}.png", ctx))
    return files


def _summarize_obstacle_table(rows) -> dict:
    return {name: {**_summarize_feasibility(a), "fz_n": fz} for name, _, a, fz in rows}


OBSTACLE_TABLE = Stage(
    name="sole_obstacle_table", doc="both step-feasibility rules on each case of sensor.obstacles: one table (CSV, Markdown) and the sole plots",
    reads=("sensor.cells", "sensor.foundation", "sensor.proximity", "sensor.feasibility", "sensor.landing", "sensor.balance.mass_kg",
           "sensor.balance.z_com_m", "sensor.obstacles", "seed"), needs=(),
    run=_obstacle_table, save=pickle_save, load=pickle_load, write=_write_obstacle_table, summarize=_summarize_obstacle_table,
    version="2")  # 2: F_z per row; the contact at a landing's impact when sensor.landing


# -------------------------------------------------------------------------------- double support
def _double_support(scene, inputs, ctx):
    import numpy as np

    from .stance import double_support

    sensor = scene.sensor
    rng = np.random.default_rng(scene.seed)  # the first foot's noise as in sole_contact, then the second's
    # both feet stand (static placement): double support comes after the landing
    contacts = tuple(contact_of_foot(sensor, foot, sensor.terrain, rng, static=True) for foot in (sensor.foot, sensor.second_foot))
    result = double_support(sensor.cells.layout(), contacts, tuple(assessment_of(sensor, c) for c in contacts))
    ctx.log(f"sole double support: polygon {1e4 * result.polygon_area:.0f} cm^2, CoP skin {np.round(1e3 * result.cop, 1)} mm, "
            f"F/T {np.round(1e3 * result.cop_ft, 1)} mm")
    return result


def _summarize_double_support(r) -> dict:
    return {"polygon_area_cm2": 1e4 * r.polygon_area, "polygon_vertices": len(r.polygon),
            "cop_mm": [1e3 * float(v) for v in r.cop], "cop_ft_mm": [1e3 * float(v) for v in r.cop_ft],
            "loads_n": [float(c.wrench[2]) for c in r.contacts],
            "sole_polygon_area_cm2": [1e4 * r.left.polygon_area, 1e4 * r.right.polygon_area],
            "active_cells": [int(r.left.active.sum()), int(r.right.active.sum())]}


def _write_double_support(r, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.patches import Polygon

    summary = _summarize_double_support(r)
    poly = ["x_mm,y_mm"] + [f"{1e3 * x:.6g},{1e3 * y:.6g}" for x, y in r.polygon]
    files = [atomic_bytes(out_dir / "sole_double_support.json", json.dumps(summary, indent=2).encode()),
             atomic_bytes(out_dir / "sole_double_support_polygon.csv", ("\n".join(poly) + "\n").encode())]
    layout = _layout_of(ctx)
    fig, ax = plt.subplots(figsize=(6.0, 6.0))
    for contact, a in zip(r.contacts, (r.left, r.right)):
        for corners, on in zip(layout.corners, a.active):
            world = contact.pose.to_world(corners)[:, :2] * 1e3
            ax.add_patch(Polygon(world[:, ::-1], closed=True, facecolor="tab:orange" if on else "0.92", edgecolor="0.5", lw=0.5))
    closed = np.vstack([r.polygon, r.polygon[:1]]) * 1e3
    ax.plot(closed[:, 1], closed[:, 0], "r-", lw=1.6, label="double-support polygon")
    ax.plot(r.cop[1] * 1e3, r.cop[0] * 1e3, "k+", ms=12, mew=2, label="CoP (skin, both soles)")
    ax.plot(r.cop_ft[1] * 1e3, r.cop_ft[0] * 1e3, "gx", ms=10, mew=2, label="CoP (ankle F/Ts)")
    ax.set(xlabel="world y (mm, left)", ylabel="world x (mm, forward)", aspect="equal",
           title=f"double support: {1e4 * r.polygon_area:.0f} cm^2")
    ax.invert_xaxis()
    ax.autoscale_view()
    fig.legend(*ax.get_legend_handles_labels(), loc="lower center", fontsize=7, ncol=3)
    fig.tight_layout(rect=(0.0, 0.06, 1.0, 1.0))
    files.append(save_png(fig, out_dir / "sole_double_support.png", dpi=110))
    return files


DOUBLE_SUPPORT = Stage(
    name="sole_double_support", doc="both feet on the terrain: each sole's reading, the double-support polygon in the world and the combined CoP",
    reads=("sensor.cells", "sensor.foundation", "sensor.proximity", "sensor.feasibility", "sensor.terrain", "sensor.foot",
           "sensor.second_foot", "seed"), needs=(),
    run=_double_support, save=pickle_save, load=pickle_load, write=_write_double_support, summarize=_summarize_double_support)


# --------------------------------------------------------------------------------- balance study
def _balance_sweep(scene, inputs, ctx):
    import numpy as np

    from .balance import simulate_balance
    from .estimators import G

    sensor = scene.sensor
    layout, runs = sensor.cells.layout(), []
    for push in sensor.balance_sweep.push_n:
        run = simulate_balance(layout, sensor.balance.model_copy(update={"push_n": push}), sensor.foundation.stiffness_n_m3,
                               np.random.default_rng(scene.seed), force_noise_n=sensor.cells.force_noise_n,
                               eps_force_n=sensor.feasibility.eps_force_kg * G)
        runs.append((float(push), run))
    return runs


def balance_sweep_rows(runs) -> list[dict]:
    """One row per push: its magnitude, the peak ZMP excursion (F/T), the largest skin-vs-F/T ZMP
    gap, the peak CoM excursion, when it fell and whether it stood."""
    import numpy as np

    return [{"push_n": push, "zmp_excursion_mm": 1e3 * run.zmp_excursion(), "skin_ft_gap_mm": 1e3 * run.skin_ft_gap(),
             "max_com_mm": 1e3 * float(np.linalg.norm(run.com, axis=1).max()),
             "fall_time_s": None if np.isnan(run.fall_time_s) else run.fall_time_s, "upright": run.upright()}
            for push, run in runs]


def _summarize_balance_sweep(runs) -> dict:
    return {"rows": balance_sweep_rows(runs)}


def _write_balance_sweep(runs, out_dir: Path, ctx) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = balance_sweep_rows(runs)
    csv = ["push_n,zmp_excursion_mm,skin_ft_gap_mm,max_com_mm,fall_time_s,upright"]
    csv += [f"{r['push_n']:.6g},{r['zmp_excursion_mm']:.6g},{r['skin_ft_gap_mm']:.6g},{r['max_com_mm']:.6g},"
            f"{'' if r['fall_time_s'] is None else r['fall_time_s']},{'yes' if r['upright'] else 'no'}" for r in rows]
    b = ctx.scene.sensor.balance if ctx is not None and getattr(ctx, "scene", None) is not None else None
    head = (f"Balance study (SPEC 4): LIPM {b.mass_kg:g} kg, CoM {b.z_com_m:g} m, CP-ZMP regulator (k_xi {b.k_xi:g}, k_f {b.k_f_per_s:g} /s, "
            f"k_x {b.k_x_per_s:g} /s) fed by the {b.zmp_source} ZMP; a push along x for {b.push_duration_s:g} s at {b.push_start_s:g} s."
            if b is not None else "Balance study (SPEC 4).")
    md = [head, "", "| push (N) | peak ZMP excursion (mm) | max abs(skin ZMP - F/T ZMP) (mm) | peak CoM (mm) | upright |",
          "|---:|---:|---:|---:|---|"]
    md += [f"| {r['push_n']:g} | {r['zmp_excursion_mm']:.1f} | {r['skin_ft_gap_mm']:.2f} | {r['max_com_mm']:.1f} | "
           f"{'yes' if r['upright'] else 'no (fell at %.2f s)' % r['fall_time_s']} |" for r in rows]
    files = [atomic_bytes(out_dir / "sole_balance_sweep.csv", ("\n".join(csv) + "\n").encode()),
             atomic_bytes(out_dir / "sole_balance_sweep.md", ("\n".join(md) + "\n").encode())]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10.0, 4.0))
    for push, run in runs:
        ax1.plot(run.t, run.zmp_ft[:, 0] * 1e3, label=f"{push:g} N" + ("" if run.upright() else " (falls)"))
    ax1.axhline(100.0, color="0.5", ls=":", lw=1)
    ax1.set(xlabel="t (s)", ylabel="ZMP x, ankle F/T (mm)", title="ZMP under pushes")
    ax1.legend(fontsize=7, ncol=2)
    pushes = [r["push_n"] for r in rows]
    ax2.plot(pushes, [r["zmp_excursion_mm"] for r in rows], "o-", label="peak ZMP excursion (mm)")
    ax2.plot(pushes, [10 * r["skin_ft_gap_mm"] for r in rows], "s--", label="10 x max skin-F/T ZMP gap (mm)")
    for r in rows:
        if not r["upright"]:
            ax2.axvline(r["push_n"], color="tab:red", alpha=0.3)
    ax2.axhline(100.0, color="0.5", ls=":", lw=1)
    ax2.set(xlabel="push (N)", ylabel="mm", title="balance study (red: falls)")
    ax2.legend(fontsize=7)
    fig.tight_layout()
    files.append(save_png(fig, out_dir / "sole_balance_sweep.png", dpi=110))
    return files


BALANCE_SWEEP = Stage(
    name="sole_balance_sweep", doc="the balance study: sensor.balance's run for each push of sensor.balance_sweep.push_n, as a table",
    reads=("sensor.cells", "sensor.foundation", "sensor.feasibility.eps_force_kg", "sensor.balance", "sensor.balance_sweep", "seed"),
    needs=(), run=_balance_sweep, save=pickle_save, load=pickle_load, write=_write_balance_sweep, summarize=_summarize_balance_sweep)
