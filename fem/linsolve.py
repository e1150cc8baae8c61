"""A factorised sparse symmetric matrix: factorise once, solve many right-hand sides.

Backends, chosen by measurement (``benchmarks/SOLVERS.md``, default sensor, P2 n = 94.7k):

- ``"pardiso"``: MKL PARDISO through pypardiso's library binding, symmetric (mtype 2 for SPD
  stiffness, -2 for the indefinite P2P1 saddle point, with symmetric scaling and weighted matching
  as MKL advises for saddle points), ``iparm`` set explicitly with no iterative refinement.
  1.2 s to factorise, 16.6 ms per right-hand side, 3.9 ms per right-hand side in blocks of 25.
- ``"superlu"``: SciPy's SuperLU in symmetric mode (MMD on A^T + A, no row pivoting):
  1.8 s, 42 ms, 17.7 ms. The fallback where MKL does not exist (non-x86 machines).

``backend="auto"`` takes PARDISO when pypardiso imports, else SuperLU. Both check the relative
residual of the first solve, so a singular matrix (a body free to move rigidly) raises a clear
error instead of returning garbage.
"""

from __future__ import annotations

import ctypes
import functools
import os
import weakref

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from threadpoolctl import ThreadpoolController

from mlsim.errors import SolverError

__all__ = ["Factorised", "factorise", "available_backends"]


def _point_pypardiso_at_mkl() -> None:
    """Tell pypardiso where mkl_rt is (``PYPARDISO_MKL_RT``) when it lies where pip's ``mkl`` puts it.

    Without the variable every PyPardisoSolver (pypardiso makes one on import, we make another) runs
    find_library (ldconfig, gcc) and then globs all of sys.prefix recursively for it: 0.9 s in each
    new process, and a dataset or sweep starts a process per worker, a CLI test one per command.
    The file found is the one pypardiso's glob picks first (the shortest path under sys.prefix/lib);
    a variable set by the user is left alone."""
    if "PYPARDISO_MKL_RT" in os.environ:
        return
    import glob
    import sys

    for pattern in ("lib/libmkl_rt.so*", "lib/libmkl_rt*.dylib", "Library/bin/mkl_rt*.dll"):
        found = sorted(glob.glob(os.path.join(sys.prefix, pattern)), key=len)
        if found:
            os.environ["PYPARDISO_MKL_RT"] = found[0]  # inherited by the worker processes too
            return


def available_backends() -> tuple[str, ...]:
    try:
        _point_pypardiso_at_mkl()
        import pypardiso  # noqa: F401

        return ("pardiso", "superlu")
    except Exception:  # ImportError, or MKL's library missing
        return ("superlu",)


class Factorised:
    """A factorised sparse matrix A (n, n), symmetric unless ``symmetric=False`` (then PARDISO's general
    LU with scaling and matching, mtype 11, or SuperLU's default). ``solve(B)``: B (n,) or (n, k) ->
    A^-1 B, same shape."""

    def __init__(self, A: sp.spmatrix, definite: bool, backend: str = "auto", symmetric: bool = True):
        if backend == "auto":
            backend = available_backends()[0]
        if backend not in ("pardiso", "superlu"):
            raise ValueError(f'backend "{backend}" is not known; choose "auto", "pardiso" or "superlu"')
        self.backend = backend
        self.n = A.shape[0]
        self._A = A.tocsr()
        if backend == "pardiso":
            self._solve = _pardiso_factor(self._A, definite, symmetric)
        elif symmetric:
            lu = spla.splu(self._A.tocsc(), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options=dict(SymmetricMode=True))
            self._solve = _into(lu.solve)
        else:
            self._solve = _into(spla.splu(self._A.tocsc()).solve)
        self._checked = False

    def solve(self, B: np.ndarray) -> np.ndarray:
        B = np.asarray(B, dtype=float)
        if B.shape[0] != self.n:
            raise ValueError(f"right-hand side has {B.shape[0]} rows, the matrix {self.n}")
        if B.size == 0:
            return np.zeros_like(B)
        X = self._solve(np.asfortranarray(B) if B.ndim == 2 else np.ascontiguousarray(B))
        X = np.ascontiguousarray(X).reshape(B.shape)
        self._check(B, X)
        return X

    def solve_into(self, B: np.ndarray, out: np.ndarray) -> np.ndarray:
        """A^-1 B written into ``out`` (and returned): B and out (n, k) float64 in column-major
        (Fortran) order, the order the backends read and write, so nothing is copied or allocated
        (PARDISO); the same values as :meth:`solve`. For a caller that solves many blocks of
        right-hand sides and keeps its buffers (the reduced tier's precompute: a new (n, 128)
        block costs its page faults, 97 MB on the default sensor)."""
        if B.shape != out.shape or B.ndim != 2 or B.shape[0] != self.n:
            raise ValueError(f"B {B.shape} and out {out.shape} must both be ({self.n}, k)")
        if B.dtype != np.float64 or out.dtype != np.float64 or not (B.flags.f_contiguous and out.flags.f_contiguous):
            raise ValueError("B and out must be float64 in column-major (Fortran) order")
        if B.size:
            self._solve(B, out)
            self._check(B, out)
        return out

    def _check(self, B: np.ndarray, X: np.ndarray) -> None:
        """The first solve's relative residual: a singular matrix raises instead of returning garbage."""
        if self._checked:
            return
        bnorm = max(float(np.linalg.norm(B)), 1e-300)
        residual = float(np.linalg.norm(self._A @ X - B)) / bnorm
        if not np.all(np.isfinite(X)) or residual > 1e-6:
            raise SolverError(
                f"the linear system is singular (relative residual {residual:.2e} with {self.backend}): "
                "is the body held against rigid motion? Check the fixed DOFs (e.g. the base bottom)"
            )
        self._checked = True


