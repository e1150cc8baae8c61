"""The ``[sensor]`` section of a CLS scene (``sensor.kind = "cls"``): pairs, foam, trajectory, noise, estimator.

Defaults are SPEC 3's values where it gives them and the documented choices of :mod:`ltv`,
:mod:`shell` and :mod:`estimator` where it does not.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field

from mlsim.scene import SpecModel

from other_sensors.cls import ltv, shell

__all__ = ["ClsSensor", "PairsSpec", "FoamSpec", "TrajectorySpec", "NoiseSpec", "CalibrationSpec", "EstimatorSpec", "OpticsSpec",
           "check"]


_Model = SpecModel  # unknown keys refused, frozen, NaN and Inf refused (the scene's own rule)


class PairsSpec(_Model):
    """The line of LED / LTV pairs along y; every pair has the same seven coefficients."""

    n: int = Field(5, ge=3, le=16)
    pitch_mm: float = Field(ltv.PAIR_PITCH_MM, gt=0, le=200)
    stagger_mm: float = Field(ltv.LED_STAGGER_MM, ge=0, le=50)
    gap_mm: float = Field(ltv.REST_GAP_MM, gt=15, lt=60)
    # the nominal (datasheet) coefficients c1..c7 (V mm^2, mm, mm^2, -, -, -, V), the same for every pair
    coefficients: tuple[float, float, float, float, float, float, float] = tuple(float(c) for c in ltv.DEFAULT_COEFFS)
    # part-to-part spread: each pair's true coefficients are the nominal ones times (1 + spread N(0, 1))
    # (c2, nominally 0, gets spread x 20 mm), drawn from the scene's seed. A choice: 3 % is a typical
    # LED intensity / LTV responsivity tolerance after binning; it makes the nominal model mm-wrong.
    coefficient_spread: float = Field(0.03, ge=0, le=0.5)
    # mounting spread: each LED's and LTV's true position is off its design by N(0, position_spread_mm)
    # per axis and its axis tilted by N(0, tilt_spread_deg) per tangent direction (scene seed, stream
    # 5). A choice: hand-placed parts on a 3D-printed shell sit to a few tenths of a mm and a degree.
    position_spread_mm: float = Field(0.3, ge=0, le=5)
    tilt_spread_deg: float = Field(1.0, ge=0, le=20)


class FoamSpec(_Model):
    """The three foam pillars (SPEC 3: 1.5 in tall, 1.5 in^2 section) and their stiffening law."""

    height_mm: float = Field(shell.PILLAR_HEIGHT_MM, gt=0, le=200)
    section_mm2: float = Field(shell.PILLAR_SECTION_MM2, gt=0)
    young_kpa: float = Field(shell.FOAM_E0_KPA, gt=0)
    stiffening_strain: float = Field(shell.FOAM_STIFFENING_STRAIN, gt=0)
    pillar_y_mm: tuple[float, float, float] = shell.PILLAR_Y_MM
    # The foam's viscoelastic arm (other_sensors.cls.foam_viscoelastic): a Maxwell arm's modulus and
    # relaxation time beside the elastic law. 0 kPa: elastic (the estimator's law is the truth). The
    # shipped scenes take 15 kPa (half of E0) and 0.2 s, a choice whose small-strain loss factor peaks
    # at 0.20 near 0.65 Hz, inside polyurethane foams' 0.1-0.5 (Mills 2007)
    maxwell_kpa: float = Field(0.0, ge=0, le=1e4)
    relaxation_s: float = Field(0.2, gt=0, le=1e3)


class TrajectorySpec(_Model):
    """The shell's motion: ``rest_s`` of rest, then ``shape``; voltages at ``rate_hz``, reference poses at ``reference_rate_hz``."""

    shape: Literal["rest", "compression", "shear", "rotation", "general"] = "general"
    duration_s: float = Field(2.0, gt=0, le=600)
    rest_s: float = Field(0.25, gt=0)
    rate_hz: float = Field(2000.0, gt=0, le=100_000)
    reference_rate_hz: float = Field(80.0, gt=0)
    compression_mm: float = Field(10.0, ge=0)
    shear_mm: float = Field(6.0, ge=0)
    rotation_deg: float = Field(6.0, ge=0, le=30)
    frequency_hz: float = Field(0.5, gt=0)


class NoiseSpec(_Model):
    """White Gaussian noise per sample and pair, then the ADC's quantisation and rails."""

    rms_mv: float = Field(0.7, ge=0)
    adc_bits: int = Field(shell.ADC_BITS, ge=8, le=24)
    adc_range_v: float = Field(shell.ADC_RANGE_V, gt=0)


class CalibrationSpec(_Model):
    """Batch calibration (SPEC 3): a general-motion trajectory of measured poses (``duration_s`` at the
    reference rate ``rate_hz``, the trajectory section's amplitudes), then LM over each pair's
    coefficients and its LED's and LTV's mounting poses."""

    duration_s: float = Field(37.0, gt=0, le=3600)
    rate_hz: float = Field(80.0, gt=0, le=100_000)
    tau: float = Field(1.0 / 40.0, gt=0)
    theta_max_deg: float = Field(40.0, gt=0, lt=90)
    r_min_mm: float = Field(20.0, gt=0)
    v_max_v: float = Field(4.5, gt=0)
    # SPEC 3 calibrates the sensor/LED poses too; off: the coefficients only, at the designed poses
    fit_mounting: bool = True
    # The motion capture's own noise on the calibration's measured poses (white, per axis; stream 6 of
    # the seed). 0: exact reference poses. The shipped scenes take 0.15 mm and 0.1 deg, the order of an
    # optical motion-capture system's static error (Merriaux et al., "A study of Vicon system
    # positioning performance", Sensors 17, 2017: under 0.2 mm static).
    mocap_noise_mm: float = Field(0.0, ge=0, le=10)
    mocap_noise_deg: float = Field(0.0, ge=0, le=10)


