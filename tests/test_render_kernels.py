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
    from mlsim.render.kernels import rasterise_arrays as rasterise_direct

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
    image = rasterise_direct(uv[None], np.ones((1, n * n), np.float32), faces, value[None], 1, orientation, n, n, throughput)[0]
    assert image.min() >= 0.0
    np.testing.assert_allclose(image, 0.5 * value.reshape(n, n), rtol=1e-5, atol=1e-6 * value.max())
    # a second sheet over the first, nearer (depth 0.5 < 1): it hides it wherever it covers
    uv2 = np.concatenate([uv, uv])
    depth = np.concatenate([np.ones(n * n), np.full(n * n, 0.5)]).astype(np.float32)[None]
    two = np.concatenate([value, np.full(n * n, 7e14, np.float32)])[None]
    image = rasterise_direct(uv2[None], depth, np.concatenate([faces, faces + n * n]), two, 1, orientation, n, n, throughput)[0]
    np.testing.assert_allclose(image, 0.5 * 7e14, rtol=1e-6)
    # seen from behind (the other winding), nothing
    assert rasterise_direct(uv[None], np.ones((1, n * n), np.float32), faces[:, ::-1].copy(), value[None], 1, orientation, n, n,
                            throughput).max() == 0.0


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


def _overlapping_sheets(n: int, rng, jitter_px: float, shift_px: float, tie: bool):
    """Two jittered grid sheets of n x n vertices over an n x n image, the second shifted by shift_px
    and at depths equal to (tie) or just off the first's: overlaps, near-ties in the z-buffer, faces
    past the image's edges, slivers, some faces seen from behind."""
    yy, xx = np.mgrid[0:n, 0:n]
    grid = np.stack([xx.ravel(), yy.ravel()], axis=1).astype(np.float64)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int64)
    uv1 = grid + rng.uniform(-jitter_px, jitter_px, grid.shape)
    uv2 = grid + shift_px + rng.uniform(-jitter_px, jitter_px, grid.shape)
    z1 = rng.uniform(1.0, 1.001, n * n)
    z2 = z1 if tie else z1 + rng.normal(0.0, 1e-9, n * n)
    uv = np.concatenate([uv1, uv2])
    depth = np.concatenate([z1, z2]).astype(np.float32)
    both = np.concatenate([faces, faces + n * n])
    return uv, depth, both[rng.permutation(len(both))]


@pytest.mark.parametrize("per_side", [1, 2])
def test_the_rasteriser_is_the_banded_one_before_it_bit_for_bit(per_side):
    """mlsim.render.kernels.rasterise_direct (one pass, the dark faces that cannot change a sample
    skipped in frames with few lit vertices) against the kernel it replaced (tests/raster_reference.py:
    eight bands, every face rasterised), bit for bit: frames with every vertex lit, half, a few (the
    sparse path), one, none, and negative zeros; two sheets overlapping at equal and nearly equal
    depths in a shuffled face order; sheets reaching past the image's edges; one thread and all."""
    from raster_reference import rasterise_direct_banded

    from mlsim.render.kernels import SPARSE_LIT_FRACTION
    from mlsim.render.kernels import rasterise_arrays as rasterise_direct

    rng = np.random.default_rng(11)
    n = 40
    for shift_px, tie in ((0.0, True), (0.37, False), (-6.5, True), (13.2, False)):
        uv, depth, faces = _overlapping_sheets(n, rng, 0.3, shift_px, tie)
        N = len(uv)
        frames = []
        for lit_fraction in (1.0, 0.5, 0.5 * SPARSE_LIT_FRACTION, 0.01, 1.0 / N, 0.0):
            value = rng.uniform(1e14, 1e15, N) * (rng.random(N) < lit_fraction)
            frames.append(value)
        frames.append(np.where(rng.random(N) < 0.02, 5e14, -0.0))  # negative zeros are dark too
        value = np.asarray(frames, np.float32)
        F = len(value)
        uvs = np.broadcast_to(uv, (F,) + uv.shape).copy()
        uvs[1::2] += rng.normal(0.0, 0.2, uvs[1::2].shape)  # each frame its own geometry
        depths = np.broadcast_to(depth, (F, N)).copy()
        throughput = rng.uniform(0.5, 1.0, (n * per_side, n * per_side)).astype(np.float32)
        ref = rasterise_direct_banded(uvs, depths, faces, value, per_side, -1.0, n, n, throughput, 8)
        threads = numba.get_num_threads()
        try:
            numba.set_num_threads(1)
            one = rasterise_direct(uvs, depths, faces, value, per_side, -1.0, n, n, throughput)
        finally:
            numba.set_num_threads(threads)
        every = rasterise_direct(uvs, depths, faces, value, per_side, -1.0, n, n, throughput)
        assert ref.max() > 0 and np.all(ref[5] == 0)
        np.testing.assert_array_equal(one.view(np.uint32), ref.view(np.uint32))
        np.testing.assert_array_equal(every.view(np.uint32), ref.view(np.uint32))


