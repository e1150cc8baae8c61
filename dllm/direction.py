"""The DLLM's push direction (SPEC 1.5): the direction a rod pushes the sensor, read from the taxels.

The study that runs it over applied directions through the pipeline (``mlsim direction``) is
:mod:`mlsim.studies.direction`; this module is its physics, pure functions of the DLLM's features.
Each taxel that fires in an event frame gives one measured direction: its light's offset omega
(:mod:`dllm.features`, image axes) turned into the sensor's axes. The camera looks up through the
base, so the image is the sensor seen from below: image +x is sensor -x and image up is sensor +y,
hence theta_measured = 180 deg - omega.

Sign convention: the DLLM reports where the probe comes from, the approach bearing theta + 180 deg,
and the error is the wrapped difference to it. Why, from the physics the chain simulates: the
light follows the *rise* of the von Mises stress (:mod:`mlsim.emission.detrapping`). A probe that
presses a rod's tip and drags it bends the rod like a beam clamped at its base and guided at its
tip, so the bending adds compression to the press's on the tip's trailing side and on the base's
leading side (the curvature changes sign along the rod), and there the stress rises. The camera
sees the tip's inner face face-on through the clear core and the walls edge-on, so the tip's
trailing-side light dominates the disk's centroid. Measured on ``scenes/direction_test.toml`` at
0 and 90 deg (push frames, 2 mm mesh): the pushed rod's emission centroid sits 1.1-1.2 mm behind
the rod axis on the tip (a third of its light) and 0.6-1.8 mm ahead near the base (two fifths);
its DLLM direction (1.5 mm mesh, the deformed render tier) is within 5 deg of theta + 180 over the
full circle (mean absolute error 2.0 deg, 24 directions; 1.4 deg over 0-90). SPEC 1.5 calls the applied angle the
"approach angle", which reads as the bearing the probe approaches from. The sign belongs to this
contact, the probe's end pressed on the tip and dragged: a probe that runs into rods' sides (the
tiny scene's sphere sliding from between four rods) leaves their light roughly on the side it moves
to, and the study's table then shows errors near 180 deg.

The episode's measured direction is the circular mean, weighted by H l (bright, clearly offset
taxels count most), over the *pushed taxels* in the *push frames*: the event frames whose exposure
overlaps the slide segment (the press and the lift have no direction: there the pushed rod's offset
is the mesh's asymmetry, a fraction of a pixel) and the taxels of the rods that carry at least half
the largest rod's contact force during them (the rods the probe pushes; a neighbour that glows from
the base's bending, or that the probe's edge reaches late, has a direction of its own). The mean
over every firing taxel of every event frame is reported beside it (``measured_all_deg``).
"""

from __future__ import annotations

import numpy as np

__all__ = ["sensor_angle_deg", "approach_deg", "episode_direction", "push_frames", "pushed_taxels", "wrap_deg", "PUSHED_FORCE_SHARE",
           "SIGN_CONVENTION"]

#: what the DLLM's direction is compared with (the module docstring gives the physics)
SIGN_CONVENTION = "the DLLM reports the bearing the probe comes from: approach_deg = applied_deg (the slide's direction) + 180"

#: a rod counts as pushed when its contact force during the push frames reaches this share of the
#: largest rod's (the rods the probe pushes, not a neighbour its edge grazes)
PUSHED_FORCE_SHARE = 0.5


def wrap_deg(a):
    """Angles to (-180, 180]."""
    return 180.0 - (180.0 - np.asarray(a, dtype=float)) % 360.0


def sensor_angle_deg(omega_image_deg):
    """The DLLM's image angle (from image +x towards image up) in the sensor's axes seen from above:
    180 - omega (the camera sees the sensor from below, mirrored), in [0, 360)."""
    return (180.0 - np.asarray(omega_image_deg, dtype=float)) % 360.0


def approach_deg(applied_deg):
    """The bearing the probe comes from, in [0, 360), for a probe moving towards ``applied_deg``: what
    the DLLM reports (the module docstring's sign convention)."""
    return (np.asarray(applied_deg, dtype=float) + 180.0) % 360.0


def episode_direction(features, events, taxels=None) -> tuple[float, np.ndarray, np.ndarray]:
    """(the H l-weighted circular mean direction in sensor degrees, and the per-sample directions
    and weights) over the firing taxels (all, or the indices ``taxels``) of the event frames
    (``events`` (T,) bool); NaN when nothing fired."""
    f = np.asarray(features)[np.asarray(events, bool)]
    if taxels is not None:
        f = f[:, np.asarray(taxels, dtype=int)]
    fired = f[..., 0] > 0
    H, l, omega = f[..., 0][fired], f[..., 1][fired], f[..., 2][fired]
    theta = sensor_angle_deg(omega)
    w = H * l
    if not len(w) or w.sum() <= 0:
        return float("nan"), theta, w
    z = np.sum(w * np.exp(1j * np.radians(theta)))
    return float(np.degrees(np.angle(z)) % 360.0), theta, w


def push_frames(windows_s, push_start_s: float, push_end_s: float) -> np.ndarray:
    """(T,) bool: the frames whose exposure window (windows_s (T, 2) s) overlaps the push [start, end)."""
    w = np.asarray(windows_s, dtype=float)
    return (w[:, 0] < push_end_s - 1e-12) & (w[:, 1] > push_start_s + 1e-12)


def pushed_taxels(rod_force_n, frames, rod_of_taxel, share: float = PUSHED_FORCE_SHARE) -> np.ndarray:
    """The taxels of the rods the probe pushes: rod_force_n (T, R, 3) N per frame, frames (T,) bool
    (the push frames), rod_of_taxel (N,). A rod is pushed when its largest contact force over those
    frames reaches ``share`` of the largest rod's; empty when no rod is touched."""
    f = np.linalg.norm(np.asarray(rod_force_n, dtype=float)[np.asarray(frames, bool)], axis=-1)  # (T', R)
    if not f.size or f.max() <= 0:
        return np.zeros(0, dtype=int)
    peak = f.max(axis=0)
    rods = np.flatnonzero(peak >= share * peak.max())
    return np.flatnonzero(np.isin(np.asarray(rod_of_taxel), rods))
