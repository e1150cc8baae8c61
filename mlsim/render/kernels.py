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


@njit(parallel=True, cache=True)
def project_through_interfaces(vertices_mm, inv_length, r2_step, z_step, pixel_map, uv):
    """Image positions uv (N, 2) (continuous pixel coordinates) of points (N, 3) mm above the core's
    bottom face, in place.

    The camera looks up through flat interfaces, so a point at radius rho and height z is seen
    along the air ray whose tangent is q(rho^2, z) rho towards it; ``inv_length`` (n_r, n_z) holds q
    on a regular grid in rho^2 (step ``r2_step``) and z (step ``z_step``), interpolated bilinearly
    (points past the grid take its edge). ``pixel_map`` (2, 3): pixel = M @ (1, tan_x, tan_y).
    Returns how many points lie outside the grid (below z = 0 or past its ends)."""
    n_r, n_z = inv_length.shape
    outside = 0
    for i in prange(vertices_mm.shape[0]):
        x, y, z = vertices_mm[i, 0], vertices_mm[i, 1], vertices_mm[i, 2]
        fr = (x * x + y * y) / r2_step
        fz = z / z_step
        if fz < -1e-6 or fz > n_z - 1 or fr > n_r - 1:
            outside += 1
        ir = min(max(int(fr), 0), n_r - 2)
        iz = min(max(int(fz), 0), n_z - 2)
        wr = min(max(fr - ir, 0.0), 1.0)
        wz = min(max(fz - iz, 0.0), 1.0)
        q = ((1.0 - wr) * ((1.0 - wz) * inv_length[ir, iz] + wz * inv_length[ir, iz + 1])
             + wr * ((1.0 - wz) * inv_length[ir + 1, iz] + wz * inv_length[ir + 1, iz + 1]))
        tx, ty = q * x, q * y
        uv[i, 0] = pixel_map[0, 0] + pixel_map[0, 1] * tx + pixel_map[0, 2] * ty
        uv[i, 1] = pixel_map[1, 0] + pixel_map[1, 1] * tx + pixel_map[1, 2] * ty
    return outside


@njit(cache=True)
def _rasterise_band(uv, depth, faces, value, per_side, orientation, width_samples, r0, r1, nearest, seen, rows_lo, rows_hi):
    """Every triangle that faces the camera, into sample rows r0 .. r1 - 1: where a triangle covers a
    sample and is nearer (smaller ``depth``, interpolated) than what the sample holds, the sample
    takes the triangle's ``value`` interpolated there. ``nearest``, ``seen``: ((r1 - r0) x
    width_samples,) float32, the band's depth and value buffers; rows_lo, rows_hi (K,): each
    triangle's span of sample rows (only those that reach the band are read). Barycentric weights
    are those of the image-space triangle (the projection is smooth on a triangle's scale)."""
    k = per_side
    for f in range(faces.shape[0]):
        if rows_hi[f] < r0 or rows_lo[f] > r1 - 1:
            continue
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        # sample-grid coordinates: sample (sx, sy) sits at pixel ((sx + 0.5) / k, (sy + 0.5) / k)
        y0 = uv[i0, 1] * k - 0.5
        y1 = uv[i1, 1] * k - 0.5
        y2 = uv[i2, 1] * k - 0.5
        y_lo = min(y0, min(y1, y2))
        y_hi = max(y0, max(y1, y2))
        sy_lo, sy_hi = max(r0, int(np.ceil(y_lo))), min(r1 - 1, int(np.floor(y_hi)))
        if sy_lo > sy_hi:  # outside the band, or between two sample rows (most of the far side's slivers)
            continue
        x0 = uv[i0, 0] * k - 0.5
        x1 = uv[i1, 0] * k - 0.5
        x2 = uv[i2, 0] * k - 0.5
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
        d0, d1, d2 = depth[i0], depth[i1], depth[i2]
        v0, v1, v2 = value[i0], value[i1], value[i2]
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
            base = (sy - r0) * width_samples
            for s in range(base + xa, base + xb + 1):
                if d < nearest[s]:
                    nearest[s] = d
                    # inside a triangle the interpolated value lies between its vertices'; what
                    # falls outside is rounding (the running sum on a sliver seen edge-on, a
                    # weight down to -EDGE_EPS on an edge), and could be below zero
                    seen[s] = min(max(v, v_min), v_max)
                d += d_step
                v += v_step


@njit(cache=True)
def _rasterise_frame(uv, depth, faces, value, per_side, orientation, height_px, width_px, throughput, n_bands, image):
    """One frame's direct light into ``image`` (height_px, width_px), band after band (small bands:
    their buffers stay in the core's cache)."""
    k = per_side
    width_samples = width_px * k
    # each triangle's rows, once: a band then skips the triangles outside it without reading them
    rows_lo = np.empty(faces.shape[0], np.float32)
    rows_hi = np.empty(faces.shape[0], np.float32)
    for f in range(faces.shape[0]):
        a, b, c = uv[faces[f, 0], 1], uv[faces[f, 1], 1], uv[faces[f, 2], 1]
        rows_lo[f] = min(a, min(b, c)) * k - 0.5
        rows_hi[f] = max(a, max(b, c)) * k - 0.5
    rows = ((height_px + n_bands - 1) // n_bands) * k
    nearest = np.empty(rows * width_samples, dtype=np.float32)
    seen = np.empty(rows * width_samples, dtype=np.float32)
    for b in range(n_bands):
        r0 = b * rows
        r1 = min(height_px * k, r0 + rows)
        if r0 >= r1:
            continue
        nearest[:] = np.inf
        seen[:] = 0.0
        _rasterise_band(uv, depth, faces, value, k, orientation, width_samples, r0, r1, nearest, seen, rows_lo, rows_hi)
        for py in range(r0 // k, r1 // k):
            for j in range(k):
                sy = py * k + j
                base = (sy - r0) * width_samples
                for px in range(width_px):
                    acc = 0.0
                    for i in range(k):
                        acc += throughput[sy, px * k + i] * seen[base + px * k + i]
                    image[py, px] += acc / (k * k)


@njit(parallel=True, cache=True)
def rasterise_direct(uv, depth, faces, value, per_side, orientation, height_px, width_px, throughput, n_bands):
    """(F, height_px, width_px) float32: per frame and pixel, the mean over its per_side x per_side
    samples of throughput (H k, W k) times the ``value`` (F, N) of the nearest camera-facing
    triangle of ``faces`` (K, 3) at the sample (zero where none covers it).

    uv (F, N, 2): the vertices' pixel positions; depth (F, N): nearer is smaller along a sample's
    ray; orientation: +1 or -1, the sign of a camera-facing triangle's area in pixel coordinates.
    The frames run in parallel, each cut into ``n_bands`` bands of whole pixel rows."""
    n_frames = uv.shape[0]
    images = np.zeros((n_frames, height_px, width_px), np.float32)
    for f in prange(n_frames):
        _rasterise_frame(uv[f], depth[f], faces, value[f], per_side, orientation, height_px, width_px, throughput, n_bands, images[f])
    return images


# out (P, F) = A @ dense for A (P, N) in CSR and dense (N, F), in place, one row per thread step (the order
# of the sums fixed): the transport matrices' batched product, the same kernel as the reduced tier's
# precompute (compiled here for float32)
csr_times_dense = sparse_product


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
