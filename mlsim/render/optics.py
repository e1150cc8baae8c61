"""The optical set-up under the rods: where the camera is, what it sees, and the spectral factors.

Geometry (SI inside, millimetres only where Mitsuba needs them, see :mod:`mlsim.render.sensor_scene`):
the base's bottom face is z = 0 and rests on the acrylic plate (z from -a to 0), the camera's lens
is ``camera.distance_mm`` below the plate on the axis of the array, looking up (+z) with +y up in
the scene. The renderer is a pinhole at the lens whose image plane sits at the thin lens's image
distance v = f (1 + m), so a pixel spans the same object patch as the lens of :mod:`mlsim.camera`
focused at the base; the camera module then applies the camera equation (f-number, pixel area,
lens transmittance) to the radiance the renderer returns.

Default lens (``camera.focal_length_mm`` unset): the focal length that images the sensing surface
plus 5 % on each side onto the crop, focused on the base's top face (the rods' roots) through air:
d = distance + acrylic + base thickness. The plate and the core make the surface look closer (their
apparent depth is thickness / n), which the 5 % margin absorbs.

Spectral shortcut: the interfaces are non-dispersive here (one refractive index per material), so
transport is the same at every wavelength and the mono render of a unit spectrum times
:func:`channel_factors` (emission spectrum x internal transmittances x camera QE, per channel)
gives the per-channel photon radiance the camera module expects. The Fresnel losses are traced
by the renderer, so the slabs' transmittances here are internal only (``fresnel_surfaces=0``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["View", "view_of", "camera_params", "ml_channel_factors", "channel_factors_of", "inner_path_transmittance_sds", "rod_disks_px", "VIEW_MARGIN", "disk_masks"]

#: Fraction of the surface's width added on each side of the default field of view.
VIEW_MARGIN = 0.05


@dataclass(frozen=True)
class View:
    """Pinhole camera of the renderer: lens at (0, 0, -lens_below_base_m), looking up.

    ``fov_x_deg`` is the full horizontal angle over ``width_px``; ``image_distance_m`` and
    ``pixel_pitch_m`` give the paraxial projection (:func:`rod_disks_px`)."""

    width_px: int
    height_px: int
    lens_below_base_m: float
    image_distance_m: float
    pixel_pitch_m: float

    @property
    def fov_x_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width_px * self.pixel_pitch_m / (2.0 * self.image_distance_m)))


def camera_params(scene):
    """:class:`mlsim.camera.CameraParams` of a scene, with the lens focused on the base's top face and,
    when ``camera.focal_length_mm`` is unset, the focal length that fits the surface (module docstring)."""
    from dataclasses import replace

    from mlsim.camera import CameraParams, focal_length_to_fit_m

    cam, s = scene.camera, scene.sensor
    distance_m = (cam.distance_mm + scene.optics.acrylic_thickness_mm + s.base.thickness_mm) * 1e-3
    params = CameraParams.from_scene(cam, object_distance_m=distance_m)
    if cam.focal_length_mm is not None:
        return params
    width_m = max(s.size_x_mm, s.size_y_mm * cam.width_px / cam.height_px) * 1e-3 * (1.0 + 2.0 * VIEW_MARGIN)
    return replace(params, focal_length_m=focal_length_to_fit_m(width_m, cam.width_px, params.effective_pixel_pitch_m, distance_m))


def view_of(scene) -> View:
    """The renderer's pinhole for a scene (same field of view as :func:`camera_params`)."""
    p = camera_params(scene)
    return View(
        width_px=p.width_px,
        height_px=p.height_px,
        lens_below_base_m=(scene.camera.distance_mm + scene.optics.acrylic_thickness_mm) * 1e-3,
        image_distance_m=p.image_distance_m,
        pixel_pitch_m=p.effective_pixel_pitch_m,
    )


def ml_channel_factors(scene) -> np.ndarray:
    """(3,) electrons per ZnS:Cu photon reaching the pixel, R, G, B (:func:`channel_factors_of`)."""
    from mlsim import spectra
    from mlsim.stage import memo

    # what channel_factors_of reads of the scene; integrating the spectra took 48 ms an episode
    key = ("ml_channel_factors", scene.content_hash(("sensor", "optics", "camera.sensitivity")))
    return memo(key, lambda: channel_factors_of(scene, spectra.zns_cu_emission_sd())).copy()


