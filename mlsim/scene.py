"""The scene: one typed, frozen, validated description of a simulation run.

A scene is written in TOML (see ``scenes/``) and loaded with :func:`load_scene`. Every field
carries its unit in its name (``height_mm``, ``speed_mm_s``); unknown keys, wrong types, NaN or
infinite numbers and inconsistent values are rejected at the door with a :class:`SceneError`
whose lines name the dotted path, the value received and what would be valid::

    sensor.rod.diameter_mm = -5.0: must be > 0

Deep code never re-validates and never reads raw dicts: it receives a :class:`Scene`.
For sweeps, :meth:`Scene.with_values` returns a new scene with some dotted fields changed.
"""

from __future__ import annotations

import hashlib
import json
import math
import tomllib
from pathlib import Path
from typing import Annotated, Any, Literal, Union

from pydantic import BaseModel, ConfigDict, Field, SerializeAsAny, Strict, ValidationError, field_validator, model_serializer, model_validator

from mlsim.errors import Problem, SceneError
from mlsim.materials import MATERIAL_PROPERTIES, SHIPPED_MATERIALS, Material, Quantity

__all__ = [
    "Scene",
    "SceneError",
    "load_scene",
    "scene_from_dict",
    "DEFAULT_SURFACE_SIZE_MM",
]

DEFAULT_SURFACE_SIZE_MM = 36.0  # SPEC 1.1: sensing surface 36 mm x 36 mm

# Strict scalar types: TOML gives ints and floats; a bool is not a number and a string "3" is not 3.
Float = Annotated[float, Strict()]
Int = Annotated[int, Strict()]
Bool = Annotated[bool, Strict()]
Pos = Annotated[float, Strict(), Field(gt=0)]
NonNeg = Annotated[float, Strict(), Field(ge=0)]


class SpecModel(BaseModel):
    """The base of every scene section, the sensor kinds' [sensor] schemas included: unknown keys
    are refused, values are frozen, NaN and Inf are refused."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


_Model = SpecModel


# --------------------------------------------------------------------------------------- sensor
class RodSpec(_Model):
    """One rod of the array (all rods are equal)."""

    diameter_mm: Pos = 5.0  # SPEC 1.1
    height_mm: Pos = 9.0  # SPEC 1.1


class BaseSpec(_Model):
    """The slab of elastomer the rods stand on."""

    thickness_mm: Pos = 2.0  # SPEC 1.1: not given, default 2 mm


class LayerSpec(_Model):
    """Layers over the top surface (rod tips, rod sides, top of the base), outside in."""

    absorber_mm: NonNeg = 0.3  # SPEC 1.1: light-absorbing layer, about 0.3 mm
    ml_mm: Pos = 0.5  # SPEC 1.1: not given, default 0.5 mm


class MaterialChoice(_Model):
    """Material of each region, by name in the materials table."""

    core: str = "SC37"
    ml_layer: str = "SC37"
    absorber: str = "SC37"


class PhosphorSpec(_Model):
    """ZnS:Cu phosphor in the ML layer."""

    loading_wt_pct: Annotated[float, Strict(), Field(ge=20, le=60)] = 60.0  # SPEC 1.2 measured range
    particle_size_um: Pos = 30.0  # SPEC 1.1


class SensorSpec(_Model):
    """The rod array, its base and layers (SPEC 1.1).

    Give either ``surface_size_mm`` (a square surface; each rod centred in its cell, so the pitch
    is the size over the count) or ``pitch_mm`` (then the surface is the pitch times the count).
    """

    # the sensor kind (mlsim.stage): this model is the "ml_rod_array" kind's [sensor] section
    kind: Literal["ml_rod_array"] = "ml_rod_array"
    rows: Annotated[int, Strict(), Field(ge=1, le=64)] = 5
    cols: Annotated[int, Strict(), Field(ge=1, le=64)] = 5
    surface_size_mm: Pos | None = None
    pitch_mm: Pos | None = None
    shell_height_mm: Pos = 65.0  # SPEC 1.1: bench version (the robot version is 50 mm)
    rod: RodSpec = RodSpec()
    base: BaseSpec = BaseSpec()
    layers: LayerSpec = LayerSpec()
    materials: MaterialChoice = MaterialChoice()
    phosphor: PhosphorSpec = PhosphorSpec()

    @model_validator(mode="before")
    @classmethod
    def _default_surface(cls, data: Any) -> Any:
        if isinstance(data, dict) and data.get("surface_size_mm") is None and data.get("pitch_mm") is None:
            data = {**data, "surface_size_mm": DEFAULT_SURFACE_SIZE_MM}
        return data

    @model_serializer(mode="wrap")
    def _default_kind_unwritten(self, handler):
        # the default kind is not written out, so that the scene hashes (and every stage's cache key)
        # of the scenes that predate sensor kinds stay as they were
        data = handler(self)
        if isinstance(data, dict) and data.get("kind") == "ml_rod_array":
            data.pop("kind")
        return data

    @property
    def pitch_x_mm(self) -> float:
        return self.pitch_mm if self.pitch_mm is not None else self.surface_size_mm / self.cols

    @property
    def pitch_y_mm(self) -> float:
        return self.pitch_mm if self.pitch_mm is not None else self.surface_size_mm / self.rows

    @property
    def size_x_mm(self) -> float:
        return self.pitch_x_mm * self.cols

    @property
    def size_y_mm(self) -> float:
        return self.pitch_y_mm * self.rows

    @property
    def n_rods(self) -> int:
        return self.rows * self.cols


class MaterialOverride(_Model):
    """A scene's change to a shipped material, or a new material (then E, nu and density are needed)."""

    description: str | None = None
    young_modulus_pa: Pos | None = None
    poisson_ratio: Annotated[float, Strict(), Field(gt=-1.0, lt=0.5)] | None = None
    density_kg_m3: Pos | None = None
    tensile_strength_pa: Pos | None = None
    elongation_at_break: Pos | None = None
    relative_ml_peak: NonNeg | None = None


# ----------------------------------------------------------------------------------------- load
class _Indenter(_Model):
    yaw_deg: Float = 0.0  # rotation of the indenter about the vertical axis at the start


class FlatIndenter(_Indenter):
    """A flat circular punch (SPEC 1.5 swipe probe: 5 cm^2 tip). Give the diameter or the tip area."""

    shape: Literal["flat"]
    diameter_mm: Pos | None = None
    tip_area_mm2: Pos | None = None
    height_mm: Pos = 10.0
    edge_radius_mm: NonNeg = 0.5  # not given; the rim's rounding (a sharp rim has no contact normal)

    @model_validator(mode="after")
    def _one_size(self):
        if (self.diameter_mm is None) == (self.tip_area_mm2 is None):
            raise ValueError("give exactly one of diameter_mm or tip_area_mm2")
        return self

    @property
    def tip_diameter_mm(self) -> float:
        if self.diameter_mm is not None:
            return self.diameter_mm
        return 2.0 * math.sqrt(self.tip_area_mm2 / math.pi)


