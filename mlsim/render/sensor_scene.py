"""The Mitsuba scene of the sensor seen from below, and the one thin stateful wrapper around it.

What is in it (lengths in millimetres inside Mitsuba: its ray offsets scale with the coordinates'
magnitude, about 1e-4 of it, which would be a tenth of a millimetre in metres, more than the
layers):

- the emitting sheet: the ML layer's inner face (:func:`fem.geometry.emitting_surface`), faces
  turned so that the normals point into the clear core. BSDF ``diffuse`` with the ML layer's
  reflectance (``optics.ml_layer_reflectance``); an ``area`` emitter whose radiance is the mesh
  attribute ``vertex_emission``, linear over each face (so the flux of a vertex of area A and
  radiance L is pi L A, the patch's photon rate: :func:`radiance_of`);
- the core's bottom face, z = 0: a ``dielectric`` between the core (``optics.elastomer_refractive_index``,
  above) and the acrylic (``optics.acrylic_refractive_index``, below), the size of the base;
- the acrylic's bottom face, z = -a: a ``dielectric`` between the acrylic and air, twice the size
  of the base so that light leaving the base obliquely still exits;
- a pinhole camera at the lens (:mod:`mlsim.render.optics`), box pixel filter (a pixel is the mean
  radiance over its footprint), ``path`` integrator.

Left out, and why: the base's side walls and the acrylic's edges (light that reaches them leaves
the field of view in the real sensor too, so they are absorbing here); the absorber and what lies
outside the ML layer (no light reaches the core from there except ambient leakage, which
:mod:`mlsim.render.ambient` adds as its own emission component); dispersion (one index per
material, see the spectral shortcut in :mod:`mlsim.render.optics`).

Variant: ``llvm_ad_mono`` on the CPU (the CPU JIT variants need libLLVM 17+, the scalar variants
crash with a ``mesh_attribute`` emitter), ``cuda_ad_mono`` on an NVIDIA GPU (``device="cuda"``: the
same scene, traced by OptiX; :func:`resolve_device` picks CUDA where it starts). The renders are
mono: the spectrum is applied afterwards.

Spectral reference (``spectra=``, a :class:`mlsim.render.spectral.RenderSpectra`): the same scene in
``llvm_ad_spectral`` (``cuda_ad_spectral`` on the GPU), the sheet's radiance the emission spectrum times the per-vertex value and the
film a ``specfilm`` whose channels are the path's sensitivities, so that :meth:`SensorScene.render`
gives per-channel images directly (see :mod:`mlsim.render.spectral`). Mitsuba's variant is global
and its objects belong to the variant they were built in: every method sets its scene's variant
first, so mono and spectral scenes can be used in turn in one process.
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["VARIANT", "SPECTRAL_VARIANT", "DEVICES", "variant_for", "use_variant", "cuda_status", "variant_starts", "choose_device", "resolve_device",
           "SensorScene", "radiance_of"]

VARIANT = "llvm_ad_mono"
SPECTRAL_VARIANT = "llvm_ad_spectral"  # the spectral reference (mlsim.render.spectral)
#: where Mitsuba traces: the CPU (Dr.Jit's LLVM back-end) or an NVIDIA GPU (its CUDA back-end, OptiX)
DEVICES = ("cpu", "cuda")
_VARIANTS = {("cpu", False): VARIANT, ("cpu", True): SPECTRAL_VARIANT, ("cuda", False): "cuda_ad_mono", ("cuda", True): "cuda_ad_spectral"}


def variant_for(device: str = "cpu", spectral: bool = False) -> str:
    """The Mitsuba variant of the sensor scene on ``device`` ("cpu" or "cuda"), mono or spectral."""
    if device not in DEVICES:
        raise ValueError(f'render device "{device}": choose one of {", ".join(DEVICES)} (or "auto" in fidelity.render.device)')
    return _VARIANTS[(device, bool(spectral))]


def use_variant(variant: str = VARIANT):
    """Import Mitsuba in ``variant`` (default the renderer's CPU mono); a clear error when the JIT
    back-end is missing."""
    if variant not in _VARIANTS.values():
        raise ValueError(f'Mitsuba variant "{variant}": choose one of {", ".join(_VARIANTS.values())}')
    try:
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - an install problem
        raise ImportError(f"mitsuba is not installed ({exc}); run `make venv`") from None
    if mi.variant() != variant:
        try:
            mi.set_variant(variant)
        except Exception as exc:  # pragma: no cover - a machine problem
            fix = ("It needs an NVIDIA GPU and driver (nvidia-smi), and Mitsuba's CUDA variants; set fidelity.render.device = "
                   '"cpu" or "auto" to render on the CPU' if variant.startswith("cuda") else
                   "It needs libLLVM 17 or newer: `apt-get install -y libllvm19`, or set DRJIT_LIBLLVM_PATH to a libLLVM.so (17+)")
            raise RuntimeError(f"Mitsuba variant {variant} failed to start ({exc}). {fix}") from None
    return mi


@functools.cache
def cuda_status() -> tuple[bool, str]:
    """(True, "Mitsuba cuda_ad_mono started") when Mitsuba's ``cuda_ad_mono`` starts here and runs a
    kernel, else (False, why not). Probed once per process (it costs a CUDA context, about a second).
    Where the machine has no CUDA driver library at all, that is the answer, without importing
    Mitsuba (0.4 s of each dataset worker's CPU)."""
    if not _cuda_driver_loads():
        return False, "no CUDA driver on this machine (libcuda.so.1 / nvcuda.dll did not load)"
    try:
        import drjit as dr
        import mitsuba as mi
    except ImportError as exc:  # pragma: no cover - an install problem
        return False, f"mitsuba is not installed ({exc})"
    if "cuda_ad_mono" not in mi.variants():
        return False, "this Mitsuba build has no cuda_ad_mono variant"
    if not dr.has_backend(dr.JitBackend.CUDA):
        return False, "Dr.Jit found no CUDA driver or GPU (libcuda.so)"
    return variant_starts("cuda_ad_mono")


def _cuda_driver_loads() -> bool:
    """Whether the NVIDIA driver's library loads here (what Dr.Jit's CUDA back-end opens first)."""
    import ctypes
    import sys

    if sys.platform == "darwin":
        return False
    try:
        ctypes.CDLL("nvcuda.dll" if sys.platform == "win32" else "libcuda.so.1")
    except OSError:
        return False
    return True


def variant_starts(variant: str) -> tuple[bool, str]:
    """(True, "Mitsuba <variant> started") when Mitsuba's ``variant`` starts here and runs a kernel,
    else (False, why not); Mitsuba's current variant is left as it was."""
    import drjit as dr
    import mitsuba as mi

    before = mi.variant()
    try:
        mi.set_variant(variant)
        total = float(np.array(dr.sum(mi.Float([1.0, 2.0]))).ravel()[0])  # one kernel through the back-end
        if total != 3.0:  # pragma: no cover - a broken driver
            return False, f"a test sum in {variant} gave {total}, not 3"
        return True, f"Mitsuba {variant} started"
    except Exception as exc:
        return False, f"Mitsuba's {variant} failed to start ({type(exc).__name__}: {exc})"
    finally:
        if before and before != mi.variant():
            mi.set_variant(before)


def choose_device(requested: str, field: str, status) -> tuple[str, str]:
    """The device ("cpu" or "cuda") a ``requested`` setting ("auto", "cpu", "cuda") of the scene or spec field
    ``field`` gives, and why (for the run log): ``"auto"`` takes CUDA where ``status() -> (ok, why)`` says it
    starts, else the CPU; ``"cuda"`` raises (with the reason and the fix) where it does not. The render's
    (:func:`resolve_device`) and the dataset's batched chain's (:func:`mlsim.dataset.batched.resolve_device`)."""
    if requested not in ("auto",) + DEVICES:
        raise ValueError(f'{field} = "{requested}": choose "auto", "cpu" or "cuda"')
    if requested == "cpu":
        return "cpu", f"{field} = cpu"
    ok, why = status()
    if ok:
        return "cuda", f"{field} = {requested}: {why}"
    if requested == "cuda":
        raise RuntimeError(f'{field} = "cuda", but {why}: set {field} = "auto" (CUDA where it is, else the CPU) or {field} = "cpu"')
    return "cpu", f"{field} = auto: no GPU ({why})"


def resolve_device(requested: str = "auto") -> tuple[str, str]:
    """The device a render runs on, and why (:func:`choose_device` by Mitsuba's :func:`cuda_status`)."""
    return choose_device(requested, "fidelity.render.device", cuda_status)


def radiance_of(photons_per_s, area_m2) -> np.ndarray:
    """Lambertian radiance (photons s^-1 m^-2 sr^-1) of patches emitting ``photons_per_s`` from
    ``area_m2`` each: L = Phi / (pi A). Works on (..., N) arrays."""
    return np.asarray(photons_per_s, dtype=float) / (np.pi * np.asarray(area_m2, dtype=float))


class SensorScene:
    """A Mitsuba scene of one emitting sheet behind the core/acrylic/air interfaces.

    sheet_vertices_m (N, 3) and sheet_faces (K, 3) with normals out of the core (as
    :func:`fem.geometry.emitting_surface` gives them; turned here); ``view``: a
    :class:`mlsim.render.optics.View`. Emission and vertex positions change in place
    (:meth:`set_radiance`, :meth:`set_vertices`) without recompiling anything.

    ``spectra`` (a :class:`mlsim.render.spectral.RenderSpectra`, optional): build the scene in
    ``llvm_ad_spectral`` with the emitter radiance spectrum(lambda) x per-vertex value and a film of
    one channel per sensitivity curve; :meth:`render` then returns (H, W, C). ``options`` holds the
    keyword settings the scene was built with (:func:`mlsim.render.spectral.spectral_twin` reuses them).

    ``device``: ``"cpu"`` (``llvm_ad_*``) or ``"cuda"`` (``cuda_ad_*``, an NVIDIA GPU; see
    :func:`resolve_device` for ``"auto"``). The scene, the seeds and the samples are the same; the
    images agree within Monte Carlo error (``tests/test_render_cuda.py``), not bit for bit.
    """

    def __init__(self, sheet_vertices_m, sheet_faces, view, *, core_ior: float = 1.41, acrylic_ior: float = 1.49,
                 acrylic_thickness_m: float = 3e-3, base_half_size_m: float | None = None, reflectance: float = 0.5,
                 max_depth: int = 12, rr_depth: int = 5, spectra=None, device: str = "cpu"):
        if spectra is not None:
            from mlsim.render.spectral import RenderSpectra

            if not isinstance(spectra, RenderSpectra):
                raise TypeError(f"spectra is a {type(spectra).__name__}: must be a mlsim.render.spectral.RenderSpectra "
                                "(see mlsim.render.spectral.ml_render_spectra)")
        self.variant = variant_for(device, spectra is not None)
        self.device = device
        self.spectra = spectra
        V = np.asarray(sheet_vertices_m, dtype=float)
        F = np.asarray(sheet_faces)
        if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) == 0:
            raise ValueError(f"sheet of {V.shape} vertices and {F.shape} faces: must be (N, 3) and (K >= 1, 3)")
        if F.min() < 0 or F.max() >= len(V):
            raise ValueError(f"sheet faces index vertices 0..{F.max()}, but there are {len(V)} vertices")
        if not 0.0 <= reflectance < 1.0:
            raise ValueError(f"reflectance = {reflectance}: must be in [0, 1)")
        self.view = view
        self.n_vertices = len(V)
        self.faces = F[:, ::-1].astype(np.uint32)  # normals into the core: the emitter's front side
        half_m = base_half_size_m if base_half_size_m is not None else max(np.abs(V[:, :2]).max(), 1e-4)
        self.options = {"core_ior": float(core_ior), "acrylic_ior": float(acrylic_ior), "acrylic_thickness_m": float(acrylic_thickness_m),
                        "base_half_size_m": float(half_m), "reflectance": float(reflectance), "max_depth": int(max_depth),
                        "rr_depth": int(rr_depth), "device": device}
        self.vertices_mm = (V * 1e3).astype(np.float32)
        self.rest_vertices_m = V.copy()  # the sheet as built (set_vertices moves it)
        self.max_depth, self.rr_depth = int(max_depth), int(rr_depth)
        # Mitsuba's objects are made when first used (:meth:`_mitsuba`): the deformed tier with its matrix and
        # rasteriser cached reads only the sheet's geometry, and a dataset worker then never imports Mitsuba
        # (0.6 s of its CPU) nor builds the scene (0.15 s)
        self._mi_scene = None

    def _mitsuba(self):
        """Mitsuba in this scene's variant, the scene built on first call (the sheet where it is now)."""
        mi = use_variant(self.variant)
        if self._mi_scene is not None:
            return mi
        o, view = self.options, self.view
        props = mi.Properties()
        props["bsdf"] = mi.load_dict({"type": "diffuse", "reflectance": {"type": "spectrum", "value": o["reflectance"]}})
        if self.spectra is None:
            radiance = {"type": "mesh_attribute", "name": "vertex_emission"}
            film = {"type": "hdrfilm", "width": int(view.width_px), "height": int(view.height_px), "rfilter": {"type": "box"},
                    "pixel_format": "luminance"}
        else:
            from mlsim.render import spectral

            radiance = spectral.radiance_texture(self.spectra, "vertex_emission")
            film = spectral.film_dict(self.spectra, int(view.width_px), int(view.height_px))
        props["emitter"] = mi.load_dict({"type": "area", "radiance": radiance})
        self._mesh = mi.Mesh("ml_sheet", self.n_vertices, len(self.faces), props=props, has_vertex_normals=False)
        self._params = mi.traverse(self._mesh)
        self._params["faces"] = mi.UInt32(self.faces.ravel())
        self._params["vertex_positions"] = mi.Float(self.vertices_mm.ravel())
        self._mesh.add_attribute("vertex_emission", 1, mi.Float(np.zeros(self.n_vertices, np.float32)))
        self._params.update()
        self._params = mi.traverse(self._mesh)  # now with the attribute
        half_mm = o["base_half_size_m"] * 1e3

        def interface(z_mm, n_inside, n_outside, half):
            # A rectangle's normal is +z; turned over it faces the camera (-z): the side opposite the
            # normal is the dielectric's interior, the medium above.
            to_world = mi.ScalarTransform4f().translate([0.0, 0.0, z_mm]).scale([half, half, 1.0]).rotate([1, 0, 0], 180)
            return {"type": "rectangle", "to_world": to_world, "bsdf": {"type": "dielectric", "int_ior": n_inside, "ext_ior": n_outside}}

        a_mm = o["acrylic_thickness_m"] * 1e3
        lens_mm = view.lens_below_base_m * 1e3
        self._mi_scene = mi.load_dict({
            "type": "scene",
            "integrator": {"type": "path", "max_depth": self.max_depth, "rr_depth": self.rr_depth},
            "sensor": {
                "type": "perspective",
                "fov": view.fov_x_deg,
                "fov_axis": "x",
                "near_clip": 1e-2,
                "far_clip": 1e4,
                "to_world": mi.ScalarTransform4f().look_at(origin=[0.0, 0.0, -lens_mm], target=[0.0, 0.0, 0.0], up=[0.0, 1.0, 0.0]),
                "film": film,
                "sampler": {"type": "independent", "sample_count": 1},
            },
            "sheet": self._mesh,
            "core_bottom": interface(0.0, o["core_ior"], o["acrylic_ior"], half_mm),
            "acrylic_bottom": interface(-a_mm, o["acrylic_ior"], 1.0, 2.0 * half_mm),
        })
        return mi

    @property
    def scene(self):
        """The Mitsuba scene (made on first use)."""
        self._mitsuba()
        return self._mi_scene

    # -- the two things that change per frame ----------------------------------------------------
    def set_radiance(self, radiance) -> None:
        """Per-vertex radiance (N,), photons s^-1 m^-2 sr^-1 (see :func:`radiance_of`); in a spectral
        scene the spectral radiance is this times the emission spectrum (1/nm, unit integral)."""
        mi = self._mitsuba()
        r = np.asarray(radiance, dtype=np.float32)
        if r.shape != (self.n_vertices,):
            raise ValueError(f"radiance of shape {r.shape}: must be ({self.n_vertices},), one value per sheet vertex")
        if not np.all(np.isfinite(r)) or r.min() < 0:
            raise ValueError("radiance must be finite and >= 0")
        self._params["vertex_emission"] = mi.Float(r)
        self._params.update()

    def set_vertices(self, vertices_m) -> None:
        """Move the sheet's vertices (N, 3) m (the deformed ML layer; the BVH is rebuilt)."""
        mi = self._mitsuba()
        v = (np.asarray(vertices_m, dtype=float) * 1e3).astype(np.float32)
        if v.shape != (self.n_vertices, 3) or not np.all(np.isfinite(v)):
            raise ValueError(f"vertices of shape {v.shape}: must be finite, ({self.n_vertices}, 3)")
        self.vertices_mm = v
        # Through the scene's parameters, not the mesh's: only the scene's update rebuilds its BVH.
        # Updated through the mesh alone, the triangles move but the BVH keeps their old boxes, and
        # rays miss whatever left its box (a 20 um shift of the sheet lost 23 % of a rod's light).
        scene_params = mi.traverse(self.scene)
        scene_params["sheet.vertex_positions"] = mi.Float(v.ravel())
        scene_params.update()

    def render(self, spp: int, seed: int) -> np.ndarray:
        """Radiance image (H, W) float32 with the current emission: Mitsuba's ``path`` integrator.

        A spectral scene gives (H, W, C): per channel c, the integral over wavelength of the spectral
        radiance at the lens times the channel's sensitivity (:mod:`mlsim.render.spectral`)."""
        mi = self._mitsuba()
        img = np.array(mi.render(self.scene, spp=int(spp), seed=int(seed) & 0xFFFFFFFF), dtype=np.float32)
        return img[:, :, 0] if self.spectra is None else img
