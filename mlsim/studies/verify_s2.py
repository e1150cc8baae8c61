"""The SPEC 1.4 verification study: ``mlsim run scenes/verify_fem_s2.toml`` (``outputs = ["verify_s2"]``).

The driver and report of the published FEM set-up of SPEC 1.4, "sliding" (rod on a slab) against
"pressing" (steel block bonded to a slab) under the same lateral force: :func:`run` meshes both
cases, solves every tier of ``spec.tiers`` at every force, records the elastomer's range and what
went wrong; :func:`summary`, :func:`write` report it (``verify_s2_profiles.csv``,
``verify_s2_ratio.csv``, ``verify_s2_profiles.png``). The set-up and its physics (geometry, meshes,
loads, the tiers' solves, the strain measures, :class:`fem.verify_s2.VerifyS2Result`) stay in the
solver library, :mod:`fem.verify_s2`, whose docstring gives the modelling choices. The ``verify_s2``
stage that runs this study is declared in :mod:`mlsim.studies.stages`.
"""

from __future__ import annotations

import os
import time
from pathlib import Path
from typing import Callable, Mapping

import numpy as np

from fem.verify_s2 import (
    CASES,
    MIN_DET_F_WARNING,
    SPEC_ROD_CENTRE_X_MM,
    CaseSystem,
    Geometry,
    Reading,
    VerifyS2Result,
    build_system,
    materials_by_label,
    measure_stats,
    nonlinear_edge_length_mm,
    pressing_mesh,
    profile_points,
    sample_displacement,
    sliding_mesh,
    solve_linear_tier,
    solve_nonlinear_tier,
    strain_beyond_break,
    strain_magnitude,
)

__all__ = ["run", "summary", "write"]


def _check_material_range(result: VerifyS2Result, s: CaseSystem, states: np.ndarray, tier: str, case: str, material: str) -> None:
    """Record the elastomer's largest principal strain and the volume beyond its elongation at break
    per force (NaN where not converged), and say in the messages from which force the load tears it."""
    limit = result.elongation_at_break
    per_force = np.array([
        strain_beyond_break(s, x, limit, finite=tier == "nonlinear") if np.all(np.isfinite(x)) else (np.nan, np.nan)
        for x in states
    ])
    result.material_range[(tier, case)] = {"max_principal_strain": per_force[:, 0], "volume_beyond_break_mm3": per_force[:, 1]}
    torn = np.flatnonzero(per_force[:, 1] > 0.0)
    if torn.size:
        k = torn[np.argmin(result.forces_n[torn])]
        result.messages.append(
            f"{tier} {case}: from {result.forces_n[k]:g} N on, the load strains {material} beyond its elongation at break "
            f"({limit:.1%}): {per_force[k, 1]:.3g} mm^3 of it (largest principal strain {per_force[k, 0]:.0%}). The set-up "
            "tears the elastomer there: the displacements and the ratio at those forces are not a physical prediction"
        )


