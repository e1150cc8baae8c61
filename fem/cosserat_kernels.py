"""Compiled (numba) kernels for the discrete Cosserat rod's Newton solve (:mod:`fem.cosserat_rod`).

About 610 lines: one compiled loop per rod for each of the numpy reference's pieces (energy, gradient and
Hessian blocks, block Cholesky, the boundary step, the update, Newton), each kept beside its helpers so
that a kernel reads against the numpy function it equals; splitting them would split those pairs.

The numpy reference spends its ~11 ms a Newton iteration (4 rods of 8 segments) in Python's overhead
over hundreds of tiny array operations; the work itself is a few thousand flops a rod. Here each rod
is one loop over its segments, joints and point loads:

* :func:`evaluate` -- the energy (J), its gradient g (6N) and block-tridiagonal Hessian (diagonal blocks
  D (N, 6, 6), off-diagonal O (N, 6, 6)) in :func:`fem.cosserat_rod.gradient_and_hessian`'s unknowns and
  convention: block e is (psi_e, x_{e+1}); H[e - 1, e] = O[e], H[e, e - 1] = O[e]^T, O[0] = 0;
* :func:`block_cholesky` / :func:`block_solve` -- H = L L^T with L block-bidiagonal (6 x 6 blocks),
  flagging a Hessian that is not positive definite;
* :func:`update` -- :func:`fem.cosserat_rod._update` (frames turned by the Cayley map, chords rebuilt);
* :func:`newton_batch` -- :func:`fem.cosserat_rod._newton` for each rod while its Hessian is positive
  definite: under conservative loads the trust region on the energy, its step Newton's where that is
  inside the radius, else the step on the boundary (More and Sorensen's iteration on block Cholesky
  factors, where numpy bisects over H's eigenvalues: the same step to ~1e-10 of the radius); with a
  dead tip moment, Newton's step with the same turn limit and backtracking on the imbalance. Each rod
  iterates alone, as each does in numpy's batch (its own radius; frozen once converged). A rod whose
  Hessian is not positive definite (a column past its buckling load, still straight), or that runs
  out of iterations, goes on in numpy's trust region, compiled (:func:`_eigen_step`: the step over the
  scaled Hessian's eigenvalues, bisected as numpy does; the radius from MAX_TURN_RAD again, a budget of
  its own), or, with a dead tip moment, is returned flagged to ``fem.cosserat_rod``'s numpy Newton.
  (That trust region in numpy was a third of the held rods' time on the default demo.) This module
  imports nothing of ``fem.cosserat_rod`` (its caller).

Verified in tests/test_cosserat_kernels.py against the numpy functions to round-off, and the whole
solve (``fem.cosserat_rod.solve_static(compiled=True)``, the default) against the numpy path to 1e-9
of the rod's length. benchmarks/bench_cosserat_rod.py: 9 rods of 8 segments under 40 point loads each,
0.13-0.18 ms a Newton iteration and 0.4-0.55 ms a load step (numpy 3.2-4.3 and 13-17 ms) on a loaded
2-core machine, about half of it solve_static's Python around the kernel. numba compiles the kernels
once (~15-25 s on that machine) and caches them beside this file.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.linalg import eigh as _eigh  # bound here: a test's counting wrapper on np.linalg.eigh is no kernel

CONVERGED, FALLBACK, FAILED = 0, 1, 2


# --- small dense helpers (3-vectors, 3 x 3 and 6 x 6 matrices as arrays) --------------------------------

@njit(cache=True)
def _rotation(q0, q1, q2, q3, R):
    """R (3, 3) of the unit quaternion (w, x, y, z), as fem.cosserat_rod.rotation_matrix."""
    R[0, 0] = 1 - 2 * (q2 * q2 + q3 * q3)
    R[0, 1] = 2 * (q1 * q2 - q0 * q3)
    R[0, 2] = 2 * (q1 * q3 + q0 * q2)
    R[1, 0] = 2 * (q1 * q2 + q0 * q3)
    R[1, 1] = 1 - 2 * (q1 * q1 + q3 * q3)
    R[1, 2] = 2 * (q2 * q3 - q0 * q1)
    R[2, 0] = 2 * (q1 * q3 - q0 * q2)
    R[2, 1] = 2 * (q2 * q3 + q0 * q1)
    R[2, 2] = 1 - 2 * (q1 * q1 + q2 * q2)


@njit(cache=True)
def _skew(v, out):
    out[0, 0] = 0.0
    out[0, 1] = -v[2]
    out[0, 2] = v[1]
    out[1, 0] = v[2]
    out[1, 1] = 0.0
    out[1, 2] = -v[0]
    out[2, 0] = -v[1]
    out[2, 1] = v[0]
    out[2, 2] = 0.0


@njit(cache=True)
def _add_jtwj(J, w, scale, out, r0, c0):
    """out[r0:r0+3, c0:c0+3] += scale * J^T diag(w) J (J (3, 3))."""
    for i in range(3):
        for j in range(3):
            acc = 0.0
            for k in range(3):
                acc += J[k, i] * w[k] * J[k, j]
            out[r0 + i, c0 + j] += scale * acc


# --- energy, gradient and Hessian of one rod --------------------------------------------------------

@njit(cache=True)
def _evaluate_rod(x, q, clamp, l, S, Bk, F, M, seg, along, offset, force, stiffness, anchor, axial, g, D, O):
    """One rod: fills g (N, 6), D and O (N, 6, 6) (overwritten); returns (energy (J), the size of its
    terms (J), the trust region's round-off scale: fem.cosserat_rod._round_off_scale). Arithmetic as
    fem.cosserat_rod.gradient_and_hessian and energy."""
    n = q.shape[0]
    reach = l  # max |x_i - x_0| + l: the lever of the round-off of the nodes' positions
    for i in range(n + 1):
        for k in range(3):
            reach = max(reach, abs(x[i, k] - x[0, k]) + l)
    internal = 0.0
    g[:] = 0.0
    D[:] = 0.0
    O[:] = 0.0
    R = np.empty((3, 3))
    Rp = np.empty((3, 3))
    Jx = np.empty((3, 3))
    Jpsi = np.empty((3, 3))
    sk = np.empty((3, 3))
    P = np.empty((3, 3))
    Ja = np.empty((3, 3))
    b = np.empty(3)
    nm = np.empty(3)
    lS = np.empty(3)
    pv = np.empty(3)
    m = np.empty(3)
    lvB = np.empty(3)
    Kpx = np.empty((3, 3))
    for k in range(3):
        lS[k] = l * S[k]
    stored = 0.0
    # segments: sigma_e = R_e^T (x_{e+1} - x_e) / l - d3
    for e in range(n):
        _rotation(q[e, 0], q[e, 1], q[e, 2], q[e, 3], R)
        for i in range(3):
            b[i] = (R[0, i] * (x[e + 1, 0] - x[e, 0]) + R[1, i] * (x[e + 1, 1] - x[e, 1]) + R[2, i] * (x[e + 1, 2] - x[e, 2])) / l
        for i in range(3):
            sig = b[i] - (1.0 if i == 2 else 0.0)
            nm[i] = sig * S[i]
            stored += 0.5 * l * sig * sig * S[i]
        lS[2] = l * S[2]
        if axial == 1:  # neo-Hookean (fem.cosserat_rod.axial_force): (E A / 3) (lambda - lambda^-2), its tangent and energy
            lam = b[2]
            mu_a = S[2] / 3.0
            # a segment turned inside out (lambda <= 0) has no energy of its own: infinite, so a step there is refused
            stored += (l * mu_a * (0.5 * lam * lam + 1.0 / lam - 1.5) if lam > 0.0 else np.inf) - 0.5 * l * (lam - 1.0) * (lam - 1.0) * S[2]
            nm[2] = mu_a * (lam - 1.0 / (lam * lam))
            lS[2] = l * mu_a * (1.0 + 2.0 / (lam * lam * lam))
        internal += (abs(nm[0]) + abs(nm[1]) + abs(nm[2])) * reach
        for i in range(3):
            fi = R[i, 0] * nm[0] + R[i, 1] * nm[1] + R[i, 2] * nm[2]  # the spatial section force
            g[e, 3 + i] += fi
            if e >= 1:
                g[e - 1, 3 + i] -= fi
        g[e, 0] += -l * (b[1] * nm[2] - b[2] * nm[1])
        g[e, 1] += -l * (b[2] * nm[0] - b[0] * nm[2])
        g[e, 2] += -l * (b[0] * nm[1] - b[1] * nm[0])
        for i in range(3):
            for j in range(3):
                Jx[i, j] = R[j, i] / l
        _skew(b, Jpsi)
        _skew(nm, sk)
        nb = nm[0] * b[0] + nm[1] * b[1] + nm[2] * b[2]
        for i in range(3):
            for j in range(3):
                kxx = 0.0
                kpp = 0.0
                kpx = 0.0
                for k in range(3):
                    kxx += Jx[k, i] * lS[k] * Jx[k, j]
                    kpp += Jpsi[k, i] * lS[k] * Jpsi[k, j]
                    kpx += Jpsi[k, i] * lS[k] * Jx[k, j] + sk[i, k] * R[j, k]  # ... + [n]x R^T
                kpp += l * (0.5 * (nm[i] * b[j] + b[i] * nm[j]) - (nb if i == j else 0.0))
                Kpx[i, j] = kpx
                D[e, i, j] += kpp
                D[e, 3 + i, 3 + j] += kxx
                if e >= 1:  # x_e (the node before segment e) sits in block e - 1
                    D[e - 1, 3 + i, 3 + j] += kxx
                    O[e, 3 + i, 3 + j] -= kxx
        for i in range(3):
            for j in range(3):
                D[e, i, 3 + j] += Kpx[i, j]
                D[e, 3 + j, i] += Kpx[i, j]
                if e >= 1:
                    O[e, 3 + j, i] -= Kpx[i, j]
    # joints: kappa_i = 2 Im(conj(q_{i-1}) q_i) / l_i on the branch p_w >= 0, q_{-1} the clamp
    for i in range(n):
        if i == 0:
            a0, a1, a2, a3 = clamp[0], clamp[1], clamp[2], clamp[3]
        else:
            a0, a1, a2, a3 = q[i - 1, 0], q[i - 1, 1], q[i - 1, 2], q[i - 1, 3]
        b0, b1, b2, b3 = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
        # conj(a) b
        pw = a0 * b0 + a1 * b1 + a2 * b2 + a3 * b3
        pv[0] = a0 * b1 - b0 * a1 - (a2 * b3 - a3 * b2)
        pv[1] = a0 * b2 - b0 * a2 - (a3 * b1 - a1 * b3)
        pv[2] = a0 * b3 - b0 * a3 - (a1 * b2 - a2 * b1)
        if pw < 0.0:
            pw = -pw
            pv[0], pv[1], pv[2] = -pv[0], -pv[1], -pv[2]
        lv = 0.5 * l if i == 0 else l
        for k in range(3):
            kap = 2.0 * pv[k] / lv
            m[k] = kap * Bk[k]
            stored += 0.5 * lv * kap * kap * Bk[k]
            internal += abs(m[k]) * lv
            lvB[k] = lv * Bk[k]
        c0 = pv[1] * m[2] - pv[2] * m[1]
        c1 = pv[2] * m[0] - pv[0] * m[2]
        c2 = pv[0] * m[1] - pv[1] * m[0]
        g[i, 0] += pw * m[0] - c0
        g[i, 1] += pw * m[1] - c1
        g[i, 2] += pw * m[2] - c2
        if i >= 1:
            g[i - 1, 0] += -pw * m[0] - c0
            g[i - 1, 1] += -pw * m[1] - c1
            g[i - 1, 2] += -pw * m[2] - c2
        _skew(pv, sk)
        for r in range(3):
            for c in range(3):
                P[r, c] = sk[r, c] + (pw if r == c else 0.0)
                Ja[r, c] = (sk[r, c] - (pw if r == c else 0.0)) / lv
        mp = m[0] * pv[0] + m[1] * pv[1] + m[2] * pv[2]
        # Jb = P / lv: J^T diag(lvB) J with the 1 / lv^2 taken out
        _add_jtwj(P, lvB, 1.0 / (lv * lv), D[i], 0, 0)
        for r in range(3):
            D[i, r, r] -= 0.5 * mp
        if i >= 1:
            _add_jtwj(Ja, lvB, 1.0, D[i - 1], 0, 0)
            for r in range(3):
                D[i - 1, r, r] -= 0.5 * mp
            _skew(m, sk)
            for r in range(3):
                for c in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += Ja[k, r] * lvB[k] * P[k, c] / lv + 0.5 * sk[r, k] * P[k, c]
                    O[i, r, c] += acc + 0.5 * m[r] * pv[c]
    # the dead tip force and moment
    work_tip = 0.0
    for k in range(3):
        g[n - 1, 3 + k] -= F[k]
        work_tip += F[k] * (x[n, k] - x[0, k])
    _rotation(q[n - 1, 0], q[n - 1, 1], q[n - 1, 2], q[n - 1, 3], R)
    for k in range(3):
        g[n - 1, k] -= R[0, k] * M[0] + R[1, k] * M[1] + R[2, k] * M[2]
    # point loads: -f . ((1 - s) x_e + s x_{e+1} + R_e cay(psi_e) rho), and a point's spring to its anchor,
    # (p - a) . K (p - a) / 2: the dead force's terms with the spring's force f - K (p - a) in its place
    # (a spring's second-order term is a dead force's), plus J^T K J
    work_pts = 0.0
    work_springs = 0.0
    fb = np.empty(3)
    pk = np.empty(3)
    fe = np.empty(3)
    A = np.empty((3, 3))
    KA = np.empty((3, 3))
    for kk in range(seg.shape[0]):
        e = seg[kk]
        s = along[kk]
        r0, r1, r2 = offset[kk, 0], offset[kk, 1], offset[kk, 2]
        _rotation(q[e, 0], q[e, 1], q[e, 2], q[e, 3], Rp)
        sprung = False
        for c in range(3):
            pk[c] = (1.0 - s) * x[e, c] + s * x[e + 1, c] + Rp[c, 0] * r0 + Rp[c, 1] * r1 + Rp[c, 2] * r2
            work_pts += force[kk, c] * (pk[c] - x[0, c])
            for d in range(3):
                if stiffness[kk, c, d] != 0.0:
                    sprung = True
        for c in range(3):
            fe[c] = force[kk, c]
        if sprung:
            for c in range(3):
                acc = 0.0
                for d in range(3):
                    acc += stiffness[kk, c, d] * (pk[d] - anchor[kk, d])
                fe[c] -= acc
                stored += 0.5 * (pk[c] - anchor[kk, c]) * acc
                work_springs += abs(acc * (pk[c] - x[0, c]))
        f0, f1, f2 = fe[0], fe[1], fe[2]
        for c in range(3):
            fb[c] = Rp[0, c] * f0 + Rp[1, c] * f1 + Rp[2, c] * f2  # R_e^T f
            g[e, 3 + c] -= s * fe[c]
            if e >= 1:
                g[e - 1, 3 + c] -= (1.0 - s) * fe[c]
        g[e, 0] -= r1 * fb[2] - r2 * fb[1]
        g[e, 1] -= r2 * fb[0] - r0 * fb[2]
        g[e, 2] -= r0 * fb[1] - r1 * fb[0]
        # the load stiffness of a dead force on a turning offset
        rf = r0 * fb[0] + r1 * fb[1] + r2 * fb[2]
        rv = (r0, r1, r2)
        for r in range(3):
            for c in range(3):
                D[e, r, c] += -0.5 * (rv[r] * fb[c] + fb[r] * rv[c]) + (rf if r == c else 0.0)
        if sprung:
            # J^T K J, J = dp / d(psi_e, x_{e+1}) = [A, s I] with A = -R_e [rho]x, and (1 - s) I for x_e (block e - 1)
            for i in range(3):
                A[i, 0] = -(Rp[i, 1] * r2 - Rp[i, 2] * r1)
                A[i, 1] = -(Rp[i, 2] * r0 - Rp[i, 0] * r2)
                A[i, 2] = -(Rp[i, 0] * r1 - Rp[i, 1] * r0)
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += stiffness[kk, i, k] * A[k, j]
                    KA[i, j] = acc
            for i in range(3):
                for j in range(3):
                    acc = 0.0
                    for k in range(3):
                        acc += A[k, i] * KA[k, j]
                    D[e, i, j] += acc
                    D[e, i, 3 + j] += s * KA[j, i]
                    D[e, 3 + i, j] += s * KA[i, j]
                    D[e, 3 + i, 3 + j] += s * s * stiffness[kk, i, j]
                    if e >= 1:
                        D[e - 1, 3 + i, 3 + j] += (1.0 - s) * (1.0 - s) * stiffness[kk, i, j]
                        O[e, 3 + i, j] += (1.0 - s) * KA[i, j]
                        O[e, 3 + i, 3 + j] += (1.0 - s) * s * stiffness[kk, i, j]
    return stored - work_tip - work_pts, abs(work_tip) + abs(work_pts) + work_springs + internal


@njit(cache=True)
def evaluate(x, q, clamp, length, S, Bk, F, M, seg, along, offset, force, stiffness, anchor, axial=0):
    """The energy E (B,) J, gradient g (B, 6N) and Hessian blocks D, O (B, N, 6, 6) of a batch of B rods
    (fem.cosserat_rod.energy and gradient_and_hessian, block convention in the module docstring).

    x (B, N + 1, 3) m, q (B, N, 4), clamp (B, 4) unit quaternions; length m; S (3,) N, Bk (3,) N m^2
    (RodSection.S, .B); F (B, 3) N, M (B, 3) N m the dead tip force and moment; point loads seg (B, K)
    int, along (B, K), offset (B, K, 3) m, force (B, K, 3) N (K = 0 for none; pad with zero forces), and each
    point's spring, stiffness (B, K, 3, 3) N/m (symmetric; zero for none) and anchor (B, K, 3) m, as
    :func:`flatten_problem` makes them; axial the section's axial law (RodSection.axial_code: 0 linear,
    1 neo-Hookean)."""
    nb, n = q.shape[0], q.shape[1]
    l = length / n
    E = np.empty(nb)
    g = np.empty((nb, n, 6))
    D = np.empty((nb, n, 6, 6))
    O = np.empty((nb, n, 6, 6))
    for r in range(nb):
        E[r], _ = _evaluate_rod(x[r], q[r], clamp[r], l, S, Bk, F[r], M[r], seg[r], along[r], offset[r], force[r], stiffness[r], anchor[r],
                                axial, g[r], D[r], O[r])
    return E, g.reshape(nb, 6 * n), D, O


# --- the block-tridiagonal Cholesky factorisation ---------------------------------------------------

@njit(cache=True)
def _cholesky_rod(D, O, L, C):
    """H = L L^T for one rod's blocks: L's diagonal blocks L[e] (lower) and below them C[e] = H[e, e-1]
    L[e-1]^-T (C[0] unused). Returns False (L, C partly filled) if H is not positive definite."""
    n = D.shape[0]
    A = np.empty((6, 6))
    for e in range(n):
        for i in range(6):
            for j in range(6):
                A[i, j] = D[e, i, j]
        if e >= 1:
            # C[e] L[e-1]^T = O[e]^T: row i of C[e] is L[e-1]^-1 (column i of O[e]), by forward substitution
            for i in range(6):
                for j in range(6):
                    acc = O[e, j, i]
                    for k in range(j):
                        acc -= C[e, i, k] * L[e - 1, j, k]
                    C[e, i, j] = acc / L[e - 1, j, j]
            for i in range(6):
                for j in range(i + 1):
                    acc = 0.0
                    for k in range(6):
                        acc += C[e, i, k] * C[e, j, k]
                    A[i, j] -= acc
        for j in range(6):
            d = A[j, j]
            for k in range(j):
                d -= L[e, j, k] * L[e, j, k]
            if not d > 0.0:  # also NaN
                return False
            d = math.sqrt(d)
            L[e, j, j] = d
            for i in range(j + 1, 6):
                acc = A[i, j]
                for k in range(j):
                    acc -= L[e, i, k] * L[e, j, k]
                L[e, i, j] = acc / d
            for i in range(j):
                L[e, i, j] = 0.0
    return True


@njit(cache=True)
def _forward_rod(L, C, rhs, y):
    """y = L^-1 rhs for one rod's factor (rhs, y (N, 6))."""
    for e in range(L.shape[0]):
        for i in range(6):
            acc = rhs[e, i]
            if e >= 1:
                for k in range(6):
                    acc -= C[e, i, k] * y[e - 1, k]
            for k in range(i):
                acc -= L[e, i, k] * y[e, k]
            y[e, i] = acc / L[e, i, i]


