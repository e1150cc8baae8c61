"""The camera's view of a real sensor from its calibration photo: where the rods' images are, fitted
to the rods' known layout (``mlsim calibrate``'s geometric part, issue 41).

Model. The paraxial image of rod r's opening (:func:`mlsim.render.rod_disks_px`) is a similarity
transform of its centre (x_r, y_r) in the sensor (m): seen from below, mirrored,

    col_r = t_col + a u_r - b v_r,    row_r = t_row + b u_r + a v_r,    (u_r, v_r) = (-x_r, -y_r),

with a = s cos(theta), b = s sin(theta): s the scale (px per m in the plane of the rod openings),
theta the camera's roll about its axis, (t_col, t_row) where the array's centre images (its lateral
offset). The four are linear: least squares over the 2 N centres that Hough found (the DLLM's
calibration, SPEC 1.6), with the covariance sigma^2 (J^T J)^-1, sigma^2 = RSS / (2 N - 4) (the
residuals' own scatter: Hough's half-pixel accumulator grid and the lens's departure from the
paraxial model, Gauss-Markov).

What the scale determines: s = v / (d_app p), the image distance v over the apparent depth of the
rod openings times the pixel pitch. With the scene's lens-to-plate distance taken as known, s fixes the
focal length (solved on :func:`mlsim.render.rod_disks_px` itself, so the scene that the overlay
writes reproduces the fitted scale); distance and focal length are not separable from one photo
(the same magnification), so the distance is left at the scene's value, and said so. The roll and
the lateral offset are measured and reported, but the scene has no field for them (the camera sits
on the array's axis): the overlay leaves them out, and says so. The mean radius of the disks is
reported beside the radius the optics predict.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["ViewFit", "fit_similarity", "fit_view", "scale_px_per_m"]


@dataclass(frozen=True)
class ViewFit:
    """The fitted view: scale_px_per_m, roll_deg, offset_px (col, row) of the array's centre from the
    image's centre, each with its standard uncertainty (``*_sigma``); rms_residual_px and the
    per-rod residuals (N, 2) px; focal_length_mm that reproduces the scale in the scene (with its
    sigma), the radius measured and predicted (px)."""

    scale_px_per_m: float
    scale_sigma: float
    roll_deg: float
    roll_sigma_deg: float
    offset_px: tuple[float, float]
    offset_sigma_px: float
    rms_residual_px: float
    residuals_px: np.ndarray
    focal_length_mm: float
    focal_length_sigma_mm: float
    radius_px: float
    predicted_radius_px: float

    def as_dict(self) -> dict:
        return {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in self.__dict__.items()}


def fit_similarity(model_xy, image_px) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least squares of image = t + [[a, -b], [b, a]] model (module docstring).

    model_xy: (N, 2) the (u, v) model coordinates; image_px: (N, 2) (col, row) px; N >= 3.
    Returns (p = (a, b, t_col, t_row), covariance (4, 4), residuals (N, 2) px)."""
    m, c = np.asarray(model_xy, float), np.asarray(image_px, float)
    n = len(m)
    if n < 3 or m.shape != c.shape:
        raise ValueError(f"fit_similarity: {n} points of shapes {m.shape}, {c.shape}: need N >= 3 matching (N, 2) arrays")
    J = np.zeros((2 * n, 4))
    J[0::2] = np.column_stack([m[:, 0], -m[:, 1], np.ones(n), np.zeros(n)])
    J[1::2] = np.column_stack([m[:, 1], m[:, 0], np.zeros(n), np.ones(n)])
    y = c.reshape(-1)
    p, *_ = np.linalg.lstsq(J, y, rcond=None)
    r = y - J @ p
    sigma2 = float(r @ r) / (2 * n - 4) if n > 2 else 0.0
    return p, sigma2 * np.linalg.inv(J.T @ J), r.reshape(n, 2)


def scale_px_per_m(scene) -> float:
    """The paraxial scale of :func:`mlsim.render.rod_disks_px` (px per m of the rod openings' plane)."""
    from fem.geometry import RodArray
    from mlsim.render import rod_disks_px

    g = RodArray.from_sensor(scene.sensor)
    centres, _ = rod_disks_px(scene)
    p, _, _ = fit_similarity(-g.centres_m[:, :2], centres)
    return float(np.hypot(p[0], p[1]))


def fit_view(centres_px, radius_px: float, scene) -> ViewFit:
    """Fit the view (module docstring) to a calibration's centres (N, 2) (row-major taxels, as
    :func:`dllm.calibration.calibrate` gives them) on the sensor of ``scene`` (its rods' layout, its
    camera distance and image size)."""
    from scipy.optimize import brentq

    from fem.geometry import RodArray
    from mlsim.render import rod_disks_px

    g = RodArray.from_sensor(scene.sensor)
    centres = np.asarray(centres_px, float)
    expected, _ = rod_disks_px(scene)
    if len(centres) != g.n_rods:
        raise ValueError(f"{len(centres)} centres for a sensor of {g.n_rods} rods")
    # taxels are row-major in the image; match each to its rod by the nearest paraxial image after
    # removing the scale (the scene's lens may be far off the real one)
    norm = lambda c: (c - c.mean(axis=0)) / np.ptp(c, axis=0).max()  # noqa: E731
    rod = np.linalg.norm(norm(centres)[:, None] - norm(expected)[None], axis=2).argmin(axis=1)
    if len(set(rod.tolist())) != g.n_rods:
        raise ValueError("the disks do not match the rods' layout one to one (is the photo of this sensor?)")
    p, cov, res = fit_similarity(-g.centres_m[rod, :2], centres)
    a, b = p[0], p[1]
    s = float(np.hypot(a, b))
    grad_s = np.array([a, b]) / s
    scale_sigma = float(np.sqrt(grad_s @ cov[:2, :2] @ grad_s))
    grad_t = np.array([-b, a]) / s**2
    roll_sigma = float(np.degrees(np.sqrt(grad_t @ cov[:2, :2] @ grad_t)))
    centre = np.array([(scene.camera.width_px - 1) / 2.0, (scene.camera.height_px - 1) / 2.0])

    def scale_at(f_mm: float) -> float:
        return scale_px_per_m(scene.with_values({"camera.focal_length_mm": f_mm}))

    # the scale grows with the focal length (magnification): bracket the root around the scene's lens
    from mlsim.render.optics import camera_params

    f0 = camera_params(scene).focal_length_m * 1e3
    lo, hi = f0 / 4.0, f0 * 4.0
    if not (scale_at(lo) < s < scale_at(hi)):
        raise ValueError(f"the fitted scale {s:.4g} px/m needs a focal length outside {lo:.3g}-{hi:.3g} mm: is the photo of this sensor?")
    f = brentq(lambda x: scale_at(x) - s, lo, hi, xtol=1e-9)
    dsdf = (scale_at(f * 1.001) - scale_at(f * 0.999)) / (0.002 * f)
    predicted_radius = rod_disks_px(scene.with_values({"camera.focal_length_mm": f}))[1]
    return ViewFit(s, scale_sigma, float(np.degrees(np.arctan2(b, a))), roll_sigma, (float(p[2] - centre[0]), float(p[3] - centre[1])),
                   float(np.sqrt(max(cov[2, 2], cov[3, 3]))), float(np.sqrt(np.mean(np.sum(res**2, axis=1)))), res,
                   float(f), float(scale_sigma / abs(dsdf)), float(radius_px), float(predicted_radius))
