"""Compiled inner loop of :func:`fem.contact_admm.admm_contact` (numba).

The ADMM iteration itself is a few passes over the m contact points and one product with the
factorised Delassus operator. In numpy each pass is a separate call with its own temporaries: on the
default demo that overhead was 0.38 of the linear tier's 0.55 ms per iteration and 0.18 of the reduced
tier's 0.20 ms. Here the passes are fused per point and the loop runs until it converges, reaches
its bound, or its residual balancing asks for another rho (the factor of each rho rung lives in
Python, :class:`fem.contact_admm._Delassus`). The cone projection and De Saxce's correction are
compiled per point too (:func:`project_cones`, :func:`de_saxce`: :mod:`fem.contact_admm` calls them
outside the loop as well, where their numpy form cost 33 and 17 us on 300 points); the tests hold
them and one whole map to the module docstring's formulas written in numpy (tests/test_contact_admm.py).

:func:`run_anderson` is the same loop with Anderson acceleration. Status codes returned by both:
CONVERGED, BOUND (max_iterations reached), RUNG_UP / RUNG_DOWN (the caller changes rho and calls
again with the same state).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

CONVERGED, BOUND, RUNG_UP, RUNG_DOWN = 0, 1, 2, 3
EIGEN, ROD_BLOCKS = 0, 1
BALANCE_EVERY = 5  # residual balancing every 5 iterations
BALANCE_RATIO = 3.0  # ... when one residual exceeds the other this many times
MAX_RUNG = 24


# numpy's error model on every kernel but _dot (issue 40): numba's default adds a zero check to each
# division (x / rho, the cone's scale, the Cholesky pivots), which keeps the loops around them from
# vectorising; the arithmetic is the same (an ADMM episode's forces, the same bits), only a division
# by zero would give inf or NaN instead of raising. _dot keeps its own flags: with reassoc allowed, a
# newly vectorised loop could sum in another order.
@njit(cache=True, error_model="numpy")
def _project_point(v0, v1, v2, n0, n1, n2, mu):
    vn = v0 * n0 + v1 * n1 + v2 * n2
    t0, t1, t2 = v0 - vn * n0, v1 - vn * n1, v2 - vn * n2
    t = math.sqrt(t0 * t0 + t1 * t1 + t2 * t2)
    if mu * t <= -vn:  # the polar cone: the projection is the apex
        return 0.0, 0.0, 0.0
    if t <= mu * vn:  # inside the cone
        return v0, v1, v2
    a = (vn + mu * t) / (1.0 + mu * mu)
    scale = mu * a / t if t > 0.0 else 0.0
    return a * n0 + scale * t0, a * n1 + scale * t1, a * n2 + scale * t2


@njit(cache=True, error_model="numpy")
def project_cones(v, n, mu):
    """:func:`fem.contact_admm.project_cone`: v (m, 3) projected onto the cones about the unit normals n (m, 3)."""
    out = np.empty_like(v)
    for i in range(v.shape[0]):
        out[i, 0], out[i, 1], out[i, 2] = _project_point(v[i, 0], v[i, 1], v[i, 2], n[i, 0], n[i, 1], n[i, 2], mu)
    return out


@njit(cache=True, error_model="numpy")
def de_saxce(sigma, n, mu):
    """:func:`fem.contact_admm.de_saxce`: mu |sigma_T| n (m, 3), in :func:`_step`'s arithmetic."""
    out = np.empty_like(sigma)
    for i in range(sigma.shape[0]):
        g0, g1, g2, n0, n1, n2 = sigma[i, 0], sigma[i, 1], sigma[i, 2], n[i, 0], n[i, 1], n[i, 2]
        gn = g0 * n0 + g1 * n1 + g2 * n2
        a0, a1, a2 = g0 - gn * n0, g1 - gn * n1, g2 - gn * n2
        st = mu * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        out[i, 0], out[i, 1], out[i, 2] = st * n0, st * n1, st * n2
    return out


@njit(cache=True, error_model="numpy")
def _rod_end(rod, start):
    """One past the last point of the rod that starts at ``start`` (the points come rod by rod)."""
    end = start
    while end < rod.shape[0] and rod[end] == rod[start]:
        end += 1
    return end


