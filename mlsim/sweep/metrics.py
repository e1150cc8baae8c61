"""What a sweep reports of each variant (pure functions of the stages' results).

- brightness: photons the ML layer emits and what the camera sees of them (:func:`brightness`);
- tear risk: the peak principal stress and strain against the material's tensile strength and
  elongation at break (:func:`tear_risk`);
- separation of neighbouring taxels in the calibration frame (:func:`separation`);
- the cantilever sensitivity of SPEC 1.3 (:func:`beam_strain_per_newton`), for reading the trends.

The strains are the small-strain strains of the solve's stresses, epsilon = ((1 + nu) sigma -
nu tr(sigma) I) / E, per tet with the material of its dominant layer: a linear estimate, the
engineering strain that elongation at break is quoted in. The peaks are per tet of the solve's mesh:
at the re-entrant corner where a rod meets the base the elastic field is singular, so the peak there
grows as the mesh is refined (the safety factors are at the mesh's resolution; the run records it).
"""

from __future__ import annotations

import numpy as np

__all__ = ["principal_stress", "principal_strain", "tear_risk", "brightness", "separation", "beam_strain_per_newton"]

#: the layers of an Episode's ``layer_fraction`` columns, and the scene region of each
LAYER_REGIONS = ("absorber", "ml_layer", "core")


def _tensor(voigt: np.ndarray) -> np.ndarray:
    """(..., 3, 3) of Voigt (..., 6) in the order xx, yy, zz, yz, xz, xy."""
    xx, yy, zz, yz, xz, xy = np.moveaxis(np.asarray(voigt, dtype=np.float64), -1, 0)
    return np.stack([np.stack([xx, xy, xz], -1), np.stack([xy, yy, yz], -1), np.stack([xz, yz, zz], -1)], -2)


def principal_stress(stress_voigt: np.ndarray) -> np.ndarray:
    """(..., 3) principal stresses, ascending, of Voigt stresses (..., 6) Pa."""
    return np.linalg.eigvalsh(_tensor(stress_voigt))


def principal_strain(stress_voigt: np.ndarray, young_modulus_pa, poisson_ratio) -> np.ndarray:
    """(..., 3) principal strains, ascending, of Voigt stresses (..., 6) Pa in an isotropic linear
    material (E, nu broadcast over ``...``): ((1 + nu) sigma_i - nu tr(sigma)) / E, the same axes."""
    s = principal_stress(stress_voigt)
    e, nu = np.asarray(young_modulus_pa, dtype=float)[..., None], np.asarray(poisson_ratio, dtype=float)[..., None]
    return ((1.0 + nu) * s - nu * s.sum(axis=-1, keepdims=True)) / e


def tear_risk(episode, scene) -> dict:
    """The peak (over steps and tets) largest principal stress and strain of a solved episode, where
    they are (rod index, -1 the base), and the safety factors against the materials' tensile strength
    and elongation at break (None where the table does not give them): a factor below 1 is a tear."""
    stress = np.moveaxis(np.asarray(episode.stress), 1, -1)  # (S, T, 6)
    layer = np.argmax(episode.layer_fraction, axis=1)  # (T,) dominant layer
    mats = [scene.material(r) for r in LAYER_REGIONS]
    E = np.array([m.young_modulus_pa.value for m in mats])[layer]
    nu = np.array([m.poisson_ratio.value for m in mats])[layer]
    s1 = principal_stress(stress)[..., -1]  # (S, T)
    e1 = principal_strain(stress, E[None], nu[None])[..., -1]
    i_s = np.unravel_index(int(np.argmax(s1)), s1.shape)
    i_e = np.unravel_index(int(np.argmax(e1)), e1.shape)
    peak_stress, peak_strain = float(s1[i_s]), float(e1[i_e])
    m_s, m_e = mats[layer[i_s[1]]], mats[layer[i_e[1]]]
    strength, elongation = m_s.tensile_strength_pa.value, m_e.elongation_at_break.value
    sf_stress = strength / peak_stress if strength and peak_stress > 0 else None
    sf_strain = elongation / peak_strain if elongation and peak_strain > 0 else None
    return {
        "peak_principal_stress_kpa": peak_stress / 1e3,
        "peak_principal_strain_pct": 100.0 * peak_strain,
        "peak_stress_rod": int(episode.tet_rod[i_s[1]]),
        "peak_strain_rod": int(episode.tet_rod[i_e[1]]),
        "tensile_strength_mpa": None if strength is None else strength / 1e6,
        "elongation_at_break_pct": None if elongation is None else 100.0 * elongation,
        "safety_factor_stress": sf_stress,
        "safety_factor_strain": sf_strain,
        "tears": bool((sf_stress is not None and sf_stress < 1.0) or (sf_strain is not None and sf_strain < 1.0)),
        "material_of_peak": m_e.name,
        "peak_normal_force_n": float(np.max(episode.normal_force_n)),
    }


