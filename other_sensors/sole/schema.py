"""The ``[sensor]`` section of a plantar-sole scene (``sensor.kind = "plantar_sole"``), validated at the door.

Scene lengths are in mm and angles in degrees (their units in the names); the models convert to
SI for the physics (:meth:`CellsSpec.layout`, the primitives' ``to_terrain``, :meth:`FootSpec.pose`).
"""

from __future__ import annotations

from typing import Annotated, Literal, Union

import numpy as np
from pydantic import Field, field_validator

from mlsim.scene import SpecModel

from .cells import CELL_AREA_M2, DEFAULT_ROW_COUNTS, SENSOR_RADIUS_FRACTION
from .feasibility import CLEARANCE_M, EPS_AREA, EPS_FORCE_KG, EPS_TORQUE_NM

__all__ = ["SoleSensor", "CellsSpec", "FoundationSpec", "ProximitySpec", "TerrainSpec", "FootSpec", "FeasibilitySpec",
           "BalanceSpec", "BalanceSweepSpec", "ObstacleSpec", "LandingSpec", "FOUNDATION_STIFFNESS_N_M3", "PROXIMITY_RANGE_MM", "EARLY_CONTACT_LOAD_N", "FORCE_NOISE_N"]

# --- documented defaults (the SPEC does not give them) -------------------------------------------
# Winkler modulus of the skin's foam and cover. A choice: the 86 kg robot standing on one whole sole
# (844 N over 290 cm^2 of cells) sinks 0.29 mm, and 250 N on a 4 cm x 4 cm obstacle sinks 1.6 mm:
# millimetres, as a few-millimetre skin allows.
FOUNDATION_STIFFNESS_N_M3 = 1.0e8
# Proximity (pre-touch) range. A choice: 10 mm, under the 20 mm obstacles of scenes/sole, so that the
# pre-touch polygon outlines an obstacle rather than the floor around it.
PROXIMITY_RANGE_MM = 10.0
# Normal load on the foot at early contact. A choice: 250 N, about 30 % of the 86 kg robot's weight
# (844 N), as the swing foot lands before the weight is transferred to it.
EARLY_CONTACT_LOAD_N = 250.0
# Noise of one force sensor. A choice: 0.02 N rms (a capacitive load cell's), far under eps_F (1.47 N).
FORCE_NOISE_N = 0.02


_Model = SpecModel  # unknown keys refused, frozen, NaN and Inf refused (the scene's own rule)


class CellsSpec(_Model):
    """The skin cells (:mod:`other_sensors.sole.cells`)."""

    row_counts: tuple[Annotated[int, Field(ge=1, le=30)], ...] = DEFAULT_ROW_COUNTS
    cell_area_mm2: float = Field(CELL_AREA_M2 * 1e6, gt=0.0, le=1e4)
    sensor_radius_fraction: float = Field(SENSOR_RADIUS_FRACTION, gt=0.0, lt=0.866)
    quadrature: int = Field(6, ge=1, le=24)  # sub-triangles per hexagon edge: 6 n^2 samples per cell
    force_noise_n: float = Field(FORCE_NOISE_N, ge=0.0, le=100.0)

    @field_validator("row_counts")
    @classmethod
    def _interlocking(cls, value):
        if not value:
            raise ValueError("give one or more rows")
        if any((a - b) % 2 == 0 for a, b in zip(value, value[1:])):
            raise ValueError("neighbouring rows must differ in parity (odd, even, odd, ...) for the hexagons to interlock")
        return value

    def layout(self):
        from .cells import sole_layout

        return sole_layout(self.row_counts, self.cell_area_mm2 * 1e-6, self.sensor_radius_fraction)


class FoundationSpec(_Model):
    """The Winkler layer (:mod:`other_sensors.sole.contact`)."""

    stiffness_n_m3: float = Field(FOUNDATION_STIFFNESS_N_M3, gt=0.0, le=1e13)


class ProximitySpec(_Model):
    range_mm: float = Field(PROXIMITY_RANGE_MM, gt=0.0, le=500.0)


