"""The indenter's motion from the scene's timed load segments, and the time grid of the solve.

The indenter starts with its lowest point ``start_gap_mm`` above the rod tips at ``start_xy_mm``,
turned by its ``yaw_deg``. Segments run one after another:

- ``press`` with ``depth_mm``: down by that distance, at ``speed_mm_s`` or over ``duration_s``
  (displacement control);
- ``press`` with ``force_n``: the total normal force ramps linearly to ``force_n`` over
  ``duration_s``, from the force at the segment's start (force control: the solver finds the
  height). Later ``hold``, ``slide`` and ``rotate`` segments keep that force, as a gripper does,
  until a ``release`` or a depth-controlled ``press``;
- ``slide``: sideways by ``distance_mm`` along ``direction_deg`` at ``speed_mm_s``, at constant
  height (or force);
- a force ramp with ``keep = "height"`` hands over to displacement control once it ends: later
  segments keep the height it reached (a clamp that locks) instead of its force;
- ``rotate``: about the vertical axis through the indenter's reference point, by ``angle_deg``;
- ``hold``: nothing moves;
- ``release``: up by ``distance_mm`` (displacement control from there on).

Every motion is at constant velocity within its segment. :class:`IndenterState` is a point of
this path; :func:`advance` moves a state from one time to a later one, which is how the solver
steps (the height under force control comes from the solver, so the path is walked, not tabled).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from mlsim import cost_model, plausibility
from mlsim.errors import SolverError

__all__ = ["IndenterState", "TimeGrid", "time_grid", "initial_state", "advance", "segment_at"]


@dataclass(frozen=True)
class IndenterState:
    """Pose of the indenter (its reference point: the lowest point on its axis) at time ``t_s``.

    ``force_target_n`` is None under displacement control, else the normal force the solver must
    reach (then ``position_m[2]`` is the solver's last height, used as a starting guess).
    """

    t_s: float
    position_m: tuple[float, float, float]
    yaw_rad: float
    force_target_n: float | None = None
    ramp_from_n: float | None = None  # inside a force ramp: the force it started from


@dataclass(frozen=True)
class TimeGrid:
    """Frames at ``frame_times_s`` (frame 0 at t = 0), each interval split into ``substeps``."""

    fps: float
    substeps: int
    n_frames: int

    @property
    def frame_times_s(self) -> np.ndarray:
        return np.arange(self.n_frames) / self.fps

    @property
    def step_times_s(self) -> np.ndarray:
        """All solve times (substeps included), (1 + (n_frames - 1) * substeps,)."""
        n = 1 + (self.n_frames - 1) * self.substeps
        return np.arange(n) / (self.fps * self.substeps)

    @property
    def frame_step(self) -> np.ndarray:
        """Index into :attr:`step_times_s` of each frame."""
        return np.arange(self.n_frames) * self.substeps


def time_grid(load, fps: float, substeps: int = 1, extra_frames: int = 1) -> TimeGrid:
    """Frames covering the whole load (its duration, rounded up to a frame) plus ``extra_frames``.

    A grid past :data:`mlsim.plausibility.MAX_SOLVE_STEPS` steps is a :class:`SolverError` before any
    array of its times is made (a scene's check refuses it first; a load built in code is not checked:
    a slide at 1e-9 mm/s asked numpy for 335 GiB of step times)."""
    frames = cost_model.episode_frames(load.duration_s, fps, extra_frames)
    steps = cost_model.solve_steps(frames, substeps)
    if steps > plausibility.MAX_SOLVE_STEPS:
        raise SolverError(f"the load lasts {load.duration_s:.4g} s: {frames:.4g} frames at {fps:g} FPS, {steps:.4g} solve steps with "
                          f"{substeps} substeps, past the limit of {plausibility.MAX_SOLVE_STEPS} (mlsim.plausibility); shorten the load")
    return TimeGrid(float(fps), int(substeps), int(frames))


def initial_state(load, tip_height_m: float) -> IndenterState:
    x, y = load.start_xy_mm
    return IndenterState(0.0, (x * 1e-3, y * 1e-3, tip_height_m + load.start_gap_mm * 1e-3), math.radians(load.indenter.yaw_deg))


def segment_at(load, t_s: float) -> tuple[int, float, float]:
    """(segment index, segment start time, segment end time) of time t (past the end: -1)."""
    start = 0.0
    for k, seg in enumerate(load.segments):
        end = start + seg.seconds
        if t_s < end - 1e-12:
            return k, start, end
        start = end
    return -1, start, start


def _move(state: IndenterState, seg, dt: float) -> IndenterState:
    """The state after ``dt`` seconds inside segment ``seg`` (constant velocities)."""
    x, y, z = state.position_m
    if seg.kind == "press" and seg.depth_mm is not None:
        speed = seg.depth_mm * 1e-3 / seg.seconds
        return replace(state, position_m=(x, y, z - speed * dt), force_target_n=None)
    if seg.kind == "press":  # force control: the ramp's value at the new time, set by the caller
        return state
    if seg.kind == "slide":
        d = seg.speed_mm_s * 1e-3 * dt
        a = math.radians(seg.direction_deg)
        return replace(state, position_m=(x + d * math.cos(a), y + d * math.sin(a), z))
    if seg.kind == "rotate":
        return replace(state, yaw_rad=state.yaw_rad + math.copysign(math.radians(seg.rate_deg_s) * dt, seg.angle_deg))
    if seg.kind == "release":
        return replace(state, position_m=(x, y, z + seg.speed_mm_s * 1e-3 * dt), force_target_n=None)
    return state  # hold


def _locks_height(load, k: int) -> bool:
    """Whether the last force ramp before segment ``k`` keeps its height (``keep = "height"``)."""
    for seg in reversed(load.segments[:k]):
        if seg.kind == "press" and seg.force_n is not None:
            return seg.keep == "height"
    return False


def advance(load, state: IndenterState, t_new: float, force_now_n: float = 0.0) -> IndenterState:
    """The indenter's state at ``t_new`` >= ``state.t_s``, walking through segment boundaries.

    ``force_now_n`` is the normal force the solver found at ``state``: a force ramp that starts
    from displacement control starts from it.
    """
    t = state.t_s
    s = state
    while t < t_new - 1e-15:
        k, start, end = segment_at(load, t)
        if k < 0:  # after the last segment the indenter stays put
            break
        seg = load.segments[k]
        if s.force_target_n is not None and not (seg.kind == "press" and seg.force_n is not None) and _locks_height(load, k):
            s = replace(s, force_target_n=None, ramp_from_n=None)  # the clamp locks where its ramp ended
        t_next = min(end, t_new)
        s = _move(s, seg, t_next - t)
        if seg.kind == "press" and seg.force_n is not None:
            f0 = s.ramp_from_n
            if f0 is None:  # entering the ramp
                f0 = force_now_n if s.force_target_n is None else s.force_target_n
            frac = (t_next - start) / (end - start)
            s = replace(s, force_target_n=f0 + (seg.force_n - f0) * frac, ramp_from_n=None if t_next >= end - 1e-15 else f0)
        t = t_next
    return replace(s, t_s=t_new)
