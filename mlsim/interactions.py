"""The eight human interactions of the SPEC 1.5 interaction test, as load trajectories of the M8 screw.

The published test: the sensor, on a robot, holds an M8 screw (7.7 mm x 160 mm) pressed against its
rods by a gripper; ten people each perform eight actions on the screw, 100 samples per action
(SPEC 1.5). The paper names the actions and gives no trajectories; this module defines them.

Frame and conventions (the sensor frame of :mod:`fem.trajectory`): x and y in the sensing surface,
z up out of the rods' tips, so "from above" means from outside the sensor, where the person stands.
The screw lies along x (its axis, yaw 0) over the middle row of rods (y = 0, plus the grip's offset),
its centre over the array's centre; at 7.7 mm wide over a 36 mm surface it covers 21 % of it.

An episode:

1. **clamp**: the gripper presses the screw onto the rods, the normal force ramping to
   ``grip_force_n`` over ``grip_s``; then the clamp locks (``keep = "height"``: a servo claw holds its
   angle, so the screw's height stays and its normal force follows the rods);
2. **settle** for ``settle_s`` plus the person's onset delay;
3. **the action**, one stroke of the screw in the surface plane with a minimum-jerk profile
   (Flash & Hogan 1985, the standard model of a human point-to-point movement), with the person's
   physiological tremor (a sinusoid of ``tremor_mm`` at ``tremor_hz``, 8-12 Hz in people) across the
   stroke:

   ============== ==================================================================
   push           along +x (along the screw) by ``stroke_mm``
   pull           along -x
   oblique_push   along +x turned by ``oblique_deg`` towards +y
   oblique_pull   the reverse of oblique_push (180 deg + ``oblique_deg``)
   sliding_left   along +y (across the screw)
   sliding_right  along -y
   rotation_cw    turned about the vertical axis through the screw's centre by ``twist_deg``,
                  clockwise seen from above
   rotation_ccw   anticlockwise seen from above
   ============== ==================================================================

   Every direction also gets the person's bias and a per-sample scatter (``direction_sd_deg``);
4. **hold** for ``tail_s``: the person lets go, the clamp keeps the screw where it ended.

The frames whose capture time lies in (stroke start, stroke end + one frame] carry the action's
label (the last of them still sees the light of the stroke's end); the others carry -1.

People: :func:`draw_people` draws one :class:`Person` per simulated person from a seeded generator
(their typical stroke, speed, twist, oblique angle, direction bias, onset and tremor), within the
ranges of :class:`InteractionSpec`; :func:`draw_sample` draws one sample of one action around the
person's typical values with the spec's per-sample variability. The ranges are not given by the
paper: the defaults are chosen so that every action stays within the reduced tier's small-strain
limit and the clamp's friction keeps the screw on the rods. They are documented in the fields.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Annotated, Any

import numpy as np
from pydantic import Field, Strict, model_validator

from mlsim.scene import Float, NonNeg, Pos, Scene, _Model

__all__ = [
    "ACTIONS",
    "ACTIONS_4",
    "InteractionSpec",
    "Person",
    "Sample",
    "draw_people",
    "draw_sample",
    "action_segments",
    "interaction_scene",
    "frame_labels",
    "minimum_jerk",
]

#: The eight actions of SPEC 1.5, in class-id order.
ACTIONS = ("push", "pull", "oblique_push", "oblique_pull", "sliding_left", "sliding_right", "rotation_cw", "rotation_ccw")
#: The four-class version of SPEC 1.7, and each action's class in it.
ACTIONS_4 = ("push_pull", "sliding", "rotation_cw", "rotation_ccw")
ACTION_TO_4 = {"push": 0, "pull": 0, "oblique_push": 0, "oblique_pull": 0, "sliding_left": 1, "sliding_right": 1,
               "rotation_cw": 2, "rotation_ccw": 3}

Range = tuple[NonNeg, NonNeg]
SignedRange = tuple[Float, Float]


class InteractionSpec(_Model):
    """The screw, the gripper and the ranges people are drawn from (lengths mm, times s, angles deg).

    Each ``*_range`` is the interval a person's typical value is drawn from (uniformly); each
    sample scatters around it by ``variability`` (the coefficient of variation, log-normal) or, for
    directions, by ``direction_sd_deg``. Not given by the paper; see the module docstring.
    """

    screw_diameter_mm: Pos = 7.7  # SPEC 1.5: M8 screw, 7.7 mm x 160 mm
    screw_length_mm: Pos = 160.0
    grip_force_n: Pos = 3.0  # the gripper's normal force; not given
    grip_s: Pos = 0.1  # the clamp's force ramp (3 frames at 30 FPS: a gripper closes fast)
    grip_offset_mm: NonNeg = 0.5  # the screw lies within this of the middle row's axis (per sample, uniform)
    settle_s: NonNeg = 0.2  # after the clamp, before the person's onset delay
    tail_s: NonNeg = 0.15  # after the stroke
    stroke_mm_range: Range = (0.4, 0.9)
    twist_deg_range: Range = (2.0, 4.0)
    duration_s_range: Range = (0.4, 0.8)  # of the stroke
    oblique_deg_range: Range = (35.0, 55.0)
    direction_bias_deg_range: SignedRange = (-8.0, 8.0)
    onset_s_range: Range = (0.05, 0.3)
    tremor_mm_range: Range = (0.005, 0.02)  # physiological tremor at the screw
    tremor_hz_range: Range = (8.0, 12.0)
    variability: Annotated[float, Strict(), Field(ge=0, le=1)] = 0.15
    direction_sd_deg: NonNeg = 5.0

    @model_validator(mode="after")
    def _ranges(self):
        for name in type(self).model_fields:
            if name.endswith("_range"):
                lo, hi = getattr(self, name)
                if hi < lo:
                    raise ValueError(f"{name} = ({lo:g}, {hi:g}): the upper end must not be below the lower")
        if self.duration_s_range[0] <= 0 or self.stroke_mm_range[0] <= 0 or self.twist_deg_range[0] <= 0:
            raise ValueError("stroke_mm_range, twist_deg_range and duration_s_range must start above 0")
        return self


@dataclass(frozen=True)
class Person:
    """One simulated person's typical way of acting (units in the names)."""

    index: int
    stroke_mm: float
    twist_deg: float
    duration_s: float
    oblique_deg: float
    direction_bias_deg: float
    onset_s: float
    tremor_mm: float
    tremor_hz: float


