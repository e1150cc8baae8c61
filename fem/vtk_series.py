"""An episode as a VTU time series for ParaView: a ``.pvd`` collection and one ``.vtu`` per frame.

Each frame is the linear tet mesh (the vertices and the four-node tets; the solve's stress is one
value per tet, at its centroid) with

- point data ``displacement_m`` (3);
- cell data ``stress_pa`` (6, ParaView's symmetric-tensor order xx, yy, zz, xy, yz, xz), its rate
  ``stress_rate_pa_s``, ``von_mises_pa`` and ``von_mises_rate_pa_s``, ``sed_j_m3`` and
  ``sed_rate_w_m3`` (strain energy density and its rate), ``rod`` (-1: base) and the layer fractions
  ``absorber_fraction``, ``ml_fraction``, ``core_fraction`` (to threshold the ML layer).

Rates are the backward differences of :meth:`fem.quasistatic.Episode.rate` (zero at frame 0).
Files are written under a temporary name and renamed, so an interrupted run leaves no half file.
"""

from __future__ import annotations

import os
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

__all__ = ["write_episode", "write_collection"]

# our Voigt order (xx, yy, zz, yz, xz, xy) -> ParaView's (xx, yy, zz, xy, yz, xz)
_TO_PARAVIEW = (0, 1, 2, 5, 3, 4)


def write_episode(episode, directory: str | Path, stem: str = "solve") -> list[Path]:
    """Write ``stem.pvd`` and ``stem_NNNN.vtu`` (one per frame) into ``directory``; returns the paths
    (the .pvd first). ``episode``: :class:`fem.quasistatic.Episode` with its mesh arrays."""
    import meshio

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    ep = episode
    stress = ep.frames("stress")[:, _TO_PARAVIEW, :]  # (F, 6, T)
    stress_rate = ep.rate("stress")[:, _TO_PARAVIEW, :]
    vm, vm_rate = ep.frames("von_mises"), ep.rate("von_mises")
    sed, sed_rate = ep.frames("sed"), ep.rate("sed")
    disp = ep.frames("displacement")
    static = {
        "rod": ep.tet_rod.astype(np.int32),
        "absorber_fraction": ep.layer_fraction[:, 0].astype(np.float32),
        "ml_fraction": ep.layer_fraction[:, 1].astype(np.float32),
        "core_fraction": ep.layer_fraction[:, 2].astype(np.float32),
    }
    files, times = [], ep.t_s[ep.frame_step]
    for i in range(ep.n_frames):
        cell = {
            "stress_pa": stress[i].T.astype(np.float32),
            "stress_rate_pa_s": stress_rate[i].T.astype(np.float32),
            "von_mises_pa": vm[i].astype(np.float32),
            "von_mises_rate_pa_s": vm_rate[i].astype(np.float32),
            "sed_j_m3": sed[i].astype(np.float32),
            "sed_rate_w_m3": sed_rate[i].astype(np.float32),
            **static,
        }
        mesh = meshio.Mesh(ep.mesh_points, [("tetra", ep.mesh_tets)], point_data={"displacement_m": disp[i].astype(np.float32)},
                           cell_data={k: [v] for k, v in cell.items()})
        path = directory / f"{stem}_{i:04d}.vtu"
        tmp = path.with_name(path.name + ".part.vtu")
        mesh.write(tmp, binary=True, compression="zlib")
        os.replace(tmp, path)
        files.append(path)
    return [write_collection(directory / f"{stem}.pvd", times, files), *files]


def write_collection(pvd: Path, times, files) -> Path:
    """A ParaView ``.pvd`` collection of the files (in pvd's directory) at the given times, atomically."""
    rows = "\n".join(f'    <DataSet timestep="{t:.9g}" part="0" file={quoteattr(Path(f).name)}/>' for t, f in zip(times, files))
    text = f'<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n  <Collection>\n{rows}\n  </Collection>\n</VTKFile>\n'
    tmp = pvd.with_name(pvd.name + ".part")
    tmp.write_text(text)
    os.replace(tmp, pvd)
    return pvd