class CylinderIndenter(_Indenter):
    """A cylinder lying across the rods (e.g. the M8 screw, 7.7 mm x 160 mm); axis along x at yaw 0."""

    shape: Literal["cylinder"]
    diameter_mm: Pos
    length_mm: Pos


class SphereIndenter(_Indenter):
    shape: Literal["sphere"]
    diameter_mm: Pos


class BoxIndenter(_Indenter):
    shape: Literal["box"]
    size_mm: tuple[Pos, Pos, Pos]
    edge_radius_mm: NonNeg = 0.5  # not given; the edges' rounding


Indenter = Annotated[
    Union[FlatIndenter, CylinderIndenter, SphereIndenter, BoxIndenter], Field(discriminator="shape")
]


class PressSegment(_Model):
    """Move the indenter down: by ``depth_mm`` (at ``speed_mm_s`` or over ``duration_s``), or ramp
    the normal force to ``force_n`` over ``duration_s``."""

    kind: Literal["press"]
    depth_mm: Pos | None = None
    force_n: Pos | None = None
    speed_mm_s: Pos | None = None
    duration_s: Pos | None = None
    # After a force ramp, what the later segments keep: the force (a compliant gripper) or the
    # height the ramp reached (a clamp that locks, e.g. a servo holding its angle).
    keep: Literal["force", "height"] = "force"

    @model_validator(mode="after")
    def _control(self):
        if (self.depth_mm is None) == (self.force_n is None):
            raise ValueError("give exactly one of depth_mm (displacement control) or force_n (force control)")
        if self.depth_mm is not None and (self.speed_mm_s is None) == (self.duration_s is None):
            raise ValueError("with depth_mm give exactly one of speed_mm_s or duration_s")
        if self.force_n is not None and (self.duration_s is None or self.speed_mm_s is not None):
            raise ValueError("with force_n give duration_s (the ramp time) and no speed_mm_s")
        if self.depth_mm is not None and self.keep != "force":
            raise ValueError('keep applies to a force ramp (force_n); remove it from a depth-controlled press')
        return self

    @property
    def seconds(self) -> float:
        return self.duration_s if self.duration_s is not None else self.depth_mm / self.speed_mm_s


class SlideSegment(_Model):
    """Move the indenter sideways, keeping its depth, along ``direction_deg`` (0 = +x, 90 = +y)."""

    kind: Literal["slide"]
    distance_mm: Pos
    speed_mm_s: Pos
    direction_deg: Float = 0.0

    @property
    def seconds(self) -> float:
        return self.distance_mm / self.speed_mm_s


class RotateSegment(_Model):
    """Turn the indenter about the vertical axis by ``angle_deg`` (positive = anticlockwise from above)."""

    kind: Literal["rotate"]
    angle_deg: Float
    rate_deg_s: Pos

    @model_validator(mode="after")
    def _nonzero(self):
        if self.angle_deg == 0:
            raise ValueError("angle_deg must be non-zero")
        return self

    @property
    def seconds(self) -> float:
        return abs(self.angle_deg) / self.rate_deg_s


class HoldSegment(_Model):
    kind: Literal["hold"]
    duration_s: Pos

    @property
    def seconds(self) -> float:
        return self.duration_s


class ReleaseSegment(_Model):
    """Move the indenter up by ``distance_mm``."""

    kind: Literal["release"]
    distance_mm: Pos
    speed_mm_s: Pos

    @property
    def seconds(self) -> float:
        return self.distance_mm / self.speed_mm_s


Segment = Annotated[
    Union[PressSegment, SlideSegment, RotateSegment, HoldSegment, ReleaseSegment],
    Field(discriminator="kind"),
]
SEGMENT_KINDS = ("press", "slide", "rotate", "hold", "release")
INDENTER_SHAPES = ("flat", "cylinder", "sphere", "box")


class LoadSpec(_Model):
    """A rigid indenter moved along timed segments, starting above the rod tips."""

    indenter: Indenter
    start_xy_mm: tuple[Float, Float] = (0.0, 0.0)
    start_gap_mm: NonNeg = 0.5  # gap between the indenter's lowest point and the rod tips
    friction_coefficient: NonNeg = 0.8  # not given; silicone on steel is about 0.5-1.0
    segments: Annotated[tuple[Segment, ...], Field(min_length=1)]

    @property
    def duration_s(self) -> float:
        return sum(s.seconds for s in self.segments)


# -------------------------------------------------------------------------------- verification
class VerifyS2Spec(_Model):
    """The published FEM set-up of SPEC 1.4, a verification case (``outputs = ["verify_s2"]``):
    a lateral force on a rod standing on a slab ("sliding") against the same force on a steel block
    bonded to a slab ("pressing"). The slab spans x, y in [0, size] and z in [0, thickness]; rod
    and block stand at the slab's centre; the force acts along +x at ``force_height_mm`` above the
    slab's top. The slab's bottom is fixed; gravity acts. Lengths in mm."""

    slab_size_mm: tuple[Pos, Pos, Pos] = (10.0, 10.0, 2.0)  # x, y, thickness
    rod_diameter_mm: Pos = 4.0
    rod_height_mm: Pos = 8.0
    block_size_mm: tuple[Pos, Pos, Pos] = (2.0, 2.0, 4.0)
    force_height_mm: Pos = 2.0
    forces_n: Annotated[tuple[Pos, ...], Field(min_length=1)] = (1.0, 2.0, 4.0, 8.0, 16.0)
    profile_x_mm: tuple[Float, Float] = (1.0, 9.0)  # the top-surface profile: x range at y = centre
    profile_points: Annotated[int, Strict(), Field(ge=2, le=10000)] = 81
    slab_material: str = "PDMS"
    block_material: str = "steel"
    edge_length_mm: Pos = 0.5
    # the nonlinear tier meshes coarser (fem.verify_s2.NONLINEAR_EDGE_MM when None)
    nonlinear_edge_length_mm: Pos | None = 1.0
    tiers: Annotated[tuple[Literal["linear", "nonlinear"], ...], Field(min_length=1)] = ("linear",)
    # the reading of SPEC 1.4 (fem.verify_s2.Reading): where the displacement is measured, how the
    # force is spread, where it acts
    measure: Literal["slab_top", "load_height", "body_top", "anywhere"] = "slab_top"
    load_distribution: Literal["band", "pushed_side", "slice"] = "band"
    force_at: Literal["height", "top"] = "height"

    @model_validator(mode="after")
    def _fits(self):
        sx, sy, _ = self.slab_size_mm
        if self.rod_diameter_mm >= min(sx, sy) or max(self.block_size_mm[:2]) >= min(sx, sy):
            raise ValueError("the rod and the block must fit on the slab: rod_diameter_mm and block_size_mm[:2] < slab_size_mm[:2]")
        if self.force_at == "height" and self.force_height_mm >= min(self.rod_height_mm, self.block_size_mm[2]):
            raise ValueError("force_height_mm must be below the rod's and the block's tops")
        return self


