"""Training of the AnySkin helmet's causal contact CNN and LSTM-MLP force map on simulated runs (SPEC 2).

Data: ``runs`` simulated helmet runs of the scene's sensor (:func:`other_sensors.anyskin.signals.simulate_helmet`),
each with its own seed and a face pitch and push peak drawn from SPEC 2's 0-30 deg and 80-220 N (so
that every sensor sees light and heavy pushes); half with the skin's set switched on (the CNN must
work on a drifting skin), half without (the force map's calibration runs: SPEC 2's F/T rig has no
drift). The last run of each half is held out for validation.

- CNN: the pipeline's slope windows G_t (no re-baselining; :mod:`other_sensors.anyskin.contact_state`)
  of every channel, labelled from prominence peaks of the sensor's ground-truth force
  (:mod:`other_sensors.anyskin.labels`); every event window and three idle windows per event window
  drawn away from events; cross-entropy, Adam; the epoch with the least validation loss is kept.
  The global normalisation is the training slopes' standard deviation.
- LSTM-MLP: each sensor's filtered signal (T, 15) uT to its force (T, 3) N on the drift-free runs;
  crops of ``crop`` samples from a zero state; mean squared error, Adam, gradient norm clipped at 1;
  the step with the least validation MAE (full-length held-out sequences) is kept.

Seeding: one ``numpy.random.SeedSequence(seed)`` spawns the runs' seeds, the idle draws and the crops;
the initial weights come from ``torch.manual_seed`` inside ``torch.random.fork_rng`` (the global
generator is left as it was) and batch orders from a ``torch.Generator``; with the same thread count
the same seed gives the same weights.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from classifiers.anyskin_contact_cnn import ContactCNN, predict_events, save_contact_cnn
from classifiers.anyskin_force_lstm import ForceLSTM, predict_forces, save_force_lstm

__all__ = ["TrainingData", "simulate_training_data", "train_contact_cnn", "train_force_lstm", "train_anyskin", "PITCHES_DEG"]

PITCHES_DEG = (0.0, 10.0, 15.0, 20.0, 25.0, 30.0)  # SPEC 2's candidate face pitches
PEAK_RANGE_N = (80.0, 220.0)
IDLE_PER_EVENT = 3


@dataclass(frozen=True)
class TrainingData:
    """Per run: slopes (T, 20) uT/s, labels (T, 20) in {-1, 0, 1, 2}, signal (T, 4, 15) uT, force (T, 4, 3) N,
    all from the first scored sample on; drift: whether the run's skin had its set; window L."""

    slopes: list
    labels: list
    signal: list
    force: list
    drift: list
    window: int


def simulate_training_data(sensor, seed: int, runs: int, duration_s: float = 12.0, log=lambda m: None) -> TrainingData:
    """Simulate ``runs`` (even, >= 4) runs and cut them into the nets' inputs and labels; see the module docstring."""
    from other_sensors.anyskin.contact_state import track_contacts
    from other_sensors.anyskin.labels import contact_runs, event_labels
    from other_sensors.anyskin.signals import simulate_helmet

    if runs < 4 or runs % 2:
        raise ValueError(f"--runs {runs}: give an even number >= 4 (half with drift, half without, one of each held out)")
    e = sensor.estimator
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(1)[0])
    data = TrainingData([], [], [], [], [], e.window_samples)
    for i in range(runs):
        drift = i < runs // 2
        pitch, peak = PITCHES_DEG[i % len(PITCHES_DEG)], float(rng.uniform(*PEAK_RANGE_N))
        s = sensor.model_copy(update={
            "helmet": sensor.helmet.model_copy(update={"face_pitch_deg": pitch}),
            "push": sensor.push.model_copy(update={"peak_n": peak}),
            "trajectory": sensor.trajectory.model_copy(update={"duration_s": duration_s}),
            "drift": sensor.drift.model_copy(update={"enabled": drift})})
        sig = simulate_helmet(s, int(rng.integers(2**31)))
        n_t = len(sig.t)
        track = track_contacts(sig.readings.reshape(n_t, -1, 3), s.magnetometers.rate_hz, e.calibration_s, e.median_samples,
                               e.lowpass_hz, e.window_samples, lambda w: np.zeros(len(w), dtype=int), rebaseline=False)
        k0 = track.start
        labels = np.repeat(np.stack([event_labels(contact_runs(sig.normal_n[:, j]), n_t) for j in range(sig.normal_n.shape[1])],
                                    axis=1), sig.readings.shape[2], axis=1)
        data.slopes.append(track.slope[k0:])
        data.labels.append(labels[k0:])
        data.signal.append(track.signal[k0:].reshape(n_t - k0, sig.readings.shape[1], -1))
        data.force.append(sig.force_n[k0:])
        data.drift.append(drift)
        log(f"run {i + 1}/{runs}: pitch {pitch:g} deg, peak {peak:.0f} N, {'with' if drift else 'without'} drift")
    return data


