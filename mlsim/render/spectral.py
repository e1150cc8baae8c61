"""Spectral reference render: the ZnS:Cu band carried through Mitsuba's spectral variant, to check
the spectral shortcut of :mod:`mlsim.render.optics`.

The shortcut renders mono photon radiance L (photons s^-1 m^-2 sr^-1) and multiplies it by

    k_c = integral s(lambda) T(lambda) QE_c(lambda) d lambda        (electrons per photon, channel c)

(:func:`mlsim.render.optics.ml_channel_factors`), which is exact when transport does not depend on
wavelength (one refractive index per material). The reference instead gives the emitter the spectral
radiance L_e(x, lambda) = s(lambda) e(x), with e the per-vertex value of the mono render and s the
photon spectral density (1/nm, unit integral), and renders it in ``llvm_ad_spectral`` onto a
``specfilm`` whose channel c has the sensitivity S_c(lambda) = T(lambda) QE_c(lambda). Each channel
of the reference is then, per pixel, the integral of the spectral radiance at the lens times S_c, in
the same units as ``mono[..., None] * k`` (electrons per photon x photons s^-1 m^-2 sr^-1).

Unit conventions, read in Mitsuba 3.9.1's sources and checked by experiment (the first two are what
tests/test_spectral_render.py asserts, against the mono render):

- ``specfilm`` does not normalise its sensitivity curves: it samples wavelengths in proportion to
  the sum of the curves, weights each sample by (integral of the sum) / (sum at lambda), and stores
  per channel the mean of S_c(lambda) L(lambda) x that weight, so a channel is the integral of
  S_c L over lambda in the curves' unit (nm). All channels share the same wavelength samples.
- A ``regular`` spectrum evaluates to its values, linearly interpolated, zero outside its range (no
  normalisation), so it serves both as the film's curves and as s(lambda) in the emitter.
- An emitter radiance given as a bare float (``"radiance": 1.0``) is *not* flat in the spectral
  variants: Mitsuba reads it as a colour and gives it the D65 illuminant's spectrum (a ``d65``
  texture); ``{"type": "spectrum", "value": 1.0}`` is flat (``uniform``). None is used here: the
  emitter is a small Python ``mi.Texture`` (:func:`radiance_texture`), s(lambda) (a ``regular``
  spectrum) times the mesh attribute, with ``is_spatially_varying()`` False so that the area
  emitter samples the sheet by area, as the mono scene's ``mesh_attribute`` emitter does (a
  spatially varying radiance would make it call the texture's ``sample_position``, which a mesh
  attribute cannot provide). Mitsuba 3.9.1 ships no texture that multiplies two others (its
  textures are bitmap, checkerboard, mesh_attribute and volume).
- Variance, not bias: the wavelengths are sampled by the film's curves, not by s(lambda) x the
  curves, so the reference is noisier per sample than the mono render (more so for a band much
  narrower than the curves); the same integral with s folded into the film's curves and a plain
  ``mesh_attribute`` emitter would sample better, at the cost of no longer rendering the emitter's
  spectrum as such.
- ``specfilm``'s default component format is float16 (it applies to the written file, not to the
  float32 image ``mi.render`` returns); set to float32 anyway, and a ``box`` filter as the mono
  ``hdrfilm`` (its default is a Gaussian, which would blur the rod disks differently).

What the comparison can and cannot show: the reference and the shortcut use the same curves and the
same non-dispersive interfaces (Mitsuba 3's ``dielectric`` takes one index), so they agree in
expectation; the comparison checks the units and the quadrature of the shortcut (the trapezoid rule
on the 1 nm grid against Mitsuba's integral of the linear interpolants) and that transport in the
spectral variant is the mono transport at every wavelength, and it measures the Monte Carlo
difference. It does not measure dispersion or the spread of path lengths in the absorbing slabs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["RenderSpectra", "ml_render_spectra", "radiance_texture", "film_dict", "spectral_twin", "spectral_reference",
           "shortcut_images", "compare_to_shortcut"]


@dataclass(frozen=True, eq=False)
class RenderSpectra:
    """The spectra of a spectral reference render, on one regular wavelength grid.

    Parameters
    ----------
    wavelengths_nm : (K,) float
        Regular, increasing grid, nm (K >= 2).
    emission_per_nm : (K,) float
        Photon spectral density of the emitter, 1/nm, >= 0, trapezoid integral 1 on the grid (so a
        vertex's value keeps its meaning: the photon radiance summed over wavelength).
    sensitivity : (C, K) float
        Electrons per photon arriving at the lens, per channel: QE_c x the path's internal
        transmittances (what :func:`mlsim.spectra.channel_factors` integrates), in [0, 1].
    channels : tuple of C str
        Channel names (default R, G, B).
    """

    wavelengths_nm: np.ndarray
    emission_per_nm: np.ndarray
    sensitivity: np.ndarray
    channels: tuple = ("r", "g", "b")

    def __post_init__(self):
        wl = _finite_array("wavelengths_nm", self.wavelengths_nm, ndim=1)
        if len(wl) < 2:
            raise ValueError(f"RenderSpectra.wavelengths_nm has {len(wl)} value(s): give a grid of at least 2")
        step = np.diff(wl)
        if step.min() <= 0 or step.max() - step.min() > 1e-9 * max(abs(wl[-1]), 1.0):
            raise ValueError(f"RenderSpectra.wavelengths_nm = {wl[0]:g}..{wl[-1]:g} nm with steps {step.min():g}..{step.max():g}: "
                             "must be a regular increasing grid (e.g. mlsim.spectra.wavelengths_nm())")
        if wl[0] <= 0:
            raise ValueError(f"RenderSpectra.wavelengths_nm starts at {wl[0]:g} nm: wavelengths must be > 0")
        s = _finite_array("emission_per_nm", self.emission_per_nm, shape=wl.shape)
        if s.min() < 0:
            raise ValueError("RenderSpectra.emission_per_nm has negative values: a photon spectral density is >= 0")
        total = float(np.trapezoid(s, wl))
        if not abs(total - 1.0) <= 1e-6:
            raise ValueError(f"RenderSpectra.emission_per_nm integrates to {total:.6g} over the grid: must be 1 "
                             "(a photon spectral density in 1/nm; divide it by its trapezoid integral)")
        channels = tuple(str(c) for c in self.channels)
        q = _finite_array("sensitivity", self.sensitivity, shape=(len(channels), len(wl)))
        if q.min() < 0 or q.max() > 1:
            raise ValueError(f"RenderSpectra.sensitivity spans {q.min():g}..{q.max():g}: must be within [0, 1] "
                             "(electrons per photon: QE times transmittances, not percent)")
        if np.any(q.max(axis=1) <= 0):
            raise ValueError(f"RenderSpectra.sensitivity of channel {channels[int(np.argmin(q.max(axis=1)))]} is zero everywhere")
        if len(set(channels)) != len(channels) or not channels:
            raise ValueError(f"RenderSpectra.channels = {channels}: must be distinct names, one per sensitivity row")
        for name, value in (("wavelengths_nm", wl), ("emission_per_nm", s), ("sensitivity", q)):
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        object.__setattr__(self, "channels", channels)

    def channel_factors(self) -> np.ndarray:
        """(C,) electrons per photon: trapz(s S_c), the spectral shortcut's factors on this grid."""
        return np.trapezoid(self.emission_per_nm[None] * self.sensitivity, self.wavelengths_nm, axis=1)


def _finite_array(name, value, ndim=None, shape=None) -> np.ndarray:
    a = np.array(value, dtype=float)  # a copy: the dataclass freezes it
    if ndim is not None and a.ndim != ndim:
        raise ValueError(f"RenderSpectra.{name} of shape {a.shape}: must be {ndim}-D")
    if shape is not None and a.shape != tuple(shape):
        raise ValueError(f"RenderSpectra.{name} of shape {a.shape}: must be {tuple(shape)} "
                         "(one value per wavelength; sensitivity: one row per channel)")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"RenderSpectra.{name} has NaN or infinite values")
    return a