# ------------------------------------------------------------------------------------- emission
class EmissionSpec(_Model):
    """ML emission from the stress history (:mod:`mlsim.emission`). The trap constants are not given
    in SPEC; their defaults and the reasons are in :mod:`mlsim.emission.detrapping`."""

    model: Literal["detrapping", "stress_rate"] = "detrapping"
    equivalent_stress: Literal["von_mises", "tresca", "max_principal", "abs_pressure"] = "von_mises"  # SPEC 1.3: von Mises contours
    detrapping_per_pa: NonNeg = 2e-7  # fraction of filled traps a 1 Pa rise empties
    recovery_time_s: Pos = 1.0  # self-recovering ZnS:Cu refills its traps with this time constant
    # photons per m^2 of ML layer when all its traps empty, before the host and loading factors.
    # Calibrated (mlsim.render.calibration; benchmarks/calibrate_brightness.py): a 16 N press of the
    # default probe over 0.15 s on the default sensor at default camera settings reaches green 192
    # of 255 at the 99.5th percentile of its brightest frame. Order of magnitude check: trap density
    # 1e23 m^-3 x phosphor volume fraction 0.29 x 0.5 mm x radiative yield 0.7 = 1e19.
    brightness_photons_per_m2: NonNeg = 2.7e19


# ------------------------------------------------------------------------------ optics and camera
ABSORBERS = ("black_silicone_pigment", "uv_opaque_colorant", "carbon_nanotubes", "water_based_ink", "none")


class OpticsSpec(_Model):
    elastomer_refractive_index: Annotated[float, Strict(), Field(ge=1.0, le=3.0)] = 1.41
    acrylic_thickness_mm: Pos = 3.0  # SPEC 1.1: not given, default 3 mm
    acrylic_refractive_index: Annotated[float, Strict(), Field(ge=1.0, le=3.0)] = 1.49  # SPEC 1.1
    absorber: Literal[ABSORBERS] = "black_silicone_pigment"  # SPEC 1.3
    # Diffuse (Lambertian) reflectance of the ML layer's inner face as seen from the clear core:
    # ZnS:Cu powder is off-white, the black absorber behind it takes what passes. Not given; 0.5
    # is a middle value for a 0.5 mm phosphor-loaded silicone sheet on black (see mlsim.render).
    ml_layer_reflectance: Annotated[float, Strict(), Field(ge=0.0, le=0.99)] = 0.5
    # Diffuse transmittance of the ML layer for light from outside (ambient leakage, the calibration
    # frame), grey. Not given; 0.3 for 0.5 mm of phosphor-loaded silicone (with the reflectance above,
    # 0.2 is absorbed).
    ml_layer_transmittance: Annotated[float, Strict(), Field(ge=0.0, le=1.0)] = 0.3

    @model_validator(mode="after")
    def _energy(self):
        if self.ml_layer_reflectance + self.ml_layer_transmittance > 1.0:
            raise ValueError("ml_layer_reflectance + ml_layer_transmittance must be <= 1 (the rest is absorbed); lower one of them")
        return self


class CameraSpec(_Model):
    """Colour CMOS under the sensor, looking up (SPEC 1.1: IMX415-class, 30 FPS, 350 x 350 crop)."""

    fps: Annotated[float, Strict(), Field(gt=0, le=10000)] = 30.0
    width_px: Annotated[int, Strict(), Field(ge=8, le=8192)] = 350
    height_px: Annotated[int, Strict(), Field(ge=8, le=8192)] = 350
    distance_mm: Pos = 40.0  # lens to the acrylic's bottom face; not given
    # None: the focal length that fits the sensing surface plus 5 % each side into the crop, focused
    # on the base (mlsim.render.optics.camera_params); M12 board lenses span about 1.5-8 mm.
    focal_length_mm: Pos | None = None
    f_number: Annotated[float, Strict(), Field(ge=0.5, le=64)] = 2.0  # typical M12 board lens; not given
    binning: Annotated[int, Strict(), Field(ge=1, le=16)] = 4  # native 1.45 um pixels per output pixel (mlsim.camera)
    exposure_ms: Pos = 33.0
    gain_db: Annotated[float, Strict(), Field(ge=0, le=72)] = 0.0
    # the sensor model of mlsim.camera (IMX415-class defaults, per native pixel; typical, not given)
    full_well_e: Pos = 5000.0
    read_noise_e: NonNeg = 2.0
    dark_current_e_per_s: NonNeg = 5.0
    conversion_gain_dn_per_e: Pos = 0.2
    black_level_dn: NonNeg = 50.0
    adc_bits: Annotated[int, Strict(), Field(ge=8, le=16)] = 10
    lens_transmittance: Annotated[float, Strict(), Field(gt=0, le=1)] = 0.9
    bayer: Bool = True
    noise: Bool = True  # false: the noiseless mean frame (still quantised)
    sensitivity: str = "imx415_like"  # a shipped QE set or a CSV (nm, R, G, B) (mlsim.spectra.camera_sensitivity_msds)


class AmbientSpec(_Model):
    """Ambient lamp above the sensor (SPEC 1.1: 50 W daylight lamps 1.5 m above), an isotropic point
    source whose light leaks through the absorber and the ML layer (:mod:`mlsim.render.ambient`)."""

    lamp: Literal["none", "daylight", "white_led"] = "none"
    power_w: NonNeg = 50.0  # electrical rating
    height_m: Pos = 1.5  # above the rods' tips
    offset_mm: tuple[float, float] = (0.0, 0.0)  # the lamp's x, y from the array's centre
    # lm per electrical W; None: the lamp type's typical value (mlsim.render.ambient.LAMP_EFFICACY_LM_PER_W)
    efficacy_lm_per_w: Pos | None = None
    occlusion: Bool = True  # rods shade the surface from the lamp (traced); false: cosine law only
    flicker_hz: NonNeg = 0.0  # light modulation: 100 (50 Hz mains) or 120 (60 Hz); 0: steady
    flicker_depth: Annotated[float, Strict(), Field(ge=0.0, le=1.0)] = 0.3  # (max - min) / (max + min) when flickering
    switch_on_s: Annotated[float, Strict()] | None = None  # the lamp is off before this time; None: on from the start
    switch_off_s: Annotated[float, Strict()] | None = None  # and off from this time on; None: stays on

    @model_validator(mode="after")
    def _switching(self):
        if self.switch_on_s is not None and self.switch_off_s is not None and self.switch_off_s <= self.switch_on_s:
            raise ValueError(f"switch_off_s = {self.switch_off_s:g} must be after switch_on_s = {self.switch_on_s:g}")
        return self