@njit(cache=True)
def _solve_rod(L, C, rhs, out):
    """out = (L L^T)^-1 rhs for one rod (rhs, out (N, 6); may be the same array)."""
    n = L.shape[0]
    y = np.empty((n, 6))
    _forward_rod(L, C, rhs, y)
    for e in range(n - 1, -1, -1):
        for i in range(5, -1, -1):
            acc = y[e, i]
            if e + 1 < n:
                for k in range(6):
                    acc -= C[e + 1, k, i] * out[e + 1, k]
            for k in range(i + 1, 6):
                acc -= L[e, k, i] * out[e, k]
            out[e, i] = acc / L[e, i, i]


@njit(cache=True)
def block_cholesky(D, O):
    """The block-tridiagonal Cholesky factors (L, C (B, N, 6, 6), see :func:`_cholesky_rod`) of a batch of
    Hessians (D, O (B, N, 6, 6), :func:`evaluate`'s convention) and ok (B,) bool: False where H is not
    positive definite (its factors are then meaningless)."""
    nb, n = D.shape[0], D.shape[1]
    L = np.zeros((nb, n, 6, 6))
    C = np.zeros((nb, n, 6, 6))
    ok = np.empty(nb, dtype=np.bool_)
    for r in range(nb):
        ok[r] = _cholesky_rod(D[r], O[r], L[r], C[r])
    return L, C, ok