def ml_render_spectra(scene) -> RenderSpectra:
    """The spectra of a scene's ML light: the ZnS:Cu band and, per channel, camera QE x the internal
    transmittance of the acrylic and of the clear core's mean path, on :data:`mlsim.spectra.SPECTRAL_SHAPE`.

    The same curves as :func:`mlsim.render.optics.ml_channel_factors`, so that
    ``ml_render_spectra(scene).channel_factors()`` equals it (tested).
    """
    from mlsim import spectra
    from mlsim.render.optics import inner_path_transmittance_sds

    wl = spectra.wavelengths_nm()
    emission = np.asarray(spectra.align_to_grid(spectra.zns_cu_emission_sd()).values, dtype=float)
    emission = emission / np.trapezoid(emission, wl)  # channel_factors normalises the same way
    path = np.ones_like(wl)
    for sd in inner_path_transmittance_sds(scene):  # the curves optics.ml_channel_factors integrates
        path = path * np.clip(np.asarray(spectra.align_to_grid(sd).values, dtype=float), 0.0, 1.0)
    qe = np.asarray(spectra.camera_sensitivity_msds(scene.camera.sensitivity).values, dtype=float)  # (K, 3)
    return RenderSpectra(wl, emission, (path[:, None] * qe).T, spectra.CHANNELS)


