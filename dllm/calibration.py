"""DLLM hardware calibration: the taxels' disks from one calibration frame (SPEC 1.6).

Procedure [Mavig]_ (SPEC 1.6): grey-scale the calibration frame (the sensor without its absorbing
layer under a white lamp, :mod:`mlsim.render.calibration_frame`), Gaussian-blur it, find the disk
outlines with OpenCV's Hough circle transform, sort them by their centres (row-major: rows from the
top of the image, each row from the left), and keep the centres c_n and the mean radius R. The
taxel n is the disk of radius R at c_n.

Hough parameters (not given in the paper): chosen from the expected grid, so that they work on the
rendered frames and on real frames of this sensor: a pitch p estimated as the image's shorter side
over the grid's longer side (times 0.9 for the margin around the array), circles at least 0.6 p
apart with radii from 0.12 p to 0.45 p, Canny's upper threshold 60 and an accumulator threshold 20.
Any of them can be given instead.

References
----------
.. [Mavig] The MAVIG sensor's paper, as summarised in SPEC 1.6 (``../shared/SPEC.md``).
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["Calibration", "CalibrationError", "calibrate", "grey", "HoughParams", "hough_params_for"]


class CalibrationError(ValueError):
    """The calibration frame did not give the expected disks; ``found`` holds what Hough found and
    ``debug_image`` the overlay written to disk (or None)."""

    def __init__(self, message: str, found: np.ndarray | None = None, debug_image: Path | None = None):
        super().__init__(message)
        self.found = found
        self.debug_image = debug_image


@dataclass(frozen=True)
class HoughParams:
    """cv2.HoughCircles' parameters (pixels) and the blur before it."""

    blur_sigma_px: float
    min_dist_px: float
    min_radius_px: int
    max_radius_px: int
    canny_high: float = 60.0
    accumulator: float = 20.0


def hough_params_for(shape_hw, rows: int, cols: int, blur_sigma_px: float = 2.0, expected=None) -> HoughParams:
    """The module's defaults for an image of ``shape_hw`` holding a ``rows`` x ``cols`` grid; with
    ``expected`` = (centres (N, 2), radius) px of the disks (e.g. the optics' paraxial image,
    :func:`mlsim.render.rod_disks_px`), circles 0.6 pitches apart with radii 0.6 to 1.6 times it."""
    if expected is None:
        pitch = 0.9 * min(shape_hw) / max(rows, cols)
        return HoughParams(float(blur_sigma_px), 0.6 * pitch, max(int(0.12 * pitch), 1), max(int(0.45 * pitch), 2))
    centres, radius = np.asarray(expected[0], dtype=float), float(expected[1])
    if len(centres) > 1:
        d = np.linalg.norm(centres[:, None] - centres[None], axis=2)
        pitch = float(d[d > 0].min())
    else:
        pitch = min(shape_hw)
    return HoughParams(float(blur_sigma_px), 0.6 * pitch, max(int(0.6 * radius), 1), max(int(np.ceil(1.6 * radius)), 2))


@dataclass(frozen=True)
class Calibration:
    """The taxels: centres (N, 2) as (column, row) pixel coordinates, row-major; one radius; the
    frame's shape (H, W) it belongs to."""

    centres_px: np.ndarray
    radius_px: float
    shape_hw: tuple[int, int]

    @property
    def n_taxels(self) -> int:
        return len(self.centres_px)

    def masks(self) -> np.ndarray:
        """(N, H, W) bool: the pixels whose centre lies within R of c_n (the areas A_n)."""
        from mlsim.render.optics import disk_masks  # the camera stage's rod disks, the same rule

        return disk_masks(self.shape_hw[0], self.shape_hw[1], self.centres_px, self.radius_px)

    def save(self, path) -> Path:
        """A small JSON file (centres, radius, frame shape)."""
        path = Path(path)
        path.write_text(json.dumps({"centres_px": self.centres_px.tolist(), "radius_px": self.radius_px,
                                    "shape_hw": list(self.shape_hw)}, indent=1))
        return path

    @classmethod
    def load(cls, path) -> "Calibration":
        d = json.loads(Path(path).read_text())
        return cls(np.asarray(d["centres_px"], dtype=float), float(d["radius_px"]), tuple(int(v) for v in d["shape_hw"]))


