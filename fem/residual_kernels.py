"""The mixed neo-Hookean residual of :mod:`fem.nonlinear`, fused and compiled.

The nonlinear tier's condensed Newton (:meth:`fem.finite_strain._Problem.condensed_step`) evaluates
the internal residual R(x) once or more per outer iteration and never its tangent; on the swipe over
10.5 mm rods (455 contact points, the full sensor) that residual was 35 % of each step, mostly
scikit-fem's interpolation of grad u at the quadrature points and the (3, 3, E, Q) temporaries of
the numpy evaluation (``fem.nonlinear.residual_u``). Here one loop over the elements and their
quadrature points forms F = I + grad u, J, F^-1 and the first Piola stress
P = mu (F - F^-T) + s p F^-T (Bonet and Wood 2008, sec. 8.6; the module docstring of
:mod:`fem.nonlinear`), and integrates

    R_u(e, i, a) = sum_q P_ak (grad phi_i)_k dx_q,        R_p(e, k) = sum_q s psi_k (ln J - s p / lambda) dx_q

per element; the discretisation's arrays and the scatter to the global vector (a :func:`numpy.bincount`,
ordered, so the sum does not depend on the thread count) are :func:`fem.nonlinear.compiled_residual`'s.
Same numbers as the numpy evaluation (tested to round-off).
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True)
def element_residuals(u, u_dofs, grads, dx, mu, p_dofs, psi, ph, lam, s, out_u, out_p):
    """The element residuals of the mixed neo-Hookean solid; returns the number of quadrature points
    with det F <= 0 (the caller refuses the state: an inverted element).

    u (N,) displacements; u_dofs (E, nb, 3) global index of the local function 3 i + a; grads
    (E, Q, nb, 3) the scalar functions' gradients; dx (E, Q) quadrature weights times det of the
    mapping; mu, lam (E, Q) Pa; p_dofs (E, np) pressure dofs; psi (E, Q, np) the pressure functions'
    values; ph (Np,) the scaled pressure unknowns; s the pressure scale. Writes out_u (E, nb, 3) and
    out_p (E, np).
    """
    E, Q, nb, _ = grads.shape
    npf = p_dofs.shape[1]
    bad = np.zeros(E, dtype=np.int64)
    for e in prange(E):
        for i in range(nb):
            for a in range(3):
                out_u[e, i, a] = 0.0
        for k in range(npf):
            out_p[e, k] = 0.0
        for q in range(Q):
            # F = I + grad u, grad u[a, k] = sum_i u[dof(i, a)] dphi_i/dx_k
            F = np.zeros((3, 3))
            for i in range(nb):
                for a in range(3):
                    ua = u[u_dofs[e, i, a]]
                    for k in range(3):
                        F[a, k] += ua * grads[e, q, i, k]
            for a in range(3):
                F[a, a] += 1.0
            c00 = F[1, 1] * F[2, 2] - F[1, 2] * F[2, 1]
            c01 = F[1, 2] * F[2, 0] - F[1, 0] * F[2, 2]
            c02 = F[1, 0] * F[2, 1] - F[1, 1] * F[2, 0]
            J = F[0, 0] * c00 + F[0, 1] * c01 + F[0, 2] * c02
            if not J > 0.0:
                bad[e] += 1
                continue
            # F^-T = cofactor(F) / J
            FiT = np.empty((3, 3))
            FiT[0, 0], FiT[0, 1], FiT[0, 2] = c00 / J, c01 / J, c02 / J
            FiT[1, 0] = (F[0, 2] * F[2, 1] - F[0, 1] * F[2, 2]) / J
            FiT[1, 1] = (F[0, 0] * F[2, 2] - F[0, 2] * F[2, 0]) / J
            FiT[1, 2] = (F[0, 1] * F[2, 0] - F[0, 0] * F[2, 1]) / J
            FiT[2, 0] = (F[0, 1] * F[1, 2] - F[0, 2] * F[1, 1]) / J
            FiT[2, 1] = (F[0, 2] * F[1, 0] - F[0, 0] * F[1, 2]) / J
            FiT[2, 2] = (F[0, 0] * F[1, 1] - F[0, 1] * F[1, 0]) / J
            pq = 0.0
            for k in range(npf):
                pq += psi[e, q, k] * ph[p_dofs[e, k]]
            w = dx[e, q]
            m = mu[e, q]
            for a in range(3):
                for k in range(3):
                    P = (m * (F[a, k] - FiT[a, k]) + s * pq * FiT[a, k]) * w
                    for i in range(nb):
                        out_u[e, i, a] += P * grads[e, q, i, k]
            rp = s * (np.log(J) - s * pq / lam[e, q]) * w
            for k in range(npf):
                out_p[e, k] += rp * psi[e, q, k]
    return bad.sum()
