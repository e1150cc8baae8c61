"""Plausibility of a scene (base layer): values that are each well-formed, and together consistent,
but describe an experiment that leaves the sensor or a run that no machine we run on could finish.

:func:`problems` refuses (``mlsim check`` and every load of a scene), naming the field, the value,
the limit and the fix:

- a press that takes the indenter's lowest point past the rods' full height below their tips, where
  it meets the base (a 100 mm press of the default demo ended in a numpy traceback, a 1e9 mm one in
  22 GB resident and the kernel's out-of-memory killer);
- a slide that carries the probe off the sensor: its reference point further from the sensing
  surface than the probe's reach (:func:`footprint_radius_mm`), so that nothing of it is over the
  surface any more (a 1 km slide ran for minutes with no estimate). A probe may overhang the edge
  (a 12 mm punch dragged 8 mm over the tiny scene's 14.4 mm array is a test of friction). The path
  is straight within a segment and the surface a rectangle, so each segment's end point is the
  farthest it goes. A ``rotate`` segment turns the indenter about the vertical axis through that
  point (:mod:`fem.trajectory`), which never moves it: a rotation cannot carry the probe off the
  sensor in this load model;
- an episode of more than ``MAX_EPISODE_FRAMES`` camera frames or ``MAX_SOLVE_STEPS`` solve steps
  (a slide at 1e-9 mm/s asked numpy for 335 GiB of step times);
- a run whose estimated memory (:mod:`mlsim.cost_model`) passes ``MAX_RUN_MEMORY_GB``.

:func:`warnings` lists what is plausible but expensive, with the estimate (printed by ``mlsim check``).

The other sensor kinds judge their own scenes (``other_sensors/<kind>/plausibility.py``, through the
kind's ``check`` and ``warnings`` hooks, :class:`mlsim.stage.SensorKind`) against the same memory
limits, through :func:`memory_problem` and :func:`cost_warnings`.

Force-controlled presses have no depth before the solve: a force ramp is taken to leave the
indenter at the rod tips (the least it can reach), so a later depth-controlled press is judged
from there, and the check never refuses a load that could be valid.
"""

from __future__ import annotations

import math

from mlsim import cost_model
from mlsim.errors import Problem

__all__ = ["MAX_EPISODE_FRAMES", "MAX_SOLVE_STEPS", "MAX_RUN_MEMORY_GB", "WARN_RUN_MEMORY_GB", "WARN_RUN_SECONDS", "problems", "warnings",
           "press_reach", "slide_limit_mm", "footprint_radius_mm", "memory_problem", "cost_warnings"]

# 10 minutes of camera at 30 FPS: 18,000 frames. The longest shipped episode is a few seconds and a
# dataset's are under 3 s; at the reduced tier's 2.8 ms a frame a 10-minute episode solves in a minute,
# at the linear tier's 46 ms in 14 minutes, and its camera frames alone fill 6.6 GB at 350 x 350.
MAX_EPISODE_FRAMES = 18_000
# frames x substeps: 60,000 linear-tier steps of the default demo take 46 minutes and keep 17 GB of
# per-step fields (fem.quasistatic.Episode keeps every step's stress); the swipe uses 6 substeps
MAX_SOLVE_STEPS = 60_000
# A scene is valid or not on every machine alike: past 64 GB no machine the project runs on (23-128 GB)
# holds the run. The machine's own budget is the run's (--max-memory-gb, mlsim.run_budget).
MAX_RUN_MEMORY_GB = 64.0
# mlsim check warns past these (plausible but expensive: say so before a sweep multiplies them)
WARN_RUN_MEMORY_GB = 8.0
WARN_RUN_SECONDS = 3600.0


def press_reach(load) -> list[tuple[int, float]]:
    """(segment index, how far the indenter's lowest point is below the rod tips at the segment's
    end, mm) for each depth-controlled press and release; negative: above the tips."""
    below = -load.start_gap_mm
    out = []
    for i, seg in enumerate(load.segments):
        if seg.kind == "press" and seg.depth_mm is not None:
            below += seg.depth_mm
        elif seg.kind == "press":
            below = max(below, 0.0)  # a force ramp reaches the tips at least (module docstring)
        elif seg.kind == "release":
            below -= seg.distance_mm
        else:
            continue
        out.append((i, below))
    return out


def footprint_radius_mm(indenter) -> float:
    """How far from its reference point (its axis) the indenter reaches in the surface's plane, mm:
    the punch's or sphere's radius, half the lying cylinder's length, the box's half diagonal."""
    if indenter.shape == "flat":
        return indenter.tip_diameter_mm / 2.0
    if indenter.shape == "sphere":
        return indenter.diameter_mm / 2.0
    if indenter.shape == "cylinder":
        return math.hypot(indenter.length_mm, indenter.diameter_mm) / 2.0
    return math.hypot(indenter.size_mm[0], indenter.size_mm[1]) / 2.0


