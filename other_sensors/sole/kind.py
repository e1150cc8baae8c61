"""The plantar sole as a sensor kind (``sensor.kind = "plantar_sole"``): its schema and its stages."""

from __future__ import annotations

from mlsim.stage import register_kind

from .plausibility import stage_cost, warnings
from .schema import SoleSensor
from .stages import BALANCE, BALANCE_SWEEP, CONTACT, DOUBLE_SUPPORT, FEASIBILITY, OBSTACLE_TABLE, check

__all__ = ["SoleSensor", "KIND"]

KIND = register_kind("plantar_sole", SoleSensor, [CONTACT, FEASIBILITY, OBSTACLE_TABLE, DOUBLE_SUPPORT, BALANCE, BALANCE_SWEEP],
                     check=check, warnings=warnings, cost=stage_cost)
