"""Error against run time of the solve's fidelity knobs: ``mlsim accuracy SCENE --stage solve``.

Runs the scene's load for every combination of mesh edge length x element order x tier (the
``nonlinear`` tier is P2P1 only), each through the pipeline (so meshes and episodes are cached and
a rerun costs nothing), and measures four errors against a reference (by default the finest
mesh, element order 2, ``nonlinear`` tier), over all frames and rods:

- ``rod_base_von_mises``: per rod, the volume-weighted mean von Mises stress over the rod's tets
  whose centroids lie within ``base_band_mm`` above the base (where a bent rod's stress peaks,
  SPEC 1.3) - a mesh-independent measure, unlike the peak of one tet;
- ``rod_contact_force``: the contact force on each rod (3 components);
- ``tip_displacement``: the mean displacement of each rod's tip vertices;
- ``rod_photons``: the photons per second each rod's ML layer emits in each frame (the scene's
  emission stage on the episode): the light the camera sees, the product's output.

Each error is the relative Frobenius norm |a - a_ref| / |a_ref| over frames x rods (x components).
Run time is the per-frame cost of the solve (contact steps and field recovery over frames); the
one-off precompute (assembly, factorisation, compliance or responses) is reported beside it. The
Pareto front (no other configuration both faster and more accurate) is marked per error.
"""

from __future__ import annotations

import csv
import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["ERRORS", "rod_measures", "relative_error", "pareto_front", "solve_accuracy"]

ERRORS = ("rod_base_von_mises", "rod_contact_force", "tip_displacement", "rod_photons")


def rod_measures(ep, base_top_m: float, base_band_m: float = 1.0e-3, emission=None) -> dict[str, np.ndarray]:
    """Mesh-independent per-rod measures of an episode at its frames.

    Returns ``rod_base_von_mises`` (F, R) Pa, ``rod_contact_force`` (F, R, 3) N,
    ``tip_displacement`` (F, R, 3) m and, given the episode's ``emission``
    (:class:`mlsim.emission.EmissionResult`), ``rod_photons`` (F, R) photons/s.
    """
    P, tets = ep.mesh_points, ep.mesh_tets
    R = ep.rod_force_n.shape[1]
    corners = P[tets]  # (T, 4, 3)
    centroid_z = corners[:, :, 2].mean(axis=1)
    e = corners[:, 1:] - corners[:, :1]
    volume = np.abs(np.linalg.det(e)) / 6.0
    vm = ep.frames("von_mises").astype(np.float64)  # (F, T)
    disp = ep.frames("displacement").astype(np.float64)  # (F, P, 3)
    base_vm = np.zeros((ep.n_frames, R))
    tip_u = np.zeros((ep.n_frames, R, 3))
    for r in range(R):
        on = ep.tet_rod == r
        band = on & (centroid_z >= base_top_m - 1e-9) & (centroid_z <= base_top_m + base_band_m)
        if not band.any():
            raise ValueError(f"rod {r} has no tets within {base_band_m * 1e3:g} mm above the base at z = {base_top_m * 1e3:g} mm")
        w = volume[band]
        base_vm[:, r] = vm[:, band] @ w / w.sum()
        verts = np.unique(tets[on])
        top = verts[P[verts, 2] >= P[verts, 2].max() - 1e-9]
        tip_u[:, r] = disp[:, top].mean(axis=1)
    out = {"rod_base_von_mises": base_vm, "rod_contact_force": ep.frames("rod_force_n"), "tip_displacement": tip_u}
    if emission is not None:
        out["rod_photons"] = emission.per_rod(R)[:, :R]
    return out


def relative_error(a: np.ndarray, ref: np.ndarray) -> float:
    """|a - ref| / |ref| (Frobenius); 0 when both vanish, inf when only ref does."""
    num, den = float(np.linalg.norm(a - ref)), float(np.linalg.norm(ref))
    if den == 0.0:
        return 0.0 if num == 0.0 else float("inf")
    return num / den


