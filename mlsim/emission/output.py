"""The emission stage's files: per-frame table (CSV), plot (PNG), and the emitting sheet's exitance as
a VTU time series (ParaView), all written atomically."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

from mlsim.emission import EmissionResult, MLPatches
from mlsim.io import atomic_bytes

__all__ = ["save", "load", "write", "summary"]


def save(result: EmissionResult, path: Path) -> None:
    p = result.patches
    filled = result.filled_fraction if result.filled_fraction is not None else np.zeros(0)
    np.savez(path, photons_per_s=result.photons_per_s, windows_s=result.windows_s, filled=filled, vertices_m=p.vertices_m, faces=p.faces,
             normals=p.normals, area_m2=p.area_m2, rod=p.rod, sample_m=p.sample_m, tet=p.tet)


def load(path: Path) -> EmissionResult:
    with np.load(path) as z:
        patches = MLPatches(z["vertices_m"], z["faces"], z["normals"], z["area_m2"], z["rod"], z["sample_m"], z["tet"])
        filled = z["filled"] if z["filled"].size else None
        return EmissionResult(z["photons_per_s"], z["windows_s"], patches, filled)


def _n_rods(result: EmissionResult) -> int:
    return int(result.patches.rod.max()) + 1


def summary(result: EmissionResult) -> dict:
    per_rod = result.per_rod(_n_rods(result))
    length = result.windows_s[:, 1] - result.windows_s[:, 0]
    return {
        "n_patches": result.patches.n,
        "photons_total": float((result.photons_per_s.sum(axis=1) * length).sum()),
        "peak_photons_per_s": float(result.photons_per_s.sum(axis=1).max()),
        "per_rod_photons": (per_rod[:, :-1] * length[:, None]).sum(axis=0).tolist(),
        "base_photons": float((per_rod[:, -1] * length).sum()),
        "min_filled_trap_fraction": None if result.filled_fraction is None else float(result.filled_fraction.min()),
    }


def write_csv(result: EmissionResult, path: Path) -> Path:
    per_rod = result.per_rod(_n_rods(result))
    cols = {"frame": np.arange(len(per_rod)), "exposure_start_s": result.windows_s[:, 0], "exposure_end_s": result.windows_s[:, 1],
            "total_photons_per_s": result.photons_per_s.sum(axis=1)}
    for r in range(per_rod.shape[1] - 1):
        cols[f"rod{r}_photons_per_s"] = per_rod[:, r]
    cols["base_photons_per_s"] = per_rod[:, -1]
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    np.savetxt(buf, np.column_stack(list(cols.values())), delimiter=",", fmt="%.9g")
    return atomic_bytes(path, buf.getvalue().encode())


def plot(result: EmissionResult, path: Path) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from mlsim.plots import rod_map, save_png

    n = _n_rods(result)
    per_rod = result.per_rod(n)
    t = result.windows_s[:, 0] * 1e3
    fig, ax = plt.subplots(1, 3, figsize=(15, 4), constrained_layout=True)
    ax[0].plot(t, result.photons_per_s.sum(axis=1), "k-o", ms=3, label="all")
    ax[0].plot(t, per_rod[:, -1], "-", label="base between rods")
    ax[0].set(xlabel="exposure start (ms)", ylabel="photons / s", title="ML emission per frame")
    ax[0].legend()
    im = ax[1].imshow(per_rod[:, :-1].T, aspect="auto", origin="lower", extent=(t[0], t[-1], -0.5, n - 0.5), cmap="viridis")
    fig.colorbar(im, ax=ax[1], label="photons / s")
    ax[1].set(xlabel="exposure start (ms)", ylabel="rod", title="per rod")
    length = result.windows_s[:, 1] - result.windows_s[:, 0]
    total = (per_rod[:, :-1] * length[:, None]).sum(axis=0)
    rod_map(fig, ax[2], total, "photons in the episode", "per-rod photons in the episode", "Greens")
    save_png(fig, path)
    return path


def write_vtu_series(result: EmissionResult, directory: Path, stem: str = "emission") -> list[Path]:
    """The emitting sheet per frame with point data ``exitance_photons_s_m2`` (photons per second per
    m^2 leaving the ML layer's inner face) and ``rod``; a ``.pvd`` collection over the frames."""
    import meshio

    from fem.vtk_series import write_collection

    directory.mkdir(parents=True, exist_ok=True)
    p = result.patches
    files = []
    for f in range(len(result.photons_per_s)):
        mesh = meshio.Mesh(p.vertices_m, [("triangle", p.faces)],
                           point_data={"exitance_photons_s_m2": (result.photons_per_s[f] / p.area_m2).astype(np.float32),
                                       "rod": p.rod.astype(np.int32)})
        path = directory / f"{stem}_{f:04d}.vtu"
        tmp = path.with_name(path.name + ".part.vtu")
        mesh.write(tmp, binary=True, compression="zlib")
        os.replace(tmp, path)
        files.append(path)
    return [write_collection(directory / f"{stem}.pvd", result.windows_s[:, 0], files), *files]


def write(result: EmissionResult, out_dir: Path) -> list[Path]:
    files = write_vtu_series(result, out_dir / "emission")
    files.append(write_csv(result, out_dir / "emission.csv"))
    files.append(plot(result, out_dir / "emission.png"))
    return files