def run(
    spec,
    progress: bool = False,
    log: Callable[[str], None] = print,
    materials: Mapping[str, object] | None = None,
    reading: Reading | None = None,
) -> VerifyS2Result:
    """Run the SPEC 1.4 verification case: both meshes, every tier of ``spec.tiers``, every force.

    spec: :class:`mlsim.scene.VerifyS2Spec` (mm). materials: {name: Material} to resolve
    ``slab_material`` and ``block_material`` (default: the shipped table; pass the scene's resolved
    materials to honour its overrides). reading: :class:`Reading` (default: the spec's, see
    :meth:`Reading.from_spec`). The linear tier meshes at ``edge_length_mm``, the nonlinear one at
    :func:`nonlinear_edge_length_mm`; the load band (its half-width from ``edge_length_mm``) is the
    same on both. Returns a :class:`VerifyS2Result`.
    """
    from tqdm.auto import tqdm

    t_all = time.perf_counter()
    reading = Reading.from_spec(spec) if reading is None else reading
    geom = Geometry.from_spec(spec, reading=reading)
    edges_mm = {tier: (spec.edge_length_mm if tier == "linear" else nonlinear_edge_length_mm(spec)) for tier in spec.tiers}
    by_label = materials_by_label(spec, materials)
    forces = np.asarray(spec.forces_n, dtype=float)
    pts = profile_points(spec, geom)
    x_slab_mm = pts[0] * 1e3
    result = VerifyS2Result(spec, forces, x_slab_mm, x_slab_mm - (geom.centre_m[0] * 1e3 - SPEC_ROD_CENTRE_X_MM), reading=reading)
    result.elongation_at_break = by_label[0].elongation_at_break.value
    if result.elongation_at_break is None:
        result.messages.append(
            f"{spec.slab_material} has no elongation at break: the forces cannot be checked against the material's range "
            f"(give elongation_at_break in the scene's [materials.{spec.slab_material}])"
        )
    steps = len(CASES) * 3 * len(spec.tiers)
    bar = tqdm(total=steps, desc="verify_s2", disable=None if progress else True, leave=False)
    systems: dict = {}
    try:
        for case in CASES:
            for tier in spec.tiers:
                edge_mm = edges_mm[tier]
                key = f"{case}_{edge_mm:g}mm"
                if (case, edge_mm) not in systems:
                    t0 = time.perf_counter()
                    mesh = sliding_mesh(geom, edge_mm * 1e-3) if case == "sliding" else pressing_mesh(geom, edge_mm * 1e-3)
                    result.seconds[f"mesh_{key}"] = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    systems[(case, edge_mm)] = build_system(mesh, geom, by_label, reading.load_distribution)
                    sys_ = systems[(case, edge_mm)]
                    result.seconds[f"assemble_{key}"] = time.perf_counter() - t0
                    info = {**mesh.info, "dofs": int(sys_.d.n_dofs), "edge_length_mm": edge_mm}
                    info["slice_volume_mm3" if reading.load_distribution == "slice" else "band_area_mm2"] = sys_.band_area_m2 * (1e9 if reading.load_distribution == "slice" else 1e6)
                    result.mesh[case if tier == "linear" or len(edges_mm) == 1 else f"{case}_{tier}"] = info
                    log(f"verify_s2: {case}: {mesh.info['tets']} tets, {sys_.d.n_dofs} DOFs (P2P1, edge {edge_mm:g} mm)")
                else:
                    result.mesh[f"{case}_{tier}"] = result.mesh[case]
                bar.update(2)
                s = systems[(case, edge_mm)]
                t0 = time.perf_counter()
                if tier == "linear":
                    states, rep = solve_linear_tier(s, forces)
                    result.linear[case] = rep
                    ok = np.ones(len(forces), dtype=bool)
                    if case == "pressing" and np.any(s.mesh.label == 1):
                        strain = strain_magnitude(s, states[int(np.argmax(forces))])
                        result.checks["pressing_block_over_slab_max_strain"] = float(strain[s.mesh.label == 1].max() / strain[s.mesh.label == 0].max())
                else:
                    states, reps = solve_nonlinear_tier(s, forces, log=log, elongation_at_break=result.elongation_at_break)
                    result.nonlinear[case] = [{"force_n": float(f), **r} for f, r in zip(forces, reps)]
                    ok = np.array([r["converged"] for r in reps])
                    for f, r in zip(forces, reps):
                        if not r["converged"] and r.get("physical_limit"):
                            result.messages.append(f"nonlinear {case} at {f:g} N: {r['physical_limit']}")
                        elif not r["converged"]:
                            result.messages.append(f"nonlinear {case} at {f:g} N did not converge: {r['message']}")
                        elif r["min_det_f"] < MIN_DET_F_WARNING:
                            result.messages.append(
                                f"nonlinear {case} at {f:g} N converged, but det F falls to {r['min_det_f']:.2g} at a quadrature point: "
                                "an element crushed near a sharp bonded edge, so this value depends on the mesh"
                            )
                result.seconds[f"{tier}_{case}"] = time.perf_counter() - t0
                if result.elongation_at_break is not None:
                    _check_material_range(result, s, states, tier, case, by_label[0].name)
                result.displacement_mm[(tier, case)] = sample_displacement(s, states, pts) * 1e3
                result.measured_mm[(tier, case)] = measure_stats(s, states, geom, reading.measure, spec)
                result.converged[(tier, case)] = ok
                bar.update(1)
    finally:
        bar.close()
    if "linear" in spec.tiers:
        for case in CASES:
            per_force = result.magnitude_mm("linear", case).max(axis=1) / forces
            result.checks[f"linear_{case}_max_u_per_force_mm_per_n"] = per_force.tolist()
            result.checks[f"linear_{case}_max_u_per_force_relative_spread"] = float(np.ptp(per_force) / np.mean(per_force))
    result.seconds["total"] = time.perf_counter() - t_all
    return result


