"""The sibling sensors (AnySkin, the compliant limb shell, the plantar sole): each a sensor kind of its own (``sensor.kind``),
registered with :func:`mlsim.stage.register_kind` (issues 19-21; none yet)."""