@dataclass(frozen=True)
class Sample:
    """One sample of one action by one person: everything its trajectory needs."""

    action: str
    person: int
    stroke_mm: float  # translation actions: the stroke's length
    twist_deg: float  # rotations: the turn (positive = anticlockwise from above)
    direction_deg: float  # translation actions: the stroke's direction in the surface plane
    duration_s: float
    onset_s: float  # settle + the person's delay: the stroke starts at grip_s + onset_s
    tremor_mm: float
    tremor_hz: float
    tremor_phase_rad: float
    grip_offset_mm: float

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


def _uniform(rng: np.random.Generator, bounds) -> float:
    lo, hi = bounds
    return float(rng.uniform(lo, hi)) if hi > lo else float(lo)


def draw_people(n: int, spec: InteractionSpec, rng: np.random.Generator) -> list[Person]:
    """``n`` people, each with typical values drawn uniformly from the spec's ranges."""
    if n < 1:
        raise ValueError(f"people = {n}: need at least 1")
    out = []
    for i in range(n):
        out.append(Person(i, _uniform(rng, spec.stroke_mm_range), _uniform(rng, spec.twist_deg_range), _uniform(rng, spec.duration_s_range),
                          _uniform(rng, spec.oblique_deg_range), _uniform(rng, spec.direction_bias_deg_range), _uniform(rng, spec.onset_s_range),
                          _uniform(rng, spec.tremor_mm_range), _uniform(rng, spec.tremor_hz_range)))
    return out


def _nominal_direction_deg(action: str, person: Person) -> float:
    return {"push": 0.0, "pull": 180.0, "oblique_push": person.oblique_deg, "oblique_pull": 180.0 + person.oblique_deg,
            "sliding_left": 90.0, "sliding_right": -90.0}[action]


def draw_sample(action: str, person: Person, spec: InteractionSpec, rng: np.random.Generator) -> Sample:
    """One sample of ``action`` by ``person``: the person's typical values, scattered per sample."""
    if action not in ACTIONS:
        raise ValueError(f'"{action}" is not an action; choose one of: {", ".join(ACTIONS)}')
    cv = spec.variability
    sigma = math.sqrt(math.log1p(cv * cv))  # log-normal with this coefficient of variation, median at the typical value

    def scatter(v):
        return float(v * math.exp(rng.normal(0.0, sigma))) if sigma > 0 else float(v)

    stroke, twist, duration = scatter(person.stroke_mm), scatter(person.twist_deg), scatter(person.duration_s)
    onset = spec.settle_s + scatter(person.onset_s)
    direction = twist_sign = 0.0
    if action.startswith("rotation"):
        twist_sign = -1.0 if action == "rotation_cw" else 1.0
    else:
        direction = _nominal_direction_deg(action, person) + person.direction_bias_deg + float(rng.normal(0.0, spec.direction_sd_deg))
    phase = float(rng.uniform(0.0, 2.0 * math.pi))
    offset = float(rng.uniform(-spec.grip_offset_mm, spec.grip_offset_mm)) if spec.grip_offset_mm > 0 else 0.0
    return Sample(action, person.index, stroke, twist_sign * twist, direction, duration, onset, scatter(person.tremor_mm), person.tremor_hz,
                  phase, offset)