@njit(cache=True)
def block_solve(L, C, rhs):
    """H^-1 rhs (B, 6N) from :func:`block_cholesky`'s factors."""
    nb, n = L.shape[0], L.shape[1]
    out = np.empty((nb, n, 6))
    r6 = rhs.reshape(nb, n, 6)
    for r in range(nb):
        _solve_rod(L[r], C[r], r6[r], out[r])
    return out.reshape(nb, 6 * n)


@njit(cache=True)
def _boundary_step(D, O, g, l, radius, L, C, step):
    """The trust region's step on its boundary for a positive definite H whose Newton step (in ``step``,
    its factor in L, C) leaves it: p = -(H + mu diag(w))^-1 g with |p| = radius in the region's norm
    |p|^2 = p.diag(w).p, w = 1 for turns and 1 / l^2 for node moves (fem.cosserat_rod._trust_region_step's
    scaling), mu > 0 found by More and Sorensen's Newton iteration on 1 / |p(mu)| = 1 / radius
    ([NocedalWright2006] Algorithm 4.3; from mu = 0 it rises to the root without overshooting, every
    H + mu diag(w) positive definite). numpy finds the same mu by bisection over H's eigenvalues.
    Overwrites L, C, step; returns (converged, mu)."""
    n = D.shape[0]
    A = D.copy()
    wp = np.empty((n, 6))
    y = np.empty((n, 6))
    mu = 0.0
    dmu = 1.0
    inv_l2 = 1.0 / (l * l)
    for _ in range(60):
        pn2 = 0.0
        for e in range(n):
            for c in range(6):
                w = 1.0 if c < 3 else inv_l2
                wp[e, c] = w * step[e, c]
                pn2 += w * step[e, c] * step[e, c]
        pn = math.sqrt(pn2)
        # |p| carries H's round-off (cond(H) ~ 1e7 in the region's norm: ~1e-9 of |p|): the step is on the
        # boundary to 1e-9, or mu settled at its round-off
        if abs(pn - radius) <= 1e-9 * radius or abs(dmu) <= 1e-14 * mu:
            return True, mu
        # |q|^2 = p.W L^-T L^-1 W p = |p|'s derivative's ingredient: d|p|/dmu = -|q|^2 / |p|
        _forward_rod(L, C, wp, y)
        qn2 = 0.0
        for e in range(n):
            for c in range(6):
                qn2 += y[e, c] * y[e, c]
        dmu = pn2 / qn2 * (pn - radius) / radius
        mu += dmu
        for e in range(n):
            for c in range(6):
                A[e, c, c] = D[e, c, c] + mu * (1.0 if c < 3 else inv_l2)
        if not _cholesky_rod(A, O, L, C):
            return False, mu
        _solve_rod(L, C, g, step)
        for e in range(n):
            for c in range(6):
                step[e, c] = -step[e, c]
    return False, mu


