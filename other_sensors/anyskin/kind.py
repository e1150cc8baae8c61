"""The AnySkin helmet as a sensor kind (``sensor.kind = "anyskin"``): its schema, checks and stages."""

from __future__ import annotations

from mlsim.stage import register_kind

from .plausibility import stage_cost, warnings
from .schema import MAX_ANGULAR_RATE_DEG_S, AnySkinSensor
from .stages import BENCH, CONTACT, DRIFT, PITCH, SIGNALS

__all__ = ["AnySkinSensor", "KIND"]


def _check(scene) -> list:
    """Cross-field rules the schema's per-field ranges cannot state."""
    from .helmet import peak_angular_rate_deg_s

    s, problems = scene.sensor, []
    tr = s.trajectory
    rate = peak_angular_rate_deg_s(tr.gait_hz, [tr.roll_amp_deg, tr.pitch_amp_deg, tr.yaw_amp_deg])
    if rate > MAX_ANGULAR_RATE_DEG_S:
        problems.append(("sensor.trajectory.gait_hz", tr.gait_hz,
                         f"with these amplitudes the head turns at up to {rate:.0f} deg/s, over SPEC 2's "
                         f"{MAX_ANGULAR_RATE_DEG_S:.0f}; lower gait_hz or the *_amp_deg"))
    if s.magnetometers.pitch_mm >= s.skin.side_mm / 2:
        problems.append(("sensor.magnetometers.pitch_mm", s.magnetometers.pitch_mm,
                         f"the outer chips must lie under the skin: make it < sensor.skin.side_mm / 2 = {s.skin.side_mm / 2:g}"))
    from .estimate import BENCH_FORCE_MODEL, model_path

    for name in ("contact_model", "force_model"):
        path = getattr(s.estimator, name)
        if path is not None and not (name == "force_model" and path == BENCH_FORCE_MODEL) and not model_path(path).is_file():
            problems.append((f"sensor.estimator.{name}", path, "no such file; train both with 'mlsim anyskin-train SCENE --out DIR'"))
    if (s.estimator.contact_model is None) != (s.estimator.force_model is None):
        problems.append(("sensor.estimator.force_model" if s.estimator.force_model is None else "sensor.estimator.contact_model", None,
                         "give both trained files (mlsim anyskin-train writes both) or neither (the stand-ins)"
                         + ("; force_model = \"bench\" needs the causal CNN's file" if s.estimator.force_model == BENCH_FORCE_MODEL
                            else "")))
    if s.skin.truth == "magnet_volume":
        from .truth import worst_stretch

        heaviest = s.push.peak_n * (1 + s.push.jitter)  # the whole push on one pad, the set at its ceiling
        stretch = worst_stretch(s, heaviest)
        if stretch <= 0:
            problems.append(("sensor.drift.set_fraction", s.drift.set_fraction,
                             f"a {heaviest:.0f} N push compresses the skin and its set through its whole thickness (stretch "
                             f"{stretch:.3g} <= 0: the magnet volume inverts); lower it or sensor.push.peak_n, or raise "
                             "sensor.skin.modulus_kpa or contact_radius_mm"))
    if tr.duration_s * s.magnetometers.rate_hz < 2:
        problems.append(("sensor.trajectory.duration_s", tr.duration_s, "give at least two samples"))
    if not problems:  # a consistent scene whose push or size no helmet or machine allows (issue 39)
        from .plausibility import problems as implausible

        problems = implausible(scene)
    return problems


KIND = register_kind("anyskin", AnySkinSensor, [SIGNALS, CONTACT, DRIFT, PITCH, BENCH], check=_check, warnings=warnings, cost=stage_cost)
"""The Head-On helmet of SPEC 2: four AnySkin magnetic skins in an X on a quadruped's pitched helmet face,
pushed against a force plate while walking; ``other_sensors.anyskin.kind`` registers the ``anyskin`` kind."""