@njit(cache=True, error_model="numpy")
def solve(mode, inverse, K, Y, d_inv, rod, n_rods, r):
    """(G + rho I)^-1 r, r (m, 3). EIGEN (:class:`fem.contact_admm.DenseDelassus`): Q diag(d_inv) Q^T r,
    ``inverse`` = Q, d_inv = 1 / (lambda + rho). ROD_BLOCKS (:class:`fem.contact_admm.RodBlockDelassus`,
    the points rod by rod, ``rod`` (m,) their rod 0 .. n_rods - 1): each rod's block inverse
    B_a^-1 = Q_a diag(d_inv_a) Q_a^T, formed per rho (``inverse`` (1, sum (3 m_a)^2): the B_a^-1 one
    after the other, row-major; one product per rod instead of two with Q_a: the default demo's
    11 tips of 93 unknowns, 13 instead of 26 us), then Woodbury on the rods' resultants:
    x = v - Y K S^T v, v the block solve, S^T the sum per rod, Y (3 m, 3) the block solves of S,
    K (3 R, 3 R); d_inv unused. Also :meth:`fem.contact_admm.RodBlockDelassus._solve`'s arithmetic."""
    m = r.shape[0]
    if mode == EIGEN:  # both products with Q (Q^T r as r^T Q: one matrix stays in cache, where Q and a
        # copy of Q^T took 1.6 x as long)
        # (astype: numba types both modes for either precision of ``inverse``; a vector's copy each)
        w = r.reshape(3 * m).astype(inverse.dtype) @ inverse
        return (inverse @ (d_inv.astype(inverse.dtype) * w)).astype(np.float64).reshape(m, 3)
    flat = r.reshape(3 * m)
    flat_in = flat.astype(inverse.dtype)  # the blocks' precision (float32: half the bytes streamed)
    v = np.empty(3 * m)
    summed = np.zeros(3 * n_rods)
    inverses = inverse[0]
    start = 0
    offset = 0
    while start < m:
        a, end = rod[start], _rod_end(rod, start)
        lo, hi = 3 * start, 3 * end
        nb = hi - lo
        v[lo:hi] = inverses[offset : offset + nb * nb].reshape(nb, nb) @ flat_in[lo:hi]
        for i in range(start, end):
            for c in range(3):
                summed[3 * a + c] += v[3 * i + c]
        offset += nb * nb
        start = end
    q = K @ summed
    out = np.empty((m, 3))
    for i in range(m):
        a = rod[i]
        for c in range(3):
            acc = v[3 * i + c]
            for e in range(3):
                acc -= Y[3 * i + c, e] * q[3 * a + e]
            out[i, c] = acc
    return out


@njit(cache=True, error_model="numpy")
def _step(mode, inverse, K, Y, d_inv, rod, n_rods, rho, b, n, mu, y, z, s, y2, z2, s2):
    """One ADMM map (y, z, s) -> (y2, z2, s2) at rho; returns (primal, dual, max |y2|) in N."""
    m = b.shape[0]
    rhs = np.empty((m, 3))
    for i in range(m):
        for c in range(3):
            rhs[i, c] = rho * y[i, c] - z[i, c] - b[i, c] - s[i, c]
    x = solve(mode, inverse, K, Y, d_inv, rod, n_rods, rhs)
    primal = 0.0
    dual = 0.0
    y_max = 0.0
    for i in range(m):
        n0, n1, n2 = n[i, 0], n[i, 1], n[i, 2]
        # sigma = G x + b = rhs - rho x + b, then De Saxce's correction mu |sigma_T| n
        g0 = rhs[i, 0] - rho * x[i, 0] + b[i, 0]
        g1 = rhs[i, 1] - rho * x[i, 1] + b[i, 1]
        g2 = rhs[i, 2] - rho * x[i, 2] + b[i, 2]
        gn = g0 * n0 + g1 * n1 + g2 * n2
        a0, a1, a2 = g0 - gn * n0, g1 - gn * n1, g2 - gn * n2
        st = mu * math.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
        s2[i, 0], s2[i, 1], s2[i, 2] = st * n0, st * n1, st * n2
        p0, p1, p2 = _project_point(x[i, 0] + z[i, 0] / rho, x[i, 1] + z[i, 1] / rho, x[i, 2] + z[i, 2] / rho, n0, n1, n2, mu)
        dual = max(dual, abs(p0 - y[i, 0]), abs(p1 - y[i, 1]), abs(p2 - y[i, 2]))
        primal = max(primal, abs(x[i, 0] - p0), abs(x[i, 1] - p1), abs(x[i, 2] - p2))
        y_max = max(y_max, abs(p0), abs(p1), abs(p2))
        y2[i, 0], y2[i, 1], y2[i, 2] = p0, p1, p2
        z2[i, 0] = z[i, 0] + rho * (x[i, 0] - p0)
        z2[i, 1] = z[i, 1] + rho * (x[i, 1] - p1)
        z2[i, 2] = z[i, 2] + rho * (x[i, 2] - p2)
    return primal, dual, y_max


