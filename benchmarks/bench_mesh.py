"""Meshing cost and accuracy of the default sensor against the edge-length knob.

Prints, per edge length, the median wall time of `build_mesh` over --repeats runs (fTetWild in a
subprocess, snapping, curving, layer fractions), the tet and node counts, and the relative errors
of the total and per-layer volumes against the analytic geometry. Also writes a PNG plot of volume
error against run time. Usage:

    .venv/bin/python benchmarks/bench_mesh.py [--edges 1.5 2.0 2.5] [--repeats 3] [--out out/bench]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path

from fem.geometry import RodArray
from fem.mesh import MeshParams, build_mesh
from mlsim.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--edges", type=float, nargs="+", default=[1.5, 2.0, 2.5])
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", default="out/bench")
    args = ap.parse_args()
    scene = load_scene(ROOT / "scenes" / "mavig_default.toml")
    g = RodArray.from_sensor(scene.sensor)
    rows = []
    for edge in args.edges:
        fid = scene.with_values({"fidelity.mesh.edge_length_mm": edge}).fidelity.mesh
        times, report = [], None
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            _, report = build_mesh(g, MeshParams.from_fidelity(fid), progress=False)
            times.append(time.perf_counter() - t0)
        rows.append({
            "edge_length_mm": edge,
            "envelope_mm": fid.resolved_envelope_mm,
            "median_s": statistics.median(times),
            "runs_s": times,
            "n_tets": report["n_tets"],
            "n_nodes_quadratic": report["n_nodes_quadratic"],
            "volume_rel_error": report["volume_rel_error"],
            "linear_volume_rel_error": report["linear_volume_rel_error"],
            "layer_volume_rel_error": report["layer_volume_rel_error"],
            "slivers": report["quality"]["slivers"],
            "min_dihedral_deg": report["quality"]["min_dihedral_deg"],
        })
    machine = f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"
    print(f"mesh benchmark, default sensor (5 x 5 rods), {args.repeats} run(s) each, {machine}")
    print("| edge mm | envelope mm | median s | tets | P2 nodes | volume err % | straight-tet err % | absorber % | ML % | core % | slivers | min dihedral |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        le = r["layer_volume_rel_error"]
        print(f"| {r['edge_length_mm']:.2f} | {r['envelope_mm']:.4f} | {r['median_s']:.1f} | {r['n_tets']} | {r['n_nodes_quadratic']} | "
              f"{100 * r['volume_rel_error']:+.3f} | {100 * r['linear_volume_rel_error']:+.3f} | {100 * le['absorber']:+.2f} | "
              f"{100 * le['ml']:+.2f} | {100 * le['core']:+.2f} | {r['slivers']} | {r['min_dihedral_deg']:.1f} |")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_mesh.json").write_text(json.dumps({"machine": machine, "rows": rows}, indent=2))
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for key, label in (("volume_rel_error", "total volume"), ("linear_volume_rel_error", "total, straight tets")):
        ax.loglog([r["median_s"] for r in rows], [abs(r[key]) + 1e-9 for r in rows], "o", label=label)
    ax.loglog([r["median_s"] for r in rows], [abs(r["layer_volume_rel_error"]["absorber"]) + 1e-9 for r in rows], "s", label="absorber layer")
    for r in rows:  # points, not lines: fTetWild's time is not monotonic in the edge length
        for key in ("volume_rel_error", "linear_volume_rel_error"):
            ax.annotate(f"{r['edge_length_mm']:g} mm", (r["median_s"], abs(r[key]) + 1e-9), fontsize=7)
    ax.set_xlabel("meshing time per build (s)")
    ax.set_ylabel("|relative volume error|")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "bench_mesh.png", dpi=120)
    print(f"wrote {out / 'bench_mesh.json'} and {out / 'bench_mesh.png'}")


if __name__ == "__main__":
    main()