# ----------------------------------------------------------------------------------- Mitsuba side
_TEXTURE_CLASSES: dict = {}


def _regular_spectrum(wavelengths_nm, values) -> dict:
    """A Mitsuba ``regular`` spectrum: linear interpolation of ``values`` on the grid, 0 outside."""
    return {"type": "regular", "wavelength_min": float(wavelengths_nm[0]), "wavelength_max": float(wavelengths_nm[-1]),
            "values": ", ".join(f"{v:.9g}" for v in values)}


def _texture_class(mi):
    """The Python texture class of the current variant (Mitsuba's classes are per variant)."""
    variant = mi.variant()
    if variant not in _TEXTURE_CLASSES:

        class SpectrumTimesAttribute(mi.Texture):
            """Spectral radiance s(lambda) x a per-vertex mesh attribute (module docstring)."""

            def __init__(self, props, spectrum, attribute):
                super().__init__(props)
                self._spectrum = spectrum
                self._attribute = attribute

            def eval(self, si, active=True):
                return self._spectrum.eval(si, active) * self._attribute.eval_1(si, active)

            def is_spatially_varying(self):
                # False: the area emitter samples the sheet by area (as with mesh_attribute)
                return False

            def to_string(self):
                return "SpectrumTimesAttribute[]"

        _TEXTURE_CLASSES[variant] = SpectrumTimesAttribute
    return _TEXTURE_CLASSES[variant]


def radiance_texture(spectra: RenderSpectra, attribute: str):
    """The emitter's radiance texture (a Mitsuba object in the current, spectral, variant):
    ``spectra.emission_per_nm`` (1/nm) times the mesh attribute ``attribute`` (photons s^-1 m^-2 sr^-1)."""
    import mitsuba as mi

    if not mi.variant() or "spectral" not in mi.variant():
        raise RuntimeError(f"radiance_texture needs a spectral Mitsuba variant, the current one is {mi.variant()}")
    spectrum = mi.load_dict(_regular_spectrum(spectra.wavelengths_nm, spectra.emission_per_nm))
    attr = mi.load_dict({"type": "mesh_attribute", "name": attribute})
    return _texture_class(mi)(mi.Properties(), spectrum, attr)


def film_dict(spectra: RenderSpectra, width_px: int, height_px: int) -> dict:
    """A ``specfilm`` of one channel per sensitivity curve, in the order of ``spectra.channels``
    (Mitsuba 3.9 keeps the order of definition), box filter, float32."""
    film = {"type": "specfilm", "width": int(width_px), "height": int(height_px), "rfilter": {"type": "box"},
            "component_format": "float32"}
    for c, name in enumerate(spectra.channels):
        film[f"{c:02d}_{name}"] = _regular_spectrum(spectra.wavelengths_nm, spectra.sensitivity[c])
    return film


