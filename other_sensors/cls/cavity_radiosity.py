"""The CLS cavity's diffuse light: two-surface radiosity between the base and the shell (issue 43).

The LED's light that does not reach the LTV directly strikes the base (the LED faces down), and
what the base reflects lights the shell's inner surface, which lights the LTV. Both surfaces are
Lambertian (reflectances rho_base, rho_shell), the cavity's sides are open (what leaves is lost),
and the LTV, lying in the base, sees the shell only. The radiosity equations of two diffuse surfaces
with non-uniform radiosity (Siegel & Howell, *Thermal Radiation Heat Transfer*, 4th ed., 2002, ch. 6,
the integral equations of exchange among diffuse surfaces; Modest, *Radiative Heat Transfer*, 3rd ed.,
2013, ch. 5) are, per unit I0,

    B_b(x) = rho_b [E_0(x) + int_shell B_s(y) K(x, y) dA_y],    B_s(y) = rho_s int_base B_b(x) K(x, y) dA_x,
    E_ltv  = int_shell B_s(y) K(y, ltv) dA_y,                   K(x, y) = cos(t_x) cos(t_y) / (pi |x - y|^2),

K the kernel of the view factor between two surface elements (Modest ch. 4), E_0 the LED's
irradiance on the base (I(theta) = cos^m(theta), Moreno & Sun 2008, eq. 1;
:func:`other_sensors.cls.optics.direct_irradiance`).
They are solved by Nystrom quadrature: a composite two-point Gauss-Legendre rule on each rectangle
(the base's and the shell's footprint, the shell at its pose: tilted, shifted, compressed), the
bounce series summed until it stops changing (each round trip multiplies by about rho_b rho_s F^2 < 0.03).
The two planes face each other over the whole footprint at every pose the shell reaches, so every
node sees every other (no occlusion test). The foam pillars are not surfaces of this cavity: the
layout puts them on the pairs' line, where the LTVs are (:mod:`other_sensors.cls.optics_render`).

Against Mitsuba's path tracer over the same cavity (:mod:`other_sensors.cls.optics_render`, 2^20
samples, ten poses from an 18 to a 50 mm gap, shifts to 6 mm, tilts to 6 deg, five pairs), this
term is within 0.7 % of the rendered light (docs/uses/sibling-sensors.md; ``tests/test_cls_optics_render.py``
holds 1.5 %). The uniform-cavity formula it replaces (Goebel 1967) was 0.7-8.6x the rendered
light at those poses: it let the base's first bounce reach the LTV, and it grew 35 % from a 40 to a 22 mm gap
against the rendered 350-420 %.

Many poses (a trajectory's thousands) are interpolated, trilinearly in (y, z, rx), on a grid over
their bounding box (:func:`diffuse_irradiance_table`); the light's logarithm varies smoothly over
tens of mm and degrees, so 3 mm and 1.5 deg cells leave under 0.3 % of it (measured in the tests).

Lengths mm, angles rad, irradiance per unit LED intensity I0 (1/mm^2).
"""

from __future__ import annotations

import numpy as np

from other_sensors.cls.ltv import PairLayout, planar_to_pose, quat_to_matrix

__all__ = ["rectangle_rule", "diffuse_irradiance", "diffuse_irradiance_table"]

#: Gauss-Legendre panels along the length (y) and width (x): 10 mm square panels, two nodes each way,
#: within 0.3 % of four times as many each way down to an 18 mm gap (tests/test_cls_cavity_radiosity.py)
PANELS = (13, 5)
#: the bounce series stops when a bounce adds under this fraction of the sum
SERIES_RTOL = 1e-6
#: the table's cells (y mm, z mm, rx rad)
CELL = (3.0, 3.0, np.radians(1.5))


def rectangle_rule(length_mm: float, width_mm: float, panels=PANELS):
    """Nodes (N, 2) = (x, y) mm, centred, and weights (N,) mm^2 of a composite two-point
    Gauss-Legendre rule on a ``width_mm`` (x) by ``length_mm`` (y) rectangle; N = 4 panels[0] panels[1]."""
    g = np.array([-1.0, 1.0]) / np.sqrt(3.0)

    def axis(size, n):
        edges = np.linspace(-size / 2.0, size / 2.0, n + 1)
        mid, half = (edges[1:] + edges[:-1]) / 2.0, (edges[1:] - edges[:-1]) / 2.0
        return (mid[:, None] + half[:, None] * g).ravel(), np.repeat(half, 2)

    y, wy = axis(length_mm, panels[0])
    x, wx = axis(width_mm, panels[1])
    X, Y = np.meshgrid(x, y)
    return np.stack([X.ravel(), Y.ravel()], axis=1), np.outer(wy, wx).ravel()


def _kernel(a, na, b, nb):
    """K (..., Na, Nb) between points a (..., Na, 3) facing na (..., 3) and b (..., Nb, 3) facing nb (..., 3)."""
    d = b[..., None, :, :] - a[..., :, None, :]
    d2 = np.einsum("...k,...k->...", d, d)
    ca = np.einsum("...abk,...k->...ab", d, na)
    cb = -np.einsum("...abk,...k->...ab", d, nb)
    return np.maximum(ca, 0.0) * np.maximum(cb, 0.0) / (np.pi * d2 * d2)


