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


@njit(parallel=True, cache=True, error_model="numpy")
def interpolate_rows(sigma, idx, nxt, w, one_minus_w, out):
    """out (G, N) = sigma[idx] * one_minus_w[:, None] + sigma[nxt] * w[:, None] in place: the stress
    history sigma (S, N) interpolated onto the merged grid (:func:`mlsim.emission.detrapping.merged_grid`),
    numpy's two products and sum per element without its three (G, N) temporaries."""
    n = sigma.shape[1]
    for g in prange(idx.shape[0]):
        a, b = idx[g], nxt[g]
        wa, wb = one_minus_w[g], w[g]
        for i in range(n):
            out[g, i] = sigma[a, i] * wa + sigma[b, i] * wb


@njit(parallel=True, cache=True, error_model="numpy")
def detrapping_rates(sig_a, sig_b, k, h, inv_tau, rate, lam, x):
    """One interval of :func:`mlsim.emission.detrapping.detrapped_fraction`, before its exponentials,
    in place per patch: rate = k max(sig_b - sig_a, 0) / h (1/s), lam = rate + inv_tau, x = -lam h.
    (The exponentials stay numpy's: numba's exp and expm1 round differently on AVX-512 hosts.)"""
    for i in prange(sig_a.shape[0]):
        d = sig_b[i] - sig_a[i]
        if d < 0.0:  # np.maximum(d, 0.0) (the stresses are finite)
            d = 0.0
        r = k * d
        r = r / h
        rate[i] = r
        l_ = r + inv_tau
        lam[i] = l_
        x[i] = -l_ * h


@njit(parallel=True, cache=True, error_model="numpy")
def detrapping_update(rate, lam, decay, expm1_x, h, inv_tau, n, cumulative_before, cumulative_after, first):
    """The rest of that interval (inv_tau > 0), in place per patch: the mean filling's factor
    -expm1(x) / lam, the filling it relaxes to inv_tau / lam, the detrapped fraction of the
    interval rate (n_inf h + (n - n_inf) factor) added to the cumulative one (``first``: the
    interval's alone), and the filling at the interval's end n_inf + (n - n_inf) exp(x). The
    operations of numpy's passes, in their order."""
    for i in prange(rate.shape[0]):
        factor = -expm1_x[i]
        factor = factor / lam[i]
        n_inf = inv_tau / lam[i]
        gap = n[i] - n_inf
        step = n_inf * h
        step = step + gap * factor
        step = step * rate[i]
        cumulative_after[i] = step if first else cumulative_before[i] + step
        gap = gap * decay[i]
        n[i] = n_inf + gap


@njit(cache=True)
def sum_by_index(values, idx, out):
    """out (F, K) = per frame, the values (F, N) summed by index idx (N,) in 0..K-1, from zero in
    the values' order: numpy's ``bincount(idx, weights=values[f], minlength=K)`` of each frame
    (the same additions in the same order: the same bits), in one pass instead of a call a frame."""
    for f in range(values.shape[0]):
        for k in range(out.shape[1]):
            out[f, k] = 0.0
        for i in range(idx.shape[0]):
            out[f, idx[i]] += values[f, i]
