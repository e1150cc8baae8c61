"""The planner: stages, their inputs and outputs, a minimal plan per scene, and a content-hash cache.

Each stage declares the dotted scene fields it ``reads`` and the stages it ``needs``. Its cache key
is the SHA-256 of its name, its version, exactly those fields' values and the keys of the stages it
needs; so changing ``camera.gain_db`` leaves the mesh's key, and the cached mesh, untouched.

:func:`plan` returns the stages a scene's ``outputs`` require, in order, each with an action:

- ``load``: its result is in the cache (the stages it needs are then not required for it);
- ``run``: it must be computed (the stages it needs are then required);
- a stage whose result nobody needs does not appear at all.

Stage code imports its heavy dependencies inside its functions, so a run imports only what its
plan touches: a scene that asks for the mesh never imports Mitsuba.
"""

from __future__ import annotations

import json
import os
import shutil
import tempfile
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from mlsim.scene import Scene

__all__ = ["Stage", "STAGES", "OUTPUTS", "PlanStep", "Cache", "plan", "run", "stage_key", "default_cache_dir", "invalidated", "atomic_bytes"]

# Scene fields that shape the rod array's geometry (shared by geometry and mesh).
_GEOMETRY_FIELDS = (
    "sensor.rows",
    "sensor.cols",
    "sensor.surface_size_mm",
    "sensor.pitch_mm",
    "sensor.rod",
    "sensor.base",
    "sensor.layers",
)


@dataclass(frozen=True)
class Stage:
    """One step of the flow of data.

    run(scene, inputs, ctx) -> result, where inputs maps each needed stage's name to its result.
    save(result, dir) / load(dir) -> result: how the result is cached (None: never cached, for cheap
    stages). write(result, out_dir, ctx) -> list of files: the user-facing output when requested.
    summarize(result) -> dict: what goes into the run's JSON summary.
    """

    name: str
    doc: str
    reads: tuple[str, ...]
    needs: tuple[str, ...]
    run: Callable[..., Any]
    version: str = "1"
    save: Callable[[Any, Path], None] | None = None
    load: Callable[[Path], Any] | None = None
    write: Callable[..., list[Path]] | None = None
    summarize: Callable[[Any], dict] | None = None


# ----------------------------------------------------------------------------------- the stages
def _geometry_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from fem.geometry import RodArray

    return RodArray.from_sensor(scene.sensor)


