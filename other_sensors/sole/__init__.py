"""The plantar robot skin of SPEC 4: hexagonal skin cells on a humanoid's soles, foot-terrain contact
through a Winkler layer, the skin's estimators (CoP, contact area, support and pre-touch polygons;
compiled for the 250 Hz loop in ``tick``), double support (``stance``), the step-feasibility rules,
the CP-ZMP balance loop, and simplified models of the cells' accelerometers and temperature
sensors. Shear is not modelled: SPEC 4's cells measure normal force only. ``other_sensors.sole.kind`` registers the
``plantar_sole`` sensor kind."""