def brightness(camera, grey_frames: np.ndarray | None = None, disk_masks: np.ndarray | None = None) -> dict:
    """Photons and camera counts of one episode (``camera``: :class:`mlsim.render.output.CameraFrames`).

    total_photons: every rod's photons over every exposure; per_rod_photons (R,); peak_rod_signal_e:
    the brightest rod's mean noiseless signal per pixel in its brightest frame. With the frames'
    grey levels (F, H, W) and the rods' disk masks (R, H, W): peak_rod_dn, the brightest rod's mean
    grey level in its disk above that rod's darkest frame (8-bit counts, noise included: the mean
    over a disk of ~10^3 pixels moves by a few hundredths of a count with the noise)."""
    per_rod = np.asarray(camera.rod_photons, dtype=np.float64).sum(axis=0)
    out = {"total_photons": float(per_rod.sum()), "per_rod_photons": [float(v) for v in per_rod],
           "peak_rod_photons": float(per_rod.max()) if per_rod.size else 0.0,
           "peak_rod_signal_e": float(np.max(camera.rod_signal_e)) if np.size(camera.rod_signal_e) else 0.0}
    if grey_frames is not None and disk_masks is not None:
        m = disk_masks.reshape(len(disk_masks), -1).astype(np.float64)
        mean = grey_frames.reshape(len(grey_frames), -1).astype(np.float64) @ (m / m.sum(axis=1, keepdims=True)).T  # (F, R)
        out["peak_rod_dn"] = float((mean - mean.min(axis=0, keepdims=True)).max())
    return out


def separation(grey: np.ndarray, centres_px: np.ndarray, radius_px: float, rows: int, cols: int) -> dict:
    """How well the calibration frame's disks stand apart: for each pair of neighbouring rods (along
    a row or a column), the valley between them, 1 - (least grey level on the segment between their
    centres) / (the dimmer centre's level), 0 where the disks merge into one blob, 1 where the gap is
    black; and the gap between the disks' rims in pixels (pitch minus two radii).

    grey (H, W) uint8; centres_px (R, 2) (column, row), row-major over rows x cols."""
    g = np.asarray(grey, dtype=np.float64)
    c = np.asarray(centres_px, dtype=np.float64).reshape(rows, cols, 2)
    pairs = [(c[i, j], c[i, j + 1]) for i in range(rows) for j in range(cols - 1)]
    pairs += [(c[i, j], c[i + 1, j]) for i in range(rows - 1) for j in range(cols)]
    valleys, gaps = [], []
    for a, b in pairs:
        n = int(np.ceil(np.linalg.norm(b - a))) + 1
        t = np.linspace(0.0, 1.0, n)
        pts = a[None] + t[:, None] * (b - a)[None]
        prof = _bilinear(g, pts)
        peak = min(prof[0], prof[-1])
        valleys.append(1.0 - prof.min() / peak if peak > 0 else 0.0)
        gaps.append(float(np.linalg.norm(b - a)) - 2.0 * radius_px)
    if not pairs:
        return {"min_valley": None, "mean_valley": None, "min_rim_gap_px": None}
    return {"min_valley": float(min(valleys)), "mean_valley": float(np.mean(valleys)), "min_rim_gap_px": float(min(gaps))}


def _bilinear(g: np.ndarray, pts: np.ndarray) -> np.ndarray:
    x = np.clip(pts[:, 0], 0, g.shape[1] - 1.000001)
    y = np.clip(pts[:, 1], 0, g.shape[0] - 1.000001)
    x0, y0 = x.astype(int), y.astype(int)
    wx, wy = x - x0, y - y0
    return ((1 - wy) * ((1 - wx) * g[y0, x0] + wx * g[y0, x0 + 1]) + wy * ((1 - wx) * g[y0 + 1, x0] + wx * g[y0 + 1, x0 + 1]))


def beam_strain_per_newton(height_mm: float, diameter_mm: float, young_modulus_pa: float) -> float:
    """SPEC 1.3's sensitivity of a rod as a cantilever: the peak bending strain at its base per
    newton of lateral tip force, S = 4 L / (pi r^3 E) (1/N): taller, thinner, softer rods strain more."""
    L, r = height_mm * 1e-3, diameter_mm * 0.5e-3
    return 4.0 * L / (np.pi * r**3 * young_modulus_pa)
