"""What a run of a scene will cost before it starts: per stage the frames, the solve steps, the
mesh size, the memory and the time it expects (base layer: a pure function of the scene).

Every figure is a stated model calibrated on measured runs (2 cores, 2026-11-26/27, quoted in the
README and ``benchmarks/``); ``benchmarks/bench_cost_model.py`` runs scenes from an empty cache and
prints each stage's estimate beside what it took. Times are calibrated against each stage's CPU
seconds, which the other jobs of a shared machine do not stretch: the wall time of a stage on one
core on an idle machine, up to twice its wall time where it keeps both cores busy (PARDISO, Mitsuba).
The model is meant to be right within a factor of two, which is what a budget needs (will this run
take seconds, minutes or hours; megabytes or tens of gigabytes), not a timing prediction.

The sizes follow from the scene alone:

- tetrahedra: the body's volume over a regular tetrahedron's of the target edge, times
  ``TETS_PER_REGULAR_TET`` (fTetWild refines at the layers and the rods' curved sides: the default
  demo's 2 mm mesh has 16,848 tets for 7,436 regular ones, 2.3 x; the tiny scene's 2.5 mm mesh
  1,585-2,027 for 609, 2.6-3.3 x);
- frames and solve steps: :func:`fem.trajectory.time_grid`'s rule (the load's duration rounded up
  to a frame, plus the first frame and one after), steps ``1 + (frames - 1) substeps``.

A stage without a model (a cheap stage, one never measured) is listed with no estimate. The other
sensor kinds price their own stages through the kind's ``cost`` hook (:class:`mlsim.stage.SensorKind`;
the sibling kinds' in ``other_sensors/<kind>/plausibility.py``, from their measured bytes and seconds
per sample or tick), which :func:`stage_cost` calls: this module imports no kind.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["StageCost", "episode_frames", "idle_frames", "solve_steps", "estimated_tets", "stage_cost", "process_bytes", "STAGE_MODELS", "GB"]

GB = 1024**3

# fTetWild's tets per regular tet of the target edge (the module docstring's two meshes: 2.3-3.3 x)
TETS_PER_REGULAR_TET = 2.5
# quadratic nodes and vertices per tet of the shipped meshes (default: 32,222 and 5,349 for 16,848)
NODES_PER_TET = 1.9
VERTICES_PER_TET = 0.32
# fTetWild, curved P2 nodes, layer fractions: the default mesh in 20-75 s (README, bench_sweep), the
# tiny one in 13 CPU s (bench_cost_model, 2026-11-27): 8 s to start the fTetWild worker and load its
# libraries, then about 2.5 ms per tet
MESH_S_PER_TET = 2.5e-3
MESH_OVERHEAD_S = 8.0
# the linear body (P2-P1 assembly and MKL PARDISO's factors): "about 1 GB on the default mesh" per
# sweep worker (mlsim.cli sweep --workers), i.e. 60 kB per tet; its assembly and factorisation
# 16.6 s of a 30 s press on the default mesh (c5efea4)
BODY_BYTES_PER_TET = 6.0e4
BODY_S_PER_TET = 1.0e-3
# the solve's imports (scikit-fem, numba's cached kernels, PARDISO) and set-up: the tiny scene's
# solve took 3.9 CPU s for 1.6 s of body and steps (bench_cost_model, 2026-11-27)
SOLVE_FIXED_S = 2.5
# a solve step: the linear tier 45.7 ms per frame on the default demo (bench_tiers, median of 9) and
# 7.4 ms on the tiny scene's (2026-11-27): 2.2 ms + 2.6 us per tet; the reduced tier 2.8 ms on the
# default demo (17x less); the nonlinear tier 15.8 s per frame on the default demo, 4.8 s on the screw
SOLVE_STEP_S = {"linear": (2.2e-3, 2.6e-6), "reduced": (0.5e-3, 0.14e-6), "nonlinear": (0.5, 0.9e-3)}
# the fast tiers with Cosserat rods (fem.rod_exact): their contact rounds, each a contact solve of the tier, and
# the rods' solves: the default demo 189 ms a frame on the reduced tier and 972 ms on the linear one (mlsim
# accuracy, solve stage 20, 2026-11-29), against 2.8 and 33 ms at first order: 25 rounds and 5 ms per rod and step
COSSERAT_ROUNDS = 25
COSSERAT_S_PER_ROD_STEP = 5.0e-3
# per step the episode keeps float32 stress (6), von Mises and energy per tet and the vertices'
# displacement (fem.quasistatic.Episode), and float64 fields of each distinct load while recovering them
SOLVE_BYTES_PER_STEP_TET = 4 * (6 + 1 + 1) + 8 * 6
SOLVE_BYTES_PER_STEP_NODE = 8 * 3
# the reduced tier's precompute: a response per contact patch (about 7 + 8 per rod) on every node
REDUCED_PATCHES_PER_ROD = 15
# emission: the sheet's vertices from its area at fidelity.render.sheet_edge_mm (a triangle per
# half square), a few float64 arrays per vertex and frame; the sheet's patches made once per run:
# the default demo's emission 1.7 CPU s, the tiny scene's 0.22 (bench_cost_model, 2026-11-27)
EMISSION_BYTES_PER_VERTEX_FRAME = 8 * 6
EMISSION_S_PER_VERTEX_FRAME = 2.0e-7
EMISSION_S_PER_VERTEX = 2.5e-4
EMISSION_FIXED_S = 0.2
# render: the deformed tier 250-307 frames/s on the demo after an 18-22 s precompute (README); path
# tracing about 1 s per 16 spp frame of 350 x 350 on 2 cores; the transport tier's product ~1 ms
RENDER_FRAME_S = {"deformed": 3.5e-3, "transport": 1.0e-3}
# the precompute from an empty cache (the bounce or transport matrix traced at transport_spp, the
# raster's tables) grows with the sheet: the default demo's 90.6 CPU s, the tiny scene's 18.2
# (bench_cost_model, 2026-11-27; README's 18-22 s of bench_deformed had its matrix cached)
RENDER_PRECOMPUTE_FIXED_S = {"deformed": 8.0, "transport": 6.0, "path": 2.0}
RENDER_PRECOMPUTE_S_PER_VERTEX = {"deformed": 0.017, "transport": 0.013, "path": 0.0}
# with the matrix in the cache: loaded, and the deformed tier's rasteriser (cached too since 2026-11-29, issue 40; made
# in-process before, 0.1-0.4 s): the default demo's render stage took 0.74 s for its 22 frames (make demo, 2026-11-29)
RENDER_CACHED_MATRIX_S = 0.7
PATH_S_PER_SAMPLE = 1.0 / (16 * 350 * 350)
# the transport matrix: 2.61 M entries on the demo at 64 spp (96069d7), 12 bytes each
TRANSPORT_ENTRIES_PER_PIXEL_SPP = 2.61e6 / (350 * 350 * 64)
# camera: per frame the native pixels (binning^2 per output pixel) in float64 through the noise model
CAMERA_BYTES_PER_NATIVE_PIXEL = 8 * 4
CAMERA_S_PER_NATIVE_PIXEL = 1.2e-8  # the default demo's 52 frames: 1.3 CPU s, the tiny scene's 38: 1.8
# Mitsuba's and numpy's own footprint once imported (a process that renders)
RENDER_PROCESS_BYTES = 1.0 * GB
# a run's process before any stage's result: python, numpy, scipy, pydantic and the project's modules,
# about 0.3 GB resident with the ml_rod_array kind's stage code; a sibling kind's run measured 0.13 GB
# max RSS in all (scenes/sole/balance_push.toml and balance_sweep.toml, bench_cost_model --siblings,
# 2026-11-27: 0.132 and 0.134 GB), its stages' results a few MB
ML_PROCESS_BYTES = 0.3 * GB
INTERPRETER_BYTES = 0.13 * GB


@dataclass(frozen=True)
class StageCost:
    """One stage's expected cost: ``memory_bytes`` (the peak it adds and keeps: its result),
    ``seconds`` (wall time on 2 cores), the sizes they come from (frames, solve steps, tets; None where
    not relevant), and ``transient_bytes``, what it holds only while it runs (a study's re-simulated
    traces, freed before the next stage; :class:`mlsim.run_budget.RunEstimate` counts the largest)."""

    stage: str
    memory_bytes: float
    seconds: float
    frames: int | None = None
    steps: int | None = None
    tets: int | None = None
    note: str = ""
    transient_bytes: float = 0.0


def episode_frames(duration_s: float, fps: float, extra_frames: int = 1) -> float:
    """Frames of an episode of ``duration_s`` at ``fps`` (:func:`fem.trajectory.time_grid`'s rule), as
    a float so that an absurd duration gives a huge number (or inf), never an overflow."""
    frames = duration_s * fps
    if not math.isfinite(frames):
        return math.inf
    return float(math.ceil(frames - 1e-9) + 1 + extra_frames)


def idle_frames(scene) -> float:
    """The idle frames before the episode that set the DLLM's thresholds (``dllm.init_s``, SPEC 1.6:
    1 s), which the camera makes too; a float (inf for an absurd duration)."""
    frames = scene.dllm.init_s * scene.camera.fps
    return float(math.ceil(frames)) if math.isfinite(frames) else math.inf


def solve_steps(frames: float, substeps: int) -> float:
    """Solve steps of ``frames`` camera frames with ``substeps`` per frame interval."""
    return 1.0 + max(frames - 1.0, 0.0) * substeps


def body_volume_mm3(sensor) -> float:
    """The elastomer's volume (mm^3): the base slab and the rods (the ml_rod_array kind's sensor)."""
    radius = sensor.rod.diameter_mm / 2.0
    return sensor.size_x_mm * sensor.size_y_mm * sensor.base.thickness_mm + sensor.n_rods * math.pi * radius * radius * sensor.rod.height_mm


def estimated_tets(scene) -> float:
    """The mesh's tetrahedra expected at ``fidelity.mesh.edge_length_mm`` (module docstring)."""
    edge = scene.fidelity.mesh.edge_length_mm
    regular_mm3 = edge * edge * edge / (6.0 * math.sqrt(2.0))  # (a product: a power past 1e308 raises, a product is inf)
    return TETS_PER_REGULAR_TET * body_volume_mm3(scene.sensor) / regular_mm3 if regular_mm3 > 0 else math.inf


