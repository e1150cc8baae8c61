"""Second-order rigid-rotation kinematics of bent rods for the linear tiers (``fidelity.solve.rod_kinematics``).

The ``linear`` and ``reduced`` tiers move the contact points by first-order kinematics, u = u_0 + E f.
A rod bent sideways by d at its tip also drops its tip by about (3/5) d^2 / L (a cantilever's
inextensible axis) and turns its tip face, so the face's far edge drops as well. A first-order
body keeps both up, and an indenter dragging rods overlaps their tips too much (per-rod contact
forces 70 % high on the tiny scene's slide, against the neo-Hookean tier). This module adds the
second-order terms of the rods' section rotations, keeping the body small-strain otherwise:

    q_i(f) = 1/2 w x (w x r_i) - e_z 1/2 int_base^tip |theta_perp(z)|^2 dz,

with theta(z) the rotation vector of the rod's section at height z and theta_perp its horizontal
part, w = theta(tip), r_i = X_i - (tip centre). theta is the least-squares rotation of the linear
displacement of the vertices of ``n_slabs`` slabs along the rod (and of the tip face): linear in
the forces, so q is quadratic in f. The contact is evaluated at X + u + q(f) (the exact rotation
R(w) r = r + w x r + 1/2 w x (w x r) + O(w^3); the axis' shortening is the arc-length condition of
an inextensible axis, Timoshenko & Gere, Theory of Elastic Stability, 1961, sec. 2.7).

P-delta: a rod's axial contact force F_z < 0 (compressive) at a tip displaced sideways by d_h adds
the moment F_z d_h at the base; it is applied as the equivalent horizontal tip load

    f_pd = -F_z d_h / L,

spread over the rod's touching points in proportion to their vertical forces (geometric softening
of a compressed column to first order, Timoshenko & Gere sec. 1.11).

What this is not: a co-rotational or finite-strain body. Stresses stay those of the linear field
under the contact (and P-delta) loads; sections are rigid; the rotations are those of the linear
solution; the axis' drop uses the slabs' mean rotation, the tip face its plane's tilt. On the tiny
scene's slide (a 6 mm sphere pressed 1 mm between four rods and slid 4 mm, mu 0.8: tilts of 10-15
deg) it brings the linear tier from 43 / 76 / 40 % to 7.4 / 11 / 7.1 % off the nonlinear tier
(rod-base von Mises / per-rod contact force / tip displacement, mlsim.studies.accuracy), and the reduced
tier from 15 / 35 / 17 % to 8.6 / 10.5 / 9.4 %. Its cost is the contact loop's fixed point in q:
5-12 linearisations per moving step instead of 1-3 (about 2-3 x the contact time per frame on the
default demo).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

__all__ = ["RodSections", "ThinSlabError", "rod_sections", "axis_drop", "rotation_offset", "second_order_points", "pdelta_load", "RodKinematics",
           "ROD_KINEMATICS", "first_order_force_error"]

ROD_KINEMATICS = ("first_order", "second_order", "cosserat")  # "cosserat": fem.rod_exact
N_SLABS = 8  # sections along a rod; 8 on the tiny mesh's 2.5 mm edges: each slab holds 2-3 vertex layers
FLAT_SLAB = 0.02  # a slab thinner than this x its width (smallest / largest spread) is fitted as a plane


@dataclass(frozen=True)
class RodSections:
    """The rods' sections as a linear observation of the vertex displacements.

    ``O`` (n_obs, 3 P) sparse acts on vertex displacements (vertex-major 3 p + c) and gives, per rod
    j of ``rods``: the rotation vectors (n_slabs + 1, 3) rad of its slabs and tip face (rows
    (j (n_slabs + 1) + k) 3 + c), then after all rods the tip face's mean horizontal displacement
    (2,) m (rows 3 R (n_slabs + 1) + 2 j + c). ``dz`` (n_slabs,) m slab heights, ``z_mid``
    (n_slabs,) m their mid-heights, ``centre`` (R, 3) m the tip centres, ``length_m`` the rod height
    above the base, ``vertices`` per rod the vertex indices (for the field's correction)."""

    O: sp.csr_matrix
    rods: np.ndarray
    dz: np.ndarray
    z_mid: np.ndarray
    base_z_m: float
    centre: np.ndarray
    length_m: float
    vertices: tuple

    @property
    def n_slabs(self) -> int:
        return len(self.dz)

    def split(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """obs (n_obs,) -> rotations (R, n_slabs + 1, 3) rad and tip displacements (R, 2) m."""
        R, K = len(self.rods), self.n_slabs + 1
        return obs[: 3 * R * K].reshape(R, K, 3), obs[3 * R * K :].reshape(R, 2)


def _rotation_rows(points: np.ndarray, verts: np.ndarray):
    """(rows 0..2, columns, values) of the least-squares rotation vector of a vertex set: with
    A = X - mean X and M^T = pinv(A) U the fitted displacement gradient, theta = axial(M - M^T) / 2.
    pinv(A) annihilates a uniform translation (A's columns sum to zero), so U needs no centring."""
    A = points[verts] - points[verts].mean(axis=0)
    Gp = np.linalg.pinv(A)  # (3, ns)
    rows, cols, vals = [], [], []
    # theta_x = (M21 - M12) / 2, M[a, b] = sum_j Gp[b, j] U[j, a]
    for r, (a1, b1, a2, b2) in enumerate(((2, 1, 1, 2), (0, 2, 2, 0), (1, 0, 0, 1))):
        rows += [np.full(len(verts), r), np.full(len(verts), r)]
        cols += [3 * verts + a1, 3 * verts + a2]
        vals += [0.5 * Gp[b1], -0.5 * Gp[b2]]
    return np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)


def _face_rotation_rows(points: np.ndarray, verts: np.ndarray):
    """(rows, columns, values) of the rotation vector of a horizontal face (the tip): a plane section's
    tilt from the least-squares gradient of u_z in the face, theta_x = du_z/dy, theta_y = -du_z/dx, and
    its twist theta_z = (du_y/dx - du_x/dy) / 2. (A 3-D fit is singular on a plane: pinv then keeps
    only half of the tilt, du_x/dz being unknown.)"""
    Gp = np.linalg.pinv(points[verts, :2] - points[verts, :2].mean(axis=0))  # (2, ns)
    n = len(verts)
    rows = np.concatenate([np.zeros(n), np.ones(n), np.full(n, 2), np.full(n, 2)]).astype(int)
    cols = np.concatenate([3 * verts + 2, 3 * verts + 2, 3 * verts + 1, 3 * verts])
    vals = np.concatenate([Gp[1], -Gp[0], 0.5 * Gp[0], -0.5 * Gp[1]])
    return rows, cols, vals


class ThinSlabError(ValueError):
    """A slab of a rod holds fewer than 3 vertices: the mesh is too coarse for that many slabs."""


def rod_sections(points: np.ndarray, tets: np.ndarray, tet_rod: np.ndarray, rods, base_z_m: float, tip_z_m: float,
                 n_slabs: int | None = None) -> RodSections:
    """The section observation of the rods ``rods`` of a mesh (points (P, 3) m, tets (T, 4), tet_rod (T,))
    between the base's top ``base_z_m`` and the tips ``tip_z_m``.

    ``n_slabs`` None: the most slabs up to :data:`N_SLABS` in which every slab of every rod holds at
    least 3 vertices (a short rod on a coarse mesh, e.g. 6 mm on 2 mm edges, takes fewer)."""
    if n_slabs is None:
        for n in range(N_SLABS, 0, -1):
            try:
                return rod_sections(points, tets, tet_rod, rods, base_z_m, tip_z_m, n)
            except ThinSlabError:
                if n == 1:
                    raise
    rods = np.asarray(rods, dtype=int)
    edges = np.linspace(base_z_m, tip_z_m, n_slabs + 1)
    # 0.1 um: the snapped tip vertices of one rod lie up to nanometres off another's (seen: 1.3 nm on a 6 mm
    # rod's mesh, which left 24 rods without a tip face at 1 nm), and no vertex layer is within a micrometre
    tol = 1e-7
    rows, cols, vals, centres, vertex_sets = [], [], [], [], []
    K = n_slabs + 1
    for j, r in enumerate(rods):
        verts = np.unique(tets[tet_rod == r])
        verts = verts[points[verts, 2] >= base_z_m - tol]
        z = points[verts, 2]
        top = verts[z >= tip_z_m - tol]
        sets = [verts[(z >= edges[k] - tol) & (z <= edges[k + 1] + tol)] for k in range(n_slabs)] + [top]
        for k, sl in enumerate(sets):
            if len(sl) < 3 and k == n_slabs:
                raise ValueError(f"rod {r}: {len(sl)} vertices within {tol:g} m of the tip height {tip_z_m:.9g} m: the mesh has no tip face there")
            if len(sl) < 3:
                raise ThinSlabError(f"rod {r}: slab {k} of {n_slabs} holds {len(sl)} vertices; use fewer slabs (n_slabs) for this mesh")
            spread = np.linalg.svd(points[sl] - points[sl].mean(axis=0), compute_uv=False)
            # a slab of one vertex layer is (nearly) plane: its 3-D fit is singular, take its plane's tilt
            flat = k == n_slabs or spread[-1] < FLAT_SLAB * spread[0]
            rr, cc, vv = (_face_rotation_rows if flat else _rotation_rows)(points, sl)
            rows.append(3 * (j * K + k) + rr)
            cols.append(cc)
            vals.append(vv)
        centres.append([*points[top, :2].mean(axis=0), tip_z_m])
        vertex_sets.append(verts)
    R = len(rods)
    for j, verts in enumerate(vertex_sets):
        top = verts[points[verts, 2] >= tip_z_m - tol]
        for c in range(2):
            rows.append(np.full(len(top), 3 * R * K + 2 * j + c))
            cols.append(3 * top + c)
            vals.append(np.full(len(top), 1.0 / len(top)))
    n_obs = 3 * R * K + 2 * R
    O = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(n_obs, 3 * len(points)))
    return RodSections(O, rods, np.diff(edges), 0.5 * (edges[1:] + edges[:-1]), float(base_z_m), np.array(centres).reshape(-1, 3),
                       float(tip_z_m - base_z_m), tuple(vertex_sets))