class CalibrationSpec(_Model):
    """The calibration frame (SPEC 1.1, 1.6): a copy of the sensor without the absorbing layer under a
    40 W white LED lamp, for the DLLM's Hough circles. The lamp's height is not given; the exposure is
    set automatically so the frame's brightest pixels reach ``target_level_dn8``."""

    lamp: Literal["daylight", "white_led"] = "white_led"
    power_w: Pos = 40.0
    height_m: Pos = 0.5  # "held above the sensor": not given
    target_level_dn8: Annotated[float, Strict(), Field(gt=0, lt=255)] = 200.0  # green, 99.5th percentile


class DllmSpec(_Model):
    """Detector thresholds (SPEC 1.6); alpha and beta are not given: defaults to be tuned by the ambient study."""

    alpha: Pos = 1.05
    beta: Pos = 1.3
    init_s: Pos = 1.0  # SPEC 1.6: 1 s of frames
    blur_sigma_px: Pos = 2.0
    # the thresholds follow recent data (dllm.detector): towards idle frames with this time constant,
    adapt_s: Pos = 1.0
    # and during events with this one (a press barely moves them; a lamp switched on is absorbed)
    recover_s: Pos = 5.0


class ClassifySpec(_Model):
    """The closed robot loop of SPEC 1.7 (``outputs = ["classify"]``): the camera frames through the
    streaming DLLM and the interaction CNN on the last 8 frames, a prediction and a robot command per
    window (:mod:`classifiers.closed_loop`)."""

    model: str | None = None  # a model file of `mlsim train` (e.g. out/interaction_train/interaction_8class.pt)
    stride: Annotated[int, Strict(), Field(ge=1, le=1000)] = 1  # frames between decisions


# ------------------------------------------------------------------------------------- fidelity
class MeshFidelity(_Model):
    """Tetrahedral meshing (fTetWild via pytetwild).

    ``edge_length_mm`` is the target edge length. ``envelope_mm`` is how far the tet surface may
    stray from the exact surface before boundary nodes are snapped back onto it; by default it
    follows the edge length (edge / 40), so one knob trades accuracy for cost.
    """

    edge_length_mm: Pos = 2.0
    envelope_mm: Pos | None = None
    coarsen: Bool = True
    segments_per_circle: Annotated[int, Strict(), Field(ge=12, le=512)] = 48
    fraction_levels: Annotated[int, Strict(), Field(ge=1, le=4)] = 3
    timeout_s: Pos = 240.0
    retries: Annotated[int, Strict(), Field(ge=0, le=10)] = 3

    @property
    def resolved_envelope_mm(self) -> float:
        return self.envelope_mm if self.envelope_mm is not None else self.edge_length_mm / 40.0


class SolveFidelity(_Model):
    """Mechanics solve: tier, elements, time sub-steps and contact discretisation (see fem.quasistatic)."""

    tier: Literal["reduced", "linear", "nonlinear"] = "linear"
    element_order: Literal[1, 2] = 2
    # "auto": mixed P2-P1 when order 2 and any layer has nu >= 0.45 (locking-free), else displacement only
    formulation: Literal["auto", "displacement", "mixed"] = "auto"
    substeps: Annotated[int, Strict(), Field(ge=1, le=1000)] = 1
    contact_band_mm: NonNeg = 2.0  # rod side faces this far below the tips may touch the indenter
    penalty_factor: Annotated[float, Strict(), Field(ge=1.0, le=1e6)] = 100.0  # contact stiffness = factor * E / h
    # reduced tier: patches whose resultants give the fields away from each loaded rod (fem.quasistatic)
    patches_per_tip: Annotated[int, Strict(), Field(ge=1, le=64)] = 7
    patches_per_side: Annotated[int, Strict(), Field(ge=1, le=64)] = 8
    gravity: Bool = True
    # linear/reduced tiers: refuse a step where a contact point moves more than this fraction of the
    # rod height (small-strain kinematics are no longer valid there; see fem.quasistatic)
    small_strain_limit: Annotated[float, Strict(), Field(gt=0.0, le=10.0)] = 0.5
    # linear/reduced tiers with rod_kinematics "second_order" or "cosserat": refuse a step (cosserat: a contact
    # round) where a rod's axial contact load passes this fraction of its Euler buckling load (fixed base, free
    # tip; fem.rod_kinematics.euler_load_n): the P-delta model cannot follow a rod near buckling (a swipe over
    # 10.5 mm rods dragged tips 4-13 mm), nor can Cosserat rods under dead contact loads (fem.rod_exact)
    buckling_limit: Annotated[float, Strict(), Field(gt=0.0, le=10.0)] = 0.5
    # linear/reduced tiers' contact step: "admm" (bounded work on the Delassus operator, fem.contact_admm)
    # or "newton" (semi-smooth Newton on the penalty law smoothed over 1e-7 h, fem.condensed; slower,
    # kept for comparison). Both solve the contact law the nonlinear tier solves.
    contact_solver: Literal["admm", "newton"] = "admm"
    # per linearisation (admm). 600, not 200: the default demo's release step (the twisted probe lifting
    # off its stuck rods) needs 431 and stopped unconverged at 200 (its frame's rod force 1.42 N where
    # the converged answer is 1.03 N and the nonlinear tier's 0); the episode costs 4 % more iterations
    contact_max_iterations: Annotated[int, Strict(), Field(ge=1, le=100000)] = 600
    # nonlinear tier: "condensed" (the body linearised once, the contact solved by the linear tiers' ADMM in every
    # outer iteration, a step it does not converge goes to the penalty Newton; fem.finite_strain.CondensedBody) or
    # "penalty" (Newton with the contact inside its loop). The condensed Newton: the default demo at full load in
    # 6 min against hours, the screw scene at 4.8 s per frame against over 15 min for one sliding step, the tiny
    # scene's press and slide in 19 s against 35 s, per-rod forces within 1.1 % of the penalty Newton's there
    nonlinear_newton: Literal["penalty", "condensed"] = "condensed"
    # linear/reduced tiers (admm): "second_order" adds the bent rods' rigid-rotation terms (tip drop,
    # tilted tip face) to the contact kinematics and the displacement output, and the P-delta load of
    # their axial contact force (fem.rod_kinematics); "cosserat": each loaded rod a geometrically exact
    # (Cosserat) rod on the body's root motion, its nonlinear part added to the points and vertices and its
    # bent root moment to the body (fem.rod_exact); "first_order": the plain small-strain body
    rod_kinematics: Literal["first_order", "second_order", "cosserat"] = "first_order"
    # rod_kinematics "cosserat": how the rods take the contact forces in their solves between the contact's
    # rounds. "dead": as dead loads (a rod past buckling_limit x its free Euler load is refused); "held"
    # (the default demo's): also held by the contact's stiffness where it touches (a Robin coupling, fem.rod_exact),
    # so a rod pressed past its free Euler load by a face that grips its tip stands (the tiny scene's flat press
    # at 1 x: 1.4 % off the nonlinear tier in force; the screw scene within 5 % on all four measures). Where bent
    # rods are let go (the default demo's lift-off: tip displacement 21.5 % off on one of two meshes, rods left bent
    # against the face by friction) the run log says its error estimate does not hold (fem.rod_error)
    rod_coupling: Literal["dead", "held"] = "dead"
    # nonlinear tier: "quasi_static" (each step an equilibrium: no answer past a limit point, where a rod
    # buckles or snaps back) or "backward_euler" (implicit dynamics with the elastomer's inertia and damping,
    # energy-stable at any step; fem.dynamics, fem.finite_strain): the swipe that buckles rods and releases them.
    # The linear tiers with rod_kinematics = "cosserat": the rods' inertia (fem.cosserat_dynamics; the base
    # quasi-static); other rod kinematics have none and say so in the run log
    dynamics: Literal["quasi_static", "backward_euler"] = "quasi_static"
    # dynamics: the elastomer's loss factor eta (not given in SPEC 1.2; 0.1, the middle of unfilled silicone
    # rubbers' 0.05-0.2 at room temperature and audio frequencies, Nashif, Jones and Henderson, "Vibration
    # Damping", Wiley 1985, ch. 3): stiffness-proportional Rayleigh damping with the damping ratio eta / 2 at
    # the rods' first bending mode, rising in proportion to frequency above it
    loss_factor: Annotated[float, Strict(), Field(ge=0.0, le=2.0)] = 0.1
    # dynamics: the least number of steps per period of the rods' first bending mode (fem.dynamics.
    # cantilever_first_mode_rad_s); a coarser step is refused naming substeps (backward Euler damps a mode it
    # steps over: at 4 steps a period it keeps 54 % of the mode's amplitude a step, the snap-back's light goes)
    steps_per_period: Annotated[float, Strict(), Field(ge=1.0, le=1000.0)] = 4.0