def pareto_front(cost: np.ndarray, error: np.ndarray) -> np.ndarray:
    """Boolean mask (n,) of the points no other point beats in both cost and error (ties kept)."""
    cost, error = np.asarray(cost, float), np.asarray(error, float)
    keep = np.ones(len(cost), dtype=bool)
    for i in range(len(cost)):
        better = (cost <= cost[i]) & (error <= error[i]) & ((cost < cost[i]) | (error < error[i]))
        keep[i] = not better.any()
    return keep


@dataclass
class Row:
    edge_length_mm: float
    element_order: int
    tier: str
    element: str = ""
    n_tets: int = 0
    n_frames: int = 0
    per_frame_ms: float = float("nan")
    precompute_s: float = float("nan")
    errors: dict = field(default_factory=dict)
    failed: str = ""
    reference: bool = False
    # the fast tiers' own estimate of their per-rod contact force error (fem.quasistatic; with Cosserat rods fem.rod_error)
    # (fem.quasistatic.geometric_error_estimate), next to the measured one
    estimated_force_error: float = float("nan")


def _configs(edges, orders, tiers):
    for e in edges:
        for o in orders:
            for t in tiers:
                if t == "nonlinear" and o != 2:
                    continue  # the nonlinear tier is mixed P2P1
                yield float(e), int(o), t


def solve_accuracy(scene, edges_mm, orders=(1, 2), tiers=("reduced", "linear", "nonlinear"), reference=None, out_dir=None,
                   cache=None, progress: bool = True, log=print) -> list[Row]:
    """Run every configuration and the reference; return the rows (and write CSV, JSON and PNG to
    ``out_dir`` when given). ``reference``: (edge_mm, order, tier), default (min(edges), 2, "nonlinear")."""
    from fem.nonlinear import SolverError
    from mlsim import pipeline

    if scene.load is None:
        raise ValueError("load: the accuracy of the solve needs a scene with a [load] section")
    edges_mm = sorted({float(e) for e in edges_mm}, reverse=True)
    ref_key = tuple(reference) if reference is not None else (min(edges_mm), 2, "nonlinear")
    base_top = scene.sensor.base.thickness_mm * 1e-3

    def episode_of(edge, order, tier):
        sc = scene.with_values({"fidelity.mesh.edge_length_mm": edge, "fidelity.solve.element_order": order,
                                "fidelity.solve.tier": tier, "outputs": ["solve", "emission"]})
        log(f"[accuracy] edge {edge:g} mm, order {order}, {tier}")
        res = pipeline.run(sc, out_dir=None, cache=cache, progress=progress, log=lambda m: None)
        return res.results["solve"], res.results["emission"]

    ref_ep, ref_emission = episode_of(float(ref_key[0]), int(ref_key[1]), str(ref_key[2]))
    ref = rod_measures(ref_ep, base_top, emission=ref_emission)
    rows: list[Row] = []
    keys = list(_configs(edges_mm, orders, tiers))
    if (float(ref_key[0]), int(ref_key[1]), str(ref_key[2])) not in keys:
        keys.append((float(ref_key[0]), int(ref_key[1]), str(ref_key[2])))
    for edge, order, tier in keys:
        row = Row(edge, order, tier, reference=(edge, order, tier) == (float(ref_key[0]), int(ref_key[1]), str(ref_key[2])))
        try:
            ep, emission = episode_of(edge, order, tier)
        except SolverError as exc:
            row.failed = str(exc)
            rows.append(row)
            log(f"[accuracy] edge {edge:g} mm, order {order}, {tier}: failed: {exc}")
            continue
        meas = rod_measures(ep, base_top, emission=emission)
        row.element, row.n_tets, row.n_frames = ep.element, int(len(ep.mesh_tets)), ep.n_frames
        row.per_frame_ms = float(ep.seconds.get("per_frame_ms", np.nan))
        row.precompute_s = float(sum(v for k, v in ep.seconds.items() if k == "precompute" or k.startswith("body_")))
        row.estimated_force_error = float(ep.seconds.get("geometric_error_estimate", np.nan))
        if ep.n_frames != ref_ep.n_frames:
            raise ValueError("the configurations disagree on the number of frames; the load and fps must not change")
        row.errors = {k: relative_error(meas[k], ref[k]) for k in ERRORS}
        rows.append(row)
    ok = [r for r in rows if not r.failed]
    for k in ERRORS:
        front = pareto_front([r.per_frame_ms for r in ok], [r.errors[k] for r in ok])
        for r, f in zip(ok, front):
            r.errors[f"{k}_pareto"] = bool(f)
    if out_dir is not None:
        write(rows, Path(out_dir), scene)
    return rows


