"""A sweep's report in its folder: ``sweep.csv`` and ``sweep.md`` (one row per variant), a line plot
of each metric against each varied field (``sweep_<field>.png``) and a Pareto plot of brightness
against tear risk (``pareto.png``).

Tear risk is the largest over the loads of peak principal strain / elongation at break (1 / the
strain safety factor; 1 is a tear); where the table gives no elongation at break, the stress ratio
(peak principal stress / tensile strength) stands in, and where it gives neither the variant has no
tear risk and stays off the Pareto plot.
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path

from mlsim.io import atomic_bytes

__all__ = ["rows", "write_report", "pareto_front"]


def _num(value):
    return value if isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value) else None


def rows(records: list[dict], varies, load_names: list[str]) -> list[dict]:
    """One flat dict per variant: the varied values, then each load's figures (prefixed with the
    load's name), the separation and direction figures, the cost and the reasons of what failed."""
    out = []
    for rec in records:
        row = {"variant": rec["variant_id"], "label": rec["label"]}
        for v in varies:
            row[v.name] = rec["values"].get(v.path)
        reasons = [] if rec.get("buildable", True) else [f"refused: {rec['reason']}"]
        reasons += [rec["reason"]] if rec.get("retry") else []  # its process was killed (mlsim.sweep.isolated)
        risks = []
        for name in load_names:
            r = rec.get("loads", {}).get(name)
            if r is None:
                continue
            if not r.get("ok"):
                # the rods collapse under the load (mlsim.errors.RodCollapseError): the load they carried last is a figure
                row[f"{name}_collapse_n"] = r.get("collapse_force_n")
                collapsed = f"the rods collapse at {r['collapse_force_n']:.3g} N: " if r.get("collapse_force_n") is not None else ""
                reasons.append(f"{name}: {collapsed}{r['reason']}")
                continue
            row[f"{name}_photons"] = r.get("total_photons")
            row[f"{name}_peak_rod_dn"] = r.get("peak_rod_dn")
            row[f"{name}_photons_per_n"] = r.get("photons_per_newton")
            row[f"{name}_force_n"] = r.get("peak_normal_force_n")
            row[f"{name}_stress_kpa"] = r.get("peak_principal_stress_kpa")
            row[f"{name}_strain_pct"] = r.get("peak_principal_strain_pct")
            row[f"{name}_sf_stress"] = r.get("safety_factor_stress")
            row[f"{name}_sf_strain"] = r.get("safety_factor_strain")
            row[f"{name}_tears"] = r.get("tears")
            row[f"{name}_force_err_est"] = r.get("solve_error_estimate")  # the fast tiers' own estimate (fem.quasistatic)
            # Cosserat rods: bent rods let go (fem.rod_error.force_error_estimate), where the estimate does not hold
            releases = r.get("solve_error_releases")
            row[f"{name}_releases"] = None if releases is None else len(releases)
            bent = r.get("solve_error_bent")  # and rods dragged over near buckling (fem.rod_error.BENT_AXIAL)
            row[f"{name}_bent"] = None if bent is None else len(bent)
            # which tier answered each load; "nonlinear<linear": the linear tier refused it as beyond its model
            # (mlsim.errors.OutOfRangeError) and the nonlinear tier answered (with backward-Euler dynamics: "+be")
            esc = r.get("escalated") or {}
            solved = r.get("solve_tier") + ("+be" if esc.get("dynamics") == "backward_euler" else "") + (f"<{esc['from_tier']}" if esc else "")
            row["tiers"] = ", ".join(filter(None, [row.get("tiers"), f"{name}: {solved}/{r.get('render_tier', '-')}"]))
            sf = r.get("safety_factor_strain") or r.get("safety_factor_stress")
            if _num(sf):
                risks.append(1.0 / sf)
            elif "peak_principal_strain_pct" in r:
                reasons.append(f"{name}: no safety factor: the materials table gives {r.get('material_of_peak')} no elongation at break "
                               "or tensile strength (SPEC 1.2: not given; add them under [materials.NAME])")
        row["tear_risk"] = max(risks) if risks else None
        # None (shown "-") where no load measured it (a refused variant, failed loads, no "tear" metric): not "no"
        measured = [row[f"{n}_tears"] for n in load_names if row.get(f"{n}_tears") is not None]
        row["tears"] = any(measured) if measured else None
        sep = rec.get("separation")
        if sep is not None:
            if sep.get("ok"):
                row.update(hough_ok=sep.get("hough_ok"), min_valley=sep.get("min_valley"), rim_gap_px=sep.get("min_rim_gap_px"),
                           hough_offset_px=sep.get("hough_max_offset_px"))
                if not sep.get("hough_ok"):
                    reasons.append(f"hough: {sep.get('hough_reason')}")
            else:
                reasons.append(f"separation: {sep['reason']}")
        d = rec.get("direction")
        if d is not None:
            if d.get("ok"):
                row["direction_mae_deg"] = d.get("mean_abs_error_deg")
                if d.get("without_events"):
                    reasons.append(f"direction: no DLLM event at {', '.join(f'{a:g}' for a in d['without_events'])} deg")
            else:
                reasons.append(f"direction: {d['reason']}")
        row["beam_strain_per_n"] = rec.get("beam_strain_per_n")
        row["seconds"] = rec.get("seconds")
        row["failed"] = " | ".join(reasons)
        out.append(row)
    return out