def minimum_jerk(tau: np.ndarray) -> np.ndarray:
    """Minimum-jerk position profile s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 on tau in [0, 1]
    (Flash & Hogan 1985): from rest to rest, s(0) = 0, s(1) = 1."""
    t = np.clip(np.asarray(tau, dtype=np.float64), 0.0, 1.0)
    return t**3 * (10.0 - 15.0 * t + 6.0 * t * t)


def _stroke_path(sample: Sample, fps: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Screw pose at the stroke's frame-interval boundaries: times (K+1,) from 0, xy (K+1, 2) mm
    relative to the start, yaw (K+1,) deg. Tremor acts across the stroke (for a rotation: along y)."""
    n = max(int(math.ceil(sample.duration_s * fps - 1e-9)), 1)
    t = np.arange(n + 1) / fps
    t[-1] = sample.duration_s
    s = minimum_jerk(t / sample.duration_s)
    a = math.radians(sample.direction_deg)
    along = np.array([math.cos(a), math.sin(a)])
    across = np.array([-along[1], along[0]])
    # the tremor fades in and out with the stroke (a hand at rest on the screw before and after)
    envelope = np.sin(np.pi * t / sample.duration_s)
    tremor = sample.tremor_mm * envelope * np.sin(2.0 * np.pi * sample.tremor_hz * t + sample.tremor_phase_rad)
    if sample.action.startswith("rotation"):
        xy = tremor[:, None] * np.array([0.0, 1.0])[None]
        yaw = sample.twist_deg * s
    else:
        xy = (sample.stroke_mm * s)[:, None] * along[None] + tremor[:, None] * across[None]
        yaw = np.zeros_like(s)
    return t, xy, yaw


def action_segments(sample: Sample, spec: InteractionSpec, fps: float) -> list[dict]:
    """The load segments (scene dicts) of one episode: clamp, settle, the stroke frame interval by
    frame interval (each interval a constant-velocity slide and/or rotate), then the tail."""
    segments: list[dict] = [{"kind": "press", "force_n": spec.grip_force_n, "duration_s": spec.grip_s, "keep": "height"},
                            {"kind": "hold", "duration_s": sample.onset_s}]
    t, xy, yaw = _stroke_path(sample, fps)
    for k in range(len(t) - 1):
        dt = float(t[k + 1] - t[k])
        d = xy[k + 1] - xy[k]
        dist = float(np.hypot(*d))
        turn = float(yaw[k + 1] - yaw[k])
        moves = []
        if abs(turn) > 1e-9:
            moves.append(("rotate", turn))
        if dist > 1e-9:
            moves.append(("slide", d))
        if not moves:
            segments.append({"kind": "hold", "duration_s": dt})
            continue
        share = dt / len(moves)  # both happen within the interval, one after the other
        for kind, v in moves:
            if kind == "rotate":
                segments.append({"kind": "rotate", "angle_deg": v, "rate_deg_s": abs(v) / share})
            else:
                length = float(np.hypot(*v))
                segments.append({"kind": "slide", "distance_mm": length, "speed_mm_s": length / share,
                                 "direction_deg": math.degrees(math.atan2(v[1], v[0]))})
    if spec.tail_s > 0:
        segments.append({"kind": "hold", "duration_s": spec.tail_s})
    return segments


def stroke_window_s(sample: Sample, spec: InteractionSpec) -> tuple[float, float]:
    """(start, end) of the stroke in episode time (s)."""
    start = spec.grip_s + sample.onset_s
    return start, start + sample.duration_s


def frame_labels(sample: Sample, spec: InteractionSpec, n_frames: int, fps: float, label: int) -> np.ndarray:
    """(n_frames,) int64: ``label`` on frames captured in (stroke start, stroke end + 1/fps], else -1."""
    start, end = stroke_window_s(sample, spec)
    t = np.arange(n_frames) / fps
    return np.where((t > start + 1e-9) & (t <= end + 1.0 / fps + 1e-9), label, -1).astype(np.int64)


def interaction_scene(base: Scene, sample: Sample, spec: InteractionSpec, *, noise_seed: int, name: str | None = None) -> Scene:
    """The base scene (sensor, optics, camera, fidelity) with the screw and this sample's load.

    The base scene's ``seed`` is kept (it seeds the sensor's shared precomputes); the episode's
    camera noise comes from ``noise_seed``."""
    load = {
        "start_xy_mm": [0.0, sample.grip_offset_mm],
        "start_gap_mm": 0.05,
        "friction_coefficient": base.load.friction_coefficient if base.load is not None else 0.8,
        "indenter": {"shape": "cylinder", "diameter_mm": spec.screw_diameter_mm, "length_mm": spec.screw_length_mm},
        "segments": action_segments(sample, spec, base.camera.fps),
    }
    return base.with_values({"load": load, "noise_seed": int(noise_seed), "name": name or f"{sample.action}_p{sample.person:02d}"})
