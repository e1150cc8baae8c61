"""Quasi-static time stepping of the rod array under a moving rigid indenter: the ``linear`` and
``reduced`` tiers.

Both tiers share the linear elastic body (:class:`LinearBody`: assembled once, factorised once,
base bottom clamped, optional gravity) and the contact on condensed compliance
(:mod:`fem.condensed`). They differ in the contact points and in how the field is recovered:

- ``linear``: every vertex of the contact faces near the indenter's path is a contact point; the
  compliance C = W^T K^-1 W is computed by blocks of solves with the factorised matrix. Each step
  solves the contact on C, and the whole field follows from one solve per step with the contact
  forces (done as one multi-right-hand-side call over the episode: the same arithmetic, batched).
  The field is exact for the discretisation, up to the penalty.
- ``reduced``: the same contact points, and no sparse solve per frame. The precompute solves once
  per point and axis (cached per sensor) and keeps each rod's own block of the point compliance,
  the patches' compliance (a few patches per rod tip, a few angular sectors of the side band), each
  point's exact response (stress of the tets, displacement of the vertices) on its own rod, and the
  patches' responses everywhere else in low-rank form (a few columns per rod: away from its own rod
  a rod's load acts as its resultant force and moment, :func:`far_field_basis`). A step solves the
  contact on each rod's exact point compliance with the rods coupled through their resultants
  (:class:`fem.contact_admm.RodBlockDelassus`: one operator per sensor, kept with the precompute in
  memory, and each episode its principal sub-operator on the points near its path, so that the
  factorisations made for one episode serve the next: :meth:`ReducedModel.contact_operator`); the fields superpose, on each loaded rod, its
  points' responses and, elsewhere, its patches' far field. The approximations, against ``linear``:
  a rod feels another's load as its resultant (through the base, far from the tips), and tets off
  the loaded rod see patch resultants (to 1e-3 of their norm in the low-rank form, its entries below
  1e-3 of each basis vector's largest dropped); on the default
  demo and the tiny scene's slide both cost under 1 % in per-rod contact force and peak stress
  (tests/test_tier_agreement.py).

With ``fidelity.solve.rod_kinematics = "second_order"`` (ADMM contact only) both tiers add the bent
rods' second-order rotation terms to the contact kinematics and the displacement output, and the
P-delta load of their axial contact force to the body (:mod:`fem.rod_kinematics`).

Time: frames at the camera's rate; each frame interval is split into ``substeps`` solves (friction
is path-dependent; an indenter sliding 200 mm/s moves 6.7 mm per 30 FPS frame). Per step the
outputs are the per-tet centroid Cauchy stress, von Mises stress and strain energy density, vertex
displacements, the contact force per rod and in total, and the reaction at the clamped base; rates
are backward differences over one step (:class:`Episode`).
"""

from __future__ import annotations

import contextlib
import json
import time
import weakref
from dataclasses import dataclass, field

import numpy as np
import scipy.sparse as sp

from fem import condensed, contact_admm, field_kernels, fields, rod_error, rod_exact, rod_kinematics, trajectory
from fem.episode import (  # the shared pieces, here too for fem.quasistatic's callers
    _EPISODE_ARRAYS,
    CONTACT_MAX_ITERATIONS,
    ContactSetup,
    Episode,
    LinearBody,
    SolveSettings,
    _bar,
    _check_finite,
    layer_materials,
    path_points,
    tip_height_m,
)
from fem.indenters import Pose
from fem.linsolve import one_blas_thread
from fem.nonlinear import SolverError
from mlsim.errors import OutOfRangeError, RodCollapseError

__all__ = ["SolveSettings", "LinearBody", "ReducedModel", "Episode", "ContactSetup", "tip_height_m", "build_reduced", "run_episode",
           "layer_materials", "bending_ratio", "geometric_error_estimate"]



def _rod_sections(scene, mesh, point_rod: np.ndarray, tip_z_m: float) -> "rod_kinematics.RodSections":
    """The section observation (fem.rod_kinematics) of the rods that carry contact points."""
    rods = np.unique(point_rod[point_rod >= 0])
    return rod_kinematics.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, rods, scene.sensor.base.thickness_mm * 1e-3, tip_z_m)


def _on_dofs(O_vertices: sp.spmatrix, body: "LinearBody") -> sp.csr_matrix:
    """An operator on vertex displacements (vertex-major 3 p + c) as one on the body's DOFs."""
    O = O_vertices.tocoo()
    return sp.csr_matrix((O.data, (O.row, body.vertex_dofs.ravel()[O.col])), shape=(O.shape[0], body.n_dofs))


def compliance(body: LinearBody, W: sp.spmatrix, block: int = 256, progress=None, observe: sp.spmatrix | None = None):
    """C = W^T K^-1 W (k, k) by blocks of ``block`` solves. With ``observe`` (o, n) sparse on the DOFs,
    also its response O K^-1 W (o, k) from the same solves: returns (C, O K^-1 W)."""
    k = W.shape[1]
    C = np.empty((k, k))
    Wd = W.tocsc()
    seen = None if observe is None else np.empty((observe.shape[0], k))
    for s in range(0, k, block):
        cols = Wd[:, s : s + block].toarray()
        Xs = body.solve(cols)
        C[:, s : s + block] = Wd.T @ Xs
        if seen is not None:
            seen[:, s : s + block] = observe @ Xs
        if progress is not None:
            progress(min(s + block, k), k)
    C = 0.5 * (C + C.T)
    return C if observe is None else (C, seen)


