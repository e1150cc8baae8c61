"""Emission proportional to the positive stress rate, without trap depletion.

The limit of :mod:`mlsim.emission.detrapping` with instant refilling (tau -> 0, n = 1): the
photons in a window are B k times the rise of the equivalent stress within it. The linear
"ML intensity follows the stress rate" picture used to read ML images as stress maps
[Xu1999]_; no memory, so repeated presses are equally bright. Useful as a baseline against the
depleting model.

References
----------
.. [Xu1999] C.-N. Xu, T. Watanabe, M. Akiyama, X.-G. Zheng, "Direct view of stress distribution in
   solid by mechanoluminescence", Appl. Phys. Lett. 74, 2414 (1999).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlsim.emission.detrapping import merged_grid

__all__ = ["StressRateParams", "stress_rate_fraction", "StressRate"]


@dataclass(frozen=True)
class StressRateParams:
    detrapping_per_pa: float = 2e-7  # the same k as the de-trapping model, so their scales compare

    def __post_init__(self):
        if not (np.isfinite(self.detrapping_per_pa) and self.detrapping_per_pa >= 0):
            raise ValueError(f"detrapping_per_pa = {self.detrapping_per_pa}: must be finite and >= 0")


def stress_rate_fraction(t_s, sigma_eq_pa, windows_s, params: StressRateParams = StressRateParams(), n0=None):
    """k times the positive rise of sigma_eq within each window: (F, N), and None (no state; ``n0``
    is accepted for the models' common signature and ignored: the traps never deplete).
    Shapes and units as :func:`mlsim.emission.detrapping.detrapped_fraction`."""
    times, sig, ranges = merged_grid(t_s, sigma_eq_pa, windows_s)
    rise = params.detrapping_per_pa * np.maximum(np.diff(sig, axis=0), 0.0)
    cumulative = np.concatenate([np.zeros((1, sig.shape[1])), np.cumsum(rise, axis=0)])
    return cumulative[ranges[:, 1]] - cumulative[ranges[:, 0]], None


class StressRate:
    name = "stress_rate"

    def __init__(self, params: StressRateParams = StressRateParams()):
        self.params = params

    def __call__(self, t_s, sigma_eq_pa, windows_s):
        return stress_rate_fraction(t_s, sigma_eq_pa, windows_s, self.params)[0]