def diffuse_irradiance(pose3, layout: PairLayout, length_mm: float, width_mm: float, rho_base: float, rho_shell: float,
                       m: float, panels=PANELS) -> np.ndarray:
    """The diffuse irradiance per unit I0 (1/mm^2) at each LTV, each lit by its own pair's LED:
    (..., P) for planar poses (..., 3) = (y mm, z mm, rx rad) of the shell over the base.

    length_mm, width_mm: the base's and the shell's footprint (y, x), both centred on their frame's
    origin. m: the LED's Lambertian order (:func:`other_sensors.cls.optics.lambert_order`).
    LTVs whose axis is off +z keep the shell's light by their own cosine (they see the base too
    only when tilted, by its tiny projected share, neglected).
    """
    pose3 = np.asarray(pose3, float)
    shape = pose3.shape[:-1]
    pose3 = pose3.reshape(-1, 3)
    nodes, w = rectangle_rule(length_mm, width_mm, panels)
    base = np.c_[nodes, np.zeros(len(nodes))]
    up = np.array([0.0, 0.0, 1.0])
    p, q = planar_to_pose(pose3)
    R = quat_to_matrix(q)  # (K, 3, 3)
    shell = p[:, None, :] + np.einsum("kij,nj->kni", R, base)  # (K, N, 3)
    down = -R[:, :, 2]  # the shell's inner surface faces the base
    G = _kernel(np.broadcast_to(base, shell.shape), np.broadcast_to(up, down.shape), shell, down)  # (K, Nb, Ns)
    led = p[:, None, :] + np.einsum("kij,pj->kpi", R, layout.led_pos)  # (K, P, 3)
    axis = np.einsum("kij,pj->kpi", R, layout.led_axis)
    to_base = base[None, None] - led[:, :, None, :]  # (K, P, N, 3)
    r2 = np.einsum("...k,...k->...", to_base, to_base)
    ct = np.einsum("kpnj,kpj->kpn", to_base, axis) / np.sqrt(r2)
    cp = -to_base[..., 2] / np.sqrt(r2)
    e0 = np.maximum(ct, 0.0) ** m * np.maximum(cp, 0.0) / r2  # (K, P, Nb)
    to_ltv = layout.ltv_pos[None, :, None, :] - shell[:, None, :, :]  # (K, P, Ns, 3)
    d2 = np.einsum("...k,...k->...", to_ltv, to_ltv)
    cs = np.einsum("kpnj,kj->kpn", to_ltv, down)
    cl = -np.einsum("kpnj,pj->kpn", to_ltv, layout.ltv_axis)
    view = np.maximum(cs, 0.0) * np.maximum(cl, 0.0) / (np.pi * d2 * d2)  # (K, P, Ns)
    bb = rho_base * e0  # the base's radiosity, first bounce
    bs = np.zeros_like(view)
    while True:
        step = rho_shell * np.einsum("kpb,kbs->kps", bb * w, G)  # the shell's radiosity from this bounce
        bs = bs + step
        if np.all(np.abs(step) <= SERIES_RTOL * np.abs(bs)):
            break
        bb = rho_base * np.einsum("kps,kbs->kpb", step * w, G)
    return np.einsum("kps,kps->kp", bs * w, view).reshape(shape + (layout.n_pairs,))


def diffuse_irradiance_table(pose3, layout: PairLayout, length_mm: float, width_mm: float, rho_base: float,
                             rho_shell: float, m: float, cell=CELL, chunk: int = 16) -> np.ndarray:
    """:func:`diffuse_irradiance` at many poses (..., 3): evaluated on a grid of ``cell`` (y mm, z mm,
    rx rad) over the poses' bounding box and interpolated trilinearly (module docstring), or at the
    poses themselves where they are fewer than the grid's nodes. (..., P)."""
    from scipy.interpolate import RegularGridInterpolator

    pose3 = np.asarray(pose3, float)
    flat = pose3.reshape(-1, 3)
    if not np.all(np.isfinite(flat)):
        raise ValueError("diffuse_irradiance_table: the poses hold NaN or Inf")
    axes = []
    for k in range(3):
        lo, hi = flat[:, k].min(), flat[:, k].max()
        n = max(int(np.ceil((hi - lo) / cell[k] - 1e-9)), 1)
        axes.append(np.linspace(lo, lo + n * cell[k], n + 1))
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    at = flat if len(flat) <= len(grid) else grid
    values = np.concatenate([diffuse_irradiance(at[i:i + chunk], layout, length_mm, width_mm, rho_base, rho_shell, m)
                             for i in range(0, len(at), chunk)])
    if at is flat:
        return values.reshape(pose3.shape[:-1] + (layout.n_pairs,))
    # its logarithm, nearly linear in the gap (the light falls off as a power of it): a tenth of the linear table's error
    values = np.log(values.reshape(tuple(len(a) for a in axes) + (layout.n_pairs,)))
    return np.exp(RegularGridInterpolator(axes, values)(flat)).reshape(pose3.shape[:-1] + (layout.n_pairs,))
