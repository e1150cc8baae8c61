"""fem.field_kernels: the compiled sums of the reduced tier's field recovery against their numpy
forms, rows and columns they must not read, and independence of the thread count."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import scipy.sparse as sp

from fem import field_kernels


def _problem(seed=0, n=400, K=12, U=5, density=0.1):
    rng = np.random.default_rng(seed)
    A = sp.random(n, K, density=density, format="csr", random_state=rng, dtype=np.float32)
    c = rng.standard_normal((K, U)).astype(np.float32)
    out = rng.standard_normal((n, U)).astype(np.float32)
    return A, c, out


def test_the_sparse_product_adds_the_used_columns_only():
    A, c, out = _problem()
    used = np.zeros(len(c), dtype=bool)
    used[[1, 4, 5, 9]] = True
    expect = out.astype(float) + A.toarray()[:, used].astype(float) @ c[used].astype(float)
    c[~used] = np.nan  # rows of c marked unused are never read
    field_kernels.add_sparse_product(A.indptr, A.indices, A.data, c, used, out)
    np.testing.assert_allclose(out, expect, rtol=1e-5, atol=1e-5)


def test_the_row_add_is_numpys_fancy_index_add():
    rng = np.random.default_rng(1)
    out = rng.standard_normal((300, 7)).astype(np.float32)
    rows = rng.choice(300, size=90, replace=False)
    values = rng.standard_normal((90, 7)).astype(np.float32)
    expect = out.copy()
    expect[rows] += values
    field_kernels.add_rows(out, rows, values)
    np.testing.assert_array_equal(out, expect)


def test_the_sums_do_not_depend_on_the_thread_count():
    A, c, out = _problem(seed=2, n=5000, K=30, U=16, density=0.3)
    used = np.ones(len(c), dtype=bool)
    results = []
    threads = numba.get_num_threads()
    try:
        for t in (1, threads):
            numba.set_num_threads(t)
            o = out.copy()
            field_kernels.add_sparse_product(A.indptr, A.indices, A.data, c, used, o)
            results.append(o)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(results[0], results[1])


@pytest.mark.parametrize("n_used", [0, 12])
def test_empty_and_full_inputs(n_used):
    A, c, out = _problem(seed=3)
    used = np.arange(len(c)) < n_used
    expect = out.astype(float) + A.toarray()[:, used].astype(float) @ c[used].astype(float)
    field_kernels.add_sparse_product(A.indptr, A.indices, A.data, c, used, out)
    np.testing.assert_allclose(out, expect, rtol=1e-5, atol=1e-5)
    field_kernels.add_rows(out, np.zeros(0, dtype=np.int64), np.zeros((0, out.shape[1]), np.float32))
    np.testing.assert_allclose(out, expect, rtol=1e-5, atol=1e-5)


def test_the_sparse_product_into_an_array_is_scipys_bit_for_bit():
    """sparse_product sums each row as scipy's csr_matvecs does (the reduced tier's precompute relies
    on it: its model stays byte-identical), overwrites what the output held, and does not depend on
    the thread count; copy_rows copies a column-major block into a row-major one."""
    rng = np.random.default_rng(4)
    A = sp.random(3000, 800, density=0.02, format="csr", random_state=rng)
    A.data = rng.standard_normal(A.nnz)  # signs and magnitudes that make the summation order matter
    c = rng.standard_normal((800, 37))
    expect = A @ c
    results = []
    threads = numba.get_num_threads()
    try:
        for t in (1, threads):
            numba.set_num_threads(t)
            out = rng.standard_normal((3000, 37))  # stale values: overwritten
            field_kernels.sparse_product(A.indptr, A.indices, A.data, c, out)
            results.append(out)
    finally:
        numba.set_num_threads(threads)
    for out in results:
        assert out.tobytes() == expect.tobytes()
    src = np.asfortranarray(c)
    out = np.empty_like(c)
    field_kernels.copy_rows(src, out)
    assert out.flags.c_contiguous and np.array_equal(out, c)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_adding_into_columns_rounds_as_numpys_fancy_index_add(dtype):
    """add_columns(out, cols, values) is numpy's ``out[:, cols] += values`` bit for bit: the float64
    sum rounded to out's type once per entry (the reduced tier's precompute adds its blocks' patch
    responses this way into float32 arrays, and its model stays byte-identical), on any number of
    threads; the columns not named are untouched."""
    rng = np.random.default_rng(6)
    out0 = (1e3 * rng.standard_normal((2000, 60))).astype(dtype)
    cols = np.sort(rng.choice(60, 17, replace=False))
    values = rng.standard_normal((2000, 17)) * np.exp(rng.uniform(-25.0, 5.0, (2000, 17)))  # many below out's rounding
    expect = out0.copy()
    expect[:, cols] += values
    threads = numba.get_num_threads()
    try:
        for t in (1, threads):
            numba.set_num_threads(t)
            out = out0.copy()
            field_kernels.add_columns(out, cols, values)
            assert out.dtype == dtype and out.tobytes() == expect.tobytes()
    finally:
        numba.set_num_threads(threads)
    assert not np.array_equal(expect[:, cols], out0[:, cols])  # (the add did something)


@pytest.mark.parametrize("layout", ["rows", "contiguous"])
def test_the_stress_invariants_are_numpys_bit_for_bit(layout):
    """fem.fields.von_mises_and_energy against von_mises and strain_energy_density in float64
    rounded to float32 (how an episode made them before): the reduced tier's transposed view of
    its (6 T, U) rows and a C-ordered array, per-tet and scalar Lame parameters, zero stress."""
    from fem import fields

    rng = np.random.default_rng(7)
    U, T = 9, 1013
    rows = (rng.standard_normal((6 * T, U)) * 10.0 ** rng.uniform(-2, 6, (6 * T, 1))).astype(np.float32)
    rows[:6] = 0.0
    stress = rows.T.reshape(U, 6, T)
    if layout == "contiguous":
        stress = np.ascontiguousarray(stress)
    for lam, mu in ((rng.uniform(1e5, 1e8, T), rng.uniform(1e4, 1e6, T)), (2.0e6, 4.0e5)):
        vm, sed = fields.von_mises_and_energy(stress, lam, mu)
        sigma = np.moveaxis(stress, 1, 0)
        assert vm.tobytes() == fields.von_mises(sigma).astype(np.float32).tobytes()
        assert sed.tobytes() == fields.strain_energy_density(sigma, lam, mu).astype(np.float32).tobytes()
    with pytest.raises(ValueError, match="float32"):
        fields.von_mises_and_energy(stress.astype(float), lam, mu)


def test_fields_by_frame_are_numpys_gather():
    """fem.quasistatic._by_frame: an episode's per-step fields from its distinct loads' (issue 40),
    compiled on the reduced tier's transposed rows and numpy's fancy index on any other layout,
    the same bytes as a[frame_of]."""
    from fem.quasistatic import _by_frame

    rng = np.random.default_rng(2)
    U, T = 7, 301
    rows = rng.standard_normal((6 * T, U)).astype(np.float32)
    view = rows.T.reshape(U, 6, T)
    frame_of = np.array([0, 0, 1, 3, 3, 3, 6, 2, 5, 4, 4])
    for a in (view, np.ascontiguousarray(view), rows[: 3 * T].T.reshape(U, -1, 3)):
        got = _by_frame(a, frame_of)
        assert got.shape == (len(frame_of),) + a.shape[1:] and got.tobytes() == a[frame_of].tobytes()
    out = np.empty((len(frame_of), 6 * T), np.float32)
    field_kernels.gather_columns(rows, frame_of, out)
    assert out.tobytes() == np.ascontiguousarray(rows.T[frame_of]).tobytes()
