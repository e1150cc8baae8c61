"""The plantar sole as a sensor kind (``sensor.kind = "plantar_sole"``): its schema and its stages."""

from __future__ import annotations

from mlsim.stage import register_kind

from .schema import SoleSensor
from .stages import BALANCE, CONTACT, FEASIBILITY

__all__ = ["SoleSensor", "KIND"]

KIND = register_kind("plantar_sole", SoleSensor, [CONTACT, FEASIBILITY, BALANCE])
