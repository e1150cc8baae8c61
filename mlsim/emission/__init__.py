"""ML emission: photons per second from each emitting patch of the ML layer, per camera frame.

One physical model per file, registered by name (``emission.model`` in a scene):

- ``detrapping`` (default): :mod:`mlsim.emission.detrapping`, piezoelectrically induced de-trapping
  with self-recovery [Chandra2013]_;
- ``stress_rate``: :mod:`mlsim.emission.stress_rate`, the same without depletion.

Both give the fraction of a patch's traps emptied radiatively in each exposure window; the photon
count per area is that times B (``emission.brightness_photons_per_m2``: photons per m^2 of ML layer
when all its traps empty) times the host's relative ML peak (SPEC 1.2 table, the ML layer's
material) times the phosphor-loading factor (SPEC 1.2). The equivalent stress that drives them is
chosen by ``emission.equivalent_stress`` (:mod:`mlsim.emission.equivalent_stress`).

.. [Chandra2013] V. K. Chandra, B. P. Chandra, P. Jha, Appl. Phys. Lett. 102, 241105 (2013).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from mlsim.emission import detrapping, stress_rate
from mlsim.emission.equivalent_stress import EQUIVALENT_STRESSES, equivalent_stress
from mlsim.emission.patches import MLPatches, ml_patches

__all__ = ["EMISSION_MODELS", "emission_model", "EQUIVALENT_STRESSES", "equivalent_stress", "MLPatches", "ml_patches",
           "photon_rates", "EmissionResult"]


@dataclass(frozen=True)
class _Model:
    name: str
    params: type
    fraction: object  # (t_s, sigma_eq (S, N), windows (F, 2), params, n0) -> ((F, N), state)

    def params_from(self, spec):
        """The model's parameters from a scene's ``emission`` section (the fields both carry)."""
        from dataclasses import fields

        return self.params(**{f.name: getattr(spec, f.name) for f in fields(self.params)})


EMISSION_MODELS = {
    "detrapping": _Model("detrapping", detrapping.DetrappingParams, detrapping.detrapped_fraction),
    "stress_rate": _Model("stress_rate", stress_rate.StressRateParams, stress_rate.stress_rate_fraction),
}


def emission_model(name: str) -> _Model:
    """The emission model registered as ``name``."""
    if name not in EMISSION_MODELS:
        raise ValueError(f'"{name}" is not an emission model; choose one of: {", ".join(EMISSION_MODELS)}')
    return EMISSION_MODELS[name]


@dataclass
class EmissionResult:
    """Per frame and patch: photons per second (F, N) (mean over the exposure window), with the
    windows (F, 2) s, the patches, and the filled trap fraction after the episode (N,) (None for
    a model without memory)."""

    photons_per_s: np.ndarray
    windows_s: np.ndarray
    patches: MLPatches
    filled_fraction: np.ndarray | None

    def per_rod(self, n_rods: int) -> np.ndarray:
        """Photons per second per rod (F, n_rods + 1); the last column is the base between rods."""
        from mlsim.emission.kernels import sum_by_index

        idx = np.where(self.patches.rod >= 0, self.patches.rod, n_rods).astype(np.int64)
        if len(idx) and (idx.min() < 0 or idx.max() > n_rods):
            raise ValueError(f"patches on rods {idx.min()}..{idx.max()}: the sensor has {n_rods} rods (0..{n_rods - 1}, -1 off them)")
        out = np.empty((len(self.photons_per_s), n_rods + 1))
        sum_by_index(np.ascontiguousarray(self.photons_per_s, dtype=np.float64), idx, out)  # each frame's bincount, bit for bit
        return out


def photon_rates(t_s, stress_voigt_pa, windows_s, patches: MLPatches, model: str = "detrapping", params=None,
                 measure: str = "von_mises", brightness_photons_per_m2: float = 1.0, scale: float = 1.0, n0=None) -> EmissionResult:
    """Photons per second from each patch, averaged over each exposure window.

    t_s: (S,) solve times, s. stress_voigt_pa: (S, 6, T) per-tet Voigt stress (the solve's
    :class:`fem.quasistatic.Episode` ``stress``). windows_s: (F, 2) exposure windows. patches: the
    emitting patches and their tets. ``scale``: host and loading factors (dimensionless).
    Returns an :class:`EmissionResult`.
    """
    m = emission_model(model)
    params = params if params is not None else m.params()
    stress = np.asarray(stress_voigt_pa)
    if stress.ndim != 3 or stress.shape[1] != 6:
        raise ValueError(f"stress of shape {stress.shape}: must be (steps, 6, tets)")
    if measure == "von_mises":  # compiled, the same bits (mlsim.emission.kernels); a NaN stays a NaN, refused below
        from mlsim.emission.kernels import von_mises_at

        sigma_eq = np.empty((stress.shape[0], len(patches.tet)))
        von_mises_at(np.ascontiguousarray(stress), np.ascontiguousarray(patches.tet, dtype=np.int64), sigma_eq)
    else:
        sigma_eq = equivalent_stress(measure)(np.moveaxis(stress[:, :, patches.tet], 1, 2))  # (S, N)
    if not (np.isfinite(brightness_photons_per_m2) and brightness_photons_per_m2 >= 0 and np.isfinite(scale) and scale >= 0):
        raise ValueError(f"brightness_photons_per_m2 = {brightness_photons_per_m2}, scale = {scale}: must be finite and >= 0")
    fraction, state = m.fraction(t_s, sigma_eq, windows_s, params, n0)
    windows_s = np.asarray(windows_s, dtype=float)
    length = (windows_s[:, 1] - windows_s[:, 0])[:, None]
    photons = brightness_photons_per_m2 * scale * fraction * patches.area_m2[None, :] / length
    return EmissionResult(photons, windows_s, patches, state)
