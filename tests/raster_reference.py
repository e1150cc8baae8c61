"""The direct light's rasteriser as it was before issue 40 (mlsim.render.kernels at dbe1c99: the frame
cut into pixel-row bands, every face rasterised, the vertices in the sheet's numbering), kept as the
reference that the faster kernel must equal bit for bit (tests/test_render_kernels.py)."""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from mlsim.render.kernels import EDGE_EPS


@njit
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


@njit
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


@njit(parallel=True)
def rasterise_direct_banded(uv, depth, faces, value, per_side, orientation, height_px, width_px, throughput, n_bands):
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
