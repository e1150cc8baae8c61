"""Step feasibility on early contact: the ankle F/T rule and the skin rule (SPEC 4).

When the swing foot touches down early (on an obstacle), the step is re-planned if
- ankle F/T rule: the horizontal ankle moment M_s >= eps_t (8 N m), or
- skin rule: A_p / A_s <= eps_A (0.8), A_p the support polygon's area at impact, A_s the sole's
  (the hull of all its cells' corners, :meth:`other_sensors.sole.cells.SoleLayout.sole_area`).
A re-plan sidesteps by the obstacle's width (the support polygon's bounding box across the sole)
plus a clearance. The F/T rule misses an obstacle under the ankle (a small moment arm); the skin
rule sees the small polygon wherever the obstacle is.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import estimators as est

__all__ = ["EPS_TORQUE_NM", "EPS_AREA", "EPS_FORCE_KG", "CLEARANCE_M", "AREA_TIE_RTOL", "ft_rule", "skin_rule", "StepAssessment", "assess_step"]

EPS_TORQUE_NM = 8.0  # SPEC 4
EPS_AREA = 0.8  # SPEC 4
EPS_FORCE_KG = 0.15  # SPEC 4: a cell is active above 0.15 kg
# Clearance added to the obstacle's width in a sidestep. A choice (not given): 3 cm, about the
# placement error of a position-controlled humanoid's footstep plus a margin.
CLEARANCE_M = 0.03
# A_p / A_s of a honeycomb is often exactly a simple fraction (0.8 with 20 cells' hull on the default
# sole): such a tie is SPEC 4's "<=" (re-plan) whatever the round-off of the areas' sums, so the
# rule compares with this relative slack (far under one cell's share of the sole, ~2e-2).
AREA_TIE_RTOL = 1e-9


def ft_rule(ankle_moment_nm: float, eps_torque_nm: float = EPS_TORQUE_NM) -> bool:
    """True (re-plan) when the ankle moment M_s (N m) reaches eps_t."""
    return bool(ankle_moment_nm >= eps_torque_nm)


def skin_rule(polygon_area_m2: float, sole_area_m2: float, eps_area: float = EPS_AREA) -> bool:
    """True (re-plan) when A_p / A_s <= eps_A (SPEC 4), a tie within round-off included (:data:`AREA_TIE_RTOL`)."""
    if not sole_area_m2 > 0:
        raise ValueError(f"sole area = {sole_area_m2}: must be > 0")
    return bool(polygon_area_m2 / sole_area_m2 <= eps_area * (1.0 + AREA_TIE_RTOL))


@dataclass(frozen=True)
class StepAssessment:
    """Both rules on one sole's contact at impact (sole frame, SI units)."""

    cop: np.ndarray  # (2,) m, skin (force sensors)
    cop_cells: np.ndarray  # (2,) m, skin (cell centres, SPEC 4's formula)
    cop_ft: np.ndarray  # (2,) m, from the ankle wrench: (-My / Fz, Mx / Fz)
    active: np.ndarray  # (N,) bool
    contact_area: float  # m^2
    polygon: np.ndarray  # (K, 2) m
    pretouch: np.ndarray  # (K', 2) m
    polygon_area: float  # A_p m^2
    sole_area: float  # A_s m^2
    ankle_moment: float  # M_s N m
    ft_replan: bool
    skin_replan: bool
    sidestep_ft: float  # m, 0 when the F/T rule keeps the step
    sidestep_skin: float  # m, 0 when the skin rule keeps the step

    @property
    def area_ratio(self) -> float:
        return self.polygon_area / self.sole_area


def assess_step(layout, contact, eps_force_n: float = EPS_FORCE_KG * est.G, eps_torque_nm: float = EPS_TORQUE_NM,
                eps_area: float = EPS_AREA, clearance_m: float = CLEARANCE_M, proximity_range_m: float = 0.03) -> StepAssessment:
    """Both rules on ``contact`` (:class:`other_sensors.sole.contact.SoleContact`) of ``layout``'s sole."""
    active = est.active_cells(contact.cell_forces, eps_force_n)
    polygon = est.support_polygon(layout.corners, active)
    a_p, a_s = est.polygon_area(polygon), layout.sole_area()
    fz, mx, my = contact.wrench[2], contact.wrench[3], contact.wrench[4]
    cop_ft = np.array([-my / fz, mx / fz]) if fz > 0 else np.full(2, np.nan)
    ft, skin = ft_rule(contact.ankle_moment, eps_torque_nm), skin_rule(a_p, a_s, eps_area)
    step = est.sidestep(polygon, clearance_m)
    return StepAssessment(
        cop=est.sole_cop(layout, contact.sensor_forces, "sensor"), cop_cells=est.sole_cop(layout, contact.sensor_forces, "cell"),
        cop_ft=cop_ft, active=active, contact_area=est.contact_area(active, layout.cell_area), polygon=polygon,
        pretouch=est.pretouch_polygon(layout.corners, contact.gaps, proximity_range_m), polygon_area=a_p, sole_area=a_s,
        ankle_moment=contact.ankle_moment, ft_replan=ft, skin_replan=skin,
        sidestep_ft=step if ft else 0.0, sidestep_skin=step if skin else 0.0)