def test_the_frames_projection_is_the_sheets_in_the_rasters_numbering():
    """project_frames puts each frame's vertex i at row number[i] of its table with the bits of
    project_through_interfaces (of the vertices in mm), of numpy's float32 depth and of its float32
    value; it counts the points outside the table and the non-finite ones (and skips those)."""
    from mlsim.render.kernels import VERTEX_FIELDS, project_frames, project_through_interfaces

    rng = np.random.default_rng(4)
    inv_length = rng.uniform(0.02, 0.03, (64, 16))
    r2_step, z_step = 4.0, 0.5
    pixel_map = np.array([[175.0, 900.0, 3.0], [175.0, -2.0, 900.0]])
    V = np.concatenate([rng.uniform(-10, 10, (3, 200, 2)), rng.uniform(0, 7, (3, 200, 1))], axis=2) * 1e-3
    number = rng.permutation(200)
    value = (rng.random((3, 200)) * 1e15).astype(np.float32)
    table = np.empty((3, 200, VERTEX_FIELDS))
    assert project_frames(V, number, value, inv_length, r2_step, z_step, pixel_map, table) == (0, 0)
    flat = np.ascontiguousarray(V.reshape(-1, 3) * 1e3)
    ref = np.empty((600, 2))
    assert project_through_interfaces(flat, inv_length, r2_step, z_step, pixel_map, ref) == 0
    np.testing.assert_array_equal(table[:, number, :2], ref.reshape(3, 200, 2))
    np.testing.assert_array_equal(table[:, number, 2], V[..., 2].astype(np.float32).astype(np.float64))
    np.testing.assert_array_equal(table[:, number, 3], value.astype(np.float64))
    V[1, 7, 2] = -1e-3  # below the table
    V[2, 9, 0] = 1.0  # far off the axis
    V[0, 3, 1] = np.nan
    assert project_frames(V, number, value, inv_length, r2_step, z_step, pixel_map, table) == (2, 1)


def test_the_repeated_frames_are_numpys():
    """repeats_previous is numpy's frame-to-frame ``np.all(a[1:] == a[:-1])`` of the values and the
    vertices (NaN differs, -0.0 equals 0.0; no vertices: the values alone)."""
    from mlsim.render.kernels import repeats_previous

    rng = np.random.default_rng(9)
    e = rng.random((9, 40)).astype(np.float32)
    V = rng.random((9, 40, 3))
    e[2], V[2] = e[1], V[1]  # a repeat
    e[4], V[4, :39] = e[3], V[3, :39]  # values repeated, last vertex moved
    e[6], V[6] = e[5], V[5]
    e[5, 0], e[6, 0] = 0.0, -0.0  # equal under ==
    e[8], V[8] = e[7], V[7]
    V[7, 3, 1] = V[8, 3, 1] = np.nan  # NaN never equals
    ref = np.zeros(9, bool)
    ref[1:] = np.all(e[1:] == e[:-1], axis=1) & np.all(V[1:] == V[:-1], axis=(1, 2))
    np.testing.assert_array_equal(repeats_previous(e, V), ref)
    assert list(np.flatnonzero(ref)) == [2, 6]
    alone = np.zeros(9, bool)
    alone[1:] = np.all(e[1:] == e[:-1], axis=1)
    np.testing.assert_array_equal(repeats_previous(e, np.empty((0, 0, 3))), alone)
    assert repeats_previous(np.zeros((0, 5), np.float32), np.empty((0, 0, 3))).shape == (0,)


