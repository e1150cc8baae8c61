"""The ``[sensor]`` section of an AnySkin helmet scene (``sensor.kind = "anyskin"``), validated at the door.

Scene lengths are in mm, angles in degrees, fields in microtesla (units in the names); the
stages convert to SI for the physics.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from mlsim.scene import SpecModel

__all__ = ["AnySkinSensor", "SkinSpec", "MagnetometersSpec", "HelmetSpec", "TrajectorySpec", "PushSpec", "AmbientFieldsSpec",
           "DriftSpec", "NoiseSpec", "EstimatorSpec", "RATE_HZ", "MAX_ANGULAR_RATE_DEG_S"]

RATE_HZ = 150.0  # SPEC 2: streamed at 150 Hz
MAX_ANGULAR_RATE_DEG_S = 180.0  # SPEC 2: angular rates up to 180 deg/s while walking

# --- documented defaults (the SPEC does not give them) -------------------------------------------
# Skin: a choice near the AnySkin paper's skins: a ~30 mm square, 2.5 mm thick silicone with magnetic
# powder, its base 1 mm over the magnetometer chips. Magnetisation 20 kA/m (Br ~ 25 mT, a lightly
# loaded magnetic elastomer) puts the rest field at the chips at hundreds of uT, well inside an
# MLX90393's range. Grid 14: 2 mm between lumped dipoles, under the 2.25 mm to the chips.
SKIN_SIDE_MM, SKIN_THICKNESS_MM, SKIN_GAP_MM, SKIN_GRID, MAGNETISATION_KA_M = 28.0, 2.5, 1.0, 14, 20.0
# Elastomer: E = 0.5 MPa (a shore 20A silicone); strain saturates at 0.6; the contact patch 8 mm (Gaussian
# radius), the pad's footprint on a domed helmet cover, so that 100 N strains the skin ~0.4.
MODULUS_KPA, MAX_STRAIN, CONTACT_RADIUS_MM = 500.0, 0.6, 8.0
# Magnetometer cross: 9 mm from the centre chip, inside the skin's 14 mm half-side.
MAGNETOMETER_PITCH_MM = 9.0
# Readout (other_sensors/anyskin/magnetometer.py): an MLX90393 at GAIN_SEL 7, RES 0: 0.150 uT per LSB on x, y
# and 0.242 on z (its datasheet's sensitivities, rev. 006); 1.5 uT rms on x, y at the 150 Hz rate (a choice) and
# z 1.5 x 0.242 / 0.150 = 2.42 uT (the same noise in LSB). Per chip: offsets 10 uT rms, gain errors 2 % rms and
# cross-axis terms 1 % rms (choices: typical Hall-sensor magnitudes, not fitted to any published error).
NOISE_UT, LSB_UT, LSB_Z_UT = 1.5, 0.150, 0.242
NOISE_Z_UT = NOISE_UT * LSB_Z_UT / LSB_UT
OFFSET_UT, GAIN_ERROR_PCT, CROSS_AXIS_PCT = 10.0, 2.0, 1.0
# Earth's field in the world frame (x north, z up): 48 uT at 66 deg inclination (central Europe).
GEOMAGNETIC_UT = (19.5, 0.0, -43.9)
# Motor stray field at the skins: 5 uT peak, a choice (motors ~20 cm away behind the neck).
MOTOR_UT = 5.0
# Skin set: 25 % of the elastic deformation, reached in 10 s of load, lost in 120 s at rest: a choice
# giving a set that builds over a handful of 2.5 s push cycles and does not recover between them.
SET_FRACTION, TAU_SET_S, TAU_RELAX_S = 0.25, 10.0, 120.0
# Helmet: the X's half-width 40 mm and half-height 30 mm, the face 150 mm ahead of the head's centre,
# pitched 15 deg (SPEC 2's candidates 0 .. 30 deg); each pad, skin on the helmet's foam backing, a 5 N/mm
# spring against the plate, so that a 150 N push (~30 mm of travel) reaches pads a few mm behind the first.
FACE_PITCH_DEG, HALF_WIDTH_MM, HALF_HEIGHT_MM, FACE_FORWARD_MM, PAD_STIFFNESS_N_MM = 15.0, 40.0, 30.0, 150.0, 5.0
# Gait: a 2 Hz trot with roll/pitch/yaw amplitudes 6, 8, 6 deg: peak rate <= 146 deg/s (under 180).
GAIT_HZ, ROLL_DEG, PITCH_DEG, YAW_DEG = 2.0, 6.0, 8.0, 6.0
# Pushes: 150 N peaks (so that some sensors pass SPEC 2's 50 N), 1.5 s on, 1.0 s off, +-20 % per push.
PUSH_PEAK_N, PUSH_S, REST_S, FIRST_PUSH_S, PUSH_JITTER = 150.0, 1.5, 1.0, 1.0, 0.2


_Model = SpecModel  # unknown keys refused, frozen, NaN and Inf refused (the scene's own rule)


class SkinSpec(_Model):
    """The magnetised elastomer. ``truth`` picks the model that generates the chips' field
    (:mod:`other_sensors.anyskin.truth`): ``"magnet_volume"`` (default), the skin as a finite magnetised
    volume (grid x grid columns, each moment following the deformation) over a thin incompressible
    neo-Hookean layer (:mod:`other_sensors.anyskin.skin_volume`); ``"point_dipole"``, grid x grid point
    dipoles over a saturating linear layer (:mod:`other_sensors.anyskin.skin`), the estimator's first
    world, kept to compare. max_strain applies to ``"point_dipole"`` only."""

    truth: Literal["magnet_volume", "point_dipole"] = "magnet_volume"
    side_mm: float = Field(SKIN_SIDE_MM, gt=0.0, le=200.0)
    thickness_mm: float = Field(SKIN_THICKNESS_MM, gt=0.0, le=20.0)
    gap_mm: float = Field(SKIN_GAP_MM, gt=0.0, le=20.0)
    grid: int = Field(SKIN_GRID, ge=1, le=60)
    magnetisation_ka_m: float = Field(MAGNETISATION_KA_M, ge=0.0, le=2000.0)
    modulus_kpa: float = Field(MODULUS_KPA, gt=0.0, le=1e6)
    max_strain: float = Field(MAX_STRAIN, gt=0.0, le=0.95)
    contact_radius_mm: float = Field(CONTACT_RADIUS_MM, gt=0.0, le=100.0)


class MagnetometersSpec(_Model):
    """The five three-axis chips in a cross under each skin."""

    pitch_mm: float = Field(MAGNETOMETER_PITCH_MM, gt=0.0, le=100.0)
    rate_hz: float = Field(RATE_HZ, gt=0.0, le=10000.0)


class HelmetSpec(_Model):
    """The X layout on the pitched face (:mod:`other_sensors.anyskin.helmet`)."""

    face_pitch_deg: float = Field(FACE_PITCH_DEG, ge=-45.0, le=45.0)
    half_width_mm: float = Field(HALF_WIDTH_MM, gt=0.0, le=500.0)
    half_height_mm: float = Field(HALF_HEIGHT_MM, gt=0.0, le=500.0)
    face_forward_mm: float = Field(FACE_FORWARD_MM, gt=0.0, le=2000.0)
    pad_stiffness_n_mm: float = Field(PAD_STIFFNESS_N_MM, gt=0.0, le=1e5)


class TrajectorySpec(_Model):
    """The walking head: sinusoidal roll, pitch, yaw at the gait frequency, seeded phases."""

    duration_s: float = Field(12.0, gt=0.0, le=600.0)
    gait_hz: float = Field(GAIT_HZ, ge=0.0, le=10.0)
    roll_amp_deg: float = Field(ROLL_DEG, ge=0.0, le=45.0)
    pitch_amp_deg: float = Field(PITCH_DEG, ge=0.0, le=45.0)
    yaw_amp_deg: float = Field(YAW_DEG, ge=0.0, le=45.0)


class PushSpec(_Model):
    """Fore-aft pushes of the head against the force plate."""

    peak_n: float = Field(PUSH_PEAK_N, ge=0.0, le=5000.0)
    push_s: float = Field(PUSH_S, gt=0.0, le=60.0)
    rest_s: float = Field(REST_S, ge=0.0, le=60.0)
    first_s: float = Field(FIRST_PUSH_S, ge=0.0)
    jitter: float = Field(PUSH_JITTER, ge=0.0, lt=1.0)


class AmbientFieldsSpec(_Model):
    """Fields besides the skin's: the Earth's (world frame, x north, z up) and the motors'."""

    geomagnetic_ut: tuple[float, float, float] = GEOMAGNETIC_UT
    motor_ut: float = Field(MOTOR_UT, ge=0.0, le=1e4)


