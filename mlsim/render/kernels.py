"""Compiled loops of the render tiers (numba): the sheet's projection through the flat interfaces,
the rasteriser of its direct light (:mod:`mlsim.render.direct_raster`), and the sparse product of
a transport matrix with a batch of frames (:meth:`mlsim.render.transport.TransportMatrix.apply`).

Each output element is written by one thread in a fixed order (a pixel row band, a matrix row), so
the results do not depend on the number of threads.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from fem.field_kernels import sparse_product

#: a sample on a triangle's edge (barycentric weight down to -EDGE_EPS) belongs to it: a sample on
#: the edge two triangles share is never lost between them
EDGE_EPS = 1e-7


@njit(parallel=True, cache=True, error_model="numpy")
def project_through_interfaces(vertices_mm, inv_length, r2_step, z_step, pixel_map, uv):
    """Image positions uv (N, 2) (continuous pixel coordinates) of points (N, 3) mm above the core's
    bottom face, in place.

    The camera looks up through flat interfaces, so a point at radius rho and height z is seen
    along the air ray whose tangent is q(rho^2, z) rho towards it; ``inv_length`` (n_r, n_z) holds q
    on a regular grid in rho^2 (step ``r2_step``) and z (step ``z_step``), interpolated bilinearly
    (points past the grid take its edge). ``pixel_map`` (2, 3): pixel = M @ (1, tan_x, tan_y).
    Returns how many points lie outside the grid (below z = 0 or past its ends)."""
    outside = 0
    for i in prange(vertices_mm.shape[0]):
        uv[i, 0], uv[i, 1], off = _through_interfaces(vertices_mm[i, 0], vertices_mm[i, 1], vertices_mm[i, 2], inv_length, r2_step, z_step, pixel_map)
        outside += off
    return outside


@njit(cache=True, error_model="numpy")
def _through_interfaces(x, y, z, inv_length, r2_step, z_step, pixel_map):
    """(u, v, 1 if the point (mm) lies outside the table's grid else 0): one point of
    :func:`project_through_interfaces`."""
    n_r, n_z = inv_length.shape
    fr = (x * x + y * y) / r2_step
    fz = z / z_step
    off = 1 if (fz < -1e-6 or fz > n_z - 1 or fr > n_r - 1) else 0
    ir = min(max(int(fr), 0), n_r - 2)
    iz = min(max(int(fz), 0), n_z - 2)
    wr = min(max(fr - ir, 0.0), 1.0)
    wz = min(max(fz - iz, 0.0), 1.0)
    q = ((1.0 - wr) * ((1.0 - wz) * inv_length[ir, iz] + wz * inv_length[ir, iz + 1])
         + wr * ((1.0 - wz) * inv_length[ir + 1, iz] + wz * inv_length[ir + 1, iz + 1]))
    tx, ty = q * x, q * y
    return pixel_map[0, 0] + pixel_map[0, 1] * tx + pixel_map[0, 2] * ty, pixel_map[1, 0] + pixel_map[1, 1] * tx + pixel_map[1, 2] * ty, off


#: the tiles of the lit samples' map (:func:`_dark_faces_that_matter`) are 2^TILE_SHIFT samples a side
TILE_SHIFT = 3

#: below this fraction of lit vertices a frame's dark faces are first tested against the map of
#: what the lit faces cover (on the screw scene's episodes a third of the frames have 0.2 % of the
#: vertices lit, the rest about half: there the test would cost more than it saves)
SPARSE_LIT_FRACTION = 0.1


#: what the rasteriser reads of a vertex, in one row of a (F, N, VERTEX_FIELDS) float64 table: its
#: pixel position u, v, its depth and its value (both float32 values: the kernel reads them back as
#: float32, so the arithmetic is the same as from float32 arrays); one cache line per vertex instead
#: of three arrays' (uv, depth, value): 15 % of the rasteriser's time on the screw scene
VERTEX_FIELDS = 4


def project_frames(vertices_m, number, value, inv_length, r2_step, z_step, pixel_map, table):
    """The sheet's frames placed in the image for the rasteriser, in its vertex numbering: row
    ``number[i]`` of ``table`` (F, N, VERTEX_FIELDS) float64 gets the sheet's vertex i's pixel
    position u, v (as :func:`project_through_interfaces`, of ``vertices_m`` (F, N, 3) m in mm), its
    depth (the height z in m, as float32) and its ``value`` (F, N) float32, in place (the sheet
    read in its order, the writes scattered: faster than the other way round). Returns (how many
    points lie outside the table's grid, how many have a NaN or infinite coordinate); a non-finite
    point is skipped. (:func:`project_frames_at` of every frame in order.)"""
    return project_frames_at(vertices_m, np.arange(vertices_m.shape[0]), number, value, inv_length, r2_step, z_step, pixel_map, table)


@njit(parallel=True, cache=True, error_model="numpy")
def project_frames_at(vertices_m, frames, number, value, inv_length, r2_step, z_step, pixel_map, table):
    """:func:`project_frames` of the frames ``frames`` (F,) of ``vertices_m`` (any number of frames,
    N, 3): frame f of ``table`` and ``value`` (F, N) is frame ``frames[f]`` of the vertices, read
    where it lies (the render's lit frames without numpy's gathered copy of their vertices, 7 ms
    of a screw-scene episode)."""
    n_frames, n = frames.shape[0], number.shape[0]
    outside = 0
    non_finite = 0
    for f in prange(n_frames):
        g = frames[f]
        for i in range(n):
            j = number[i]
            table[f, j, 3] = value[f, i]
            x, y, z = vertices_m[g, i, 0] * 1e3, vertices_m[g, i, 1] * 1e3, vertices_m[g, i, 2] * 1e3
            if not (np.isfinite(x) and np.isfinite(y) and np.isfinite(z)):
                non_finite += 1
                continue
            table[f, j, 0], table[f, j, 1], off = _through_interfaces(x, y, z, inv_length, r2_step, z_step, pixel_map)
            outside += off
            table[f, j, 2] = np.float32(vertices_m[g, i, 2])
    return outside, non_finite


@njit(cache=True)
def _dark_faces_that_matter(table, faces, per_side, width_samples, n_rows, needed):
    """needed (K,) bool, in place: the faces that can change a sample's value, the lit faces (a
    vertex value other than zero) and the dark faces that may cover a sample which a lit face may
    cover, on tiles of 2^TILE_SHIFT samples a side. A sample no lit face covers ends at zero whichever
    dark faces cover it, and the faces that cover a lit sample are all kept (in their order), so
    rasterising only these gives the same bits."""
    k = per_side
    tiles_w = ((width_samples - 1) >> TILE_SHIFT) + 1
    tiles_h = ((n_rows - 1) >> TILE_SHIFT) + 1
    # each vertex's tile (clamped into the image): a face's samples lie in the tiles between its vertices'
    tile_x = np.empty(table.shape[0], np.int32)
    tile_y = np.empty(table.shape[0], np.int32)
    for i in range(table.shape[0]):
        tile_x[i] = min(max(int(np.floor(table[i, 0] * k - 0.5)), 0), width_samples - 1) >> TILE_SHIFT
        tile_y[i] = min(max(int(np.floor(table[i, 1] * k - 0.5)), 0), n_rows - 1) >> TILE_SHIFT
    tiles = np.zeros(tiles_h * tiles_w, np.bool_)
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        lit = table[i0, 3] != 0.0 or table[i1, 3] != 0.0 or table[i2, 3] != 0.0
        needed[f] = lit
        if lit:
            for ty in range(min(tile_y[i0], min(tile_y[i1], tile_y[i2])), max(tile_y[i0], max(tile_y[i1], tile_y[i2])) + 1):
                for tx in range(min(tile_x[i0], min(tile_x[i1], tile_x[i2])), max(tile_x[i0], max(tile_x[i1], tile_x[i2])) + 1):
                    tiles[ty * tiles_w + tx] = True
    for f in range(faces.shape[0]):
        if needed[f]:
            continue
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        tx0, tx1 = min(tile_x[i0], min(tile_x[i1], tile_x[i2])), max(tile_x[i0], max(tile_x[i1], tile_x[i2]))
        ty0, ty1 = min(tile_y[i0], min(tile_y[i1], tile_y[i2])), max(tile_y[i0], max(tile_y[i1], tile_y[i2]))
        if tx0 == tx1 and ty0 == ty1:  # most faces: within one tile
            needed[f] = tiles[ty0 * tiles_w + tx0]
            continue
        hit = False
        for ty in range(ty0, ty1 + 1):
            for tx in range(tx0, tx1 + 1):
                hit = hit or tiles[ty * tiles_w + tx]
        needed[f] = hit


@njit(cache=True, error_model="numpy")
def _rasterise_frame(table, faces, per_side, orientation, height_px, width_px, throughput, image):
    """One frame's direct light into ``image`` (height_px, width_px), in the faces' order: where a
    camera-facing triangle covers a sample and is nearer (smaller ``depth``, interpolated) than
    what the sample holds, the sample takes the triangle's ``value`` interpolated there.
    Barycentric weights are those of the image-space triangle (the projection is smooth on a
    triangle's scale).

    A frame with few lit vertices (below SPARSE_LIT_FRACTION) rasterises only the faces that can
    change a sample (:func:`_dark_faces_that_matter`): the same bits, a sixth of the time on
    such frames of the screw scene."""
    k = per_side
    width_samples = width_px * k
    n_rows = height_px * k
    n_lit_vertices = 0
    for i in range(table.shape[0]):
        n_lit_vertices += table[i, 3] != 0.0
    if n_lit_vertices == 0:
        return  # every sample ends at zero
    sparse = n_lit_vertices < SPARSE_LIT_FRACTION * table.shape[0]
    needed = np.empty(faces.shape[0] if sparse else 0, np.bool_)
    if sparse:
        _dark_faces_that_matter(table, faces, k, width_samples, n_rows, needed)
    # per sample its nearest depth and its value side by side (one cache line for the test and the write)
    zbuffer = np.empty((n_rows * width_samples, 2), dtype=np.float32)
    zbuffer[:, 0] = np.inf
    zbuffer[:, 1] = 0.0
    for f in range(faces.shape[0]):
        if sparse and not needed[f]:
            continue
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        # sample-grid coordinates: sample (sx, sy) sits at pixel ((sx + 0.5) / k, (sy + 0.5) / k)
        y0 = table[i0, 1] * k - 0.5
        y1 = table[i1, 1] * k - 0.5
        y2 = table[i2, 1] * k - 0.5
        y_lo = min(y0, min(y1, y2))
        y_hi = max(y0, max(y1, y2))
        sy_lo, sy_hi = max(0, int(np.ceil(y_lo))), min(n_rows - 1, int(np.floor(y_hi)))
        if sy_lo > sy_hi:  # outside the image, or between two sample rows (most of the far side's slivers)
            continue
        x0 = table[i0, 0] * k - 0.5
        x1 = table[i1, 0] * k - 0.5
        x2 = table[i2, 0] * k - 0.5
        area = ((x1 - x0) * (y2 - y0) - (x2 - x0) * (y1 - y0)) * orientation
        if area <= 0.0:  # seen from behind (from outside the core), or edge-on
            continue
        inv = orientation / area
        # barycentric weights w_i = A_i + B_i sx + C_i sy (w_2 = 1 - w_0 - w_1)
        A0, B0, C0 = (x1 * y2 - x2 * y1) * inv, (y1 - y2) * inv, (x2 - x1) * inv
        A1, B1, C1 = (x2 * y0 - x0 * y2) * inv, (y2 - y0) * inv, (x0 - x2) * inv
        A2, B2, C2 = 1.0 - A0 - A1, -B0 - B1, -C0 - C1
        R0 = 1.0 / B0 if B0 != 0.0 else 0.0
        R1 = 1.0 / B1 if B1 != 0.0 else 0.0
        R2 = 1.0 / B2 if B2 != 0.0 else 0.0
        d0, d1, d2 = np.float32(table[i0, 2]), np.float32(table[i1, 2]), np.float32(table[i2, 2])
        v0, v1, v2 = np.float32(table[i0, 3]), np.float32(table[i1, 3]), np.float32(table[i2, 3])
        d_step = B0 * (d0 - d2) + B1 * (d1 - d2)
        v_step = B0 * (v0 - v2) + B1 * (v1 - v2)
        v_min, v_max = min(v0, min(v1, v2)), max(v0, max(v1, v2))
        x_lo = max(0.0, min(x0, min(x1, x2)))
        x_hi = min(width_samples - 1.0, max(x0, max(x1, x2)))
        for sy in range(sy_lo, sy_hi + 1):
            # the columns where all three weights are >= -EDGE_EPS; an edge along the rows (B = 0)
            # bounds only rows, and the bounding box's rows are inside it
            lo, hi = x_lo, x_hi
            t = (-EDGE_EPS - A0 - C0 * sy) * R0
            if B0 > 0.0:
                lo = max(lo, t)
            elif B0 < 0.0:
                hi = min(hi, t)
            t = (-EDGE_EPS - A1 - C1 * sy) * R1
            if B1 > 0.0:
                lo = max(lo, t)
            elif B1 < 0.0:
                hi = min(hi, t)
            t = (-EDGE_EPS - A2 - C2 * sy) * R2
            if B2 > 0.0:
                lo = max(lo, t)
            elif B2 < 0.0:
                hi = min(hi, t)
            xa, xb = int(np.ceil(lo)), int(np.floor(hi))
            if xa > xb:
                continue
            w0 = A0 + B0 * xa + C0 * sy
            w1 = A1 + B1 * xa + C1 * sy
            d = w0 * d0 + w1 * d1 + (1.0 - w0 - w1) * d2
            v = w0 * v0 + w1 * v1 + (1.0 - w0 - w1) * v2
            base = sy * width_samples
            for s in range(base + xa, base + xb + 1):
                # the depth is compared in float64 with what the sample holds in float32 (its
                # rounding decides near-ties: so the faces' order is kept)
                if d < zbuffer[s, 0]:
                    zbuffer[s, 0] = d
                    # inside a triangle the interpolated value lies between its vertices'; what
                    # falls outside is rounding (the running sum on a sliver seen edge-on, a
                    # weight down to -EDGE_EPS on an edge), and could be below zero
                    zbuffer[s, 1] = min(max(v, v_min), v_max)
                d += d_step
                v += v_step
    for py in range(height_px):
        for j in range(k):
            sy = py * k + j
            base = sy * width_samples
            for px in range(width_px):
                acc = 0.0
                for i in range(k):
                    acc += throughput[sy, px * k + i] * zbuffer[base + px * k + i, 1]
                image[py, px] += acc / (k * k)


@njit(parallel=True, cache=True, error_model="numpy")
def rasterise_direct(table, faces, per_side, orientation, height_px, width_px, throughput):
    """(F, height_px, width_px) float32: per frame and pixel, the mean over its per_side x per_side
    samples of throughput (H k, W k) times the value of the nearest camera-facing triangle of
    ``faces`` (K, 3) at the sample (zero where none covers it).

    table (F, N, VERTEX_FIELDS) float64: per frame and vertex its pixel position u, v, its depth
    (nearer is smaller along a sample's ray) and its value, the last two float32 values
    (:func:`project_frames` writes it; :func:`rasterise_arrays` from separate arrays);
    orientation: +1 or -1, the sign of a camera-facing triangle's area in pixel coordinates.
    The frames run in parallel (one frame per thread step: the same bits on any thread count).
    Faces in image order and vertices numbered in the faces' order keep the reads near each other
    (:class:`mlsim.render.direct_raster.DirectRaster` does both)."""
    n_frames = table.shape[0]
    images = np.zeros((n_frames, height_px, width_px), np.float32)
    for f in prange(n_frames):
        _rasterise_frame(table[f], faces, per_side, orientation, height_px, width_px, throughput, images[f])
    return images


def rasterise_arrays(uv, depth, faces, value, per_side, orientation, height_px, width_px, throughput):
    """:func:`rasterise_direct` of uv (F, N, 2), depth (F, N) float32 and value (F, N) float32 (the
    rasteriser's inputs as separate arrays, as the tests and the reference kernel hold them)."""
    uv = np.asarray(uv, dtype=np.float64)
    table = np.empty(uv.shape[:2] + (VERTEX_FIELDS,))
    table[..., :2] = uv
    table[..., 2] = np.asarray(depth, dtype=np.float32)
    table[..., 3] = np.asarray(value, dtype=np.float32)
    return rasterise_direct(table, faces, per_side, orientation, height_px, width_px, throughput)


# out (P, F) = A @ dense for A (P, N) in CSR and dense (N, F), in place, one row per thread step (the order
# of the sums fixed): the transport matrices' batched product, the same kernel as the reduced tier's
# precompute (compiled here for float32)
csr_times_dense = sparse_product


#: rows of the product per thread step of :func:`csr_times_dense_into` (a block's sums, 256 x F
#: float32, stay in cache until they are added to the images)
PRODUCT_ROWS = 256


@njit(parallel=True, cache=True, error_model="numpy")
def csr_times_dense_into(indptr, indices, data, c, frames, images):
    """images[frames[u], i] += (A @ c)[i, u] in place, for A (P, N) in CSR, c (N, U) float32
    row-major, frames (U,) distinct rows of images (F, P) float32.

    The bits of :func:`csr_times_dense` into a zeroed (P, U) array, then that array's column u
    added to ``images[frames[u]]``: each row's sum runs from zero in the CSR's order in float32,
    then is added once. The (P, U) product and its transposed addition (numpy's ``images +=
    out.T``, 0.17 ms a frame of the screw scene) are replaced by blocks of PRODUCT_ROWS rows
    summed in cache and added where they go. One block per thread step: the same bits on any
    thread count."""
    n = indptr.shape[0] - 1
    U = c.shape[1]
    n_blocks = (n + PRODUCT_ROWS - 1) // PRODUCT_ROWS
    for b in prange(n_blocks):
        i0 = b * PRODUCT_ROWS
        i1 = min(n, i0 + PRODUCT_ROWS)
        acc = np.zeros((i1 - i0, U), np.float32)
        for i in range(i0, i1):
            for p in range(indptr[i], indptr[i + 1]):
                k = indices[p]
                v = data[p]
                for u in range(U):
                    acc[i - i0, u] += v * c[k, u]
        for u in range(U):
            f = frames[u]
            for i in range(i0, i1):
                images[f, i] += acc[i - i0, u]


@njit(parallel=True, cache=True)
def lit_columns_product(col_ptr, col_rows, col_data, values, out):
    """out (F, P) += the product of A (P, N), given by its columns (CSC: col_ptr (N + 1,), col_rows,
    col_data), with each frame's ``values`` (F, N), in place (out zero on entry), for frames with
    few non-zero values: each non-zero value's column is scattered, the columns in increasing order.

    The bits of :func:`csr_times_dense` when A's rows hold their columns in increasing order
    (scipy's canonical CSR) and its entries are finite: each row's sum then gets the same terms in
    the same order less the products with a zero value, which add nothing (a sum from +0.0 plus
    +-0.0 keeps its bits). One frame per thread step."""
    n_frames, n = values.shape
    for u in prange(n_frames):
        for k in range(n):
            c = values[u, k]
            if c == 0.0:
                continue
            for p in range(col_ptr[k], col_ptr[k + 1]):
                out[u, col_rows[p]] += col_data[p] * c


@njit(cache=True)
def _rows_equal(a, b):
    """all(a == b) of two equal-shaped arrays, stopping at the first difference (NaN differs)."""
    fa, fb = a.ravel(), b.ravel()
    for i in range(fa.shape[0]):
        if not fa[i] == fb[i]:
            return False
    return True


@njit(cache=True)
def repeats_previous(values, vertices):
    """(F,) bool: frame f > 0 has the same ``values`` (F, N) and, when ``vertices`` (F, N, 3) has
    frames, the same vertices as frame f - 1 (``==``, as numpy's: NaN differs, -0.0 equals 0.0).
    Each comparison stops at the first difference: numpy's ``np.all(a[1:] == a[:-1], axis=...)``
    compared every vertex of every frame (0.1-0.2 ms a frame of the screw scene), where frames
    that differ do so at their first vertices."""
    n_frames = values.shape[0]
    out = np.zeros(n_frames, np.bool_)
    for f in range(1, n_frames):
        same = _rows_equal(values[f], values[f - 1])
        if same and vertices.shape[0] > 0:
            same = _rows_equal(vertices[f], vertices[f - 1])
        out[f] = same
    return out


@njit(parallel=True, cache=True)
def largest_displacement(vertices, rest):
    """(F,) the largest distance of any vertex of vertices (F, N, 3) from its rest position rest (N, 3):
    what the render tiers log per frame. numpy's difference and einsum took 0.3 ms per frame of the
    default demo (30 k vertices, 2 cores), a fifth of the deformed tier's time outside its two parts."""
    n_frames, n = vertices.shape[0], vertices.shape[1]
    out = np.zeros(n_frames)
    for f in prange(n_frames):
        worst = 0.0
        for i in range(n):
            dx = vertices[f, i, 0] - rest[i, 0]
            dy = vertices[f, i, 1] - rest[i, 1]
            dz = vertices[f, i, 2] - rest[i, 2]
            worst = max(worst, dx * dx + dy * dy + dz * dz)
        out[f] = np.sqrt(worst)
    return out


@njit(parallel=True, cache=True)
def deformed_sheet(rest, corners, bary, displacement, frame_step, out):
    """out (F, N, 3) float64 = rest (N, 3) + the displacement at each of the F frames, interpolated at
    each sheet vertex: sum over k = 0..3 of bary (N, 4) times displacement (S, P, 3) float32 at step
    frame_step (F,) and mesh vertex corners (N, 4), in place.

    The sum runs from 0 in k's order in float64, as numpy's ``einsum("nk,fnkd->fnd")`` did (bit for
    bit); it reads the steps and corners where they lie instead of gathering an (F, N, 4, 3) copy
    and widening it (0.23 s an episode of the screw scene on a loaded machine, a seventh of the
    render stage). One frame per thread step: the same sums on any thread count."""
    n_frames, n = out.shape[0], out.shape[1]
    for f in prange(n_frames):
        s = frame_step[f]
        for i in range(n):
            c0, c1, c2, c3 = corners[i, 0], corners[i, 1], corners[i, 2], corners[i, 3]
            w0, w1, w2, w3 = bary[i, 0], bary[i, 1], bary[i, 2], bary[i, 3]
            for d in range(3):
                acc = 0.0
                acc += w0 * np.float64(displacement[s, c0, d])
                acc += w1 * np.float64(displacement[s, c1, d])
                acc += w2 * np.float64(displacement[s, c2, d])
                acc += w3 * np.float64(displacement[s, c3, d])
                out[f, i, d] = rest[i, d] + acc