def test_the_transport_product_of_frames_with_few_lit_vertices_keeps_the_row_products_bits():
    """TransportMatrix.apply takes frames with few lit vertices column by column
    (kernels.lit_columns_product) and the others row by row (csr_times_dense): every frame's image,
    added to a buffer or not, has the bits of the row product of all frames at once (the kernel as
    it was for every frame); a matrix not in canonical form takes the row product for all."""
    from mlsim.render.kernels import SPARSE_LIT_FRACTION
    from mlsim.render.transport import TransportMatrix

    rng = np.random.default_rng(12)
    A = sp.random(30 * 20, 400, density=0.08, random_state=5, format="csr", dtype=np.float32)
    e = rng.uniform(0.0, 3.0, (6, 400)).astype(np.float32)
    e[1] *= rng.random(400) < 0.5 * SPARSE_LIT_FRACTION
    e[2] *= rng.random(400) < 0.01
    e[3] = 0.0
    e[4] *= rng.random(400) < 0.5
    e[5, :] = -0.0
    e[5, 17] = 2.0
    full = np.zeros((600, 6), np.float32)
    csr_times_dense(A.indptr, A.indices, A.data, np.ascontiguousarray(e.T), full)
    base = rng.random((6, 30, 20)).astype(np.float32)
    expected = (base.reshape(6, -1) + full.T).reshape(6, 30, 20)
    for matrix in (A, sp.csr_matrix((A.data, A.indices, A.indptr), shape=A.shape)):
        T = TransportMatrix(matrix, 30, 20, 16, 0.0, 0.0)
        np.testing.assert_array_equal(T.apply(e).view(np.uint32), full.T.reshape(6, 30, 20).view(np.uint32))
        np.testing.assert_array_equal(T.apply(e, add_to=base.copy()).view(np.uint32), expected.view(np.uint32))
        np.testing.assert_array_equal(T.apply(e[2]), full[:, 2].reshape(30, 20))
    shuffled = A.copy()
    for i in range(shuffled.shape[0]):  # the rows' columns out of order: not canonical
        a, b = shuffled.indptr[i], shuffled.indptr[i + 1]
        shuffled.indices[a:b] = shuffled.indices[a:b][::-1].copy()
        shuffled.data[a:b] = shuffled.data[a:b][::-1].copy()
    shuffled.has_sorted_indices = False
    T = TransportMatrix(shuffled, 30, 20, 16, 0.0, 0.0)
    assert T._columns() is None
    np.testing.assert_allclose(T.apply(e), full.T.reshape(6, 30, 20), rtol=1e-5)


def test_the_product_added_into_the_images_is_the_product_then_its_addition_bit_for_bit():
    """csr_times_dense_into (the product's rows summed in blocks and added straight to their
    frames' images) gives the bits of csr_times_dense into a zeroed array then added to the images
    (numpy's ``images[frames] += out.T``), for a row count that is not a multiple of its block,
    a subset of the frames, and on one thread as on all."""
    from mlsim.render.kernels import PRODUCT_ROWS, csr_times_dense_into

    rng = np.random.default_rng(8)
    P = 3 * PRODUCT_ROWS + 37
    A = sp.random(P, 150, density=0.04, random_state=2, format="csr", dtype=np.float32)
    E = (rng.random((150, 4)) * rng.random((150, 1)) ** 8).astype(np.float32)  # spread exponents: rounding matters
    images = (rng.random((6, P)) * 1e-3).astype(np.float32)
    frames = np.array([5, 0, 2, 3])
    out = np.zeros((P, 4), np.float32)
    csr_times_dense(A.indptr, A.indices, A.data, E, out)
    ref = images.copy()
    for u, f in enumerate(frames):
        ref[f] += out[:, u]
    got = images.copy()
    csr_times_dense_into(A.indptr, A.indices, A.data, E, frames, got)
    np.testing.assert_array_equal(got.view(np.uint32), ref.view(np.uint32))
    assert np.array_equal(got[[1, 4]], images[[1, 4]])  # the frames not named are left alone
    threads = numba.get_num_threads()
    one = images.copy()
    try:
        numba.set_num_threads(1)
        csr_times_dense_into(A.indptr, A.indices, A.data, E, frames, one)
    finally:
        numba.set_num_threads(threads)
    np.testing.assert_array_equal(one, got)