class DriftSpec(_Model):
    """The skin's permanent set (:func:`other_sensors.anyskin.skin.permanent_set`)."""

    enabled: bool = True
    set_fraction: float = Field(SET_FRACTION, ge=0.0, le=1.0)
    tau_set_s: float = Field(TAU_SET_S, gt=0.0, le=1e5)
    tau_relax_s: float = Field(TAU_RELAX_S, gt=0.0, le=1e6)


class NoiseSpec(_Model):
    """The chips' read-out (:mod:`other_sensors.anyskin.magnetometer`): white noise rms on x, y (``rms_ut``)
    and z (``rms_z_ut``), uT; quantisation steps (0: none), uT per LSB; each chip's offset (rms, uT), gain
    error and cross-axis sensitivity (rms, %), drawn once per chip from the seed."""

    rms_ut: float = Field(NOISE_UT, ge=0.0, le=1e4)
    rms_z_ut: float = Field(NOISE_Z_UT, ge=0.0, le=1e4)
    lsb_ut: float = Field(LSB_UT, ge=0.0, le=1e3)
    lsb_z_ut: float = Field(LSB_Z_UT, ge=0.0, le=1e3)
    offset_ut: float = Field(OFFSET_UT, ge=0.0, le=1e5)
    gain_error_pct: float = Field(GAIN_ERROR_PCT, ge=0.0, le=50.0)
    cross_axis_pct: float = Field(CROSS_AXIS_PCT, ge=0.0, le=50.0)