class RenderFidelity(_Model):
    """Light transport (:mod:`mlsim.render`). ``path``: Mitsuba path-traces every frame on the deformed
    sheet with ``spp`` samples per pixel. ``transport``: one sparse pixels x patches matrix traced once
    per geometry with ``transport_spp`` samples per pixel (cached), then each frame is a product;
    entries below ``transport_drop`` times the largest are dropped (the dropped share is reported).
    The matrix is of the rest shape. ``deformed``: the direct light rasterised on each frame's
    deformed sheet (``direct_samples_per_side`` squared samples per pixel) plus the rest shape's
    bounces from a matrix of the paths with a bounce (traced and cached as ``transport``'s): the
    default, about as fast as ``transport`` and within 1 % per rod of path tracing where the rods
    bend (``mlsim accuracy SCENE --stage render``)."""

    tier: Literal["transport", "deformed", "path"] = "deformed"
    # Where Mitsuba traces (path frames, the transport matrix): "auto" takes an NVIDIA GPU where
    # Mitsuba's cuda_ad_mono starts (about 50x the 2-core CPU on a path-traced frame), else the CPU;
    # the run log says which. "cuda" fails with the reason where there is no GPU.
    device: Literal["auto", "cpu", "cuda"] = "auto"
    spp: Annotated[int, Strict(), Field(ge=1, le=65536)] = 16
    # The emitting sheet's edges are split down to this length: emission is linear over each face
    # and one value per vertex (mlsim.emission.patches); 1 mm is half the default tet edge.
    sheet_edge_mm: Annotated[float, Strict(), Field(ge=0.05, le=50.0)] = 1.0
    transport_spp: Annotated[int, Strict(), Field(ge=1, le=4096)] = 64
    transport_drop: Annotated[float, Strict(), Field(ge=0.0, lt=1.0)] = 1e-4
    # transport tier: the matrix is of the rest shape. Frames in which the ML layer moved further than this are
    # path-traced at `spp` instead: on the default demo, rest-shape transport stayed within 3 % per
    # rod up to 0.8 mm and was 10-45 % off on the slide (1-2.6 mm). "off": every frame from the matrix.
    # "off": pure transport (a dataset at the fast tiers; the run log says how far the sheet moved).
    transport_max_displacement_mm: Annotated[float, Strict(), Field(gt=0.0)] | Literal["off"] = 0.5

    @property
    def path_above_mm(self) -> float | None:
        """The displacement above which a transport-tier frame is path-traced; None: never."""
        return None if self.transport_max_displacement_mm == "off" else self.transport_max_displacement_mm
    # deformed tier: samples per pixel side of the rasterised direct light (mlsim.render.direct_raster).
    # Against Mitsuba's 3 x 3 primary rays, per rod 0.08-0.25 % at 1, 0.05-0.10 % at 2, 0.02-0.06 % at 3;
    # per pixel (edge aliasing) 1.6-3.2 %, 0.4-0.8 %, 0.03-0.1 %. Against the spectral path reference
    # every count gives 0.8 % per rod on the default demo. 2 cores: 205-244 frames/s at 1, 150-182 at 2.
    direct_samples_per_side: Annotated[int, Strict(), Field(ge=1, le=8)] = 1
    max_depth: Annotated[int, Strict(), Field(ge=3, le=64)] = 12  # camera, acrylic, core: 3 vertices reach the sheet
    rr_depth: Annotated[int, Strict(), Field(ge=1, le=64)] = 5  # Russian roulette from this depth on


class FidelitySpec(_Model):
    mesh: MeshFidelity = MeshFidelity()
    solve: SolveFidelity = SolveFidelity()
    render: RenderFidelity = RenderFidelity()