def _per_force(forces: np.ndarray, values: np.ndarray) -> dict:
    return {f"{f:g}": (None if not np.isfinite(v) else float(v)) for f, v in zip(forces, values)}


def summary(result: VerifyS2Result) -> dict:
    """JSON-able summary; the sliding/pressing ratios per tier and force under keys containing ``ratio``."""
    ratio_max = {t: _per_force(result.forces_n, result.ratio(t, "max")) for t in result.tiers}
    ratio_mean = {t: _per_force(result.forces_n, result.ratio(t, "mean")) for t in result.tiers}
    max_mm = {
        t: {c: _per_force(result.forces_n, result.magnitude_mm(t, c).max(axis=1)) for c in CASES} for t in result.tiers
    }
    measured = {
        t: {c: {stat: _per_force(result.forces_n, result.measured(t, c, stat)) for stat in ("max", "mean")} for c in CASES}
        for t in result.tiers
    }
    not_converged = [
        {"tier": t, "case": c, "force_n": float(f)}
        for (t, c), ok in result.converged.items()
        for f, good in zip(result.forces_n, ok)
        if not good
    ]
    material_range = {
        t: {
            c: {key: _per_force(result.forces_n, np.asarray(values)) for key, values in result.material_range[(t, c)].items()}
            for c in CASES
            if (t, c) in result.material_range
        }
        for t in result.tiers
    }
    return {
        "ratio_max_sliding_over_pressing": ratio_max,
        "ratio_mean_sliding_over_pressing": ratio_mean,
        "reading": {"measure": result.reading.measure, "load_distribution": result.reading.load_distribution, "force_at": result.reading.force_at},
        "measured_displacement_mm": measured,
        "max_displacement_mm": max_mm,
        "mesh": result.mesh,
        "linear_solves": result.linear,
        "nonlinear_solves": result.nonlinear,
        "checks": result.checks,
        "not_converged": not_converged,
        "messages": list(result.messages),
        "seconds": result.seconds,
        "elongation_at_break": result.elongation_at_break,
        "material_range": material_range,
        "within_break": {t: _per_force(result.forces_n, result.within_break(t).astype(float)) for t in result.tiers},
    }