def slide_limit_mm(x_mm: float, y_mm: float, direction_deg: float, half_x_mm: float, half_y_mm: float) -> float:
    """How far a point at (x, y) may move along ``direction_deg`` and stay within |x| <= half_x,
    |y| <= half_y (mm; 0 when it is already outside)."""
    if abs(x_mm) > half_x_mm or abs(y_mm) > half_y_mm:
        return 0.0
    a = math.radians(direction_deg)
    limits = []
    for pos, d, half in ((x_mm, math.cos(a), half_x_mm), (y_mm, math.sin(a), half_y_mm)):
        if abs(d) > 1e-12:
            limits.append(((half if d > 0 else -half) - pos) / d)
    return min(limits) if limits else math.inf


def _load_problems(scene) -> list[Problem]:
    load, s = scene.load, scene.sensor
    out: list[Problem] = []
    height = s.rod.height_mm
    for i, below in press_reach(load):
        seg = load.segments[i]
        if seg.kind == "press" and seg.depth_mm is not None and below >= height:
            room = seg.depth_mm - (below - height)
            fix = f"use depth_mm < {room:.4g}" if room > 0 else "lift the indenter first (a release segment) or press less before"
            out.append(Problem(f"load.segments[{i}].depth_mm", seg.depth_mm,
                               f"the press takes the indenter's lowest point {below:.4g} mm below the rod tips (start gap "
                               f"{load.start_gap_mm:g} mm, the presses less the releases so far), where it meets the base: the limit "
                               f"is the rods' height, {height:g} mm; {fix}"))
            break  # the later segments follow from an impossible pose
    reach = footprint_radius_mm(load.indenter)
    half_x, half_y = s.size_x_mm / 2.0 + reach, s.size_y_mm / 2.0 + reach
    x, y = load.start_xy_mm
    for i, seg in enumerate(load.segments):
        if seg.kind != "slide":
            continue
        room = slide_limit_mm(x, y, seg.direction_deg, half_x, half_y)
        if seg.distance_mm > room * (1 + 1e-9) + 1e-9:
            a = math.radians(seg.direction_deg)
            end = (x + seg.distance_mm * math.cos(a), y + seg.distance_mm * math.sin(a))
            out.append(Problem(f"load.segments[{i}].distance_mm", seg.distance_mm,
                               f"the slide carries the indenter from ({_mm(x)}, {_mm(y)}) to ({_mm(end[0])}, {_mm(end[1])}) mm, off the "
                               f"sensor: its reach of {reach:.4g} mm no longer meets the {s.size_x_mm:g} x {s.size_y_mm:g} mm surface "
                               f"(|x| <= {half_x:.4g}, |y| <= {half_y:.4g} mm); along {seg.direction_deg:g} deg the limit is "
                               f"{room:.4g} mm: use distance_mm <= {room:.4g}"))
            break
        a = math.radians(seg.direction_deg)
        x, y = x + seg.distance_mm * math.cos(a), y + seg.distance_mm * math.sin(a)
    return out


def _mm(value: float) -> str:
    return f"{round(value, 6) + 0.0:.4g}"  # (cos 90 deg is 6e-17: a position of 0 mm, not 6e-16)


def _slowest_field(load) -> tuple[str, float]:
    """The dotted field and value of the longest segment's pace (what makes the episode long)."""
    k = max(range(len(load.segments)), key=lambda j: load.segments[j].seconds)
    seg = load.segments[k]
    name = {"rotate": "rate_deg_s", "hold": "duration_s"}.get(seg.kind)
    if name is None:
        name = "duration_s" if getattr(seg, "duration_s", None) is not None else "speed_mm_s"
    return f"load.segments[{k}].{name}", getattr(seg, name)


