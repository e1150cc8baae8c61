"""The helmet studies of SPEC 2: force error against the skin's drift rate, and the face-pitch criteria.

- :func:`drift_sweep`: the scene re-simulated with the permanent-set fraction scaled (the set's rate,
  fraction / tau_set, SPEC 2's dominant drift), each run estimated with and without re-baselining;
  per rate the MAE per axis over the scored samples and the z MAE over the last ``tail_cycles`` push
  cycles (where the drift has built up).
- :func:`pitch_criteria`: SPEC 2's two criteria for the face pitch, from the simulated ground truth
  (as the helmet's designers chose it, by simulation): B, per sensor, the count of samples whose
  contact force exceeds 50 N (the SPEC wants a high mean and a low spread across sensors), and
  SNR_xy = |mean F_xy| / sqrt(trace(Sigma_xy)) of each sensor's planar force over its contact
  samples (normal force > 2 N), the mean of the planar force against its spread; NaN for a sensor
  with fewer than ``MIN_CONTACT_SAMPLES`` (15, 0.1 s) contact samples, whose ratio is noise.
- :func:`truth_comparison` (issue 43): per truth model (the finite magnet volume, the point dipoles),
  the LSTM-MLP trained on the simulated calibration bench and scored on the helmet's pushes, with and
  without re-baselining: the estimator's error with the model error in it, beside the error in the
  world it was first built on.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["DriftRow", "PitchRow", "TruthRow", "drift_sweep", "pitch_criteria", "truth_comparison", "snr_xy", "count_above",
           "B_FORCE_N", "SWEEP_FACTORS", "TRUTHS", "PITCHES_DEG"]

B_FORCE_N = 50.0  # SPEC 2: contact forces above 50 N
CONTACT_N = 2.0  # a sample is in contact above this normal force (the labels' threshold)
MIN_CONTACT_SAMPLES = 15
SWEEP_FACTORS = (0.0, 0.5, 1.0, 2.0, 4.0)  # times the scene's set fraction (capped at 1)
PITCHES_DEG = (0.0, 10.0, 15.0, 20.0, 25.0, 30.0)  # SPEC 2's candidates


def count_above(normal_n, threshold_n: float = B_FORCE_N) -> np.ndarray:
    """B: per sensor, the samples with normal force > threshold, (S,) int from normal_n (T, S)."""
    return (np.asarray(normal_n) > threshold_n).sum(axis=0)


def snr_xy(force_n, normal_n, contact_n: float = CONTACT_N, min_samples: int = MIN_CONTACT_SAMPLES) -> np.ndarray:
    """SNR_xy per sensor, (S,): |mean F_xy| / sqrt(trace(cov F_xy)) over its contact samples (NaN: < min_samples).

    force_n (T, S, 3) N in each sensor's frame; normal_n (T, S) N.
    """
    out = np.full(force_n.shape[1], np.nan)
    for i in range(force_n.shape[1]):
        f = force_n[normal_n[:, i] > contact_n, i, :2]
        if len(f) >= max(2, min_samples):
            out[i] = np.linalg.norm(f.mean(axis=0)) / np.sqrt(np.trace(np.cov(f, rowvar=False)))
    return out


@dataclass(frozen=True)
class DriftRow:
    """One drift rate: set_fraction, rate_per_s (fraction / tau_set), final_set_um (largest, any sensor),
    mae_rebaselined, mae_static (3,) N per axis; tail_z_rebaselined, tail_z_static N; rebaselines (total)."""

    set_fraction: float
    rate_per_s: float
    final_set_um: float
    mae_rebaselined: np.ndarray
    mae_static: np.ndarray
    tail_z_rebaselined: float
    tail_z_static: float
    rebaselines: int


def drift_sweep(sensor, seed: int, estimator, factors=SWEEP_FACTORS, tail_cycles: int = 5) -> list[DriftRow]:
    """See the module docstring. estimator: an :class:`other_sensors.anyskin.estimate.Estimator`."""
    from .estimate import estimate_contacts
    from .signals import simulate_helmet

    rows = []
    for f in factors:
        fraction = min(1.0, sensor.drift.set_fraction * f)
        s = sensor.model_copy(update={"drift": sensor.drift.model_copy(update={"enabled": fraction > 0, "set_fraction": fraction})})
        sig = simulate_helmet(s, seed)
        est = estimate_contacts(s, sig, seed, estimator)
        tail = slice(-tail_cycles - 1, None)  # the last complete cycles and the partial one at the end
        rows.append(DriftRow(fraction, fraction / s.drift.tau_set_s, float(sig.set_mm[-1].max() * 1e3),
                             np.array([est.mae("rebaselined", a) for a in range(3)]), np.array([est.mae("static", a) for a in range(3)]),
                             float(np.nanmean(est.cycle_mae("rebaselined")[tail, 2])), float(np.nanmean(est.cycle_mae("static")[tail, 2])),
                             int(est.rebaselines.sum())))
    return rows


@dataclass(frozen=True)
class PitchRow:
    """One face pitch: b (4,) samples above 50 N per sensor, snr (4,) SNR_xy per sensor."""

    pitch_deg: float
    b: np.ndarray
    snr: np.ndarray

    @property
    def b_mean(self) -> float:
        return float(self.b.mean())

    @property
    def b_std(self) -> float:
        return float(self.b.std())


def pitch_criteria(sensor, seed: int, pitches=PITCHES_DEG) -> list[PitchRow]:
    """See the module docstring: the scene's run at each face pitch, same seed."""
    from .signals import simulate_helmet

    rows = []
    for p in pitches:
        s = sensor.model_copy(update={"helmet": sensor.helmet.model_copy(update={"face_pitch_deg": float(p)})})
        sig = simulate_helmet(s, seed)
        rows.append(PitchRow(float(p), count_above(sig.normal_n), snr_xy(sig.force_n, sig.normal_n)))
    return rows


