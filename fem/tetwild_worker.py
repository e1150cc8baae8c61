"""Run fTetWild (pytetwild) on one surface, in a process of its own.

fTetWild can hang or run for minutes at some sizes, so :mod:`fem.mesh` runs it here under a time
limit. Usage: ``python -m fem.tetwild_worker IN.npz OUT.npz`` where IN holds ``vertices`` (V, 3),
``faces`` (F, 3) and the scalar arguments of :func:`pytetwild.tetrahedralize`; OUT receives
``points`` and ``tets`` as fTetWild returns them (not yet validated or re-oriented).
"""

from __future__ import annotations

import sys

import numpy as np


def main(argv: list[str]) -> int:
    src, dst = argv
    data = np.load(src)
    import pytetwild  # imports pyvista as well (pytetwild 0.4 does so unconditionally)

    points, tets = pytetwild.tetrahedralize(
        np.ascontiguousarray(data["vertices"], dtype=np.float64),
        np.ascontiguousarray(data["faces"], dtype=np.int32),
        edge_length_abs=float(data["edge_length"]),
        epsilon=float(data["epsilon_rel"]),
        coarsen=bool(data["coarsen"]),
        num_threads=int(data["num_threads"]),
        quiet=True,
    )
    tmp = dst + ".part.npz"
    np.savez(tmp, points=np.asarray(points, dtype=np.float64), tets=np.asarray(tets, dtype=np.int64))
    import os

    os.replace(tmp, dst)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
