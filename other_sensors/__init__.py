"""other_sensors package (filled by later issues)."""
