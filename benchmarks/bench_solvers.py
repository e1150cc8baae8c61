"""Sparse direct (and one iterative) solvers on the default sensor's elasticity matrices.

Builds the clamped stiffness matrices of the default 5 x 5 sensor for P1, P2 and P2P1 (the base
bottom fixed, E = 1.5 MPa, nu = 0.49), then, per matrix and per solver that applies, measures the
median over --repeats runs of: the factorisation, one solve with one right-hand side, one solve
with a block of 25 unit loads (a unit z force at the tip centre of each rod), the peak-memory
growth over all of that and the relative residual ||K x - b|| / ||b|| for a random b
(np.random.default_rng(0)).

Cholesky-type solvers (CHOLMOD, cholespy, PARDISO SPD, CG) run on the SPD P1/P2 matrices only;
the P2P1 saddle point [A B; B^T -C] gets SuperLU, spsolve, PARDISO symmetric indefinite and, for
information, two unpivoted factorisations, CHOLMOD's LDL' and SuperLU in symmetric mode (they
exist because -C is negative definite for nu < 1/2, the matrix is quasi-definite, but nothing
bounds their pivot growth as nu -> 1/2, so they are not production options for P2P1).

Each (matrix, solver) pair runs in a fresh subprocess, so a crash or a time-out costs one row and
the peak memory (VmHWM reset through /proc/self/clear_refs, minus the RSS before) is that
solver's own. A solver whose package cannot be imported prints "not installed" and is skipped.
A measurement is repeated up to --repeats times but not once its runs took --budget seconds
(SuperLU's COLAMD and spsolve take 10-25 s a run on P2), CG's 25-rhs time is 25 x its 1-rhs time
when that would exceed 2 x --budget, and SuperLU with MMD and its default partial pivoting gets
60 s on the large matrices (it did not finish in 400 s on P2; its symmetric mode takes 2 s). The mesh is cached in --out (rebuilt only when missing, ~45 s).
About 6.5 minutes on 2 cores with the mesh cached (+45 s to mesh on a first run); two of them are
SuperLU-MMD timing out on P2 and P2P1.

    python benchmarks/bench_solvers.py [--out out/bench] [--repeats 3] [--elements P1 P2 P2P1]
                                      [--solvers NAME ...] [--timeout 240] [--budget 10] [--nu 0.49]

Optional solver packages: scikit-sparse (CHOLMOD; with Debian's libsuitesparse-dev and, for
speed, libopenblas0-pthread), pypardiso (MKL), cholespy.

Writes --out/bench_solvers.json and prints a markdown table.
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import platform
import resource
import statistics
import subprocess
import sys
import time
import weakref
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
N_UNIT_LOADS = 25
CG_RTOL = 1e-8
CG_MAXITER = 20000
CG_MAX_S = 150.0  # wall-clock cap of one CG solve (P2: ~6800 iterations, 25 s idle, 2 min under load)
# per-solver subprocess time-outs that override --timeout on the large (P2, P2P1) matrices:
# SuperLU with MMD on A^T + A takes 0.5 s on P1 but did not finish in 400 s on P2.
LARGE_TIMEOUT_S = {"superlu-mmd-ata": 60.0}


# ------------------------------------------------------------------------------------ solvers
# Each factory takes (K csr, info dict) and returns solve(B) -> X for B of shape (n,) or (n, k);
# it may record extra facts (factor nonzeros, iterations, ...) in info.


def _splu(permc_spec, symmetric=False):
    """scipy's SuperLU. symmetric: SuperLU's symmetric mode (the column order applied to the rows
    too) with diag_pivot_thresh = 0, i.e. no row pivoting: right for SPD matrices, and for the
    quasi-definite P2P1 matrix an unpivoted LDL'-like factorisation (same caveat as CHOLMOD's LDL').
    With the default threshold 1.0, partial pivoting undoes the symmetric MMD order (P2: > 400 s)."""

    def factor(K, info):
        import scipy.sparse.linalg as spla

        kw = dict(diag_pivot_thresh=0.0, options=dict(SymmetricMode=True)) if symmetric else {}
        lu = spla.splu(K.tocsc(), permc_spec=permc_spec, **kw)
        info["factor_nnz"] = int(lu.nnz)  # stored L + U entries (lu.L / lu.U would copy them: ~4 s on P2)
        return lu.solve

    return factor


def _cholmod(K, info):
    from sksparse.cholmod import cholesky

    f = cholesky(K.tocsc())  # supernodal LL' (mode "auto")
    info["factor_nnz"] = int(f.L().nnz)
    return f.solve_A


def _cholmod_ldl(K, info):
    from sksparse.cholmod import cholesky

    f = cholesky(K.tocsc(), mode="simplicial")  # LDL' without pivoting (fill-reducing order only)
    d = f.D()  # (f.L() would convert to LL', which fails on an indefinite matrix; f.L_D() densifies)
    info["negative_pivots"] = int(np.sum(d < 0))
    info["min_abs_pivot_rel"] = float(np.min(np.abs(d)) / np.max(np.abs(d)))
    return f.solve_A


def _cholespy(K, info):
    from cholespy import CholeskySolverD, MatrixType

    K = K.tocsr()
    n = K.shape[0]
    s = CholeskySolverD(n, K.indptr.astype(np.int32), K.indices.astype(np.int32), K.data.astype(np.float64), MatrixType.CSR)

    def solve(B):
        B = np.ascontiguousarray(B, dtype=np.float64)
        X = np.empty_like(B)
        s.solve(B, X)
        return X

    return solve


def _pardiso(mtype, iparm: str = "explicit"):
    """MKL PARDISO via pypardiso's ctypes binding. Symmetric types get the upper triangle only.

    iparm: "defaults" leaves pypardiso's iparm(1) = 0, so MKL picks its defaults, which include two
    steps of iterative refinement on every solve (iparm(8) = 2; each step is one more solve);
    "explicit" sets iparm(1) = 1 with MKL's documented values and no refinement (iparm(8) = 0: only
    when pivots were perturbed); "matching" adds symmetric scaling and weighted matching, MKL's
    advice for saddle points. pypardiso re-converts the index arrays on every call (an O(nnz) copy
    per solve), so the solve goes through a thin subclass that converts them once."""

    def factor(K, info):
        import pypardiso

        class Solver(pypardiso.PyPardisoSolver):
            _ia = _ja = None

            def _call_pardiso(self, A, b):  # pypardiso 0.4.x's body, with ia/ja cached
                import ctypes

                if self._ia is None:
                    self._ia = A.indptr.astype(np.int32) + 1
                    self._ja = A.indices.astype(np.int32) + 1
                x = np.zeros_like(b)
                err = ctypes.c_int32(0)
                i32 = ctypes.POINTER(ctypes.c_int32)
                f64 = ctypes.POINTER(ctypes.c_double)
                self._mkl_pardiso(self.pt.ctypes.data_as(ctypes.POINTER(self._pt_type[0])), ctypes.byref(ctypes.c_int32(1)),
                                  ctypes.byref(ctypes.c_int32(1)), ctypes.byref(ctypes.c_int32(self.mtype)),
                                  ctypes.byref(ctypes.c_int32(self.phase)), ctypes.byref(ctypes.c_int32(A.shape[0])),
                                  A.data.ctypes.data_as(f64), self._ia.ctypes.data_as(i32), self._ja.ctypes.data_as(i32),
                                  self.perm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(1 if b.ndim == 1 else b.shape[1])),
                                  self.iparm.ctypes.data_as(i32), ctypes.byref(ctypes.c_int32(self.msglvl)),
                                  b.ctypes.data_as(f64), x.ctypes.data_as(f64), ctypes.byref(err))
                if err.value != 0:
                    raise pypardiso.pardiso_wrapper.PyPardisoError(err.value)
                return np.ascontiguousarray(x)

        A = sp.triu(K, format="csr") if mtype in (2, -2) else K.tocsr()
        A.sort_indices()
        s = Solver(mtype=mtype)
        if iparm != "defaults":
            s.set_iparm(1, 1)    # use the iparm values below, not PARDISO's defaults
            s.set_iparm(2, 2)    # nested dissection (METIS)
            s.set_iparm(8, 0)    # iterative refinement only when pivots were perturbed
            s.set_iparm(10, 13 if mtype == 2 else 8)  # pivot perturbation 1e-13 / 1e-8 (MKL's defaults)
            s.set_iparm(18, -1)  # report the factor's nonzeros
            s.set_iparm(21, 1)   # Bunch-Kaufman pivoting (symmetric indefinite)
            if iparm == "matching":
                s.set_iparm(11, 1)  # symmetric scaling
                s.set_iparm(13, 1)  # symmetric weighted matching
        s.factorize(A)
        info["factor_nnz"] = int(s.get_iparm(18))
        if mtype == -2:
            info["perturbed_pivots"] = int(s.get_iparm(14))
            info["inertia_pos_neg"] = [int(s.get_iparm(22)), int(s.get_iparm(23))]
        s.set_phase(33)

        def solve(B):
            x = s._call_pardiso(A, np.asfortranarray(B))
            info["refinement_steps"] = int(s.get_iparm(7))
            return x

        # MKL keeps the factor until phase -1: free it with the solve function (pypardiso has no __del__)
        weakref.finalize(solve, s.free_memory, True)
        return solve

    return factor


def _cg_jacobi(K, info):
    import scipy.sparse.linalg as spla

    d = 1.0 / K.diagonal()
    M = spla.LinearOperator(K.shape, matvec=lambda x: d * x, dtype=float)

    class OutOfTime(Exception):
        pass

    def one(b):
        it, last = [0], [np.zeros_like(b)]
        t0 = time.perf_counter()

        def count(xk):
            it[0] += 1
            if time.perf_counter() - t0 > CG_MAX_S:
                last[0] = xk.copy()
                raise OutOfTime

        try:
            x, flag = spla.cg(K, b, rtol=CG_RTOL, atol=0.0, maxiter=CG_MAXITER, M=M, callback=count)
        except OutOfTime:
            x, flag = last[0], -1
        info.setdefault("iterations", []).append(it[0])
        if flag != 0:
            info["converged"] = False
        return x

    def solve(B):
        return one(B) if B.ndim == 1 else np.column_stack([one(B[:, j]) for j in range(B.shape[1])])

    return solve


def _spsolve(K, info):
    """Reference: spsolve factorises on every call, so its 'solve' times include the factorisation."""
    import scipy.sparse.linalg as spla

    Kc = K.tocsc()
    return lambda B: spla.spsolve(Kc, B)


# name -> (factory, module to import, elements it applies to, note)
SOLVERS = {
    "superlu-colamd": (_splu("COLAMD"), "scipy", ("P1", "P2", "P2P1"), "scipy splu, default COLAMD order"),
    "superlu-mmd-ata": (_splu("MMD_AT_PLUS_A"), "scipy", ("P1", "P2", "P2P1"), "scipy splu, MMD on A^T+A"),
    "superlu-mmd-sym": (_splu("MMD_AT_PLUS_A", symmetric=True), "scipy", ("P1", "P2", "P2P1"),
                        "splu, MMD on A^T+A, SymmetricMode, diag_pivot_thresh 0 (no pivoting)"),
    "spsolve": (_spsolve, "scipy", ("P1", "P2", "P2P1"), "scipy spsolve (factor + solve every call)"),
    "cholmod": (_cholmod, "sksparse.cholmod", ("P1", "P2"), "scikit-sparse CHOLMOD supernodal LL'"),
    "cholespy": (_cholespy, "cholespy", ("P1", "P2"), "cholespy (CHOLMOD inside) CPU"),
    "pardiso-spd": (_pardiso(2), "pypardiso", ("P1", "P2"), "MKL PARDISO mtype 2 (SPD), iparm set, no refinement"),
    "pardiso-spd-defaults": (_pardiso(2, "defaults"), "pypardiso", ("P1", "P2"), "mtype 2 with pypardiso's iparm(1)=0 defaults"),
    "pardiso-sym-indef": (_pardiso(-2), "pypardiso", ("P2P1",), "MKL PARDISO mtype -2, iparm set, no refinement"),
    "pardiso-sym-indef-defaults": (_pardiso(-2, "defaults"), "pypardiso", ("P2P1",), "mtype -2 with pypardiso's defaults"),
    "pardiso-sym-indef-mw": (_pardiso(-2, "matching"), "pypardiso", ("P2P1",), "mtype -2, + scaling and weighted matching"),
    "cholmod-ldl-unsafe": (_cholmod_ldl, "sksparse.cholmod", ("P2P1",), "CHOLMOD simplicial LDL', no pivoting (informational)"),
    "cg-jacobi": (_cg_jacobi, "scipy", ("P1", "P2"), f"scipy cg, Jacobi, rtol {CG_RTOL:g}"),
}


# ------------------------------------------------------------------------------------ worker
def _proc_status_kb(key: str) -> float | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(key + ":"):
                return float(line.split()[1])
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset the kernel's peak-RSS mark (VmHWM, and with it ru_maxrss) of this process (Linux >= 4.0)."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


def _peak_rss_mb() -> float:
    hwm = _proc_status_kb("VmHWM")
    return (hwm if hwm is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) / 1024.0


def _current_rss_mb() -> float:
    rss = _proc_status_kb("VmRSS")
    return (rss if rss is not None else resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) / 1024.0


def _timed(fn, repeats: int, budget_s: float):
    """Median time of up to `repeats` calls of fn(); stops repeating once the calls took budget_s.
    Returns (median s, runs, last result)."""
    times, res = [], None
    for _ in range(repeats):
        res = None
        gc.collect()
        t0 = time.perf_counter()
        res = fn()
        times.append(time.perf_counter() - t0)
        if sum(times) > budget_s:
            break
    return statistics.median(times), len(times), res


def _relres(K, X, B) -> float:
    R = K @ X - B
    if B.ndim == 1:
        return float(np.linalg.norm(R) / np.linalg.norm(B))
    return float(np.max(np.linalg.norm(R, axis=0) / np.linalg.norm(B, axis=0)))


def _blas_of_process() -> list[str]:
    """Shared BLAS/LAPACK/MKL libraries mapped into this process (which BLAS a solver really uses)."""
    libs = set()
    try:
        for line in Path("/proc/self/maps").read_text().splitlines():
            name = line.split()[-1] if "/" in line else ""
            base = os.path.basename(name)
            if any(k in base for k in ("blas", "lapack", "mkl_core", "mkl_rt", "cholmod")):
                libs.add(name)
    except OSError:
        pass
    return sorted(libs)


def worker(element: str, name: str, data_dir: Path, repeats: int, budget_s: float = 10.0) -> dict:
    factory, module, _, _ = SOLVERS[name]
    try:
        __import__(module)
    except Exception as e:  # ImportError, or an OSError from a missing shared library
        return {"status": "not installed", "error": f"{type(e).__name__}: {e}"}
    K = sp.load_npz(data_dir / f"K_{element}.npz").tocsr()
    with np.load(data_dir / f"rhs_{element}.npz") as z:
        b, B = z["b"], z["B"]
    gc.collect()
    rss0 = _current_rss_mb()
    exact_peak = _reset_peak_rss()
    peak0 = _peak_rss_mb()
    info: dict = {}
    t_fac, n_fac, solve = _timed(lambda: factory(K, info), repeats, budget_s)
    t1, n1, x = _timed(lambda: solve(b), repeats, budget_s)
    res1 = _relres(K, x, b)
    iters1 = list(info.get("iterations", []))
    if name.startswith("cg") and t1 * B.shape[1] > 2 * budget_s:
        t25, n25, X, res25 = t1 * B.shape[1], 0, None, None  # estimated: one CG per right-hand side
    else:
        t25, n25, X = _timed(lambda: solve(B), repeats, budget_s)
        res25 = _relres(K, X, B)
    out = {
        "status": "ok",
        "factor_s": t_fac if name != "spsolve" else None,
        "factor_runs": n_fac,
        "solve1_s": t1,
        "solve1_runs": n1,
        "solve25_s": t25,
        "solve25_runs": n25,
        "peak_mem_mb": _peak_rss_mb() - (rss0 if exact_peak else peak0),
        "peak_mem_exact": exact_peak,
        "relres": res1,
        "relres25_max": res25,
        "libs": _blas_of_process(),
    }
    for k in ("factor_nnz", "perturbed_pivots", "inertia_pos_neg", "refinement_steps", "negative_pivots", "min_abs_pivot_rel", "converged"):
        if k in info:
            out[k] = info[k]
    if "iterations" in info:
        out["iterations"] = int(np.median(iters1))
        out["iterations_25_max"] = int(max(info["iterations"][len(iters1):] or [0]))
    if not np.all(np.isfinite(x)):
        out["status"] = "nan"
    return out


# ------------------------------------------------------------------------------------ matrices
def machine() -> dict:
    cpu = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        cpu = platform.processor() or platform.machine()
    return {"cores": os.cpu_count(), "cpu": cpu, "python": platform.python_version(), "numpy": np.__version__,
            "scipy": __import__("scipy").__version__}


def _loadavg() -> str | None:
    try:
        return Path("/proc/loadavg").read_text().split()[0]
    except OSError:
        return None


def build_matrices(out: Path, elements: list[str], nu: float = 0.49) -> tuple[Path, dict]:
    from fem.elasticity import assemble, discretise, facet_indices, skfem_mesh
    from fem.geometry import FaceTag, RodArray
    from fem.materials.linear_elastic import lame_parameters
    from fem.mesh import MeshParams, TetMesh, build_mesh
    from mlsim.scene import load_scene

    data = out / "solver_matrices"
    data.mkdir(parents=True, exist_ok=True)
    mesh_path = out / "solver_mesh_default.npz"
    if mesh_path.exists():
        mesh = TetMesh.load(mesh_path)
    else:
        scene = load_scene(ROOT / "scenes" / "mavig_default.toml")
        t0 = time.perf_counter()
        mesh, _ = build_mesh(RodArray.from_sensor(scene.sensor), MeshParams.from_fidelity(scene.fidelity.mesh), progress=False)
        print(f"meshed the default sensor in {time.perf_counter() - t0:.0f} s -> {mesh_path}", file=sys.stderr)
        mesh.save(mesh_path)
    sk = skfem_mesh(mesh.points, mesh.tets, mesh.edge_nodes, mesh.tet_edges)
    bottom = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM])
    lam, mu = lame_parameters(1.5e6, nu)
    # the unit loads: z at the tip vertex nearest each rod's tip centre
    tip = mesh.face_tag == FaceTag.ROD_TIP
    tips = []
    for r in np.unique(mesh.face_rod[tip]):
        verts = np.unique(mesh.faces[tip & (mesh.face_rod == r)])
        c = mesh.points[verts].mean(axis=0)
        tips.append(verts[np.argmin(np.linalg.norm(mesh.points[verts] - c, axis=1))])
    # fTetWild runs multi-threaded, so two meshings of the same scene can differ (17054 vs 16311
    # tets seen): the hash says which mesh these numbers belong to.
    sizes = {"mesh": {"tets": int(mesh.n_tets), "vertices": int(mesh.n_points), "rods": len(tips),
                      "content_hash": mesh.content_hash(), "path": str(mesh_path)}}
    for element in elements:
        d = discretise(sk, element)
        K = assemble(d, lam, mu)
        fixed = d.u.get_dofs(facets=bottom).all()
        free = np.setdiff1d(np.arange(K.shape[0]), fixed)
        Kff = K[free][:, free].tocsr()
        Kff.sort_indices()
        pos = np.full(K.shape[0], -1)
        pos[free] = np.arange(len(free))
        B = np.zeros((len(free), N_UNIT_LOADS))
        for j in range(N_UNIT_LOADS):
            dof = pos[d.u.nodal_dofs[2, tips[j % len(tips)]]]
            B[dof, j] = 1.0
        b = np.random.default_rng(0).standard_normal(len(free))
        sp.save_npz(data / f"K_{element}.npz", Kff, compressed=False)
        np.savez(data / f"rhs_{element}.npz", b=b, B=B)
        asym = abs(Kff - Kff.T).max() / abs(Kff).max()
        sizes[element] = {"n": int(Kff.shape[0]), "nnz": int(Kff.nnz), "n_pressure": int(d.p.N) if d.p is not None else 0,
                          "rel_asymmetry": float(asym)}
    return data, sizes


# ------------------------------------------------------------------------------------ report
def _fmt_t(s):
    if s is None:
        return "–"
    return f"{1e3 * s:.1f} ms" if s < 1.0 else f"{s:.2f} s"


def table(rows: list[dict], sizes: dict, repeats: int) -> str:
    lines = ["| matrix | solver | factor | solve 1 rhs | solve 25 rhs | peak mem MB | factor nnz | rel. residual | notes |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        el = r["element"]
        mat = f"{el} (n={sizes[el]['n']})"
        if r["status"] != "ok":
            lines.append(f"| {mat} | {r['solver']} | {r['status']} | | | | | | {r.get('error', '')[:80]} |")
            continue
        notes = []
        if "iterations" in r:
            notes.append(f"{r['iterations']} it")
            if r.get("converged") is False:
                notes.append("NOT converged")
        if r.get("refinement_steps"):
            notes.append(f"{r['refinement_steps']} refinement steps per solve")
        if "perturbed_pivots" in r:
            notes.append(f"{r['perturbed_pivots']} perturbed pivots, inertia +{r['inertia_pos_neg'][0]}/-{r['inertia_pos_neg'][1]}")
        if "negative_pivots" in r:
            notes.append(f"{r['negative_pivots']} neg. pivots, min |d|/max |d| {r['min_abs_pivot_rel']:.1e}")
        if r["solver"] == "spsolve":
            notes.append("times include factorisation")
        if r["solver"] == "superlu-mmd-sym" and el == "P2P1":
            notes.append("unpivoted")
        if r["solve25_runs"] == 0:
            notes.append("25-rhs time estimated as 25 x 1-rhs")
        runs = [r["factor_runs"], r["solve1_runs"], r["solve25_runs"]]
        if min(x for x in runs if x) < repeats:
            notes.append("runs " + "/".join(str(x) for x in runs))
        nnz = f"{r['factor_nnz'] / 1e6:.1f} M" if r.get("factor_nnz") else "–"
        lines.append(f"| {mat} | {r['solver']} | {_fmt_t(r['factor_s'])} | {_fmt_t(r['solve1_s'])} | {_fmt_t(r['solve25_s'])} | "
                     f"{r['peak_mem_mb']:.0f} | {nnz} | {r['relres']:.1e} | {'; '.join(notes)} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/bench")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--elements", nargs="+", default=["P1", "P2", "P2P1"])
    ap.add_argument("--solvers", nargs="+", default=list(SOLVERS), choices=list(SOLVERS))
    ap.add_argument("--nu", type=float, default=0.49, help="Poisson ratio (E = 1.5 MPa); e.g. 0.499999 to stress P2P1")
    ap.add_argument("--timeout", type=float, default=240.0, help="seconds per (matrix, solver) subprocess")
    ap.add_argument("--budget", type=float, default=10.0,
                    help="stop repeating a measurement once its runs took this many seconds (CG: estimate 25 rhs beyond 2x this)")
    ap.add_argument("--worker", nargs=3, metavar=("ELEMENT", "SOLVER", "DATA_DIR"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker:
        el, name, data_dir = args.worker
        print("RESULT " + json.dumps(worker(el, name, Path(data_dir), args.repeats, args.budget)), flush=True)
        return

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    m = machine()
    m["loadavg_start"] = _loadavg()
    t_start = time.perf_counter()
    data, sizes = build_matrices(out, args.elements, args.nu)
    print(f"matrices built in {time.perf_counter() - t_start:.0f} s: "
          + ", ".join(f"{e} n={sizes[e]['n']} nnz={sizes[e]['nnz']}" for e in args.elements), file=sys.stderr)
    rows = []
    for el in args.elements:
        for name in args.solvers:
            if el not in SOLVERS[name][2]:
                continue
            t0 = time.perf_counter()
            cmd = [sys.executable, str(Path(__file__).resolve()), "--worker", el, name, str(data), "--repeats", str(args.repeats), "--budget", str(args.budget)]
            timeout = LARGE_TIMEOUT_S.get(name, args.timeout) if el != "P1" else args.timeout
            try:
                p = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
                res = next((json.loads(l[7:]) for l in p.stdout.splitlines() if l.startswith("RESULT ")), None)
                if res is None:
                    tail = (p.stderr.strip().splitlines() or [""])[-1]
                    res = {"status": f"failed (exit {p.returncode})", "error": tail}
            except subprocess.TimeoutExpired:
                res = {"status": f"timed out (> {timeout:.0f} s)"}
            res.update(element=el, solver=name, description=SOLVERS[name][3], wall_s=time.perf_counter() - t0)
            if res["status"] == "not installed":
                print(f"{el:5s} {name:22s} not installed ({res['error']})", file=sys.stderr)
            else:
                print(f"{el:5s} {name:22s} {res['status']} in {res['wall_s']:.0f} s", file=sys.stderr)
            rows.append(res)
    total = time.perf_counter() - t_start
    m["loadavg_end"] = _loadavg()
    print(f"sparse solvers, default sensor (5 x 5 rods), E = 1.5 MPa, nu = {args.nu:g}, base bottom clamped; "
          f"median of {args.repeats}; {m['cpu']}, {m['cores']} cores, Python {m['python']}, numpy {m['numpy']}, scipy {m['scipy']}")
    print(f"mesh: {sizes['mesh']['tets']} tets, {sizes['mesh']['vertices']} vertices; "
          + "; ".join(f"{e}: n = {sizes[e]['n']}, nnz = {sizes[e]['nnz']}" for e in args.elements))
    print()
    print(table(rows, sizes, args.repeats))
    print(f"\ntotal {total:.0f} s; load average (1 min) {m['loadavg_start']} at start, {m['loadavg_end']} at end")
    (out / "bench_solvers.json").write_text(json.dumps({"machine": m, "sizes": sizes, "nu": args.nu, "repeats": args.repeats,
                                                        "rows": rows, "total_s": total}, indent=2))


if __name__ == "__main__":
    main()
