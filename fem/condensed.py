"""Frictional contact of a linear elastic body with a rigid indenter, condensed onto contact points.

For a linear body the displacement is u = u_0 + K^-1 W f, with f the contact forces at a set of
contact points and W their load columns. Only the points' own displacements enter the contact
conditions, so the problem condenses exactly onto them [Johnson1985]_ (sec. 5.9, influence
coefficients) with the compliance

    C = W^T K^-1 W   (3 m, 3 m), symmetric positive semi-definite,

and is solved for u_c = u_c0 + C f(u_c) alone; the whole field follows from one more solve (the
``linear`` tier) or from superposing precomputed responses (the ``reduced`` tier).

Contact points and their load columns (mortar-type): point i is a boundary vertex of the contact
faces with the P1 hat function phi_i on those faces, area a_i = int phi_i dA. Its force F_i acts as
the traction F_i phi_i / a_i, so W[:, 3i + c] = int phi_i N e_c dA / a_i (N: the element's shape
functions, exact for P2 where a nodal point force would be wrong: a uniform pressure loads P2
vertices with zero force); the conjugate displacement W^T u is the phi-weighted mean displacement.
Points may be grouped into patches (the ``reduced`` tier): patch forces spread over their points
in proportion to area.

Contact law at each point (penalty normal force, Coulomb friction by a return map,
[Wriggers2006]_ ch. 5): with the gap g and unit normal n of the indenter's signed distance
function at the deformed point X + u (:mod:`fem.indenters`),

    f_n = k_n <-g>_+,   trial f_T* = P f_T,old - k_t P (du - d_ind),   P = I - n n^T,
    stick when |f_T*| <= mu f_n (f_T = f_T*), else slip f_T = mu f_n f_T* / |f_T*|,

where du is the point's displacement increment and d_ind the motion of the indenter's material
point there (translation and yaw); the force on the body is f = f_n n + f_T. k_n = eps_n a_i,
k_t = eps_t a_i. Semi-smooth Newton on R(u) = u - u_0 - C f(u) with the consistent tangent of f and
backtracking on |R|; the first iteration of a step assumes stick (a fresh trial force dwarfs
mu f_n and a slip linearisation has no tangential stiffness).

References
----------
.. [Johnson1985] K. L. Johnson, "Contact Mechanics", Cambridge University Press (1985).
.. [Wriggers2006] P. Wriggers, "Computational Contact Mechanics", 2nd ed., Springer (2006).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import skfem
from skfem import BilinearForm, ElementTetP1, ElementTetP2, ElementVector, LinearForm

from fem.indenters import IndenterShape, Pose, gap_normal_hessian, rigid_motion
from fem.indenters import gap as indenter_gap
from fem.nonlinear import SolverError

__all__ = ["ContactPoints", "PointState", "contact_faces", "contact_points", "solve_points", "solve_path", "solve_points_at_force", "group_patches"]


@dataclass
class ContactPoints:
    """m contact points: reference positions X (m, 3) m, areas (m,) m^2, rod index (m,) (-1: base),
    mesh vertex (m,), and their load columns W (n_dofs, 3 m) (point-major: column 3 i + c)."""

    X: np.ndarray
    area_m2: np.ndarray
    rod: np.ndarray
    vertex: np.ndarray
    W: sp.csc_matrix

    @property
    def m(self) -> int:
        return len(self.X)

    def subset(self, keep: np.ndarray) -> "ContactPoints":
        keep = np.asarray(keep)
        cols = (3 * keep[:, None] + np.arange(3)).ravel()
        return ContactPoints(self.X[keep], self.area_m2[keep], self.rod[keep], self.vertex[keep], self.W[:, cols])


@dataclass
class PointState:
    """Per point after the last converged step: displacement u (m, 3) and tangential force (m, 3) N."""

    u: np.ndarray
    f_t: np.ndarray

    @classmethod
    def zero(cls, m: int) -> "PointState":
        return cls(np.zeros((m, 3)), np.zeros((m, 3)))


def contact_faces(mesh, band_m: float) -> np.ndarray:
    """Rows of ``mesh.faces`` that may touch an indenter from above: every rod tip face, and the rod
    side faces within ``band_m`` of the tips' height (a sliding indenter's edge meets them)."""
    from fem.geometry import FaceTag

    tip = mesh.face_tag == FaceTag.ROD_TIP
    if not np.any(tip):
        raise ValueError("the mesh has no rod tip faces to touch")
    top = mesh.points[mesh.faces[tip]].max()
    side = (mesh.face_tag == FaceTag.ROD_SIDE) & (mesh.points[mesh.faces, 2].min(axis=1) >= top - band_m - 1e-12)
    return np.flatnonzero(tip | side)


def _hat_component(c: int) -> BilinearForm:
    """phi v_c: a P1 hat traction along axis c against the vector test functions."""

    @BilinearForm
    def form(phi, v, w):
        return phi * v[c]

    return form


@LinearForm
def _hat_area(phi, w):
    return phi


def contact_points(mesh, skmesh, d, faces: np.ndarray) -> ContactPoints:
    """The vertices of ``faces`` (rows of ``mesh.faces``) as contact points with their load columns
    for the discretisation ``d`` (:func:`fem.elasticity.discretise` on ``skmesh``)."""
    from fem.elasticity import facet_indices

    idx = facet_indices(skmesh, mesh.faces[faces])
    e_u = ElementVector(ElementTetP1() if d.element == "P1" else ElementTetP2())
    fb_u = skfem.FacetBasis(skmesh, e_u, facets=idx, intorder=4)
    fb_1 = fb_u.with_element(ElementTetP1())
    verts = np.unique(mesh.faces[faces])
    area_all = skfem.asm(_hat_area, fb_1)
    area = area_all[verts]
    if np.any(area <= 0):
        raise ValueError("a contact vertex has no area: the contact faces are degenerate")
    m = len(verts)
    scale = sp.diags(1.0 / area)
    blocks = [skfem.asm(_hat_component(c), fb_1, fb_u).tocsc()[:, verts] @ scale for c in range(3)]  # (n_u, m) each
    # interleave: column 3 i + c
    W = sp.hstack(blocks, format="csc")[:, (np.arange(3)[None, :] * m + np.arange(m)[:, None]).ravel()]
    if d.n_dofs > d.n_u:
        W = sp.vstack([W, sp.csc_matrix((d.n_dofs - d.n_u, 3 * m))], format="csc")
    # rod of each point: the rod of any face that uses it
    rod = np.full(mesh.n_points, -1)
    rod[mesh.faces[faces].ravel()] = np.repeat(mesh.face_rod[faces], 3)
    return ContactPoints(mesh.points[verts].copy(), area, rod[verts], verts, W.tocsc())


def group_patches(points: ContactPoints, per_rod_tip: int, per_rod_side: int, top_m: float, seed: int = 0) -> np.ndarray:
    """Patch label (m,) of each point: per rod, ``per_rod_tip`` patches of the tip by k-means on
    (x, y) (seeded), and ``per_rod_side`` angular sectors of the side band."""
    from scipy.cluster.vq import kmeans2

    label = np.full(points.m, -1)
    next_label = 0
    for r in np.unique(points.rod):
        on_rod = np.flatnonzero(points.rod == r)
        tip = on_rod[points.X[on_rod, 2] >= top_m - 1e-9]
        side = np.setdiff1d(on_rod, tip)
        if len(tip):
            k = min(per_rod_tip, len(tip))
            centre = points.X[tip, :2].mean(axis=0)
            if k == 1:
                lab = np.zeros(len(tip), dtype=int)
            else:
                _, lab = kmeans2(points.X[tip, :2] - centre, k, seed=np.random.default_rng(seed + int(r) + 1), minit="++")
            _, lab = np.unique(lab, return_inverse=True)
            label[tip] = next_label + lab
            next_label += lab.max() + 1
        if len(side):
            centre = points.X[on_rod, :2].mean(axis=0)
            angle = np.arctan2(points.X[side, 1] - centre[1], points.X[side, 0] - centre[0])
            lab = np.floor((angle + np.pi) / (2 * np.pi) * per_rod_side).astype(int) % per_rod_side
            _, lab = np.unique(lab, return_inverse=True)
            label[side] = next_label + lab
            next_label += lab.max() + 1
    return label


# ------------------------------------------------------------------------------- the point solver
@dataclass
class _Law:
    f: np.ndarray  # (m, 3) force on the body at each point
    D: np.ndarray  # (m, 3, 3) df/du
    fn: np.ndarray  # (m,)
    touching: np.ndarray
    stick: np.ndarray
    f_t: np.ndarray


SMOOTH_P = 8  # sharpness of the regularised return map (see _contact_law)


def _contact_law(X, u, shape, pose, drag, state, friction, k_n, k_t, stick_predictor=False, smooth_m=1e-7) -> _Law:
    """Forces on the body (m, 3) and their derivative D = df/du (m, 3, 3) at displacements u.

    The Coulomb return map is regularised so that Newton's method sees a smooth law:
    f_T = g(s) f_T*, s = |f_T*| / (mu f_n), g(s) = (1 + s^p)^(-1/p), p = 8. Well inside the cone
    (s < 1/2) this is the stick law to 4e-3; in gross slip (s > 2) |f_T| is mu f_n to 2e-3; only
    near the stick-slip transition does it round the corner (|f_T| = 0.917 mu f_n at s = 1).
    The exact return map's kink makes semi-smooth Newton cycle between stick and slip when a few
    points sit at the transition (seen with a sphere on a coarse rod tip).
    """
    gap, n, dn_dx = gap_normal_hessian(shape, pose, X + u)
    # smoothed penalty f_n = k_n delta softplus(-g / delta): C^1, so Newton's line search has a
    # smooth merit and points at the contact's edge cannot make the active set cycle
    z = -gap / smooth_m
    touching = z > -30.0  # beyond that the force is below 1e-13 k_n delta
    fn = np.where(touching, k_n * smooth_m * np.logaddexp(0.0, z), 0.0)
    dfn = np.where(touching, k_n * 0.5 * (1.0 + np.tanh(0.5 * z)), 0.0)  # -d f_n / d g = k_n sigmoid(z)
    P = np.eye(3)[None] - n[:, :, None] * n[:, None, :]
    rel = (u - state.u) - drag
    trial = np.einsum("mij,mj->mi", P, state.f_t - k_t[:, None] * rel)
    trial[~touching] = 0.0
    size = np.linalg.norm(trial, axis=1)
    limit = friction * fn
    that = trial / np.maximum(size, 1e-300)[:, None]
    s = np.minimum(np.divide(size, limit, out=np.full_like(size, 1e30), where=limit > 0), 1e30)
    p = SMOOTH_P
    g = np.exp(-np.log1p(s**p) / p)  # (1 + s^p)^(-1/p)
    dg = -np.exp((-1.0 / p - 1.0) * np.log1p(s**p)) * s ** (p - 1)  # g'(s)
    g = np.where(limit > 0, g, 0.0)
    f_t = g[:, None] * trial
    f = fn[:, None] * n + f_t
    D = -dfn[:, None, None] * n[:, :, None] * n[:, None, :]
    if np.any(touching):
        # the force's direction turns with the point on a curved indenter: f_n dn/dx (the SDF's Hessian)
        D[touching] += fn[touching, None, None] * dn_dx[touching]  # analytic (fem.indenters)
    if stick_predictor:
        D_t = -k_t[:, None, None] * P
    else:
        # f_T = g(s) trial with d trial/du = -k_t P, ds = (that . d trial) / L - s dL / L, dL/du = -mu k_n n^T
        inv_l = np.divide(1.0, limit, out=np.zeros_like(limit), where=limit > 0)
        outer_tt = trial[:, :, None] * that[:, None, :]
        outer_tn = trial[:, :, None] * n[:, None, :]
        D_t = (-(g * k_t)[:, None, None] * P - (dg * inv_l * k_t)[:, None, None] * outer_tt
               + (dg * s * inv_l * friction * dfn)[:, None, None] * outer_tn)
        D_t[limit <= 0] = 0.0
    D = D + D_t
    D[~touching] = 0.0
    stick = touching & (s < 1.0)
    return _Law(f, D, fn, touching, stick, f_t)


def solve_points(C, u0, X, shape, pose, pose_old, state, friction, k_n, k_t, guess=None, smooth_m: float = 1e-7, stages: int = 3, **kw):
    """One contact step. With ``delassus`` (and ``warm``) in ``kw``: ADMM on the Delassus operator with
    bounded work (:func:`_admm_points`). Otherwise :func:`_newton_points`, and if it fails,
    continuation in the penalty's smoothing length: solved with ``smooth_m`` x 100, x 10, then x 1
    (for ``stages`` = 3), each from the last solution. The smooth problems converge in a few
    iterations and leave the sharp one close to its answer."""
    if kw.get("delassus") is not None:
        return _admm_points(u0, X, shape, pose, pose_old, state, friction, k_n, k_t, guess, **kw)
    kw.pop("delassus", None)
    kw.pop("warm", None)
    try:  # from the last step's state the sharp problem usually converges at once
        return _newton_points(C, u0, X, shape, pose, pose_old, state, friction, k_n, k_t, guess, smooth_m=smooth_m, **kw)
    except SolverError:
        if stages <= 1:
            raise
    total, kicks = 0, 0
    for k in range(stages - 1, -1, -1):
        u, law, info = _newton_points(C, u0, X, shape, pose, pose_old, state, friction, k_n, k_t, guess, smooth_m=smooth_m * 10.0**k, **kw)
        guess = u
        total += info["iterations"]
        kicks += info["kicks"]
    info["iterations"], info["kicks"] = total, kicks
    return u, law, info


def _admm_points(u0, X, shape, pose, pose_old, state, friction, k_n, k_t, guess=None, delassus=None, warm=None,
                 case: str = "contact step", max_iterations: int = 200, admm_rtol: float = 1e-4, relaxation_halvings: int | None = None,
                 **ignored):
    """:func:`fem.contact_admm.solve_step` with the arguments and returns of :func:`_newton_points`.
    The penalty is isotropic (k_t = k_n)."""
    from fem import contact_admm

    if not np.allclose(k_t, k_n):
        raise ValueError("the ADMM contact solver needs one isotropic penalty per point (k_t = k_n)")
    halvings = {} if relaxation_halvings is None else {"relaxation_halvings": relaxation_halvings}
    u, law, info = contact_admm.solve_step(delassus, u0, X, shape, pose, pose_old, state, friction, k_n, warm, guess, rtol=admm_rtol,
                                           max_iterations=max_iterations, **halvings)
    if not np.all(np.isfinite(u)):
        raise SolverError(f"{case}: NaN or Inf in the contact solution")
    return u, law, {"iterations": info.iterations, "kicks": 0, "residuals_m": [], "f": law.f, "admm": info}


def _newton_points(C: np.ndarray, u0: np.ndarray, X: np.ndarray, shape: IndenterShape, pose: Pose, pose_old: Pose, state: PointState,
                 friction: float, k_n: np.ndarray, k_t: np.ndarray, guess: np.ndarray | None = None,
                 tol_m: float = 1e-12, rtol: float = 1e-8, max_iterations: int = 200, case: str = "contact step", smooth_m: float = 1e-7,
                 max_step_m: float | None = None):
    """Solve u = u0 + C f(u) for the points' displacements u (m, 3) at indenter ``pose``.

    C: (3 m, 3 m) point compliance (m/N), point-major. u0: (m, 3) displacements without contact
    forces. state: the points' state at ``pose_old`` (the previous converged step). k_n, k_t: (m,)
    N/m. Converged when max |R| <= max(tol_m, rtol max |u|). ``max_step_m`` caps how far any point
    moves in one iteration (a trust region): a penalty contact has distant spurious equilibria (a
    rod tip squeezed out from under a punch and held bent by its side wall), and an uncapped first
    Newton step can land in their basin. Returns (u, law at u, info dict:
    iterations, residual 2-norms). Raises SolverError on failure.
    """
    m = len(u0)
    drag = rigid_motion(pose_old, pose, X + state.u)
    u = (state.u if guess is None else guess).copy()
    if not np.all(np.isfinite(u0)):
        raise SolverError(f"{case}: the load gives NaN or Inf displacements")
    def residual(u, predictor=False):
        law = _contact_law(X, u, shape, pose, drag, state, friction, k_n, k_t, predictor, smooth_m)
        r = u - u0
        if law.touching.any():  # f is zero off contact: one product with the whole C beats copying its columns
            r = r - (C @ law.f.ravel()).reshape(m, 3)
        return r, law

    r, law = residual(u, predictor=True)
    norms = [float(np.linalg.norm(r))]
    scale = max(float(np.abs(u0).max()), float(np.abs(u).max()), 1e-9)
    it = 0
    kicks = 0
    while it < max_iterations:
        if float(np.abs(r).max()) <= max(tol_m, rtol * scale):
            break
        a = np.flatnonzero(law.touching)
        if len(a) == 0:
            du = -r
        else:
            # Newton on the active points: (I - C_aa D_a) du_a = -r_a, D block-diagonal (3 x 3 per point);
            # the others follow, du = -r + C_:a D_a du_a
            cols = (3 * a[:, None] + np.arange(3)).ravel()
            Dblk = law.D[a]  # (na, 3, 3)
            # C_aa blockdiag(D_a) as a dense-times-sparse product: a generic einsum over (3a, a, 3, 3)
            # costs ten times the LU that follows
            J = -np.asarray((_block_diag_csr(Dblk).T @ C[np.ix_(cols, cols)].T).T)
            J[np.diag_indices_from(J)] += 1.0  # I - C_aa D_a
            try:
                du_a = np.linalg.solve(J, -r.ravel()[cols])
            except np.linalg.LinAlgError:
                raise SolverError(f"{case}: the condensed contact tangent is singular (iteration {it})") from None
            push = np.zeros((m, 3))
            push[a] = np.einsum("pde,pe->pd", Dblk, du_a.reshape(-1, 3))
            du = (-r.ravel() + C @ push.ravel()).reshape(m, 3)
            du[a] = du_a.reshape(-1, 3)  # the same up to round-off; exact on the active rows
        if max_step_m is not None:
            longest = float(np.linalg.norm(du, axis=1).max())
            if longest > max_step_m:
                du *= max_step_m / longest
        # backtracking on |R|_2 (smooth: the penalty is smoothed); the first step is always taken
        alpha = 1.0
        while True:
            trial = u + alpha * du
            r_t, law_t = residual(trial)
            n_t = float(np.linalg.norm(r_t))
            if n_t < norms[-1] or it == 0:
                break
            alpha *= 0.5
            if alpha < 1.0 / 64:
                # No decrease along the Newton direction: the tangent is off where a point sits on a
                # curvature jump of the indenter (a rounded edge meeting a flat face). Take the full
                # step (non-monotone); a few such kicks move the iterate off the kink.
                kicks += 1
                if kicks > 20:
                    raise SolverError(f"{case}: the contact line search stalled at iteration {it}; residual {norms[-1]:.3e} m (start {norms[0]:.3e} m)")
                trial = u + du
                r_t, law_t = residual(trial)
                n_t = float(np.linalg.norm(r_t))
                break
        u, r, law = trial, r_t, law_t
        norms.append(n_t)
        scale = max(scale, float(np.abs(u).max()))
        it += 1
        if not np.isfinite(n_t):
            raise SolverError(f"{case}: NaN or Inf in the contact iteration {it}")
    if float(np.abs(r).max()) > max(tol_m, rtol * scale):
        raise SolverError(f"{case}: contact Newton did not converge in {max_iterations} iterations; residual {norms[-1]:.3e} m (start {norms[0]:.3e} m)")
    return u, law, {"iterations": it, "residuals_m": norms, "kicks": kicks, "f": law.f}


def _block_diag_csr(blocks: np.ndarray) -> sp.csr_matrix:
    """The block-diagonal matrix (3 k, 3 k) of k 3 x 3 blocks (k, 3, 3), built directly in CSR."""
    k = len(blocks)
    rows = np.repeat(np.arange(3 * k), 3)
    cols = (3 * np.arange(k)[:, None, None] + np.zeros((1, 3, 1), dtype=int) + np.arange(3)[None, None, :]).ravel()
    return sp.csr_matrix((blocks.ravel(), (rows, cols)), shape=(3 * k, 3 * k))


#: held Cosserat rods: how many levels of halves a step whose rounds did not settle is cut into (solve_path)
UNSETTLED_CUTS = 2


def solve_path(C, u0, X, shape, pose, pose_old, state, friction, k_n, k_t, case: str = "contact step", max_depth: int = 8,
               max_penetration_m: float | None = None, max_jump_m: float | None = None, unsettled_cuts: int | None = None, **kw):
    """:func:`solve_points` from ``pose_old`` to ``pose``; the move is split in halves
    (:func:`fem.continuation.solve_with_halving`, ``max_depth`` times: down to 1/256 of it), each
    solved from the last, when

    - the indenter at ``pose`` would reach deeper than ``max_jump_m`` into the points where they were
      (before they respond): a larger jump can carry a thin indenter past a point, which the penalty
      then pushes out of the far side (tunnelling that no converged state shows);
    - the solve fails, or a point ends deeper in the indenter than ``max_penetration_m`` (at the
      last depth: a :class:`SolverError`);
    - held Cosserat rods' rounds (:mod:`fem.rod_exact`) did not settle in their first budget, at most
      ``unsettled_cuts`` levels deep (default UNSETTLED_CUTS); only the last level's solves go on at half
      their relaxation (:data:`fem.contact_admm.ROUND_RELAXATION_HALVINGS`).

    Returns (u, law, info) with the total iterations and the number of cuts in info."""
    from fem.continuation import solve_with_halving

    guess = kw.pop("guess", None)
    warm = kw.get("warm")
    # held Cosserat rods (fem.rod_exact): a step whose rounds do not settle in their first budget is cut in halves
    # (UNSETTLED_CUTS levels) before the rounds' relaxation is halved: the default demo's lift-off step, where rods are
    # let go, cycled for 180 rounds (13 s of its 18 s of contact) and did not settle; its halves settle
    held = kw.get("delassus") is not None and warm is not None and getattr(warm.kinematics, "round_relaxation", None) is not None
    starts = {}  # per move's start pose: the warm start its first solve had (a cut's first half starts there again)

    def step(p_old, p, st, whole, final=True):
        extra = {} if final else {"relaxation_halvings": 0}
        if held:
            if id(p_old) in starts:
                warm.restart_from(starts[id(p_old)][1])
            else:
                starts[id(p_old)] = (p_old, warm.starting_point())  # (the pose kept: its id stays its own)
        u, law, info = solve_points(C, u0, X, shape, p, p_old, st, friction, k_n, k_t, case=case, guess=guess if whole else None, **kw, **extra)
        info.setdefault("cuts", 0)
        return u, law, info

    def unsettled(result):
        a = result[2].get("admm")
        return a is not None and not a.linearised

    def jumps(p, st):
        return max_jump_m is not None and -float(indenter_gap(shape, p, X + st.u).min()) > max_jump_m

    def too_deep(result):
        _, law, _ = result
        depth = float(np.max(law.fn / k_n)) if law.fn.size else 0.0
        if max_penetration_m is None or depth <= max_penetration_m:
            return None
        # a point sank deeper than a penalty ever lets it: the indenter jumped past it in one step
        # (tunnelling into a rod it should have pushed aside); smaller steps
        return f"{case}: penetration {depth * 1e6:.1f} um exceeds {max_penetration_m * 1e6:.1f} um even at 1/256 of the step"

    def chain(first, second):
        (_, _, i1), (u2, law2, i2) = first, second
        info = {"iterations": i1["iterations"] + i2["iterations"], "cuts": 1 + i1["cuts"] + i2["cuts"], "residuals_m": i2["residuals_m"], "f": i2["f"]}
        if "admm" in i2:  # the worse half's convergence (an unsettled half first)
            info["admm"] = max(i1["admm"], i2["admm"], key=lambda a: (not a.linearised, a.residual_n / max(a.tolerance_n, 1e-300)))
        return u2, law2, info

    return solve_with_halving(step, pose_old, pose, state, max_depth, jumps=jumps, too_deep=too_deep, deep_at_the_end="raise",
                              next_start=lambda r: PointState(r[0].copy(), r[1].f_t.copy()), chain=chain,
                              unsettled=unsettled if held else None,
                              unsettled_cuts=UNSETTLED_CUTS if unsettled_cuts is None else unsettled_cuts)


def normal_force(law: _Law) -> float:
    """The indenter's downward push on the body (N): -sum of the vertical contact forces."""
    return float(-law.f[:, 2].sum())