def channel_factors_of(scene, photon_sd) -> np.ndarray:
    """(3,) electrons per photon of spectrum ``photon_sd`` (shape) leaving the ML layer's inner face
    and reaching the pixel, R, G, B: spectrum x internal transmittance of the acrylic and of the
    clear core (half a rod plus the base below the layers, the mean path) x camera QE
    (``camera.sensitivity``)."""
    from mlsim import spectra

    return spectra.channel_factors(photon_sd, inner_path_transmittance_sds(scene), spectra.camera_sensitivity_msds(scene.camera.sensitivity))


def inner_path_transmittance_sds(scene) -> tuple:
    """The internal transmittances between the ML layer and the lens: the acrylic plate and the
    clear core over its mean path (half a rod plus the base below the layers). Fresnel losses are
    not in them: the renderer traces those."""
    from mlsim import spectra

    s = scene.sensor
    core_path_mm = s.base.thickness_mm - s.layers.absorber_mm - s.layers.ml_mm + 0.5 * s.rod.height_mm
    return (spectra.acrylic_transmittance_sd(scene.optics.acrylic_thickness_mm, fresnel_surfaces=0),
            spectra.elastomer_transmittance_sd(max(core_path_mm, 0.0)))


def rod_disks_px(scene) -> tuple[np.ndarray, float]:
    """Paraxial image of each rod's clear core where it meets the base: centres (R, 2) as (column,
    row) pixel coordinates (pixel centres at integers) and the radius in pixels.

    The apparent depth of a point at height z in the core is distance + a / n_acrylic + z / n_core
    (paraxial refraction at the two flat faces); the image of the rod opening at the base's top
    face under the layers is what the DLLM's disks see. Rows run along -y (row 0 sees +y, as the
    renderer's film does), columns along +x seen from below (mirrored: -x is on the right).
    """
    from fem.geometry import RodArray

    g = RodArray.from_sensor(scene.sensor)
    view = view_of(scene)
    z_m = g.base_thickness_m - g.core_depth_m
    depth_m = scene.camera.distance_mm * 1e-3 + scene.optics.acrylic_thickness_mm * 1e-3 / scene.optics.acrylic_refractive_index
    depth_m += z_m / scene.optics.elastomer_refractive_index
    scale_px = view.image_distance_m / depth_m / view.pixel_pitch_m  # pixels per metre in that plane
    c = g.centres_m
    col = (view.width_px - 1) / 2.0 - c[:, 0] * scale_px
    row = (view.height_px - 1) / 2.0 - c[:, 1] * scale_px
    radius_px = (g.rod_radius_m - g.core_depth_m) * scale_px
    return np.stack([col, row], axis=1), float(radius_px)


def disk_masks(height_px: int, width_px: int, centres_px, radius_px: float) -> np.ndarray:
    """(R, H, W) bool: pixels whose centre lies within radius_px of each centre (column, row)."""
    c = np.asarray(centres_px, dtype=float)
    out = np.zeros((len(c), height_px, width_px), dtype=bool)
    # each disk on its bounding box (a pixel off it by one is outside the disk): the whole frame per
    # disk cost 70 ms an episode on the 5 x 5 sensor, made twice per episode (the camera, the DLLM)
    for n, (x, y) in enumerate(c):
        if not np.isfinite(x + y + radius_px):  # no pixel is within a NaN distance
            continue
        r0, r1 = max(int(np.floor(y - radius_px)) - 1, 0), min(int(np.ceil(y + radius_px)) + 2, height_px)
        c0, c1 = max(int(np.floor(x - radius_px)) - 1, 0), min(int(np.ceil(x + radius_px)) + 2, width_px)
        if r0 >= r1 or c0 >= c1:
            continue
        rows, cols = np.mgrid[r0:r1, c0:c1]
        out[n, r0:r1, c0:c1] = (cols - x) ** 2 + (rows - y) ** 2 <= radius_px**2
    return out
