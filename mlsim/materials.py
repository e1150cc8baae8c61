"""The shipped table of elastomers (and rigid parts) with the provenance of every value.

Values come from SPEC section 1.2 where the published work gives them; where it does not, the
value is derived by a published relation or taken from the manufacturer's data, and its
``source`` says which. A scene may override any value or add a material (``[materials.NAME]``);
an overridden value's source becomes ``"scene override"``.

Elastomer moduli where SPEC 1.2 gives only a Shore hardness come from Gent's relation
(:mod:`fem.materials.shore_hardness`).
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from types import MappingProxyType

import numpy as np

from fem.materials.shore_hardness import young_modulus_from_modulus_100, young_modulus_gent_pa

__all__ = [
    "Quantity",
    "Material",
    "SHIPPED_MATERIALS",
    "MATERIAL_PROPERTIES",
    "PHOSPHOR_LOADING_BRIGHTNESS",
    "phosphor_relative_brightness",
]


@dataclass(frozen=True)
class Quantity:
    """A material value (SI units, or None when unknown) and where it comes from."""

    value: float | None
    source: str


@dataclass(frozen=True)
class Material:
    """One material of the table. Units are in the field names (SI)."""

    name: str
    description: str
    young_modulus_pa: Quantity
    poisson_ratio: Quantity
    density_kg_m3: Quantity
    tensile_strength_pa: Quantity
    elongation_at_break: Quantity  # fraction, 1.0 = 100 %
    relative_ml_peak: Quantity  # ML peak intensity relative to PDMS (1.0), ZnS:Cu at equal loading
    rigid: bool = False

    def with_overrides(self, values: dict) -> "Material":
        """A copy with some values replaced (their source becomes 'scene override')."""
        changes = {k: Quantity(float(v), "scene override") for k, v in values.items() if v is not None}
        return replace(self, **changes)

    def as_dict(self) -> dict:
        out = {"name": self.name, "description": self.description, "rigid": self.rigid}
        for f in fields(self):
            q = getattr(self, f.name)
            if isinstance(q, Quantity):
                out[f.name] = {"value": q.value, "source": q.source}
        return out


# Names of the numeric properties a scene may override, in SI units.
MATERIAL_PROPERTIES = (
    "young_modulus_pa",
    "poisson_ratio",
    "density_kg_m3",
    "tensile_strength_pa",
    "elongation_at_break",
    "relative_ml_peak",
)

_SPEC = "SPEC 1.2"
_NU = Quantity(0.49, _SPEC)
# Smooth-On platinum silicones have specific gravity 1.07-1.08 (technical bulletins); SPEC 1.2
# gives no density for them.
_SILICONE_DENSITY = Quantity(1080.0, "not given in SPEC 1.2; default 1080 (Smooth-On platinum silicones, s.g. 1.07-1.08)")
_ML_LOWER = Quantity(
    0.5,
    "not given (SPEC 1.2 says lower than SC37's 0.717); default 0.5, an assumption to override per scene",
)
_UNKNOWN = Quantity(None, "not given in SPEC 1.2")


def _gent(shore_a: float) -> Quantity:
    e = float(young_modulus_gent_pa(shore_a))
    note = "" if shore_a >= 40 else " (below the relation's 40A validity range: rough estimate)"
    return Quantity(e, f"Gent's relation at Shore {shore_a:g}A{note} [Gent 1958; ASTM D2240]")


_TABLE = {
    "PDMS": Material(
        name="PDMS",
        description="Sylgard-type PDMS, 10:1 base:curing agent",
        young_modulus_pa=Quantity(550e3, "SPEC 1.2 (value used in the published FEM)"),
        poisson_ratio=_NU,
        density_kg_m3=Quantity(970.0, _SPEC),
        tensile_strength_pa=Quantity(19.4e6, _SPEC),
        elongation_at_break=Quantity(0.631, "SPEC 1.2 gives < 63.1 %; the bound is stored"),
        relative_ml_peak=Quantity(1.0, _SPEC),
    ),
    "SC37": Material(
        name="SC37",
        description="Smooth-On Sorta-Clear 37 (Shore 37A), the sensor's default elastomer",
        young_modulus_pa=_gent(37),
        poisson_ratio=_NU,
        density_kg_m3=_SILICONE_DENSITY,
        tensile_strength_pa=Quantity(23.9e6, _SPEC),
        elongation_at_break=Quantity(1.93, "SPEC 1.2 gives 193-196 %; the lower value is stored"),
        relative_ml_peak=Quantity(0.717, _SPEC),
    ),
    "SC10": Material(
        name="SC10",
        description="Smooth-On Sorta-Clear 10 (Shore 10A)",
        young_modulus_pa=_gent(10),
        poisson_ratio=_NU,
        density_kg_m3=_SILICONE_DENSITY,
        tensile_strength_pa=_UNKNOWN,
        elongation_at_break=_UNKNOWN,
        relative_ml_peak=_ML_LOWER,
    ),
    "DS30": Material(
        name="DS30",
        description="Smooth-On Dragon Skin 30 (Shore 30A)",
        young_modulus_pa=_gent(30),
        poisson_ratio=_NU,
        density_kg_m3=_SILICONE_DENSITY,
        tensile_strength_pa=Quantity(500 * 6894.757, "not given in SPEC 1.2; Smooth-On Dragon Skin 30 bulletin, 500 psi (ASTM D412)"),
        elongation_at_break=Quantity(3.64, "not given in SPEC 1.2; Smooth-On Dragon Skin 30 bulletin, 364 % (ASTM D412)"),
        relative_ml_peak=_ML_LOWER,
    ),
    "EF30": Material(
        name="EF30",
        description="Smooth-On Ecoflex 00-30 (Shore 00-30)",
        # Gent's relation is for Shore A; Ecoflex's technical bulletin gives a 100 % modulus of 10 psi.
        young_modulus_pa=Quantity(
            float(young_modulus_from_modulus_100(10 * 6894.757)),
            "100 % modulus 10 psi (Smooth-On Ecoflex 00-30 bulletin) -> E = 3 G, neo-Hookean uniaxial",
        ),
        poisson_ratio=_NU,
        density_kg_m3=Quantity(1070.0, "not given in SPEC 1.2; Smooth-On bulletin s.g. 1.07"),
        tensile_strength_pa=Quantity(5.4e6, _SPEC),
        elongation_at_break=Quantity(5.34, "SPEC 1.2 gives > 534 %; the bound is stored"),
        relative_ml_peak=_ML_LOWER,
    ),
    "steel": Material(
        name="steel",
        description="structural steel (the rigid block of the published FEM set-up, SPEC 1.4)",
        young_modulus_pa=Quantity(200e9, "SPEC 1.4 (about 200 GPa)"),
        poisson_ratio=Quantity(0.3, "not given; textbook value for steel"),
        density_kg_m3=Quantity(7850.0, "not given; textbook value for steel"),
        tensile_strength_pa=_UNKNOWN,
        elongation_at_break=_UNKNOWN,
        relative_ml_peak=Quantity(0.0, "not luminescent"),
        rigid=True,
    ),
}

#: The shipped materials, by name (read-only).
SHIPPED_MATERIALS = MappingProxyType(_TABLE)

#: Relative ML brightness against ZnS:Cu loading in wt% (SPEC 1.2: 60 wt% = 100 %).
PHOSPHOR_LOADING_BRIGHTNESS = MappingProxyType(
    {20.0: 0.0513, 30.0: 0.1783, 40.0: 0.2167, 50.0: 0.6224, 60.0: 1.0}
)


def phosphor_relative_brightness(loading_wt_pct):
    """Relative ML brightness at a ZnS:Cu loading (wt%), piecewise-linear in the SPEC 1.2 table.

    loading_wt_pct: scalar or array within [20, 60] (the measured range). Returns the same shape.
    """
    x = np.asarray(loading_wt_pct, dtype=float)
    keys = np.array(sorted(PHOSPHOR_LOADING_BRIGHTNESS))
    if np.any(~np.isfinite(x)) or np.any(x < keys[0]) or np.any(x > keys[-1]):
        raise ValueError(
            f"loading_wt_pct = {loading_wt_pct}: must be within [{keys[0]:g}, {keys[-1]:g}] "
            "(the range measured in SPEC 1.2)"
        )
    return np.interp(x, keys, [PHOSPHOR_LOADING_BRIGHTNESS[k] for k in keys])