def solve_points_at_force(target_n: float, z_guess: float, solve_at_z, z_free: float, tol_rel: float = 1e-6, max_iterations: int = 60,
                          case: str = "force control", z_min: float | None = None):
    """Height z of the indenter at which ``solve_at_z(z)`` -> (normal force, payload) gives ``target_n``.

    The normal force is non-increasing in z, zero at and above ``z_free`` (no contact). From
    ``z_guess`` the search marches down in doubling steps until the force exceeds the target, never
    below ``z_min`` (m; None: unbounded; the tiers pass the rods' roots, the base's top: no indenter
    gets lower), then closes the bracket by the Illinois secant on F(z) - target. Unbounded, a march
    whose trials had passed the contact points (zero force below them) ran on to z = -1.6e18 mm.
    Returns (z, payload, evaluations).

    Raises :class:`SolverError` when the target is not reached at ``z_min``, when the force falls as
    the indenter goes deeper (the monotony the search rests on fails: the solves at the two heights
    are on different branches of the frictional contact problem, or the indenter has passed the
    points), or after ``max_iterations`` evaluations.
    """
    if z_min is not None and not z_min < z_free:
        raise ValueError(f"z_min = {z_min:.6g} m must be below z_free = {z_free:.6g} m")
    if target_n <= 0:
        f, payload = solve_at_z(z_free)
        return z_free, payload, 1
    hi, (f_hi, _) = z_free, solve_at_z(z_free)  # F(hi) - target < 0
    step = max(z_free - z_guess, 1e-5)
    lo = min(z_guess, z_free - 1e-5)
    if z_min is not None:
        lo = max(lo, z_min)
    f_lo, p_lo = solve_at_z(lo)
    n_eval = 2
    while f_lo < target_n:  # march down until the force exceeds the target
        if f_lo < f_hi - tol_rel * target_n:
            raise SolverError(f"{case}: the normal force falls from {f_hi:.4g} N at z = {hi * 1e3:.4f} mm to {f_lo:.4g} N at z = "
                              f"{lo * 1e3:.4f} mm, deeper: the contact solves are not monotone in the indenter's height, so "
                              f"{target_n:.4g} N cannot be bracketed (a probe wedged between tips with friction has several equilibria): "
                              "press on a tip (load.start_xy_mm)")
        if z_min is not None and lo <= z_min:
            raise SolverError(f"{case}: cannot reach {target_n:.4g} N: {f_lo:.4g} N at z = {lo * 1e3:.4f} mm, the lowest height the "
                              "search allows (the rods' roots); lower the press's force_n")
        hi, f_hi = lo, f_lo
        step *= 2.0
        lo = lo - step if z_min is None else max(lo - step, z_min)
        f_lo, p_lo = solve_at_z(lo)
        n_eval += 1
        if n_eval > max_iterations:
            raise SolverError(f"{case}: cannot reach {target_n:.4g} N (reached {f_lo:.4g} N at z = {lo * 1e3:.3f} mm)")
    g_lo, g_hi = f_lo - target_n, f_hi - target_n
    side = 0
    for _ in range(max_iterations):
        z = (lo * g_hi - hi * g_lo) / (g_hi - g_lo)
        f, p = solve_at_z(z)
        n_eval += 1
        g = f - target_n
        if abs(g) <= tol_rel * target_n or abs(hi - lo) < 1e-13:
            return z, p, n_eval
        if g > 0:
            lo, g_lo = z, g
            if side == -1:
                g_hi *= 0.5
            side = -1
        else:
            hi, g_hi = z, g
            if side == 1:
                g_lo *= 0.5
            side = 1
    raise SolverError(f"{case}: force control did not converge to {target_n:.4g} N (last {f:.4g} N)")
