"""Flux-to-force map per sensor: a quadratic ridge regression, the untrained stand-in for SPEC 2's LSTM + MLP
(:mod:`classifiers.anyskin_force_lstm` replaces it when the scene names trained files; see :mod:`.estimate`).

Features of one sensor's five chips x (15,) uT: [1, x / s, (x / s)^2] with s = 100 uT (a choice, to
keep the features O(1)); weights by ridge least squares, lambda = RIDGE (a choice: a tiny ridge only
to keep the solve well-posed on idle-heavy data). Forces in the sensor frame, N.
"""

from __future__ import annotations

import numpy as np

__all__ = ["features", "fit_force_map", "predict_force", "RIDGE", "SCALE_UT"]

RIDGE = 1e-6
SCALE_UT = 100.0


def features(signal) -> np.ndarray:
    """signal (T, 5, 3) uT -> (T, 31)."""
    x = np.asarray(signal, dtype=float).reshape(len(signal), -1) / SCALE_UT
    return np.column_stack([np.ones(len(x)), x, x**2])


def fit_force_map(signal, force) -> np.ndarray:
    """Weights (31, 3) mapping one sensor's signal (T, 5, 3) uT to its force (T, 3) N."""
    a = features(signal)
    lhs = a.T @ a + RIDGE * len(a) * np.eye(a.shape[1])
    return np.linalg.solve(lhs, a.T @ np.asarray(force, dtype=float))


def predict_force(weights, signal) -> np.ndarray:
    return features(signal) @ weights
