"""The ML brightness of a real sensor from a recorded press of known force (``mlsim calibrate --press
VIDEO --force-n F``, issue 41).

Measure: the light a recording shows over an episode, L = sum over frames of (M(t) - D), M(t) the
frame's summed grey level (the DLLM's, SPEC 1.6) and D the mean M of its idle first second (the
DLLM's threshold initialisation): the camera's output above its dark level, summed (grey levels).

Fit: the scene's own [load], with every force-controlled press set to ``force_n``, is simulated
(the pipeline's frames after its idle second, as :func:`dllm.stage.idle_before` gives them), and its
``emission.brightness_photons_per_m2`` is scaled by L_recorded / L_simulated until they agree. The
camera is linear in the photons above its dark level except for the 8-bit cut and clipping (a 0.3 N
press of the tiny scene at 96 px: 1.7 times the brightness gives 1.51 times the light), so the
brightness is found by the secant method on L_sim(b) = L_rec (at most ``iterations`` simulations,
stopping when they agree within their uncertainty): the cut's and the clipping's effects at the
sensor's own brightness are then the simulation's too. The uncertainty is the sums' over the local
slope dL/db. Each sum's uncertainty: the frames' temporal noise, the grey levels' rounding and the light's shot
noise (:func:`light_sum`), recorded and simulated in quadrature.

The lens. The press is simulated through the scene's camera, whose focal length ``mlsim calibrate``
fits to the calibration photo with an uncertainty of its own. At a fixed f-number the light a press
shows grows with the image's magnification (about as f^2: the same rods on more pixels, each as
bright), so a lens fitted 3.1 % short read as a phosphor 7.3 % too bright (the first of three
simulated sensors of the tiny scene at 96 px, whose 4 disks fix the lens to 2-3 %: 7.6 sigma of the
light's uncertainty alone, tests/test_sensor_calibration.py). With ``focal_length_sigma_mm`` the fit
simulates the press once more at the fitted brightness through a lens one sigma longer, and the
brightness that light would need, |L(f + sigma_f) - L(f)| / (dL/db), is added in quadrature
(``sigma_lens``; ``sigma_light`` is the sums' part).

What this assumes (and the overlay says): the scene's [load] is the press that was recorded (probe,
place, speed or duration); the emission model's shape (SPEC 1.3: light follows the stress rate and
the traps) is the scene's; only its scale is fitted.
"""

from __future__ import annotations

import numpy as np

__all__ = ["light_sum", "fit_brightness", "with_press_force"]


def light_sum(frames, n_idle: int, dn10_per_e: float = 0.0) -> tuple[float, float]:
    """(L, sigma_L): the summed grey light above the idle level of RGB frames (T, H, W, 3) uint8 whose
    first ``n_idle`` frames are idle (module docstring).

    sigma_L: per episode frame the idle frames' temporal variance of M plus the grey levels' rounding,
    1/12 per pixel that the light lifts off the idle image (uniform, independent errors: where the
    camera's noise is below a grey level, as at 0 dB, the rounding is all there is), and the light's
    own shot noise, (K / 4) times its grey levels with ``dn10_per_e`` = K the camera's 10-bit DN per
    electron (each grey level counted as a photosite's: the demosaic's averaging makes this an upper
    bound), summed over the frames, and D's uncertainty times T."""
    from dllm.calibration import grey

    g = np.stack([grey(f) for f in frames]).astype(np.float64)
    if n_idle < 2 or len(g) <= n_idle:
        raise ValueError(f"{len(g)} frames with {n_idle} idle: need at least 2 idle frames and one after them")
    m = g.reshape(len(g), -1).sum(axis=1)
    idle, episode = m[:n_idle], m[n_idle:]
    D, s = float(idle.mean()), float(idle.std(ddof=1))
    lit = (np.abs(g[n_idle:] - g[:n_idle].mean(axis=0)) >= 1.0).reshape(len(episode), -1).sum(axis=1)
    T = len(episode)
    L = float((episode - D).sum())
    var = float(np.sum(s**2 + lit / 12.0)) + (T * s) ** 2 / n_idle + dn10_per_e / 4.0 * max(L, 0.0)
    return L, float(np.sqrt(var))


def with_press_force(scene, force_n: float):
    """The scene with every force-controlled press segment of its [load] at ``force_n`` (N)."""
    from mlsim.errors import Problem, SceneError

    if scene.load is None:
        raise SceneError([Problem("--scene", scene.name, "needs a [load]: the press that was recorded")])
    idx = [k for k, s in enumerate(scene.load.segments) if s.kind == "press" and getattr(s, "force_n", None) is not None]
    if not idx:
        raise SceneError([Problem("--force-n", force_n, "the scene's [load] has no force-controlled press (kind = \"press\", "
                                                         "force_n = ...) to set: describe the recorded press there")])
    return scene.with_values({f"load.segments[{k}].force_n": float(force_n) for k in idx})


def _dn10_per_e(scene) -> float:
    from mlsim.render.optics import camera_params

    p = camera_params(scene)
    return p.effective_conversion_gain_dn_per_e * 10.0 ** (p.gain_db / 20.0) * 2.0 ** (10 - p.adc_bits)


