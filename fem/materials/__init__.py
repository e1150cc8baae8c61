"""Material models, one published model per file, registered by name.

>>> from fem.materials import material_model
>>> material_model("neo_hookean")  # the module holding its pure functions
"""

from __future__ import annotations

import importlib

#: Constitutive models a scene can select, by name -> module.
MATERIAL_MODELS = {
    "linear_elastic": "fem.materials.linear_elastic",
    "neo_hookean": "fem.materials.neo_hookean",
}


def material_model(name: str):
    """The module of a registered constitutive model; a wrong name lists the valid ones."""
    if name not in MATERIAL_MODELS:
        raise ValueError(f'"{name}" is not a material model; choose one of: {", ".join(MATERIAL_MODELS)}')
    return importlib.import_module(MATERIAL_MODELS[name])