def pareto_front(points: list[tuple[float, float]]) -> list[bool]:
    """Which (risk, brightness) points no other point beats: lower or equal risk and higher or equal
    brightness, one of them strictly."""
    front = []
    for i, (r, b) in enumerate(points):
        beaten = any((r2 <= r and b2 >= b) and (r2 < r or b2 > b) for j, (r2, b2) in enumerate(points) if j != i)
        front.append(not beaten)
    return front


def _fmt(value) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _cell(row: dict, column: str) -> str:
    """A Markdown cell: the value, and a load's force error estimate marked where it does not hold (bent rods let
    go, or rods dragged over near buckling: its ``releases`` or ``bent`` above 0; fem.rod_error)."""
    text = _fmt(row.get(column))
    if column.endswith("_force_err_est") and text != "-":
        load = column[: -len("_force_err_est")]
        if any((row.get(f"{load}_{k}") or 0) > 0 for k in ("releases", "bent")):
            text += " (does not hold)"
    return text


def write_report(out: Path, records: list[dict], varies, meta: dict, summary: dict) -> list[Path]:
    """The CSV, Markdown table and plots of a sweep's records (module docstring); returns the files."""
    load_names = [ld["name"] for ld in meta["loads"]]
    table = rows(records, varies, load_names)
    # a fixed order (the varied fields, each load's figures in load order, the rest), of the columns
    # some variant has a value in
    per_load = ("photons", "peak_rod_dn", "photons_per_n", "force_n", "stress_kpa", "strain_pct", "sf_stress", "sf_strain", "tears",
                "force_err_est", "releases", "bent", "collapse_n")
    order = ["variant", "label", *(v.name for v in varies), *(f"{n}_{m}" for n in load_names for m in per_load), "tear_risk", "tears",
             "hough_ok", "min_valley", "rim_gap_px", "hough_offset_px", "direction_mae_deg", "beam_strain_per_n", "tiers", "seconds", "failed"]
    present = {k for row in table for k, v in row.items() if v not in (None, "")}
    columns = [c for c in order if c in present] + sorted(present - set(order))
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=columns, extrasaction="ignore")
    w.writeheader()
    for row in table:
        w.writerow({k: ("" if row.get(k) is None else row.get(k)) for k in columns})
    files = [out / "sweep.csv"]
    atomic_bytes(files[0], buf.getvalue().encode())
    shown = [c for c in columns if c not in ("variant", "failed", "label") and not c.endswith("_tears") and not c.endswith("_force_n")
             and not c.endswith("_sf_stress")]
    md = [f"# Sweep of {meta['base_scene'].get('name', 'scene')}: " + ", ".join(f"`{v['path']}`" for v in meta["varies"]), "",
          f"{summary['stored']}/{summary['variants']} variants; loads {', '.join(load_names)}; metrics {', '.join(meta['metrics'])}; "
          f"direction angles {meta['angles_deg']} deg.", "",
          "| " + " | ".join(shown) + " |", "|" + "---|" * len(shown)]
    md += ["| " + " | ".join(_cell(row, c) for c in shown) + " |" for row in table]
    failures = [(row["label"], row["failed"]) for row in table if row["failed"]]
    if failures:
        md += ["", "## What failed", ""] + [f"- {label}: {why}" for label, why in failures]
    md += ["", "Photons: over the episode, every rod. DN: the brightest rod's mean 8-bit grey level above its darkest frame. "
           "Strain: peak principal (small-strain) strain; sf: safety factor (elongation at break / peak strain; "
           "tensile strength / peak stress); tear_risk: 1 / the smallest safety factor over the loads; tears: a safety factor below 1 "
           "under any load (the press is the design load). min_valley: the "
           "calibration frame's darkest gap between neighbouring disks (0 merged, 1 black). beam_strain_per_n: SPEC 1.3's "
           "cantilever sensitivity 4 L / (pi r^3 E). tiers: solve/render per load (nonlinear+be<linear: the linear tier refused the load as beyond its model, the nonlinear tier answered it with backward-Euler dynamics); force_err_est: the fast tiers' own estimate of "
           "their per-rod contact force error (fem.quasistatic: first-order kinematics from the rods' bending; Cosserat rods from "
           "their ends' response turned with their tips, fem.rod_error; none with second-order rod kinematics); releases: with "
           "Cosserat rods, how many times a bent rod was let go (it snaps back at a step that depends on its frictional equilibrium: "
           "where above 0 the estimate does not hold); bent: with Cosserat rods, how many rods were dragged over, sliding past a tenth of their length under more than half their free Euler load (where their tips land follows the path: where above 0 the estimate does not hold; either marks the estimate \"does not hold\"); collapse_n: the load the rods collapse at (the last that converged: held Cosserat "
           "rods past their clamped-guided buckling load, where a dead load snaps through), in place of the load's figures; the deformed render tier is within 1 % per rod of path tracing (`mlsim accuracy --stage render`)."]
    files.append(out / "sweep.md")
    atomic_bytes(files[-1], ("\n".join(md) + "\n").encode())
    files += _plots(out, table, varies, load_names)
    return files