def spectral_twin(sensor_scene, spectra: RenderSpectra):
    """A :class:`mlsim.render.sensor_scene.SensorScene` with the same sheet (its current vertices),
    interfaces, view and integrator as ``sensor_scene``, built in ``llvm_ad_spectral`` with ``spectra``."""
    vertices_m = np.asarray(sensor_scene.vertices_mm, dtype=float) * 1e-3
    return type(sensor_scene)(vertices_m, sensor_scene.faces[:, ::-1], sensor_scene.view, spectra=spectra, **sensor_scene.options)


def _frame_seed(seed: int, frame: int) -> int:
    return int(np.random.SeedSequence([int(seed) & 0xFFFFFFFF, int(frame)]).generate_state(1)[0])


def spectral_reference(sensor_scene, vertex_radiance, spectra: RenderSpectra, *, spp: int, seed: int) -> np.ndarray:
    """Per-channel images of per-vertex radiance, rendered spectrally.

    Parameters
    ----------
    sensor_scene : SensorScene
        The (mono) scene whose sheet, interfaces and view are rendered (:func:`spectral_twin`).
    vertex_radiance : (F, N) or (N,) float
        Per-vertex photon radiance, photons s^-1 m^-2 sr^-1 (:func:`mlsim.render.radiance_of`).
    spectra : RenderSpectra
        Emission spectrum and channel sensitivities (:func:`ml_render_spectra`).
    spp, seed : int
        Samples per pixel; frame f is rendered with a seed drawn from (seed, f).

    Returns
    -------
    numpy.ndarray
        (F, H, W, C) (or (H, W, C)) float32: per pixel and channel, integral over lambda of the
        spectral radiance at the lens times the channel's sensitivity, in electrons per photon x
        photons s^-1 m^-2 sr^-1: the units of ``mono[..., None] * spectra.channel_factors()``.
    """
    e = np.asarray(vertex_radiance, dtype=np.float32)
    single = e.ndim == 1
    e2 = e[None] if single else e
    if e2.ndim != 2 or e2.shape[1] != sensor_scene.n_vertices:
        raise ValueError(f"vertex_radiance of shape {e.shape}: must be (frames, {sensor_scene.n_vertices}) or ({sensor_scene.n_vertices},)")
    if int(spp) < 1:
        raise ValueError(f"spp = {spp}: must be >= 1")
    twin = spectral_twin(sensor_scene, spectra)
    out = np.empty((len(e2), sensor_scene.view.height_px, sensor_scene.view.width_px, len(spectra.channels)), np.float32)
    for f, frame in enumerate(e2):
        twin.set_radiance(frame)
        out[f] = twin.render(spp, _frame_seed(seed, f))
    return out[0] if single else out


def shortcut_images(mono, factors) -> np.ndarray:
    """The spectral shortcut: mono radiance (..., H, W) times channel factors (C,) -> (..., H, W, C)."""
    k = np.asarray(factors, dtype=float)
    if k.ndim != 1 or not np.all(np.isfinite(k)):
        raise ValueError(f"factors of shape {k.shape}: must be (C,) and finite")
    return np.asarray(mono, dtype=np.float64)[..., None] * k