def axis_drop(theta: np.ndarray, dz: np.ndarray) -> np.ndarray:
    """The drop (..., ) m of an inextensible axis whose sections turn by theta (..., n_slabs, 3) rad over
    slabs of heights dz (n_slabs,) m: 1/2 sum_k |theta_perp,k|^2 dz_k."""
    return 0.5 * np.einsum("...k,k->...", theta[..., 0] ** 2 + theta[..., 1] ** 2, dz)


def rotation_offset(w: np.ndarray, r: np.ndarray) -> np.ndarray:
    """The second-order term 1/2 w x (w x r) (n, 3) m of a rotation w (3,) rad of the offsets r (n, 3) m."""
    return 0.5 * np.cross(w, np.cross(w, r))


def second_order_points(theta: np.ndarray, sections: RodSections, X: np.ndarray, point_rod: np.ndarray) -> np.ndarray:
    """q (m, 3) m: the second-order displacement of points X (m, 3) on rods ``point_rod`` (m,) (index into
    sections.rods, -1 off them: q = 0), for section rotations theta (R, n_slabs + 1, 3) rad."""
    q = np.zeros((len(X), 3))
    drop = axis_drop(theta[:, :-1], sections.dz)  # (R,)
    on = point_rod >= 0
    j = point_rod[on]
    w = theta[j, -1]  # (n, 3) tip rotations
    r = X[on] - sections.centre[j]
    q[on] = 0.5 * np.cross(w, np.cross(w, r))
    q[on, 2] -= drop[j]
    return q