def _into(solve):
    """A backend's ``solve(B)`` as ``solve(B, out=None)``: into ``out`` where one is given."""

    def solve_maybe_into(B, out=None):
        X = solve(B)
        if out is None:
            return X
        out[...] = X
        return out

    return solve_maybe_into


def factorise(A: sp.spmatrix, definite: bool, backend: str = "auto", symmetric: bool = True) -> Factorised:
    """Factorise the matrix A: symmetric (SPD when ``definite``, else symmetric indefinite), or general
    with ``symmetric=False``."""
    return Factorised(A, definite, backend, symmetric)


_LIBRARY = None


def _pardiso_library():
    """pypardiso's binding of MKL's pardiso (kept: creating a PyPardisoSolver searches the disk for
    mkl_rt, 0.4 s, and the nonlinear tier factorises once per few Newton iterations)."""
    global _LIBRARY
    if _LIBRARY is None:
        _point_pypardiso_at_mkl()
        import pypardiso

        _LIBRARY = pypardiso.PyPardisoSolver(mtype=11)  # loads mkl_rt and declares the argument types; mtype goes per call
        _reproducible(_LIBRARY.libmkl)
    return _LIBRARY


MKL_CBWR_AUTO = 2  # mkl_service.h: conditional numerical reproducibility, the best code path of this CPU


def _reproducible(libmkl) -> None:
    """Put MKL in its conditional numerical reproducibility mode (AUTO) unless the user chose one
    (``MKL_CBWR``). Without it PARDISO's threaded factorisation and solves round differently from one
    run to the next: the default sensor's gravity state differed in its last bits in 1 of 6 processes,
    and the screw scene's reduced episode then took 2270 contact iterations instead of 2267. With it
    every process on one machine gets the same bits (MKL's own condition: the same CPU and thread
    count), at no measured cost (factorisation 2.7 s, a right-hand side 58 ms, as before)."""
    if os.environ.get("MKL_CBWR"):
        return
    try:
        libmkl.MKL_CBWR_Set.restype = ctypes.c_int
        libmkl.MKL_CBWR_Set.argtypes = [ctypes.c_int]
        libmkl.MKL_CBWR_Set(MKL_CBWR_AUTO)  # (fails, harmlessly, where MKL ran before: then as before)
    except AttributeError:  # an MKL without the service function
        pass


def _pardiso_factor(A: sp.csr_matrix, definite: bool, symmetric: bool = True):
    mtype = (2 if definite else -2) if symmetric else 11
    lib = _pardiso_library()
    upper = sp.triu(A, format="csr") if symmetric else A.tocsr(copy=True)  # a general matrix: all of it
    upper.sort_indices()
    data = np.ascontiguousarray(upper.data, dtype=np.float64)
    ia = upper.indptr.astype(np.int32) + 1
    ja = upper.indices.astype(np.int32) + 1
    iparm = np.zeros(64, dtype=np.int32)
    # 1-based iparm numbers as in MKL's documentation
    for k, v in {1: 1, 2: 2, 8: 0, 10: 13 if definite or not symmetric else 8, 21: 1, 18: -1}.items():
        iparm[k - 1] = v
    if not definite:
        iparm[10], iparm[12] = 1, 1  # (symmetric) scaling, weighted matching
    pt = np.zeros(64, dtype=np.int64)
    perm = np.zeros(0, dtype=np.int32)
    i32 = ctypes.POINTER(ctypes.c_int32)
    f64 = ctypes.POINTER(ctypes.c_double)
    n = A.shape[0]

    def call(phase, b, x):
        err = ctypes.c_int32(0)
        nrhs = 1 if b.ndim == 1 else b.shape[1]
        lib._mkl_pardiso(pt.ctypes.data_as(ctypes.POINTER(ctypes.c_int64)), ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(1)),
                         ctypes.byref(ctypes.c_int32(mtype)), ctypes.byref(ctypes.c_int32(phase)), ctypes.byref(ctypes.c_int32(n)),
                         data.ctypes.data_as(f64), ia.ctypes.data_as(i32), ja.ctypes.data_as(i32), perm.ctypes.data_as(i32),
                         ctypes.byref(ctypes.c_int32(nrhs)), iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(0)),
                         b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(err))
        if err.value != 0:
            raise SolverError(f"PARDISO phase {phase} failed with error {err.value} (n = {n}); -4 or -2 usually mean a singular or too large system")

    dummy = np.zeros(1)
    call(12, dummy, dummy)  # analysis and numerical factorisation

    def solve(B, out=None):
        B = np.asfortranarray(B, dtype=np.float64)
        X = np.zeros_like(B, order="F") if out is None else out  # (out: column-major float64, its shape B's)
        call(33, B, X)
        return X

    # MKL keeps the factor until phase -1
    weakref.finalize(solve, lambda: call(-1, dummy, dummy))
    return solve


@functools.cache
def blas_pools() -> ThreadpoolController:
    """The process's BLAS thread pools, found once (threadpoolctl's ``threadpool_limits`` scans the
    loaded libraries on every call: 0.2 ms, per episode)."""
    return ThreadpoolController()


def one_blas_thread():
    """A context on one BLAS thread: for small or thin dense work (the rod blocks' LAPACK, tall thin SVDs,
    the contact steps' products), whose two threads on the shared 2-core machine waited for each other
    (the screw sensor's 25 rod-block eigendecompositions: 3.2 s on two threads, 28 ms on one), and whose
    bits then do not depend on the thread count."""
    return blas_pools().limit(limits=1, user_api="blas")
