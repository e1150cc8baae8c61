"""mlsim.render.kernels.csr_times_dense, the transport matrices' batched product: against scipy's,
with empty rows and columns, the same bit for bit on one thread and on all."""

from __future__ import annotations

import numba
import numpy as np
import pytest
import scipy.sparse as sp

from mlsim.render.kernels import csr_times_dense


def test_the_batched_sparse_product_is_scipys_and_does_not_depend_on_threads():
    rng = np.random.default_rng(3)
    A = sp.random(300, 120, density=0.05, random_state=4, format="csr", dtype=np.float32)
    A = sp.csr_matrix(A.multiply(sp.csr_matrix(np.repeat((np.arange(300) % 7 != 0)[:, None], 120, axis=1))))  # empty rows
    E = rng.random((120, 5)).astype(np.float32)
    out = np.zeros((300, 5), np.float32)
    csr_times_dense(A.indptr, A.indices, A.data, E, out)
    np.testing.assert_allclose(out, A.toarray().astype(np.float64) @ E, rtol=1e-5, atol=1e-7)
    assert np.all(out[::7] == 0.0)
    threads = numba.get_num_threads()
    one = np.zeros_like(out)
    try:
        numba.set_num_threads(1)
        csr_times_dense(A.indptr, A.indices, A.data, E, one)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one, out)
    empty = np.zeros((300, 0), np.float32)
    csr_times_dense(A.indptr, A.indices, A.data, np.zeros((120, 0), np.float32), empty)  # no frames
    assert empty.shape == (300, 0)


def test_the_rasteriser_reads_vertex_values_at_samples_on_vertices_and_never_goes_negative():
    """A grid mesh whose vertices sit on the pixel centres (k = 1): every sample lies on a vertex
    and on edges, so each pixel is exactly its vertex's value (times the throughput), whichever
    triangle claims it; half the vertices dark beside bright ones, and no pixel below zero. The
    nearer of two overlapping sheets wins (the z-buffer)."""
    from mlsim.render.kernels import rasterise_direct

    n = 24
    yy, xx = np.mgrid[0:n, 0:n]
    uv = np.stack([xx.ravel() + 0.5, yy.ravel() + 0.5], axis=1).astype(np.float64)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int64)
    rng = np.random.default_rng(5)
    value = (1e15 * rng.random(n * n) * (rng.random(n * n) > 0.5)).astype(np.float32)
    throughput = np.full((n, n), 0.5, np.float32)
    orientation = -1.0  # (a, c, b): clockwise on the screen, y down
    image = rasterise_direct(uv[None], np.ones((1, n * n), np.float32), faces, value[None], 1, orientation, n, n, throughput, 4)[0]
    assert image.min() >= 0.0
    np.testing.assert_allclose(image, 0.5 * value.reshape(n, n), rtol=1e-5, atol=1e-6 * value.max())
    # a second sheet over the first, nearer (depth 0.5 < 1): it hides it wherever it covers
    uv2 = np.concatenate([uv, uv])
    depth = np.concatenate([np.ones(n * n), np.full(n * n, 0.5)]).astype(np.float32)[None]
    two = np.concatenate([value, np.full(n * n, 7e14, np.float32)])[None]
    image = rasterise_direct(uv2[None], depth, np.concatenate([faces, faces + n * n]), two, 1, orientation, n, n, throughput, 4)[0]
    np.testing.assert_allclose(image, 0.5 * 7e14, rtol=1e-6)
    # seen from behind (the other winding), nothing
    assert rasterise_direct(uv[None], np.ones((1, n * n), np.float32), faces[:, ::-1].copy(), value[None], 1, orientation, n, n,
                            throughput, 4).max() == 0.0


def test_the_largest_displacement_and_the_in_place_product_are_numpys():
    """largest_displacement is the largest vertex distance per frame (zero at rest);
    TransportMatrix.apply(add_to=) adds the product in place, bit for bit, and checks the buffer."""
    from mlsim.render.kernels import largest_displacement
    from mlsim.render.transport import TransportMatrix

    rng = np.random.default_rng(8)
    V = rng.normal(size=(4, 50, 3))
    rest = rng.normal(size=(50, 3))
    np.testing.assert_allclose(largest_displacement(V, rest), np.linalg.norm(V - rest, axis=2).max(axis=1), rtol=1e-15)
    assert np.all(largest_displacement(np.broadcast_to(rest, (2, 50, 3)).copy(), rest) == 0.0)
    A = sp.random(12 * 10, 30, density=0.1, random_state=2, format="csr", dtype=np.float32)
    T = TransportMatrix(A, 12, 10, 16, 0.0, 0.0)
    E = rng.random((3, 30)).astype(np.float32)
    base = rng.random((3, 12, 10)).astype(np.float32)
    into = base.copy()
    assert T.apply(E, add_to=into) is into
    np.testing.assert_array_equal(into, base + T.apply(E))
    assert T.apply(E).flags.c_contiguous
    np.testing.assert_allclose(T.apply(E[0]), (A @ E[0]).reshape(12, 10), rtol=1e-5)
    with pytest.raises(ValueError, match="add_to"):
        T.apply(E, add_to=np.zeros((3, 12, 10)))  # float64


def test_the_deformed_sheet_is_the_interpolated_displacement_bit_for_bit_on_any_thread_count():
    """mlsim.render.deformed_vertices (compiled: mlsim.render.kernels.deformed_sheet) gives the sheet
    that numpy's einsum over the gathered corners gave, bit for bit (datasets keep their bytes), reads
    the frames' steps out of order, and moves a vertex exactly with a rigid translation."""
    from types import SimpleNamespace

    from mlsim.render import deformed_vertices

    rng = np.random.default_rng(11)
    S, P, N = 9, 300, 500
    tets = rng.integers(0, P, (200, 4))
    bary = rng.random((N, 4))
    bary /= bary.sum(axis=1, keepdims=True)
    tet = rng.integers(0, 200, N)
    ep = SimpleNamespace(displacement=(1e-4 * rng.standard_normal((S, P, 3))).astype(np.float32), frame_step=np.array([0, 3, 2, 8, 8]),
                         mesh_tets=tets, mesh_points=rng.random((P, 3)))
    V = 1e-2 * rng.standard_normal((N, 3))
    got = deformed_vertices(ep, V, (tet, bary))
    u = ep.displacement[ep.frame_step]
    np.testing.assert_array_equal(got, V[None] + np.einsum("nk,fnkd->fnd", bary, u[:, tets[tet], :].astype(float)))
    threads = numba.get_num_threads()
    try:
        numba.set_num_threads(1)
        np.testing.assert_array_equal(deformed_vertices(ep, V, (tet, bary)), got)
    finally:
        numba.set_num_threads(threads)
    shift = np.array([1e-4, -2e-4, 3e-4], np.float32)
    ep.displacement[:] = shift  # every mesh vertex moved alike: the sheet moves by it (weights sum to 1)
    np.testing.assert_allclose(deformed_vertices(ep, V, (tet, bary)) - V[None], np.broadcast_to(shift, (5, N, 3)), rtol=1e-12, atol=1e-19)
