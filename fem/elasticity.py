"""Small-strain elasticity on tetrahedra: weak forms, assembly (scikit-fem) and static solves.

Two discretisations, selected by ``element``:

- ``"P1"``, ``"P2"``: displacement only, linear or quadratic (isoparametric on curved meshes).
  Stiffness form ``a(u, v) = int 2 mu eps(u) : eps(v) + lambda div u div v``. Lock as nu -> 1/2.
- ``"P2P1"``: Taylor-Hood mixed displacement-pressure (Herrmann) form, stable as nu -> 1/2
  [BoffiBrezziFortin2013]_ (sec. 8.8): with p = lambda div u,

      int 2 mu eps(u) : eps(v) + p div v = int f . v
      int q div u - p q / lambda         = 0

  a symmetric saddle-point system; p is continuous P1. Stress: sigma = 2 mu eps(u) + p I.

Material parameters are per element (arrays (T,)): the mesh's layers are a material field, and
each tet gets the volume-fraction-weighted (Voigt) mean of its layers' Lame parameters, a
simplification that is exact when the layers share a material (the default) and an upper bound
on the stiffness of a tet cut by an interface otherwise.

Shapes: node-based vectors are scikit-fem's interleaved DOF vectors; ``points`` (P, 3) in metres.

References
----------
.. [BoffiBrezziFortin2013] D. Boffi, F. Brezzi, M. Fortin, "Mixed Finite Element Methods and
   Applications", Springer (2013).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import skfem
from skfem import BilinearForm, ElementTetP1, ElementTetP2, ElementVector, LinearForm
from skfem.helpers import ddot, div, dot, sym_grad

__all__ = [
    "ELEMENTS",
    "Discretisation",
    "skfem_mesh",
    "discretise",
    "elasticity_form",
    "divergence_form",
    "pressure_mass_form",
    "body_force_form",
    "body_force",
    "deviatoric_form",
    "assemble",
    "solve_static",
    "split",
    "element_lame",
    "dof_components",
    "facet_indices",
]

ELEMENTS = ("P1", "P2", "P2P1")


# ------------------------------------------------------------------------------------ weak forms
@BilinearForm
def elasticity_form(u, v, w):
    """2 mu eps(u) : eps(v) + lambda div u div v (w.lam, w.mu per element)."""
    return 2.0 * w.mu * ddot(sym_grad(u), sym_grad(v)) + w.lam * div(u) * div(v)


@BilinearForm
def deviatoric_form(u, v, w):
    """2 mu eps(u) : eps(v): the displacement block of the mixed form."""
    return 2.0 * w.mu * ddot(sym_grad(u), sym_grad(v))


@BilinearForm
def divergence_form(p, v, w):
    """p div v (rows: displacement test functions, columns: pressure)."""
    return p * div(v)


@BilinearForm
def pressure_mass_form(p, q, w):
    """p q / lambda."""
    return p * q / w.lam


def body_force_form(f) -> LinearForm:
    """The linear form f . v for a body force density f(x) -> (3, ...) N/m^3 of the coordinates."""

    @LinearForm
    def form(v, w):
        return dot(f(w.x), v)

    return form


# --------------------------------------------------------------------------------- discretisation
def skfem_mesh(points: np.ndarray, tets: np.ndarray, edge_nodes: np.ndarray | None = None, tet_edges: np.ndarray | None = None):
    """A scikit-fem mesh: ``MeshTet`` from vertices, or a curved ``MeshTet2`` when mid-edge nodes are given.

    points: (P, 3). tets: (T, 4) positively oriented. edge_nodes: (E, 3) and tet_edges: (T, 6) as in
    :class:`fem.mesh.TetMesh` (same local edge order as scikit-fem's ``t2e``).
    """
    base = skfem.MeshTet(np.ascontiguousarray(points.T), np.ascontiguousarray(tets.T), sort_t=False)
    if edge_nodes is None:
        return base
    # scikit-fem numbers edges its own way; its t2e uses our local edge order, so map through it.
    ours_of_theirs = np.empty(base.edges.shape[1], dtype=np.int64)
    ours_of_theirs[base.t2e.T.ravel()] = np.asarray(tet_edges).ravel()
    doflocs = np.vstack([points, edge_nodes[ours_of_theirs]]).T
    return skfem.MeshTet2(np.ascontiguousarray(doflocs), np.ascontiguousarray(tets.T), sort_t=False)


@dataclass
class Discretisation:
    """Bases of one discretisation: ``u`` (vector displacement) and, for P2P1, ``p`` (pressure).

    The pressure unknowns of the assembled system are p / ``pressure_scale`` (Pa): with the scale
    set to the shear modulus, every block of the saddle-point matrix is of the order mu h, which
    keeps the direct solve accurate (unscaled, the patch test loses 4 digits at E = 1 MPa).
    """

    element: str
    u: skfem.Basis
    p: skfem.Basis | None = None
    pressure_scale: float = 1.0

    @property
    def n_u(self) -> int:
        return self.u.N

    @property
    def n_dofs(self) -> int:
        return self.u.N + (self.p.N if self.p is not None else 0)


def discretise(mesh, element: str, intorder: int | None = None) -> Discretisation:
    """Bases for ``element`` in :data:`ELEMENTS` on a scikit-fem tet mesh (``MeshTet`` or ``MeshTet2``)."""
    if element not in ELEMENTS:
        raise ValueError(f'"{element}" is not an element; choose one of: {", ".join(ELEMENTS)}')
    if element == "P1":
        return Discretisation(element, skfem.Basis(mesh, ElementVector(ElementTetP1()), intorder=intorder or 2))
    ubasis = skfem.Basis(mesh, ElementVector(ElementTetP2()), intorder=intorder or 4)
    if element == "P2":
        return Discretisation(element, ubasis)
    return Discretisation(element, ubasis, ubasis.with_element(ElementTetP1()))


def _per_qp(values, basis: skfem.Basis) -> np.ndarray:
    """Per-element values (T,) or a scalar as (T, n_qp) coefficients."""
    v = np.broadcast_to(np.asarray(values, dtype=float), (basis.mesh.nelements,))
    return np.repeat(v[:, None], basis.X.shape[1], axis=1)


def assemble(d: Discretisation, lam, mu) -> sp.csr_matrix:
    """The system matrix: stiffness (P1, P2) or the symmetric saddle-point block matrix (P2P1),
    ordered [u; p]. lam, mu: Pa, scalars or per element (T,)."""
    lam_q, mu_q = _per_qp(lam, d.u), _per_qp(mu, d.u)
    if d.p is None:
        return skfem.asm(elasticity_form, d.u, lam=lam_q, mu=mu_q).tocsr()
    d.pressure_scale = float(np.max(mu))
    s = d.pressure_scale
    a = deviatoric_matrix(d.u, mu_q)
    b = skfem.asm(divergence_form, d.p, d.u)  # (n_u, n_p)
    c = skfem.asm(pressure_mass_form, d.p, lam=_per_qp(lam, d.p))
    return sp.bmat([[a, s * b], [s * b.T, -(s * s) * c]], format="csr")


def deviatoric_matrix(u: skfem.Basis, mu_q: np.ndarray, threads: int = 2) -> sp.csr_matrix:
    """The displacement block of the mixed form, ``skfem.asm(deviatoric_form, u, mu=mu_q)``, bit for bit.

    u: the displacement basis (N DOFs, n_b functions per element); mu_q: (T, n_q) Pa at the
    quadrature points. Returns (N, N) CSR.

    scikit-fem evaluates the form for each of the n_b^2 pairs of an element's basis functions (900
    for P2), making both symmetric gradients anew for each (1800 of them), on one thread: 8.8 s of
    the screw sensor's 14 s assembly. Here each function's symmetric gradient is made once, the form
    on the pairs i <= j only (the form is symmetric, and so are its floating-point operations: the
    same products summed in the same order), those pairs on ``threads`` threads (numpy's einsum and
    ufuncs release the GIL); every value is then the one scikit-fem computes, and the sparse matrix
    is made from them in scikit-fem's order (:meth:`skfem.assembly.form.coo_data.COOData.tocsr`:
    the duplicate entries summed in the same order).
    """
    from concurrent.futures import ThreadPoolExecutor

    from skfem.assembly.form.coo_data import COOData
    from skfem.element.discrete_field import DiscreteField

    nt, nb = u.nelems, u.Nbfun
    dx = u.dx
    # as the form reads them (skfem's FormExtraParams wraps a (T, n_q) array as a DiscreteField)
    two_mu = 2.0 * DiscreteField(np.asarray(mu_q, dtype=float))
    grads = [sym_grad(*u.basis[j]) for j in range(nb)]
    data = np.zeros((nb, nb, nt))

    def column(j: int) -> None:
        # skfem's _kernel: np.sum(form(u_j, v_i, w) * dx, axis=1), form = 2.0 * w.mu * ddot(sym_grad(u_j), sym_grad(v_i))
        for i in range(j, nb):
            data[j, i] = data[i, j] = np.sum(two_mu * ddot(grads[j], grads[i]) * dx, axis=1)

    with ThreadPoolExecutor(max(int(threads), 1)) as pool:
        list(pool.map(column, range(nb)))  # column j has n_b - j pairs: the longest go first
    rows = np.zeros(nb * nb * nt, dtype=np.int32)
    cols = np.zeros(nb * nb * nt, dtype=np.int32)
    for j in range(nb):
        for i in range(nb):
            ixs = slice(nt * (nb * j + i), nt * (nb * j + i + 1))
            rows[ixs] = u.element_dofs[i]
            cols[ixs] = u.element_dofs[j]
    return COOData(np.array([rows, cols]), data.flatten("C"), (u.N, u.N), (nb, nb)).tocsr()


def split(d: Discretisation, x: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(displacement DOFs, pressure DOFs in Pa or None) of a solution vector."""
    if d.p is None:
        return x[: d.n_u], None
    return x[: d.n_u], d.pressure_scale * x[d.n_u :]