def euler_load_n(radius_m: float, height_m: float, young_pa, thickness_m) -> float:
    """Euler's buckling load pi^2 EI / (4 L^2) N of a rod clamped at its base with its tip free to move
    sideways (the lowest of a rod a sliding probe drags), EI of its layered section: ``young_pa``
    (k,) Pa of the layers outside in, the last the core, and ``thickness_m`` (k - 1,) of all but the
    core (the layers coat the rods' sides, :mod:`fem.geometry`).

    The bound of the P-delta model: its rod's sideways stiffness 3 EI / L^3 - P / L falls to zero at
    P = 3 EI / L^2 = 1.22 x this load, where the real rod has already buckled. At half of it the
    true beam-column amplification of a sideways deflection is 1 / (1 - 0.5) = 2.0 and the model's
    1 / (1 - 0.5 pi^2 / 12) = 1.70 (15 % short), beyond it the gap grows without bound
    (Timoshenko and Gere, Theory of Elastic Stability, 2nd ed., sections 1.3 and 2.1)."""
    if height_m <= 0:
        raise ValueError(f"euler_load_n: height {height_m} m: must be > 0")
    return np.pi ** 2 * layered_bending_stiffness_n_m2(radius_m, young_pa, thickness_m) / (4.0 * height_m ** 2)