@njit(cache=True, error_model="numpy")
def _balance(it, primal, dual):
    """Residual balancing (every BALANCE_EVERY iterations): RUNG_UP, RUNG_DOWN, or -1."""
    if it % BALANCE_EVERY == 0:
        if primal > BALANCE_RATIO * dual:
            return RUNG_UP
        if dual > BALANCE_RATIO * primal:
            return RUNG_DOWN
    return -1


@njit(cache=True, error_model="numpy")
def run(mode, inverse, K, Y, d_inv, rod, n_rods, rho, b, n, mu, y, z, s, it0, max_iterations, rtol, f_scale):
    """ADMM iterations it0 + 1 .. max_iterations at one rho, in place on y (forces), z (multipliers)
    and s (De Saxce's correction), all (m, 3).

    Returns (status, last iteration, primal residual, dual residual, tolerance) in N.
    """
    y2, z2, s2 = np.empty_like(y), np.empty_like(z), np.empty_like(s)
    primal = dual = tol = 0.0
    it = it0
    while it < max_iterations:
        it += 1
        primal, dual, y_max = _step(mode, inverse, K, Y, d_inv, rod, n_rods, rho, b, n, mu, y, z, s, y2, z2, s2)
        y[:], z[:], s[:] = y2, z2, s2
        tol = rtol * max(y_max, f_scale, 1e-300)
        if max(primal, dual) <= tol:
            return CONVERGED, it, primal, dual, tol
        status = _balance(it, primal, dual)
        if status >= 0:
            return status, it, primal, dual, tol
    return BOUND, it, primal, dual, tol


@njit(cache=True, error_model="numpy")
def _spd_solve(A, k, rhs):
    """x with (A[:k, :k] + 1e-12 trace I) x = rhs by Cholesky, in place on a copy (k is at most a few:
    LAPACK's call costs more than the arithmetic). The tiny Tikhonov term keeps the normal equations
    solvable when the differences are nearly dependent."""
    L = np.empty((k, k))
    shift = 0.0
    for i in range(k):
        shift += A[i, i]
    shift = 1e-12 * max(shift, 1e-300)
    for i in range(k):
        for j in range(i + 1):
            acc = A[i, j] + (shift if i == j else 0.0)
            for q in range(j):
                acc -= L[i, q] * L[j, q]
            if i == j:
                L[i, i] = math.sqrt(max(acc, 1e-300))
            else:
                L[i, j] = acc / L[j, j]
    x = rhs.copy()
    for i in range(k):  # L y = rhs
        for q in range(i):
            x[i] -= L[i, q] * x[q]
        x[i] /= L[i, i]
    for i in range(k - 1, -1, -1):  # L^T x = y
        for q in range(i + 1, k):
            x[i] -= L[q, i] * x[q]
        x[i] /= L[i, i]
    return x


@njit(cache=True, fastmath={"reassoc", "contract"})
def _dot(a, b):
    """a . b of two equal-length vectors, a compiled loop (``reassoc`` lets it vectorise; its order is
    that of the compiled code, the same every run). (The process-to-process differences in iterations
    first blamed on BLAS here were MKL PARDISO's: :func:`fem.linsolve._reproducible`.)"""
    acc = 0.0
    for k in range(a.shape[0]):
        acc += a[k] * b[k]
    return acc


