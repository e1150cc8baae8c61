"""The direct light of the deformed sheet, rasterised: the camera's primary rays without ray tracing.

The direct light (camera -> acrylic -> core -> sheet, no bounce on the sheet) is most of what the
camera sees and what the rods' bending moves across the image (:mod:`mlsim.render.reprojection`).
Its primary rays cross two flat, parallel interfaces that never move (the acrylic's and the core's
bottom faces), so the ray through each sample of the image is the same every frame; only where it
first meets the sheet changes. Two consequences make the first hits cheap:

- **Projection.** A point of the sheet at radius rho from the lens axis and height z above the
  core's bottom is seen along the one air ray whose refracted path reaches it:
  ``(L - a) tan t0 + a tan t1 + z tan t2 = rho`` with ``sin t0 = n_a sin t1 = n_c sin t2``
  (Snell at both faces; L: lens to the core's bottom, a: the acrylic's thickness). That is solved
  once, by Newton's method, on a grid of (rho^2, z), and each frame's vertices are placed in the
  image by bilinear interpolation in it (:func:`tangent_table`; 0.0002 px from the exact root on
  the default view). The pixel of an air ray is Mitsuba's camera's, fitted once (affine in the
  ray's tangents; residual 1e-5 px).
- **Visibility.** The sheet is the boundary of the clear core, and a ray inside the core leaves it
  at its first hit, so every first hit is on a face seen from inside the core: faces seen from
  behind are culled, and among the rest the nearest along the ray wins. Along one ray inside the
  core the height z grows, so the nearest is the lowest: a z-buffer.

Each frame is then a software rasteriser (:func:`mlsim.render.kernels.rasterise_direct`) over
``per_side`` x ``per_side`` samples per pixel: the per-vertex radiance, interpolated with the
image-space barycentric weights of the triangle the sample falls in, times the sample's
throughput, the camera's importance times the two interfaces' Fresnel transmittance (traced once
by Mitsuba, :func:`sample_throughput`). Simplification: barycentric weights in the image rather
than on the sheet; the projection is smooth over a triangle (edges of 1 mm at 40 mm), and the
images agree with Mitsuba's own primary rays (:func:`mlsim.render.reprojection.primary_samples`)
within 0.2 % per rod at the same samples, at rest and with a rod bent 2.5 mm
(``tests/test_render_direct_raster.py``).

Samples per pixel, against Mitsuba's 3 x 3 primary rays on the default demo's pressed and slid
frames (frames 9 and 16), and the rasteriser's cost on the demo's 14 lit frames (2 cores, frames in
parallel):

| per_side | per rod | per pixel (sum of |difference|) | ms per frame |
|---|---|---|---|
| 1 (default) | 0.08-0.25 % | 1.6-3.2 % | 2.3-2.8 |
| 2 | 0.05-0.10 % | 0.4-0.8 % | 3.3-4.0 |
| 3 | 0.015-0.06 % | 0.03-0.11 % | about 5-6 |

The per-pixel error at 1 is the edges' aliasing (point samples at the pixel centres instead of
the pixel's mean); against the spectral path reference every count gives the tier the same
0.8 % per rod (``mlsim accuracy scenes/mavig_default.toml --stage render``).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from mlsim.errors import require_finite
from mlsim.render.transport import RADIANCE_FIX

__all__ = ["DirectRaster", "direct_raster", "tangent_table", "sample_throughput"]

_VERTICES_WHAT = "vertices_m (..., 3) of the sheet to rasterise"
_VERTICES_FIX = "the deformed sheet comes from the solve's displacement: check the solve stage (solve_forces.csv) or the vertices passed in"


def tangent_table(lens_mm: float, acrylic_mm: float, acrylic_ior: float, core_ior: float, rho_max_mm: float, z_max_mm: float,
                  n_r: int = 2048, n_z: int = 256) -> tuple[np.ndarray, float, float]:
    """(q (n_r, n_z), rho^2 step mm^2, z step mm): q = tan(t0) / rho of the air ray that reaches the
    point at radius rho and height z above the core's bottom (module docstring), on a regular grid
    in rho^2 over [0, rho_max^2] and z over [0, z_max]. At rho = 0, the paraxial limit."""
    if not (lens_mm > acrylic_mm >= 0 and acrylic_ior >= 1 and core_ior >= 1 and rho_max_mm > 0 and z_max_mm > 0):
        raise ValueError(f"tangent_table: lens {lens_mm} mm, acrylic {acrylic_mm} mm (n = {acrylic_ior}), core n = {core_ior}, "
                         f"rho_max {rho_max_mm} mm, z_max {z_max_mm} mm: need lens > acrylic >= 0, indices >= 1, ranges > 0")
    r2 = np.linspace(0.0, rho_max_mm ** 2, n_r)
    z = np.linspace(0.0, z_max_mm, n_z)
    R2, Z = np.meshgrid(r2, z, indexing="ij")
    rho = np.sqrt(R2)
    air = lens_mm - acrylic_mm
    s = rho / np.sqrt(rho ** 2 + (lens_mm + Z) ** 2)  # sin t0: the straight line, a start below the root
    for _ in range(50):
        s1, s2 = s / acrylic_ior, s / core_ior
        c0, c1, c2 = np.sqrt(1 - s * s), np.sqrt(1 - s1 * s1), np.sqrt(1 - s2 * s2)
        f = air * s / c0 + acrylic_mm * s1 / c1 + Z * s2 / c2 - rho
        df = air / c0 ** 3 + acrylic_mm / (acrylic_ior * c1 ** 3) + Z / (core_ior * c2 ** 3)
        step = f / df
        s = s - step
        if np.abs(step).max() < 1e-15:
            break
    q = np.where(rho > 0, s / np.sqrt(1 - s * s) / np.where(rho > 0, rho, 1.0), 1.0 / (air + acrylic_mm / acrylic_ior + Z / core_ior))
    return q, float(r2[1] - r2[0]), float(z[1] - z[0])


def sample_throughput(sensor_scene, per_side: int) -> np.ndarray:
    """(H k, W k) float32, k = per_side: each sample's camera importance times the Fresnel
    transmittance (and radiance scaling) of the acrylic's and the core's bottom faces, traced by
    Mitsuba (the weights of :func:`mlsim.render.reprojection.primary_samples`); zero where the ray
    does not enter the core. Sample (sx, sy) sits at pixel ((sx + 0.5) / k, (sy + 0.5) / k)."""
    from mlsim.render.reprojection import transmit_interfaces

    W, H, k = int(sensor_scene.view.width_px), int(sensor_scene.view.height_px), int(per_side)
    sy, sx = np.mgrid[0:H * k, 0:W * k]
    pos = np.stack([(sx.ravel() + 0.5) / (k * W), (sy.ravel() + 0.5) / (k * H)], axis=1)
    _, beta, _ = transmit_interfaces(sensor_scene, pos)
    return beta.reshape(H * k, W * k).astype(np.float32)


def _pixel_map(sensor_scene) -> np.ndarray:
    """(2, 3): continuous pixel position = M @ (1, tan_x, tan_y) of an air ray from the lens, fitted to
    Mitsuba's camera on a 15 x 15 grid (a pinhole: exact up to rounding)."""
    from mlsim.render.sensor_scene import use_variant

    mi = use_variant(sensor_scene.variant)
    W, H = int(sensor_scene.view.width_px), int(sensor_scene.view.height_px)
    g = np.stack(np.meshgrid(np.linspace(0.5, W - 0.5, 15), np.linspace(0.5, H - 0.5, 15)), -1).reshape(-1, 2)
    ray, _ = sensor_scene.scene.sensors()[0].sample_ray(0.0, 0.0, mi.Point2f(mi.Float(g[:, 0] / W), mi.Float(g[:, 1] / H)),
                                                        mi.Point2f(0.5, 0.5))
    d = np.stack([np.array(ray.d.x), np.array(ray.d.y), np.array(ray.d.z)], axis=1).astype(np.float64)
    A = np.stack([np.ones(len(d)), d[:, 0] / d[:, 2], d[:, 1] / d[:, 2]], axis=1)
    M, *_ = np.linalg.lstsq(A, g, rcond=None)
    residual = float(np.abs(A @ M - g).max())
    if residual > 1e-3:  # pragma: no cover - a camera that is not a pinhole looking along +z
        raise RuntimeError(f"the camera's pixels are not affine in the ray tangents (residual {residual:.2g} px): "
                           "the rasterised direct light needs the pinhole looking up the lens axis")
    return M.T.copy()


