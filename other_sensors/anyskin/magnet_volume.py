"""The flux density of a magnetised elastomer as a finite volume: quadrature over its deformed elements (SPEC 2).

The skin's point dipoles (:mod:`other_sensors.anyskin.skin`) lump a layer into a grid. Here the
layer is a body: a structured mesh of trilinear hexahedra (n_x x n_y x n_z) over the undeformed
slab, each carrying the skin's remanent magnetisation M~ (A/m, per undeformed volume). A hard-
magnetic elastomer's moment is carried by its particles, so a material element's moment follows
the deformation gradient F = dx / dX: m = F M~ dV0 (Zhao, Kim, Yuk, Zhao, "Mechanics of hard-magnetic
soft materials", J. Mech. Phys. Solids 124, 2019, eq. 2.8: M = F M~ / J per current volume, dV =
J dV0). The field outside the body is the superposition of its elements' dipole fields,

    B(x) = sum_e sum_q w_q det(J0_q) dipole(x - x_q, F_q M~)     (tesla)

with x_q the Gauss points' deformed positions, F_q the deformation gradient there and J0_q the
reference element's Jacobian (2 x 2 x 2 Gauss-Legendre points per element; the volume integral of
Jackson's eq. 5.56 kernel, exact in the limit of fine elements for points outside the body; the error
falls as the elements shrink against their distance to the point, ``tests/test_anyskin_magnet_volume.py``).

An element that inverts (det F <= 0 at a Gauss point) is refused: a folded skin has no field.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .dipoles import dipole_field

__all__ = ["MagnetBody", "slab_body", "element_moments", "body_field", "GAUSS"]

_G = 1.0 / np.sqrt(3.0)
GAUSS = np.array([[i, j, k] for i in (-_G, _G) for j in (-_G, _G) for k in (-_G, _G)])  # (8, 3), unit weights
# trilinear hexahedron: node a at (xi_a, eta_a, zeta_a) in {-1, 1}^3, ordered like GAUSS's signs
_CORNERS = np.array([[i, j, k] for i in (-1, 1) for j in (-1, 1) for k in (-1, 1)], dtype=float)  # (8, 3)


def _shape(points):
    """N (Q, 8) and dN/dxi (Q, 8, 3) of the trilinear hexahedron at reference points (Q, 3)."""
    p = np.asarray(points, dtype=float)
    f = 1.0 + p[:, None, :] * _CORNERS[None]  # (Q, 8, 3)
    n = f.prod(axis=-1) / 8.0
    dn = np.stack([_CORNERS[None, :, 0] * f[..., 1] * f[..., 2], f[..., 0] * _CORNERS[None, :, 1] * f[..., 2],
                   f[..., 0] * f[..., 1] * _CORNERS[None, :, 2]], axis=-1) / 8.0
    return n, dn


@dataclass(frozen=True)
class MagnetBody:
    """A magnetised body: nodes (V, 3) m undeformed, hexahedra (E, 8) node indices (ordered as the
    reference cube's corners, ``_CORNERS``), magnetisation (3,) A/m per undeformed volume."""

    nodes: np.ndarray
    elements: np.ndarray
    magnetisation: np.ndarray

    @property
    def volume(self) -> float:
        """The undeformed volume (m^3) by the same quadrature."""
        _, dn = _shape(GAUSS)
        j0 = np.einsum("eai,qaj->eqij", self.nodes[self.elements], dn)
        return float(np.linalg.det(j0).sum())


def slab_body(side_x_m: float, side_y_m: float, thickness_m: float, base_z_m: float, divisions: tuple[int, int, int],
              magnetisation_a_m) -> MagnetBody:
    """A slab [-sx/2, sx/2] x [-sy/2, sy/2] x [base, base + t] cut into divisions (nx, ny, nz) hexahedra."""
    nx, ny, nz = divisions
    if min(nx, ny, nz) < 1 or not (side_x_m > 0 and side_y_m > 0 and thickness_m > 0):
        raise ValueError(f"magnet body: sides {side_x_m}, {side_y_m}, thickness {thickness_m} m and divisions {divisions} must be > 0")
    xs = np.linspace(-side_x_m / 2, side_x_m / 2, nx + 1)
    ys = np.linspace(-side_y_m / 2, side_y_m / 2, ny + 1)
    zs = np.linspace(base_z_m, base_z_m + thickness_m, nz + 1)
    nodes = np.stack(np.meshgrid(xs, ys, zs, indexing="ij"), axis=-1).reshape(-1, 3)

    def index(i, j, k):
        return (i * (ny + 1) + j) * (nz + 1) + k

    i, j, k = (a.ravel() for a in np.meshgrid(np.arange(nx), np.arange(ny), np.arange(nz), indexing="ij"))
    elements = np.stack([index(i + a, j + b, k + c) for a, b, c in _CORNERS.astype(int).clip(0)], axis=1)
    return MagnetBody(nodes, elements, np.broadcast_to(np.asarray(magnetisation_a_m, dtype=float), (3,)).copy())


def element_moments(body: MagnetBody, deformed_nodes=None):
    """Each Gauss point's deformed position (..., E * 8, 3) m and moment F M~ dV0 (..., E * 8, 3) A m^2.

    deformed_nodes: (..., V, 3) m (leading axes: a batch of deformations, e.g. time samples), None for
    the undeformed body. Raises ValueError where an element inverts (det F <= 0 at a Gauss point)."""
    x = body.nodes if deformed_nodes is None else np.asarray(deformed_nodes, dtype=float)
    if x.shape[-2:] != body.nodes.shape or not np.isfinite(x).all():
        raise ValueError(f"magnet body: deformed nodes must be finite and shaped (..., {len(body.nodes)}, 3); got {x.shape}")
    n, dn = _shape(GAUSS)
    ref, cur = body.nodes[body.elements], x[..., body.elements, :]  # (E, 8, 3), (..., E, 8, 3)
    j0 = np.einsum("eai,qaj->eqij", ref, dn)  # dX/dxi (E, Q, 3, 3)
    j = np.einsum("...eai,qaj->...eqij", cur, dn)  # dx/dxi
    f = j @ np.linalg.inv(j0)  # dx/dX
    det_f = np.linalg.det(f)
    if np.any(det_f <= 0):
        bad = int(np.argmax(np.any(det_f <= 0, axis=-1).reshape(-1, len(body.elements)).any(axis=0)))
        raise ValueError(f"sensor.skin: the magnet volume inverts (det F = {det_f.min():.3g} <= 0 in element {bad}); "
                         "a smaller load or a wider contact keeps the skin from folding")
    dv0 = np.linalg.det(j0)  # unit Gauss weights
    moments = (f @ body.magnetisation) * dv0[..., None]
    positions = np.einsum("qa,...eai->...eqi", n, cur)
    lead = x.shape[:-2]
    return positions.reshape(lead + (-1, 3)), moments.reshape(lead + (-1, 3))


def body_field(body: MagnetBody, points, deformed_nodes=None) -> np.ndarray:
    """Flux density B (P, 3) tesla of the (deformed) body at points (P, 3) m outside it."""
    positions, moments = element_moments(body, deformed_nodes)
    return dipole_field(np.asarray(points, dtype=float), positions, moments)