# ---------------------------------------------------------------------------------------- scene
class Scene(_Model):
    """A whole run: the sensor, its load, optics, camera, ambient light, detector, fidelity, outputs.

    Frozen: use :meth:`with_values` to derive a changed scene.
    """

    name: str = "unnamed"
    description: str = ""
    seed: Annotated[int, Strict(), Field(ge=0, lt=2**63)] = 0
    # The camera's noise stream (episode frames and the idle frames before them); None: from `seed`.
    # A dataset varies it per episode and keeps `seed`, which also seeds the sensor's precomputes
    # (the reduced tier's patches, the transport matrix, the calibration frame), so they are shared.
    noise_seed: Annotated[int, Strict(), Field(ge=0, lt=2**63)] | None = None
    # the [sensor] section of the scene's sensor kind (``sensor.kind``, default "ml_rod_array": the
    # SensorSpec above; another kind's model comes from its registration, mlsim.stage.register_kind)
    sensor: SerializeAsAny[SensorSpec] = SensorSpec()
    materials: dict[str, MaterialOverride] = {}
    load: LoadSpec | None = None
    emission: EmissionSpec = EmissionSpec()
    optics: OpticsSpec = OpticsSpec()
    camera: CameraSpec = CameraSpec()
    ambient: AmbientSpec = AmbientSpec()
    calibration: CalibrationSpec = CalibrationSpec()
    dllm: DllmSpec = DllmSpec()
    classify: ClassifySpec = ClassifySpec()
    fidelity: FidelitySpec = FidelitySpec()
    verify_s2: VerifyS2Spec | None = None
    outputs: tuple[str, ...] = ("mesh",)

    @field_validator("sensor", mode="wrap")
    @classmethod
    def _sensor_of_its_kind(cls, value: Any, handler):
        kind = value.get("kind", "ml_rod_array") if isinstance(value, dict) else getattr(value, "kind", "ml_rod_array")
        if kind == "ml_rod_array":
            return handler(value)
        from mlsim.stage import kind as registered_kind

        try:
            model = registered_kind(str(kind)).sensor_model
        except KeyError as exc:
            raise ValueError(str(exc.args[0])) from None
        return value if isinstance(value, model) else model.model_validate(value)

    @property
    def kind(self) -> str:
        """The sensor kind (``sensor.kind``)."""
        return getattr(self.sensor, "kind", "ml_rod_array")

    # -- access ---------------------------------------------------------------------------------
    def get(self, path: str):
        """The value at a dotted path, e.g. ``scene.get("sensor.rod.height_mm")``."""
        node: Any = self
        for part in _split_path(path):
            if isinstance(part, int):
                node = node[part]
            elif isinstance(node, dict):
                node = node[part]
            else:
                if part not in type(node).model_fields:
                    raise KeyError(f"{path}: no field {part!r} in {type(node).__name__}")
                node = getattr(node, part)
        return node

    def with_values(self, values: dict[str, Any]) -> "Scene":
        """A new scene with the given dotted fields changed, validated like a loaded one.

        >>> scene.with_values({"sensor.rod.height_mm": 12.0})
        """
        data = self.model_dump(mode="json", exclude_none=True)
        for path, value in values.items():
            _set_path(data, _split_path(path), value, path)
        return scene_from_dict(data, source="with_values")

    def material(self, region: str) -> Material:
        """The resolved material of a region (``core``, ``ml_layer``, ``absorber``)."""
        return resolve_material(getattr(self.sensor.materials, region), self.materials)

    def content_hash(self, paths: tuple[str, ...] | None = None, exclude: tuple[str, ...] = ()) -> str:
        """SHA-256 of the canonical JSON of the whole scene, or of the given dotted fields only; ``exclude``:
        dotted fields inside those left out (a section's entries: "fidelity.solve.rod_kinematics" inside
        "fidelity.solve")."""
        if paths is None:
            payload = self.model_dump(mode="json")
        else:
            payload = {p: _jsonable(self.get(p)) for p in sorted(paths)}
        for field in exclude:
            if paths is None:
                _drop_dotted(payload, field)
                continue
            payload.pop(field, None)
            for p in payload:
                if field.startswith(p + "."):
                    _drop_dotted(payload[p], field[len(p) + 1 :])
        return hashlib.sha256(json.dumps(payload, sort_keys=True).encode()).hexdigest()

    def to_dotted(self) -> dict[str, Any]:
        """Every leaf field as ``{"sensor.rod.height_mm": 9.0, ...}`` (for printing and sweeps)."""
        out: dict[str, Any] = {}
        _flatten(self.model_dump(mode="json"), "", out)
        return out


def _drop_dotted(data, dotted: str) -> None:
    """Remove the entry at ``dotted`` ("a.b.c") from nested dicts, if it is there."""
    *path, last = dotted.split(".")
    for key in path:
        data = data.get(key) if isinstance(data, dict) else None
    if isinstance(data, dict):
        data.pop(last, None)


def resolve_material(name: str, overrides: dict[str, MaterialOverride]) -> Material:
    """A shipped material with a scene's overrides applied, or a material the scene defines."""
    values = overrides[name].model_dump(exclude={"description"}) if name in overrides else {}
    if name in SHIPPED_MATERIALS:
        return SHIPPED_MATERIALS[name].with_overrides(values)
    unknown = Quantity(None, "not given in the scene")
    base = Material(
        name=name,
        description=overrides[name].description or "defined in the scene",
        **{p: unknown for p in MATERIAL_PROPERTIES},
    )
    return base.with_overrides(values)


# ------------------------------------------------------------------------------------ loading
def read_toml(path: str | Path, what: str = "scene file") -> dict:
    """The TOML file at ``path`` as a dict; a :class:`SceneError` if it is missing or not TOML."""
    path = Path(path)
    if not path.is_file():
        raise SceneError([Problem("<file>", str(path), f"no such {what}")], source=str(path))
    try:
        return tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise SceneError([Problem("<file>", str(path), f"not valid TOML: {exc}")], source=str(path)) from None


def load_scene(path: str | Path, overrides: dict[str, Any] | None = None) -> Scene:
    """Read and validate a TOML scene. Raises :class:`SceneError` (with every problem) if invalid.

    A scene may start from another: ``scene = "base.toml"`` (relative to the file) takes that scene
    and changes the fields this file gives (tables merged, other values replaced): an overlay such as
    ``mlsim calibrate`` writes."""
    data = _with_base(read_toml(path), Path(path), ())
    for dotted, value in (overrides or {}).items():
        _set_path(data, _split_path(dotted), value, dotted)
    return scene_from_dict(data, source=str(path))


def _with_base(data: dict, path: Path, seen: tuple) -> dict:
    """``data`` merged over the scene its ``scene`` key names, recursively (:func:`load_scene`)."""
    if "scene" not in data:
        return data
    base_path = (path.parent / str(data.pop("scene"))).resolve()
    if base_path in seen or base_path == path.resolve():
        raise SceneError([Problem("scene", str(base_path), "the scenes include each other in a circle")], source=str(path))
    base = _with_base(read_toml(base_path), base_path, seen + (path.resolve(),))

    def merge(into: dict, over: dict) -> dict:
        for key, value in over.items():
            into[key] = merge(dict(into[key]), value) if isinstance(value, dict) and isinstance(into.get(key), dict) else value
        return into

    return merge(base, data)


def scene_from_dict(data: dict, source: str | None = None) -> Scene:
    """Validate a plain dict (as read from TOML) into a :class:`Scene`."""
    try:
        scene = Scene.model_validate(data)
    except ValidationError as exc:
        raise SceneError(_problems_from_pydantic(exc), source=source) from None
    problems = check_consistency(scene)
    if problems:
        raise SceneError(problems, source=source)
    return scene


