"""The deformed tier's split of the light (issue 16, CPU): the direct light on the deformed sheet,
the bounces from the rest shape's transport matrix; and the direct light from Mitsuba's own
primary rays, the reference of the rasteriser (:mod:`mlsim.render.direct_raster`).

The rest-shape transport (:mod:`mlsim.render.transport`) is off by tens of % per rod once a rod's
tip has moved a millimetre or two. Most of that error is in the *direct* light, the light the
camera sees through the acrylic and the core's bottom without a bounce: 72 % of the image of the
default demo's most bent frame, and 64 % off there. The camera sees each rod's tip face-on, and
the tip moves across the image. The bounces inside the rods change far less with the shape.

So an image is split in two:

    image = D(x) L + B_rest e

- **Direct light on the deformed sheet, D(x) L.** The camera's primary rays, ``per_side`` x
  ``per_side`` per pixel, pass through the two flat interfaces. Each is weighted by the camera's
  importance and by the Fresnel transmittance of both interfaces, and reads the radiance L of the
  deformed sheet x where it first hits it (:func:`primary_samples`, :func:`direct_image`). The
  interfaces do not move, so the rays inside the core are the same every frame; only their first
  hits change.
- **Bounces on the rest shape, B_rest e.** B_rest is the transport matrix of the paths with at
  least one bounce on the sheet: the hits after the first, recorded along the same paths as the
  full matrix's (:func:`split_transport`, ``trace_transport(..., first_depth=3)``).

Measured against 2 x 64 spp path renders on the deformed sheet (mono; per-rod disk sums, Frobenius
over every lit frame x rod; the split traced at 16 spp and 3 x 3 primary rays, 2026-11-26):

| scene | this split | rest-shape transport | worst frame: split / rest |
|---|---|---|---|
| default demo | 0.86 % | 3.1 % | 7.2 % / 51 % |
| screw | 0.67 % | 1.29 % | 1.1 % / 6.3 % |
| direction test, 0 deg (1.5 mm mesh) | 1.05 % | 2.77 % | 3.2 % / 39 % |

What is left is the bounces on the rest shape: 7-15 % off, on 28-48 % of the light. The deformed
tier's own figures (its rasterised direct light, the bounces at ``transport_spp``) are
``benchmarks/bench_deformed.py``'s.

:func:`primary_samples` casts the primary rays with Mitsuba (the sheet's BVH rebuilt per frame:
0.5-0.9 s per frame at 3 x 3 per pixel on 2 cores); the deformed tier finds the same first hits by
projection and rasterisation in a few milliseconds (:mod:`mlsim.render.direct_raster`, tested
against this module).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlsim.render.transport import TransportMatrix, _barycentric, _hits, trace_transport

__all__ = ["DIRECT_DEPTH", "PrimarySamples", "split_transport", "trace_bounces", "transmit_interfaces", "primary_samples", "direct_image"]

#: intersections on a direct path: the acrylic's bottom, the core's bottom, the sheet
DIRECT_DEPTH = 3


def split_transport(sensor_scene, spp: int = 64, seed: int = 0, drop: float = 1e-4, progress: bool = False
                    ) -> tuple[TransportMatrix, TransportMatrix]:
    """(direct, bounces): the transport matrix of the sheet as it is, split into its direct paths
    (camera -> acrylic -> core -> sheet) and the rest. Both are traced with the same seed, so they
    follow the same paths: the direct trace stops at the sheet, the other records only the hits
    after it (``first_depth``), and the two add up to the full matrix. Entries below ``drop`` x the
    largest are removed from each part."""
    depth = sensor_scene.max_depth
    try:
        sensor_scene.max_depth = DIRECT_DEPTH
        direct = trace_transport(sensor_scene, spp=spp, seed=seed, drop=drop, progress=progress)
    finally:
        sensor_scene.max_depth = depth
    return direct, trace_transport(sensor_scene, spp=spp, seed=seed, drop=drop, progress=progress, first_depth=DIRECT_DEPTH)


@dataclass
class PrimarySamples:
    """The camera's primary rays' first hits on the sheet: per sample its pixel (n,), the sheet's face
    (n,) (-1: the ray misses the sheet), barycentric weights (n, 3), and throughput (n,): the
    camera's importance times both interfaces' Fresnel transmittance and radiance scaling. There
    are ``per_pixel`` samples per pixel, and ``n_pixels`` pixels."""

    pixel: np.ndarray
    face: np.ndarray
    bary: np.ndarray
    throughput: np.ndarray
    per_pixel: int
    n_pixels: int
    height_px: int
    width_px: int


def trace_bounces(sensor_scene, spp: int = 64, seed: int = 0, drop: float = 1e-4, progress: bool = False) -> TransportMatrix:
    """The deformed tier's matrix of the light's bounces on the sheet as it is: the hits after the
    direct one (``first_depth`` = :data:`DIRECT_DEPTH`), each drawn to one vertex of its face
    (``one_vertex``, :func:`mlsim.render.transport.trace_transport`)."""
    return trace_transport(sensor_scene, spp=spp, seed=seed, drop=drop, progress=progress, first_depth=DIRECT_DEPTH, one_vertex=True)


def transmit_interfaces(sensor_scene, film_positions):
    """Camera rays through film positions (n, 2) in [0, 1]^2, transmitted through the acrylic's and
    the core's bottom faces: (Mitsuba rays inside the core, throughput (n,) numpy, Mitsuba mask of
    the rays that entered it). The throughput is the camera's importance times both faces' Fresnel
    transmittance and radiance scaling; zero where a ray misses the acrylic."""
    from mlsim.render.sensor_scene import use_variant

    mi = use_variant(sensor_scene.variant)
    import drjit as dr

    p = np.asarray(film_positions, dtype=np.float64)
    camera = sensor_scene.scene.sensors()[0]
    ray, weight = camera.sample_ray(0.0, 0.0, mi.Point2f(mi.Float(p[:, 0]), mi.Float(p[:, 1])), mi.Point2f(0.5, 0.5))
    beta = mi.Float(weight[0])
    active = mi.Bool(True)
    ctx = mi.BSDFContext()
    for _ in range(DIRECT_DEPTH - 1):
        si = sensor_scene.scene.ray_intersect(ray, active)
        active &= si.is_valid() & (si.shape.emitter() == None)  # noqa: E711 (Dr.Jit mask)
        # transmitted through the dielectric (the sample that picks transmission): the weight
        # Mitsuba returns is its estimator's (value / probability), so the probability, the Fresnel
        # transmittance, is multiplied back in
        bs, value = si.bsdf(ray).sample(ctx, si, mi.Float(1.0 - 1e-6), mi.Point2f(0.5, 0.5), active)
        beta = beta * mi.Float(value[0]) * bs.pdf
        active &= bs.pdf > 0
        ray = si.spawn_ray(si.to_world(bs.wo))
    beta = dr.select(active, beta, 0.0)
    dr.eval(ray, beta, active)
    return ray, np.array(beta, dtype=np.float64), active


def primary_samples(sensor_scene, per_side: int = 3) -> PrimarySamples:
    """Trace the camera's primary rays (a regular ``per_side`` x ``per_side`` grid in each pixel),
    transmitted through the acrylic's and the core's bottom faces, to their first hit on the
    sheet as it is now (:meth:`mlsim.render.sensor_scene.SensorScene.set_vertices`)."""
    from mlsim.render.sensor_scene import use_variant

    if per_side < 1:
        raise ValueError(f"per_side = {per_side}: must be >= 1")
    mi = use_variant(sensor_scene.variant)
    import drjit as dr

    view = sensor_scene.view
    W, H = int(view.width_px), int(view.height_px)
    k = per_side * per_side
    n = W * H * k
    idx = np.arange(n, dtype=np.int64)
    pixel = idx // k
    s = idx % k
    ox, oy = ((s % per_side) + 0.5) / per_side, ((s // per_side) + 0.5) / per_side
    ray, beta, active = transmit_interfaces(sensor_scene, np.stack([((pixel % W) + ox) / W, ((pixel // W) + oy) / H], axis=1))
    si = sensor_scene.scene.ray_intersect(ray, active)
    on_sheet = active & si.is_valid() & (si.shape.emitter() != None) & (mi.Frame3f.cos_theta(si.wi) > 0)  # noqa: E711 (Dr.Jit mask)
    dr.eval(on_sheet, si.prim_index, si.p)
    hit = np.array(on_sheet, dtype=bool)
    face = np.full(n, -1, dtype=np.int64)
    bary = np.zeros((n, 3))
    if hit.any():
        face[hit], p = _hits(si, hit)
        faces = sensor_scene.faces.astype(np.int64)
        bary[hit] = _barycentric(p, sensor_scene.vertices_mm.astype(np.float64)[faces[face[hit]]])
    return PrimarySamples(pixel, face, bary, np.where(hit, beta, 0.0), k, W * H, H, W)


def direct_image(samples: PrimarySamples, faces: np.ndarray, radiance) -> np.ndarray:
    """(H, W) the direct light of per-vertex radiance (N,): per pixel, the mean over its samples of
    throughput x the radiance interpolated at the sample's hit (zero where a ray misses the sheet)."""
    e = np.asarray(radiance, dtype=np.float64)
    hit = samples.face >= 0
    value = np.zeros(len(samples.face))
    corners = np.asarray(faces, dtype=np.int64)[samples.face[hit]]
    value[hit] = samples.throughput[hit] * np.einsum("nk,nk->n", samples.bary[hit], e[corners])
    image = np.bincount(samples.pixel, weights=value, minlength=samples.n_pixels) / samples.per_pixel
    return image.reshape(samples.height_px, samples.width_px).astype(np.float32)