@njit(cache=True)
def _hessian_times(D, O, p, out):
    """out = H p for one rod's block-tridiagonal Hessian (:func:`evaluate`'s convention; p, out (N, 6))."""
    n = D.shape[0]
    for e in range(n):
        for i in range(6):
            acc = 0.0
            for j in range(6):
                acc += D[e, i, j] * p[e, j]
            if e >= 1:  # H[e, e - 1] = O[e]^T
                for j in range(6):
                    acc += O[e, j, i] * p[e - 1, j]
            if e + 1 < n:  # H[e, e + 1] = O[e + 1]
                for j in range(6):
                    acc += O[e + 1, i, j] * p[e + 1, j]
            out[e, i] = acc


@njit(cache=True)
def _region_norm(step, l):
    """|p| of a step p (N, 6) in the trust region's norm: turns in rad, node moves in segment lengths l."""
    norm2 = 0.0
    for e in range(step.shape[0]):
        for c in range(6):
            sc = step[e, c] if c < 3 else step[e, c] / l
            norm2 += sc * sc
    return math.sqrt(norm2)


@njit(cache=True)
def _model_decrease(D, O, g, step, work):
    """The trust region's model decrease -g.p - p.H.p / 2 at the step p (N, 6); ``work`` (N, 6) scratch."""
    _hessian_times(D, O, step, work)
    gp = 0.0
    php = 0.0
    for e in range(D.shape[0]):
        for c in range(6):
            gp += g[e, c] * step[e, c]
            php += step[e, c] * work[e, c]
    return -gp - 0.5 * php


