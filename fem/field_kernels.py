"""Compiled accumulations of the reduced tier's field recovery (:func:`fem.quasistatic.reduced_fields_of`).

The recovery writes (n, U) float32 fields (n = 6 T stress or 3 P displacement rows, U distinct
loads of an episode) as sums of precomputed responses. Two of its sums are poor fits for numpy:

- the far field, ``out += A[:, used] @ c[used]`` with A (n, K) the far-field basis in CSR, its
  small entries dropped (:data:`fem.quasistatic.FAR_FIELD_DROP`): scipy's sparse-dense product
  makes a new (n, U) array and reads every column, loaded or not;
- a rod's own rows, ``out[rows] += values``: numpy's fancy-index add gathers, adds and scatters in
  three passes with two temporaries.

Both are plain loops here, each output row written by one thread in a fixed order, so the result
does not depend on the thread count. The reduced tier's precompute (:meth:`fem.quasistatic.ReducedModel.build`)
reads its solves' blocks through three more: a sparse-dense product into a given array, each row
summed as scipy's ``csr_matvecs`` sums it (the same bits, on every core), a copy of a
column-major block into a row-major one on every core, and a block's patch responses added into
some columns of the float32 responses as numpy's ``out[:, cols] += values`` adds them.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def add_sparse_product(indptr, indices, data, c, used, out):
    """out += A[:, used] @ c[used] in place.

    A (n, K) in CSR (indptr (n + 1,), indices, data); c (K, U); used (K,) bool: the rows of c that
    may be nonzero (the others are skipped unread); out (n, U)."""
    n, U = out.shape
    for i in prange(n):
        for p in range(indptr[i], indptr[i + 1]):
            k = indices[p]
            if used[k]:
                v = data[p]
                for u in range(U):
                    out[i, u] += v * c[k, u]


@njit(parallel=True, cache=True)
def add_rows(out, rows, values):
    """out[rows] += values in place: out (n, U), rows (k,) distinct row indices, values (k, U)."""
    U = out.shape[1]
    for j in prange(rows.shape[0]):
        r = rows[j]
        for u in range(U):
            out[r, u] += values[j, u]


@njit(parallel=True, cache=True)
def sparse_product(indptr, indices, data, c, out):
    """out = A @ c in place, every row of ``out`` written.

    A (n, K) in CSR (indptr (n + 1,), indices, data); c (K, U) float64 (float32 for the render's
    transport matrices, :data:`mlsim.render.kernels.csr_times_dense`), row-major (a row of c is read
    at once); out (n, U). Each row is summed from zero in the CSR's order, one product added
    at a time, as scipy's ``A @ c`` (``csr_matvecs``) sums it: the same bits, on every core
    instead of one, and into an array the caller keeps instead of a new one."""
    n, U = out.shape
    for i in prange(n):
        for u in range(U):
            out[i, u] = 0.0
        for p in range(indptr[i], indptr[i + 1]):
            k = indices[p]
            v = data[p]
            for u in range(U):
                out[i, u] += v * c[k, u]


@njit(parallel=True, cache=True)
def copy_rows(src, out):
    """out[:] = src: src (n, U) in any order (a direct solver's column-major solution), out (n, U)
    row-major, on every core (numpy's copy between the two orders runs on one)."""
    n, U = out.shape
    for i in prange(n):
        for u in range(U):
            out[i, u] = src[i, u]


@njit(parallel=True, cache=True)
def add_columns(out, cols, values):
    """out[:, cols] += values in place: out (n, K) (float32 or float64), cols (k,) distinct column
    indices, values (n, k) float64. Each entry is rounded as numpy rounds it, the sum in float64 and
    then to out's type: the same bits, but one pass on every core where numpy's fancy-index add
    gathers the columns, adds and scatters them (three passes over a float32 (6 T, 3 M) array whose
    rows are 2 KB apart, on one core: 3.2 s of the screw sensor's precompute)."""
    n = out.shape[0]
    for i in prange(n):
        for j in range(cols.shape[0]):
            c = cols[j]
            out[i, c] = out[i, c] + values[i, j]


@njit(cache=True, error_model="numpy")
def stress_invariants(stress, lam, mu, vm, sed):
    """The von Mises stress and the strain energy density of stresses, in place: stress (U, 6, T)
    float32 in Voigt order (any strides: the reduced tier's fields are a transposed view), lam, mu
    (T,) Pa; vm, sed (U, T) float32.

    :func:`fem.fields.von_mises` and :func:`fem.fields.strain_energy_density` of the stresses
    widened to float64, each result rounded to float32, in one pass instead of numpy's two sets of
    six float64 copies and a dozen passes (15 ms of a screw-scene episode's 85): the same float64
    operations in numpy's order, so the same bits. Loads innermost, where the reduced tier's
    stresses are contiguous."""
    U, T = stress.shape[0], stress.shape[2]
    for t in range(T):
        bulk = lam[t] + 2.0 * mu[t] / 3.0
        four_mu = 4.0 * mu[t]
        eighteen_bulk = 18.0 * bulk
        for u in range(U):
            s0, s1, s2 = np.float64(stress[u, 0, t]), np.float64(stress[u, 1, t]), np.float64(stress[u, 2, t])
            s3, s4, s5 = np.float64(stress[u, 3, t]), np.float64(stress[u, 4, t]), np.float64(stress[u, 5, t])
            tr = s0 + s1 + s2
            mean = tr / 3.0
            a, b, c = s0 - mean, s1 - mean, s2 - mean
            ss = a * a + b * b + c * c + 2.0 * (s3 * s3 + s4 * s4 + s5 * s5)
            vm[u, t] = np.float32(np.sqrt(1.5 * ss))
            sed[u, t] = np.float32(ss / four_mu + tr * tr / eighteen_bulk)


@njit(cache=True)
def gather_columns(rows, cols, out):
    """out[s, i] = rows[i, cols[s]] in place: rows (n, U) row-major, cols (S,) in 0..U-1, out (S, n).

    An episode's per-step fields from its distinct loads' (the reduced tier recovers them as
    (6 T, U) and (3 P, U) rows): numpy's ``rows.T[cols]`` gathers from the transposed view one
    strided element at a time (6 ms of a screw-scene episode for the stresses); here each row of
    ``rows`` is read once, contiguously. A copy: the same bits."""
    n, S = rows.shape[0], cols.shape[0]
    for i in range(n):
        for s in range(S):
            out[s, i] = rows[i, cols[s]]
