"""SPEC 2's calibration bench: a single AnySkin skin pressed on a force plate, the data its LSTM-MLP force map is trained on.

SPEC 2: "Force mapping: an LSTM followed by an MLP maps flux to a 3D force; ground truth from a 6-axis
F/T sensor. Reference: MAE 3.6 N in Z on the calibration rig". Here one skin of the scene (its truth
model, its chips' read-out) lies still on the bench: no head motion, so the Earth's field is a
constant that the initial baseline removes, and no motor field. An indenter presses it in sin^2 pulses
of the helmet's push length and rest (``sensor.push``), each with a seeded peak normal force uniform in
[PEAK_MIN_N, peak_n (1 + jitter)] (the heaviest push the helmet's scene can put on one pad) and a
tangential part |F_t| = r |F_n| in a seeded direction, r uniform in [0, TANGENT_RATIO]:
tan(38.7 deg), the steepest face pitch SPEC 2 considers (30 deg) plus the head's pitch amplitude
(8 deg), the plate's largest tilt in a sensor's frame. The F/T sensor reads the force exactly (its own
error, ~0.1 N on a 6-axis cell, is far below the chips'). The bench's skin has no permanent set (a
fresh skin, calibrated before the robot walks; SPEC 2's rig reports no drift), and its chips are other
draws than the helmet's (:mod:`.magnetometer`).

:func:`bench_training_data` cuts ``runs`` bench runs into the force map's inputs (the causal pipeline's
filtered, baseline-free signal, :mod:`.contact_state`) and the F/T force, in the form
:func:`classifiers.anyskin_train.train_force_lstm` takes (the last run held out).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["BenchRun", "bench_forces", "simulate_bench", "bench_training_data", "train_bench_force_map", "bench_force_map", "TANGENT_RATIO",
           "PEAK_MIN_N", "BENCH_RUNS", "BENCH_S"]

TANGENT_RATIO = float(np.tan(np.radians(38.7)))  # see the module docstring
PEAK_MIN_N = 5.0  # the lightest press: a touch above the labels' 2 N contact threshold
BENCH_RUNS, BENCH_S = 4, 30.0  # 3 runs trained on and 1 held out, 12 presses each


@dataclass(frozen=True)
class BenchRun:
    """t (T,) s; readings (T, 5, 3) uT; force (T, 3) N on the skin (sensor frame, F_z < 0 presses)."""

    t: np.ndarray
    readings: np.ndarray
    force: np.ndarray


def bench_forces(t_s, first_s: float, press_s: float, rest_s: float, peak_n: float, rng: np.random.Generator) -> np.ndarray:
    """The indenter's force (T, 3) N; see the module docstring."""
    if not (np.isfinite(peak_n) and peak_n > PEAK_MIN_N):
        raise ValueError(f"sensor.push.peak_n = {peak_n}: the bench presses up to it, give more than {PEAK_MIN_N} N")
    t = np.asarray(t_s, dtype=float)
    period = press_s + rest_s
    n = int(np.ceil(max(t[-1] - first_s, 0.0) / period)) + 1
    peaks = rng.uniform(PEAK_MIN_N, peak_n, n)
    ratio, angle = rng.uniform(0.0, TANGENT_RATIO, n), rng.uniform(-np.pi, np.pi, n)
    phase = t - first_s
    k = np.clip(np.floor(phase / period).astype(int), 0, n - 1)
    within = phase - k * period
    normal = np.where((phase >= 0) & (within < press_s), peaks[k] * np.sin(np.pi * within / press_s) ** 2, 0.0)
    return np.column_stack([normal * ratio[k] * np.cos(angle[k]), normal * ratio[k] * np.sin(angle[k]), -normal])


def simulate_bench(sensor, seed: int, duration_s: float = BENCH_S) -> BenchRun:
    """One bench run of the scene's skin (its truth model and chips); see the module docstring."""
    from .signals import chip_errors_of, read_chips_of
    from .skin import N_MAGNETOMETERS
    from .truth import skin_fields

    press_rng, orient_rng, noise_rng, chip_rng = (np.random.default_rng(s) for s in np.random.SeedSequence(seed).spawn(4))
    p, dt = sensor.push, 1.0 / sensor.magnetometers.rate_hz
    t = np.arange(int(round(duration_s / dt))) * dt
    force = bench_forces(t, p.first_s, p.push_s, p.rest_s, p.peak_n * (1 + p.jitter), press_rng)
    fresh = sensor.model_copy(update={"drift": sensor.drift.model_copy(update={"enabled": False})})
    skin = skin_fields(fresh, force[:, None], dt).skin[:, 0]  # (T, 5, 3)
    q, _ = np.linalg.qr(orient_rng.normal(size=(3, 3)))  # the bench's orientation in the world: a seeded rotation
    earth = q.T @ np.asarray(sensor.ambient.geomagnetic_ut, dtype=float)
    offsets, sensitivity = chip_errors_of(sensor, N_MAGNETOMETERS, chip_rng)
    readings = read_chips_of(sensor, skin + earth, offsets, sensitivity, noise_rng)
    return BenchRun(t, readings, force)


def bench_training_data(sensor, seed: int, runs: int = BENCH_RUNS, duration_s: float = BENCH_S):
    """``runs`` (>= 2) bench runs as a :class:`classifiers.anyskin_train.TrainingData` of one sensor each
    (drift False: every run is a calibration run; the last is held out by the trainer)."""
    from classifiers.anyskin_train import TrainingData

    from .contact_state import track_contacts

    if runs < 2:
        raise ValueError(f"bench runs = {runs}: give at least 2 (one is held out)")
    e = sensor.estimator
    data = TrainingData([], [], [], [], [], e.window_samples)
    for child in np.random.SeedSequence(seed).spawn(runs):
        run = simulate_bench(sensor, int(child.generate_state(1)[0]), duration_s)
        track = track_contacts(run.readings, sensor.magnetometers.rate_hz, e.calibration_s, e.median_samples, e.lowpass_hz,
                               e.window_samples, lambda w: np.zeros(len(w), dtype=int), rebaseline=False)
        k0 = track.start
        data.signal.append(track.signal[k0:].reshape(len(run.t) - k0, 1, -1))
        data.force.append(run.force[k0:, None])
        data.drift.append(False)
    return data


def train_bench_force_map(sensor, seed: int, runs: int = BENCH_RUNS, duration_s: float = BENCH_S, steps: int = 400):
    """The LSTM-MLP trained on the bench (one torch thread, so that the weights reproduce); returns
    (model, metrics: the held-out bench run's MAE per axis, ``val_mae_xyz_n``)."""
    import torch

    from classifiers.anyskin_train import train_force_lstm

    data = bench_training_data(sensor, seed, runs, duration_s)
    previous = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        return train_force_lstm(data, seed, steps=steps)
    finally:
        torch.set_num_threads(previous)


_TRAINED: dict = {}  # (what the bench reads of the scene, seed) -> model: the stages of one run share a training


def bench_force_map(sensor, seed: int):
    """(model, metrics) of :func:`train_bench_force_map` with its defaults, trained once per process
    for what the bench reads of the scene (the skin, the chips, the pushes, the Earth's field, the
    estimator's filters) and the seed: the contact, drift and bench stages of a run share it."""
    key = (seed,) + tuple(getattr(sensor, k).model_dump_json() for k in ("skin", "magnetometers", "noise", "push", "ambient",
                                                                          "estimator"))
    if key not in _TRAINED:
        _TRAINED[key] = train_bench_force_map(sensor, seed)
    return _TRAINED[key]
