"""The ``cls`` sensor kind (SPEC 3, issue 20): its [sensor] schema and its stages, registered on import
(``mlsim.stage.BUILTIN_KINDS`` maps "cls" to this module)."""

from __future__ import annotations

from mlsim.stage import register_kind
from other_sensors.cls.plausibility import stage_cost, warnings
from other_sensors.cls.schema import ClsSensor, check
from other_sensors.cls.stages import CALIBRATE, ESTIMATE, SIGNALS

KIND = register_kind("cls", ClsSensor, [SIGNALS, CALIBRATE, ESTIMATE], check=check, warnings=warnings, cost=stage_cost)