def layered_bending_stiffness_n_m2(radius_m: float, young_pa, thickness_m) -> float:
    """EI (N m^2) of a round rod's layered section: ``young_pa`` (k,) Pa of the layers outside in, the last
    the core, ``thickness_m`` (k - 1,) of all but the core (the layers coat the rods' sides)."""
    E = np.asarray(young_pa, dtype=float)
    t = np.asarray(thickness_m, dtype=float)
    if len(t) != len(E) - 1 or np.any(t < 0) or np.any(E <= 0) or radius_m <= 0:
        raise ValueError(f"euler_load_n: radius {radius_m} m, moduli {E} Pa and thicknesses {t} m: "
                         "need positive sizes and moduli and one thickness per layer outside the core")
    outer = radius_m - np.concatenate([[0.0], np.cumsum(t)])  # each layer's outer radius, outside in
    inner = np.append(outer[1:], 0.0).clip(min=0.0)
    return float(np.sum(E * np.pi / 4.0 * (outer.clip(min=0.0) ** 4 - inner ** 4)))


def pdelta_load(f: np.ndarray, tip_h: np.ndarray, point_rod: np.ndarray, length_m: float) -> np.ndarray:
    """The P-delta equivalent load (m, 3) N on the points: per rod j, -F_z d_h / L with F_z = sum of the
    vertical forces f (m, 3) N on its points and d_h = tip_h[j] (2,) m, where F_z < 0 (compression),
    spread over its points in proportion to |f_z|."""
    extra = np.zeros_like(f)
    on = point_rod >= 0
    R = len(tip_h)
    fz = np.where(on, f[:, 2], 0.0)
    Fz = np.bincount(point_rod[on], weights=fz[on], minlength=R)
    weight = np.bincount(point_rod[on], weights=np.abs(fz[on]), minlength=R)
    load = np.where((Fz < 0)[:, None], -Fz[:, None] * tip_h / length_m, 0.0)  # (R, 2)
    share = np.zeros(len(f))
    share[on] = np.abs(fz[on]) / np.where(weight[point_rod[on]] > 0, weight[point_rod[on]], 1.0)
    extra[on, :2] = share[on, None] * load[point_rod[on]]
    return extra


