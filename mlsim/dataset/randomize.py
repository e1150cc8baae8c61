"""Domain randomisation of a dataset: the parameters that differ between real sensors and set-ups,
drawn per episode from the spec's seed (DESIGN "Real sensors"; Tobin et al., "Domain randomization
for transferring deep neural networks from simulation to the real world", IROS 2017).

A spec lists ranges under ``[randomize]``, each a scene field and its ``[low, high]``::

    [randomize]
    "emission.brightness_photons_per_m2" = [1.8e19, 3.6e19]   # brightness per newton: phosphor loading, mixing
    "camera.gain_db" = [0.0, 6.0]
    "camera.read_noise_e" = [1.5, 4.0]

Each episode draws every listed field uniformly in its range from its own stream, seeded by (spec
seed, 4, action, sample index): the same spec gives the same values, a larger dataset extends a
smaller one, and the people, samples and camera noise (streams 1-3) are drawn exactly as without
randomisation. The values are stored with the episode (its ``randomized`` attribute) and listed by
the dataset card; without ``[randomize]`` nothing changes (no attribute, the same bytes).

Only fields that leave the sensor's precomputes (mesh, reduced model, transport matrix) shared may be
randomised (:data:`RANDOMIZABLE`, with why each differs between real set-ups): rod positions and the
camera's pose change the mesh or the view, which would mean a mesh or a trace per episode. A camera
field also changes the episode's calibration frame (the calibration stage reads the camera): each
simulated sensor is calibrated through its own camera, as a real one is.
"""

from __future__ import annotations

import numpy as np

__all__ = ["RANDOMIZABLE", "check_ranges", "draw_randomized", "RANDOMIZE_STREAM"]

#: The stream index of the per-episode draws (1: people, 2: samples, 3: noise seeds; mlsim.dataset.generate).
RANDOMIZE_STREAM = 4

#: Scene fields a dataset may randomise, and why they differ between real sensors and set-ups.
RANDOMIZABLE: dict[str, str] = {
    "emission.brightness_photons_per_m2": "brightness per newton: phosphor loading and its mixing differ between moulded sensors (SPEC 1.2)",
    "emission.detrapping_per_pa": "the phosphor's trap response to stress (SPEC 1.3: de-trapping, not given)",
    "emission.recovery_time_s": "the phosphor's trap refilling time (self-recovering ZnS:Cu, not given)",
    "camera.gain_db": "the camera's analogue gain setting",
    "camera.read_noise_e": "read noise differs between camera units",
    "camera.dark_current_e_per_s": "dark current differs between units and with temperature",
    "camera.black_level_dn": "black level (offset) setting",
    "camera.conversion_gain_dn_per_e": "conversion gain differs between units",
    "camera.f_number": "lens aperture between set-ups",
    "camera.lens_transmittance": "lens and window transmittance between set-ups",
    "camera.exposure_ms": "exposure time setting (at most the frame period)",
    "ambient.power_w": "ambient lamp power (with ambient.lamp set in the base scene)",
    "ambient.height_m": "ambient lamp height above the sensor (with ambient.lamp set in the base scene)",
}


def check_ranges(ranges: dict) -> dict[str, tuple[float, float]]:
    """The ranges of a spec's ``[randomize]``, validated: known fields, two finite numbers low <= high.
    Raises ValueError naming the field and what is valid (the spec's validator turns it into a SceneError)."""
    out = {}
    for path, value in ranges.items():
        if path not in RANDOMIZABLE:
            raise ValueError(f'"{path}" cannot be randomised per episode; choose from: {", ".join(RANDOMIZABLE)} (rod positions and the camera '
                             "pose change the mesh or the view: not yet)")
        if (not isinstance(value, (list, tuple)) or len(value) != 2
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) for v in value)):
            raise ValueError(f"{path} = {value!r}: give [low, high], two finite numbers")
        low, high = float(value[0]), float(value[1])
        if low > high:
            raise ValueError(f"{path} = [{low:g}, {high:g}]: low is above high")
        out[path] = (low, high)
    return out


def draw_randomized(ranges: dict[str, tuple[float, float]], rng: np.random.Generator) -> dict[str, float]:
    """One episode's values: each field uniform in [low, high], drawn in the fields' sorted order
    (so the order in the spec file does not matter). Returns {dotted path: float}."""
    paths = sorted(ranges)
    u = rng.random(len(paths))
    return {p: float(ranges[p][0] + (ranges[p][1] - ranges[p][0]) * x) for p, x in zip(paths, u)}
