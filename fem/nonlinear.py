"""Finite-strain statics: mixed neo-Hookean solid, Newton's method with line search and load stepping.

The compressible neo-Hookean energy of :mod:`fem.materials.neo_hookean` is written in the
two-field (Herrmann-type) form [BonetWood2008]_ (sec. 8.6) so that it does not lock as
lambda -> infinity:

    Pi(u, p) = int [ mu/2 (I1 - 3) - mu ln J + p ln J - p^2 / (2 lambda) ] dV - W_ext(u)

Stationarity in p gives p = lambda ln J and recovers W exactly. Residuals and consistent tangent:

    R_u(v)        = int [ mu (F - F^-T) + p F^-T ] : grad v  - W_ext(v)
    R_p(q)        = int q (ln J - p / lambda)
    K_uu(du, v)   = int mu grad du : grad v + (mu - p) tr(F^-1 grad v F^-1 grad du)
    K_up(dp, v)   = int dp tr(F^-1 grad v),     K_pp(dp, q) = -int dp q / lambda

At F = I, p = 0 the tangent is the linear P2P1 operator of :mod:`fem.elasticity` (tested). The
pressure unknowns are scaled by the shear modulus, as there.

Newton: the tangent system is solved directly (SuperLU); the step is damped by backtracking on
the residual norm (Armijo-type sufficient decrease; the saddle point has no energy to minimise)
and by refusing any trial state that inverts an element (det F <= 0). Loads are applied in
increments; an increment that fails to converge is halved, down to a minimum, after which a
:class:`SolverError` names the load factor and the residual reached.

References
----------
.. [BonetWood2008] J. Bonet, R. D. Wood, "Nonlinear Continuum Mechanics for Finite Element
   Analysis", 2nd ed., Cambridge University Press (2008).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import scipy.sparse as sp
import skfem
from skfem import BilinearForm, LinearForm
from skfem.helpers import ddot, det, grad, inv, mul, trace, transpose

from fem.elasticity import Discretisation, _per_qp
from mlsim.errors import SolverError  # (defined with the other errors; imported from here by the solvers)

__all__ = ["SolverError", "NewtonReport", "residual_and_tangent", "solve_nonlinear", "FullStepNewton"]


def _kinematics(w):
    # F, J and F^-1 at the quadrature points, computed once per assembly (residual_and_tangent) and
    # passed in: a bilinear form is evaluated once per pair of basis functions (900 for P2 vectors)
    return w.F, w.J, w.Finv


def _identity_like(g):
    out = np.zeros_like(g)
    for i in range(3):
        out[i, i] = 1.0
    return out


@LinearForm
def _residual_u(v, w):
    F, J, Finv = _kinematics(w)
    FinvT = transpose(Finv)
    P = w.mu * (F - FinvT) + w.s * w.p * FinvT
    return ddot(P, grad(v))


@LinearForm
def _residual_p(q, w):
    _, J, _ = _kinematics(w)
    return w.s * q * (np.log(J) - w.s * w.p / w.lam)


@BilinearForm
def _tangent_uu(du, v, w):
    F, J, Finv = _kinematics(w)
    return w.mu * ddot(grad(du), grad(v)) + (w.mu - w.s * w.p) * trace(mul(mul(Finv, grad(v)), mul(Finv, grad(du))))


@BilinearForm
def _tangent_up(dp, v, w):
    _, _, Finv = _kinematics(w)
    return w.s * dp * trace(mul(Finv, grad(v)))


@BilinearForm
def _tangent_pp(dp, q, w):
    return -(w.s * w.s) * dp * q / w.lam


def _scalar_gradients(basis) -> np.ndarray:
    """(nb, 3, E, Q): the gradients of the scalar functions of a vector basis whose local function 3 i + a
    is scalar function i along component a."""
    return np.stack([np.asarray(basis.basis[3 * i][0].grad[0]) for i in range(basis.Nbfun // 3)])


def tangent_uu(basis, mu_q: np.ndarray, p_q: np.ndarray, s: float, Finv: np.ndarray) -> sp.csr_matrix:
    """K_uu of :data:`_tangent_uu`, assembled without scikit-fem's per-pair loop (same matrix, tested).

    A vector basis function is a scalar one times a unit vector, grad v = e_a grad(phi_i)^T, so
    tr(F^-1 grad v F^-1 grad du) = (F^-T grad phi_j)_a (F^-T grad phi_i)_b for du = e_b phi_j: the
    geometric term is an outer product of "spatial" scalar gradients, and the whole element matrix
    is two batched products over the quadrature points (scikit-fem evaluates the form once per pair
    of the 30 vector functions: 900 small 3 x 3 matrix products per point; 10x slower on the sensor).
    basis: the P2 vector basis (local function 3 i + a: scalar function i, component a);
    mu_q, p_q: (E, Q) Pa and scaled pressure; Finv: (3, 3, E, Q).
    """
    nb = basis.Nbfun // 3
    G = _scalar_gradients(basis)  # (nb, 3, E, Q): grad phi_i
    g = np.einsum("kaeq,ikeq->eqia", Finv, G)  # (E, Q, nb, 3): F^-T grad phi_i
    dx = basis.dx  # (E, Q)
    E = dx.shape[0]
    lap = np.einsum("ikeq,jkeq,eq->eij", G, G, mu_q * dx)  # (E, nb, nb): mu grad phi_i . grad phi_j
    c = ((mu_q - s * p_q) * dx)[:, :, None]
    # geo[e, i, b, j, a] = sum_q c g_i[b] g_j[a]: a batched (3 nb x Q) @ (Q x 3 nb) product
    geo = np.matmul(g.reshape(E, -1, 3 * nb).transpose(0, 2, 1), c * g.reshape(E, -1, 3 * nb)).reshape(E, nb, 3, nb, 3)
    K = geo.transpose(0, 1, 4, 3, 2) + lap[:, :, None, :, None] * np.eye(3)[None, None, :, None, :]  # [e, i, a, j, b]
    slot, indices, indptr = _csr_pattern(basis.element_dofs, basis.N)
    data = np.bincount(slot, weights=K.reshape(-1), minlength=len(indices))
    return sp.csr_matrix((data, indices, indptr), shape=(basis.N, basis.N))


def tangent_up(basis, pbasis, s: float, Finv: np.ndarray) -> sp.csr_matrix:
    """K_up of :data:`_tangent_up` (rows: the P2 vector functions, columns: the P1 pressure functions),
    assembled as one batched product (same matrix, tested). tr(F^-1 grad v) = (F^-T grad phi_i)_a for
    v = e_a phi_i, so the element matrix is sum_q s (F^-T grad phi_i)_a psi_k dx; scikit-fem's per-pair
    loop took 0.9 s of the 2.3 s tangent on the default sensor. Finv: (3, 3, E, Q)."""
    nb = basis.Nbfun // 3
    G = _scalar_gradients(basis)  # (nb, 3, E, Q)
    g = np.einsum("kaeq,ikeq->eqia", Finv, G).reshape(G.shape[2], G.shape[3], 3 * nb)  # (E, Q, 3 nb)
    psi = np.stack([np.asarray(pbasis.basis[k][0].value) for k in range(pbasis.Nbfun)])  # (np, E, Q)
    local = np.einsum("eqi,keq,eq->eik", g, psi, s * basis.dx)  # (E, 3 nb, np)
    rows = np.broadcast_to(basis.element_dofs.T[:, :, None], local.shape).ravel()
    cols = np.broadcast_to(pbasis.element_dofs.T[:, None, :], local.shape).ravel()
    return sp.csr_matrix((local.ravel(), (rows, cols)), shape=(basis.N, pbasis.N))


def residual_u(basis, mu_q: np.ndarray, p_q: np.ndarray, s: float, F: np.ndarray, Finv: np.ndarray) -> np.ndarray:
    """The displacement residual of :data:`_residual_u`, int P : grad v with the first Piola stress
    P = mu (F - F^-T) + s p F^-T, assembled as one batched product (scikit-fem evaluates the form once
    per vector function, 30 passes; the line search evaluates it often). mu_q, p_q: (E, Q); F, Finv:
    (3, 3, E, Q). Same vector as the form (tested)."""
    G = _scalar_gradients(basis)  # (nb, 3, E, Q): grad phi_i
    FinvT = Finv.transpose(1, 0, 2, 3)
    P = mu_q * (F - FinvT) + (s * p_q) * FinvT  # (3, 3, E, Q)
    local = np.einsum("akeq,ikeq,eq->eia", P, G, basis.dx)  # (E, nb, 3): local function 3 i + a
    return np.bincount(basis.element_dofs.T.reshape(-1), weights=local.reshape(-1), minlength=basis.N)


_LAYOUT: dict = {}


def _kernel_layout(d: Discretisation) -> tuple:
    """The arrays of :func:`fem.residual_kernels.element_residuals` for a P2P1 discretisation (kept for
    one discretisation at a time): u_dofs (E, nb, 3), grads (E, Q, nb, 3), dx (E, Q), p_dofs (E, np),
    psi (E, Q, np)."""
    hit = _LAYOUT.get(id(d))
    if hit is not None and hit[0] is d:
        return hit[1]
    b, pb = d.u, d.p
    nb = b.Nbfun // 3
    arrays = (np.ascontiguousarray(b.element_dofs.T.reshape(-1, nb, 3), dtype=np.int64),
              np.ascontiguousarray(_scalar_gradients(b).transpose(2, 3, 0, 1)),
              np.ascontiguousarray(b.dx, dtype=float),
              np.ascontiguousarray(pb.element_dofs.T, dtype=np.int64),
              np.ascontiguousarray(np.stack([np.asarray(pb.basis[k][0].value) for k in range(pb.Nbfun)], axis=-1), dtype=float))
    _LAYOUT.clear()
    _LAYOUT[id(d)] = (d, arrays)
    return arrays


def compiled_residual(d: Discretisation, x: np.ndarray, lam_q: np.ndarray, mu_q: np.ndarray) -> np.ndarray:
    """The internal residual [R_u; R_p] (n_dofs,) at x = [u; p / scale] by the fused compiled loop of
    :mod:`fem.residual_kernels`; lam_q, mu_q (E, Q) Pa. Raises FloatingPointError where det F <= 0."""
    from fem.residual_kernels import element_residuals

    u_dofs, grads, dx, p_dofs, psi = _kernel_layout(d)
    E, _, nb, _ = grads.shape
    out_u, out_p = np.empty((E, nb, 3)), np.empty((E, p_dofs.shape[1]))
    x = np.ascontiguousarray(x, dtype=float)
    bad = element_residuals(x[: d.n_u], u_dofs, grads, dx, np.ascontiguousarray(mu_q, dtype=float), p_dofs, psi,
                            x[d.n_u :], np.ascontiguousarray(lam_q, dtype=float), float(d.pressure_scale), out_u, out_p)
    if bad:
        raise FloatingPointError(f"det F <= 0 at {int(bad)} quadrature point(s)")
    return np.concatenate([np.bincount(u_dofs.reshape(-1), weights=out_u.reshape(-1), minlength=d.n_u),
                           np.bincount(p_dofs.reshape(-1), weights=out_p.reshape(-1), minlength=d.p.N)])


_PATTERNS: dict = {}
#: residual_and_tangent(..., with_tangent=False) by the compiled kernel of fem.residual_kernels (False: the
#: numpy evaluation below, the same vector to round-off; the A/B switch)
COMPILED_RESIDUAL = True


def _csr_pattern(element_dofs: np.ndarray, n: int):
    """The CSR pattern of an element-by-element assembly over ``element_dofs`` (k, E), and each element
    entry's slot in it (the entries [e, r, c] in C order): one sort, kept per mesh, where a COO
    assembly sorts its E k^2 entries on every tangent (0.6 of the 1.2 s one took on the sensor)."""
    key = (element_dofs.shape, n, hash(element_dofs.tobytes()))
    if key not in _PATTERNS:
        dofs = element_dofs.T.astype(np.int64)  # (E, k)
        flat = (dofs[:, :, None] * n + dofs[:, None, :]).reshape(-1)
        keys, slot = np.unique(flat, return_inverse=True)  # row-major: CSR order with sorted columns
        indptr = np.zeros(n + 1, dtype=np.int64)
        np.cumsum(np.bincount(keys // n, minlength=n), out=indptr[1:])
        _PATTERNS.clear()  # one mesh at a time
        _PATTERNS[key] = (slot.astype(np.int64), (keys % n).astype(np.int32), indptr.astype(np.int32))
    return _PATTERNS[key]


def residual_and_tangent(d: Discretisation, x: np.ndarray, lam, mu, with_tangent: bool = True):
    """Internal residual (n,) and tangent (CSR) at state x = [u; p / scale] of a P2P1 discretisation.

    Raises FloatingPointError if any quadrature point has det F <= 0 (an inverted element).
    """
    if d.p is None:
        raise ValueError("the nonlinear tier uses the mixed P2P1 discretisation")
    if not with_tangent and COMPILED_RESIDUAL:
        # the residual alone (the condensed Newton's outer iterations, line searches): one fused compiled
        # loop, without scikit-fem's interpolation and the (3, 3, E, Q) temporaries (fem.residual_kernels)
        return compiled_residual(d, x, _per_qp(lam, d.u), _per_qp(mu, d.u)), None
    s = d.pressure_scale
    u, ph = x[: d.n_u], x[d.n_u :]
    prev = d.u.interpolate(u)
    F = _identity_like(prev.grad) + prev.grad
    J = det(F)
    if not np.all(J > 0):
        raise FloatingPointError(f"det F <= 0 at {int(np.sum(~(J > 0)))} quadrature point(s)")
    Finv = inv(F)
    lam_q, mu_q = _per_qp(lam, d.u), _per_qp(mu, d.u)
    p_q = np.asarray(d.p.interpolate(ph))
    kin = dict(F=F, J=J, Finv=Finv)
    r = np.concatenate([residual_u(d.u, np.asarray(mu_q), p_q, s, np.asarray(F), np.asarray(Finv)),
                        skfem.asm(_residual_p, d.p, p=p_q, lam=lam_q, s=s, **kin)])
    if not with_tangent:
        return r, None
    kuu = tangent_uu(d.u, np.asarray(mu_q), p_q, s, np.asarray(Finv))
    kup = tangent_up(d.u, d.p, s, np.asarray(Finv))
    kpp = skfem.asm(_tangent_pp, d.p, lam=_per_qp(lam, d.p), s=s)
    return r, sp.bmat([[kuu, kup], [kup.T, kpp]], format="csr")


@dataclass
class NewtonReport:
    """What a nonlinear solve did: per load increment its factor, iterations and residual history."""

    load_factors: list = field(default_factory=list)
    iterations: list = field(default_factory=list)
    residuals: list = field(default_factory=list)  # per increment: the residual norms, first to last
    cuts: int = 0

    @property
    def total_iterations(self) -> int:
        return int(sum(self.iterations))


def solve_nonlinear(
    d: Discretisation,
    lam,
    mu,
    external: Callable[[float], np.ndarray],
    fixed: np.ndarray,
    fixed_values: Callable[[float], np.ndarray] | None = None,
    increments: int = 10,
    rtol: float = 1e-8,
    max_iterations: int = 25,
    min_increment: float = 1e-4,
    case: str = "nonlinear solve",
    x0: np.ndarray | None = None,
) -> tuple[np.ndarray, NewtonReport]:
    """Ramp the load factor t from 0 to 1 and solve R_int(x) = external(t) at each increment.

    external(t) -> (n,) external force vector (zeros on the pressure rows); fixed: constrained
    DOFs with values fixed_values(t) (default 0). Each increment is solved by the full-step Newton of
    :class:`FullStepNewton` (the one Newton of the tier); it converges when the residual on the free
    DOFs falls below ``rtol`` times its value at the start of the increment (or below an absolute
    floor of 1e-14 of the load's size), or when the correction is at round-off. An increment that
    fails is halved, down to ``min_increment``; after a converged increment the next one grows by
    1.5, up to 4 / ``increments``. Returns the state and a :class:`NewtonReport`.

    Why full steps: backtracking on the residual norm (this function's line search until 2026-11-27)
    stalls where the rod rotates far: the Newton step of a bending rod stretches it by about theta^2 / 2
    before the next step removes the stretch, so the residual norm rises on a step that is right. On a
    20:1 cantilever at P L^2 / EI = 1 the backtracking Newton's residual fell 2-4 % an iteration, its
    increments were halved again and again, and it had not reached the load after 5 minutes; full steps
    converge in 6-9 iterations up to P L^2 / EI = 5 (tests/test_nonlinear_large_deflection.py).
    """
    n = d.n_dofs
    d.pressure_scale = float(np.max(mu))  # as in fem.elasticity.assemble
    x = np.zeros(n) if x0 is None else x0.copy()
    newton = FullStepNewton(d, lam, mu, np.asarray(fixed), rtol=rtol, max_iterations=max_iterations)
    report = NewtonReport()
    t, dt = 0.0, 1.0 / increments
    while t < 1.0 - 1e-12:
        t_next = min(1.0, t + dt)
        trial = x.copy()
        if fixed_values is not None:
            trial[fixed] = fixed_values(t_next)
        ok, trial, _, why = newton.solve(trial, external(t_next))
        history = newton.history
        if ok:
            x, t = trial, t_next
            report.load_factors.append(t)
            report.iterations.append(len(history) - 1)
            report.residuals.append(history)
            dt = min(dt * 1.5, 1.0 / increments * 4)
            continue
        report.cuts += 1
        dt *= 0.5
        if dt < min_increment:
            raise SolverError(
                f"{case}: Newton did not converge at load factor {t_next:.4g} (increment {dt * 2:.3g}); "
                f"residual {history[-1]:.3e} after {len(history) - 1} iterations, from {history[0]:.3e} ({why})"
            )
    if not np.all(np.isfinite(x)):
        raise SolverError(f"{case}: the solution contains NaN or Inf")
    return x, report


@dataclass
class FullStepNewton:
    """Newton's method on R_int(x) = f_ext for one load level: full steps, refusing inverted states
    (the Newton of the S2 verification, :mod:`fem.verify_s2`, for a steel block bonded to PDMS).

    :func:`solve_nonlinear` backtracks on the residual norm, which fails there from the first
    increment: the linearised step of a steel block that tilts stretches the steel by
    ~theta^2 / 2, and the steel's 77 GPa turns that into residual forces 1e3-1e5 times the load
    (measured at 50 mN on a 1 mm mesh: 0.009 N before the step, 373 N after it; the residual of a
    damped step falls only as alpha^2, so no damping passes). The full step is nevertheless
    right: with the tangent at the tilted state the next step removes the stretch and Newton
    converges quadratically (0.18, 8e-4, 2e-4, 5e-9 N). Scaling the residual row by row does not
    help (the load acts on the steel too), nor does the simplified-Newton monotonicity test (the
    tangent at the untilted state turns the stretch forces into a large PDMS correction). So: full
    steps, halved only while a trial state inverts an element (det F <= 0, as :mod:`fem.nonlinear`
    refuses). The correction does not shrink monotonically (it alternates while the stretch is
    corrected), so the increment fails only when it grows to 1e3 times its smallest value or
    after ``max_iterations``; the caller then halves the load increment. Converged when the
    displacement correction is below ``xtol`` of the displacement (then taken in full). Same
    residual and tangent as :mod:`fem.nonlinear` (:func:`fem.nonlinear.residual_and_tangent`);
    factorised by :func:`fem.linsolve.factorise` (PARDISO where present) with one step of
    iterative refinement.
    """

    d: Discretisation
    lam: object  # Lame parameters per element (as residual_and_tangent takes them)
    mu: object
    fixed: np.ndarray  # constrained DOFs (held at the start state's values)
    xtol: float = 1e-9
    max_iterations: int = 30
    min_damping: float = 1.0 / 64
    rtol: float | None = None  # also converged when the residual falls below rtol x its start value
    history: list = field(default_factory=list, init=False)  # the last solve's residual norms (free DOFs)

    def __post_init__(self):
        self.free = np.setdiff1d(np.arange(self.d.n_dofs), self.fixed)
        self.u_rows = self.free < self.d.n_u  # free rows that are displacements

    def _norm_u(self, v: np.ndarray) -> float:
        return float(np.linalg.norm(v[self.u_rows]))

    def _residual_and_tangent(self, x, added, with_tangent=True):
        r, K = residual_and_tangent(self.d, x, self.lam, self.mu, with_tangent)
        if added is None:
            return r, K
        return r + added @ x, (K + added if with_tangent else None)

    def solve(self, x: np.ndarray, f_ext: np.ndarray, added_stiffness: sp.spmatrix | None = None) -> tuple[bool, np.ndarray, int, str]:
        """(converged, state, iterations, why not) from the start state x for the load f_ext (n,).
        The residual norms on the free DOFs, first to last, are left in ``history``.

        added_stiffness: a constant matrix A (n, n) added to the body, R_int(x) + A x = f_ext (an implicit
        time step's inertia and damping, :mod:`fem.dynamics`)."""
        from fem.linsolve import factorise

        free = self.free
        x = x.copy()
        self.history = history = []
        added = added_stiffness
        try:
            r, K = self._residual_and_tangent(x, added)
        except FloatingPointError as exc:
            history.append(np.inf)
            return False, x, 0, f"start state: {exc}"
        g = (r - f_ext)[free]
        history.append(float(np.linalg.norm(g)))
        floor = 1e-14 * max(float(np.linalg.norm(f_ext[free])), 1e-300)
        smallest, ndx = np.inf, np.nan
        for it in range(1, self.max_iterations + 1):
            if history[-1] <= floor or (self.rtol is not None and history[-1] <= self.rtol * history[0]):
                return True, x, it - 1, ""
            Kf = K[free][:, free]
            try:
                lu = factorise(Kf, definite=False)
                dx = -lu.solve(g)
                dx -= lu.solve(Kf @ dx + g)  # one refinement step: the steel rows cost the factor digits
            except SolverError as exc:
                return False, x, it, f"tangent: {exc}"
            if not np.all(np.isfinite(dx)):
                return False, x, it, "the Newton step is not finite"
            ndx = self._norm_u(dx)
            if ndx <= self.xtol * self._norm_u(x[free] + dx):  # converged: the residual is at round-off
                x[free] += dx
                try:
                    r, _ = self._residual_and_tangent(x, added, with_tangent=False)
                    history.append(float(np.linalg.norm((r - f_ext)[free])))
                except FloatingPointError:
                    pass
                return True, x, it, ""
            smallest = min(smallest, ndx)
            if ndx > 1e3 * smallest:
                return False, x, it, f"the Newton correction diverges ({smallest:.3e} -> {ndx:.3e} m)"
            alpha = 1.0
            while True:
                trial = x.copy()
                trial[free] += alpha * dx
                try:
                    r, K = self._residual_and_tangent(trial, added)
                    break
                except FloatingPointError:  # an inverted element: shorten the step
                    alpha *= 0.5
                    if alpha < self.min_damping:
                        return False, x, it, f"every step down to {self.min_damping:g} of Newton's inverts an element"
            x = trial
            g = (r - f_ext)[free]
            history.append(float(np.linalg.norm(g)))
            if not np.isfinite(history[-1]):
                return False, x, it, "the residual is not finite"
        if history[-1] <= floor or (self.rtol is not None and history[-1] <= self.rtol * history[0]):
            return True, x, self.max_iterations, ""
        return False, x, self.max_iterations, f"no convergence in {self.max_iterations} iterations (last |du| = {ndx:.3e} m)"