def _size_problems(scene) -> list[Problem]:
    load = scene.load
    frames = cost_model.episode_frames(load.duration_s, scene.camera.fps)
    steps = cost_model.solve_steps(frames, scene.fidelity.solve.substeps)
    idle = cost_model.idle_frames(scene)
    if idle > MAX_EPISODE_FRAMES - frames and idle > frames:
        return [Problem("dllm.init_s", scene.dllm.init_s, f"{idle:.4g} idle frames at {scene.camera.fps:g} FPS before the episode's "
                        f"{frames:.4g}; the limit is {MAX_EPISODE_FRAMES} frames in all: use dllm.init_s <= "
                        f"{max(MAX_EPISODE_FRAMES - frames, 0) / scene.camera.fps:.4g} (SPEC 1.6: 1 s)")]
    if frames + idle > MAX_EPISODE_FRAMES:
        field, value = _slowest_field(load)
        longest = max(s.seconds for s in load.segments)
        return [Problem(field, value, f"the load lasts {load.duration_s:.4g} s ({frames:.4g} frames at {scene.camera.fps:g} FPS), its longest "
                        f"segment {longest:.4g} s; the limit is {MAX_EPISODE_FRAMES} frames "
                        f"({MAX_EPISODE_FRAMES / scene.camera.fps:.4g} s at this frame rate): make the segment faster or shorter, or "
                        "split the experiment into several scenes")]
    if steps > MAX_SOLVE_STEPS:
        room = max(1, int((MAX_SOLVE_STEPS - 1) // max(frames - 1, 1)))
        return [Problem("fidelity.solve.substeps", scene.fidelity.solve.substeps,
                        f"{frames:.0f} frames x {scene.fidelity.solve.substeps} substeps = {steps:.4g} solve steps; the limit is "
                        f"{MAX_SOLVE_STEPS}: use substeps <= {room} or a shorter load")]
    return []


def run_costs(scene) -> list[cost_model.StageCost]:
    """The cost of every modelled stage of the scene's kind (all of them: the most a run can ask for)."""
    from mlsim.stage import stages

    return [c for c in (cost_model.stage_cost(scene, name) for name in stages(scene.kind)) if c is not None]


def _memory_problems(scene, costs) -> list[Problem]:
    worst = max(costs, key=lambda c: c.memory_bytes, default=None)
    if worst is None or worst.memory_bytes <= MAX_RUN_MEMORY_GB * cost_model.GB:
        return []
    field = {"mesh": "fidelity.mesh.edge_length_mm", "render": "camera.width_px", "camera": "camera.width_px",
             "emission": "fidelity.render.sheet_edge_mm"}.get(worst.stage, "fidelity.mesh.edge_length_mm")
    return [Problem(field, scene.get(field), f"the {worst.stage} stage would need about {worst.memory_bytes / cost_model.GB:.3g} GB "
                    f"(mlsim.cost_model: {_sizes(worst)}); the limit is {MAX_RUN_MEMORY_GB:g} GB: make the mesh coarser, the "
                    "camera smaller or the load shorter")]


def _sizes(cost) -> str:
    parts = [f"{v:,} {k}" for k, v in (("frames", cost.frames), ("solve steps", cost.steps), ("tets", cost.tets)) if v is not None]
    return ", ".join(parts) or "its fixed cost"


def problems(scene) -> list[Problem]:
    """What refuses the (ml_rod_array) scene: each problem names the field, the value, the limit and the fix."""
    if scene.kind != "ml_rod_array":
        return []
    out: list[Problem] = []
    if scene.load is not None:
        out = _load_problems(scene) or _size_problems(scene)
        if out:
            return out  # the costs follow from a load that is already refused
    return _memory_problems(scene, run_costs(scene))


def memory_problem(field: str, value, what: str, memory_bytes: float, fix: str) -> tuple | None:
    """``(field, value, reason)`` when ``what`` (a phrase naming the work and its size) would need more
    than ``MAX_RUN_MEMORY_GB``; ``fix`` says what to change. None when it fits (a NaN estimate does not)."""
    if memory_bytes <= MAX_RUN_MEMORY_GB * cost_model.GB:
        return None
    return (field, value, f"{what} would need about {memory_bytes / cost_model.GB:.3g} GB; the limit is {MAX_RUN_MEMORY_GB:g} GB "
                          f"(mlsim.plausibility.MAX_RUN_MEMORY_GB): {fix}")


def cost_warnings(what: str, memory_bytes: float, seconds: float) -> list[str]:
    """The warnings of work that is plausible but expensive: past ``WARN_RUN_MEMORY_GB`` or
    ``WARN_RUN_SECONDS``, each with its estimate."""
    out = []
    if memory_bytes > WARN_RUN_MEMORY_GB * cost_model.GB:
        out.append(f"{what}: about {memory_bytes / cost_model.GB:.3g} GB expected")
    if seconds > WARN_RUN_SECONDS:
        out.append(f"{what}: about {seconds / 60:.3g} min expected")
    return out


def warnings(scene) -> list[str]:
    """What is plausible but expensive, with the estimate (empty for a scene that is cheap); another
    kind's come from its registered ``warnings`` hook."""
    if scene.kind != "ml_rod_array":
        from mlsim.stage import kind

        hook = kind(scene.kind).warnings
        return hook(scene) if hook is not None else []
    if problems(scene):
        return []
    out = []
    for c in run_costs(scene):
        if c.memory_bytes > WARN_RUN_MEMORY_GB * cost_model.GB:
            out.append(f"the {c.stage} stage is expected to need about {c.memory_bytes / cost_model.GB:.3g} GB ({_sizes(c)})")
        if c.seconds > WARN_RUN_SECONDS:
            out.append(f"the {c.stage} stage is expected to take about {c.seconds / 60:.3g} min ({_sizes(c)})")
    return out
