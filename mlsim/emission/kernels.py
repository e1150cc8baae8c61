"""Compiled loops of the emission stage (numba).

:func:`von_mises_at` is :func:`mlsim.emission.equivalent_stress.von_mises` of the solve's per-tet
stress read at the emitting patches' tets, without the gathered (S, N, 6) copy, its widening to
float64 and the formula's six temporaries (0.27 s of an episode's 0.69 s of emission on the screw
scene, a loaded machine). The same float64 operations in the same order (only +, -, * and sqrt,
each rounded exactly by IEEE 754), so the same bits.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def von_mises_at(stress, tet, out):
    """out (S, N) float64 = sqrt(3 J2) Pa of the Voigt stress (S, 6, T) Pa (xx, yy, zz, yz, xz, xy) at
    tets tet (N,), in place. One step per thread step: the same values on any thread count."""
    for s in prange(out.shape[0]):
        for i in range(out.shape[1]):
            t = tet[i]
            xx = np.float64(stress[s, 0, t])
            yy = np.float64(stress[s, 1, t])
            zz = np.float64(stress[s, 2, t])
            yz = np.float64(stress[s, 3, t])
            xz = np.float64(stress[s, 4, t])
            xy = np.float64(stress[s, 5, t])
            a = xx - yy
            b = yy - zz
            c = zz - xx
            out[s, i] = np.sqrt(0.5 * (a * a + b * b + c * c) + 3.0 * (yz * yz + xz * xz + xy * xy))