def write(rows: list[Row], out_dir: Path, scene) -> list[Path]:
    """``accuracy_solve.csv``, ``accuracy_solve.json`` and ``accuracy_solve.png`` in ``out_dir``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    csv_path, json_path, png_path = out_dir / "accuracy_solve.csv", out_dir / "accuracy_solve.json", out_dir / "accuracy_solve.png"
    header = ["edge_length_mm", "element_order", "tier", "element", "n_tets", "n_frames", "per_frame_ms", "precompute_s", "reference"]
    header += [k for e in ERRORS for k in (f"error_{e}", f"pareto_{e}")] + ["estimated_rod_contact_force_error", "failed"]
    tmp = csv_path.with_name(".accuracy_solve.csv.part")
    with open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for r in rows:
            errs = [v for e in ERRORS for v in (r.errors.get(e, ""), r.errors.get(f"{e}_pareto", ""))]
            w.writerow([r.edge_length_mm, r.element_order, r.tier, r.element, r.n_tets, r.n_frames, f"{r.per_frame_ms:.6g}",
                        f"{r.precompute_s:.6g}", r.reference, *errs, f"{r.estimated_force_error:.6g}", r.failed])
    os.replace(tmp, csv_path)
    payload = {"scene": scene.name, "errors": list(ERRORS), "rows": [r.__dict__ for r in rows]}
    tmp = json_path.with_name(".accuracy_solve.json.part")
    tmp.write_text(json.dumps(payload, indent=2, default=float))
    os.replace(tmp, json_path)
    _plot(rows, png_path)
    return [csv_path, json_path, png_path]


def _plot(rows: list[Row], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ok = [r for r in rows if not r.failed and not r.reference]
    markers = {"reduced": "s", "linear": "o", "nonlinear": "^"}
    colours = {1: "tab:blue", 2: "tab:orange"}
    fig, axes = plt.subplots(1, len(ERRORS), figsize=(5 * len(ERRORS), 4.2), constrained_layout=True)
    for ax, k in zip(axes, ERRORS):
        floor = 1e-6
        for r in ok:
            ax.loglog(max(r.per_frame_ms, 1e-3), max(r.errors[k], floor), markers[r.tier], color=colours[r.element_order], ms=7,
                      mfc="none" if not r.errors.get(f"{k}_pareto") else colours[r.element_order])
            ax.annotate(f"{r.edge_length_mm:g}", (max(r.per_frame_ms, 1e-3), max(r.errors[k], floor)), fontsize=7, xytext=(4, 2),
                        textcoords="offset points")
        front = sorted((r.per_frame_ms, max(r.errors[k], floor)) for r in ok if r.errors.get(f"{k}_pareto"))
        if front:
            ax.step(*zip(*front), where="post", color="k", lw=0.8, label="Pareto front")
        ax.set(xlabel="solve cost per frame (ms)", ylabel=f"relative error: {k.replace('_', ' ')}", title=k.replace("_", " "))
        ax.grid(True, which="both", alpha=0.3)
    handles = [plt.Line2D([], [], marker=m, ls="", color="k", mfc="none", label=t) for t, m in markers.items()]
    handles += [plt.Line2D([], [], marker="o", ls="", color=c, label=f"order {o}") for o, c in colours.items()]
    handles += [plt.Line2D([], [], color="k", lw=0.8, label="Pareto front (filled)")]
    axes[0].legend(handles=handles, fontsize=7, loc="best")
    fig.suptitle("solve: error against the reference vs run time (labels: edge length, mm)")
    tmp = path.with_name(f".{path.stem}.part.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    os.replace(tmp, path)