@njit(cache=True)
def _eigen_step(D, O, g, l, radius, step):
    """fem.cosserat_rod._trust_region_step's step for one rod from its Hessian's eigenvalues: argmin g.p +
    p.H.p / 2 over |p| <= radius in the region's norm (turns in rad, node moves in segment lengths), p = -(H +
    mu W)^-1 g with the least mu >= max(0, -lambda_min) that keeps p within the radius, bisected over the
    eigenvalues of the scaled Hessian as numpy does; in the hard case (g orthogonal to the lowest mode) that
    mode fills the radius ([NocedalWright2006] sec. 4.3). For any H, also indefinite (a column past its
    buckling load, still straight). Writes the step (N, 6); returns its norm in the region's."""
    n = D.shape[0]
    K = 6 * n
    s = np.empty(K)  # numpy's 1 / scale: the step in the region's units times s is the step
    for e in range(n):
        for c in range(6):
            s[6 * e + c] = 1.0 if c < 3 else l
    H = np.zeros((K, K))
    for e in range(n):
        for i in range(6):
            for j in range(6):
                H[6 * e + i, 6 * e + j] = D[e, i, j] * s[6 * e + i] * s[6 * e + j]
                if e >= 1:
                    v = O[e, i, j] * s[6 * (e - 1) + i] * s[6 * e + j]
                    H[6 * (e - 1) + i, 6 * e + j] = v
                    H[6 * e + j, 6 * (e - 1) + i] = v
    gs = np.empty(K)
    for e in range(n):
        for c in range(6):
            gs[6 * e + c] = g[e, c] * s[6 * e + c]
    lam, V = _eigh(H)
    cg = V.T @ gs
    tiny = 1e-14 * max(np.abs(lam).max(), 1e-300)
    lo = max(0.0, -lam[0]) + tiny
    newton = lam[0] > tiny
    p = np.empty(K)
    if newton:
        p[:] = -(V @ (cg / lam))
        if math.sqrt(np.sum(p * p)) <= radius:
            return _scaled_back(p, s, step)
    p_lo = -(V @ (cg / (lam + lo)))
    n_lo = math.sqrt(np.sum(p_lo * p_lo))
    if n_lo <= radius:
        # the hard case: the lowest mode v fills the rest of the radius, on the side that lowers the model
        v = V[:, 0]
        extra = math.sqrt(max(radius * radius - n_lo * n_lo, 0.0))
        sign = 1.0 if np.sum(v * gs) <= 0.0 else -1.0
        p[:] = p_lo + sign * extra * v
        return _scaled_back(p, s, step)
    a, b = lo, lo + math.sqrt(np.sum(gs * gs)) / radius + abs(lam[0])
    for _ in range(100):  # |p(mu)| falls monotonically in mu
        mid = 0.5 * (a + b)
        p[:] = -(V @ (cg / (lam + mid)))
        if math.sqrt(np.sum(p * p)) > radius:
            a = mid
        else:
            b = mid
    p[:] = -(V @ (cg / (lam + b)))
    return _scaled_back(p, s, step)