class FlatSpec(_Model):
    shape: Literal["flat"] = "flat"
    top_mm: float = 0.0

    def to_terrain(self):
        from .terrain import Flat

        return Flat(self.top_mm * 1e-3)


class BoxSpec(_Model):
    shape: Literal["box"] = "box"
    center_mm: tuple[float, float]
    size_mm: tuple[Annotated[float, Field(gt=0.0)], Annotated[float, Field(gt=0.0)]]
    top_mm: float
    yaw_deg: float = Field(0.0, ge=-180.0, le=180.0)

    def to_terrain(self):
        from .terrain import Box

        return Box(tuple(np.multiply(self.center_mm, 1e-3)), tuple(np.multiply(self.size_mm, 1e-3)), self.top_mm * 1e-3,
                   np.radians(self.yaw_deg))


class SphereSpec(_Model):
    shape: Literal["sphere"] = "sphere"
    center_mm: tuple[float, float, float]
    radius_mm: float = Field(gt=0.0)

    def to_terrain(self):
        from .terrain import Sphere

        return Sphere(tuple(np.multiply(self.center_mm, 1e-3)), self.radius_mm * 1e-3)


class StepSpec(_Model):
    shape: Literal["step"] = "step"
    point_mm: tuple[float, float]
    direction_deg: float = Field(0.0, ge=-180.0, le=180.0)  # the upper side's direction in the ground plane
    top_mm: float

    def to_terrain(self):
        from .terrain import Step

        return Step(tuple(np.multiply(self.point_mm, 1e-3)), np.radians(self.direction_deg), self.top_mm * 1e-3)


class HeightFieldSpec(_Model):
    shape: Literal["height_field"] = "height_field"
    origin_mm: tuple[float, float]
    spacing_mm: float = Field(gt=0.0)
    heights_mm: tuple[tuple[float, ...], ...]  # rows along y, columns along x

    @field_validator("heights_mm")
    @classmethod
    def _grid(cls, value):
        if len(value) < 2 or len({len(r) for r in value}) != 1 or len(value[0]) < 2:
            raise ValueError("give at least 2 rows of equal length >= 2")
        return value

    def to_terrain(self):
        from .terrain import HeightField

        return HeightField(tuple(np.multiply(self.origin_mm, 1e-3)), self.spacing_mm * 1e-3, np.asarray(self.heights_mm) * 1e-3)


Primitive = Annotated[Union[FlatSpec, BoxSpec, SphereSpec, StepSpec, HeightFieldSpec], Field(discriminator="shape")]


class TerrainSpec(_Model):
    """The terrain: the union of its primitives (:mod:`other_sensors.sole.terrain`); default a flat floor."""

    primitives: tuple[Primitive, ...] = (FlatSpec(),)

    def to_terrain(self) -> tuple:
        return tuple(p.to_terrain() for p in self.primitives)


class FootSpec(_Model):
    """The foot's pose: the sole frame's origin (under the ankle) at (x, y) in the world, its angles,
    and its height, given (``height_mm``) or found so that the terrain carries ``load_n``."""

    x_mm: float = 0.0
    y_mm: float = 0.0
    roll_deg: float = Field(0.0, ge=-30.0, le=30.0)
    pitch_deg: float = Field(0.0, ge=-30.0, le=30.0)
    yaw_deg: float = Field(0.0, ge=-180.0, le=180.0)
    load_n: float = Field(EARLY_CONTACT_LOAD_N, gt=0.0, le=1e5)
    height_mm: float | None = None  # None: from load_n; given: load_n is not used

    def pose(self, height_m: float = 0.0):
        from .contact import FootPose

        return FootPose((self.x_mm * 1e-3, self.y_mm * 1e-3, height_m), np.radians(self.roll_deg), np.radians(self.pitch_deg),
                        np.radians(self.yaw_deg))


