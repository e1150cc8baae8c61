"""Units from field names (base layer): every scene field carries its unit in its name.

``height_mm`` is in millimetres, ``speed_mm_s`` in mm/s. :func:`unit_of` reads the unit from the
name's suffix; :data:`DIMENSIONLESS` lists the numeric fields that are pure numbers (a ratio, a
count, a factor) and so carry no suffix. ``mlsim check`` prints the units, the scene reference
(``docs/``, :mod:`mlsim.docgen`) lists them, and ``tests/test_scene_files.py`` fails on a numeric
field that has neither a unit suffix nor a place in :data:`DIMENSIONLESS`.
"""

from __future__ import annotations

__all__ = ["UNIT_SUFFIXES", "UNIT_NAMES", "DIMENSIONLESS", "UNIT_OF_KEYS", "unit_of"]

#: name suffix -> unit, the longest suffixes first (``_mm_s`` before ``_s``).
UNIT_SUFFIXES: tuple[tuple[str, str], ...] = (
    ("_photons_per_m2", "photons/m^2"),
    ("_e_per_s", "e-/s"),
    ("_dn_per_e", "DN/e-"),
    ("_lm_per_w", "lm/W"),
    ("_kg_m3", "kg/m^3"),
    ("_n_m3", "N/m^3"),
    ("_mm_s", "mm/s"),
    ("_deg_s", "deg/s"),
    ("_rad_s", "rad/s"),
    ("_m_s2", "m/s^2"),
    ("_m_s", "m/s"),
    ("_per_pa", "1/Pa"),
    ("_per_s", "1/s"),
    ("_mm2", "mm^2"),
    ("_cm2", "cm^2"),
    ("_m2", "m^2"),
    ("_wt_pct", "wt%"),
    ("_pct", "%"),
    ("_dn8", "DN (8-bit)"),
    ("_dn", "DN"),
    ("_nm", "nm"),
    ("_mm", "mm"),
    ("_cm", "cm"),
    ("_um", "um"),
    ("_ms", "ms"),
    ("_kpa", "kPa"),
    ("_pa", "Pa"),
    ("_deg", "deg"),
    ("_rad", "rad"),
    ("_px", "px"),
    ("_db", "dB"),
    ("_hz", "Hz"),
    ("_kg", "kg"),
    ("_n", "N"),
    ("_w", "W"),
    ("_v", "V"),
    ("_mv", "mV"),
    ("_ut", "uT"),
    ("_g", "g"),
    ("_c", "degC"),
    ("_e", "e-"),
    ("_m", "m"),
    ("_s", "s"),
)

#: fields whose whole name is their unit.
UNIT_NAMES: dict[str, str] = {"fps": "frames/s"}

#: numeric fields that are pure numbers, with what they count or compare.
DIMENSIONLESS: dict[str, str] = {
    "rows": "a count", "cols": "a count", "n": "a count", "seed": "a seed", "noise_seed": "a seed",
    "poisson_ratio": "a ratio", "elongation_at_break": "a strain", "relative_ml_peak": "relative to PDMS",
    "friction_coefficient": "Coulomb's mu", "alpha": "a factor of the idle mean", "beta": "a factor of the idle taxel sums",
    "ml_layer_reflectance": "a fraction", "ml_layer_transmittance": "a fraction", "lens_transmittance": "a fraction",
    "elastomer_refractive_index": "a refractive index", "acrylic_refractive_index": "a refractive index",
    "f_number": "focal length over aperture", "binning": "native pixels per output pixel", "adc_bits": "bits",
    "flicker_depth": "(max - min) / (max + min)", "stride": "frames", "segments_per_circle": "a count",
    "fraction_levels": "a count", "retries": "a count", "element_order": "the elements' polynomial order",
    "substeps": "a count", "penalty_factor": "times E / h", "patches_per_tip": "a count", "patches_per_side": "a count",
    "small_strain_limit": "a fraction of the rod height", "buckling_limit": "a fraction of the Euler load",
    "contact_max_iterations": "a count", "loss_factor": "the elastomer's loss tangent", "steps_per_period": "time steps per period",
    "spp": "samples per pixel", "transport_spp": "samples per pixel",
    "transport_drop": "a fraction of the largest entry", "direct_samples_per_side": "samples per pixel side",
    "max_depth": "path vertices", "rr_depth": "path vertices", "profile_points": "a count",
    "people": "a count", "samples_per_action": "a count", "variability": "relative spread of a person's strokes",
    "batch_episodes": "a count (episodes per batch)",
    # the sibling sensors' (other_sensors/*/schema.py)
    "coefficient_spread": "relative spread", "stiffening_strain": "a strain", "tau": "a fraction of the range",
    "tolerance": "relative", "max_iterations": "a count", "lambda0": "Levenberg-Marquardt damping",
    "row_counts": "cells per row", "sensor_radius_fraction": "a fraction of the cell radius", "quadrature": "sub-triangles per edge",
    "eps_area": "a fraction of the sole's area", "k_xi": "a gain (SPEC 4)", "grid": "points per side", "max_strain": "a strain",
    "jitter": "relative", "set_fraction": "a fraction", "median_samples": "samples", "window_samples": "samples",
    "rho_base": "a diffuse reflectance", "rho_shell": "a diffuse reflectance",
    "leg_mass_fraction": "a fraction of the body's mass",
}

#: numeric fields keyed by scene fields, each value in the unit of the field that keys it (a dataset
#: spec's ``[randomize]``: ``"camera.gain_db" = [0.0, 6.0]`` is in dB): the keys carry the units, and
#: ``tests/test_scene_files.py`` checks that every key such a field accepts has one (or is dimensionless).
UNIT_OF_KEYS: dict[str, str] = {
    "randomize": "each range in the unit of the scene field that keys it",
}


def unit_of(name: str) -> str:
    """The unit a field's name carries (``"speed_mm_s"`` -> ``"mm/s"``; a dotted path or an index is
    read at its last name); ``""`` when the name has no unit suffix."""
    leaf = name.rsplit(".", 1)[-1].split("[")[0].removesuffix("_range")  # stroke_mm_range: an interval in mm
    if leaf in UNIT_NAMES:
        return UNIT_NAMES[leaf]
    for suffix, unit in UNIT_SUFFIXES:
        if leaf.endswith(suffix):
            return unit
    return ""
