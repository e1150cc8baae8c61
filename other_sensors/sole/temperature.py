"""The cells' temperature sensors (SPEC 4: each cell carries one).

SPEC 4 lists a temperature sensor per cell and gives no model of it. The simplification here: a
cell's reading relaxes with one time constant toward the temperature of what it touches, the
ground's while the cell is active (in contact) and the air's otherwise (a lumped first-order
model: no conduction between cells, no heat from the robot, no contact-pressure dependence):

    T_j(t + dt) = T_target + (T_j(t) - T_target) exp(-dt / tau),   T_target = T_ground if active else T_air,

exact for a target held over the step. The time constant is a choice (not given): 20 s, a skin
cell's few grams of PCB and elastomer behind a thin cover.
"""

from __future__ import annotations

import numpy as np

__all__ = ["TIME_CONSTANT_S", "cell_temperatures"]

TIME_CONSTANT_S = 20.0


def cell_temperatures(previous_c: np.ndarray, active: np.ndarray, dt_s: float, air_c: float, ground_c: float,
                      time_constant_s: float = TIME_CONSTANT_S) -> np.ndarray:
    """The cells' readings (N,) deg C one step ``dt_s`` (s) after ``previous_c`` (N,) deg C, the
    cells in contact ``active`` (N,) bool relaxing toward ``ground_c``, the others toward ``air_c``."""
    if not dt_s >= 0 or not time_constant_s > 0:
        raise ValueError(f"dt_s = {dt_s}, time_constant_s = {time_constant_s}: need dt_s >= 0 and time_constant_s > 0")
    target = np.where(np.asarray(active, dtype=bool), ground_c, air_c)
    return target + (np.asarray(previous_c, dtype=float) - target) * np.exp(-dt_s / time_constant_s)
