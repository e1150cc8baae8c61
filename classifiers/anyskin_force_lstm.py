"""The AnySkin force regressor (SPEC 2): an LSTM followed by an MLP maps one sensor's flux to its 3-D force.

Input per sample: the sensor's five chips' filtered, baseline- and offset-free field x (15,) uT (the
contact pipeline's signal, :mod:`other_sensors.anyskin.contact_state`), divided by ``in_scale``
(100 uT, a choice keeping it O(1)). Output: the force on the skin in the sensor frame (3,) N,
``out_scale`` (50 N) times the MLP's output. SPEC 2 gives "an LSTM followed by an MLP" and no sizes;
here one LSTM layer of 32 units and an MLP 32 -> 32 (GELU) -> 3, a choice (about 8,000 weights).

The LSTM runs forward in time only, from a zero state at the first scored sample, so the force at t
depends on x up to t (causal); inference runs it once over a whole stream (:func:`predict_forces`),
one call for all sensors, which is the same as stepping it sample by sample. Training crops short
sequences (:mod:`classifiers.anyskin_train`); a simplification: the model has no drift input, it
relies on the re-baselined signal being drift-free.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from classifiers.anyskin_contact_cnn import _load, save_payload

__all__ = ["ForceLSTM", "predict_forces", "save_force_lstm", "load_force_lstm", "FORCE_LSTM_FORMAT", "IN_SCALE_UT", "OUT_SCALE_N"]

FORCE_LSTM_FORMAT = "mlsim.anyskin.force_lstm"
IN_SCALE_UT, OUT_SCALE_N = 100.0, 50.0
HIDDEN = 32


class ForceLSTM(nn.Module):
    """LSTM(15 -> hidden) then MLP(hidden -> hidden -> 3), SPEC 2's force map for one sensor.

    Parameters
    ----------
    n_inputs : int
        Features per sample (5 chips x 3 axes = 15).
    hidden : int
        LSTM units and the MLP's width.
    """

    def __init__(self, n_inputs: int = 15, hidden: int = HIDDEN):
        super().__init__()
        self.n_inputs, self.hidden = int(n_inputs), int(hidden)
        self.lstm = nn.LSTM(self.n_inputs, self.hidden, batch_first=True)
        self.mlp = nn.Sequential(nn.Linear(self.hidden, self.hidden), nn.GELU(), nn.Linear(self.hidden, 3))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (B, T, 15) uT -> force (B, T, 3) N, causal along T."""
        h, _ = self.lstm(x / IN_SCALE_UT)
        return OUT_SCALE_N * self.mlp(h)


def predict_forces(model: ForceLSTM, signal) -> np.ndarray:
    """Forces (S, T, 3) N of S sensors' signals (S, T, 15) uT, one batched causal pass."""
    x = np.asarray(signal, dtype=np.float32)
    if x.ndim != 3 or x.shape[-1] != model.n_inputs:
        raise ValueError(f"signal of shape {x.shape}; expected (sensors, samples, {model.n_inputs})")
    with torch.inference_mode():
        return model(torch.from_numpy(x)).numpy().astype(float)


def save_force_lstm(model: ForceLSTM, path, meta: dict | None = None) -> Path:
    """Write the regressor (weights, sizes, the training's meta data) to one file."""
    payload = {"format": FORCE_LSTM_FORMAT, "version": 1, "n_inputs": model.n_inputs, "hidden": model.hidden,
               "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}, "meta": dict(meta or {})}
    return save_payload(payload, path)


def load_force_lstm(path) -> ForceLSTM:
    """Read a file of :func:`save_force_lstm`; a ValueError names the file and how to make one."""
    d = _load(path, FORCE_LSTM_FORMAT)
    model = ForceLSTM(int(d["n_inputs"]), int(d["hidden"]))
    model.load_state_dict(d["state_dict"])
    model.meta = d.get("meta", {})
    return model.eval()