def simulated_light(scene, cache) -> tuple[float, float, np.ndarray]:
    """(L, sigma_L, frames with the idle second first) of a scene's episode through the pipeline."""
    from dllm.detector import DllmParams
    from dllm.stage import idle_before
    from mlsim import pipeline

    res = pipeline.run(scene, out_dir=None, cache=cache, outputs=("render", "camera"), progress=False, log=lambda m: None)
    idle = idle_before(scene, res.results["render"])
    frames = np.concatenate([idle, res.results["camera"].frames])
    n = DllmParams.from_scene(scene).init_frames
    return (*light_sum(frames, n, _dn10_per_e(scene)), frames)


def fit_brightness(frames, scene, force_n: float, cache, iterations: int = 8, focal_length_sigma_mm: float | None = None) -> dict:
    """Fit ``emission.brightness_photons_per_m2`` to a recorded press (module docstring).

    Parameters
    ----------
    frames : numpy.ndarray
        The recording, RGB (T, H, W, 3) uint8, its first second (the DLLM's ``init_frames``) idle.
    scene : mlsim.scene.Scene
        The sensor (its camera as fitted) with the recorded press as its [load].
    force_n : float
        The press's force (N), set on the scene's force-controlled press segments.
    cache : mlsim.pipeline.Cache
        The pipeline's cache (each simulation reuses the solve and the render).
    iterations : int
        At most this many simulations of the secant search.
    focal_length_sigma_mm : float or None
        The standard uncertainty of the scene's ``camera.focal_length_mm`` (``mlsim calibrate``'s fit
        of the photo); propagated into the brightness by one more simulation (module docstring,
        "The lens"). None: the lens is taken as exact (``sigma_lens`` = 0).

    Returns
    -------
    dict
        ``brightness_photons_per_m2`` and its standard uncertainty ``sigma`` (``sigma_light`` and
        ``sigma_lens`` in quadrature), ``light_per_brightness`` (dL/db at the fit), the recorded light
        and its uncertainty, ``converged`` and the iterations.
    """
    from dllm.detector import DllmParams

    if focal_length_sigma_mm is not None and not (np.isfinite(focal_length_sigma_mm) and focal_length_sigma_mm >= 0):
        raise ValueError(f"focal_length_sigma_mm = {focal_length_sigma_mm}: must be a standard uncertainty >= 0 (mm), "
                         "or None for an exact lens")
    n_idle = DllmParams.from_scene(scene).init_frames
    L_rec, s_rec = light_sum(frames, n_idle, _dn10_per_e(scene))
    if L_rec <= 3.0 * s_rec:
        raise ValueError(f"the press recording shows {L_rec:.4g} grey levels of light, within 3 sigma ({s_rec:.3g}) of none")
    press = with_press_force(scene, force_n)
    b = press.emission.brightness_photons_per_m2
    history, sigma = [], float("nan")
    for _ in range(max(int(iterations), 1)):
        L_sim, s_sim, _ = simulated_light(press.with_values({"emission.brightness_photons_per_m2": b}), cache)
        if L_sim <= 0:
            raise ValueError("the simulated press shows no light: check the scene's [load] (does the probe reach the rods?)")
        history.append({"brightness_photons_per_m2": b, "light_simulated": L_sim, "light_simulated_sigma": s_sim})
        # the slope dL/db: proportional at the first step, then the secant of the last two (the
        # light grows slower than the brightness where pixels clip)
        if len(history) > 1 and history[-1]["light_simulated"] != history[-2]["light_simulated"]:
            slope = (L_sim - history[-2]["light_simulated"]) / (b - history[-2]["brightness_photons_per_m2"])
        else:
            slope = L_sim / b
        if slope <= 0:
            raise ValueError(f"the simulated light does not grow with the brightness near {b:.4g} photons/m^2 (clipped?)")
        sigma = float(np.hypot(s_rec, s_sim) / slope)
        converged = abs(L_rec - L_sim) < np.hypot(s_rec, s_sim)
        b = b + (L_rec - L_sim) / slope
        if converged:
            break
    sigma_lens = 0.0
    if focal_length_sigma_mm is not None:
        from mlsim.render.optics import camera_params

        f_mm = camera_params(press).focal_length_m * 1e3
        at = {"emission.brightness_photons_per_m2": b}
        L_fit, _, _ = simulated_light(press.with_values(at), cache)
        L_long, _, _ = simulated_light(press.with_values(at | {"camera.focal_length_mm": f_mm + float(focal_length_sigma_mm)}), cache)
        sigma_lens = abs(L_long - L_fit) / slope
    return {"brightness_photons_per_m2": float(b), "sigma": float(np.hypot(sigma, sigma_lens)), "sigma_light": sigma,
            "sigma_lens": float(sigma_lens), "light_per_brightness": float(slope), "force_n": float(force_n), "light_recorded": L_rec,
            "light_recorded_sigma": s_rec, "converged": bool(converged), "iterations": history}
