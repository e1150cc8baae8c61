"""The optical stages of the ML rod array (``mlsim.ml_rod_array``): the render (Mitsuba: transport,
deformed or path tier, with its transport matrix cached per sensor and view), the camera, and the
DLLM's calibration frame."""

from __future__ import annotations

from pathlib import Path

from fem.stages import GEOMETRY_FIELDS
from mlsim.emission.stage import patches_in_mesh, patches_of
from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage, cached_precompute, memo, npz_io, stage_key

__all__ = ["VIEW_FIELDS", "transport_payload", "RENDER", "CAMERA", "CALIBRATION", "TRANSPORT", "TRANSPORT_DEFORMATION_WARN_MM"]

_transport_save, _transport_load = npz_io("transport.npz", "mlsim.render:TransportMatrix")
_render_save, _render_load = npz_io("render.npz", "mlsim.render:RenderResult")
_camera_save, _camera_load = npz_io("camera.npz", "mlsim.render.output:CameraFrames")
_calibration_save, _calibration_load = npz_io("calibration.npz", "mlsim.render.calibration_frame:CalibrationFrame")


def _sheet(scene: Scene, patches, ctx: "RunContext | None" = None):
    """The Mitsuba scene of the sheet on the scene's render device (shared in-process; render_frames
    returns it to its rest shape). The run log says which device and why."""
    from mlsim import render
    from mlsim.render.sensor_scene import resolve_device, variant_for

    device, why = resolve_device(scene.fidelity.render.device)
    if ctx is not None:
        ctx.log(f"[render] device: {device} (Mitsuba {variant_for(device)}; {why})")
    return memo(("sheet", stage_key(scene, "mesh"), scene.content_hash(VIEW_FIELDS), device),
                lambda: render.sensor_scene_for(scene, patches, device))


# Scene fields that shape the renderer's view of the sheet (not the emission): the transport matrix
# is keyed on these, so a dataset of episodes on one sensor traces it once.
VIEW_FIELDS = GEOMETRY_FIELDS + (
    "fidelity.mesh.segments_per_circle",
    "fidelity.render.sheet_edge_mm",
    "optics.elastomer_refractive_index",
    "optics.acrylic_thickness_mm",
    "optics.acrylic_refractive_index",
    "optics.ml_layer_reflectance",
    "camera.width_px",
    "camera.height_px",
    "camera.distance_mm",
    "camera.focal_length_mm",
    "camera.binning",
    "fidelity.render.max_depth",
    "fidelity.render.rr_depth",
)


#: Pure transport (``transport_max_displacement_mm = "off"``): above this sheet displacement (mm) the
#: run says that the matrix ignores the deformation.
TRANSPORT_DEFORMATION_WARN_MM = 0.5

# What shapes the ambient lamp's image (its level over time is the camera stage's business).
AMBIENT_IMAGE_FIELDS = ("ambient.lamp", "ambient.power_w", "ambient.height_m", "ambient.offset_mm", "ambient.efficacy_lm_per_w",
                         "ambient.occlusion", "optics.absorber", "optics.ml_layer_transmittance")


def _render_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim import render

    em, episode = inputs["emission"], inputs["solve"]
    sheet = _sheet(scene, em.patches, ctx)
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2)
    spec = scene.fidelity.render
    transport = raster = None
    # where each sheet vertex sits in the mesh: of the sensor, not the episode (shared in-process)
    located = patches_in_mesh(scene, episode.mesh_points, episode.mesh_tets, em.patches, ctx)
    vertices = render.deformed_vertices(episode, em.patches.vertices_m, located)
    if spec.tier == "deformed":
        transport, raster = _deformed_parts(scene, sheet, ctx)
        result = render.render_frames(sheet, radiance, "deformed", transport=transport, raster=raster, vertices_m=vertices, progress=ctx.progress)
        result.info.update(transport_spp=transport.spp, transport_nnz=int(transport.matrix.nnz),
                           transport_dropped_fraction=transport.dropped_fraction, transport_trace_s=transport.seconds)
        ctx.log(f"[render] deformed tier: every frame's direct light rasterised on its deformed sheet ({spec.direct_samples_per_side}^2 samples "
                f"per pixel), its bounces from the rest shape's matrix ({transport.spp} spp); the sheet moves up to "
                f"{max(result.info['sheet_displacement_mm'] or [0.0]):.2f} mm")
    elif spec.tier == "transport":
        transport = _cached_transport(scene, sheet, ctx)
        limit_mm = spec.path_above_mm
        result = render.render_frames(sheet, radiance, "transport", transport=transport, spp=spec.spp, seed=scene.seed, vertices_m=vertices,
                                      path_above_m=None if limit_mm is None else limit_mm * 1e-3, progress=ctx.progress)
        result.info.update(transport_spp=transport.spp, transport_nnz=int(transport.matrix.nnz),
                           transport_dropped_fraction=transport.dropped_fraction, transport_trace_s=transport.seconds)
        moved_mm = result.info["sheet_displacement_mm"]
        if result.info["path_frames"]:
            ctx.log(f"[render] {len(result.info['path_frames'])} frames in which the sheet moved more than {limit_mm:g} mm were path-traced "
                    f"at {spec.spp} spp (the matrix is of the rest shape; fidelity.render.transport_max_displacement_mm)")
        elif limit_mm is None and max(moved_mm) > TRANSPORT_DEFORMATION_WARN_MM:
            f = max(range(len(moved_mm)), key=moved_mm.__getitem__)
            ctx.log(f"[render] note: the transport tier renders the rest shape; the sheet moves up to {moved_mm[f]:.2f} mm (frame {f}), "
                    "which changes rods' intensities by up to tens of % (mlsim accuracy SCENE --stage render)")
    else:
        result = render.render_frames(sheet, radiance, "path", spp=spec.spp, seed=scene.seed, vertices_m=vertices, progress=ctx.progress)
    result.info["device"] = sheet.device
    if scene.ambient.lamp != "none":
        result.ambient, result.info["ambient"] = _ambient_image(scene, em.patches, sheet, transport, raster)
    return result


