"""The calibration frame: the sensor without its absorbing layer under a white lamp (SPEC 1.1, 1.6).

The DLLM's hardware calibration (SPEC 1.6) finds the 25 rod disks in one frame of a copy of the
sensor that has no absorbing layer, lit from above by a 40 W white LED lamp. Here that copy is the
same sensor with ``absorber = "none"`` (same shape; the clear outer layer is left in place), and its
light is the ambient model of :mod:`mlsim.render.ambient` with the calibration lamp
(``[calibration]``) and no ML emission. The rods' tips and the base between them face the lamp and
glow; the rods' walls do not, so each rod shows as a bright disk (its tip, seen through the rod)
inside a dark ring (its walls) on a bright background.

Exposure: the frame is exposed as an auto-exposing camera would (:func:`auto_exposure_s`): the
exposure time, then the analog gain, are set so that the noiseless green level at the 99.5th
percentile of the pixels reaches ``calibration.target_level_dn8``; the level reached (lower when
both are at their limits) is reported.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from mlsim.render.calibration import noiseless_dn8

__all__ = ["CalibrationFrame", "calibration_frame", "auto_exposure_s", "write_calibration", "PERCENTILE", "MAX_AUTO_GAIN_DB"]

PERCENTILE = 99.5


@dataclass
class CalibrationFrame:
    """rgb (H, W, 3) uint8; radiance (H, W) photons s^-1 m^-2 sr^-1 of the lamp's light leaving the
    sensor (its own spectrum); exposure_s the auto exposure; info (lamp, levels)."""

    rgb: np.ndarray
    radiance: np.ndarray
    exposure_s: float
    info: dict = field(default_factory=dict)

    def save(self, path) -> None:
        np.savez(path, rgb=self.rgb, radiance=self.radiance, exposure_s=self.exposure_s, info=np.array(repr(self.info)))

    @classmethod
    def load(cls, path) -> "CalibrationFrame":
        import ast

        z = np.load(path)
        return cls(z["rgb"], z["radiance"], float(z["exposure_s"]), ast.literal_eval(str(z["info"])))


#: The most analog gain the auto exposure adds once the exposure is at the frame period (IMX415: 30 dB).
MAX_AUTO_GAIN_DB = 30.0


def auto_exposure_s(params, green_electrons_per_s, target_dn8: float, percentile: float = PERCENTILE) -> tuple[float, float, float]:
    """(exposure s, gain dB, reached noiseless 8-bit green level) putting the ``percentile`` of the
    green signal (electrons per second per pixel, (H, W)) at ``target_dn8``, as an auto-exposing
    camera would: the exposure first (up to the frame period), then analog gain (up to
    :data:`MAX_AUTO_GAIN_DB` above the scene's)."""
    rate = float(np.percentile(np.asarray(green_electrons_per_s, dtype=np.float64), percentile))
    if not rate > 0:
        raise ValueError("the calibration frame is black: the lamp does not reach the camera (check [calibration] and optics.absorber)")
    dn_per_e = params.effective_conversion_gain_dn_per_e * 10.0 ** (params.gain_db / 20.0)
    scale = 2.0 ** (params.adc_bits - 8)
    black8 = params.black_level_dn / scale
    if not target_dn8 > black8:
        raise ValueError(f"calibration.target_level_dn8 = {target_dn8:g} is at or below the black level ({black8:g}); raise it")
    needed_e = (target_dn8 - black8) * scale / dn_per_e  # electrons at the percentile
    exposure = min(needed_e / rate, 1.0 / params.fps)
    extra_db = min(max(20.0 * np.log10(needed_e / (rate * exposure)), 0.0), MAX_AUTO_GAIN_DB)
    gain_db = params.gain_db + extra_db
    return exposure, float(gain_db), noiseless_dn8(replace(params, gain_db=gain_db), rate * exposure)


def calibration_frame(scene, patches, sensor_scene, transport=None, raster=None) -> CalibrationFrame:
    """Render and expose the calibration frame of a scene (module docstring); ``transport`` is the
    sheet's transport matrix for the transport tier, with ``raster`` (a
    :class:`mlsim.render.direct_raster.DirectRaster`) the bounces' matrix of the deformed tier
    (else the frame is path-traced)."""
    from mlsim import render
    from mlsim.camera import Camera
    from mlsim.render import ambient
    from mlsim.render.optics import camera_params, channel_factors_of

    c = scene.calibration
    lamp_m = ambient.lamp_above_tips_m(scene, c.height_m)
    leak = ambient.leak_through_layers(scene, patches, sensor_scene, lamp=c.lamp, power_w=c.power_w, lamp_m=lamp_m, absorber="none",
                                       occlusion=scene.ambient.occlusion)
    spec = scene.fidelity.render
    tier = "path" if transport is None else ("deformed" if raster is not None else "transport")
    radiance = render.render_still(sensor_scene, render.radiance_of(leak.photons_per_s, patches.area_m2), tier,
                                   spp=spec.spp, seed=scene.seed ^ 0xCA11B, transport=transport, raster=raster)
    k = channel_factors_of(scene, leak.sd).astype(np.float32)
    params = camera_params(scene)
    per_s = params.electrons_per_radiance_m2_sr_s / params.exposure_s
    exposure, gain_db, level = auto_exposure_s(params, radiance * (k[1] * per_s), c.target_level_dn8)
    params = replace(params, exposure_s=exposure, gain_db=gain_db)
    rng = np.random.default_rng([scene.seed, 0xCA11B])
    rgb = Camera(params)(radiance[..., None] * k, rng, noise=scene.camera.noise)
    info = {"lamp": c.lamp, "power_w": c.power_w, "height_m": c.height_m, "radiant_power_w": leak.radiant_power_w,
            "exposure_s": exposure, "gain_db": gain_db, "green_level_dn8": level, "percentile": PERCENTILE, "tier": tier,
            "irradiance_on_top_w_m2": float(leak.irradiance_w_m2[patches.normals[:, 2] > 0.99].mean())}
    return CalibrationFrame(rgb, radiance.astype(np.float32), exposure, info)


def write_calibration(result: CalibrationFrame, out_dir: Path) -> list[Path]:
    """``calibration_frame.png`` (the frame the DLLM calibrates on) and ``calibration_frame.json``."""
    import json

    from mlsim.io import atomic_bytes
    from mlsim.render.output import write_png

    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    return [write_png(out_dir / "calibration_frame.png", result.rgb),
            atomic_bytes(out_dir / "calibration_frame.json", json.dumps(result.info, indent=2).encode())]