class FeasibilitySpec(_Model):
    """The step-feasibility rules (:mod:`other_sensors.sole.feasibility`)."""

    eps_force_kg: float = Field(EPS_FORCE_KG, gt=0.0, le=100.0)
    eps_torque_nm: float = Field(EPS_TORQUE_NM, gt=0.0, le=1e4)
    eps_area: float = Field(EPS_AREA, gt=0.0, le=1.0)
    clearance_mm: float = Field(CLEARANCE_M * 1e3, ge=0.0, le=1000.0)


class BalanceSpec(_Model):
    """The CP-ZMP balance loop on the LIPM (:mod:`other_sensors.sole.balance`)."""

    mass_kg: float = Field(86.0, gt=0.0, le=1000.0)
    z_com_m: float = Field(0.8, gt=0.0, le=5.0)
    k_xi: float = Field(1.5, ge=0.0, le=100.0)
    k_f_per_s: float = Field(0.5, ge=0.0, le=100.0)  # the ZMP error's gain in the CoM velocity command (SPEC 4)
    k_x_per_s: float = Field(1.0, ge=0.0, le=100.0)  # the CoM position's gain (SPEC 4)
    rate_hz: float = Field(250.0, gt=0.0, le=10000.0)
    duration_s: float = Field(4.0, gt=0.0, le=60.0)
    # The push: a choice (SPEC 4 gives none): 80 N along x for 0.2 s at 0.5 s moves the ZMP ~7.5 cm,
    # inside the 10 cm of the reference experiment and short of the sole's edge.
    push_n: float = Field(80.0, ge=-5000.0, le=5000.0)
    push_start_s: float = Field(0.5, ge=0.0)
    push_duration_s: float = Field(0.2, gt=0.0, le=10.0)
    zmp_source: Literal["skin", "ft"] = "skin"


class BalanceSweepSpec(_Model):
    """The balance study (stage ``sole_balance_sweep``): :class:`BalanceSpec`'s run once per push
    magnitude, each reported as its peak ZMP excursion, skin-vs-F/T ZMP gap and whether the robot
    stood. The default magnitudes (a choice): from small pushes through the one that moves the ZMP
    10 cm (SPEC 4's reference, ~105 N for 0.2 s) to ones past the sole's edge that topple it."""

    push_n: tuple[Annotated[float, Field(ge=-5000.0, le=5000.0)], ...] = (20.0, 40.0, 60.0, 80.0, 100.0, 105.0, 150.0, 200.0,
                                                                            250.0, 300.0)

    @field_validator("push_n")
    @classmethod
    def _some(cls, value):
        if not value:
            raise ValueError("give one or more push magnitudes (N)")
        return value