@njit(cache=True, error_model="numpy")
def run_anderson(mode, inverse, K, Y, d_inv, rod, n_rods, rho, b, n, mu, y, z, s, it0, max_iterations, rtol, f_scale, memory, rejections,
                 max_rejections):
    """:func:`run` with Anderson acceleration (type II, ``memory`` last differences) of the ADMM map,
    safeguarded: an extrapolated point whose own step is longer than the plain iterate's it replaced
    is dropped for that iterate and the history cleared [Zhang2020]_ ; after ``max_rejections`` drops
    in one solve (``rejections`` (1,) counts them across calls) the iterations go on plain. The
    history starts empty at each call (each rho).

    The map is accelerated on its Douglas-Rachford state v = (w, s / rho), w = y + z / rho
    (3 m + 3 m numbers, where (y, z / rho, s / rho) had 9 m): ADMM's y and z are the Moreau split of
    w, y = Proj_K(w) and z / rho = w - y (both updates above read only x + z_old / rho), so every
    extrapolated w gives forces in the cones and multipliers in their polar cones, and the
    acceleration's passes over its history cost two thirds of what they did (on a default demo step,
    301 points: 27.3 us per iteration where (y, z / rho, s / rho) took 31.5, plain ADMM 16.8; over the
    demo's episode 1489 iterations where it took 1522).

    .. [Zhang2020] J. Zhang, B. O'Donoghue, S. Boyd, "Globally convergent type-I Anderson
       acceleration for nonsmooth fixed-point iterations", SIAM J. Optim. 30 (2020) 3170-3197.
    """
    m = b.shape[0]
    M3 = 3 * m
    N = 2 * M3
    inv_rho = 1.0 / rho
    y2, z2, s2 = np.empty_like(y), np.empty_like(z), np.empty_like(s)
    yf, zf, sf, y2f, z2f, s2f = y.reshape(M3), z.reshape(M3), s.reshape(M3), y2.reshape(M3), z2.reshape(M3), s2.reshape(M3)
    safe_y, safe_z, safe_s = np.empty_like(y), np.empty_like(z), np.empty_like(s)
    # a ring of the last ``memory`` differences of the maps f(v) and of their residuals g = f(v) - v,
    # with the Gram matrix of the residuals' differences kept up to date: each iteration adds one row
    # of it (``memory`` dot products) instead of forming every difference and their products anew
    dF = np.empty((memory, N))  # (every slot is written before it is read)
    dG = np.empty((memory, N))
    gram = np.empty((memory, memory))
    f_last = np.empty(N)
    g_last = np.empty(N)
    have_last = False
    fv = np.empty(N)
    g = np.empty(N)
    v = np.empty(N)
    count = 0
    head = 0
    safe_norm = -1.0  # >= 0: the current point is extrapolated, and the plain one it replaced is kept
    primal = dual = tol = 0.0
    it = it0
    while it < max_iterations:
        it += 1
        primal, dual, y_max = _step(mode, inverse, K, Y, d_inv, rod, n_rods, rho, b, n, mu, y, z, s, y2, z2, s2)
        # flat passes (each one vectorises; one fused pass with the reductions did not)
        for k in range(M3):
            w2 = y2f[k] + z2f[k] * inv_rho
            fv[k] = w2
            g[k] = w2 - (yf[k] + zf[k] * inv_rho)
        for k in range(M3):
            fv[M3 + k] = s2f[k] * inv_rho
            g[M3 + k] = (s2f[k] - sf[k]) * inv_rho
        g_norm2 = _dot(g, g)
        s_change = 0.0  # an extrapolated s need not be De Saxce's of its x: converged only when it is
        for k in range(M3, N):
            s_change = max(s_change, abs(g[k]))
        if safe_norm >= 0.0 and g_norm2 > safe_norm:
            # the extrapolation did worse than the plain iterate it replaced: go on from that one
            y[:], z[:], s[:] = safe_y, safe_z, safe_s
            safe_norm = -1.0
            count = head = 0
            have_last = False
            rejections[0] += 1
            continue
        safe_norm = -1.0
        tol = rtol * max(y_max, f_scale, 1e-300)
        if max(primal, dual, s_change) <= tol:
            y[:], z[:], s[:] = y2, z2, s2
            return CONVERGED, it, primal, dual, tol
        y[:], z[:], s[:] = y2, z2, s2
        status = _balance(it, primal, dual)
        if status >= 0:
            return status, it, primal, dual, tol
        if rejections[0] >= max_rejections:
            continue
        if have_last:
            dF_h, dG_h = dF[head], dG[head]
            for k in range(N):
                dF_h[k] = fv[k] - f_last[k]
                dG_h[k] = g[k] - g_last[k]
            count = min(count + 1, memory)
            for j in range(count):  # the slots 0 .. count - 1 hold the differences (filled from 0)
                gram[head, j] = gram[j, head] = _dot(dG[j], dG_h)
            head = (head + 1) % memory
        f_last[:] = fv
        g_last[:] = g
        have_last = True
        if count < 1:
            continue
        # gamma = argmin |g - dG gamma| over the differences, by the normal equations (a tiny Tikhonov
        # term keeps them solvable when the differences are nearly dependent)
        rhs = np.empty(count)
        for j in range(count):
            rhs[j] = _dot(dG[j], g)
        gamma = _spd_solve(gram, count, rhs)
        safe_y[:], safe_z[:], safe_s[:] = y2, z2, s2
        safe_norm = g_norm2
        v[:] = fv
        for j in range(count):
            dF_j = dF[j]
            gj = gamma[j]
            for k in range(N):
                v[k] -= gj * dF_j[k]
        for i in range(m):  # the Moreau split of the extrapolated w
            w0, w1, w2 = v[3 * i], v[3 * i + 1], v[3 * i + 2]
            p0, p1, p2 = _project_point(w0, w1, w2, n[i, 0], n[i, 1], n[i, 2], mu)
            y[i, 0], y[i, 1], y[i, 2] = p0, p1, p2
            z[i, 0], z[i, 1], z[i, 2] = rho * (w0 - p0), rho * (w1 - p1), rho * (w2 - p2)
        for k in range(M3):
            sf[k] = v[M3 + k] * rho
    if safe_norm >= 0.0:  # return a plain ADMM iterate (an extrapolated s need not be De Saxce's of its x)
        y[:], z[:], s[:] = safe_y, safe_z, safe_s
    return BOUND, it, primal, dual, tol