@njit(cache=True)
def _scaled_back(p, s, step):
    """step (N, 6) = p (6N,) in the region's units times s; returns |p|."""
    norm2 = 0.0
    for i in range(p.shape[0]):
        norm2 += p[i] * p[i]
        step[i // 6, i % 6] = p[i] * s[i]
    return math.sqrt(norm2)


# --- the update and Newton's loop -------------------------------------------------------------------

@njit(cache=True)
def _update_rod(x, q, step, t, x_out, q_out):
    """fem.cosserat_rod._update of one rod by t * step (N, 6), into x_out (N + 1, 3), q_out (N, 4)."""
    n = q.shape[0]
    R = np.empty((3, 3))
    for c in range(3):
        x_out[0, c] = x[0, c]
    for e in range(n):
        _rotation(q[e, 0], q[e, 1], q[e, 2], q[e, 3], R)
        p0, p1, p2 = t * step[e, 0], t * step[e, 1], t * step[e, 2]
        d0 = t * step[e, 3]
        d1 = t * step[e, 4]
        d2 = t * step[e, 5]
        if e >= 1:
            d0 -= t * step[e - 1, 3]
            d1 -= t * step[e - 1, 4]
            d2 -= t * step[e - 1, 5]
        c0, c1, c2 = x[e + 1, 0] - x[e, 0], x[e + 1, 1] - x[e, 1], x[e + 1, 2] - x[e, 2]
        b0 = R[0, 0] * c0 + R[1, 0] * c1 + R[2, 0] * c2
        b1 = R[0, 1] * c0 + R[1, 1] * c1 + R[2, 1] * c2
        b2 = R[0, 2] * c0 + R[1, 2] * c1 + R[2, 2] * c2
        # b + db, db = R^T (dx_{e+1} - dx_e) + b x psi
        v0 = b0 + R[0, 0] * d0 + R[1, 0] * d1 + R[2, 0] * d2 + (b1 * p2 - b2 * p1)
        v1 = b1 + R[0, 1] * d0 + R[1, 1] * d1 + R[2, 1] * d2 + (b2 * p0 - b0 * p2)
        v2 = b2 + R[0, 2] * d0 + R[1, 2] * d1 + R[2, 2] * d2 + (b0 * p1 - b1 * p0)
        # q cay(psi), cay(psi) = (1, psi / 2) / |.|, then renormalised (as the numpy code: both)
        h0, h1, h2, h3 = 1.0, 0.5 * p0, 0.5 * p1, 0.5 * p2
        hn = math.sqrt(h0 * h0 + h1 * h1 + h2 * h2 + h3 * h3)
        h0, h1, h2, h3 = h0 / hn, h1 / hn, h2 / hn, h3 / hn
        a0, a1, a2, a3 = q[e, 0], q[e, 1], q[e, 2], q[e, 3]
        w = a0 * h0 - (a1 * h1 + a2 * h2 + a3 * h3)
        v1q = a0 * h1 + h0 * a1 + (a2 * h3 - a3 * h2)
        v2q = a0 * h2 + h0 * a2 + (a3 * h1 - a1 * h3)
        v3q = a0 * h3 + h0 * a3 + (a1 * h2 - a2 * h1)
        qn = math.sqrt(w * w + v1q * v1q + v2q * v2q + v3q * v3q)
        q_out[e, 0], q_out[e, 1], q_out[e, 2], q_out[e, 3] = w / qn, v1q / qn, v2q / qn, v3q / qn
        _rotation(q_out[e, 0], q_out[e, 1], q_out[e, 2], q_out[e, 3], R)
        for c in range(3):
            x_out[e + 1, c] = x_out[e, c] + R[c, 0] * v0 + R[c, 1] * v1 + R[c, 2] * v2


@njit(cache=True)
def update(x, q, step):
    """fem.cosserat_rod._update for a batch: x (B, N + 1, 3), q (B, N, 4), step (B, 6N) -> (x, q)."""
    nb, n = q.shape[0], q.shape[1]
    x2 = np.empty_like(x)
    q2 = np.empty_like(q)
    s6 = step.reshape(nb, n, 6)
    for r in range(nb):
        _update_rod(x[r], q[r], s6[r], 1.0, x2[r], q2[r])
    return x2, q2


@njit(cache=True)
def _imbalance_rod(g, tol_f, tol_m):
    """fem.cosserat_rod._imbalance of one rod's g (N, 6)."""
    sf = 0.0
    sm = 0.0
    for e in range(g.shape[0]):
        for c in range(3):
            sm += g[e, c] * g[e, c]
            sf += g[e, 3 + c] * g[e, 3 + c]
    return max(math.sqrt(sf) / tol_f, math.sqrt(sm) / tol_m)


@njit(cache=True)
def newton_batch(x, q, clamp, length, S, Bk, F, M, seg, along, offset, force, stiffness, anchor, tol_f, tol_m, max_iterations, conservative,
                 max_turn, axial=0):
    """fem.cosserat_rod._newton on each rod of a batch (arguments as :func:`evaluate`; tol_f (B,) N and
    tol_m (B,) N m its tolerances; max_turn rad, MAX_TURN_RAD): Newton's method while the rod's Hessian is
    positive definite, then under conservative loads numpy's trust region over the Hessian's eigenvalues (the
    module docstring). Overwrites x and q with the rods' last accepted states; returns status (B,) (CONVERGED;
    FAILED: the trust region out of iterations or radius, where numpy's raises; FALLBACK: with a dead moment,
    numpy's Newton is to go on from there) and the iterations taken (B,)."""
    nb, n = q.shape[0], q.shape[1]
    l = length / n
    status = np.empty(nb, dtype=np.int64)
    iterations = np.zeros(nb, dtype=np.int64)
    g = np.empty((n, 6))
    D = np.empty((n, 6, 6))
    O = np.empty((n, 6, 6))
    gt = np.empty((n, 6))
    Dt = np.empty((n, 6, 6))
    Ot = np.empty((n, 6, 6))
    L = np.zeros((n, 6, 6))
    C = np.zeros((n, 6, 6))
    step = np.empty((n, 6))
    xt = np.empty((n + 1, 3))
    qt = np.empty((n, 4))
    scratch = np.empty((n, 6))
    for r in range(nb):
        xr, qr = x[r], q[r]
        radius = max_turn
        E, work = _evaluate_rod(xr, qr, clamp[r], l, S, Bk, F[r], M[r], seg[r], along[r], offset[r], force[r], stiffness[r], anchor[r], axial, g, D, O)
        status[r] = FALLBACK
        # eigen: numpy's trust region (fem.cosserat_rod._newton), which the rod enters where its Hessian is not
        # positive definite or it runs out of iterations, as numpy's solve hands it over: its radius from
        # max_turn again, a budget of its own; out of that budget the rod has FAILED (numpy's loop raises)
        eigen = False
        it = 0
        while True:
            if it == max_iterations:
                if eigen or not conservative:  # with a dead moment numpy's Newton goes on (FALLBACK)
                    break
                eigen, radius, it, status[r] = True, max_turn, 0, FAILED
            i0 = _imbalance_rod(g, tol_f[r], tol_m[r])
            if not i0 > 1.0:
                status[r] = CONVERGED
                break
            definite = _cholesky_rod(D, O, L, C)
            if not definite and not eigen:
                if not conservative:
                    break
                eigen, radius, it, status[r] = True, max_turn, 0, FAILED
            it += 1
            iterations[r] += 1
            if definite:  # Newton's step from H's factors
                _solve_rod(L, C, g, step)
                for e in range(n):
                    for c in range(6):
                        step[e, c] = -step[e, c]
            # the trust region's norm of it (turns in rad, node moves in segment lengths); none without the factors
            norm = _region_norm(step, l) if definite and conservative else math.inf
            predicted = 0.0
            if eigen:
                # numpy's step (fem.cosserat_rod._trust_region_step): Newton's where H is positive definite and it stays
                # inside the radius, else from H's eigenvalues (:func:`_eigen_step`); the model's decrease in full
                if not norm <= radius:
                    norm = _eigen_step(D, O, g, l, radius, step)
                predicted = _model_decrease(D, O, g, step, scratch)
            elif conservative:
                # the trust region ([NocedalWright2006] ch. 4, as fem.cosserat_rod._newton): the step within the radius,
                # the energy's actual decrease against the model's, -g.p - p.H.p / 2 = -g.p / 2 at Newton's step
                gp = 0.0
                for e in range(n):
                    for c in range(6):
                        gp += g[e, c] * step[e, c]
                predicted = -0.5 * gp
                if norm > radius:
                    found, mu = _boundary_step(D, O, g, l, radius, L, C, step)
                    if not found:
                        break
                    # the model's decrease -g.p - p.H.p / 2 with H p = -g - mu W p, |p|^2 = p.W.p = radius^2
                    gp = 0.0
                    for e in range(n):
                        for c in range(6):
                            gp += g[e, c] * step[e, c]
                    norm = radius
                    predicted = -0.5 * gp + 0.5 * mu * radius * radius
            else:
                # Newton's step, its largest turn limited to max_turn, backtracking on the imbalance (below)
                turn = 0.0
                for e in range(n):
                    for c in range(3):
                        turn = max(turn, abs(step[e, c]))
                cut = min(1.0, max_turn / max(turn, 1e-300))
                for e in range(n):
                    for c in range(6):
                        step[e, c] *= cut
            # the trial: the whole step, or with a dead moment numpy's backtracking (up to 20 halvings, the
            # last taken unchecked). One call site each for the update and the evaluation: numba's compile
            # time grows with the copies LLVM inlines
            t = 1.0
            for halving in range(21):
                _update_rod(xr, qr, step, t, xt, qt)
                Et, work_t = _evaluate_rod(xt, qt, clamp[r], l, S, Bk, F[r], M[r], seg[r], along[r], offset[r], force[r], stiffness[r],
                                           anchor[r], axial, gt, Dt, Ot)
                if conservative or halving == 20 or _imbalance_rod(gt, tol_f[r], tol_m[r]) < i0:
                    break
                t = 0.5 * t
            if conservative:
                actual = E - Et
                ratio = actual / predicted if predicted > 0.0 else 0.0
                if ratio < 0.25:
                    radius = 0.25 * radius
                elif ratio > 0.75 and norm > 0.99 * radius:
                    radius = min(2.0 * radius, 16.0 * max_turn)
                noise = 1e-12 * (abs(E) + work)
                if not (ratio > 1e-4 or (actual >= -noise and _imbalance_rod(gt, tol_f[r], tol_m[r]) < i0)):
                    # rejected: the state stays, the radius shrank (above); numpy's loop does the same. A radius
                    # run down ends the Newton (FALLBACK: numpy's trust region from max_turn) or the trust region
                    # (FAILED, as numpy's loop ends)
                    if radius < 1e-12:
                        break
                    continue
            # accept the trial: it and its derivatives become the state's
            xr[:] = xt
            qr[:] = qt
            E, work = Et, work_t
            g[:] = gt
            D[:] = Dt
            O[:] = Ot
    return status, iterations


def _owned(a, shape, dtype=float):
    """a broadcast to shape, as a writable C-ordered copy: one array type per argument, so numba compiles
    each kernel once (a read-only view, as np.broadcast_to makes, is another type: another compile)."""
    return np.array(np.broadcast_to(a, shape), dtype=dtype, order="C")


def flatten_problem(state, section, clamp, F, M, loads, lead):
    """The batch as :func:`newton_batch` and :func:`evaluate` take it: (x, q, clamp, F, M, seg, along, offset,
    force, stiffness, anchor), every array broadcast to ``lead`` and flattened to B rods (copies: the kernels
    overwrite x, q); the points' springs zero where ``loads`` has none."""
    nrods = int(np.prod(lead, dtype=np.int64))
    n = state.q.shape[-2]
    k = 0 if loads is None else np.shape(loads.force_n)[-2]
    flat = (_owned(state.x, lead + (n + 1, 3)).reshape(nrods, n + 1, 3), _owned(state.q, lead + (n, 4)).reshape(nrods, n, 4),
            _owned(clamp, lead + (4,)).reshape(nrods, 4), _owned(F, lead + (3,)).reshape(nrods, 3), _owned(M, lead + (3,)).reshape(nrods, 3))
    if loads is None:
        return flat + (np.zeros((nrods, 0), np.int64), np.zeros((nrods, 0)), np.zeros((nrods, 0, 3)), np.zeros((nrods, 0, 3)),
                       np.zeros((nrods, 0, 3, 3)), np.zeros((nrods, 0, 3)))
    if loads.stiffness_n_m is None:
        springs = (np.zeros((nrods, k, 3, 3)), np.zeros((nrods, k, 3)))
    else:
        springs = (_owned(loads.stiffness_n_m, lead + (k, 3, 3)).reshape(nrods, k, 3, 3), _owned(loads.anchor_m, lead + (k, 3)).reshape(nrods, k, 3))
    return flat + (_owned(loads.segment, lead + (k,), np.int64).reshape(nrods, k), _owned(loads.along, lead + (k,)).reshape(nrods, k),
                   _owned(loads.offset_m, lead + (k, 3)).reshape(nrods, k, 3), _owned(loads.force_n, lead + (k, 3)).reshape(nrods, k, 3)) + springs