class EstimatorSpec(_Model):
    """SPEC 2's causal contact pipeline (:mod:`other_sensors.anyskin.contact_state`): the causal CNN and
    the LSTM-MLP force map when ``contact_model`` and ``force_model`` name their files (written by
    ``mlsim anyskin-train``; a relative path is tried from the working directory, then from the
    project's root), else the stand-ins (a slope-threshold detector with ``onset_slope_ut_s`` and
    ``release_slope_ut_s``, and a quadratic map fitted on a calibration run)."""

    median_samples: int = Field(5, ge=1, le=101)  # a choice: odd, ~33 ms at 150 Hz, removes single-sample spikes
    lowpass_hz: float = Field(10.0, gt=0.0, le=75.0)  # a choice: pushes last ~1 s; keeps 10 Hz, cuts noise
    window_samples: int = Field(50, ge=3, le=1000)  # SPEC 2: L = 50
    onset_slope_ut_s: float = Field(60.0, gt=0.0)  # a choice, see contact_state.py
    release_slope_ut_s: float = Field(60.0, gt=0.0)
    calibration_s: float = Field(1.0, gt=0.0, le=60.0)  # the initial baseline: the mean of the first samples
    contact_model: str | None = None  # the causal CNN's file (mlsim anyskin-train: anyskin_contact_cnn.pt)
    force_model: str | None = None  # the LSTM-MLP's file (mlsim anyskin-train: anyskin_force_lstm.pt), or "bench": trained
    # on the simulated calibration bench at run time (other_sensors/anyskin/bench.py, seeded by the scene's seed)


class AnySkinSensor(_Model):
    """Four AnySkin magnetic skins on a quadruped's helmet face (SPEC 2)."""

    kind: Literal["anyskin"] = "anyskin"
    skin: SkinSpec = SkinSpec()
    magnetometers: MagnetometersSpec = MagnetometersSpec()
    helmet: HelmetSpec = HelmetSpec()
    trajectory: TrajectorySpec = TrajectorySpec()
    push: PushSpec = PushSpec()
    ambient: AmbientFieldsSpec = AmbientFieldsSpec()
    drift: DriftSpec = DriftSpec()
    noise: NoiseSpec = NoiseSpec()
    estimator: EstimatorSpec = EstimatorSpec()