def _frames(scene) -> float:
    return episode_frames(scene.load.duration_s, scene.camera.fps) if scene.load is not None else 0.0


def _sheet_vertices(scene) -> float:
    s = scene.sensor
    radius = s.rod.diameter_mm / 2.0
    area_mm2 = s.size_x_mm * s.size_y_mm + s.n_rods * 2.0 * math.pi * radius * s.rod.height_mm
    return area_mm2 / (0.5 * scene.fidelity.render.sheet_edge_mm**2) / 2.0


def _mesh(scene) -> StageCost:
    tets = estimated_tets(scene)
    return StageCost("mesh", tets * 2000.0, MESH_OVERHEAD_S + MESH_S_PER_TET * tets, tets=int(min(tets, 2**62)))


def _solve(scene, precompute_cached: bool = False) -> StageCost:
    tets = estimated_tets(scene)
    nodes = NODES_PER_TET * tets
    frames = _frames(scene)
    settings = scene.fidelity.solve
    steps = solve_steps(frames, settings.substeps)
    fixed, per_tet = SOLVE_STEP_S[settings.tier]
    if settings.tier != "nonlinear" and settings.rod_kinematics == "cosserat":
        fixed, per_tet = COSSERAT_ROUNDS * fixed + COSSERAT_S_PER_ROD_STEP * scene.sensor.n_rods, COSSERAT_ROUNDS * per_tet
    body = BODY_BYTES_PER_TET * tets
    precompute = BODY_S_PER_TET * tets
    if settings.tier == "reduced":
        body += REDUCED_PATCHES_PER_ROD * scene.sensor.n_rods * 3 * nodes * 8
        # a response per contact patch after the factorisation: the screw scene's reduced solve took
        # 138 CPU s from an empty cache (bench_cost_model, 2026-11-27), 7 x the linear body's; after issue 40's
        # precompute work 22.7 s (the screw scene) and 29.6 s (the default demo, Cosserat rods) from a cache
        # holding only the mesh (2026-11-29, mlsim run --outputs solve): 1.2 x
        precompute *= 1.2
        if precompute_cached:
            # the sensor's reduced model loaded from the cache (fem.stages.reduced_model_payload): with it counted the
            # default demo's solve from that cache was priced 29 s where it took 5.8 s (now 7.0 s; 2026-11-29). The swipe's
            # is still 41.6 s against 11 s: its steps are lighter than the demo's, whose rounds the Cosserat price is
            precompute = 0.0
    memory = body + steps * (SOLVE_BYTES_PER_STEP_TET * tets + SOLVE_BYTES_PER_STEP_NODE * VERTICES_PER_TET * tets)
    seconds = SOLVE_FIXED_S + precompute + steps * (fixed + per_tet * tets)
    note = settings.tier + (" (its precompute cached)" if settings.tier == "reduced" and precompute_cached else "")
    return StageCost("solve", memory, seconds, frames=_int(frames), steps=_int(steps), tets=_int(tets), note=note)