class EstimatorSpec(_Model):
    """The LM estimator and the motion detector (SPEC 3 values); ``coefficients``: which pairs' model
    the estimator uses: the batch-calibrated coefficients and mounting poses (default), the nominal
    (as designed) ones, or the true ones (an oracle, for separating the calibration's error from the
    estimator's)."""

    coefficients: Literal["calibrated", "nominal", "true"] = "calibrated"

    tau: float = Field(1.0 / 70.0, gt=0)
    tolerance: float = Field(1e-4, gt=0)
    max_iterations: int = Field(50, ge=1, le=10_000)
    r_min_mm: float = Field(15.0, gt=0)
    r_max_mm: float = Field(60.0, gt=0)
    theta_max_deg: float = Field(45.0, gt=0, lt=90)
    lambda0: float = Field(1e-5, gt=0)  # see estimator.LmSettings
    motion_threshold_mv: float = Field(5.0, gt=0)


class OpticsSpec(_Model):
    """The optical truth (:mod:`other_sensors.cls.optics`): when given, the pairs' voltages come from
    the LED's beam, the LTV's acceptance and the cavity's diffuse light instead of the estimator's
    seven-coefficient law. SPEC 3 gives none of these; each default's source is beside it."""

    # A 5 mm IR LED's half-intensity angle: +-30 deg (a common datasheet class, e.g. the wide-angle
    # 940 nm parts; a choice, not the nominal law's c4)
    half_angle_deg: float = Field(30.0, gt=0, lt=90)
    # Diffuse reflectances at the LED's near infrared (choices): a green solder-mask base 0.1, a grey
    # 3D-printed shell's inner surface 0.3. The foam pillars are not walls of the optical cavity (the
    # layout puts them on the pairs' line: other_sensors/cls/cavity_radiosity.py), so no foam reflectance
    rho_base: float = Field(0.1, ge=0, lt=1)
    rho_shell: float = Field(0.3, ge=0, lt=1)
    # The cavity's footprint, the base's and the shell's (a choice: the 130 mm the pillars span along y, 50 mm across)
    length_mm: float = Field(130.0, gt=0, le=2000)
    width_mm: float = Field(50.0, gt=0, le=2000)
    # The LTV's dark output (a choice of a light-to-voltage converter's few millivolts)
    dark_mv: float = Field(5.0, ge=0, le=1000)

    def optics(self):
        from other_sensors.cls.optics import Optics

        return Optics(self.half_angle_deg, self.rho_base, self.rho_shell, (self.length_mm, self.width_mm), self.dark_mv * 1e-3)


class ClsSensor(_Model):
    """The compliant limb sensor of SPEC 3 (planar prototype: y, z, rx)."""

    kind: Literal["cls"] = "cls"
    pairs: PairsSpec = PairsSpec()
    foam: FoamSpec = FoamSpec()
    trajectory: TrajectorySpec = TrajectorySpec()
    noise: NoiseSpec = NoiseSpec()
    calibration: CalibrationSpec = CalibrationSpec()
    estimator: EstimatorSpec = EstimatorSpec()
    optics: OpticsSpec | None = None  # given: the optical truth (other_sensors.cls.optics); None: the law is the truth


def check(scene) -> list:
    """Consistency beyond the schema: [(dotted field, value, what is valid)]."""
    s = scene.sensor
    problems = []
    tr, est = s.trajectory, s.estimator
    if tr.rest_s >= tr.duration_s:
        problems.append(("sensor.trajectory.rest_s", tr.rest_s, f"must be < sensor.trajectory.duration_s = {tr.duration_s}"))
    if tr.rest_s * tr.rate_hz < 1:
        problems.append(("sensor.trajectory.rest_s", tr.rest_s, "must hold at least one sample at sensor.trajectory.rate_hz"))
    if tr.reference_rate_hz > tr.rate_hz:
        problems.append(("sensor.trajectory.reference_rate_hz", tr.reference_rate_hz, f"must be <= sensor.trajectory.rate_hz = {tr.rate_hz}"))
    if est.r_min_mm >= est.r_max_mm:
        problems.append(("sensor.estimator.r_min_mm", est.r_min_mm, f"must be < sensor.estimator.r_max_mm = {est.r_max_mm}"))
    if tr.compression_mm >= s.pairs.gap_mm - est.r_min_mm:
        problems.append(("sensor.trajectory.compression_mm", tr.compression_mm,
                         f"must be < sensor.pairs.gap_mm - sensor.estimator.r_min_mm = {s.pairs.gap_mm - est.r_min_mm:g}"))
    if s.calibration.v_max_v > s.noise.adc_range_v:
        problems.append(("sensor.calibration.v_max_v", s.calibration.v_max_v, f"must be <= sensor.noise.adc_range_v = {s.noise.adc_range_v}"))
    if tr.compression_mm >= s.foam.height_mm:
        problems.append(("sensor.trajectory.compression_mm", tr.compression_mm, f"must be < sensor.foam.height_mm = {s.foam.height_mm}"))
    if not problems:  # a consistent scene whose motion or size no shell or machine allows (issue 39)
        from other_sensors.cls.plausibility import problems as implausible

        problems = implausible(scene)
    return problems
