"""One AnySkin sensor's skin as a finite magnetised volume over a thin hyperelastic layer (SPEC 2's richer truth).

The estimator knows nothing of this model; it is the world the helmet's chips measure when
``sensor.skin.truth = "magnet_volume"`` (:mod:`other_sensors.anyskin.truth`). Compared with the
point-dipole skin (:mod:`other_sensors.anyskin.skin`): the skin is a body whose moments follow the
deformation gradient (m = F M~ dV0, :mod:`other_sensors.anyskin.magnet_volume`: they tilt under shear
and shrink with the compressed volume), and the contact law is the thin incompressible neo-Hookean
layer (:mod:`other_sensors.anyskin.thin_layer`: the stretch lambda from mu l^3 + p l^2 - mu = 0,
simple shear gamma = tau / mu, mu = E / 3), without the point-dipole path's tanh strain saturation.

Kinematics: the thin layer's columns deform independently (its Winkler assumption, Johnson 1985,
sec. 5.9), so the body is an n x n grid of columns, each one hexahedron of the slab (cut s x s in plane
for the quadrature) deformed homogeneously by F = [[1, 0, h_x], [0, 1, h_y], [0, 0, 1 + h_z]] with
h = (gamma_x, gamma_y, lambda - 1) at the column's centre: a point at height zeta over the base moves
by zeta h. The contact force F (N, sensor frame; F_z < 0 presses) spreads as the point-dipole path's
Gaussian patch of radius a, tau = F exp(-r^2 / 2 a^2) / (2 pi a^2). The skin's permanent set
(:func:`.skin.permanent_set`) acts on h (the set of zeta h is zeta times the set of h: the rule is
homogeneous of degree 1); an elastic compression plus a set that reach the whole thickness
(1 + h_z <= 0) invert the column and are refused (``sensor.skin``: :func:`.magnet_volume.element_moments`).

Field: B = B_prism + sum_c [f_c(h_c) - f_c(0)], with B_prism the rest slab's closed form
(:mod:`.prism_field`, exact) and f_c (5 chips x 3) the field of column c by Gauss-point dipoles; the
quadrature's own error at rest (24 % at the centre chip for 14 x 14 columns of 2 x 2 x 2 points)
cancels in the difference. Because each f_c depends on its own h_c only, it is tabulated once per run
on a TABLE_NODES^3 grid over the run's range of h and interpolated trilinearly per sample (an
evaluation per sample and Gauss point costs minutes per run; the table's error against the direct sum
is checked in ``tests/test_anyskin_truth.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .magnet_volume import element_moments, slab_body
from .prism_field import prism_field
from .thin_layer import compressive_stretch

__all__ = ["VolumeSkin", "volume_skin", "column_strains", "column_fields", "volume_field", "dipole_sum", "T_TO_UT",
           "TABLE_NODES", "COLUMN_CUTS"]

T_TO_UT = 1e6
TABLE_NODES = 9  # per axis of h: the trilinear table is within ~0.1 % of the direct sum (tests)
COLUMN_CUTS = 2  # each column's hexahedron cut 2 x 2 in plane: 32 Gauss points per column


@dataclass(frozen=True)
class VolumeSkin:
    """column (a MagnetBody: one column at the origin, base at z = gap); centres (N, 2) m the columns'
    (x, y); magnetometers (5, 3) m; gap, thickness m; shear_modulus Pa; radius m (the patch's);
    rest_ut (5, 3) uT, the slab's exact rest field."""

    column: object
    centres: np.ndarray
    magnetometers: np.ndarray
    gap: float
    thickness: float
    shear_modulus: float
    radius: float
    rest_ut: np.ndarray


def dipole_sum(points, positions, moments) -> np.ndarray:
    """Flux density (T, P, 3) tesla at points (P, 3) m of T sets of Q point dipoles, positions and
    moments (T, Q, 3) (Jackson eq. 5.56, summed; the same as :func:`.dipoles.dipole_field`, written per
    component so that the (T, Q) temporaries are the largest arrays)."""
    from .dipoles import MU0

    out = np.empty((positions.shape[0], len(points), 3))
    mx, my, mz = moments[..., 0], moments[..., 1], moments[..., 2]
    for k, c in enumerate(np.asarray(points, dtype=float)):
        rx, ry, rz = c[0] - positions[..., 0], c[1] - positions[..., 1], c[2] - positions[..., 2]
        inv2 = 1.0 / (rx * rx + ry * ry + rz * rz)
        inv3 = inv2 * np.sqrt(inv2)
        k3 = 3.0 * (mx * rx + my * ry + mz * rz) * inv2
        out[:, k, 0] = ((k3 * rx - mx) * inv3).sum(axis=-1)
        out[:, k, 1] = ((k3 * ry - my) * inv3).sum(axis=-1)
        out[:, k, 2] = ((k3 * rz - mz) * inv3).sum(axis=-1)
    return MU0 / (4.0 * np.pi) * out


def volume_skin(side_m: float, thickness_m: float, gap_m: float, columns: int, magnetisation_a_m: float,
                magnetometer_pitch_m: float, modulus_pa: float, contact_radius_m: float, cuts: int = COLUMN_CUTS) -> VolumeSkin:
    """The slab magnetised along +z over the chip cross, as columns x columns columns; see the module docstring.

    modulus_pa: Young's modulus E (mu = E / 3, incompressible)."""
    cell = side_m / columns
    column = slab_body(cell, cell, thickness_m, gap_m, (cuts, cuts, 1), (0.0, 0.0, magnetisation_a_m))
    c = (np.arange(columns) + 0.5) * cell - side_m / 2
    centres = np.stack(np.meshgrid(c, c, indexing="ij"), axis=-1).reshape(-1, 2)
    p = magnetometer_pitch_m
    mags = np.array([[0, 0, 0], [p, 0, 0], [-p, 0, 0], [0, p, 0], [0, -p, 0]], dtype=float)
    rest = T_TO_UT * prism_field(mags, [-side_m / 2, -side_m / 2, gap_m], [side_m / 2, side_m / 2, gap_m + thickness_m],
                                 (0.0, 0.0, magnetisation_a_m))
    return VolumeSkin(column, centres, mags, gap_m, thickness_m, modulus_pa / 3.0, contact_radius_m, rest)


def column_strains(skin: VolumeSkin, force_n) -> np.ndarray:
    """h (T, N, 3) per column under the contact forces (T, 3) N: (tau_x / mu, tau_y / mu, lambda - 1)
    where the force presses (F_z < 0), 0 elsewhere."""
    force = np.atleast_2d(np.asarray(force_n, dtype=float))
    a = skin.radius
    weight = np.exp(-(skin.centres**2).sum(axis=1) / (2 * a * a)) / (2 * np.pi * a * a)  # (N,) 1/m^2
    traction = force[:, None, :] * weight[None, :, None]  # (T, N, 3) Pa
    pressing = force[:, 2] < 0
    lam = compressive_stretch(np.where(pressing[:, None], -traction[..., 2], 0.0), skin.shear_modulus)
    shear = np.where(pressing[:, None, None], traction[..., :2] / skin.shear_modulus, 0.0)
    return np.concatenate([shear, (lam - 1.0)[..., None]], axis=-1)


def column_fields(skin: VolumeSkin, strains, at=None, chunk: int = 16) -> np.ndarray:
    """f_c(h) by each column's Gauss points, tesla: (G, N, 5, 3) for G strains h (G, 3) at every column,
    or (G, 5, 3) with ``at`` (G,) the column of each strain.

    Raises ValueError (naming ``sensor.skin``) where a strain inverts the column (1 + h_z <= 0)."""
    h = np.atleast_2d(np.asarray(strains, dtype=float))
    base = skin.column.nodes
    nodes = base[None] + (base[None, :, 2:3] - skin.gap) * h[:, None, :]  # (G, V, 3): zeta h
    positions, moments = element_moments(skin.column, nodes)  # (G, q, 3)
    shift = np.concatenate([skin.centres, np.zeros((len(skin.centres), 1))], axis=1)  # (N, 3)
    if at is not None:
        return dipole_sum(skin.magnetometers, positions + shift[np.asarray(at)][:, None], moments)
    out = np.empty((len(h), len(skin.centres), 5, 3))
    for lo in range(0, len(h), chunk):
        pos = positions[lo:lo + chunk, None] + shift[None, :, None]  # (g, N, q, 3)
        mom = np.broadcast_to(moments[lo:lo + chunk, None], pos.shape)
        g = pos.shape[0]
        out[lo:lo + g] = dipole_sum(skin.magnetometers, pos.reshape(g * len(shift), -1, 3),
                                    mom.reshape(g * len(shift), -1, 3)).reshape(g, len(shift), 5, 3)
    return out


def _grid(lo, hi, nodes):
    """Axes (3, G) spanning [lo, hi] per component; a flat component (lo == hi) gets a unit-free width."""
    width = np.maximum(hi - lo, 1e-9)
    return np.linspace(lo, lo + width, nodes, axis=1)


def volume_field(skin: VolumeSkin, strains=None, nodes: int = TABLE_NODES, direct: bool | None = None) -> np.ndarray:
    """The chips' flux density, uT: (5, 3) at rest (strains None), else (T, 5, 3) for column strains h (T, N, 3).

    direct: True sums each sample's Gauss points, False interpolates the table, None (default) takes
    the direct sum when fewer samples move than the table has nodes (it is then the cheaper). Raises ValueError (naming
    ``sensor.skin``) where a column inverts."""
    if strains is None:
        return skin.rest_ut.copy()
    h = np.asarray(strains, dtype=float)
    n_t, n_c = h.shape[:2]
    out = np.broadcast_to(skin.rest_ut, (n_t, 5, 3)).copy()
    moved = np.flatnonzero(np.abs(h).reshape(n_t, -1).max(axis=1) > 0)
    if moved.size == 0:
        return out
    rest = column_fields(skin, np.zeros(3))[0]  # (N, 5, 3) f_c(0)
    cols = np.arange(n_c)
    if direct or (direct is None and len(moved) <= nodes**3):
        for a in range(0, len(moved), 16):
            idx = moved[a:a + 16]
            f = column_fields(skin, h[idx].reshape(-1, 3), at=np.tile(cols, len(idx))).reshape(len(idx), n_c, 5, 3)
            out[idx] += T_TO_UT * (f - rest[None]).sum(axis=1)
        return out
    hm = h[moved]
    lo, hi = hm.min(axis=(0, 1)), hm.max(axis=(0, 1))
    axes = _grid(lo, hi, nodes)  # (3, G)
    mesh = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    table = (column_fields(skin, mesh) - rest[None]).reshape(nodes ** 3 * n_c, 15)  # flat index (node, column)
    step = (axes[:, -1] - axes[:, 0]) / (nodes - 1)
    for a in range(0, len(moved), 512):
        x = (hm[a:a + 512] - axes[:, 0]) / step  # (t, N, 3) grid coordinates
        i = np.clip(np.floor(x).astype(int), 0, nodes - 2)
        w = np.clip(x - i, 0.0, 1.0)
        acc = np.zeros(x.shape[:2] + (15,))
        for corner in range(8):
            d = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
            flat = (((i[..., 0] + d[0]) * nodes + i[..., 1] + d[1]) * nodes + i[..., 2] + d[2]) * n_c + cols
            weight = np.prod(np.where(d == 1, w, 1.0 - w), axis=-1)
            acc += weight[..., None] * table[flat]
        out[moved[a:a + 512]] += T_TO_UT * acc.sum(axis=1).reshape(-1, 5, 3)
    return out
