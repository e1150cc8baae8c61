"""The plantar robot skin of SPEC 4: hexagonal skin cells on a humanoid's soles, foot-terrain contact
through a Winkler layer, the skin's estimators (CoP, contact area, support and pre-touch polygons),
the step-feasibility rules and the CP-ZMP balance loop. ``other_sensors.sole.kind`` registers the
``plantar_sole`` sensor kind."""
