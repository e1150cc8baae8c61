"""The causal contact CNN of the AnySkin helmet (SPEC 2): slope windows G_t -> {idle, onset, release}.

SPEC 2: "a global scalar normalisation, then causal conv (kernel 5, 8 channels, stride 2, GELU), then
causal conv (kernel 3, 16 channels, stride 2, GELU), then a classifier head; causality by left padding
of (K - 1) d". The network here is shared by all channels: one channel's window of its last L slopes
g (uT/s, oldest first) is one input sequence of one feature, and its output is that channel's class
(SPEC: "maps G_t (L x C) to one of {idle 0, onset 1, release 2} per channel"; sharing the weights
across the 20 channels is a choice: the chips differ in gain, not in the shape of a press).

Choices where SPEC 2 is silent:

- the normalisation divides by one scalar ``scale`` (uT/s), the standard deviation of the training
  slopes, stored with the weights (a buffer, not trained);
- each causal convolution is left-padded by (K - 1) d, plus ``(1 - n) mod stride`` more samples so
  that the stride grid ends on the newest sample (without it a stride-2 layer on L = 50 drops the
  newest slope, the one that matters most for a prompt onset); no right padding anywhere, so the
  output at position j of every layer depends only on inputs at positions <= j of the layer below;
- the head is one linear layer on the flattened last feature map (16 x 14 for L = 50): the cheapest
  head that sees where in the window a slope peak lies (a pooled head would not), which keeps
  inference >= 100 x real time on one core (``benchmarks/bench_anyskin.py``).

:func:`causal_features` runs the convolutions over a whole sequence, which the causality test uses:
perturbing inputs after position t never changes its features at positions <= t.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["CausalConv1d", "ContactCNN", "causal_padding", "predict_events", "save_contact_cnn", "load_contact_cnn",
           "CONTACT_CNN_FORMAT", "N_EVENTS"]

CONTACT_CNN_FORMAT = "mlsim.anyskin.contact_cnn"
_VERSION = 1
N_EVENTS = 3  # idle 0, onset 1, release 2 (SPEC 2)
LAYERS = ((8, 5, 2), (16, 3, 2))  # (channels, kernel, stride) per causal convolution, SPEC 2


def causal_padding(n: int, kernel: int, stride: int, dilation: int = 1) -> tuple[int, int]:
    """Left padding of a causal convolution on n samples and the output length.

    (K - 1) d (SPEC 2) plus (1 - n) mod stride so that the last output's receptive field ends on the
    newest input; returns (left padding, output length).
    """
    pad = (kernel - 1) * dilation + (1 - n) % stride
    span = (kernel - 1) * dilation + 1
    return pad, (n + pad - span) // stride + 1


class CausalConv1d(nn.Module):
    """A 1-D convolution padded on the left only: output j sees inputs <= j's newest sample."""

    def __init__(self, c_in: int, c_out: int, kernel: int, stride: int = 1, dilation: int = 1):
        super().__init__()
        self.kernel, self.stride, self.dilation = kernel, stride, dilation
        self.conv = nn.Conv1d(c_in, c_out, kernel, stride=stride, dilation=dilation)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        pad, _ = causal_padding(x.shape[-1], self.kernel, self.stride, self.dilation)
        return self.conv(F.pad(x, (pad, 0)))


class ContactCNN(nn.Module):
    """Scalar normalisation, causal conv 5/8/2 + GELU, causal conv 3/16/2 + GELU, linear head (SPEC 2).

    Parameters
    ----------
    window : int
        L, slopes per window (SPEC 2: 50).
    scale : float
        The global normalisation, uT/s (the training slopes' standard deviation).

    The initial weights are PyTorch's defaults; a training seeds them without touching the global
    generator's state (``torch.random.fork_rng``, :mod:`classifiers.anyskin_train`).
    """

    def __init__(self, window: int = 50, scale: float = 1.0):
        super().__init__()
        self.window = int(window)
        self.register_buffer("scale", torch.tensor(float(scale)))
        n, convs, c_in = self.window, [], 1
        for c_out, k, s in LAYERS:
            convs.append(CausalConv1d(c_in, c_out, k, s))
            n, c_in = causal_padding(n, k, s)[1], c_out
        self.convs = nn.ModuleList(convs)
        self.head = nn.Linear(c_in * n, N_EVENTS)

    def features(self, g: torch.Tensor) -> torch.Tensor:
        """g (N, L') uT/s -> the last feature map (N, 16, n'); causal along the last axis for any L'."""
        x = (g / self.scale).unsqueeze(1)
        for conv in self.convs:
            x = F.gelu(conv(x))
        return x

    def forward(self, g: torch.Tensor) -> torch.Tensor:
        """g (N, L) slope windows, uT/s, oldest first -> logits (N, 3)."""
        if g.shape[-1] != self.window:
            raise ValueError(f"slope windows of {g.shape[-1]} samples; this CNN was built for L = {self.window}")
        return self.head(self.features(g).flatten(1))


def causal_features(model: ContactCNN, slopes) -> np.ndarray:
    """The convolutional features of one long slope sequence (n,) -> (16, n'), for the causality test."""
    with torch.no_grad():
        return model.features(torch.as_tensor(np.asarray(slopes, dtype=np.float32))[None])[0].numpy()


def predict_events(model: ContactCNN, windows) -> np.ndarray:
    """Classes (N,) int of slope windows (N, L) uT/s: the argmax of the logits, one batched call."""
    w = np.asarray(windows, dtype=np.float32)
    if len(w) == 0:
        return np.zeros(0, dtype=int)
    with torch.inference_mode():
        return model(torch.from_numpy(w)).argmax(dim=1).numpy().astype(int)


def save_contact_cnn(model: ContactCNN, path, meta: dict | None = None) -> Path:
    """Write the CNN (its weights, L, scale and the training's meta data: plain values) to one file."""
    payload = {"format": CONTACT_CNN_FORMAT, "version": _VERSION, "window": model.window,
               "state_dict": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()}, "meta": dict(meta or {})}
    return save_payload(payload, path)


def save_payload(payload: dict, path) -> Path:
    """torch.save ``payload`` to ``path`` atomically (:func:`mlsim.io.atomic_bytes`), making its folder."""
    import io

    from mlsim.io import atomic_bytes

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    buffer = io.BytesIO()
    torch.save(payload, buffer)
    return atomic_bytes(path, buffer.getvalue())


def load_contact_cnn(path) -> ContactCNN:
    """Read a file of :func:`save_contact_cnn`; a ValueError names the file and how to make one."""
    d = _load(path, CONTACT_CNN_FORMAT)
    model = ContactCNN(int(d["window"]))
    model.load_state_dict(d["state_dict"])
    model.meta = d.get("meta", {})
    return model.eval()


def _load(path, fmt: str) -> dict:
    path = Path(path)
    hint = "train one with 'mlsim anyskin-train SCENE --out DIR'"
    if not path.is_file():
        raise ValueError(f"model file {path}: not found; {hint}")
    try:
        d = torch.load(path, map_location="cpu", weights_only=True)  # tensors and plain values only: nothing executes
    except Exception as exc:  # torch raises several types (UnpicklingError, RuntimeError, EOFError)
        raise ValueError(f"model file {path}: not a torch file ({type(exc).__name__}); {hint}") from None
    if not isinstance(d, dict) or d.get("format") != fmt:
        raise ValueError(f"model file {path}: not a {fmt} file; {hint}")
    if d.get("version") != _VERSION:
        raise ValueError(f"model file {path}: version {d.get('version')!r}, this mlsim reads {_VERSION}; {hint}")
    return d
