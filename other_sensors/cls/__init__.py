"""CLS: the compliant limb sensor (SPEC 3): a rigid shell on foam pillars whose pose LED / light-to-voltage pairs measure."""
