"""The FEM stages of the ML rod array (``mlsim.ml_rod_array``): the parametric geometry, the tet mesh
and the quasi-static solve (the verification case of SPEC 1.4 is a study: :mod:`mlsim.studies.stages`).
Each stage imports its heavy dependencies inside its functions."""

from __future__ import annotations

import json
from pathlib import Path

from mlsim.io import atomic_bytes
from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage, cached_precompute, npz_io, stage_key

__all__ = ["GEOMETRY_FIELDS", "BODY_FIELDS", "GEOMETRY", "MESH", "SOLVE", "REDUCED_MODEL", "reduced_model_payload"]

# Scene fields that shape the rod array's geometry (shared by geometry and mesh).
GEOMETRY_FIELDS = (
    "sensor.rows",
    "sensor.cols",
    "sensor.surface_size_mm",
    "sensor.pitch_mm",
    "sensor.rod",
    "sensor.base",
    "sensor.layers",
)



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
BODY_FIELDS = (
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



#: the solve's fields that only the linear tiers read, and those that only the nonlinear tier reads
#: (fem.quasistatic, fem.finite_strain): each tier's cached episode is kept whatever the others' are (the
#: dynamics' fields are also read by the linear tiers' Cosserat rods, fem.quasistatic.rod_inertia)
REDUCED_TIER_ONLY = ("fidelity.solve.patches_per_tip", "fidelity.solve.patches_per_side")
LINEAR_TIERS_ONLY = tuple(f"fidelity.solve.{f}" for f in ("rod_kinematics", "rod_coupling", "buckling_limit", "small_strain_limit",
                                                            "contact_solver")) + REDUCED_TIER_ONLY
NONLINEAR_TIER_ONLY = tuple(f"fidelity.solve.{f}" for f in ("nonlinear_newton", "dynamics", "loss_factor", "steps_per_period"))


def _solve_ignores(scene: Scene) -> tuple[str, ...]:
    """The solve fields this scene's tier does not read (Stage.ignores)."""
    tier = scene.fidelity.solve.tier
    if tier == "nonlinear":
        return LINEAR_TIERS_ONLY
    nonlinear_only = NONLINEAR_TIER_ONLY
    if scene.fidelity.solve.rod_kinematics == "cosserat":  # its rods' inertia reads the dynamics' fields (fem.quasistatic.rod_inertia)
        nonlinear_only = ("fidelity.solve.nonlinear_newton",)
    return nonlinear_only + (REDUCED_TIER_ONLY if tier == "linear" else ())


_solve_save, _solve_load = npz_io("episode.npz", "fem.quasistatic:Episode")
_reduced_save, _reduced_load = npz_io("reduced.npz", "fem.quasistatic:ReducedModel")


def _solve_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from fem.quasistatic import run_episode

    mesh, _ = inputs["mesh"]
    reduced = body = None
    if scene.fidelity.solve.tier == "reduced":
        reduced = _cached_reduced(scene, mesh, ctx)
    if scene.fidelity.solve.tier == "linear":
        body = _last_linear_body(scene, mesh)
    return run_episode(scene, mesh, body=body, reduced=reduced, progress=ctx.progress, log=ctx.log)


# The linear tier's assembled and factorised body of the last sensor solved in this process: the loads
# of a sweep's variant and the angles of a direction study share it (16.6 s of a 30 s press on the
# default sensor: 13.2 s assembly, 3.1 s factorisation, before 7f04b7c cut the assembly about 3x). One entry:
# a factorisation is hundreds of MB.
_LAST_BODY: list = [None, None]


def _last_linear_body(scene: Scene, mesh):
    from fem.episode import SolveSettings, layer_materials
    from fem.quasistatic import LinearBody

    settings = SolveSettings.from_scene(scene)
    key = (stage_key(scene, "mesh"), scene.content_hash(BODY_FIELDS), settings.element, settings.gravity, settings.backend)
    if _LAST_BODY[0] != key:
        _LAST_BODY[:] = [None, None]  # the old factorisation goes before the new one is made
        lame, rho, _ = layer_materials(scene)
        _LAST_BODY[:] = [key, LinearBody(mesh, lame, rho, settings.element, settings.gravity, settings.backend)]
    return _LAST_BODY[1]


def reduced_model_payload(scene: Scene) -> dict:
    """What the reduced tier's precompute is keyed on: the mesh and the body (not the load); its cache key is
    the hash of this (:func:`mlsim.stage.precompute_key`), which the run's estimate also reads."""
    # 3: each rod's point compliance and local responses (fem.contact_admm.RodBlockDelassus);
    # 4: the patch responses off their own rod in low-rank form (fem.quasistatic.far_field_basis);
    # 5: their SVDs on one BLAS thread (the same model to round-off: on two threads 70 of the screw
    # sensor's 14.8 M stress basis entries differed in their last bit, and the coefficients in round-off);
    # 6: the far field's sparse rows saved with it (ReducedModel.save; each worker made them, 0.47 s)
    return {"mesh": stage_key(scene, "mesh"), "body": scene.content_hash(BODY_FIELDS), "version": "6"}


def _cached_reduced(scene: Scene, mesh, ctx: "RunContext"):
    """The reduced tier's precompute, keyed on the mesh and the body (not the load)."""
    from fem.quasistatic import build_reduced

    payload = reduced_model_payload(scene)
    return cached_precompute(ctx, REDUCED_MODEL, payload, lambda: build_reduced(scene, mesh),
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


# Not a stage of the plan (its need depends on the tier): the solve stage caches it through this.
REDUCED_MODEL = Stage(name="reduced_model", doc="reduced tier precompute", reads=(), needs=(), run=lambda *a: None,
                      save=_reduced_save, load=_reduced_load)

GEOMETRY = Stage(
    name="geometry",
    doc="parametric rod array; writes the outer surface and the layer surfaces (PLY)",
    reads=GEOMETRY_FIELDS,
    needs=(),
    run=_geometry_run,
    write=_geometry_write,
    summarize=_geometry_summary,
)

MESH = Stage(
    name="mesh",
    doc="labelled quadratic tet mesh (fTetWild), layer fractions, tagged faces; writes VTU",
    # timeout_s and retries change how hard we try, not what an accepted mesh is.
    reads=GEOMETRY_FIELDS
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
)

SOLVE = Stage(
    name="solve",
    doc="quasi-static FEM of the rods under the scene's load, per frame; writes a VTU time series, forces CSV and plot",
    reads=BODY_FIELDS + ("load", "camera.fps", "fidelity.solve", "fidelity.mesh.edge_length_mm"),
    needs=("mesh",),
    version="25",  # 2: the reduced tier's contact on each rod's point compliance; 3: its rod sections observed exactly; 4: the nonlinear tier's condensed Newton; 5: the reduced tier's contact point by point and its far field in low rank (issue 15); 6: the reduced tier's rho ladder from the sensor's contact operator, the condensed Newton the nonlinear default; 7: the linear tiers' geometric error estimate from the episode's own field; 8: the reduced tier's rod blocks in float32 for loose solves, 600 ADMM iterations per linearisation; 9: Anderson acceleration on the ADMM map's Douglas-Rachford state, MKL PARDISO in its reproducible mode; 10: the nonlinear tier's condensed Newton relinearised at a step it cannot do; 11: the reduced tier's far field read without its entries below 1e-3 of each basis vector's largest; 12: second-order rod kinematics refuse a rod past half its Euler buckling load (fidelity.solve.buckling_limit); 13: the nonlinear tier's implicit dynamics (fidelity.solve.dynamics) and its one full-step Newton for dead loads; 14: the nonlinear tier's condensed Newton solves its contact loosely while far from balance and keeps a fresh linearisation under dynamics; 15: its contact solves linearised at the last iterate (the start kept for points an iterate carried off the indenter), a failed step retried following its iterates; 16: its outer iteration to a relative residual of 1e-4 (was 1e-6), a quasi-static step following its iterates before a fresh linearisation; 17: Cosserat rods' axial law neo-Hookean and their section stress Cauchy's, fidelity.solve.rod_coupling ("held": the rods held by the contact in their solves, a Robin coupling); 18: the Cosserat rods' rounds tested on their residual (the force a round moves over its relaxation), held rounds relaxed by 0.15 in up to 60 rounds; 19: the Cosserat rods' own force error estimate and their releases of bent rods (fem.rod_error.force_error_estimate); 20: a held rods' step whose rounds do not settle in their first budget cut in halves, two levels, before their relaxation is halved (fem.condensed.solve_path; not under force control); 21: the Cosserat rods' trust region compiled where a rod's Hessian is indefinite (fem.cosserat_kernels), a held rods' step that fails with a rod past its free Euler load refused as the rods' collapse (RodCollapseError, with the load they collapse at: mlsim sweep records it); 22: the Cosserat rods' bending and shear stiffnesses identified from the mesh's rods where their lateral tip compliance is off the section's beyond their spread (fem.rod_error.identified_stiffness_scale); 23: under the Cosserat rods' inertia their contact rounds also settle to a tenth of the force their step moved, down to 1e-5 of the normal force (at 1e-3 of it alone held rods jittered and lit); 24: the Cosserat rods' estimate lists the rods dragged over near buckling (sliding past L / 10 sideways under half their free Euler load: fem.rod_error.BENT_AXIAL), where it does not hold; 25: the Cosserat rods' bending stiffness identified from the mesh's rods' tip compliance to a couple and their shear stiffness from that to a sideways force (fem.rod_error.identified_section_scales: a flat face guides a rod, and its deflection is the difference of the two)
    run=_solve_run,
    ignores=_solve_ignores,
    save=_solve_save,
    load=_solve_load,
    write=_solve_write,
    summarize=_solve_summary,
)