def body_force(d: Discretisation, f) -> np.ndarray:
    """Load vector of a body force density f(x) -> (3, ...) N/m^3, padded with zeros for the pressure."""
    rhs = skfem.asm(body_force_form(f), d.u)
    return np.concatenate([rhs, np.zeros(d.n_dofs - d.n_u)])


def solve_static(K: sp.spmatrix, rhs: np.ndarray, fixed: np.ndarray, values: np.ndarray | None = None) -> np.ndarray:
    """Solve K x = rhs with x[fixed] = values (default 0). Returns the full x.

    Direct sparse LU (SuperLU): the saddle-point matrix of P2P1 is indefinite, so no Cholesky here.
    """
    x = np.zeros(K.shape[0])
    if values is not None:
        x[fixed] = values
    free = np.setdiff1d(np.arange(K.shape[0]), fixed)
    Kff = K[free][:, free].tocsc()
    b = rhs[free] - K[free][:, fixed] @ x[fixed]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", spla.MatrixRankWarning)  # judged below, with a clear message
        x[free] = spla.spsolve(Kff, b)
    # A singular system (e.g. no support against rigid motion) gives NaN, or finite garbage: check
    # the residual of the solve itself.
    residual = np.linalg.norm(Kff @ x[free] - b) / max(np.linalg.norm(b), 1e-300)
    if not np.all(np.isfinite(x)) or residual > 1e-6:
        raise FloatingPointError(
            f"the linear system is singular (relative residual {residual:.2e}): is the body held against "
            "rigid motion? Check the fixed DOFs (e.g. the base bottom)"
        )
    return x