def _emission(scene) -> StageCost:
    frames, vertices = _frames(scene), _sheet_vertices(scene)
    seconds = EMISSION_FIXED_S + vertices * EMISSION_S_PER_VERTEX + frames * vertices * EMISSION_S_PER_VERTEX_FRAME
    return StageCost("emission", frames * vertices * EMISSION_BYTES_PER_VERTEX_FRAME, seconds,
                     frames=_int(frames))


def _render(scene, precompute_cached: bool = False) -> StageCost:
    frames = _frames(scene)
    r = scene.fidelity.render
    pixels = scene.camera.width_px * scene.camera.height_px
    memory = RENDER_PROCESS_BYTES + frames * pixels * 4
    if r.tier == "path":
        per_frame = PATH_S_PER_SAMPLE * pixels * r.spp
    else:
        per_frame = RENDER_FRAME_S[r.tier] * pixels / (350 * 350) * (r.direct_samples_per_side**2 if r.tier == "deformed" else 1)
        memory += TRANSPORT_ENTRIES_PER_PIXEL_SPP * pixels * r.transport_spp * 12
    per_vertex = RENDER_PRECOMPUTE_S_PER_VERTEX[r.tier] * (pixels / (350 * 350)) * (r.transport_spp / 64)
    precompute = RENDER_PRECOMPUTE_FIXED_S[r.tier] + per_vertex * _sheet_vertices(scene)
    cached = precompute_cached and r.tier in ("transport", "deformed")
    if cached:
        # the matrix (mlsim.render.stage.transport_payload) and the deformed tier's rasteriser loaded from the cache: priced
        # at the whole precompute, the default demo's render was 90 s where it took 0.74 (make demo, 2026-11-29)
        precompute = RENDER_CACHED_MATRIX_S
    return StageCost("render", memory, precompute + frames * per_frame, frames=_int(frames), note=r.tier + (" (its matrix cached)" if cached else ""))