def grey(frame) -> np.ndarray:
    """(H, W) uint8 grey level of an (H, W, 3) RGB or (H, W) uint8 frame: OpenCV's fixed-point
    Y = (9798 R + 19235 G + 3735 B + 2^14) >> 15 (0.299, 0.587, 0.114 in 15 bits), which
    :func:`dllm.batched.rgb_to_grey` reproduces bit for bit, so every path sees the same values."""
    import cv2

    f = _check_frame(frame, "frame")
    return f if f.ndim == 2 else cv2.cvtColor(f, cv2.COLOR_RGB2GRAY)


def _check_frame(frame, name: str) -> np.ndarray:
    f = np.asarray(frame)
    if f.dtype != np.uint8:
        extra = " (NaN values)" if np.issubdtype(f.dtype, np.floating) and np.isnan(f).any() else ""
        raise ValueError(f"{name} has dtype {f.dtype}{extra}: the detector reads 8-bit camera frames (uint8); "
                         "convert with np.clip(x, 0, 255).astype(np.uint8)")
    if not (f.ndim == 2 or (f.ndim == 3 and f.shape[2] == 3)) or min(f.shape[:2]) < 8:
        raise ValueError(f"{name} has shape {f.shape}: must be (H, W, 3) RGB or (H, W) grey, at least 8 x 8")
    return np.ascontiguousarray(f)


def _row_major(centres: np.ndarray, rows: int, cols: int) -> np.ndarray:
    """Sort N = rows x cols centres into rows (by y) and, within each, by x."""
    by_y = centres[np.argsort(centres[:, 1], kind="stable")]
    out = [row[np.argsort(row[:, 0], kind="stable")] for row in by_y.reshape(rows, cols, 2)]
    return np.concatenate(out)


def _overlay(g: np.ndarray, found, path: Path) -> Path:
    import cv2

    img = cv2.cvtColor(g, cv2.COLOR_GRAY2BGR)
    for x, y, r in ([] if found is None else found):
        cv2.circle(img, (int(round(x)), int(round(y))), int(round(r)), (0, 0, 255), 1)
        cv2.circle(img, (int(round(x)), int(round(y))), 1, (0, 255, 0), -1)
    path.parent.mkdir(parents=True, exist_ok=True)
    cv2.imwrite(str(path), img)
    return path


def calibrate(frame, rows: int = 5, cols: int = 5, params: HoughParams | None = None, debug_path=None) -> Calibration:
    """The DLLM calibration P = (C, R) of a calibration frame (module docstring).

    Parameters
    ----------
    frame : (H, W, 3) RGB or (H, W) uint8
    rows, cols : int
        The taxel grid; exactly rows x cols circles must be found.
    params : HoughParams, optional
        Default :func:`hough_params_for` the frame and grid.
    debug_path : path, optional
        Where the overlay of the circles found is written when the count is wrong (default: not
        written); it is written on success too when given.

    Raises
    ------
    CalibrationError
        When Hough finds no circles or a number other than rows x cols (the message gives the count
        and the overlay's path).
    """
    import cv2

    g = grey(frame)
    p = params or hough_params_for(g.shape, rows, cols)
    blurred = cv2.GaussianBlur(g, (0, 0), p.blur_sigma_px)
    found = cv2.HoughCircles(blurred, cv2.HOUGH_GRADIENT, dp=1, minDist=p.min_dist_px, param1=p.canny_high, param2=p.accumulator,
                             minRadius=p.min_radius_px, maxRadius=p.max_radius_px)
    found = None if found is None else found[0].astype(float)
    n = 0 if found is None else len(found)
    overlay = _overlay(g, found, Path(debug_path)) if debug_path is not None else None
    if n != rows * cols:
        what = "no circles" if n == 0 else f"{n} circles"
        raise CalibrationError(
            f"calibration frame: Hough found {what}, expected {rows} x {cols} = {rows * cols}"
            + (f" (overlay: {overlay})" if overlay else " (pass debug_path= to see them)")
            + "; check that the frame is the sensor without its absorber under a lamp, or adjust the HoughParams", found, overlay)
    centres = _row_major(found[:, :2], rows, cols)
    return Calibration(centres, float(found[:, 2].mean()), (int(g.shape[0]), int(g.shape[1])))