def dof_components(basis: skfem.Basis) -> np.ndarray:
    """(N,) the displacement component (0, 1, 2) of each DOF of a vector P1/P2 basis."""
    comp = np.full(basis.N, -1)
    for name in ("nodal_dofs", "edge_dofs"):
        arr = getattr(basis, name)
        if arr.size:
            for c in range(3):
                comp[arr[c]] = c
    if np.any(comp < 0):
        raise ValueError("dof_components expects a vector P1 or P2 basis")
    return comp


def facet_indices(skmesh, faces: np.ndarray) -> np.ndarray:
    """scikit-fem facet indices of boundary triangles given by their vertices (F, 3)."""
    n = np.int64(skmesh.nvertices)

    def keys(tri):
        t = np.sort(np.asarray(tri, dtype=np.int64), axis=1)
        return (t[:, 0] * n + t[:, 1]) * n + t[:, 2]

    theirs = keys(skmesh.facets.T)
    order = np.argsort(theirs)
    want = keys(faces)
    pos = np.minimum(np.searchsorted(theirs, want, sorter=order), len(order) - 1)
    found = order[pos]
    if not np.array_equal(theirs[found], want):
        raise ValueError("some faces are not facets of this mesh")
    return found


def element_lame(layer_fraction: np.ndarray, lame_by_layer) -> tuple[np.ndarray, np.ndarray]:
    """Per-element (lambda, mu) (T,) as the volume-fraction-weighted mean of each layer's.

    layer_fraction: (T, 3) absorber, ML, core. lame_by_layer: three (lambda, mu) pairs in that order.
    """
    lam = np.asarray([l for l, _ in lame_by_layer], dtype=float)
    mu = np.asarray([m for _, m in lame_by_layer], dtype=float)
    return layer_fraction @ lam, layer_fraction @ mu