@dataclass
class DirectRaster:
    """What the rasteriser keeps of a sheet and view (:func:`direct_raster`): the samples'
    throughput (H k, W k), the pixel map (2, 3) and tangent table of the projection, the sheet's
    faces (K, 3) (sorted along the image, for memory locality) and which way a camera-facing face
    winds in the image (``orientation``)."""

    throughput: np.ndarray
    per_side: int
    pixel_map: np.ndarray
    inv_length: np.ndarray
    r2_step_mm2: float
    z_step_mm: float
    faces: np.ndarray
    orientation: float
    n_vertices: int
    height_px: int
    width_px: int

    def save(self, path) -> None:
        """Write every field to an ``.npz`` file (:meth:`load` reads it back, the same bits)."""
        np.savez(path, **{f.name: np.asarray(getattr(self, f.name)) for f in fields(self)})

    @classmethod
    def load(cls, path) -> "DirectRaster":
        scalar = {"int": int, "float": float}  # the fields' annotations (strings: postponed evaluation)
        with np.load(path) as data:
            return cls(**{f.name: scalar[f.type](data[f.name]) if f.type in scalar else data[f.name] for f in fields(cls)})

    @property
    def z_max_mm(self) -> float:
        return self.z_step_mm * (self.inv_length.shape[1] - 1)

    @property
    def rho_max_mm(self) -> float:
        return float(np.sqrt(self.r2_step_mm2 * (self.inv_length.shape[0] - 1)))

    def pixels_of(self, vertices_m) -> np.ndarray:
        """(..., 2) continuous pixel positions of sheet points (..., 3) m (x right, y down in the image)."""
        from mlsim.render.kernels import project_through_interfaces

        V = np.asarray(vertices_m, dtype=np.float64)
        flat = np.ascontiguousarray(V.reshape(-1, 3) * 1e3)
        require_finite(V, _VERTICES_WHAT, _VERTICES_FIX)
        uv = np.empty((len(flat), 2))
        outside = project_through_interfaces(flat, self.inv_length, self.r2_step_mm2, self.z_step_mm, self.pixel_map, uv)
        if outside:
            self._raise_outside(outside, flat)
        return uv.reshape(V.shape[:-1] + (2,))

    def _raise_outside(self, outside: int, vertices_mm) -> None:
        z, rho = vertices_mm[..., 2], np.hypot(vertices_mm[..., 0], vertices_mm[..., 1])
        raise ValueError(f"{outside} sheet points lie at z = {z.min():.3f} .. {z.max():.3f} mm and up to {rho.max():.2f} mm off the lens "
                         f"axis; the rasteriser's projection covers z = 0 .. {self.z_max_mm:.2f} mm (above the core's bottom face) "
                         f"and {self.rho_max_mm:.2f} mm: a vertex below the core's bottom or this far out is no deformation of "
                         'this sensor (check the solve), or render with fidelity.render.tier = "path"')

    def raster_order(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(order (N,), number (N,), faces (K, 3)): the sheet's vertices numbered in the order in
        which ``faces`` first use them (the sheet's vertex ``order[j]`` is vertex j of the returned
        faces, its vertex i is vertex ``number[i]``; unused vertices last), so the rasteriser's
        reads of neighbouring faces fall near each other in memory (0.4 ms a frame of the screw
        scene's 3.9). Made from ``faces`` again when they change."""
        if getattr(self, "_order_of", None) is not self.faces:
            first = np.full(self.n_vertices, self.faces.size, dtype=np.int64)
            np.minimum.at(first, self.faces.ravel(), np.arange(self.faces.size))
            order = np.argsort(first, kind="stable")
            number = np.empty_like(order)
            number[order] = np.arange(len(order))
            self._order = (order, number, np.ascontiguousarray(number[self.faces]))
            self._order_of = self.faces
        return self._order

    def images(self, vertices_m, radiance, frames=None) -> np.ndarray:
        """Direct-light images (F, H, W) float32 of per-vertex radiance (F, N) on the sheet at
        vertices_m (F, N, 3) m (the same units as :meth:`mlsim.render.sensor_scene.SensorScene.render`).
        ``frames`` (F,) int: the radiance's frames are these frames of vertices_m (any number of
        frames), read where they lie (the same images as ``images(vertices_m[frames], radiance)``)."""
        from mlsim.render.kernels import VERTEX_FIELDS, project_frames_at, rasterise_direct

        V = np.asarray(vertices_m, dtype=np.float64)
        e = np.ascontiguousarray(radiance, dtype=np.float32)
        frames = np.arange(len(V)) if frames is None else np.asarray(frames, dtype=np.int64)
        if (V.ndim != 3 or V.shape[1:] != (self.n_vertices, 3) or e.shape != (len(frames), self.n_vertices) or frames.ndim != 1
                or (len(frames) and not (0 <= frames.min() and frames.max() < len(V)))):
            raise ValueError(f"vertices_m {V.shape}, radiance {e.shape} and frames {frames.shape}: must be (F, {self.n_vertices}, 3), "
                             f"(K, {self.n_vertices}) and K frames of the F")
        require_finite(e, "radiance (frames, vertices) to rasterise", RADIANCE_FIX)
        order, number, faces = self.raster_order()
        # per frame and vertex (raster numbering): pixel u, v, depth (along a ray inside the core, z grows), radiance
        table = np.empty((len(frames), len(order), VERTEX_FIELDS))
        outside, non_finite = project_frames_at(V, frames, number, e, self.inv_length, self.r2_step_mm2, self.z_step_mm, self.pixel_map, table)
        if non_finite:
            require_finite(V[frames], _VERTICES_WHAT, _VERTICES_FIX)
        if outside:
            self._raise_outside(outside, V[frames] * 1e3)
        return rasterise_direct(table, faces, self.per_side, self.orientation, self.height_px, self.width_px, self.throughput)


def direct_raster(sensor_scene, per_side: int = 1) -> DirectRaster:
    """The :class:`DirectRaster` of a :class:`mlsim.render.sensor_scene.SensorScene`: its samples'
    throughput (Mitsuba, about 0.1-0.3 s), the projection's table and pixel map, and the sheet's
    faces in image order."""
    if not isinstance(per_side, (int, np.integer)) or not 1 <= per_side <= 8:
        raise ValueError(f"per_side = {per_side!r}: samples per pixel side must be an integer in 1 .. 8")
    if getattr(sensor_scene, "spectra", None) is not None:
        raise ValueError("direct_raster needs a mono SensorScene (the spectra are applied afterwards); build the scene without spectra=")
    view, o = sensor_scene.view, sensor_scene.options
    rest_mm = np.asarray(sensor_scene.rest_vertices_m, dtype=np.float64) * 1e3
    half_mm = o["base_half_size_m"] * 1e3
    # the table reaches well past the sheet at rest: twice its height, 1.5 x the base's corner
    table = tangent_table(view.lens_below_base_m * 1e3, o["acrylic_thickness_m"] * 1e3, o["acrylic_ior"], o["core_ior"],
                          1.5 * np.sqrt(2.0) * max(half_mm, np.hypot(rest_mm[:, 0], rest_mm[:, 1]).max()), 2.0 * rest_mm[:, 2].max() + 1.0)
    raster = DirectRaster(sample_throughput(sensor_scene, per_side), int(per_side), _pixel_map(sensor_scene), *table,
                          faces=sensor_scene.faces.astype(np.int64), orientation=1.0, n_vertices=sensor_scene.n_vertices,
                          height_px=int(view.height_px), width_px=int(view.width_px))
    # Which way a face seen from inside the core winds in the image: the rods' tips face the camera
    # (their normals, into the core, point down at it).
    uv = raster.pixels_of(rest_mm * 1e-3)
    F = raster.faces
    tri = rest_mm[F]
    normal_z = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])[:, 2]
    a, b, c = uv[F[:, 0]], uv[F[:, 1]], uv[F[:, 2]]
    area = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (c[:, 0] - a[:, 0]) * (b[:, 1] - a[:, 1])
    facing = normal_z < 0
    if not facing.any():  # pragma: no cover - a sheet with nothing facing the camera
        raise ValueError("no face of the sheet faces the camera (normals into the core pointing down)")
    raster.orientation = float(np.sign(np.median(area[facing])))
    centre = uv[F].mean(axis=1)
    raster.faces = np.ascontiguousarray(F[np.lexsort((centre[:, 0], np.floor(centre[:, 1] / 4.0)))])
    return raster