def _plots(out: Path, table: list[dict], varies, load_names) -> list[Path]:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    metrics = [c for c in (*(f"{n}_photons" for n in load_names), *(f"{n}_photons_per_n" for n in load_names),
                           *(f"{n}_strain_pct" for n in load_names), "tear_risk", "min_valley", "direction_mae_deg")
               if any(_num(row.get(c)) is not None for row in table)]
    files = []
    for v in varies:
        xs = [row.get(v.name) for row in table]
        numeric = all(_num(x) is not None for x in xs)
        if not metrics:
            break
        ncols = min(4, len(metrics))
        nrows = -(-len(metrics) // ncols)
        fig, axes = plt.subplots(nrows, ncols, figsize=(3.4 * ncols, 2.8 * nrows), squeeze=False)
        for ax in axes.ravel()[len(metrics):]:
            ax.set_visible(False)
        for ax, m in zip(axes.ravel(), metrics):
            pts = [(x, row.get(m)) for x, row in zip(xs, table) if _num(row.get(m)) is not None]
            if numeric:
                pts.sort()
                ax.plot([p[0] for p in pts], [p[1] for p in pts], "o-")
            else:
                ax.plot(range(len(pts)), [p[1] for p in pts], "o")
                ax.set_xticks(range(len(pts)), [str(p[0]) for p in pts], rotation=45)
            ax.set_xlabel(v.name)
            ax.set_title(m, fontsize=9)
            if m == "tear_risk":
                ax.axhline(1.0, color="r", lw=0.8, ls="--")
        fig.tight_layout()
        path = out / f"sweep_{v.name}.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        files.append(path)
    # brightness: the swipe's photons where there is a swipe (SPEC 1.5's brightness test), else the first load's
    ordered = sorted(load_names, key=lambda n: n != "swipe")
    bright = next((f"{n}_photons" for n in ordered if any(_num(r.get(f"{n}_photons")) is not None for r in table)), None)
    pts = [(row["tear_risk"], row[bright], row["label"]) for row in table
           if bright and _num(row.get("tear_risk")) is not None and _num(row.get(bright)) is not None]
    if pts:
        front = pareto_front([(p[0], p[1]) for p in pts])
        fig, ax = plt.subplots(figsize=(5.5, 4.2))
        for (r, b, label), on in zip(pts, front):
            ax.plot(r, b, "o", color="C1" if on else "C0")
            ax.annotate(label, (r, b), fontsize=7, xytext=(3, 3), textcoords="offset points")
        ax.axvline(1.0, color="r", lw=0.8, ls="--", label="tears (risk 1)")
        ax.set_xlabel("tear risk (peak strain / elongation at break)")
        ax.set_ylabel(f"brightness: {bright}")
        ax.set_title("brightness against tear risk (orange: Pareto front)", fontsize=9)
        ax.legend(fontsize=8)
        fig.tight_layout()
        path = out / "pareto.png"
        fig.savefig(path, dpi=100)
        plt.close(fig)
        files.append(path)
    return files
