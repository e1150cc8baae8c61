"""Render: the radiance the camera's lens receives from the glowing ML layer, per frame.

Three tiers behind one function (:func:`render_frames`), selected by ``fidelity.render.tier``:

- ``path`` (:meth:`mlsim.render.sensor_scene.SensorScene.render`): Mitsuba path-traces every frame
  on the deformed sheet, ``fidelity.render.spp`` samples per pixel, on the CPU or, where there is
  one, an NVIDIA GPU (``fidelity.render.device``; the same scene in ``cuda_ad_mono``: on an H100,
  see ``benchmarks/bench_render_device.py``);
- ``transport`` (:mod:`mlsim.render.transport`): one sparse pixels x vertices matrix traced once per
  geometry (cached by the pipeline), then every frame is a sparse product. The matrix is of the rest
  shape, and the rods' deformation changes what reaches the camera (on the default demo's slide,
  10-45 % per rod, from the moved walls and tips and from the changed bounces inside the rods), so
  frames in which the sheet moved more than a limit (``fidelity.render.transport_max_displacement_mm``)
  are path-traced instead.
- ``deformed`` (:mod:`mlsim.render.reprojection`, :mod:`mlsim.render.direct_raster`): the light
  that follows the deformation. The direct light (no bounce on the sheet; most of the image, and
  what the rods' bending moves) is rasterised on each frame's deformed sheet through the flat
  interfaces, with each sample's Fresnel throughput traced once; the bounces come from the rest
  shape's transport matrix of the paths with a bounce (traced once per geometry, cached). On the
  default demo, every lit frame: 0.9 % per rod against deformed path renders, where the rest
  shape's transport is 3.1 % off (51 % on its worst frame).

All three return mono photon radiance (photons s^-1 m^-2 sr^-1 of ZnS:Cu light, (F, H, W)); the camera
stage turns it into per-channel radiance with :func:`mlsim.render.optics.ml_channel_factors`.

Frames the renderer never sees: a frame whose emission is zero everywhere (the stress is not
changing) renders to exactly zero and is not rendered (``RenderResult.rendered`` is False; the
camera draws its sensor noise); a frame with the same emission and geometry as the frame before
reuses that frame's image.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from mlsim.render.optics import View, camera_params, ml_channel_factors, rod_disks_px, view_of
from mlsim.render.sensor_scene import SensorScene, radiance_of
from mlsim.render.transport import TransportMatrix, trace_transport

__all__ = ["RENDER_TIERS", "RenderResult", "render_frames", "render_still", "sensor_scene_for", "deformed_vertices", "View", "view_of",
           "camera_params", "ml_channel_factors", "rod_disks_px", "SensorScene", "radiance_of", "TransportMatrix",
           "trace_transport"]

RENDER_TIERS = ("transport", "deformed", "path")


@dataclass
class RenderResult:
    """radiance (F, H, W) float32 photons s^-1 m^-2 sr^-1 at the lens (mono, ZnS:Cu light);
    rendered (F,) bool: frames the renderer computed (False: dark or repeated); seconds per
    computed frame (F,) (0 where not computed); the tier and samples per pixel."""

    radiance: np.ndarray
    rendered: np.ndarray
    frame_seconds: np.ndarray
    tier: str
    spp: int
    info: dict = field(default_factory=dict)
    #: (H, W) radiance of the ambient lamp's light leaking into the core at lamp level 1 (photons of
    #: its own spectrum, :mod:`mlsim.render.ambient`); None without a lamp.
    ambient: np.ndarray | None = None

    @property
    def n_frames(self) -> int:
        return len(self.radiance)

    def save(self, path) -> None:
        extra = {} if self.ambient is None else {"ambient": self.ambient}
        np.savez(path, radiance=self.radiance, rendered=self.rendered, frame_seconds=self.frame_seconds,
                 tier=self.tier, spp=self.spp, info=np.array(repr(self.info)), **extra)

    @classmethod
    def load(cls, path) -> "RenderResult":
        import ast

        z = np.load(path)
        return cls(z["radiance"], z["rendered"], z["frame_seconds"], str(z["tier"]), int(z["spp"]), ast.literal_eval(str(z["info"])),
                   z["ambient"] if "ambient" in z.files else None)


def sensor_scene_for(scene, patches, device: str | None = None) -> SensorScene:
    """The :class:`SensorScene` of a scene whose emitting sheet is ``patches``
    (:class:`mlsim.emission.MLPatches`), on ``device`` ("cpu" or "cuda"; None: the scene's
    ``fidelity.render.device`` resolved by :func:`mlsim.render.sensor_scene.resolve_device`)."""
    from fem.geometry import RodArray
    from mlsim.render.sensor_scene import resolve_device

    g = RodArray.from_sensor(scene.sensor)
    o, r = scene.optics, scene.fidelity.render
    device = device if device is not None else resolve_device(r.device)[0]
    return SensorScene(patches.vertices_m, patches.faces, view_of(scene), core_ior=o.elastomer_refractive_index,
                       acrylic_ior=o.acrylic_refractive_index, acrylic_thickness_m=o.acrylic_thickness_mm * 1e-3,
                       base_half_size_m=max(g.size_x_m, g.size_y_m) / 2, reflectance=o.ml_layer_reflectance,
                       max_depth=r.max_depth, rr_depth=r.rr_depth, device=device)


def deformed_vertices(episode, vertices_m, located: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """The sheet's vertices (N, 3) moved by the FEM displacement at each frame: (F, N, 3) m.

    The displacement is interpolated linearly in the tet of the solve's mesh that holds each vertex
    (:func:`fem.mesh.locate_points`; a vertex on the curved core boundary just outside the straight
    tets takes its nearest tet's extrapolation). ``located``: that function's (tet, barycentric)
    result for these vertices on this mesh, when the caller already has it (it depends on the
    mesh and the sheet only, not on the episode)."""
    from fem.mesh import locate_points
    from mlsim.render.kernels import deformed_sheet

    V = np.ascontiguousarray(vertices_m, dtype=float)
    tet, bary = located if located is not None else locate_points(episode.mesh_points, episode.mesh_tets, V)
    corners = np.ascontiguousarray(episode.mesh_tets[tet], dtype=np.int64)  # (N, 4)
    steps = np.ascontiguousarray(episode.frame_step, dtype=np.int64)
    out = np.empty((len(steps),) + V.shape)
    deformed_sheet(V, corners, np.ascontiguousarray(bary, dtype=float), np.ascontiguousarray(episode.displacement), steps, out)
    return out


def render_frames(sensor_scene: SensorScene, vertex_radiance, tier: str = "transport", *, spp: int = 16, seed: int = 0,
                  vertices_m=None, transport: TransportMatrix | None = None, path_above_m: float | None = None,
                  raster=None, progress: bool = False) -> RenderResult:
    """Radiance images (F, H, W) of per-vertex radiance (F, N) (see :func:`radiance_of`).

    tier ``transport`` needs ``transport`` (a :class:`TransportMatrix` of this sheet); ``path`` renders
    with Mitsuba at ``spp``, frame f with the seed (seed, f), on ``vertices_m`` (F, N, 3) when given
    (the deformed sheet), else on the sheet as built. ``deformed`` needs ``transport``, the bounces'
    matrix (``first_depth`` 3, :func:`mlsim.render.reprojection.split_transport`), and ``raster``, the
    sheet's :class:`mlsim.render.direct_raster.DirectRaster`; its direct light is rasterised on
    ``vertices_m`` (else the sheet as built).

    ``path_above_m`` (transport tier, with ``vertices_m``): frames in which some vertex of the sheet
    moved further than this from the rest shape are path-traced instead (the matrix is of the rest
    shape; ``RenderResult.info["path_frames"]`` lists them). None: every frame from the matrix.
    With ``vertices_m``, ``info["sheet_displacement_mm"]`` gives each frame's largest displacement.
    """
    if tier not in RENDER_TIERS:
        raise ValueError(f'render tier "{tier}": choose one of {", ".join(RENDER_TIERS)}')
    e = np.asarray(vertex_radiance, dtype=np.float32)
    if e.ndim != 2 or e.shape[1] != sensor_scene.n_vertices:
        raise ValueError(f"vertex_radiance of shape {e.shape}: must be (frames, {sensor_scene.n_vertices})")
    if not np.all(np.isfinite(e)) or (e.size and e.min() < 0):
        raise ValueError("vertex_radiance must be finite and >= 0")
    view = sensor_scene.view
    F = len(e)
    out = np.zeros((F, view.height_px, view.width_px), np.float32)
    rendered = np.zeros(F, bool)
    seconds = np.zeros(F)
    lit = e.max(axis=1) > 0 if e.size else np.zeros(F, bool)
    from mlsim.render.kernels import largest_displacement, repeats_previous

    if vertices_m is not None:
        vertices_m = np.asarray(vertices_m, dtype=float)
        if vertices_m.shape != (F, sensor_scene.n_vertices, 3):
            raise ValueError(f"vertices_m of shape {vertices_m.shape}: must be ({F}, {sensor_scene.n_vertices}, 3)")
        moved_m = largest_displacement(vertices_m, np.asarray(sensor_scene.rest_vertices_m, dtype=float))
    same = lit & repeats_previous(np.ascontiguousarray(e), np.empty((0, 0, 3)) if vertices_m is None else np.ascontiguousarray(vertices_m))
    todo = np.flatnonzero(lit & ~same)
    every = len(todo) == F
    pick = slice(None) if every else todo  # every frame: the frames' arrays go in as views, not copied by index
    traced = todo if tier == "path" else np.array([], int)
    if tier == "deformed":
        _check_deformed(sensor_scene, transport, raster)
        t0 = time.perf_counter()
        if len(todo):
            rest = sensor_scene.rest_vertices_m
            e_pick = e[pick]
            if vertices_m is not None:  # the lit frames' vertices read where they lie (no gathered copy)
                direct = raster.images(vertices_m, e_pick, frames=None if every else todo)
            else:
                direct = raster.images(np.broadcast_to(rest, (len(todo),) + rest.shape), e_pick)
            images = transport.apply(e_pick, add_to=direct)
            if every:
                out = images
            else:
                out[todo] = images
        seconds[todo] = (time.perf_counter() - t0) / max(len(todo), 1)
    if tier == "transport":
        if transport is None:
            raise ValueError("the transport tier needs the sheet's TransportMatrix (trace_transport)")
        if transport.n_vertices != sensor_scene.n_vertices or (transport.height_px, transport.width_px) != (view.height_px, view.width_px):
            raise ValueError("the TransportMatrix was traced for another sheet or view: trace it again")
        if path_above_m is not None and vertices_m is not None:
            traced, todo = todo[moved_m[todo] > path_above_m], todo[moved_m[todo] <= path_above_m]
        t0 = time.perf_counter()
        if len(todo):
            out[todo] = transport.apply(e[todo])
        seconds[todo] = (time.perf_counter() - t0) / max(len(todo), 1)
    if len(traced):
        from tqdm.auto import tqdm

        try:
            for f in tqdm(traced, desc="path tracing", unit="frame", disable=None if progress else True, leave=False):
                t0 = time.perf_counter()
                if vertices_m is not None:
                    sensor_scene.set_vertices(vertices_m[f])
                sensor_scene.set_radiance(e[f])
                out[f] = sensor_scene.render(spp, _frame_seed(seed, f))
                seconds[f] = time.perf_counter() - t0
        finally:
            if vertices_m is not None:  # the sheet is shared (the ambient still, the next episode): back to rest
                sensor_scene.set_vertices(sensor_scene.rest_vertices_m)
    rendered[todo] = True
    rendered[traced] = True
    for f in np.flatnonzero(same):  # in order, so a run of repeats copies its first frame
        out[f] = out[f - 1]
    result = RenderResult(out, rendered, seconds, tier, int(spp if tier == "path" else (transport.spp if transport else 0)))
    if tier == "deformed":
        result.info["direct_samples_per_pixel"] = int(raster.per_side) ** 2
    if tier == "transport":
        result.info["path_frames"] = [int(f) for f in traced]
        result.info["path_spp"] = int(spp)
    if vertices_m is not None:
        result.info["sheet_displacement_mm"] = [round(float(d) * 1e3, 4) for d in moved_m]
    return result


def render_still(sensor_scene: SensorScene, vertex_radiance, tier: str = "transport", *, spp: int = 16, seed: int = 0,
                 transport: TransportMatrix | None = None, raster=None) -> np.ndarray:
    """One image (H, W) of per-vertex radiance (N,) on the sheet at rest (the ambient leak, the
    calibration frame): a product with the transport matrix (``deformed``: the rasterised direct
    light plus the bounces' matrix), or a path-traced render at ``spp``."""
    e = np.asarray(vertex_radiance, dtype=np.float32)[None]
    if tier in ("transport", "deformed"):
        return render_frames(sensor_scene, e, tier, transport=transport, raster=raster).radiance[0]
    sensor_scene.set_vertices(sensor_scene.rest_vertices_m)
    return render_frames(sensor_scene, e, "path", spp=spp, seed=seed).radiance[0]


def _check_deformed(sensor_scene: SensorScene, bounces: TransportMatrix | None, raster) -> None:
    """The deformed tier's two precomputed parts belong to this sheet and view, and the matrix holds
    the bounces only (the direct light is the rasteriser's)."""
    from mlsim.render.reprojection import DIRECT_DEPTH

    view = sensor_scene.view
    if bounces is None or raster is None:
        raise ValueError("the deformed tier needs the bounces' TransportMatrix (mlsim.render.reprojection.split_transport) and the "
                         "sheet's DirectRaster (mlsim.render.direct_raster.direct_raster)")
    if bounces.first_depth != DIRECT_DEPTH:
        raise ValueError(f"the deformed tier's matrix must hold the bounces only (traced with first_depth = {DIRECT_DEPTH}); this one "
                         f"has first_depth = {bounces.first_depth}, and its direct light would be counted twice")
    for name, part in (("TransportMatrix", bounces), ("DirectRaster", raster)):
        if part.n_vertices != sensor_scene.n_vertices or (part.height_px, part.width_px) != (view.height_px, view.width_px):
            raise ValueError(f"the {name} was made for another sheet or view: make it again for this one")


def _frame_seed(seed: int, frame: int) -> int:
    """A 32-bit seed per (scene seed, frame): splitmix-style mixing, so neighbouring seeds differ."""
    x = (int(seed) * 0x9E3779B97F4A7C15 + int(frame) * 0xBF58476D1CE4E5B9 + 1) & 0xFFFFFFFFFFFFFFFF
    x ^= x >> 31
    x = (x * 0x94D049BB133111EB) & 0xFFFFFFFFFFFFFFFF
    return (x ^ (x >> 29)) & 0xFFFFFFFF