def _ambient_image(scene: Scene, patches, sheet, transport, raster=None):
    """The ambient lamp's leak (mlsim.render.ambient) rendered once on the rest shape, at lamp level 1."""
    from mlsim import render
    from mlsim.render import ambient

    a = scene.ambient
    leak = ambient.leak_through_layers(scene, patches, sheet, lamp=a.lamp, power_w=a.power_w, lamp_m=ambient.lamp_position_m(scene),
                                       absorber=scene.optics.absorber, efficacy_lm_per_w=a.efficacy_lm_per_w, occlusion=a.occlusion)
    spec = scene.fidelity.render
    image = render.render_still(sheet, render.radiance_of(leak.photons_per_s, patches.area_m2), spec.tier, spp=spec.spp,
                                seed=scene.seed ^ 0xA3B1E7, transport=transport, raster=raster)
    top = patches.normals[:, 2] > 0.99
    info = {"radiant_power_w": leak.radiant_power_w, "shaded_fraction": leak.shaded_fraction,
            "irradiance_on_top_w_m2": float(leak.irradiance_w_m2[top].mean()) if top.any() else 0.0,
            "leaked_photons_per_s": float(leak.photons_per_s.sum())}
    return image, info


def transport_payload(scene: Scene, bounces: bool = False) -> dict:
    """What the render's cached matrix is keyed on (:data:`TRANSPORT`, :func:`mlsim.stage.precompute_key`): this
    sensor and view, the trace's samples, not the load; ``bounces``: the deformed tier's matrix of the light's bounces.
    The run's estimate (:mod:`mlsim.run_budget`) asks the cache with it."""
    from mlsim.render.reprojection import DIRECT_DEPTH

    spec = scene.fidelity.render
    payload = {"view": scene.content_hash(VIEW_FIELDS), "spp": spec.transport_spp, "drop": spec.transport_drop, "seed": scene.seed, "version": "1"}
    if bounces:
        payload.update(first_depth=DIRECT_DEPTH, one_vertex=True)
    return payload


def _cached_transport(scene: Scene, sheet, ctx: "RunContext", bounces: bool = False):
    """The transport matrix, keyed on this sensor and view (not the load); ``bounces``: the deformed
    tier's matrix of the light's bounces (:func:`mlsim.render.reprojection.trace_bounces`)."""
    from mlsim.render import trace_transport
    from mlsim.render.reprojection import trace_bounces

    spec = scene.fidelity.render
    payload = transport_payload(scene, bounces)
    trace, what = (trace_bounces, "matrix of the light's bounces") if bounces else (trace_transport, "light-transport matrix")
    return cached_precompute(
        ctx, TRANSPORT, payload,
        lambda: trace(sheet, spp=spec.transport_spp, seed=scene.seed, drop=spec.transport_drop, progress=ctx.progress),
        f"[render] {spec.tier} tier: tracing the {what} at {spec.transport_spp} spp (cached for this sensor and view)")


def _deformed_parts(scene: Scene, sheet, ctx: "RunContext"):
    """The deformed tier's (bounces' matrix, DirectRaster), both cached on disk for this sensor and view.

    The DirectRaster (0.4 s to make: Mitsuba's sample throughput, the projection's table) was made in each
    process; from the cache a dataset worker needs Mitsuba for neither part and never imports it."""
    from mlsim.render.direct_raster import direct_raster

    k = scene.fidelity.render.direct_samples_per_side
    payload = {"what": "direct_raster", "mesh": stage_key(scene, "mesh"), "view": scene.content_hash(VIEW_FIELDS), "per_side": k,
               "version": "1"}
    raster = cached_precompute(ctx, DIRECT_RASTER, payload, lambda: direct_raster(sheet, k),
                               "[render] deformed tier: the direct light's rasteriser for this sensor and view (cached)")
    return _cached_transport(scene, sheet, ctx, bounces=True), raster


