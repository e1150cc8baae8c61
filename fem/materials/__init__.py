"""Material models. One published model per file (see each module's docstring for its source)."""