def _atomic(path: Path, writer: Callable[[Path], None]) -> Path:
    tmp = path.with_name(path.name + ".part")
    try:
        writer(tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def _profiles_csv(result: VerifyS2Result) -> str:
    lines = ["tier,case,force_n,x_mm,x_slab_mm,ux_mm,uz_mm,u_mm"]
    for (tier, case), u in result.displacement_mm.items():
        mag = np.linalg.norm(u, axis=1)
        for k, f in enumerate(result.forces_n):
            for i in range(len(result.x_slab_mm)):
                lines.append(
                    f"{tier},{case},{f:g},{result.x_spec_mm[i]:.6g},{result.x_slab_mm[i]:.6g},{u[k, 0, i]:.9g},{u[k, 2, i]:.9g},{mag[k, i]:.9g}"
                )
    return "\n".join(lines) + "\n"


def _ratio_csv(result: VerifyS2Result) -> str:
    # the displacements are measured where the reading says (result.reading.measure), written in each row
    # and the elastomer's volume strained beyond its elongation at break per case (NaN when unknown)
    lines = [
        "tier,measure,force_n,sliding_max_u_mm,pressing_max_u_mm,ratio_max,sliding_mean_u_mm,pressing_mean_u_mm,ratio_mean,"
        "sliding_volume_beyond_break_mm3,pressing_volume_beyond_break_mm3,within_break"
    ]
    nan = np.full(len(result.forces_n), np.nan)
    for tier in result.tiers:
        s = {stat: result.measured(tier, "sliding", stat) for stat in ("max", "mean")}
        p = {stat: result.measured(tier, "pressing", stat) for stat in ("max", "mean")}
        torn = {c: result.material_range.get((tier, c), {}).get("volume_beyond_break_mm3", nan) for c in CASES}
        within = result.within_break(tier)
        for k, f in enumerate(result.forces_n):
            vals = [s["max"][k], p["max"][k], s["max"][k] / p["max"][k], s["mean"][k], p["mean"][k], s["mean"][k] / p["mean"][k]]
            vals += [torn["sliding"][k], torn["pressing"][k]]
            lines.append(f"{tier},{result.reading.measure},{f:g}," + ",".join(f"{v:.9g}" for v in vals) + f",{int(within[k])}")
    return "\n".join(lines) + "\n"


def _plot(result: VerifyS2Result, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    tiers = result.tiers
    fig, axes = plt.subplots(1, len(tiers) + 1, figsize=(5.0 * (len(tiers) + 1), 4.2), squeeze=False)
    axes = axes[0]
    rod_lo = SPEC_ROD_CENTRE_X_MM - 0.5 * result.spec.rod_diameter_mm
    rod_hi = SPEC_ROD_CENTRE_X_MM + 0.5 * result.spec.rod_diameter_mm
    block_half = 0.5 * result.spec.block_size_mm[0]
    colours = plt.cm.viridis(np.linspace(0.0, 0.9, len(result.forces_n)))
    for ax, tier in zip(axes, tiers):
        ax.axvspan(rod_lo, rod_hi, color="0.9", label="rod")
        ax.axvspan(SPEC_ROD_CENTRE_X_MM - block_half, SPEC_ROD_CENTRE_X_MM + block_half, fill=False, hatch="//", edgecolor="0.75", lw=0, label="block")
        for k, f in enumerate(result.forces_n):
            ax.plot(result.x_spec_mm, result.magnitude_mm(tier, "sliding")[k], "-", color=colours[k], label=f"{f:g} N")
            ax.plot(result.x_spec_mm, result.magnitude_mm(tier, "pressing")[k], "--", color=colours[k])
        ax.set_yscale("log")
        ax.set_xlabel("x along the slab's top (mm, SPEC 1.4 coordinate)")
        ax.set_ylabel("|u| (mm)")
        ax.set_title(f"{tier}: sliding (solid), pressing (dashed)")
        ax.legend(fontsize=7)
    ax = axes[-1]
    for tier, marker in zip(tiers, "os"):
        torn = ~result.within_break(tier)
        for stat, style in (("max", "-"), ("mean", ":")):
            line = ax.plot(result.forces_n, result.ratio(tier, stat), marker + style, label=f"{tier}, {stat} |u|")[0]
            if torn.any():  # hollow: the elastomer is strained beyond its elongation at break there
                ax.plot(result.forces_n[torn], result.ratio(tier, stat)[torn], marker, mfc="white", color=line.get_color())
    ax.set_xscale("log", base=2)
    ax.set_xlabel("lateral force (N)")
    ax.set_ylabel("sliding / pressing displacement")
    ax.set_title("ratio per force (hollow: elastomer beyond its break)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, format="png", dpi=120)
    plt.close(fig)


def write(result: VerifyS2Result, out_dir: str | Path) -> list[Path]:
    """Write ``verify_s2_profiles.csv``, ``verify_s2_ratio.csv`` and ``verify_s2_profiles.png`` into
    out_dir (each atomically: a temporary name, then renamed). Returns the paths."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    return [
        _atomic(out / "verify_s2_profiles.csv", lambda p: p.write_text(_profiles_csv(result), encoding="utf-8")),
        _atomic(out / "verify_s2_ratio.csv", lambda p: p.write_text(_ratio_csv(result), encoding="utf-8")),
        _atomic(out / "verify_s2_profiles.png", lambda p: _plot(result, p)),
    ]