def check_consistency(scene: Scene) -> list[Problem]:
    """Checks that involve several fields (each field alone is already valid): the ML rod array's
    below; another sensor kind's by its registered ``check`` (mlsim.stage.SensorKind), and for every
    kind that its ``outputs`` are stages of the kind."""
    if scene.kind != "ml_rod_array":
        from mlsim.stage import kind, outputs

        problems = [Problem(f"outputs[{i}]", out, f"unknown output; choose from: {', '.join(outputs(scene.kind))}")
                    for i, out in enumerate(scene.outputs) if out not in outputs(scene.kind)]
        check = kind(scene.kind).check
        return problems + [Problem(*p) for p in (check(scene) if check is not None else [])]
    problems: list[Problem] = []
    s = scene.sensor
    if s.surface_size_mm is not None and s.pitch_mm is not None:
        problems.append(Problem("sensor.pitch_mm", s.pitch_mm, "give either surface_size_mm or pitch_mm, not both"))
        return problems
    pitch = min(s.pitch_x_mm, s.pitch_y_mm)
    if s.rod.diameter_mm >= pitch:
        problems.append(
            Problem(
                "sensor.rod.diameter_mm",
                s.rod.diameter_mm,
                f"rods overlap: the pitch is {pitch:g} mm ({_pitch_origin(s)}); "
                f"use a diameter < {pitch:g} mm or a larger pitch",
            )
        )
    radius = s.rod.diameter_mm / 2.0
    layers = s.layers.absorber_mm + s.layers.ml_mm
    for limit, what in ((radius, "rod radius"), (s.base.thickness_mm, "base thickness"), (s.rod.height_mm, "rod height")):
        if layers >= limit:
            problems.append(
                Problem(
                    "sensor.layers.ml_mm",
                    s.layers.ml_mm,
                    f"the layers (absorber {s.layers.absorber_mm:g} + ML {s.layers.ml_mm:g} = {layers:g} mm) "
                    f"must be thinner than the {what} ({limit:g} mm)",
                )
            )
            break
    stack = scene.camera.distance_mm + scene.optics.acrylic_thickness_mm + s.base.thickness_mm + s.rod.height_mm
    if stack > s.shell_height_mm:
        problems.append(
            Problem(
                "sensor.rod.height_mm",
                s.rod.height_mm,
                f"the rod tips would be {stack:g} mm above the camera (camera distance {scene.camera.distance_mm:g} "
                f"+ acrylic {scene.optics.acrylic_thickness_mm:g} + base {s.base.thickness_mm:g} + rod "
                f"{s.rod.height_mm:g}) but the shell is {s.shell_height_mm:g} mm tall; shorten the rod, "
                "move the camera closer (camera.distance_mm) or raise sensor.shell_height_mm",
            )
        )
    frame_ms = 1000.0 / scene.camera.fps
    if scene.camera.exposure_ms > frame_ms * (1 + 1e-9):
        problems.append(
            Problem("camera.exposure_ms", scene.camera.exposure_ms, f"must be <= the frame period {frame_ms:.4g} ms at {scene.camera.fps:g} FPS")
        )
    known = sorted(set(SHIPPED_MATERIALS) | set(scene.materials))
    for region in ("core", "ml_layer", "absorber"):
        name = getattr(s.materials, region)
        if name not in known:
            problems.append(Problem(f"sensor.materials.{region}", name, f"unknown material; choose one of: {', '.join(known)}"))
        elif SHIPPED_MATERIALS.get(name) is not None and SHIPPED_MATERIALS[name].rigid:
            problems.append(Problem(f"sensor.materials.{region}", name, "is a rigid material; the rods must be an elastomer"))
    for name, override in scene.materials.items():
        if name not in SHIPPED_MATERIALS:
            for needed in ("young_modulus_pa", "poisson_ratio", "density_kg_m3"):
                if getattr(override, needed) is None:
                    problems.append(
                        Problem(f"materials.{name}.{needed}", None, "a new material needs young_modulus_pa, poisson_ratio and density_kg_m3")
                    )
    from mlsim.stage import outputs  # the kind's registered stages are the products

    OUTPUTS = outputs(scene.kind)
    for i, out in enumerate(scene.outputs):
        if out not in OUTPUTS:
            problems.append(Problem(f"outputs[{i}]", out, f"unknown output; choose from: {', '.join(OUTPUTS)}"))
        elif out in ("solve", "emission", "render", "camera", "dllm", "classify") and scene.load is None:
            problems.append(Problem(f"outputs[{i}]", out, f"the {out} stage needs a [load] section (an indenter and its segments)"))
        elif out == "classify" and scene.classify.model is None:
            problems.append(Problem("classify.model", None, "the closed loop needs a trained model: make one with "
                                    "'mlsim dataset scenes/interactions/paper.toml --out DATA' and 'mlsim train DATA --out DIR', "
                                    "then give DIR/interaction_8class.pt"))
        elif out == "verify_s2" and scene.verify_s2 is None:
            problems.append(Problem(f"outputs[{i}]", out, "the verification needs a [verify_s2] section (see scenes/verify_fem_s2.toml)"))
    if scene.load is not None:
        x, y = scene.load.start_xy_mm
        if abs(x) > s.size_x_mm / 2 or abs(y) > s.size_y_mm / 2:
            problems.append(
                Problem("load.start_xy_mm", [x, y], f"the indenter must start over the surface (|x| <= {s.size_x_mm / 2:g}, |y| <= {s.size_y_mm / 2:g} mm)")
            )
    mesh = scene.fidelity.mesh
    if mesh.edge_length_mm > s.rod.diameter_mm:
        problems.append(
            Problem("fidelity.mesh.edge_length_mm", mesh.edge_length_mm, f"must be <= the rod diameter ({s.rod.diameter_mm:g} mm) to resolve the rods")
        )
    volume_mm3 = s.size_x_mm * s.size_y_mm * s.base.thickness_mm + s.n_rods * math.pi * radius * radius * s.rod.height_mm
    # products, not powers: a float power past 1e308 raises OverflowError where a product is inf; an
    # edge below 1e-103 mm cubes to 0.0 (inf tets); inf / inf is NaN, refused too
    regular_tet_mm3 = mesh.edge_length_mm * mesh.edge_length_mm * mesh.edge_length_mm / (6 * math.sqrt(2))
    n_tets = volume_mm3 / regular_tet_mm3 if regular_tet_mm3 > 0 else math.inf
    if not n_tets <= 5e6:
        problems.append(
            Problem(
                "fidelity.mesh.edge_length_mm",
                mesh.edge_length_mm,
                f"would give about {n_tets:.3g} tetrahedra (limit 5e6); use a larger edge length",
            )
        )
    if mesh.resolved_envelope_mm >= min(s.layers.ml_mm, radius) and mesh.envelope_mm is not None:
        problems.append(Problem("fidelity.mesh.envelope_mm", mesh.envelope_mm, f"must be < the ML layer ({s.layers.ml_mm:g} mm)"))
    if not problems:  # a load off the sensor, an episode or a run too large for any machine (mlsim.plausibility)
        from mlsim.plausibility import problems as implausible

        problems = implausible(scene)
    if not problems:  # the kind's own checks (fem: the nonlinear tier's dynamics step) on an otherwise sound scene
        from mlsim.stage import kind

        check = kind(scene.kind).check
        problems += [Problem(*p) for p in (check(scene) if check is not None else [])]
    return problems


