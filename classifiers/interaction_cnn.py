"""The 1D CNN that classifies 8-frame DLLM windows into interactions (SPEC 1.7).

SPEC 1.7 gives the layer sequence: Conv1D with 32 filters and ReLU, batch normalisation,
down-sampling, Conv1D with 128 filters, two dense ReLU layers, a dense softmax output. It does not
give kernel sizes, the down-sampling or the dense widths; the defaults here are:

- both convolutions: kernel 3 over time, padding 1 ("same"), stride 1 -- the smallest kernel that
  sees a frame and both neighbours; two of them plus the pooling cover 8 frames in a receptive
  field of 6 input frames, so the dense layers see the whole window;
- down-sampling: ``MaxPool1d(2)``, 8 frames -> 4;
- dense widths 64 and 32: the 128 x 4 = 512 features are halved in steps; at 50 channels the net
  has 52,488 parameters, small beside a few thousand training windows;
- batch normalisation after the first ReLU, as SPEC lists it.

The net returns logits (N, n_classes); training uses cross-entropy on them and inference takes the
softmax (:func:`softmax_probabilities`), which is SPEC's softmax output layer.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import nn

__all__ = ["InteractionCNN", "softmax_probabilities", "predict_proba", "DENSE_WIDTHS", "KERNEL_SIZE"]

#: Kernel size of both convolutions (not given in SPEC 1.7).
KERNEL_SIZE = 3
#: Widths of the two dense ReLU layers (not given in SPEC 1.7).
DENSE_WIDTHS = (64, 32)


def softmax_probabilities(logits: np.ndarray) -> np.ndarray:
    """Softmax over the last axis: logits (..., K) -> probabilities (..., K), each row summing to 1."""
    z = np.asarray(logits, dtype=np.float64)
    z = z - z.max(axis=-1, keepdims=True)  # exp of the largest logit is 1: no overflow
    e = np.exp(z)
    return e / e.sum(axis=-1, keepdims=True)


class InteractionCNN(nn.Module):
    """Conv(32) ReLU, BatchNorm, MaxPool(2), Conv(128) ReLU, Dense ReLU x2, Dense (SPEC 1.7).

    Parameters
    ----------
    n_channels : int
        Input channels C (SPEC 1.7: 50 = l and omega of 25 taxels).
    n_classes : int
        Outputs (8 or 4).
    window : int
        Frames per window L (SPEC 1.7: 8); even, >= 2.
    kernel_size : int
        Odd kernel of both convolutions (default 3, padding keeps the length).
    dense : tuple of int
        Widths of the two dense ReLU layers (default (64, 32)).
    generator : torch.Generator, optional
        Draws the initial weights (PyTorch's default initialisation, from this generator); without
        one they come from torch's global generator.

    Notes
    -----
    ``forward``: x (N, C, L) float32 -> logits (N, n_classes).
    """

    def __init__(
        self,
        n_channels: int,
        n_classes: int,
        window: int = 8,
        kernel_size: int = KERNEL_SIZE,
        dense: tuple[int, int] = DENSE_WIDTHS,
        generator: torch.Generator | None = None,
    ):
        super().__init__()
        for name, v in (("n_channels", n_channels), ("n_classes", n_classes), ("window", window)):
            if not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"InteractionCNN {name} = {v!r}: must be a positive integer")
        if window < 2 or window % 2:
            raise ValueError(f"InteractionCNN window = {window}: must be even and >= 2 (MaxPool1d(2) halves it)")
        if kernel_size < 1 or kernel_size % 2 == 0:
            raise ValueError(f"InteractionCNN kernel_size = {kernel_size}: must be odd (padding (k-1)/2 keeps the length)")
        if len(dense) != 2:
            raise ValueError(f"InteractionCNN dense = {dense!r}: SPEC 1.7 has two dense ReLU layers; give two widths")
        self.config = {
            "n_channels": int(n_channels),
            "n_classes": int(n_classes),
            "window": int(window),
            "kernel_size": int(kernel_size),
            "dense": [int(d) for d in dense],
        }
        pad = kernel_size // 2
        # the layers are built under fork_rng so their throw-away default init leaves the global
        # generator as it was; reset_parameters then draws from the caller's generator
        with torch.random.fork_rng(devices=[]):
            self.features = nn.Sequential(
                nn.Conv1d(n_channels, 32, kernel_size, padding=pad),
                nn.ReLU(),
                nn.BatchNorm1d(32),
                nn.MaxPool1d(2),
                nn.Conv1d(32, 128, kernel_size, padding=pad),
                nn.ReLU(),
            )
            self.head = nn.Sequential(
                nn.Flatten(),
                nn.Linear(128 * (window // 2), dense[0]),
                nn.ReLU(),
                nn.Linear(dense[0], dense[1]),
                nn.ReLU(),
                nn.Linear(dense[1], n_classes),
            )
        if generator is not None:
            self.reset_parameters(generator)

    def reset_parameters(self, generator: torch.Generator) -> None:
        """PyTorch's default init of Conv1d / Linear (kaiming uniform, a = sqrt 5; bias U(+-1/sqrt fan_in)),
        drawn from ``generator``; BatchNorm to weight 1, bias 0, running statistics reset."""
        for m in self.modules():
            if isinstance(m, (nn.Conv1d, nn.Linear)):
                nn.init.kaiming_uniform_(m.weight, a=math.sqrt(5), generator=generator)
                fan_in = m.weight[0].numel()
                bound = 1.0 / math.sqrt(fan_in)
                nn.init.uniform_(m.bias, -bound, bound, generator=generator)
            elif isinstance(m, nn.BatchNorm1d):
                m.reset_parameters()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (N, C, L) -> logits (N, n_classes)."""
        c, L = self.config["n_channels"], self.config["window"]
        if x.ndim != 3 or x.shape[1] != c or x.shape[2] != L:
            raise ValueError(f"InteractionCNN input: shape {tuple(x.shape)} should be (N, {c} channels, {L} frames)")
        return self.head(self.features(x))


def predict_proba(model: InteractionCNN, X: np.ndarray, batch_size: int = 4096) -> np.ndarray:
    """Class probabilities of standardised windows.

    Parameters
    ----------
    model : InteractionCNN
    X : np.ndarray, shape (N, C, L)
        Standardised windows.

    Returns
    -------
    np.ndarray float64, shape (N, n_classes)
        Softmax of the logits; rows sum to 1. The model is run in eval mode (BatchNorm's running
        statistics) and put back in the mode it was in.
    """
    was_training = model.training
    model.eval()
    out = []
    try:
        with torch.no_grad():
            for a in range(0, len(X), batch_size):
                out.append(model(torch.as_tensor(np.ascontiguousarray(X[a:a + batch_size]), dtype=torch.float32)).numpy())
    finally:
        model.train(was_training)
    logits = np.concatenate(out) if out else np.zeros((0, model.config["n_classes"]), np.float32)
    return softmax_probabilities(logits)