def _geometry_write(g, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from fem.geometry import emitting_surface, solid_below_depth

    segments = ctx.scene.fidelity.mesh.segments_per_circle
    surfaces = {
        "surface_outer.ply": solid_below_depth(g, 0.0, segments),
        "surface_ml_outer.ply": solid_below_depth(g, g.absorber_m, segments),
        "surface_ml_inner_emitting.ply": emitting_surface(g, segments),
    }
    files = []
    for name, mesh in surfaces.items():
        path = out_dir / name
        atomic_bytes(path, mesh.export(file_type="ply"))
        files.append(path)
    return files


def _geometry_summary(g) -> dict:
    return {
        "n_rods": g.n_rods,
        "pitch_mm": [g.pitch_x_m * 1e3, g.pitch_y_m * 1e3],
        "surface_mm": [g.size_x_m * 1e3, g.size_y_m * 1e3],
        "volume_mm3": g.volume_m3() * 1e9,
        "layer_volume_mm3": {k: v * 1e9 for k, v in g.layer_volumes_m3().items()},
        "ml_inner_area_mm2": g.sheet_area_m2(g.core_depth_m) * 1e6,
    }


def _mesh_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from fem.mesh import MeshParams, build_mesh

    return build_mesh(inputs["geometry"], MeshParams.from_fidelity(scene.fidelity.mesh), progress=ctx.progress)


def _mesh_save(result, directory: Path) -> None:
    mesh, report = result
    mesh.save(directory / "mesh.npz")
    (directory / "report.json").write_text(json.dumps(report, indent=2))


def _mesh_load(directory: Path):
    from fem.mesh import TetMesh

    return TetMesh.load(directory / "mesh.npz"), json.loads((directory / "report.json").read_text())


def _mesh_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from fem.mesh import write_vtu

    mesh, report = result
    vtu = out_dir / "mesh.vtu"
    write_vtu(mesh, vtu)
    rep = out_dir / "mesh_report.json"
    atomic_bytes(rep, json.dumps(report, indent=2).encode())
    return [vtu, rep]


def _mesh_summary(result) -> dict:
    _, report = result
    keys = ("mesh_hash", "n_tets", "n_points", "n_nodes_quadratic", "volume_rel_error", "layer_volume_rel_error", "face_area_rel_error", "quality", "attempts")
    return {k: report[k] for k in keys if k in report}


# Scene fields that decide the linear body of the solve (materials and the solve's discretisation),
# not the load: the ``reduced`` tier's precompute is keyed on these and the mesh.
_BODY_FIELDS = (
    "sensor.materials",
    "materials",
    "fidelity.solve.element_order",
    "fidelity.solve.formulation",
    "fidelity.solve.contact_band_mm",
    "fidelity.solve.patches_per_tip",
    "fidelity.solve.patches_per_side",
    "fidelity.solve.gravity",
    "seed",  # the seeded k-means of the reduced tier's patches
)


def _npz_io(filename: str, cls: str):
    """(save, load) of a result with ``result.save(path)`` and ``Cls.load(path)``; ``cls`` is
    "module:Name", imported when a cached result is loaded (heavy modules stay unimported)."""

    def save(result, directory: Path) -> None:
        result.save(directory / filename)

    def load(directory: Path):
        import importlib

        module, name = cls.split(":")
        return getattr(importlib.import_module(module), name).load(directory / filename)

    return save, load


_solve_save, _solve_load = _npz_io("episode.npz", "fem.quasistatic:Episode")
_reduced_save, _reduced_load = _npz_io("reduced.npz", "fem.quasistatic:ReducedModel")
_transport_save, _transport_load = _npz_io("transport.npz", "mlsim.render:TransportMatrix")
_render_save, _render_load = _npz_io("render.npz", "mlsim.render:RenderResult")
_camera_save, _camera_load = _npz_io("camera.npz", "mlsim.render.output:CameraFrames")
_calibration_save, _calibration_load = _npz_io("calibration.npz", "mlsim.render.calibration_frame:CalibrationFrame")
_dllm_save, _dllm_load = _npz_io("dllm.npz", "dllm.episode:DllmEpisode")


def _solve_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from fem.quasistatic import run_episode

    mesh, _ = inputs["mesh"]
    reduced = None
    if scene.fidelity.solve.tier == "reduced":
        reduced = _cached_reduced(scene, mesh, ctx)
    return run_episode(scene, mesh, reduced=reduced, progress=ctx.progress, log=ctx.log)


# Per-sensor objects that episodes share (the ML sheet's patches and its Mitsuba scene, the reduced
# model, the transport matrix), kept in this process: a worker running a dataset's episodes on one
# sensor builds or loads each once instead of once per episode. Small: a few sensors' worth.
_MEMO: OrderedDict = OrderedDict()
_MEMO_ENTRIES = 8


def _memo(key: tuple, build: Callable[[], Any]):
    if key in _MEMO:
        _MEMO.move_to_end(key)
        return _MEMO[key]
    value = build()
    _MEMO[key] = value
    while len(_MEMO) > _MEMO_ENTRIES:
        _MEMO.popitem(last=False)
    return value


def _cached_precompute(ctx: "RunContext", stage: "Stage", payload: dict, build: Callable[[], Any], message: str):
    """A load-independent precompute (not a stage of the plan) from the cache by the hash of
    ``payload``, else ``build()`` and cache it: a dataset of episodes on one sensor pays once."""
    import hashlib

    key = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()

    def load_or_build():
        if ctx.cache.has(stage.name, key):
            return ctx.cache.fetch(stage, key)
        ctx.log(message)
        result = build()
        ctx.cache.store(stage, key, result)
        return result

    return _memo((stage.name, key, str(ctx.cache.root)), load_or_build)


def _patches_key(scene: Scene) -> tuple:
    """What the emitting patches depend on: the mesh and the sheet's discretisation."""
    return stage_key(scene, "mesh"), scene.fidelity.mesh.segments_per_circle, scene.fidelity.render.sheet_edge_mm * 1e-3


def _patches(scene: Scene, geometry, mesh):
    """The ML sheet's emitting patches of this sensor and mesh (shared in-process)."""
    from mlsim import emission

    key = _patches_key(scene)
    return _memo(("patches",) + key, lambda: emission.ml_patches(geometry, mesh, key[1], key[2]))


def _sheet(scene: Scene, patches):
    """The Mitsuba scene of the sheet (shared in-process; render_frames returns it to its rest shape)."""
    from mlsim import render

    return _memo(("sheet", stage_key(scene, "mesh"), scene.content_hash(_VIEW_FIELDS)), lambda: render.sensor_scene_for(scene, patches))


def _cached_reduced(scene: Scene, mesh, ctx: "RunContext"):
    """The reduced tier's precompute, keyed on the mesh and the body (not the load)."""
    from fem.quasistatic import build_reduced

    # 3: each rod's point compliance and local responses (fem.contact_admm.RodBlockDelassus)
    payload = {"mesh": stage_key(scene, "mesh"), "body": scene.content_hash(_BODY_FIELDS), "version": "3"}
    return _cached_precompute(ctx, _REDUCED_MODEL, payload, lambda: build_reduced(scene, mesh),
                              "[solve] reduced tier: precomputing the contact points' compliance and responses (cached for this sensor)")


def _solve_write(episode, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from fem.vtk_series import write_episode

    files = write_episode(episode, out_dir / "solve", stem="solve")
    files.append(_write_solve_csv(episode, out_dir / "solve_forces.csv"))
    files.append(_plot_solve(episode, out_dir / "solve_forces.png"))
    return files


def _write_solve_csv(ep, path: Path) -> Path:
    """Per frame: time, indenter pose, forces, contact iterations, stick fraction, peak von Mises."""
    import io

    import numpy as np

    k = ep.frame_step
    cols = {
        "frame": np.arange(ep.n_frames),
        "t_s": ep.t_s[k],
        "indenter_x_mm": ep.pose[k, 0] * 1e3,
        "indenter_y_mm": ep.pose[k, 1] * 1e3,
        "indenter_z_mm": ep.pose[k, 2] * 1e3,
        "indenter_yaw_deg": np.degrees(ep.pose[k, 3]),
        "normal_force_n": ep.normal_force_n[k],
        "contact_fx_n": ep.contact_force_n[k, 0],
        "contact_fy_n": ep.contact_force_n[k, 1],
        "contact_fz_n": ep.contact_force_n[k, 2],
        "reaction_x_n": ep.reaction_n[k, 0],
        "reaction_y_n": ep.reaction_n[k, 1],
        "reaction_z_n": ep.reaction_n[k, 2],
        "peak_von_mises_kpa": ep.von_mises[k].max(axis=1) / 1e3,
        "contact_iterations": ep.iterations[k],
        "stick_fraction": ep.stick_fraction[k],
    }
    for r in range(ep.rod_force_n.shape[1]):
        cols[f"rod{r}_normal_force_n"] = -ep.rod_force_n[k, r, 2]
    buf = io.StringIO()
    buf.write(",".join(cols) + "\n")
    np.savetxt(buf, np.column_stack(list(cols.values())), delimiter=",", fmt="%.9g")
    atomic_bytes(path, buf.getvalue().encode())
    return path


def _plot_solve(ep, path: Path) -> Path:
    """Forces and per-rod peak stress over the episode, one PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import matplotlib.ticker

    from mlsim.plots import rod_map, save_png

    k = ep.frame_step
    t = ep.t_s[k] * 1e3
    fig, ax = plt.subplots(1, 3, figsize=(15, 4), constrained_layout=True)
    ax[0].plot(t, ep.normal_force_n[k], "k-o", ms=3, label="normal (-z)")
    ax[0].plot(t, ep.contact_force_n[k, 0], "-s", ms=3, label="x")
    ax[0].plot(t, ep.contact_force_n[k, 1], "-^", ms=3, label="y")
    ax[0].set(xlabel="time (ms)", ylabel="contact force on the sensor (N)", title=f"{ep.tier} tier, {ep.element}")
    ax[0].legend()
    rods = -ep.rod_force_n[k, :, 2]
    im = ax[1].imshow(rods.T, aspect="auto", origin="lower", extent=(t[0], t[-1], -0.5, rods.shape[1] - 0.5), cmap="viridis")
    fig.colorbar(im, ax=ax[1], label="normal force (N)")
    ax[1].set(xlabel="time (ms)", ylabel="rod", title="normal force per rod")
    ax[1].yaxis.set_major_locator(matplotlib.ticker.MaxNLocator(integer=True))
    rod_map(fig, ax[2], ep.rod_peaks()["ml_von_mises_kpa"], "peak von Mises in the ML layer (kPa)", "per-rod peak ML-layer stress", "magma")
    return save_png(fig, path)


def _solve_summary(episode) -> dict:
    return episode.summary()


def _verify_s2_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from fem.verify_s2 import run
    from mlsim.scene import resolve_material

    spec = scene.verify_s2
    materials = {name: resolve_material(name, scene.materials) for name in {spec.slab_material, spec.block_material}}
    return run(spec, progress=ctx.progress, log=ctx.log, materials=materials)


def _pickle_save(result, directory: Path) -> None:
    import pickle

    (directory / "result.pkl").write_bytes(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))


def _pickle_load(directory: Path):
    import pickle

    return pickle.loads((directory / "result.pkl").read_bytes())


def _verify_s2_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from fem.verify_s2 import write

    return write(result, out_dir)


def _verify_s2_summary(result) -> dict:
    from fem.verify_s2 import summary

    return summary(result)


def _emission_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim import emission
    from mlsim.camera import exposure_windows_s
    from mlsim.materials import phosphor_relative_brightness

    geometry, (mesh, _), episode = inputs["geometry"], inputs["mesh"], inputs["solve"]
    spec = scene.emission
    patches = _patches(scene, geometry, mesh)
    params = emission.emission_model(spec.model).params_from(spec)
    scale = float(scene.material("ml_layer").relative_ml_peak.value) * float(phosphor_relative_brightness(scene.sensor.phosphor.loading_wt_pct))
    windows = exposure_windows_s(episode.n_frames, scene.camera.fps, scene.camera.exposure_ms * 1e-3)
    return emission.photon_rates(episode.t_s, episode.stress, windows, patches, spec.model, params, spec.equivalent_stress,
                                 spec.brightness_photons_per_m2, scale)


def _emission_save(result, directory: Path) -> None:
    from mlsim.emission import output

    output.save(result, directory / "emission.npz")


def _emission_load(directory: Path):
    from mlsim.emission import output

    return output.load(directory / "emission.npz")


def _emission_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.emission import output

    return output.write(result, out_dir)


def _emission_summary(result) -> dict:
    from mlsim.emission import output

    return output.summary(result)


# Scene fields that shape the renderer's view of the sheet (not the emission): the transport matrix
# is keyed on these, so a dataset of episodes on one sensor traces it once.
_VIEW_FIELDS = _GEOMETRY_FIELDS + (
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
_AMBIENT_IMAGE_FIELDS = ("ambient.lamp", "ambient.power_w", "ambient.height_m", "ambient.offset_mm", "ambient.efficacy_lm_per_w",
                         "ambient.occlusion", "optics.absorber", "optics.ml_layer_transmittance")


def _render_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    import numpy as np

    from fem.mesh import locate_points
    from mlsim import render

    em, episode = inputs["emission"], inputs["solve"]
    sheet = _sheet(scene, em.patches)
    radiance = render.radiance_of(em.photons_per_s, em.patches.area_m2)
    spec = scene.fidelity.render
    transport = None
    # where each sheet vertex sits in the mesh: of the sensor, not the episode (shared in-process)
    located = _memo(("patches_in_mesh",) + _patches_key(scene),
                    lambda: locate_points(episode.mesh_points, episode.mesh_tets, np.asarray(em.patches.vertices_m, dtype=float)))
    vertices = render.deformed_vertices(episode, em.patches.vertices_m, located)
    if spec.tier == "transport":
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
    if scene.ambient.lamp != "none":
        result.ambient, result.info["ambient"] = _ambient_image(scene, em.patches, sheet, transport)
    return result


def _ambient_image(scene: Scene, patches, sheet, transport):
    """The ambient lamp's leak (mlsim.render.ambient) rendered once on the rest shape, at lamp level 1."""
    from mlsim import render
    from mlsim.render import ambient

    a = scene.ambient
    leak = ambient.leak_through_layers(scene, patches, sheet, lamp=a.lamp, power_w=a.power_w, lamp_m=ambient.lamp_position_m(scene),
                                       absorber=scene.optics.absorber, efficacy_lm_per_w=a.efficacy_lm_per_w, occlusion=a.occlusion)
    spec = scene.fidelity.render
    image = render.render_still(sheet, render.radiance_of(leak.photons_per_s, patches.area_m2), spec.tier, spp=spec.spp,
                                seed=scene.seed ^ 0xA3B1E7, transport=transport)
    top = patches.normals[:, 2] > 0.99
    info = {"radiant_power_w": leak.radiant_power_w, "shaded_fraction": leak.shaded_fraction,
            "irradiance_on_top_w_m2": float(leak.irradiance_w_m2[top].mean()) if top.any() else 0.0,
            "leaked_photons_per_s": float(leak.photons_per_s.sum())}
    return image, info


def _cached_transport(scene: Scene, sheet, ctx: "RunContext"):
    """The transport matrix, keyed on this sensor and view (not the load)."""
    from mlsim.render import trace_transport

    spec = scene.fidelity.render
    payload = {"view": scene.content_hash(_VIEW_FIELDS), "spp": spec.transport_spp, "drop": spec.transport_drop, "seed": scene.seed, "version": "1"}
    return _cached_precompute(
        ctx, _TRANSPORT, payload,
        lambda: trace_transport(sheet, spp=spec.transport_spp, seed=scene.seed, drop=spec.transport_drop, progress=ctx.progress),
        f"[render] transport tier: tracing the light-transport matrix at {spec.transport_spp} spp (cached for this sensor and view)")


def _render_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render import output

    return output.write_render(result, out_dir)


def _render_summary(result) -> dict:
    from mlsim.render import output

    return output.render_summary(result)


def _calibration_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim.render.calibration_frame import calibration_frame

    geometry, (mesh, _) = inputs["geometry"], inputs["mesh"]
    patches = _patches(scene, geometry, mesh)
    sheet = _sheet(scene, patches)
    transport = _cached_transport(scene, sheet, ctx) if scene.fidelity.render.tier == "transport" else None
    return calibration_frame(scene, patches, sheet, transport)


def _calibration_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render.calibration_frame import write_calibration

    return write_calibration(result, out_dir)


def _idle_before(scene: Scene, render_result):
    """The idle frames before the episode on which the DLLM initialises its thresholds (SPEC 1.6)."""
    from dllm.detector import DllmParams
    from mlsim.render.output import idle_frames

    return idle_frames(scene, render_result, DllmParams.from_scene(scene).init_frames)


def _dllm_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from dllm.episode import run_episode

    return run_episode(scene, inputs["camera"], inputs["calibration"].rgb, _idle_before(scene, inputs["render"]))


def _dllm_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from dllm.episode import write

    return write(result, out_dir)


def _classify_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from classifiers.closed_loop import run_loop
    from classifiers.train import load_model
    from dllm.detector import DllmParams
    from dllm.episode import calibrate_scene

    model = load_model(scene.classify.model)
    calibration, _ = calibrate_scene(scene, inputs["calibration"].rgb)
    idle = _idle_before(scene, inputs["render"])
    result = run_loop(inputs["camera"].frames, idle, calibration, DllmParams.from_scene(scene), model, scene.camera.fps, scene.classify.stride)
    for i in range(len(result.classes)):
        if result.classes[i] >= 0:
            ctx.log(f"[classify] t = {result.t_end_s[i]:6.3f} s  {result.names[i]:<14} p {result.probability[i]:.2f}  -> "
                    f"{result.commands[i]:<12} latency {result.latency_ms[i]:.2f} ms")
    s = result.summary()
    ctx.log(f"[classify] {s['active_windows']} of {s['windows']} windows active (the others idle: no DLLM event); "
            f"latency median {s['latency_ms_median']:.2f} ms, max {s['latency_ms_max']:.2f} ms from a window's last frame to its prediction")
    return result


def _classify_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from classifiers.closed_loop import write

    return write(result, out_dir)


def _camera_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim.render import output

    return output.expose(scene, inputs["render"], inputs["emission"])


def _camera_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.render import output

    return output.write_camera(result, out_dir)


def _camera_summary(result) -> dict:
    return result.summary()


# Not a stage of the plan (its need depends on the tier): the solve stage caches it through this.
_REDUCED_MODEL = Stage(name="reduced_model", doc="reduced tier precompute", reads=(), needs=(), run=lambda *a: None,
                       save=_reduced_save, load=_reduced_load)
_TRANSPORT = Stage(name="transport_matrix", doc="transport tier precompute", reads=(), needs=(), run=lambda *a: None,
                   save=_transport_save, load=_transport_load)

_STAGE_LIST = [
    Stage(
        name="geometry",
        doc="parametric rod array; writes the outer surface and the layer surfaces (PLY)",
        reads=_GEOMETRY_FIELDS,
        needs=(),
        run=_geometry_run,
        write=_geometry_write,
        summarize=_geometry_summary,
    ),
    Stage(
        name="mesh",
        doc="labelled quadratic tet mesh (fTetWild), layer fractions, tagged faces; writes VTU",
        # timeout_s and retries change how hard we try, not what an accepted mesh is.
        reads=_GEOMETRY_FIELDS
        + (
            "fidelity.mesh.edge_length_mm",
            "fidelity.mesh.envelope_mm",
            "fidelity.mesh.coarsen",
            "fidelity.mesh.segments_per_circle",
            "fidelity.mesh.fraction_levels",
        ),
        needs=("geometry",),
        run=_mesh_run,
        version="2",  # 2: curved (quadratic) geometry, edge-aware snapping, jittered layer fractions
        save=_mesh_save,
        load=_mesh_load,
        write=_mesh_write,
        summarize=_mesh_summary,
    ),
    Stage(
        name="solve",
        doc="quasi-static FEM of the rods under the scene's load, per frame; writes a VTU time series, forces CSV and plot",
        reads=_BODY_FIELDS + ("load", "camera.fps", "fidelity.solve", "fidelity.mesh.edge_length_mm"),
        needs=("mesh",),
        version="2",  # 2: the reduced tier's contact on each rod's point compliance (issue 15)
        run=_solve_run,
        save=_solve_save,
        load=_solve_load,
        write=_solve_write,
        summarize=_solve_summary,
    ),
    Stage(
        name="emission",
        doc="ZnS:Cu photons per second from each patch of the ML layer's inner face, per camera exposure; writes a VTU series, CSV and plot",
        reads=_BODY_FIELDS + ("sensor", "emission", "camera.fps", "camera.exposure_ms", "fidelity.mesh.segments_per_circle",
                                "fidelity.render.sheet_edge_mm"),
        needs=("geometry", "mesh", "solve"),
        run=_emission_run,
        save=_emission_save,
        load=_emission_load,
        write=_emission_write,
        summarize=_emission_summary,
    ),
    Stage(
        name="render",
        doc="radiance of the ML light at the camera's lens per frame (Mitsuba: transport or path tier); writes radiance.npz and a PNG",
        reads=_VIEW_FIELDS + ("fidelity.render", "seed") + _AMBIENT_IMAGE_FIELDS,
        needs=("emission", "solve"),
        run=_render_run,
        save=_render_save,
        load=_render_load,
        write=_render_write,
        summarize=_render_summary,
    ),
    Stage(
        name="camera",
        doc="8-bit RGB camera frames (radiometry, spectra, noise, ADC); writes an MP4, PNG frames, a contact sheet and a per-frame CSV",
        reads=("camera", "optics", "sensor", "ambient", "seed", "noise_seed"),
        needs=("render", "emission"),
        run=_camera_run,
        save=_camera_save,
        load=_camera_load,
        write=_camera_write,
        summarize=_camera_summary,
    ),
    Stage(
        name="calibration",
        doc="the DLLM's calibration frame: the sensor without its absorber under the white calibration lamp, auto-exposed; writes a PNG and JSON",
        reads=_VIEW_FIELDS + ("fidelity.render", "seed", "calibration", "camera", "optics", "ambient.occlusion"),
        needs=("geometry", "mesh"),
        run=_calibration_run,
        save=_calibration_save,
        load=_calibration_load,
        write=_calibration_write,
        summarize=lambda result: dict(result.info),
    ),
    Stage(
        name="dllm",
        doc="the DLLM detector (SPEC 1.6) on the camera frames: calibration on the calibration frame, thresholds from 1 s of idle frames; "
            "writes the feature time series, the events table and a taxel heatmap",
        reads=("dllm", "camera", "ambient", "optics", "sensor", "seed", "noise_seed"),
        needs=("camera", "calibration", "render"),
        run=_dllm_run,
        save=_dllm_save,
        load=_dllm_load,
        write=_dllm_write,
        summarize=lambda result: result.summary(),
    ),
    Stage(
        name="classify",
        doc="the closed robot loop (SPEC 1.7): the streaming DLLM and the interaction CNN on the last 8 frames; prints a class and a "
            "robot command per window and the latency to each prediction; writes classify.csv (not cached: the model file may change)",
        reads=("classify", "dllm", "camera", "ambient", "optics", "sensor", "seed", "noise_seed"),
        needs=("camera", "calibration", "render"),
        run=_classify_run,
        write=_classify_write,
        summarize=lambda result: result.summary(),
    ),
    Stage(
        name="verify_s2",
        doc="the published FEM set-up of SPEC 1.4 (rod on a slab vs steel block on a slab); profiles CSV and plot, ratios in the summary",
        reads=("verify_s2", "materials"),
        needs=(),
        run=_verify_s2_run,
        save=_pickle_save,  # an internal cache of this code version (the stage key carries the version)
        load=_pickle_load,
        write=_verify_s2_write,
        summarize=_verify_s2_summary,
    ),
]

#: The registered stages, in an order where every stage follows the stages it needs.
STAGES: dict[str, Stage] = {s.name: s for s in _STAGE_LIST}
#: What a scene may list in ``outputs``.
OUTPUTS: tuple[str, ...] = tuple(s.name for s in _STAGE_LIST if s.write is not None)


# ------------------------------------------------------------------------------------ the cache
def default_cache_dir() -> Path:
    """``$MLSIM_CACHE_DIR``, else ``$XDG_CACHE_HOME/mlsim``, else ``~/.cache/mlsim``."""
    if os.environ.get("MLSIM_CACHE_DIR"):
        return Path(os.environ["MLSIM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "mlsim"


class Cache:
    """Stage results on disk, one directory per (stage, key), written atomically (rename)."""

    def __init__(self, root: str | Path | None = None, keep: tuple[str, ...] | None = None):
        """``keep``: store only these stages' results (None: all). A dataset keeps the per-sensor
        stages and precomputes and not each episode's intermediates."""
        self.root = Path(root) if root is not None else default_cache_dir()
        self.keep = None if keep is None else frozenset(keep)

    def keeps(self, stage: str) -> bool:
        return self.keep is None or stage in self.keep

    def path(self, stage: str, key: str) -> Path:
        return self.root / stage / key

    def has(self, stage: str, key: str) -> bool:
        return (self.path(stage, key) / "COMPLETE").is_file()

    def store(self, stage: Stage, key: str, result) -> None:
        final = self.path(stage.name, key)
        final.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{key[:12]}.", dir=final.parent))
        try:
            stage.save(result, tmp)
            (tmp / "COMPLETE").write_text(key)
            if final.exists():
                shutil.rmtree(final)
            os.replace(tmp, final)
        except BaseException:
            shutil.rmtree(tmp, ignore_errors=True)
            raise

    def fetch(self, stage: Stage, key: str):
        return stage.load(self.path(stage.name, key))


# ---------------------------------------------------------------------------------- the planner
def stage_key(scene: Scene, name: str, _memo: dict | None = None) -> str:
    """Content hash of what a stage's result depends on: its code version, the scene fields it
    reads and, recursively, the keys of the stages it needs."""
    import hashlib

    memo = {} if _memo is None else _memo
    if name in memo:
        return memo[name]
    stage = STAGES[name]
    payload = {
        "stage": name,
        "version": stage.version,
        "reads": scene.content_hash(stage.reads),
        "needs": {n: stage_key(scene, n, memo) for n in stage.needs},
    }
    memo[name] = hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()
    return memo[name]


@dataclass
class PlanStep:
    stage: Stage
    key: str
    action: str  # "run" or "load"
    requested: bool


def plan(scene: Scene, cache: Cache | None = None, outputs: tuple[str, ...] | None = None) -> list[PlanStep]:
    """The minimal ordered list of stages that produce ``outputs`` (default: the scene's)."""
    outputs = tuple(scene.outputs if outputs is None else outputs)
    for name in outputs:
        if name not in STAGES:
            raise KeyError(f"unknown output {name!r}; choose from: {', '.join(OUTPUTS)}")
    memo: dict = {}
    actions: dict[str, str] = {}

    def require(name: str) -> None:
        if name in actions:
            return
        key = stage_key(scene, name, memo)
        stage = STAGES[name]
        if cache is not None and stage.save is not None and cache.has(name, key):
            actions[name] = "load"
        else:
            actions[name] = "run"
            for need in stage.needs:
                require(need)

    for name in outputs:
        require(name)
    return [PlanStep(STAGES[n], stage_key(scene, n, memo), actions[n], n in outputs) for n in STAGES if n in actions]


def invalidated(old: Scene, new: Scene) -> list[str]:
    """Names of the stages whose results differ between two scenes (e.g. after ``with_values``)."""
    return [n for n in STAGES if stage_key(old, n) != stage_key(new, n)]


# ---------------------------------------------------------------------------------- the runner
@dataclass
class RunContext:
    scene: Scene
    cache: Cache
    out_dir: Path | None
    progress: bool = True
    log: Callable[[str], None] = print


@dataclass
class RunResult:
    steps: list[PlanStep]
    results: dict[str, Any]
    seconds: dict[str, float]
    files: dict[str, list[Path]] = field(default_factory=dict)
    summary: dict = field(default_factory=dict)


def run(scene: Scene, out_dir: str | Path | None = None, cache: Cache | None = None, outputs: tuple[str, ...] | None = None,
        progress: bool = True, log: Callable[[str], None] = print, scene_path: str | None = None) -> RunResult:
    """Execute the plan: load cached results, run the rest (caching them), write requested outputs
    and a JSON summary to ``out_dir`` (nothing is written when it is None)."""
    cache = cache if cache is not None else Cache()
    steps = plan(scene, cache, outputs)
    out = Path(out_dir) if out_dir is not None else None
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    ctx = RunContext(scene, cache, out, progress, log)
    results: dict[str, Any] = {}
    seconds: dict[str, float] = {}
    files: dict[str, list[Path]] = {}
    for step in steps:
        st = step.stage
        t0 = time.perf_counter()
        if step.action == "load":
            results[st.name] = cache.fetch(st, step.key)
        else:
            log(f"[{st.name}] running")
            results[st.name] = st.run(scene, {n: results[n] for n in st.needs}, ctx)
            if st.save is not None and cache.keeps(st.name):
                cache.store(st, step.key, results[st.name])
        seconds[st.name] = time.perf_counter() - t0
        if step.requested and out is not None and st.write is not None:
            files[st.name] = st.write(results[st.name], out, ctx)
        log(f"[{st.name}] {'loaded from cache' if step.action == 'load' else 'done'} in {seconds[st.name]:.2f} s")
    result = RunResult(steps, results, seconds, files)
    result.summary = _summary(scene, steps, results, seconds, files, scene_path)
    if out is not None:
        path = out / "summary.json"
        atomic_bytes(path, json.dumps(result.summary, indent=2, default=str).encode())
        files["summary"] = [path]
    return result


def _summary(scene, steps, results, seconds, files, scene_path) -> dict:
    import mlsim

    return {
        "mlsim_version": mlsim.__version__,
        "scene": {"name": scene.name, "path": scene_path, "hash": scene.content_hash(), "seed": scene.seed},
        "outputs": {k: [p.name for p in v] for k, v in files.items()},
        "stages": {
            s.stage.name: {
                "key": s.key,
                "action": s.action,
                "seconds": seconds[s.stage.name],
                **({"summary": s.stage.summarize(results[s.stage.name])} if s.stage.summarize else {}),
            }
            for s in steps
        },
        "versions": package_versions(),
    }


def package_versions() -> dict:
    """The Python version and the versions of the packages results depend on (for run summaries
    and dataset metadata)."""
    import platform
    from importlib import metadata

    out = {"python": platform.python_version()}
    for pkg in ("mlsim", "numpy", "scipy", "pydantic", "trimesh", "manifold3d", "pytetwild", "meshio", "scikit-fem", "pypardiso", "mitsuba",
                "drjit", "colour-science", "opencv-contrib-python-headless", "torch", "zarr"):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            pass
    return out


def atomic_bytes(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` under a temporary name and rename: never a half-written file."""
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_bytes(data)
    os.replace(tmp, path)
    return path
