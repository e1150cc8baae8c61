"""The sibling sensors, each a sensor kind of its own (``sensor.kind``), registered with
:func:`mlsim.stage.register_kind` and listed in :data:`mlsim.stage.BUILTIN_KINDS`: ``cls`` (the compliant limb
shell, :mod:`other_sensors.cls`), ``plantar_sole`` (:mod:`other_sensors.sole`) and ``anyskin`` (the magnetic
skins of the Head-On helmet, :mod:`other_sensors.anyskin`)."""