class LandingSpec(_Model):
    """The swing foot's landing (:mod:`other_sensors.sole.landing`): when a scene gives this section,
    the foot lands on its terrain and the contact is read at impact, instead of the static placement
    under ``sensor.foot.load_n`` (which stays the weight share the landing leg takes over). The robot's
    mass and CoM height are ``sensor.balance``'s. SPEC 4 gives none of these values; each default's
    source is beside it, and none is fitted to a published figure."""

    # Landing mass: the swing leg's share of the body mass, thigh 0.100 + shank 0.0465 + foot 0.0145
    # (Winter, Biomechanics and Motor Control of Human Movement, 4th ed., 2009, table 4.1: human
    # segment fractions, taken for the humanoid's leg, a simplification): 13.8 kg of 86 kg.
    leg_mass_fraction: float = Field(0.161, gt=0.0, le=1.0)
    # The swing profile (a choice): a 50 mm foot clearance, descended in 0.25 s on a cosine, so the
    # planned touchdown is at rest and an obstacle 20 mm up is met at 0.31 m/s.
    swing_height_mm: float = Field(50.0, gt=0.0, le=1000.0)
    swing_descent_s: float = Field(0.25, gt=0.0, le=10.0)
    # The descent speed at first contact, when given, instead of the swing profile's (mm/s).
    speed_mm_s: float | None = Field(None, ge=0.0, le=1e4)
    # The periodic LIPM gait at touchdown (choices): 200 mm steps, feet 200 mm apart (as
    # scenes/sole/double_support.toml), 0.8 s of single support; the landing foot is the left one.
    step_length_mm: float = Field(200.0, ge=0.0, le=2000.0)
    step_width_mm: float = Field(200.0, ge=0.0, le=2000.0)
    single_support_s: float = Field(0.8, gt=0.0, le=10.0)
    side: Literal["left", "right"] = "left"
    # The ankle F/T's height over the sole (a choice of an adult-size humanoid's order, ~0.1 m).
    ankle_height_mm: float = Field(100.0, ge=0.0, le=1000.0)
    # The skin foam's Kelvin-Voigt time tau = c / k (a choice: 2 ms, a loss factor omega tau of 0.9
    # at the full sole's 460 rad/s impact, within open-cell foams' 0.1-1; 0 is the elastic layer).
    damping_time_ms: float = Field(2.0, ge=0.0, le=1000.0)
    # The early-contact window read at the skin's 250 Hz (SPEC 4: cells up to 250 Hz): 40 ms, ten
    # ticks, longer than the impact's compression (a quarter period: 3-15 ms on the sole's cells).
    window_ms: float = Field(40.0, gt=0.0, le=2000.0)
    rate_hz: float = Field(250.0, gt=0.0, le=10000.0)

    def params(self, load_n: float, stiffness_n_m3: float, balance, contact_height_m: float):
        """The :class:`other_sensors.sole.landing.LandingParams` of this landing for a first contact at
        ``contact_height_m`` above the planned ground (m)."""
        from .landing import LandingParams, swing_speed, touchdown_com

        speed = (self.speed_mm_s * 1e-3 if self.speed_mm_s is not None
                 else swing_speed(contact_height_m, self.swing_height_mm * 1e-3, self.swing_descent_s))
        com, vel = touchdown_com(self.step_length_mm * 1e-3, self.step_width_mm * 1e-3, self.single_support_s, balance.z_com_m, self.side)
        return LandingParams(mass_kg=self.leg_mass_fraction * balance.mass_kg, speed_m_s=speed, load_n=load_n,
                             stiffness_n_m3=stiffness_n_m3, damping_s=self.damping_time_ms * 1e-3, com_m=tuple(com),
                             com_velocity_m_s=tuple(vel), z_com_m=balance.z_com_m, ankle_height_m=self.ankle_height_mm * 1e-3,
                             rate_hz=self.rate_hz, window_s=self.window_ms * 1e-3)


class ObstacleSpec(_Model):
    """One case of the obstacle table (stage ``sole_obstacle_table``): a terrain and the foot's pose
    on it; the cells, foundation, proximity and rules are the scene's."""

    name: str = Field(pattern=r"^[a-z0-9_]{1,40}$")  # names the case's plot file
    description: str = ""
    terrain: TerrainSpec
    foot: FootSpec = FootSpec()


class SoleSensor(_Model):
    """A humanoid's sole covered by hexagonal skin cells (SPEC 4).

    ``foot`` is the (swing or single-support) foot; ``second_foot``, when given, the other foot on
    the same terrain, for double support (stage ``sole_double_support``, both soles' polygon in the
    world); ``obstacles``, when given, the cases of the obstacle table (stage ``sole_obstacle_table``).
    """

    kind: Literal["plantar_sole"] = "plantar_sole"
    cells: CellsSpec = CellsSpec()
    foundation: FoundationSpec = FoundationSpec()
    proximity: ProximitySpec = ProximitySpec()
    terrain: TerrainSpec = TerrainSpec()
    foot: FootSpec = FootSpec()
    feasibility: FeasibilitySpec = FeasibilitySpec()
    balance: BalanceSpec = BalanceSpec()
    balance_sweep: BalanceSweepSpec = BalanceSweepSpec()
    second_foot: FootSpec | None = None
    obstacles: tuple[ObstacleSpec, ...] = ()
    landing: LandingSpec | None = None  # given: the foot lands (other_sensors.sole.landing); None: static placement

    @field_validator("obstacles")
    @classmethod
    def _unique_names(cls, value):
        names = [o.name for o in value]
        if len(set(names)) != len(names):
            raise ValueError(f"obstacle names {names} repeat; give each case its own name")
        return value