def _pitch_origin(s: SensorSpec) -> str:
    if s.pitch_mm is not None:
        return "sensor.pitch_mm"
    return f"surface {s.surface_size_mm:g} mm over {max(s.rows, s.cols)} rods"


# ----------------------------------------------------------------------- error text from pydantic
_TAGS = set(SEGMENT_KINDS) | set(INDENTER_SHAPES)


def _problems_from_pydantic(exc: ValidationError) -> list[Problem]:
    problems = []
    for err in exc.errors(include_url=False):
        loc = list(err["loc"])
        # Discriminated unions put the tag in the location: load.segments.0.press.speed_mm_s.
        clean = [p for i, p in enumerate(loc) if not (p in _TAGS and i > 0 and (isinstance(loc[i - 1], int) or loc[i - 1] == "indenter"))]
        # a union of value types (a number or "off") names its branches in the location too:
        # transport_max_displacement_mm.constrained-float, ...literal['off']: the field is the path
        clean = [p for p in clean if not (isinstance(p, str) and not p.isidentifier())]
        path = _join_path(clean)
        problems.append(Problem(path or "<scene>", err.get("input"), _message(err, clean)))
    merged: dict = {}  # one line per field: the union's branches joined ("must be > 0, or must be one of: 'off'")
    for p in problems:
        merged[p.path] = Problem(p.path, p.value, f"{merged[p.path].message}, or {p.message}") if p.path in merged else p
    return list(merged.values())


_BOUNDS = {"greater_than": ">", "greater_than_equal": ">=", "less_than": "<", "less_than_equal": "<="}
_BOUND_KEYS = {">": "gt", ">=": "ge", "<": "lt", "<=": "le"}
_FIXED = {
    "finite_number": "must be a finite number (NaN and inf are not allowed)",
    "bool_type": "must be true or false",
    "string_type": "must be a string",
    "missing": "required field is missing",
    "tuple_type": "must be a list",
    "list_type": "must be a list",
    "dict_type": "must be a table (section)",
    "model_type": "must be a table (section)",
}
_TYPED = {"float_type": "a number", "float_parsing": "a number", "int_type": "an integer", "int_parsing": "an integer", "int_from_float": "an integer"}


def _message(err: dict, loc: list) -> str:
    """Our wording of a pydantic error: what is valid, in the scene's own terms."""
    kind = err["type"]
    ctx = err.get("ctx") or {}
    if kind in _BOUNDS:
        op = _BOUNDS[kind]
        return f"must be {op} {ctx[_BOUND_KEYS[op]]}"
    if kind in _FIXED:
        return _FIXED[kind]
    if kind in _TYPED:
        return f"must be {_TYPED[kind]}, not {type(err.get('input')).__name__}"
    if kind == "extra_forbidden":
        valid = _valid_keys(loc[:-1])
        return f"unknown key; valid keys here: {', '.join(valid)}" if valid else "unknown key"
    if kind == "literal_error":
        return f"must be one of: {ctx.get('expected', '')}"
    if kind == "union_tag_invalid":
        return f"unknown {ctx.get('discriminator', '').strip(chr(39))} {ctx.get('tag')!r}; choose one of: {ctx.get('expected_tags')}"
    if kind == "union_tag_not_found":
        return f"needs {ctx.get('discriminator', '')} (one of the kinds listed in the docs)"
    if kind in ("too_short", "too_long"):
        return f"must have {'at least' if kind == 'too_short' else 'at most'} {ctx.get('min_length', ctx.get('max_length'))} item(s)"
    if kind == "value_error":
        return str(ctx.get("error", err["msg"]))
    return err["msg"]


def _valid_keys(loc: list) -> list[str]:
    """Field names of the model at a location, for 'unknown key' messages."""
    model: Any = Scene
    for part in loc:
        if isinstance(part, int) or model is None:
            continue
        if part in _TAGS:
            model = _tagged_model(part)
            continue
        fields = getattr(model, "model_fields", None)
        if fields is None or part not in fields:
            return []
        model = _model_of(fields[part].annotation)
    return sorted(getattr(model, "model_fields", {}) or [])


def _tagged_model(tag: str):
    for cls in (PressSegment, SlideSegment, RotateSegment, HoldSegment, ReleaseSegment, FlatIndenter, CylinderIndenter, SphereIndenter, BoxIndenter):
        for key in ("kind", "shape"):
            field = cls.model_fields.get(key)
            if field is not None and tag in getattr(field.annotation, "__args__", ()):
                return cls
    return None


def _model_of(annotation):
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in getattr(annotation, "__args__", ()):
        found = _model_of(arg)
        if found is not None:
            return found
    return None


# ---------------------------------------------------------------------------------- dotted paths
def _split_path(path: str) -> list:
    parts: list = []
    for token in path.split("."):
        while "[" in token:
            head, _, rest = token.partition("[")
            if head:
                parts.append(head)
            index, _, token = rest.partition("]")
            try:
                parts.append(int(index))
            except ValueError:
                raise SceneError([Problem(path, index, "a list index in brackets must be an integer, e.g. load.segments[0].speed_mm_s")]) from None
        if token:
            parts.append(int(token) if token.isdigit() else token)  # load.segments.2 means load.segments[2]
    return parts


def _join_path(parts: list) -> str:
    out = ""
    for p in parts:
        out += f"[{p}]" if isinstance(p, int) else (f".{p}" if out else str(p))
    return out


def _set_path(data: dict, parts: list, value, dotted: str) -> None:
    node = data
    for i, part in enumerate(parts):
        where = _join_path(parts[:i])
        if isinstance(node, list):
            if not isinstance(part, int):
                raise SceneError([Problem(dotted, value, f"{where} is a list: index it, e.g. {where}[0].{part}")])
            if not -len(node) <= part < len(node):
                raise SceneError([Problem(dotted, value, f"index {part} is out of range: {where} has {len(node)} entries")])
        elif isinstance(node, dict):
            if isinstance(part, int):
                raise SceneError([Problem(dotted, value, f"{where or 'the scene'} is a section, not a list: name a field, not an index")])
        else:
            raise SceneError([Problem(dotted, value, "is not a field (its parent is a value, not a section)")])
        if i == len(parts) - 1:
            node[part] = value
        else:
            node = node[part] if isinstance(node, list) else node.setdefault(part, {})


def _flatten(node, prefix: str, out: dict) -> None:
    if isinstance(node, dict):
        for k, v in node.items():
            _flatten(v, f"{prefix}.{k}" if prefix else k, out)
    elif isinstance(node, list) and node and isinstance(node[0], dict):
        for i, v in enumerate(node):
            _flatten(v, f"{prefix}[{i}]", out)
    else:
        out[prefix] = node


def _jsonable(value):
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (tuple, list)):
        return [_jsonable(v) for v in value]
    return value