def first_order_force_error(sections: RodSections, points: np.ndarray, du: np.ndarray, rod_force_n: np.ndarray, radius_m: float,
                            weights: np.ndarray | None = None) -> float:
    """A posteriori estimate of the relative error of first-order kinematics' per-rod contact forces,
    from the episode's own displacement field (the linear tiers' ``geometric_error_estimate``).

    A first-order body keeps a bent rod's tip up. Per rod and step, the drop it misses is that of
    :func:`second_order_points` at the tip's edge, from the linear field's section rotations theta:

        delta = 1/2 sum_k |theta_perp,k|^2 dz_k + 1/2 |w_perp|^2 a,

    (the inextensible axis' shortening, the tilted tip face's edge at the rod radius a). The indenter
    reaches delta less deep into a rod pressed by c at its tip (the mean vertical displacement of its
    tip face) with a force F_z, so with the rod's secant stiffness F_z / c the force is off by about
    dF = F_z delta / c. The estimate is the relative Frobenius norm of dF over steps (weighted by
    ``weights``, e.g. frames per step) and rods against the forces, the measure of
    :mod:`mlsim.studies.accuracy`.

    A linearisation of the missed geometry, not a bound: it leaves out the material's own
    nonlinearity and friction's changed stick and slip. Measured against the nonlinear tier (2 mm,
    P2; ``mlsim accuracy``): default demo (flat punch pressed, slid, twisted) 14.0 % estimated /
    12.7 % measured; screw scene (a cylinder rolled over the tips) 5.3 / 4.5 %; tiny scene (a
    sphere dragging rods 10-15 deg) 167 / 94 %: past the linear regime it overstates.

    Parameters
    ----------
    sections : RodSections
        Of the rods ``sections.rods`` (mesh rod indices).
    points : (P, 3) float
        Mesh vertices, m.
    du : (U, P, 3) float
        Vertex displacement of each step from the state without contact (gravity alone), m.
    rod_force_n : (U, n_rods, 3) float
        Contact force on each mesh rod, N (compressive: F_z < 0).
    radius_m : float
        Rod radius.
    weights : (U,) float, optional
        Weight of each step (default 1).
    """
    du = np.asarray(du, dtype=float)
    F = np.asarray(rod_force_n, dtype=float)
    w_u = np.ones(len(du)) if weights is None else np.asarray(weights, dtype=float)
    tip_z = sections.base_z_m + sections.length_m
    tops = [v[points[v, 2] >= tip_z - 1e-9] for v in sections.vertices]
    rods = sections.rods
    # each rod's tip face's mean vertical displacement: numpy's mean of the face's values (its pairwise
    # sum over a contiguous slice, over the count) without ndarray.mean's per-call overhead (a mean
    # over an axis of all steps at once sums in another order: other bits)
    top_all = np.concatenate(tops) if tops else np.zeros(0, dtype=np.int64)
    top_end = np.cumsum([len(t) for t in tops])
    top_start = top_end - np.array([len(t) for t in tops], dtype=top_end.dtype)
    num = 0.0
    for u in range(len(du)):
        Fz = -F[u, rods, 2]
        if not np.any(Fz > 0) or w_u[u] == 0:
            continue
        theta, _ = sections.split(sections.O @ du[u].ravel())
        missed = axis_drop(theta[:, :-1], sections.dz) + 0.5 * (theta[:, -1, 0] ** 2 + theta[:, -1, 1] ** 2) * radius_m
        z = du[u, top_all, 2]
        c = np.array([-(np.add.reduce(z[a:b]) / (b - a)) for a, b in zip(top_start.tolist(), top_end.tolist())])
        dF = np.where((Fz > 0) & (c > 0), Fz * missed / np.where(c > 0, c, 1.0), 0.0)
        num += w_u[u] * float(np.sum(dF**2))
    den = float(np.einsum("u,urc->", w_u, F**2))
    return float(np.sqrt(num / den)) if den > 0 else 0.0


def resultant_change(df: np.ndarray, point_rod: np.ndarray, n_rods: int) -> float:
    """sum over rods of |sum of df (m, 3) N over the rod's points|, plus |df| of points off the rods (N):
    the contact loop's measure of how far the kinematics' last round moved the load (point_rod (m,)
    indexes the rods 0..n_rods - 1, -1 off them)."""
    on = point_rod >= 0
    per_rod = np.stack([np.bincount(point_rod[on], weights=df[on, c], minlength=n_rods) for c in range(3)], axis=1)
    return float(np.linalg.norm(per_rod, axis=1).sum() + np.linalg.norm(df[~on], axis=1).sum())


