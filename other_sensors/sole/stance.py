"""Double support: both soles on the terrain, their support polygon and centre of pressure in the world (SPEC 4).

SPEC 4: "for double support transform both soles' points to the world and take one hull". Each
sole is read as in single support (:func:`other_sensors.sole.contact.sole_contact`, each foot
lowered until the terrain carries its own load) and assessed by
:func:`other_sensors.sole.feasibility.assess_step`; the double-support polygon is the hull of both
soles' active hexagon corners in the world's ground plane
(:func:`other_sensors.sole.estimators.double_support_polygon`), and the combined CoP is each sole's
CoP in the world weighted by its normal force, from the skin (force sensors) and from the two
ankle F/T sensors. The same model's limits apply (no friction, no load sharing between the feet
beyond the loads given: a choice of the scene, not solved from the robot's statics).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import estimators as est

__all__ = ["DoubleSupport", "double_support"]


@dataclass(frozen=True)
class DoubleSupport:
    """Both soles at once (world frame for the combined quantities, SI units).

    left, right: each sole's :class:`other_sensors.sole.feasibility.StepAssessment` (its own frame);
    contacts: the two :class:`other_sensors.sole.contact.SoleContact` (``foot`` first, then
    ``second_foot``); polygon (K, 2) m and polygon_area m^2: the double-support hull in the world;
    cop, cop_ft (2,) m: the combined CoP from the skin and from the ankle F/T sensors.
    """

    left: object
    right: object
    contacts: tuple
    polygon: np.ndarray
    polygon_area: float
    cop: np.ndarray
    cop_ft: np.ndarray


def double_support(layout, contacts, assessments) -> DoubleSupport:
    """Combine two soles: ``contacts`` and ``assessments`` are pairs (first foot, second foot) of
    :class:`other_sensors.sole.contact.SoleContact` and their :class:`StepAssessment`."""
    (c1, c2), (a1, a2) = contacts, assessments
    polygon = est.double_support_polygon(layout.corners, a1.active, c1.pose, layout.corners, a2.active, c2.pose)
    forces = np.array([c1.cell_forces.sum(), c2.cell_forces.sum()])
    skin = [c.pose.to_world(a.cop)[:2] if f > 0 else np.full(2, np.nan) for c, a, f in zip(contacts, assessments, forces)]
    ft_forces = np.array([c1.wrench[2], c2.wrench[2]])
    ft = [c.pose.to_world(a.cop_ft)[:2] if f > 0 else np.full(2, np.nan) for c, a, f in zip(contacts, assessments, ft_forces)]
    return DoubleSupport(a1, a2, (c1, c2), polygon, est.polygon_area(polygon), est.combined_cop(np.array(skin), forces),
                         est.combined_cop(np.array(ft), ft_forces))