def _render_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render import output

    return output.write_render(result, out_dir)


def _render_summary(result) -> dict:
    from mlsim.render import output

    return output.render_summary(result)


def _calibration_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim.render.calibration_frame import calibration_frame

    geometry, (mesh, _) = inputs["geometry"], inputs["mesh"]
    patches = patches_of(scene, geometry, mesh, ctx)
    sheet = _sheet(scene, patches)
    tier = scene.fidelity.render.tier
    if tier == "deformed":
        transport, raster = _deformed_parts(scene, sheet, ctx)
        return calibration_frame(scene, patches, sheet, transport, raster)
    transport = _cached_transport(scene, sheet, ctx) if tier == "transport" else None
    return calibration_frame(scene, patches, sheet, transport)


def _calibration_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render.calibration_frame import write_calibration

    return write_calibration(result, out_dir)


def _camera_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim.render import output

    return output.expose(scene, inputs["render"], inputs["emission"], channel_factors=ml_channel_factors_cached(scene, ctx))


#: the scene fields that the ML light's channel factors read (mlsim.render.optics.ml_channel_factors)
CHANNEL_FACTOR_FIELDS = ("sensor", "optics", "camera.sensitivity")


def _factors_save(result, directory: Path) -> None:
    import numpy as np

    np.save(directory / "factors.npy", np.asarray(result, dtype=np.float64))


def _factors_load(directory: Path):
    import numpy as np

    return np.load(directory / "factors.npy")


# Not a stage of the plan: the camera stage caches the ML light's channel factors through this.
ML_CHANNEL_FACTORS = Stage(name="ml_channel_factors", doc="electrons per ZnS:Cu photon reaching a pixel, R, G, B (a precompute of the "
                           "sensor's optics and camera)", reads=(), needs=(), run=lambda *a: None, save=_factors_save, load=_factors_load)


def ml_channel_factors_cached(scene: Scene, ctx: "RunContext"):
    """:func:`mlsim.render.optics.ml_channel_factors` (3,) from the cache: its spectra need
    colour-science, whose import (with pandas) cost each dataset worker 1.5 s of CPU in its first
    episode for three numbers that depend on the sensor alone. The same float64 values (saved as
    .npy), a copy per call."""
    from mlsim.render.optics import ml_channel_factors

    payload = {"what": "ml_channel_factors", "fields": scene.content_hash(CHANNEL_FACTOR_FIELDS), "version": "1"}
    return cached_precompute(ctx, ML_CHANNEL_FACTORS, payload, lambda: ml_channel_factors(scene),
                             "[camera] the ML light's channel factors (cached for this sensor)").copy()


def _camera_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render import output

    return output.write_camera(result, out_dir)


def _camera_summary(result) -> dict:
    return result.summary()



TRANSPORT = Stage(name="transport_matrix", doc="transport tier precompute", reads=(), needs=(), run=lambda *a: None,
                  save=_transport_save, load=_transport_load)

_raster_save, _raster_load = npz_io("raster.npz", "mlsim.render.direct_raster:DirectRaster")
# Not a stage of the plan: the deformed tier caches its rasteriser's sample throughput, projection and faces through this.
DIRECT_RASTER = Stage(name="direct_raster", doc="deformed tier precompute: the direct light's rasteriser", reads=(), needs=(),
                      run=lambda *a: None, save=_raster_save, load=_raster_load)

RENDER = Stage(
    name="render",
    doc="radiance of the ML light at the camera's lens per frame (Mitsuba: transport, deformed or path tier); writes radiance.npz and a PNG",
    version="2",  # 2: the deformed tier's bounces with one vertex drawn per hit (its first version spread each hit over three)
    reads=VIEW_FIELDS + ("fidelity.render", "seed") + AMBIENT_IMAGE_FIELDS,
    needs=("emission", "solve"),
    run=_render_run,
    save=_render_save,
    load=_render_load,
    write=_render_write,
    summarize=_render_summary,
)

CAMERA = Stage(
    name="camera",
    doc="8-bit RGB camera frames (radiometry, spectra, noise, ADC); writes an MP4, PNG frames, a contact sheet and a per-frame CSV",
    reads=("camera", "optics", "sensor", "ambient", "seed", "noise_seed"),
    needs=("render", "emission"),
    run=_camera_run,
    save=_camera_save,
    load=_camera_load,
    write=_camera_write,
    summarize=_camera_summary,
)

CALIBRATION = Stage(
    name="calibration",
    version="2",  # 2: rendered by the deformed tier's one-vertex bounces where that is the tier
    doc="the DLLM's calibration frame: the sensor without its absorber under the white calibration lamp, auto-exposed; writes a PNG and JSON",
    reads=VIEW_FIELDS + ("fidelity.render", "seed", "calibration", "camera", "optics", "ambient.occlusion"),
    needs=("geometry", "mesh"),
    run=_calibration_run,
    save=_calibration_save,
    load=_calibration_load,
    write=_calibration_write,
    summarize=lambda result: dict(result.info),
)