def _windows(slopes, window: int) -> np.ndarray:
    """All slope windows (T, C, L) of one run, zeros before its start (as the pipeline pads)."""
    from numpy.lib.stride_tricks import sliding_window_view

    padded = np.concatenate([np.zeros((window - 1, slopes.shape[1])), slopes])
    return sliding_window_view(padded, window, axis=0)


def _cnn_set(data: TrainingData, runs, rng) -> tuple[np.ndarray, np.ndarray]:
    xs, ys = [], []
    for i in runs:
        w, lab = _windows(data.slopes[i], data.window).reshape(-1, data.window), data.labels[i].reshape(-1)
        event, idle = np.flatnonzero(lab > 0), np.flatnonzero(lab == 0)
        pick = rng.choice(idle, size=min(len(idle), IDLE_PER_EVENT * max(len(event), 1)), replace=False)
        keep = np.sort(np.concatenate([event, pick]))
        xs.append(w[keep])
        ys.append(lab[keep])
    return np.concatenate(xs).astype(np.float32), np.concatenate(ys)


def _seeded_model(build, seed: int):
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(seed)
        return build()


def train_contact_cnn(data: TrainingData, seed: int, epochs: int = 16, batch: int = 256, lr: float = 3e-3, log=lambda m: None):
    """Train the CNN; returns (model, metrics dict with per-class recall and precision on the held-out runs)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(2)[1])
    half = len(data.slopes) // 2
    val_runs = [half - 1, len(data.slopes) - 1]
    train_runs = [i for i in range(len(data.slopes)) if i not in val_runs]
    x, y = _cnn_set(data, train_runs, rng)
    xv, yv = _cnn_set(data, val_runs, rng)
    scale = float(x.std())
    model = _seeded_model(lambda: ContactCNN(data.window, scale), seed)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    gen = torch.Generator().manual_seed(seed)
    xt, yt, xvt, yvt = torch.from_numpy(x), torch.from_numpy(y), torch.from_numpy(xv), torch.from_numpy(yv)
    best, best_state, history = np.inf, None, []
    for epoch in range(epochs):
        model.train()
        for idx in torch.randperm(len(xt), generator=gen).split(batch):
            opt.zero_grad()
            F.cross_entropy(model(xt[idx]), yt[idx]).backward()
            opt.step()
        model.eval()
        with torch.no_grad():
            val = float(F.cross_entropy(model(xvt), yvt))
        history.append(val)
        if val < best:
            best, best_state = val, {k: v.clone() for k, v in model.state_dict().items()}
        log(f"cnn epoch {epoch + 1}/{epochs}: validation loss {val:.4f}")
    model.load_state_dict(best_state)
    model.eval()
    pred = predict_events(model, xv)
    recall = [float((pred[yv == c] == c).mean()) for c in range(3)]
    precision = [float((yv[pred == c] == c).mean()) if (pred == c).any() else 0.0 for c in range(3)]
    return model, {"val_loss": best, "val_recall": recall, "val_precision": precision, "train_windows": int(len(x)),
                   "val_windows": int(len(xv)), "scale_ut_s": scale, "history": history}


def train_force_lstm(data: TrainingData, seed: int, steps: int = 400, batch: int = 32, crop: int = 300, lr: float = 3e-3,
                     log=lambda m: None):
    """Train the LSTM-MLP on the drift-free runs; returns (model, metrics with the held-out MAE per axis)."""
    rng = np.random.default_rng(np.random.SeedSequence(seed).spawn(3)[2])
    clean = [i for i in range(len(data.signal)) if not data.drift[i]]
    train_runs, val_run = clean[:-1], clean[-1]
    x = np.concatenate([data.signal[i].transpose(1, 0, 2) for i in train_runs]).astype(np.float32)  # (S, T, 15) per run
    y = np.concatenate([data.force[i].transpose(1, 0, 2) for i in train_runs]).astype(np.float32)
    xv, yv = data.signal[val_run].transpose(1, 0, 2), data.force[val_run].transpose(1, 0, 2)
    crop = min(crop, x.shape[1])
    model = _seeded_model(lambda: ForceLSTM(x.shape[2]), seed + 1)
    opt = torch.optim.Adam(model.parameters(), lr=lr)
    best, best_state, history = np.inf, None, []
    for step in range(steps):
        rows = rng.integers(0, len(x), batch)
        starts = rng.integers(0, x.shape[1] - crop + 1, batch)
        xb = torch.from_numpy(np.stack([x[r, s:s + crop] for r, s in zip(rows, starts)]))
        yb = torch.from_numpy(np.stack([y[r, s:s + crop] for r, s in zip(rows, starts)]))
        model.train()
        opt.zero_grad()
        loss = F.mse_loss(model(xb), yb)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        if (step + 1) % 25 == 0 or step + 1 == steps:
            model.eval()
            mae = float(np.abs(predict_forces(model, xv) - yv).mean())
            history.append(mae)
            if mae < best:
                best, best_state = mae, {k: v.clone() for k, v in model.state_dict().items()}
            log(f"lstm step {step + 1}/{steps}: held-out MAE {mae:.2f} N")
    model.load_state_dict(best_state)
    model.eval()
    per_axis = np.abs(predict_forces(model, xv) - yv).mean(axis=(0, 1))
    return model, {"val_mae_n": best, "val_mae_xyz_n": [float(v) for v in per_axis], "history": history,
                   "train_sequences": int(len(x))}


def train_anyskin(sensor, out_dir, seed: int = 0, runs: int = 12, cnn_epochs: int = 16, lstm_steps: int = 400, threads: int = 1,
                  log=lambda m: None) -> dict:
    """Simulate, train both nets, write ``anyskin_contact_cnn.pt``, ``anyskin_force_lstm.pt`` and
    ``anyskin_train.json`` into out_dir; returns the metrics."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    previous = torch.get_num_threads()
    torch.set_num_threads(threads)
    try:
        t0 = time.perf_counter()
        data = simulate_training_data(sensor, seed, runs, log=log)
        t1 = time.perf_counter()
        cnn, cnn_metrics = train_contact_cnn(data, seed, epochs=cnn_epochs, log=log)
        t2 = time.perf_counter()
        lstm, lstm_metrics = train_force_lstm(data, seed, steps=lstm_steps, log=log)
        t3 = time.perf_counter()
    finally:
        torch.set_num_threads(previous)
    meta = {"seed": seed, "runs": runs, "threads": threads, "labels": "prominence peaks of the simulated plate force"}
    save_contact_cnn(cnn, out / "anyskin_contact_cnn.pt", {**meta, "epochs": cnn_epochs})
    save_force_lstm(lstm, out / "anyskin_force_lstm.pt", {**meta, "steps": lstm_steps})
    metrics = {"contact_cnn": cnn_metrics, "force_lstm": lstm_metrics, "seed": seed, "runs": runs, "threads": threads,
               "seconds": {"simulate": t1 - t0, "cnn": t2 - t1, "lstm": t3 - t2}}
    tmp = out / ".anyskin_train.json.part"
    tmp.write_text(json.dumps(metrics, indent=2) + "\n")
    tmp.replace(out / "anyskin_train.json")
    return metrics
