"""The emission stage of the ML rod array (``mlsim.ml_rod_array``): ZnS:Cu photons from the stress
history, per patch of the ML sheet and camera exposure; and the sheet's patches, which the render
and calibration stages share."""

from __future__ import annotations

from pathlib import Path

from mlsim.scene import Scene
from fem.stages import BODY_FIELDS
from mlsim.stage import RunContext, Stage, cached_precompute, memo, stage_key

__all__ = ["EMISSION", "ML_PATCHES", "PATCHES_IN_MESH", "patches_key", "patches_of", "patches_in_mesh"]


def patches_key(scene: Scene) -> tuple:
    """What the emitting patches depend on: the mesh and the sheet's discretisation."""
    return stage_key(scene, "mesh"), scene.fidelity.mesh.segments_per_circle, scene.fidelity.render.sheet_edge_mm * 1e-3


def _patches_payload(key: tuple) -> dict:
    """The cache payload of a precompute of the ML sheet on a mesh (:func:`patches_key`'s key)."""
    return {"mesh": key[0], "segments_per_circle": key[1], "sheet_edge_m": key[2], "version": "1"}


def patches_of(scene: Scene, geometry, mesh, ctx: "RunContext | None" = None):
    """The ML sheet's emitting patches of this sensor and mesh (shared in-process; with ``ctx``, also
    in its cache: building them, 1.9 s, was most of a fresh dataset worker's first emission)."""
    from mlsim import emission

    key = patches_key(scene)
    build = lambda: emission.ml_patches(geometry, mesh, key[1], key[2])  # noqa: E731
    if ctx is None:
        return memo(("patches",) + key, build)
    return cached_precompute(ctx, ML_PATCHES, _patches_payload(key), build, "[emission] the ML sheet's patches (cached for this sensor)")


def patches_in_mesh(scene: Scene, points, tets, patches, ctx: "RunContext | None" = None):
    """Where each of the sheet's vertices sits in the sensor's mesh (points, tets): (tet (N,), bary
    (N, 4)) of :func:`fem.mesh.locate_points`. Shared in-process; with ``ctx``, also in its cache
    (0.9 s of a fresh dataset worker's first render)."""
    import numpy as np

    from fem.mesh import locate_points

    key = patches_key(scene)
    build = lambda: locate_points(points, tets, np.asarray(patches.vertices_m, dtype=float))  # noqa: E731
    if ctx is None:
        return memo(("patches_in_mesh",) + key, build)
    return cached_precompute(ctx, PATCHES_IN_MESH, _patches_payload(key), build, "[render] the sheet's vertices located in the mesh (cached for this sensor)")


def _located_save(located, directory: Path) -> None:
    import numpy as np

    tet, bary = located
    np.savez(directory / "located.npz", tet=tet, bary=bary)


def _located_load(directory: Path):
    import numpy as np

    with np.load(directory / "located.npz") as data:
        return data["tet"], data["bary"]


def _patches_save(patches, directory: Path) -> None:
    import dataclasses

    import numpy as np

    np.savez(directory / "patches.npz", **dataclasses.asdict(patches))


def _patches_load(directory: Path):
    import numpy as np

    from mlsim.emission.patches import MLPatches

    with np.load(directory / "patches.npz") as data:
        return MLPatches(**{name: data[name] for name in data.files})


PATCHES_IN_MESH = Stage(name="ml_patches_in_mesh", doc="the sheet's vertices located in the sensor's mesh (a precompute of the mesh)",
                        reads=(), needs=(), run=lambda *a: None, save=_located_save, load=_located_load)

# Not a stage of the plan: the emission and calibration stages cache the patches through this.
ML_PATCHES = Stage(name="ml_patches", doc="the ML sheet's emitting patches (a precompute of the sensor's mesh)", reads=(), needs=(),
                   run=lambda *a: None, save=_patches_save, load=_patches_load)


def _emission_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim import emission
    from mlsim.camera import exposure_windows_s
    from mlsim.materials import phosphor_relative_brightness

    geometry, (mesh, _), episode = inputs["geometry"], inputs["mesh"], inputs["solve"]
    spec = scene.emission
    patches = patches_of(scene, geometry, mesh, ctx)
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


EMISSION = Stage(
    name="emission",
    doc="ZnS:Cu photons per second from each patch of the ML layer's inner face, per camera exposure; writes a VTU series, CSV and plot",
    reads=BODY_FIELDS + ("sensor", "emission", "camera.fps", "camera.exposure_ms", "fidelity.mesh.segments_per_circle",
                            "fidelity.render.sheet_edge_mm"),
    needs=("geometry", "mesh", "solve"),
    run=_emission_run,
    save=_emission_save,
    load=_emission_load,
    write=_emission_write,
    summarize=_emission_summary,
)
