"""Deformation-aware transport, first piece (issue 16, CPU): the direct light traced on the deformed
sheet's primary rays, the bounces from the rest shape's transport matrix.

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
  least one bounce on the sheet: the full matrix minus its direct part, traced with the same
  random numbers (:func:`split_transport`).

Measured against 2 x 64 spp path renders on the deformed sheet (mono; per-rod disk sums, Frobenius
over every lit frame x rod; a 16 spp split and 3 x 3 primary rays, 2026-11-26,
``benchmarks/bench_reprojection.py``):

| scene | this split | rest-shape transport | worst frame: split / rest |
|---|---|---|---|
| default demo | 0.86 % | 3.1 % | 7.2 % / 51 % |
| screw | 0.67 % | 1.29 % | 1.1 % / 6.3 % |
| direction test, 0 deg (1.5 mm mesh) | 1.05 % | 2.77 % | 3.2 % / 39 % |

What is left is the bounces on the rest shape: 7-15 % off, on 28-48 % of the light.

Cost: the primary rays are cast by Mitsuba, with the sheet's BVH rebuilt per frame (0.5-0.9 s at
3 x 3 per pixel on 2 cores). That is about a 16 spp path render's cost, and without its Monte Carlo
noise in the direct light. The fast tier of issue 16 (200 frames/s) needs these first hits without
ray tracing: the interfaces are flat and parallel, so each sheet vertex projects to the image
analytically (Snell at two planes), and each rod, seen from below, is a single-layer cup that can
be rasterised. This module is the reference that such a rasteriser must match.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlsim.render.transport import TransportMatrix, _barycentric, _drop_small, _hits, trace_transport

__all__ = ["DIRECT_DEPTH", "PrimarySamples", "split_transport", "primary_samples", "direct_image"]

#: intersections on a direct path: the acrylic's bottom, the core's bottom, the sheet
DIRECT_DEPTH = 3


def split_transport(sensor_scene, spp: int = 64, seed: int = 0, drop: float = 1e-4, progress: bool = False
                    ) -> tuple[TransportMatrix, TransportMatrix]:
    """(direct, bounces): the transport matrix of the sheet as it is, split into its direct paths
    (camera -> acrylic -> core -> sheet) and the rest. Both are traced with the same seed, so the
    direct paths of the full trace are those of the direct trace, and their difference holds only
    paths with a bounce. Entries below ``drop`` x the largest are removed from each part."""
    depth = sensor_scene.max_depth
    try:
        sensor_scene.max_depth = DIRECT_DEPTH
        direct = trace_transport(sensor_scene, spp=spp, seed=seed, drop=0.0, progress=progress)
    finally:
        sensor_scene.max_depth = depth
    full = trace_transport(sensor_scene, spp=spp, seed=seed, drop=0.0, progress=progress)
    bounces = (full.matrix.astype(np.float64) - direct.matrix.astype(np.float64)).tocsr()
    bounces.data[np.abs(bounces.data) < 1e-30] = 0.0  # the direct paths cancel exactly
    bounces.eliminate_zeros()
    d = direct.matrix.astype(np.float64).tocsr()
    parts = []
    for m, seconds in ((d, direct.seconds), (bounces, full.seconds)):
        dropped = _drop_small(m, drop)
        parts.append(TransportMatrix(m.astype(np.float32), full.height_px, full.width_px, int(spp), dropped, seconds))
    return parts[0], parts[1]


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
    pos = mi.Point2f(mi.Float(((pixel % W) + ox) / W), mi.Float(((pixel // W) + oy) / H))
    camera = sensor_scene.scene.sensors()[0]
    ray, weight = camera.sample_ray(0.0, 0.0, pos, mi.Point2f(0.5, 0.5))
    beta = mi.Float(weight[0])
    active = mi.Bool(True)
    ctx = mi.BSDFContext()
    face = np.full(n, -1, dtype=np.int64)
    hit_p = np.zeros((n, 3))
    throughput = np.zeros(n)
    for _ in range(DIRECT_DEPTH):
        si = sensor_scene.scene.ray_intersect(ray, active)
        active &= si.is_valid()
        on_sheet = active & (si.shape.emitter() != None) & (mi.Frame3f.cos_theta(si.wi) > 0)  # noqa: E711 (Dr.Jit mask)
        dr.eval(on_sheet, si.prim_index, si.p, beta)
        m = np.array(on_sheet, dtype=bool) & (face < 0)
        if m.any():
            face[m], hit_p[m] = _hits(si, m)
            throughput[m] = np.array(beta)[m]
        active &= ~on_sheet
        # transmitted through the dielectric (the sample that picks transmission): the weight
        # Mitsuba returns is its estimator's (value / probability), so the probability, the Fresnel
        # transmittance, is multiplied back in
        bs, value = si.bsdf(ray).sample(ctx, si, mi.Float(1.0 - 1e-6), mi.Point2f(0.5, 0.5), active)
        beta = beta * mi.Float(value[0]) * bs.pdf
        active &= bs.pdf > 0
        ray = si.spawn_ray(si.to_world(bs.wo))
    hit = face >= 0
    faces = sensor_scene.faces.astype(np.int64)
    bary = np.zeros((n, 3))
    if hit.any():
        bary[hit] = _barycentric(hit_p[hit], sensor_scene.vertices_mm.astype(np.float64)[faces[face[hit]]])
    return PrimarySamples(pixel, face, bary, np.where(hit, throughput, 0.0), k, W * H, H, W)


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
