"""Small sheets for the render tests (mlsim.render.reprojection, mlsim.render.direct_raster): a 2 x 2
rod sheet seen by a low-resolution camera, a rod bent as a beam, and block sums of images."""

from __future__ import annotations

import numpy as np

from fem.geometry import RodArray, emitting_surface
from mlsim.render import View
from mlsim.render.sensor_scene import SensorScene


def small_sheet(px=48):
    """(rod array, vertices (N, 3) m, faces (K, 3), SensorScene) of a 2 x 2 rod sheet at px x px pixels."""
    g = RodArray(rows=2, cols=2, pitch_x_m=7.2e-3, pitch_y_m=7.2e-3, rod_radius_m=2.5e-3, rod_height_m=9e-3, base_thickness_m=2e-3,
                 absorber_m=0.3e-3, ml_m=0.5e-3)
    s = emitting_surface(g, 24, 1.5e-3)
    V, F = np.asarray(s.vertices), np.asarray(s.faces)
    view = View(width_px=px, height_px=px, lens_below_base_m=0.043, image_distance_m=0.0023068 * 2.4, pixel_pitch_m=5.8e-6 * 350 / px)
    return g, V, F, SensorScene(V, F, view, base_half_size_m=7.2e-3, reflectance=0.5)


def blocks(img, n=2):
    """(..., H, W) -> (..., n * n) sums over an n x n grid of blocks (n = 2: the four rods' quadrants)."""
    h = img.shape[-1] // n
    return img[..., : n * h, : n * h].reshape(img.shape[:-2] + (n, h, n, h)).sum(axis=(-1, -3)).reshape(img.shape[:-2] + (n * n,))


def bent(g, V, tip_m=1.5e-3, rod=0, axis=0):
    """Rod ``rod`` bent along ``axis`` as a beam clamped at the base and guided at the tip (its tip moved by tip_m)."""
    base = g.base_thickness_m
    on = (g.rod_of(V) == rod) & (V[:, 2] > base)
    h = np.clip((V[on, 2] - base) / g.rod_height_m, 0.0, 1.0)
    out = V.copy()
    out[on, axis] += tip_m * (3 * h**2 - 2 * h**3)
    return out