@njit(cache=True, error_model="numpy")
def rod_block_product(C_flat, H, rod, n_rods, f):
    """blockdiag_a(C_aa) f + S H S^T f for points rod by rod (:class:`fem.contact_admm.RodBlockDelassus`'s
    elastic part): C_flat the blocks (3 m_a, 3 m_a) one after the other, row-major; f (m, 3)."""
    m = f.shape[0]
    flat = f.reshape(3 * m)
    out = np.empty(3 * m)
    summed = np.zeros(3 * n_rods)
    start = 0
    offset = 0
    while start < m:
        a, end = rod[start], _rod_end(rod, start)
        lo, hi = 3 * start, 3 * end
        nb = hi - lo
        loaded = False
        for k in range(lo, hi):
            summed[3 * a + k % 3] += flat[k]
            loaded = loaded or flat[k] != 0.0
        if loaded:  # (most rods near the path carry no force: the default demo's 9 of 20 never do)
            out[lo:hi] = C_flat[offset : offset + nb * nb].reshape(nb, nb) @ flat[lo:hi]
        else:
            out[lo:hi] = 0.0
        offset += nb * nb
        start = end
    coupled = H @ summed
    for i in range(m):
        for c in range(3):
            out[3 * i + c] += coupled[3 * rod[i] + c]
    return out.reshape(m, 3)


_warm = False


def warm_up() -> None:
    """Compile the kernels for the argument types the solver passes (or load them from numba's cache)
    on a one-point problem, so that compilation is not charged to the first contact step."""
    global _warm
    if _warm:
        return
    one = np.ones((1, 3)) / math.sqrt(3.0)
    for mode, inverse, d_inv in ((EIGEN, np.eye(3), np.ones(3)), (ROD_BLOCKS, np.eye(3).reshape(1, 9), np.ones(3)),
                                 (ROD_BLOCKS, np.eye(3, dtype=np.float32).reshape(1, 9), np.ones(3))):
        args = (mode, inverse, np.eye(3), np.zeros((3, 3)), d_inv, np.zeros(1, dtype=np.int64), 1, 1.0, -one, one, 0.5)
        run(*args, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), 0, 1, 1e-4, 0.0)
        run_anderson(*args, np.zeros((1, 3)), np.zeros((1, 3)), np.zeros((1, 3)), 0, 3, 1e-4, 0.0, 2, np.zeros(1, dtype=np.int64), 10)
    rod_block_product(np.eye(3).ravel(), np.zeros((3, 3)), np.zeros(1, dtype=np.int64), 1, np.ones((1, 3)))
    project_cones(one, one, 0.5)
    de_saxce(one, one, 0.5)
    _warm = True