class RodKinematics:
    """The per-episode operators: section observation obs(f) = obs_0 + A f (f the forces on the
    contact points) and the contact points' geometry.

    sections: :class:`RodSections`; A (n_obs, 3 m) the observation per unit point force; obs_0 (n_obs,)
    the observation without contact (gravity); X (m, 3) m the contact points, point_rod (m,) their
    rods (mesh rod index, -1 on the base); ``pdelta``: add the P-delta load."""

    def __init__(self, sections: RodSections, A: np.ndarray, obs_0: np.ndarray, X: np.ndarray, point_rod: np.ndarray, pdelta: bool = True):
        self.sections = sections
        self.A = np.ascontiguousarray(A, dtype=float)
        self.obs_0 = np.asarray(obs_0, dtype=float)
        self.X = X
        index = {int(r): j for j, r in enumerate(sections.rods)}
        self.point_rod = np.array([index.get(int(r), -1) for r in point_rod], dtype=int)
        self.pdelta = pdelta

    def resultant_change(self, df: np.ndarray) -> float:
        """sum over rods of |sum of df (m, 3) N over the rod's points|, plus |df| of points off the rods (N)."""
        return resultant_change(df, self.point_rod, len(self.sections.rods))

    def observe(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Section rotations (R, n_slabs + 1, 3) rad and tip displacements (R, 2) m at point forces f (m, 3) N."""
        return self.sections.split(self.obs_0 + self.A @ f.ravel())

    def q(self, f: np.ndarray) -> np.ndarray:
        """The points' second-order displacement (m, 3) m at point forces f (m, 3) N."""
        theta, _ = self.observe(f)
        return second_order_points(theta, self.sections, self.X, self.point_rod)

    def q_and_load(self, f_points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """q (m, 3) m and the P-delta load (m, 3) N (zero without ``pdelta``) at point forces f_points (m, 3) N."""
        theta, tip_h = self.observe(f_points)
        q = second_order_points(theta, self.sections, self.X, self.point_rod)
        load = pdelta_load(f_points, tip_h, self.point_rod, self.sections.length_m) if self.pdelta else np.zeros_like(f_points)
        return q, load

    def vertex_correction(self, U: np.ndarray, points: np.ndarray, forces: np.ndarray | None = None) -> np.ndarray:
        """The second-order displacement (P, 3) m of the mesh's vertices (points (P, 3) m) for a linear
        vertex displacement U (P, 3) m: per rod, the section rotation theta(z) interpolated between
        slab mid-heights and the tip face, 1/2 theta x (theta x r) about the axis at z, and the axis'
        drop integrated up to z. At the tip face it is :meth:`q`'s."""
        sec = self.sections
        U = np.asarray(U, dtype=float)
        theta, _ = sec.split(sec.O @ U.ravel())
        out = np.zeros_like(U)
        z_nodes = np.concatenate([[sec.base_z_m], sec.z_mid, [sec.base_z_m + sec.length_m]])
        for j, verts in enumerate(sec.vertices):
            th = np.concatenate([theta[j, :1], theta[j, :-1], theta[j, -1:]])  # (n_slabs + 2, 3)
            z = points[verts, 2]
            t = np.stack([np.interp(z, z_nodes, th[:, c]) for c in range(3)], axis=1)
            rate = 0.5 * (theta[j, :-1, 0] ** 2 + theta[j, :-1, 1] ** 2)  # drop per height in each slab
            edges = np.concatenate([[sec.base_z_m], sec.base_z_m + np.cumsum(sec.dz)])
            drop_edges = np.concatenate([[0.0], np.cumsum(rate * sec.dz)])
            r = points[verts] - np.column_stack([np.broadcast_to(sec.centre[j, :2], (len(verts), 2)), z])
            out[verts] = 0.5 * np.cross(t, np.cross(t, r))
            out[verts, 2] -= np.interp(z, edges, drop_edges)
        return out