@dataclass
class ReducedModel:
    """The ``reduced`` tier's precompute: the contact points' compliance per rod (each rod's own block,
    exact), the patches' compliance (the rods' mutual compliance is their patches' mean), the
    responses to a unit force on each patch away from its own rod in low-rank form (float32 bases:
    centroid stress (6 T, K) and vertex displacement (3 P, K_d), :func:`far_field_basis`), each
    rod's points' exact responses on its own tets and vertices; plus the gravity state."""

    X: np.ndarray  # (M, 3) patch centroids
    area_m2: np.ndarray  # (M,)
    rod: np.ndarray  # (M,)
    C: np.ndarray  # (3 M, 3 M) patch compliance
    # the patches' responses away from their own rod, per rod a few columns (far_field_basis):
    # response (6 T, 3 M) = stress_basis.T @ stress_coeff off each rod's own rows; the bases are stored
    # transposed, a rod's rows contiguous (the field recovery reads them sparse: far_field_rows)
    stress_basis: np.ndarray  # (K, 6 T) float32, the rods' bases one after the other
    stress_coeff: np.ndarray  # (K, 3 M), each basis row's weights on its rod's patch columns
    displacement_basis: np.ndarray  # (K_d, 3 P) float32, vertex-major (3 p + c)
    displacement_coeff: np.ndarray  # (K_d, 3 M)
    stress_gravity: np.ndarray  # (6 T,)
    displacement_gravity: np.ndarray  # (3 P,)
    patch_u_gravity: np.ndarray  # (M, 3)
    weight_n: np.ndarray  # (3,) the body's weight
    lam: np.ndarray  # (T,) Pa, per tet (for the strain energy density)
    mu: np.ndarray  # (T,) Pa
    point_X: np.ndarray  # (m, 3) the contact points (the contact is evaluated at each)
    point_area_m2: np.ndarray  # (m,)
    point_patch: np.ndarray  # (m,) the patch of each point
    point_rod: np.ndarray  # (m,)
    point_u_gravity: np.ndarray  # (m, 3)
    point_compliance_blocks: np.ndarray  # each rod's (3 m_a, 3 m_a) point compliance, rods ascending, raveled one after the other
    # per rod (ascending, rods >= 0 with points): what its own points' forces do to its own tets' stress
    # and vertices' displacement (each point's response, exact), rows (6 T_a) component-major (c T + t)
    # and (3 P_a) vertex-major, columns its points' (3 m_a)
    local_stress_rows: np.ndarray  # concatenated row indices into the (6 T) stress
    local_displacement_rows: np.ndarray  # ... into the (3 P) displacement
    local_stress: np.ndarray  # concatenated raveled (6 T_a, 3 m_a) float32
    local_displacement: np.ndarray  # concatenated raveled (3 P_a, 3 m_a) float32
    local_sizes: np.ndarray  # (R, 3) per rod: rod index, 6 T_a, 3 P_a
    element: str = "P2P1"
    seconds: dict = field(default_factory=dict)
    # the contact operators of the whole sensor, per penalty (contact_operator), kept in memory only
    _operators: dict = field(default_factory=dict, repr=False, compare=False)
    # the far-field bases in the sparse form the field recovery reads (far_field_rows), made on first use
    _far_rows: dict = field(default_factory=dict, repr=False, compare=False)

    _ARRAYS = ("X", "area_m2", "rod", "C", "stress_basis", "stress_coeff", "displacement_basis", "displacement_coeff", "stress_gravity", "displacement_gravity",
               "patch_u_gravity", "weight_n", "lam", "mu", "point_X", "point_area_m2", "point_patch", "point_rod", "point_u_gravity",
               "point_compliance_blocks", "local_stress_rows", "local_displacement_rows", "local_stress", "local_displacement", "local_sizes")

    def save(self, path) -> None:
        """Every array, and the far-field bases in their sparse form (:meth:`far_field_rows`): each dataset
        worker made them again from the dense bases, 0.47 s of its CPU before its first episode."""
        far = {}
        for which in ("stress", "displacement"):
            A = self.far_field_rows(which)
            far.update({f"far_{which}_data": A.data, f"far_{which}_indices": A.indices, f"far_{which}_indptr": A.indptr,
                        f"far_{which}_shape": np.asarray(A.shape)})
        np.savez(path, element=self.element, seconds_json=json.dumps(self.seconds), **{k: getattr(self, k) for k in self._ARRAYS}, **far)

    @classmethod
    def load(cls, path) -> "ReducedModel":
        with np.load(path) as z:
            model = cls(**{k: z[k] for k in cls._ARRAYS}, element=str(z["element"]), seconds=json.loads(str(z["seconds_json"])))
            for which in ("stress", "displacement"):  # a model cached before they were saved makes them on first use
                if f"far_{which}_data" in z.files:
                    model._far_rows[which] = sp.csr_matrix((z[f"far_{which}_data"], z[f"far_{which}_indices"], z[f"far_{which}_indptr"]),
                                                           shape=tuple(int(n) for n in z[f"far_{which}_shape"]))
        return model

    def rod_blocks(self) -> dict[int, np.ndarray]:
        """Each rod's point compliance (3 m_a, 3 m_a), its points in ascending index order."""
        out, offset = {}, 0
        for r in np.unique(self.point_rod):
            n = 3 * int(np.sum(self.point_rod == r))
            out[int(r)] = self.point_compliance_blocks[offset : offset + n * n].reshape(n, n)
            offset += n * n
        return out

    def __getstate__(self) -> dict:
        # a worker that receives the model makes its own contact operators (they are caches, up to ~100 MB)
        return {**self.__dict__, "_operators": {}, "_far_rows": {}}

    def rod_order(self) -> np.ndarray:
        """(m,) the contact points rod by rod (a stable sort: ascending index within each rod)."""
        return np.argsort(self.point_rod, kind="stable")

    def contact_operator(self, k_n: np.ndarray) -> contact_admm.RodBlockDelassus:
        """The ADMM contact solver's Delassus operator on every contact point of the sensor, in
        :meth:`rod_order`, for penalties ``k_n`` (m,) N/m in that order; an episode takes its
        principal sub-operator on the points near its path (``restrict_points``). Kept per penalty,
        so the rods' diagonalised blocks, their inverses per rho and the sub-operators that the
        contact steps use are made once per sensor, not once per episode (a dataset's episodes share
        them). Its coupling H is the rods' mean mutual compliance from the patch compliance
        (:func:`fem.contact_admm.rod_resultant_coupling`)."""
        key = np.asarray(k_n, dtype=float).tobytes()
        if key not in self._operators:
            order = self.rod_order()
            blocks, H = _rod_operator(self, order)
            self._operators.clear()  # one penalty per scene: a new one replaces the last
            self._operators[key] = contact_admm.RodBlockDelassus(blocks, H, self.point_rod[order], k_n)
        return self._operators[key]

    def far_field_rows(self, which: str) -> sp.csr_matrix:
        """The far-field basis of ``which`` (``"stress"`` or ``"displacement"``) as the field recovery
        reads it: transposed, (6 T or 3 P, K) CSR float32, each basis vector's entries below
        :data:`FAR_FIELD_DROP` of its largest dropped. Made once per model, kept in memory."""
        if which not in self._far_rows:
            basis = {"stress": self.stress_basis, "displacement": self.displacement_basis}[which]
            peak = np.abs(basis).max(axis=1, keepdims=True)
            self._far_rows[which] = sp.csr_matrix(np.where(np.abs(basis) >= FAR_FIELD_DROP * peak, basis, 0.0).T.astype(np.float32))
        return self._far_rows[which]

    def local_responses(self) -> dict[int, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
        """Per rod: (stress rows, its points' stress response there (6 T_a, 3 m_a), displacement rows,
        their displacement response there (3 P_a, 3 m_a)), its points in ascending index order."""
        out, o_s, o_d, r_s, r_d = {}, 0, 0, 0, 0
        for r, n_s, n_d in self.local_sizes:
            n_c = 3 * int(np.sum(self.point_rod == r))
            out[int(r)] = (self.local_stress_rows[r_s : r_s + n_s], self.local_stress[o_s : o_s + n_s * n_c].reshape(n_s, n_c),
                           self.local_displacement_rows[r_d : r_d + n_d], self.local_displacement[o_d : o_d + n_d * n_c].reshape(n_d, n_c))
            r_s, r_d, o_s, o_d = r_s + n_s, r_d + n_d, o_s + n_s * n_c, o_d + n_d * n_c
        return out

    @classmethod
    def build(cls, body: LinearBody, points: condensed.ContactPoints, patches: np.ndarray, progress=None) -> "ReducedModel":
        t0 = time.perf_counter()
        M = int(patches.max()) + 1
        area = np.bincount(patches, weights=points.area_m2, minlength=M)
        X = np.stack([np.bincount(patches, weights=points.area_m2 * points.X[:, c], minlength=M) for c in range(3)], axis=1) / area[:, None]
        rod = np.array([np.bincount(points.rod[patches == p] + 1).argmax() - 1 for p in range(M)])
        # patch force spreads over its points in proportion to area: P (3 m, 3 M)
        w = points.area_m2 / area[patches]
        rows = (3 * np.arange(points.m)[:, None] + np.arange(3)).ravel()
        cols = (3 * patches[:, None] + np.arange(3)).ravel()
        P = sp.csr_matrix((np.repeat(w, 3), (rows, cols)), shape=(3 * points.m, 3 * M))
        T, Pn = body.mesh.n_tets, body.mesh.n_points
        stress = np.zeros((6 * T, 3 * M), dtype=np.float32)
        disp = np.zeros((3 * Pn, 3 * M), dtype=np.float32)
        vdofs = body.vertex_dofs.ravel()
        # one solve per point and axis, the points rod by rod: each rod's own block of the point
        # compliance, and the patches' responses as the area-weighted sums of their points'
        order = np.argsort(points.rod, kind="stable")
        col_order = (3 * order[:, None] + np.arange(3)).ravel()
        point_rod = points.rod
        blocks = {int(r): np.zeros((3 * int(np.sum(point_rod == r)),) * 2) for r in np.unique(point_rod)}
        place = np.empty(3 * points.m, dtype=int)  # each point column's index within its rod's block
        for r in blocks:
            idx = np.flatnonzero(point_rod == r)
            place[(3 * idx[:, None] + np.arange(3)).ravel()] = np.arange(3 * len(idx))
        rod3 = np.repeat(point_rod, 3)
        mesh = body.mesh
        local_rows = {}
        for r in blocks:
            if r < 0:
                continue
            tets = np.flatnonzero(mesh.tet_rod == r)
            verts = np.unique(mesh.tets[tets])
            local_rows[r] = ((np.arange(6)[:, None] * T + tets[None, :]).ravel(), (3 * verts[:, None] + np.arange(3)).ravel())
        local = {r: (np.zeros((len(rs), len(blocks[r])), dtype=np.float32), np.zeros((len(rd), len(blocks[r])), dtype=np.float32))
                 for r, (rs, rd) in local_rows.items()}
        Wd = points.W.tocsc()
        Wp = (Wd @ P).tocsc()
        # Every product below reads the solution on the free DOFs only (it is zero on the clamped ones,
        # whose terms added exact zeros): the right-hand sides are made there, in the solver's column
        # order, and nothing widens them to all DOFs and back (body.solve made five dense copies of
        # each block, n x 128 doubles, a third of the precompute). The same sums in the same order.
        free = body.free
        Wf, Wpf, Sf = Wd[free].tocsc(), Wp[free].tocsc(), body.S[:, free].tocsr()
        WfT, WpfT = Wf.T.tocsr(), Wpf.T.tocsr()
        at_free = np.full(body.n_dofs, -1)
        at_free[free] = np.arange(len(free))
        v_free = at_free[vdofs]
        v_on = v_free >= 0
        C_patch = np.zeros((3 * M, 3 * M))  # P^T C P: the patches' mean displacements under their own loads
        block = 128
        n_cols = 3 * points.m
        # One set of arrays for every block of columns, written in place: the right-hand sides and the
        # solution in the solver's column order (Factorised.solve_into), the solution row-major for the
        # products (they gather its rows), its stress rows and the points' and patches' displacements
        # (W^T X, W_p^T X). Fresh arrays per block (the solver's output, its row-major copy, the rhs,
        # the stress rows: about 100 MB each on the screw sensor) cost 5-6 s of page faults, zero fills
        # and single-threaded copies in a 34 s loop on the shared machine; these cost 1.3-1.5 s. Every
        # product runs on every core, each row summed from zero in scipy's order
        # (field_kernels.sparse_product), so the values are scipy's, bit for bit.
        n_free = len(free)
        rhs_f, x_f = np.zeros((n_free, block), order="F"), np.empty((n_free, block), order="F")
        x_rows, sx_rows = np.empty(n_free * block), np.empty(Sf.shape[0] * block)
        wx_rows, wpx_rows = np.empty(WfT.shape[0] * block), np.empty(WpfT.shape[0] * block)

        def rows_of(buffer: np.ndarray, n: int, b: int) -> np.ndarray:
            return buffer[: n * b].reshape(n, b)  # a row-major (n, b) block at the buffer's start

        t_loop = time.perf_counter()
        for s in range(0, n_cols, block):
            cs = col_order[s : s + block]
            b = len(cs)
            B, Xcol = rhs_f[:, :b], x_f[:, :b]  # column-major (n_free, b) views
            Wf[:, cs].toarray(out=B)  # (zeroes B first)
            body.factor.solve_into(B, Xcol)
            Xf = rows_of(x_rows, n_free, b)
            field_kernels.copy_rows(Xcol, Xf)
            WtX = rows_of(wx_rows, WfT.shape[0], b)
            field_kernels.sparse_product(WfT.indptr, WfT.indices, WfT.data, Xf, WtX)
            SX = rows_of(sx_rows, Sf.shape[0], b)
            field_kernels.sparse_product(Sf.indptr, Sf.indices, Sf.data, Xf, SX)
            DX = np.zeros((len(vdofs), b))
            DX[v_on] = Xf[v_free[v_on]]
            for r in np.unique(rod3[cs]):
                on = rod3[cs] == r
                rows_r = np.flatnonzero(rod3 == r)
                blocks[int(r)][np.ix_(place[rows_r], place[cs[on]])] = WtX[rows_r][:, on]
                if r in local:
                    local[r][0][:, place[cs[on]]] = SX[local_rows[r][0]][:, on]
                    local[r][1][:, place[cs[on]]] = DX[local_rows[r][1]][:, on]
            Pb = P[cs]  # (b, 3 M): these columns' shares of their patches
            touched = np.unique(Pb.indices)
            Pt = Pb[:, touched].toarray()
            # the patches' responses added in one pass on every core, rounded as numpy's fancy-index
            # add rounds them (field_kernels.add_columns); the (n, b) x (b, k) products on one BLAS
            # thread (thin: on two threads of the shared cores they took twice as long, same bits)
            with one_blas_thread():
                SXP, DXP = SX @ Pt, DX @ Pt
            field_kernels.add_columns(stress, touched, SXP)
            field_kernels.add_columns(disp, touched, DXP)
            WpX = rows_of(wpx_rows, WpfT.shape[0], b)
            field_kernels.sparse_product(WpfT.indptr, WpfT.indices, WpfT.data, Xf, WpX)
            C_patch[:, touched] += WpX @ Pt
            if progress is not None:
                progress(min(s + block, n_cols), n_cols)
        t_far = time.perf_counter()
        blocks = {r: 0.5 * (B + B.T) for r, B in blocks.items()}
        rods_local = sorted(local)
        own_s = {r: rows[0] for r, rows in local_rows.items()}
        own_d = {r: rows[1] for r, rows in local_rows.items()}
        stress_basis, stress_coeff = far_field_basis(stress, rod, own_s)
        disp_basis, disp_coeff = far_field_basis(disp, rod, own_d)
        del stress, disp
        t_gravity = time.perf_counter()
        xg = body.x_gravity
        return cls(X, area, rod, 0.5 * (C_patch + C_patch.T), stress_basis, stress_coeff, disp_basis, disp_coeff, (body.S @ xg), xg[vdofs], (Wp.T @ xg).reshape(M, 3),
                   body.weight_n(), body.lam, body.mu, points.X.copy(), points.area_m2.copy(), np.asarray(patches).copy(), point_rod.copy(),
                   (Wd.T @ xg).reshape(-1, 3), np.concatenate([blocks[r].ravel() for r in sorted(blocks)]),
                   _concat([local_rows[r][0] for r in rods_local], int), _concat([local_rows[r][1] for r in rods_local], int),
                   _concat([local[r][0].ravel() for r in rods_local], np.float32), _concat([local[r][1].ravel() for r in rods_local], np.float32),
                   np.array([(r, len(local_rows[r][0]), len(local_rows[r][1])) for r in rods_local], dtype=int).reshape(-1, 3), body.element,
                   {"precompute": time.perf_counter() - t0, "responses": t_far - t_loop, "far_field": t_gravity - t_far})


# The patches' responses away from their own rod are of low rank: a rod's tip loads reach its base, and
# from there every other tet and vertex, as the rod's resultant force and moment (Saint-Venant), six
# numbers. Default sensor, 2 mm mesh, P2P1, a rod's 21 patch columns (7 patches): the stress away
# from the rod's own tets has a relative Frobenius tail of 1.1e-2 at rank 5 and 2.6e-4 at rank 6, and
# its largest entry error at rank 6 is 2e-4 of the rod's largest response. The basis keeps the
# rank whose tail is below FAR_FIELD_RTOL; the field recovery reads 6-7 columns per loaded rod instead
# of 21 (each rod's own tets and vertices keep their exact point responses).
FAR_FIELD_RTOL = 1e-3
# ... and each basis vector decays away from its rod (a resultant spreading through the base): in the
# field recovery its entries below this fraction of its largest are dropped (ReducedModel.far_field_rows).
# Default demo, 2 mm mesh: 7 % of the stress basis' entries are kept, and the far-field product costs
# 2.7 ms per episode instead of 8.9 (dense float32 BLAS; both on 2 cores), its largest error 2.5e-3 of
# the far field's largest entry, the order of the rank truncation's. Against the dense basis, over the
# episode: stress within 1.0e-3 of the largest load stress, per-rod peak ML von Mises within 6.3e-4 of
# the largest, per-rod sums of |d von Mises| over the ML tets within 6.7e-4 of the largest (3e-4 keeps
# 12 % and is within 2.9e-4 / 3.9e-4 / 2.8e-4 at 5.1 ms; 3e-3, 4 %: 2.8e-3 / 2.0e-3 / 1.3e-3).
FAR_FIELD_DROP = 1e-3


def far_field_basis(response: np.ndarray, patch_rod: np.ndarray, own_rows: dict, rtol: float = FAR_FIELD_RTOL) -> tuple[np.ndarray, np.ndarray]:
    """A low-rank form of the patch responses away from each patch's own rod.

    response (n, 3 M) float32: each patch's response to a unit force along each axis (rows: tets'
    stress components or vertices' displacements); patch_rod (M,) each patch's rod; own_rows
    {rod: row indices} the rows of each rod's own tets or vertices.

    Per rod a, with A_a its patches' columns and its own rows set to zero: the truncated SVD
    A_a = U S V^T to the smallest rank whose relative Frobenius tail is at most ``rtol``. Returns
    (basis (K, n) float32 = the (U S)^T of the rods one after the other, coeff (K, 3 M) = each basis
    vector's V^T on its own rod's columns, zero elsewhere): basis^T @ coeff is the response on every
    row but the loaded rod's own, where it is zero. The basis is returned transposed, (K, n)
    C-contiguous: a rod's columns are then one contiguous block of memory."""
    rods = np.unique(patch_rod)
    bases, coeffs = [], []
    n_cols = response.shape[1]
    for a in rods:
        cols = (3 * np.flatnonzero(patch_rod == a)[:, None] + np.arange(3)).ravel()
        own = own_rows.get(int(a), np.zeros(0, dtype=int))
        A = response[:, cols].astype(float)
        A[own] = 0.0
        # one BLAS thread: a tall, thin SVD (98448 x 21 on the screw sensor) is a few memory-bound
        # passes, and on the 2 shared cores its two threads waited for each other (the screw sensor's
        # stress basis, 25 SVDs: 9.0-11.6 s, 1.5 s on one thread); its bits no longer depend on the thread count
        with one_blas_thread():
            U, S, Vt = np.linalg.svd(A, full_matrices=False)
        tail = np.sqrt(np.cumsum((S**2)[::-1])[::-1])  # tail[k]: the Frobenius norm left out at rank k
        total = tail[0] if len(tail) else 0.0
        k = int(np.argmax(np.r_[tail, 0.0] <= rtol * total)) if total > 0 else 0
        B = U[:, :k] * S[:k]
        B[own] = 0.0  # zero there, not LAPACK's round-off
        bases.append(B.astype(np.float32))
        c = np.zeros((k, n_cols))
        c[:, cols] = Vt[:k]
        coeffs.append(c)
    return (np.ascontiguousarray(np.concatenate(bases, axis=1).T) if bases else np.zeros((0, response.shape[0]), np.float32),
            np.concatenate(coeffs, axis=0) if coeffs else np.zeros((0, n_cols)))


def reduced_fields_of(reduced: "ReducedModel", keep: np.ndarray, rod: np.ndarray, loads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The reduced tier's fields of the loads (U, m, 3) N on the path's points ``keep`` (of rods
    ``rod`` (m,)): stress (6 T, U) and displacement (3 P, U) rows, float32, gravity included.

    By superposition of the sensor's unit responses: away from each loaded rod's own tets and
    vertices its points' loads, summed per patch, act through its few far-field columns
    (``stress_basis``, ``stress_coeff``, read without their entries below :data:`FAR_FIELD_DROP`:
    :meth:`ReducedModel.far_field_rows`); on its own tets and vertices through its points' exact
    responses (:meth:`ReducedModel.local_responses`). Rods the loads never touch cost nothing."""
    U, m = loads.shape[0], loads.shape[1]
    # (3 M, U) the points' loads summed per patch, zero away from the loaded rods
    patch_cols = (3 * reduced.point_patch[keep][:, None] + np.arange(3)).ravel()
    to_patches = sp.csr_matrix((np.ones(3 * m), (patch_cols, np.arange(3 * m))), shape=(reduced.stress_coeff.shape[1], 3 * m))
    Fp = to_patches @ loads.reshape(U, 3 * m).T
    # float32 sums (the fields are stored as float32; the responses are float32), one row per
    # stress or displacement component (6 T, U), each row's U values contiguous
    stress = np.repeat(reduced.stress_gravity.astype(np.float32)[:, None], U, axis=1)
    disp = np.repeat(reduced.displacement_gravity.astype(np.float32)[:, None], U, axis=1)
    for which, coeff, out in (("stress", reduced.stress_coeff, stress), ("displacement", reduced.displacement_coeff, disp)):
        c = (coeff @ Fp).astype(np.float32)  # (K, U), zero on the unloaded rods' rows
        A = reduced.far_field_rows(which)
        field_kernels.add_sparse_product(A.indptr, A.indices, A.data, c, np.any(c != 0, axis=1), out)
    # each rod's own tets and vertices: its points' responses to their forces, exact
    for r, (rows_s, own_s, rows_d, own_d) in reduced.local_responses().items():
        on_rod = np.flatnonzero(rod == r)
        if not len(on_rod) or not np.any(loads[:, on_rod]):
            continue  # (a rod near the path that the indenter never loads: the demo's 9 of 20)
        all_on_rod = np.flatnonzero(reduced.point_rod == r)
        local = np.searchsorted(all_on_rod, keep[on_rod])
        # the rod's loads on all its points, zero off the path (no copy of the corrections' columns)
        f_r = np.zeros((len(all_on_rod), 3, U), dtype=np.float32)
        f_r[local] = np.moveaxis(loads[:, on_rod], 0, -1)
        f_r = f_r.reshape(-1, U)
        field_kernels.add_rows(stress, rows_s, own_s @ f_r)
        field_kernels.add_rows(disp, rows_d, own_d @ f_r)
    return stress, disp


# ------------------------------------------------------------------------------------ an episode
def _by_frame(a: np.ndarray, frame_of: np.ndarray) -> np.ndarray:
    """a[frame_of] (S, ...) of an episode's fields a (U, ...) by distinct load; read row by row
    (fem.field_kernels.gather_columns) where a is the transposed view of (n, U) rows that the
    reduced tier's recovery makes, numpy's fancy index otherwise. The same values either way."""
    rows = a.reshape(len(a), -1).T
    if not (rows.flags.c_contiguous and np.may_share_memory(rows, a)):
        return a[frame_of]
    out = np.empty((len(frame_of),) + a.shape[1:], dtype=a.dtype)
    field_kernels.gather_columns(rows, np.ascontiguousarray(frame_of, dtype=np.int64), out.reshape(len(frame_of), -1))
    return out


def _pose(state: trajectory.IndenterState) -> Pose:
    return Pose(tuple(state.position_m), state.yaw_rad)


def _concat(arrays: list, dtype) -> np.ndarray:
    return np.concatenate(arrays).astype(dtype) if arrays else np.zeros(0, dtype=dtype)


def _rod_operator(reduced: ReducedModel, keep: np.ndarray) -> tuple[list, np.ndarray]:
    """The reduced tier's elastic operator on the contact points ``keep`` (sorted by rod): each rod's
    block of the point compliance (3 m_a, 3 m_a) and the rods' mutual compliance H (3 R, 3 R)
    through their resultants, from the patch compliance (:func:`fem.contact_admm.rod_resultant_coupling`)."""
    all_blocks = reduced.rod_blocks()
    rods = np.unique(reduced.point_rod[keep])
    blocks = []
    for r in rods:
        on_rod = np.flatnonzero(reduced.point_rod == r)
        local = np.searchsorted(on_rod, keep[reduced.point_rod[keep] == r])
        idx = (3 * local[:, None] + np.arange(3)).ravel()
        blocks.append(all_blocks[int(r)][np.ix_(idx, idx)])
    patch_rods = np.unique(reduced.rod)
    H_all = contact_admm.rod_resultant_coupling(reduced.C, reduced.rod, reduced.area_m2)
    sel = (3 * np.searchsorted(patch_rods, rods)[:, None] + np.arange(3)).ravel()
    return blocks, H_all[np.ix_(sel, sel)]


def build_reduced(scene, mesh, body: LinearBody | None = None, settings: SolveSettings | None = None, progress=None) -> ReducedModel:
    """The ``reduced`` tier's precompute for a scene's sensor (independent of its load): contact
    points of the tips and side bands, grouped into patches, and their responses."""
    settings = settings or SolveSettings.from_scene(scene)
    t0 = time.perf_counter()
    if body is None:
        lame, rho, _ = layer_materials(scene)
        body = LinearBody(mesh, lame, rho, settings.element, settings.gravity, settings.backend)
    points = condensed.contact_points(mesh, body.skmesh, body.d, condensed.contact_faces(mesh, settings.contact_band_m))
    patches = condensed.group_patches(points, settings.patches_per_tip, settings.patches_per_side, tip_height_m(mesh), seed=scene.seed)
    body_s = time.perf_counter() - t0
    model = ReducedModel.build(body, points, patches, progress=progress)
    model.seconds["body"] = body_s
    return model


def run_episode(scene, mesh, body: LinearBody | None = None, settings: SolveSettings | None = None, reduced: ReducedModel | None = None,
                progress: bool = False, log=None) -> Episode:
    """Solve the scene's load on ``mesh`` with the ``linear`` or ``reduced`` tier; returns the :class:`Episode`.

    ``body`` (and for ``reduced`` the precompute) may be passed in to reuse a factorisation.
    """

    settings = settings or SolveSettings.from_scene(scene)
    if scene.load is None:
        raise ValueError("load: the scene has no load; add a [load] section with an indenter and segments")
    if settings.tier == "nonlinear":
        from fem.finite_strain import run_nonlinear_episode

        return run_nonlinear_episode(scene, mesh, settings, progress=progress, log=log)
    if settings.tier not in ("linear", "reduced"):
        raise ValueError(f'fidelity.solve.tier = "{settings.tier}": choose "reduced", "linear" or "nonlinear"')
    if settings.rod_kinematics in ("second_order", "cosserat") and settings.contact_solver != "admm":
        raise ValueError(f'fidelity.solve.rod_kinematics = "{settings.rod_kinematics}" needs fidelity.solve.contact_solver = "admm"')
    rods_move = settings.dynamics != "quasi_static" and settings.rod_kinematics == "cosserat"
    if settings.dynamics != "quasi_static" and log is not None:
        log(quasi_static_warning(settings))
    timings: dict = {}
    lame, rho, e_contact = layer_materials(scene)
    if settings.tier == "reduced" and reduced is None:
        reduced = build_reduced(scene, mesh, body, settings)
    if settings.tier == "linear" and body is None:
        body = LinearBody(mesh, lame, rho, settings.element, settings.gravity, settings.backend)
    if body is not None:
        timings.update({f"body_{k}": v for k, v in body.seconds.items()})
    load = scene.load
    setup = ContactSetup.from_scene(scene, mesh, settings, e_contact)
    shape, tip_z, grid, solve_kw = setup.shape, setup.tip_z_m, setup.grid, setup.solve_kw()
    t0 = time.perf_counter()
    if settings.rod_kinematics not in rod_kinematics.ROD_KINEMATICS:
        raise ValueError(f'fidelity.solve.rod_kinematics = "{settings.rod_kinematics}": choose one of {", ".join(rod_kinematics.ROD_KINEMATICS)}')
    second_order = settings.rod_kinematics in ("second_order", "cosserat")
    exact = settings.rod_kinematics == "cosserat"
    kinematics = None
    if settings.tier == "reduced":
        # contact at every point near the path, rod by rod: each rod's points with their own compliance,
        # the rods coupled through their resultants (fem.contact_admm.RodBlockDelassus)
        keep = path_points(reduced.point_X, shape, load, grid, tip_z, settings.path_margin_m)
        # rod by rod, ascending within a rod: the points' order in the sensor's contact operator
        order = reduced.rod_order()
        position = np.empty(len(order), dtype=np.int64)
        position[order] = np.arange(len(order))
        keep_at = np.sort(position[keep])
        keep = order[keep_at]
        X, area, rod = reduced.point_X[keep], reduced.point_area_m2[keep], reduced.point_rod[keep]
        u0 = reduced.point_u_gravity[keep]
        C = None  # the ADMM solver takes the sensor's operator (below); the Newton solver the dense form
        timings.update({f"precompute_{k}": v for k, v in reduced.seconds.items()})
        t_f = time.perf_counter()
        reduced.far_field_rows("stress"), reduced.far_field_rows("displacement")  # made once per model
        timings["precompute_far_field_rows"] = time.perf_counter() - t_f
        # the build's parts ("responses", "far_field") are inside its "precompute"
        timings["precompute"] = sum(v for k, v in reduced.seconds.items() if k in ("precompute", "body")) + timings["precompute_far_field_rows"]
        if second_order:
            t_k = time.perf_counter()
            sections = _rod_sections(scene, mesh, rod, setup.tip_z_m)
            # the sections' response to each point's force as the vertices see it: its patch's far-field
            # response plus, on its own rod, its own exact response (the displacement field's rule below)
            cols = (3 * reduced.point_patch[keep][:, None] + np.arange(3)).ravel()
            O = (rod_exact.root_observation(mesh.points, sections) if exact else sections.O).tocsc()
            A = np.asarray((O @ reduced.displacement_basis.T) @ reduced.displacement_coeff[:, cols], dtype=float)
            for r, (_, _, rows_d, own_d) in reduced.local_responses().items():
                on_rod = np.flatnonzero(rod == r)
                if len(on_rod):
                    local = np.searchsorted(np.flatnonzero(reduced.point_rod == r), keep[on_rod])
                    A[:, (3 * on_rod[:, None] + np.arange(3)).ravel()] += O[:, rows_d] @ own_d[:, (3 * local[:, None] + np.arange(3)).ravel()]
            obs_0 = O @ reduced.displacement_gravity.astype(float)
            make_exact = lambda section: rod_exact.CosseratKinematics(sections, section, A, obs_0, X, rod)  # noqa: E731
            kinematics = make_exact(_rod_section(scene)) if exact else rod_kinematics.RodKinematics(sections, A, obs_0, X, rod)
            timings["precompute_rod_kinematics"] = time.perf_counter() - t_k
            timings["precompute"] += timings["precompute_rod_kinematics"]
    else:
        faces = condensed.contact_faces(mesh, settings.contact_band_m)
        all_points = condensed.contact_points(mesh, body.skmesh, body.d, faces)
        keep = path_points(all_points.X, shape, load, grid, tip_z, settings.path_margin_m)
        points = all_points.subset(keep)
        X, area, rod = points.X, points.area_m2, points.rod
        if second_order:
            sections = _rod_sections(scene, mesh, rod, setup.tip_z_m)
            O_dofs = _on_dofs(rod_exact.root_observation(mesh.points, sections) if exact else sections.O, body)
            C, seen = compliance(body, points.W, observe=O_dofs)
            make_exact = lambda section: rod_exact.CosseratKinematics(sections, section, seen, O_dofs @ body.x_gravity, X, rod)  # noqa: E731
            kinematics = make_exact(_rod_section(scene)) if exact else rod_kinematics.RodKinematics(sections, seen, O_dofs @ body.x_gravity, X, rod)
        else:
            C = compliance(body, points.W)
        u0 = (points.W.T @ body.x_gravity).reshape(-1, 3)
        timings["precompute"] = time.perf_counter() - t0
    m = len(u0)
    if m == 0 and any(seg.kind == "press" and seg.force_n is not None for seg in load.segments):
        raise SolverError(f"no contact point of the sensor lies within {settings.path_margin_m * 1e3:g} mm of the indenter's path: a "
                          "force ramp (load.segments[*].force_n) cannot be met; move the indenter over the rods (load.start_xy_mm) "
                          "or make it larger")
    k_n, k_t = setup.penalties(area)
    contact_kw = {"max_iterations": CONTACT_MAX_ITERATIONS}
    if settings.tier == "reduced" and settings.contact_solver != "admm":
        C = contact_admm.rod_block_compliance(*_rod_operator(reduced, keep), rod)
    if settings.contact_solver == "admm" and m > 0:  # (no contact point near the path: no operator, below)
        t_d = time.perf_counter()
        if settings.tier == "linear":
            delassus = contact_admm.DenseDelassus(C, k_n)
        else:
            sensor = reduced.contact_operator(setup.penalties(reduced.point_area_m2[order])[0])
            delassus = sensor.restrict_points(keep_at)
        factorisations_before = delassus.all_factorisations
        delassus.solve(np.zeros((len(X), 3)), 0)  # the first factorisation belongs to the precompute
        timings["precompute_delassus"] = time.perf_counter() - t_d
        timings["precompute"] += timings["precompute_delassus"]
        if exact and kinematics is not None:
            # the rods' section identified from the mesh's own rods (their lateral tip compliance, fem.rod_error): on the
            # tiny scene's 2.5 mm mesh the layered section was 4-7 % softer sideways than the mesh's rods, and the held tier
            # 3.6 / 5.7 / 5.2 % off the nonlinear tier (rod-base von Mises / force / tip), with the identified one 2.2 / 3.3 / 3.0 %
            kinematics.local_compliance = delassus.elastic_block  # the tier's error estimate too (fem.rod_error)
            scales = rod_error.identified_section_scales(kinematics)
            if scales != (1.0, 1.0):
                kinematics = make_exact(rod_exact.stiffened(kinematics.section, *scales))
                kinematics.local_compliance = delassus.elastic_block
            timings["rod_section_scale"], timings["rod_section_shear_scale"] = scales
        contact_kw = {"delassus": delassus, "warm": contact_admm.WarmStart(kinematics=kinematics), "max_iterations": settings.contact_max_iterations}
    # force control finds the height by a secant on the total force to 1e-6 (condensed.solve_points_at_force):
    # the contact solves under it must be ten times tighter than that
    force_kw = contact_kw if settings.contact_solver != "admm" else {**contact_kw, "admm_rtol": 1e-7}
    # force control's trial heights are not cut where held rods' rounds do not settle (condensed.solve_path): every trial
    # would be, and rods pressed past their Euler load cycle at any step length (the sweep's 9 x 3 mm press at 3 x: 780 s,
    # unsettled in four steps, where the rounds at half their relaxation settle it in 173 s)
    force_kw = {**force_kw, "unsettled_cuts": 0}
    worst = {"residual_n": 0.0, "ratio": 0.0, "step": -1, "unlinearised": []}
    worst_bend = [0.0, -1]  # the largest bending_ratio and its step
    n_rods = int(mesh.tet_rod.max()) + 1
    rod_height = scene.sensor.rod.height_mm * 1e-3
    # second order refuses a rod past buckling_limit x its free Euler load: its P-delta runs away there. The
    # Cosserat rods are held in their solve by the contact's stiffness (fem.rod_exact, the Robin coupling) and
    # follow a rod past it; under dead loads between rounds (CosseratKinematics.holds False) a rod past its free
    # Euler load buckled sideways whatever held its tip (the default demo's flat punch, rods at 1.18 x: the
    # rounds diverged and the normal force fell from 18.4 N to 2.8 N), and they are refused as second order's
    held = exact and kinematics is not None and settings.rod_coupling == "held"
    euler_n = _euler_load_n(scene) if second_order and not held else None
    # a held rods' step that fails with a rod pressed past its free Euler load is a collapse the rounds do not
    # follow: a RodCollapseError with the load the rods collapse at (mlsim sweep records it), not a solver's failure
    held_rods, free_euler_n = (kinematics, _euler_load_n(scene)) if held else (None, None)
    rod_model = "Cosserat rods under dead contact loads" if exact else "second-order rod kinematics (P-delta)"
    if exact and kinematics is not None:
        kinematics.holds = held
        if rods_move:
            kinematics.inertia = rod_inertia(scene)
        if not held:
            # every round of the contact loop, before the rods are solved: the rounds' fixed point diverges past the
            # limit (to an answer with little force, which the check after the step would pass)
            kinematics.guard = lambda f: _check_buckling(f, rod, n_rods, euler_n, settings.buckling_limit, "a contact round", settings.tier,
                                                         rod_model)

    steps = grid.step_times_s
    S = len(steps)
    forces = np.zeros((S, m, 3))
    extras = np.zeros((S, m, 3)) if second_order else None  # the P-delta loads on the unknowns (fem.rod_kinematics)
    pose_arr = np.zeros((S, 4))
    target = np.full(S, np.nan)
    iters = np.zeros(S, dtype=np.int64)
    stick = np.zeros(S)
    round_residual = np.zeros(S)  # the rod kinematics' rounds' residual at each step's end (N; contact_admm.AdmmInfo)
    state = trajectory.initial_state(load, tip_z)
    pstate = condensed.PointState(u0.copy(), np.zeros((len(X), 3)))
    u_now = u0.copy()
    pose_old = _pose(state)
    normal_now = 0.0
    u_last, last_move = None, None
    bar = _bar(progress, S, f"solve ({settings.tier})")
    t_loop = time.perf_counter()
    step_ms = np.zeros(S)
    # the contact steps are many small dense products (3 m = 1095 on the demo): BLAS threads cost more
    # in synchronisation than they gain there (default demo, linear tier: 93 ms of contact per frame on
    # 2 threads, 68 ms on 1)
    with one_blas_thread():
        for s, t in enumerate(steps):
            t_step = time.perf_counter()
            state = trajectory.advance(load, state, t, normal_now)
            if m == 0:
                # the indenter passes no contact point within the path margin (a small probe between
                # the rods): it never touches, and the sensor carries its weight alone at every step
                pose_arr[s] = (*_pose(state).position_m, state.yaw_rad)
                stick[s] = np.nan
                bar(s + 1)
                continue
            case = f"step {s} (t = {t * 1e3:.1f} ms)"
            if REUSE_HOLDS and not rods_move and s > 0 and _holds(state, pose_old, target[s - 1]):
                # the indenter is where the last step left it (a hold): a quasi-static step from a
                # converged state to the same pose is that state (no slip increment, the same gaps),
                # so the last solution is reused rather than re-confirmed
                pose = pose_old
                if state.force_target_n is not None:
                    state = trajectory.IndenterState(state.t_s, pose.position_m, state.yaw_rad, state.force_target_n, state.ramp_from_n)
                    target[s] = state.force_target_n
                u, n_it = u_now, 0
                u_last, last_move = u_now, np.zeros(4)
            elif state.force_target_n is None:
                pose = _pose(state)
                move = np.array([*pose.position_m, pose.yaw_rad]) - np.array([*pose_old.position_m, pose_old.yaw_rad])
                guess = None
                if u_last is not None and np.any(move != 0) and np.allclose(move, last_move, rtol=1e-9, atol=1e-15):
                    guess = 2.0 * u_now - u_last  # the same motion as the last step: extrapolate
                u_before = u_now
                with _collapse_refused(held_rods, free_euler_n, case, settings.tier, s, normal_now):
                    u, law, info = condensed.solve_path(C, u0, X, shape, pose, pose_old, pstate, load.friction_coefficient, k_n, k_t, case=case,
                                                         guess=guess, **contact_kw, **solve_kw)
                u_last, last_move = u_before, move
                n_it = info["iterations"]
            else:
                z_free = tip_z + 1e-4 + float(np.abs(u0[:, 2]).max())
                count = [0]
                warm = force_kw.get("warm")
                start = None if warm is None else warm.starting_point()

                def at_z(z):
                    # every trial height starts from this step's warm start, not from the last trial's
                    # answer: with friction the contact problem can have several solutions (a sphere
                    # wedged between the tiny scene's four tips), and a trial warm-started from the one
                    # before lands on that trial's branch, so the force was not a function of the height
                    # (0, 0.36 and 0.76 N at z = 9.7275 mm by the order of the trials) and the search
                    # that assumes a monotone force marched past the sensor (z = -1.6e18 mm)
                    if start is not None:
                        warm.restart_from(start)
                    p = Pose((state.position_m[0], state.position_m[1], z), state.yaw_rad)
                    u, law, info = condensed.solve_path(C, u0, X, shape, p, pose_old, pstate, load.friction_coefficient, k_n, k_t, case=case,
                                                     **force_kw, **solve_kw)
                    count[0] += info["iterations"]
                    return condensed.normal_force(law), (u, law, p, info)

                with _collapse_refused(held_rods, free_euler_n, case, settings.tier, s, normal_now):
                    z, (u, law, pose, info), _ = condensed.solve_points_at_force(state.force_target_n, state.position_m[2], at_z, z_free, case=case,
                                                                                 z_min=tip_z - scene.sensor.rod.height_mm * 1e-3)
                state = trajectory.IndenterState(state.t_s, (state.position_m[0], state.position_m[1], z), state.yaw_rad, state.force_target_n, state.ramp_from_n)
                target[s] = state.force_target_n
                n_it = count[0]
                u_last = None
            if "admm" in info:
                a = info["admm"]
                ratio = a.residual_n / max(a.tolerance_n, 1e-300)
                if ratio > worst["ratio"]:
                    worst.update(residual_n=a.residual_n, ratio=ratio, step=s)
                if not a.linearised:
                    worst["unlinearised"].append(s)
                round_residual[s] = a.round_residual_n
            _check_small_strain(u - u0, rod, rod_height, settings.small_strain_limit, case, settings.tier)
            if euler_n is not None:
                _check_buckling(info["f"], rod, n_rods, euler_n, settings.buckling_limit, case, settings.tier, rod_model)
            bend = bending_ratio(u - u0, rod, rod_height)
            if bend > worst_bend[0]:
                worst_bend[:] = [bend, s]
            pstate = condensed.PointState(u.copy(), law.f_t.copy())
            u_now = u
            pose_old = pose
            forces[s] = info["f"]
            if kinematics is not None and rods_move:
                kinematics.end_step(s, info["f"])  # the rods' nodes and velocities: the next step's start
            if extras is not None and law.f_extra is not None:
                extras[s] = law.f_extra
            normal_now = condensed.normal_force(law)
            pose_arr[s] = (*pose.position_m, pose.yaw_rad)
            iters[s] = n_it
            touching = law.touching
            stick[s] = float(law.stick.sum() / touching.sum()) if touching.any() else np.nan
            step_ms[s] = 1e3 * (time.perf_counter() - t_step)
            bar(s + 1)
    timings["contact_steps"] = time.perf_counter() - t_loop
    timings["rod_bending_ratio"] = worst_bend[0]
    timings["contact_step_ms"] = step_ms.tolist()  # each step's contact solve (benchmarks take medians by kind of frame)
    if "delassus" in contact_kw:
        timings["contact_worst_residual_n"] = worst["residual_n"]
        timings["contact_factorisations"] = contact_kw["delassus"].all_factorisations - factorisations_before
        timings["contact_unlinearised_steps"] = len(worst["unlinearised"])
        if worst["ratio"] > 1.0 and log is not None:
            log(f"warning: the contact solve of step {worst['step']} stopped at its bound of {settings.contact_max_iterations} ADMM "
                f"iterations with a force residual of {worst['residual_n']:.3g} N ({worst['ratio']:.3g} x its tolerance): "
                "raise fidelity.solve.contact_max_iterations for a tighter answer")
        if worst["unlinearised"] and log is not None:
            bound = (getattr(kinematics, "max_rounds", contact_admm.SECOND_ORDER_LINEARISATIONS) if second_order
                     else contact_admm.MAX_LINEARISATIONS)
            relaxed = getattr(kinematics, "round_relaxation", None) if second_order else None
            if relaxed is not None:
                bound = (f"{bound * (1 + contact_admm.ROUND_RELAXATION_HALVINGS)} linearisations (relaxed by {relaxed:g}, then "
                         f"{contact_admm.ROUND_RELAXATION_HALVINGS} x halved)")
            else:
                bound = f"{bound} linearisations"
            why = (f"the rods' rounds (their kinematics' fixed point) or the indenter's gap did not settle in {bound}"
                   if second_order else f"the indenter's gap curves more than {bound} follow")
            log(f"warning: in steps {worst['unlinearised']} {why} (the largest gap error is reported per step); "
                "use more fidelity.solve.substeps")

    t0 = time.perf_counter()
    T = mesh.n_tets
    loads = forces if extras is None else forces + extras  # the body carries the P-delta load too
    # the fields are linear in the loads: recover them once per distinct load (holds and free steps repeat theirs);
    # under the rods' inertia every step (a rod swinging free after its release carries no force)
    first, frame_of = _distinct_rows(loads.reshape(S, -1)) if not (rods_move and m > 0) else (np.arange(S), np.arange(S))
    U = len(first)
    if settings.tier == "reduced":
        # (its sums run on numba's threads; BLAS's, spinning between its small products, fought them
        # for the two cores: default demo, 15 to 200 ms per episode, where one BLAS thread gives 10)
        with one_blas_thread():
            stress, disp = reduced_fields_of(reduced, keep, rod, loads[first])
        stress, disp = stress.T.reshape(U, 6, T), disp.T.reshape(U, -1, 3)
        total = forces.sum(axis=1)
        reaction = -(total + reduced.weight_n)
    else:
        F = body.f_gravity[:, None] + points.W @ loads[first].reshape(U, 3 * m).T  # (n, U)
        Xs = body.solve(F)
        stress = body.stress(Xs)
        disp = Xs[body.vertex_dofs.ravel()].T.reshape(U, -1, 3)
        # the clamp balances the contact forces and the weight: the P-delta load is a moment's stand-in
        reaction = body.reaction(Xs, F)[frame_of] + (0.0 if extras is None else extras.sum(axis=1))
        total = forces.sum(axis=1)
    if kinematics is not None:
        by_step = [{"step": s} if rods_move else {} for s in first]  # under inertia the rods' answers are by step
        disp = disp + np.stack([kinematics.vertex_correction(disp[i], mesh.points, forces=forces[first[i]], **by_step[i]) for i in range(U)])
    if exact and m > 0:
        # the bent rods' section resultants in their own frames (fem.rod_exact: Saint-Venant's recovery through
        # each loaded rod's responses to unit tip loads, made by this tier's own field recovery)
        unit, unit_rods = kinematics.unit_tip_loads(area)
        if len(unit_rods):
            J = len(unit_rods)
            flat = unit.reshape(J * 6, m, 3)
            if settings.tier == "reduced":
                with one_blas_thread():
                    s_unit, _ = reduced_fields_of(reduced, keep, rod, np.concatenate([flat, np.zeros((1, m, 3))]))
                s_unit = s_unit.T.reshape(J * 6 + 1, 6, T)
                s_unit = s_unit[:-1] - s_unit[-1:]  # less the weight's field
            else:
                s_unit = body.stress(body.solve(points.W @ flat.reshape(J * 6, 3 * m).T))
            s_unit = s_unit.reshape(J, 6, 6, T)
            tet_z = mesh.points[mesh.tets][:, :, 2].mean(axis=1)
            stress = stress + np.stack([kinematics.stress_correction(forces[first[i]], s_unit, unit_rods, tet_z, mesh.tet_rod, **by_step[i])
                                        for i in range(U)])
    timings["fields"] = time.perf_counter() - t0
    # each step's share of the field recovery: the distinct loads share it, a repeat is a copy
    timings["fields_step_ms"] = np.where(np.isin(np.arange(S), first), 1e3 * timings["fields"] / U, 0.0).tolist()
    stress = stress.astype(np.float32, copy=False)  # (the reduced tier's: a view of its float32 rows, copied below by frame)
    lam_t, mu_t = (body.lam, body.mu) if body is not None else (reduced.lam, reduced.mu)
    vm, sed = fields.von_mises_and_energy(stress, lam_t, mu_t)
    vm, sed = vm[frame_of], sed[frame_of]
    stress, disp = _by_frame(stress, frame_of), _by_frame(disp, frame_of)
    on_rod = rod >= 0
    rod_force = np.zeros((S, n_rods, 3))
    np.add.at(rod_force, (slice(None), rod[on_rod]), forces[:, on_rod])
    if exact and kinematics is not None:
        # the Cosserat rods' own: their ends' linear response turned with their tips, the section's mismatch, the rounds'
        # residual; and the releases of bent rods, where it does not hold (fem.rod_error)
        weights = np.bincount(frame_of[grid.frame_step], minlength=U)
        estimate = rod_error.force_error_estimate(kinematics, forces[first], weights, first, round_residual[first], load.friction_coefficient)
        timings["geometric_error_estimate"] = estimate.force
        timings["geometric_error_releases"] = [list(r) for r in estimate.releases]
        timings["geometric_error_bent"] = [list(r) for r in estimate.bent]
        if log is not None and np.isfinite(estimate.force):
            where = sorted({s for s, _ in estimate.releases})
            bent = sorted({s for s, _ in estimate.bent})
            log(f"the {settings.tier} tier's Cosserat rods: per-rod contact forces estimated {estimate.force:.1%} off the nonlinear tier's "
                "(fem.rod_error.force_error_estimate)"
                + (f"; it does not hold here: bent rods are let go in steps {where} (rods {sorted({r for _, r in estimate.releases})}) and "
                   "snap back at a step that depends on which frictional equilibrium held them (the default demo's lift-off 10-18 %, "
                   'a swipe over 12 mm rods 14-22 % off in those frames); compare with fidelity.solve.tier = "nonlinear" there'
                   if where else "")
                + (f"; it does not hold {'either ' if where else ''}where rods {sorted({r for _, r in estimate.bent})} are dragged over, "
                   f"sliding past a tenth of their length under more than half their free Euler load (from steps {bent}): where "
                   "their tips land follows the path (swipes over 12 x 5 and 6 x 3 mm rods: 23-28 % off in force, 25-51 % in "
                   'light; fem.rod_error.BENT_AXIAL); compare with fidelity.solve.tier = "nonlinear"' if bent else ""))
    elif second_order:
        # the estimate is of first-order kinematics; second order measured 7-11 % on the tiny slide (fem.rod_kinematics)
        timings["geometric_error_estimate"] = float("nan")
    else:
        gravity = (reduced.displacement_gravity.reshape(-1, 3) if settings.tier == "reduced"
                   else body.x_gravity[body.vertex_dofs.ravel()].reshape(-1, 3))
        weights = np.bincount(frame_of[grid.frame_step], minlength=U)  # frames per distinct load
        timings["geometric_error_estimate"] = geometric_error_estimate(scene, mesh, disp[first] - gravity[None], rod_force[first], weights,
                                                                   setup.tip_z_m)
        if timings["geometric_error_estimate"] > GEOMETRIC_WARNING and log is not None:
            log(f"warning: the rods bend (contact points moved sideways up to {worst_bend[0]:.1%} of the rod height, step {worst_bend[1]}) and "
                f"the {settings.tier} tier's small-strain kinematics keep their tips up: its per-rod contact forces are estimated "
                f"{timings['geometric_error_estimate']:.0%} off the nonlinear tier's (fem.rod_kinematics.first_order_force_error, from this "
                "episode's own field; it came within 1.1-1.2 x of the measured error on a flat punch and a rolled cylinder, and "
                'overstates past the linear regime); use fidelity.solve.tier = "nonlinear" for this load, or a smaller one')
    timings["per_frame_ms"] = 1e3 * (timings["contact_steps"] + timings["fields"]) / grid.n_frames
    episode = Episode(settings.tier, settings.element, steps, grid.frame_step, pose_arr, target, stress, vm, sed, disp.astype(np.float32, copy=False),
                      rod_force, total, -total[:, 2], reaction, iters, stick, mesh.points, mesh.tets, mesh.tet_rod, mesh.layer_fraction,
                      timings)
    _check_finite(episode)
    return episode


# The linear tiers' error against the nonlinear tier grows with how far the rods bend (issue 15's
# diagnosis): a first-order body keeps the tips' edges up where the bent rods drop them, so the
# indenter overlaps them too much. Each episode estimates the resulting per-rod force error from its
# own field (geometric_error_estimate; until 2026-11 it was 4 x the tips' sideways travel over the rod
# height, measured on a sphere dragging rods, which overstated a flat punch's and a rolled cylinder's
# error 5-6 x) and warns above this:
GEOMETRIC_WARNING = 0.10  # warn when the estimated per-rod contact force error exceeds this
# hold steps (the indenter where the last step left it) reuse the last step's answer, which is their
# fixed point (tests/test_contact_admm.py solves them anyway and compares)
REUSE_HOLDS = True


def quasi_static_warning(settings: SolveSettings) -> str:
    """The run log's line for a scene that asks the linear tiers for dynamics: without Cosserat rods they have
    no inertia, and solve each step as an equilibrium (the solve's key leaves the field out for them,
    fem.stages); with them the rods move (:func:`rod_inertia`) and the base stays quasi-static."""
    if settings.rod_kinematics == "cosserat":
        return (f'fidelity.solve.dynamics = "{settings.dynamics}": the {settings.tier} tier\'s Cosserat rods have their inertia '
                "(fem.cosserat_dynamics: backward Euler, lumped masses, the damping of fidelity.solve.loss_factor at their first "
                "mode); the base is quasi-static")
    return (f'warning: fidelity.solve.dynamics = "{settings.dynamics}" is the nonlinear tier\'s: the {settings.tier} tier has no inertia '
            "and solves each step as an equilibrium (quasi-static); a rod that buckles or snaps back does so there within a step "
            '(the swipe over 12 mm rods: 24-62 % off the dynamic reference, docs/stages/solve.md); use fidelity.solve.tier = "nonlinear" '
            "for its dynamics")


def rod_inertia(scene) -> "rod_exact.cd.RodInertia":
    """The Cosserat rods' backward Euler inertia of the scene (:class:`fem.cosserat_dynamics.RodInertia`): the
    layers' mass per length, the solve's step 1 / (fps x substeps), and mass-proportional damping a_M = eta
    omega_1 (``fidelity.solve.loss_factor``), the nonlinear tier's damping ratio eta / 2 at the rods' first
    bending mode (:func:`fem.finite_strain.rod_first_mode_rad_s`). A step too coarse for that mode is refused
    as the nonlinear tier's (:func:`fem.finite_strain.dynamics_step_problems`, also the scene's check)."""
    from fem.finite_strain import dynamics_step_problems, rod_first_mode_rad_s, rod_mass_per_length_kg_m
    from mlsim.errors import Problem, SceneError

    problems = dynamics_step_problems(scene)
    if problems:
        raise SceneError([Problem(*p) for p in problems])
    f = scene.fidelity.solve
    return rod_exact.cd.RodInertia(rod_mass_per_length_kg_m(scene), 1.0 / (scene.camera.fps * f.substeps),
                                   f.loss_factor * rod_first_mode_rad_s(scene))


def _holds(state: trajectory.IndenterState, pose_old: Pose, last_target_n: float) -> bool:
    """Whether the indenter is where the last step left it: the same pose, or under force control the
    same target at the same x, y and yaw."""
    if state.force_target_n is None:
        return np.isnan(last_target_n) and _pose(state) == pose_old
    return (state.force_target_n == last_target_n and tuple(state.position_m[:2]) == tuple(pose_old.position_m[:2])
            and state.yaw_rad == pose_old.yaw_rad)


def _distinct_rows(A: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(first, of): the rows of A (S, n) that differ from their predecessor, and each row's index into them."""
    changed = np.r_[True, np.any(A[1:] != A[:-1], axis=1)] if len(A) else np.zeros(0, dtype=bool)
    return np.flatnonzero(changed), np.cumsum(changed) - 1


def bending_ratio(du: np.ndarray, rod: np.ndarray, rod_height_m: float) -> float:
    """The largest sideways displacement of a rod's contact points (or patches) du (m, 3) m, over the
    rod height: the rods' bending, which the small-strain kinematics of the linear tiers miss."""
    on = rod >= 0
    return float(np.linalg.norm(du[on, :2], axis=1).max() / rod_height_m) if on.any() else 0.0


def geometric_error_estimate(scene, mesh, du: np.ndarray, rod_force_n: np.ndarray, weights: np.ndarray, tip_z_m: float) -> float:
    """Estimated relative error of the linear tiers' per-rod contact forces against the nonlinear
    tier's, from an episode's displacement du (U, P, 3) m from the state without contact and its
    per-rod contact forces (U, n_rods, 3) N, each distinct load weighted by its frames
    (:func:`fem.rod_kinematics.first_order_force_error`: the tips' second-order drop that the
    first-order body misses, through each rod's secant stiffness). NaN where the mesh's rods are
    too coarse to be cut into sections."""
    sections = _all_rod_sections(scene, mesh, tip_z_m)
    if sections is None:
        return float("nan")
    return rod_kinematics.first_order_force_error(sections, mesh.points, du, rod_force_n, 0.5e-3 * scene.sensor.rod.diameter_mm, weights)


_SECTIONS: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()


def _all_rod_sections(scene, mesh, tip_z_m: float) -> "rod_kinematics.RodSections | None":
    """The section observation of all the mesh's rods (kept per mesh: 24 ms on the default sensor),
    with the most slabs up to 8 that its vertex layers allow; None if not even 2 do."""
    base_z = scene.sensor.base.thickness_mm * 1e-3
    kept = _SECTIONS.setdefault(mesh, {})
    key = (base_z, tip_z_m)
    if key not in kept:
        rods = np.arange(int(mesh.tet_rod.max()) + 1)
        kept[key] = None
        for n_slabs in (rod_kinematics.N_SLABS, 4, 2):
            try:
                kept[key] = rod_kinematics.rod_sections(mesh.points, mesh.tets, mesh.tet_rod, rods, base_z, tip_z_m, n_slabs)
                break
            except ValueError:  # a slab with fewer than 3 vertices
                continue
    return kept[key]


def _rod_section(scene) -> "rod_exact.cr.RodSection":
    """The Cosserat section of the scene's rods (fem.rod_exact.layered_section, the layers from the scene)."""
    from fem.geometry import RodArray

    g = RodArray.from_sensor(scene.sensor)
    mats = [scene.material(r) for r in ("absorber", "ml_layer", "core")]
    return rod_exact.layered_section(g.rod_radius_m, g.rod_height_m, [m.young_modulus_pa.value for m in mats],
                                     [m.poisson_ratio.value for m in mats], [g.absorber_m, g.ml_m])


def _euler_load_n(scene) -> float:
    """The sensor's rods' Euler buckling load N (fem.rod_kinematics.euler_load_n, the layers from the scene)."""
    from fem.geometry import RodArray

    g = RodArray.from_sensor(scene.sensor)
    young = [scene.material(r).young_modulus_pa.value for r in ("absorber", "ml_layer", "core")]
    return rod_kinematics.euler_load_n(g.rod_radius_m, g.rod_height_m, young, [g.absorber_m, g.ml_m])


def _check_buckling(f: np.ndarray, rod: np.ndarray, n_rods: int, euler_n: float, limit: float, case: str, tier: str,
                    model: str = "second-order rod kinematics (P-delta)") -> None:
    """Refuse a step where a rod's axial (compressive) contact load, from the point forces f (m, 3) N
    on the body at points of rods ``rod`` (m,) (-1: the base), passes ``limit`` x its Euler load: the
    second-order rod kinematics' P-delta model then runs away (fem.rod_kinematics.euler_load_n). Seen:
    the swipe over 10.5 mm rods, whose rods carried 0.7-2.0 x their Euler load on three meshes and
    whose tips were dragged 3.7-12.7 mm, the light 7.5e15-1.3e16 photons/s summed, peak strain
    15-39 % (9 mm rods: 0.28 x, 0.7 mm, the same light on every mesh)."""
    on = rod >= 0
    axial = -np.bincount(rod[on], weights=f[on, 2], minlength=n_rods)  # compression > 0
    j = int(np.argmax(axial))
    if axial[j] > limit * euler_n:
        raise OutOfRangeError(
            f"{case}: rod {j} carries {axial[j]:.3g} N along its axis, {axial[j] / euler_n:.2f} x its Euler buckling load "
            f"{euler_n:.3g} N (base clamped, tip free: pi^2 EI / 4 L^2 of its layered section), beyond "
            f"fidelity.solve.buckling_limit = {limit}: the {tier} tier's {model} cannot follow a rod "
            'near buckling. Use fidelity.solve.tier = "nonlinear", a shallower press, shorter or thicker rods, or raise '
            "buckling_limit to accept the error")


@contextlib.contextmanager
def _collapse_refused(kinematics, euler_n: float, case: str, tier: str, step: int, force_n: float):
    """Held Cosserat rods' step ``step``: a :class:`SolverError` inside it, where a rod was solved under an axial
    contact load above its free Euler load ``euler_n`` (N), becomes a :class:`RodCollapseError` (beyond the tier;
    ``force_n``: the indenter's normal force at the last step that converged, the load the rods collapse at,
    which ``mlsim sweep`` records). The held rods follow a rod the contact's friction grips past that load (to the
    clamped-guided load, 4 x), but their rounds are a fixed point between the rods' and the contact's solves,
    without the rods' inertia across a snap: a rod that collapses fails there, in its own Newton (the sweep's 5 N
    press on 12 x 3 mm rods, at 5 x: "Newton did not converge ... unbalanced force 64 N") or in force control (the
    force falls as the face goes deeper). Below that load a failure is the solver's, and is raised as it is; without
    held rods (``kinematics`` None) every error is."""
    if kinematics is None:
        yield
        return
    kinematics.axial_peak_n[:] = 0.0
    try:
        yield
    except OutOfRangeError:
        raise
    except SolverError as exc:
        peak = kinematics.axial_peak_n
        j = int(np.argmax(peak))
        if not peak[j] > euler_n:
            raise
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise RodCollapseError(
            f"{case}: the rods collapse: after the last step that converged, at {force_n:.4g} N on the indenter, this step's contact "
            f"rounds loaded rod {j} with up to {peak[j]:.3g} N along its axis, {peak[j] / euler_n:.2f} x its free Euler load "
            f"{euler_n:.3g} N ({peak[j] / (4.0 * euler_n):.2f} x the clamped-guided load), and the step failed ({first}): the {tier} "
            "tier's held Cosserat rods follow a rod gripped past its free Euler load, not its collapse. To follow it use "
            'fidelity.solve.tier = "nonlinear" with fidelity.solve.dynamics = "backward_euler"; else a smaller load, or shorter or '
            "thicker rods", force_n, step) from exc


def _check_small_strain(du: np.ndarray, rod: np.ndarray, rod_height_m: float, limit: float, case: str, tier: str) -> None:
    """Refuse a contact displacement beyond ``limit`` x the rod height: a linear body has no
    rotations, so a rod bent that far neither shortens nor turns its tip away, and an indenter
    pressed below the tips of rods in its path pushes them along instead of passing over them
    (seen: rod tips dragged 27 mm by a 1 mm-deep probe sweep). Its stresses would be garbage."""
    size = np.linalg.norm(du, axis=1)
    i = int(np.argmax(size))
    if size[i] > limit * rod_height_m:
        where = f"rod {int(rod[i])}" if rod[i] >= 0 else "the base"
        raise OutOfRangeError(
            f"{case}: a contact point of {where} moves {size[i] * 1e3:.2f} mm, {size[i] / rod_height_m:.0%} of the "
            f"{rod_height_m * 1e3:.1f} mm rod height, beyond fidelity.solve.small_strain_limit = {limit}: the {tier} tier's "
            "small-strain model is invalid there. An indenter pressed deeper than its edge rounding into rods in its path "
            "pushes them along; use a shallower press (below the indenter's edge_radius_mm), less friction, a smaller "
            "slide, or raise small_strain_limit to accept the error")