def compare_to_shortcut(reference, shortcut, centres_px, radius_px: float, *, channels=("r", "g", "b"),
                        min_share: float = 0.05) -> dict:
    """Per-channel difference between the spectral shortcut and the spectral reference.

    Parameters
    ----------
    reference, shortcut : (B, F, H, W, C) float
        B >= 1 independent renders (different seeds) of the same F frames: the reference
        (:func:`spectral_reference`) and the shortcut (:func:`shortcut_images`). Each side's mean over
        B is compared; with B >= 2 the Monte Carlo standard errors come from the spread over B.
    centres_px : (R, 2) float
        Rod disk centres (column, row), and ``radius_px`` their radius (:func:`mlsim.render.rod_disks_px`).
    channels : sequence of C str
    min_share : float
        A rod-frame counts in a channel when its reference sum is at least this share of the
        brightest rod's in that frame and channel (dim rods' relative differences are noise over nothing).

    Returns
    -------
    dict
        ``channels``; per channel (lists of C floats, percent, difference = shortcut / reference - 1):
        ``total_diff_pct`` over all pixels and frames and ``total_se_pct`` its standard error (NaN if
        B = 1); over the counted rod-frames ``rod_median_abs_diff_pct``, ``rod_max_abs_diff_pct``,
        ``rod_median_se_pct`` (the median standard error of a rod-frame's difference) and ``rod_frames``;
        ``frame_total_diff_pct`` (F lists of C).
    """
    from mlsim.render.optics import disk_masks

    ref = np.asarray(reference, dtype=np.float64)
    cut = np.asarray(shortcut, dtype=np.float64)
    if ref.ndim != 5 or cut.ndim != 5 or ref.shape[1:] != cut.shape[1:]:
        raise ValueError(f"reference {ref.shape} and shortcut {cut.shape}: must both be (B, F, H, W, C) with the same F, H, W, C")
    B, F, H, W, C = ref.shape
    if len(channels) != C:
        raise ValueError(f"{len(channels)} channel names for {C} channels")
    masks = disk_masks(H, W, centres_px, radius_px).reshape(len(centres_px), -1).astype(np.float64)  # (R, HW)

    def rods(x):  # (B, F, H, W, C) -> (B, F, R, C)
        return np.einsum("rp,bfpc->bfrc", masks, x.reshape(x.shape[0], F, H * W, C))

    def ratio_and_se(a, b):
        """Relative difference mean(a)/mean(b) - 1 over the batch axis 0, with its delta-method SE."""
        ma, mb = a.mean(axis=0), b.mean(axis=0)
        va = a.var(axis=0, ddof=1) / a.shape[0] if a.shape[0] > 1 else np.full_like(ma, np.nan)
        vb = b.var(axis=0, ddof=1) / b.shape[0] if b.shape[0] > 1 else np.full_like(mb, np.nan)
        with np.errstate(divide="ignore", invalid="ignore"):
            d = ma / mb - 1.0
            se = np.abs(ma / mb) * np.sqrt(va / ma**2 + vb / mb**2)
        return d, se

    total_d, total_se = ratio_and_se(cut.sum(axis=(1, 2, 3)), ref.sum(axis=(1, 2, 3)))  # (C,)
    frame_d, _ = ratio_and_se(cut.sum(axis=(2, 3)), ref.sum(axis=(2, 3)))  # (F, C)
    rod_cut, rod_ref = rods(cut), rods(ref)
    rod_d, rod_se = ratio_and_se(rod_cut, rod_ref)  # (F, R, C)
    mean_ref = rod_ref.mean(axis=0)
    keep = mean_ref >= min_share * mean_ref.max(axis=1, keepdims=True)
    keep &= mean_ref > 0
    med, worst, med_se, count = [], [], [], []
    for c in range(C):
        d, se = np.abs(rod_d[..., c][keep[..., c]]), rod_se[..., c][keep[..., c]]
        med.append(float(np.median(d)) * 100 if d.size else math.nan)
        worst.append(float(d.max()) * 100 if d.size else math.nan)
        med_se.append(float(np.median(se)) * 100 if se.size else math.nan)
        count.append(int(d.size))
    return {
        "channels": list(channels),
        "total_diff_pct": (total_d * 100).tolist(),
        "total_se_pct": (total_se * 100).tolist(),
        "rod_median_abs_diff_pct": med,
        "rod_max_abs_diff_pct": worst,
        "rod_median_se_pct": med_se,
        "rod_frames": count,
        "frame_total_diff_pct": (frame_d * 100).tolist(),
    }