def _camera(scene) -> StageCost:
    frames = _frames(scene)
    c = scene.camera
    native = c.width_px * c.height_px * c.binning**2
    # the idle frames before the episode (dllm.init_s) go through the same noise model
    frames_all = frames + idle_frames(scene)
    memory = native * CAMERA_BYTES_PER_NATIVE_PIXEL + frames_all * c.width_px * c.height_px * 3
    return StageCost("camera", memory, 0.5 + frames_all * native * CAMERA_S_PER_NATIVE_PIXEL, frames=_int(frames_all))


def _calibration(scene) -> StageCost:
    # after the render stage (Mitsuba loaded, the sensor's scene built) the default demo's took 0.07
    # CPU s (bench_cost_model, 2026-11-27); alone it builds the scene first
    pixels = scene.camera.width_px * scene.camera.height_px
    return StageCost("calibration", 0.2 * GB + pixels * 3 * 8, 0.5 + pixels * 1e-6)


def process_bytes(scene) -> float:
    """The run's process before any stage's result (bytes): the interpreter and the kind's libraries."""
    return ML_PROCESS_BYTES if scene.kind == "ml_rod_array" else INTERPRETER_BYTES


def _int(value: float) -> int | None:
    return int(value) if math.isfinite(value) and value < 2**62 else None


#: the ml_rod_array kind's stages with a cost model (the others: small, or not modelled)
STAGE_MODELS = {"mesh": _mesh, "solve": _solve, "emission": _emission, "render": _render, "camera": _camera, "calibration": _calibration}


def stage_cost(scene, stage: str, precompute_cached: bool = False) -> StageCost | None:
    """The expected cost of running ``stage`` on ``scene``; None where no model applies (a stage whose
    cost is negligible or not measured, a scene without the section it needs). Another sensor kind's
    stages are priced by its ``cost`` hook (None without one). ``precompute_cached``: the stage's
    load-independent precompute (the solve's reduced-tier model, the render's matrix) is in the cache, and
    is not priced."""
    if scene.kind != "ml_rod_array":
        from mlsim.stage import kind

        hook = kind(scene.kind).cost
        return hook(scene, stage) if hook is not None else None
    model = STAGE_MODELS.get(stage)
    if model is None or (stage not in ("mesh", "calibration") and scene.load is None):
        return None
    if stage in ("solve", "render"):
        return model(scene, precompute_cached)
    return model(scene)