TRUTHS = ("magnet_volume", "point_dipole")  # the richer world first, then the estimator's first one


@dataclass(frozen=True)
class TruthRow:
    """One truth model: truth; bench_mae (3,) N, the bench-trained force map's MAE per axis on the held-out
    bench run; mae_rebaselined, mae_static (3,) N per axis on the helmet's pushes; rebaselines (total)."""

    truth: str
    bench_mae: np.ndarray
    mae_rebaselined: np.ndarray
    mae_static: np.ndarray
    rebaselines: int


def truth_comparison(sensor, seed: int, truths=TRUTHS, log=lambda m: None, bench_runs: int | None = None,
                     bench_s: float | None = None, steps: int | None = None) -> list[TruthRow]:
    """Issue 43's acceptance table: per truth model, the LSTM-MLP trained on the simulated calibration
    bench (:mod:`.bench`) and scored on the scene's helmet pushes, with and without re-baselining.

    The contact detector is the scene's (the causal CNN when ``sensor.estimator.contact_model`` names
    it, else the threshold stand-in); only the force map changes between the rows. bench_runs, bench_s,
    steps: the bench's runs and their length (None: :data:`.bench.BENCH_RUNS`, :data:`.bench.BENCH_S`)
    and the LSTM-MLP's training steps (None: 400)."""
    from classifiers.anyskin_force_lstm import predict_forces

    from .bench import bench_force_map, train_bench_force_map
    from .contact_state import ThresholdStandIn
    from .estimate import Estimator, cnn_detector, estimate_contacts, model_path
    from .signals import simulate_helmet

    e = sensor.estimator
    if e.contact_model is not None:
        from classifiers.anyskin_contact_cnn import load_contact_cnn

        detector, name = cnn_detector(load_contact_cnn(model_path(e.contact_model))), "causal CNN"
    else:
        detector, name = ThresholdStandIn(e.onset_slope_ut_s, e.release_slope_ut_s), "threshold stand-in"
    rows = []
    for truth in truths:
        s = sensor.model_copy(update={"skin": sensor.skin.model_copy(update={"truth": truth})})
        if bench_runs is None and bench_s is None and steps is None:  # the defaults: shared with the contact and drift stages
            lstm, metrics = bench_force_map(s, seed)
        else:
            from .bench import BENCH_RUNS, BENCH_S

            lstm, metrics = train_bench_force_map(s, seed, bench_runs or BENCH_RUNS, bench_s or BENCH_S, steps or 400)
        est = Estimator(s.magnetometers.rate_hz, e.calibration_s, e.median_samples, e.lowpass_hz, e.window_samples, detector,
                        lambda x, m=lstm: predict_forces(m, x), f"{name} + bench-trained LSTM-MLP", torch=True)
        out = estimate_contacts(s, simulate_helmet(s, seed), seed, est)
        rows.append(TruthRow(truth, np.asarray(metrics["val_mae_xyz_n"]), np.array([out.mae("rebaselined", a) for a in range(3)]),
                             np.array([out.mae("static", a) for a in range(3)]), int(out.rebaselines.sum())))
        log(f"anyskin truth {truth}: bench MAE x y z {np.round(rows[-1].bench_mae, 2)} N; helmet MAE x y z "
            f"{np.round(rows[-1].mae_rebaselined, 2)} N re-baselined, {np.round(rows[-1].mae_static, 2)} N static")
    return rows
