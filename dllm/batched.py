"""The DLLM on whole episodes at once: the same events and features as the streaming
:class:`dllm.detector.Dllm`, run on each episode from a fresh state (SPEC 1.6).

The detector's work splits in two. The per-pixel part, grey level, the frame sum M(t) and the taxel
sums (H_n, Sx_n, Sy_n) (:mod:`dllm.features`), does not depend on the thresholds, so it runs for
every frame of every episode in chunks (:func:`frame_statistics`). The threshold recursion
(:mod:`dllm.detector`'s docstring) is sequential in time but cheap: it runs over the frames once,
vectorised over the episodes (:func:`threshold_gates`), and the features of the firing taxels
follow in one vectorised pass (:func:`batched_features`).

Why the results are identical to the streaming path, not merely close:

- grey levels are OpenCV's own: on the CPU ``cv2.cvtColor`` itself, frame by frame, elsewhere
  :func:`rgb_to_grey` computes OpenCV's fixed-point formula
  Y = (9798 R + 19235 G + 3735 B + 2^14) >> 15 in integers (bit-exact against cv2 on all 2^24
  colours; the 14-bit variant with weights 4899, 9617, 1868 differs on 0.26 % of them);
- M, H, Sx and Sy are sums of integers (grey levels times pixel coordinates) far below 2^53, so
  float64 holds them exactly whatever the order of summation;
- the recursion and the features apply the streaming path's float64 operations, in its order, to
  those identical inputs. The streaming path skips the taxel sums of discarded frames; here they
  are computed for every frame and not read on discarded ones.

Cost (``benchmarks/bench_dllm.py``, 350 x 350, 2 cores): 65-95 us per frame whatever the frame
holds (torch on 1 or 2 threads), against the streaming path's 22 us on a discarded frame and 70 us
on an event. The per-pixel kernels are OpenCV's on both paths and bound by memory; batching saves
the Python work per event, but computes the taxel sums that the streaming path skips on discarded
frames. Its use is one call for many episodes with arrays out, and torch devices.

kornia is not used: its ``rgb_to_grayscale`` is the floating-point 0.299 R + 0.587 G + 0.114 B,
which rounds differently from OpenCV's fixed point, and nothing else of the detector is an image
filter.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, field

import numpy as np
import torch

from dllm.calibration import Calibration
from dllm.detector import DllmParams
from dllm.features import TaxelIndex, taxel_index

__all__ = ["OPENCV_GREY_WEIGHTS", "rgb_to_grey", "frame_statistics", "threshold_gates", "batched_features",
           "dllm_batched", "BatchedDllm"]

#: OpenCV's fixed-point RGB -> grey weights for 8-bit images (R, G, B); they sum to 2^15.
OPENCV_GREY_WEIGHTS = (9798, 19235, 3735)
_GREY_SHIFT = 15


def rgb_to_grey(frames: torch.Tensor) -> torch.Tensor:
    """OpenCV's ``COLOR_RGB2GRAY`` of 8-bit frames, on any device.

    Parameters
    ----------
    frames : (..., H, W, 3) uint8 tensor
        RGB.

    Returns
    -------
    (..., H, W) uint8 tensor
        Y = (9798 R + 19235 G + 3735 B + 2^14) >> 15, OpenCV's rounding.
    """
    if not isinstance(frames, torch.Tensor) or frames.dtype != torch.uint8 or frames.ndim < 3 or frames.shape[-1] != 3:
        raise ValueError(f"frames: expected a (..., H, W, 3) uint8 tensor, got {type(frames).__name__} "
                         f"{getattr(frames, 'dtype', '')} {tuple(getattr(frames, 'shape', ()))}")
    wr, wg, wb = OPENCV_GREY_WEIGHTS
    # int32: the weighted sum reaches 255 * 2^15 + 2^14, beyond int16; integers, not a float matmul,
    # so that no TF32 or reduced-precision setting can move a rounding
    x = frames.to(torch.int32)
    y = x[..., 0] * wr + x[..., 1] * wg + x[..., 2] * wb + (1 << (_GREY_SHIFT - 1))
    return (y >> _GREY_SHIFT).to(torch.uint8)


@dataclass(frozen=True)
class _TaxelOperator:
    """The taxel sums as a gather and one sparse product: ``pixels`` (P,) flat indices of the disks;
    ``weights`` (3N, P) CSR float64, rows n, N + n and 2N + n hold 1, x and y on taxel n's pixels."""

    pixels: torch.Tensor
    weights: torch.Tensor
    n_taxels: int


def _taxel_operator(index: TaxelIndex, device: torch.device) -> _TaxelOperator:
    n, p = index.n_taxels, len(index.pixels)
    counts = np.diff(np.r_[index.starts, p])
    # row k N + n of the (3N, P) matrix spans taxel n's run of pixels, the same run for every k
    crow = np.r_[0, np.cumsum(np.tile(counts, 3))]
    col = np.tile(np.arange(p), 3)
    val = np.concatenate([np.ones(p), index.x, index.y])
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta state")
        weights = torch.sparse_csr_tensor(torch.from_numpy(crow), torch.from_numpy(col), torch.from_numpy(val),
                                          size=(3 * n, p), dtype=torch.float64, device=device, check_invariants=False)
    return _TaxelOperator(torch.from_numpy(np.asarray(index.pixels, np.int64)).to(device), weights, n)


def _disks_opencv(rgb: np.ndarray, pixels: np.ndarray, M: np.ndarray, disks: np.ndarray, grey: np.ndarray) -> None:
    """CPU: for each frame of (C, H, W, 3) uint8, its frame sum into M (C,) and the grey levels of
    the disks' pixels into disks (C, P) uint8, through the reusable (H, W) uint8 buffer grey.

    Frame by frame with OpenCV's own kernels, on a grey frame that stays in cache: 31 us per
    350 x 350 frame on the 2-core benchmark machine (20 of them cvtColor), where the same work on
    a whole chunk costs about 45 us through float32 copies in torch and over 1 ms through torch's
    int32 and uint8 kernels (:func:`rgb_to_grey`, ``sum``, ``index_select``).
    """
    import cv2

    for i, frame in enumerate(rgb):
        cv2.cvtColor(np.ascontiguousarray(frame), cv2.COLOR_RGB2GRAY, dst=grey)
        M[i] = cv2.sumElems(grey)[0]
        np.take(grey.reshape(-1), pixels, out=disks[i])


def _disks_torch(rgb: torch.Tensor, pixels: torch.Tensor, grey: torch.Tensor, disks: torch.Tensor) -> torch.Tensor:
    """Any device: the frame sums (C,) float64 of (C, H, W, 3) uint8 frames, and the disks' grey
    levels into disks (C, P) float32, through the (C, H W) float32 buffer grey."""
    c, h, w = rgb.shape[:3]
    grey.copy_(rgb_to_grey(rgb).view(c, h * w))
    # row sums in float32 are exact (at most 255 W < 2^24); the rows' sum in float64
    M = grey.view(c, h, w).sum(dim=2).sum(dim=1, dtype=torch.float64)
    torch.index_select(grey, 1, pixels, out=disks)  # float32: torch's uint8 gather is 5 x slower
    return M


def frame_statistics(frames, index: TaxelIndex, chunk_frames: int = 16, opencv: bool | None = None
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The per-pixel work of the DLLM for every frame: M(t) and the taxel sums.

    Parameters
    ----------
    frames : (F, H, W, 3) uint8, numpy array or tensor
        RGB frames matching ``index.shape_hw`` (not checked here: :func:`dllm_batched` does).
    index : TaxelIndex
        The taxels' disks (:func:`dllm.features.taxel_index`).
    chunk_frames : int
        Frames per chunk: the sums weighted by x and y are one sparse product per chunk.
    opencv : bool, optional
        Grey levels and frame sums from OpenCV frame by frame (default for numpy input and CPU
        tensors), or from :func:`rgb_to_grey` and torch on the tensor's device (the default for
        other devices); both give the same numbers.

    Returns
    -------
    M : (F,) float64
        Sum of all grey levels of each frame (the streaming path's ``cv2.sumElems``).
    sums : (F, N, 3) float64
        Per taxel (H_n, Sx_n, Sy_n): the sums of I, I x and I y over its disk
        (:func:`dllm.features.taxel_sums`).
    """
    device = frames.device if isinstance(frames, torch.Tensor) else torch.device("cpu")
    opencv = device.type == "cpu" if opencv is None else bool(opencv)
    if opencv:
        frames, device = (frames.cpu().numpy() if isinstance(frames, torch.Tensor) else frames), torch.device("cpu")
    elif not isinstance(frames, torch.Tensor):
        frames = torch.from_numpy(np.ascontiguousarray(frames))
    F, h, w = frames.shape[0], frames.shape[1], frames.shape[2]
    op = _taxel_operator(index, device)
    n, p = op.n_taxels, len(op.pixels)
    M = torch.empty(F, dtype=torch.float64, device=device)
    S = torch.empty(F, 3 * n, dtype=torch.float64, device=device)
    c_max = max(1, min(int(chunk_frames), F))
    # buffers reused by every chunk: a fresh multi-MB tensor per chunk costs its page faults again,
    # which on this CPU is more than the arithmetic
    disks_f64 = torch.empty(c_max, p, dtype=torch.float64, device=device)
    if opencv:
        grey_u8, pixels = np.empty((h, w), np.uint8), np.asarray(index.pixels, np.int64)
        disks_u8 = np.empty((c_max, p), np.uint8)
        M_np = M.numpy()
    else:
        grey_f32 = torch.empty(c_max, h * w, dtype=torch.float32, device=device)
        disks_f32 = torch.empty(c_max, p, dtype=torch.float32, device=device)
    for k0 in range(0, F, c_max):
        k1 = min(k0 + c_max, F)
        c = k1 - k0
        v = disks_f64[:c]
        if opencv:
            _disks_opencv(frames[k0:k1], pixels, M_np[k0:k1], disks_u8[:c], grey_u8)
            v.copy_(torch.from_numpy(disks_u8[:c]))
        else:
            M[k0:k1] = _disks_torch(frames[k0:k1], op.pixels, grey_f32[:c], disks_f32[:c])
            v.copy_(disks_f32[:c])
        # float64 for the sums weighted by x and y (up to 255 x W x the disk's pixels)
        S[k0:k1] = (op.weights @ v.T).T
    return M.cpu().numpy(), S.view(F, 3, n).transpose(1, 2).cpu().numpy()


def threshold_gates(M: np.ndarray, H: np.ndarray, params: DllmParams) -> tuple[np.ndarray, np.ndarray]:
    """The streaming detector's thresholds, gates and their update, for E episodes side by side.

    Parameters
    ----------
    M : (E, T) float64
        Frame sums M(t).
    H : (E, T, N) float64
        Taxel sums H_n(t) (read only on the initialisation frames and on events).
    params : DllmParams

    Returns
    -------
    events : (E, T) bool
        The global gate M(t) > alpha D passed (never during the first ``init_frames`` frames).
    firing : (E, T, N) bool
        Taxels over their gate H_n(t) > beta B_n on event frames.

    Every operation is the streaming path's, in its order (see :mod:`dllm.detector`), so equal
    inputs give equal thresholds bit for bit.
    """
    M, H = np.asarray(M, dtype=np.float64), np.asarray(H, dtype=np.float64)
    E, T = M.shape
    events = np.zeros((E, T), bool)
    firing = np.zeros(H.shape, bool)
    n0 = params.init_frames
    if T <= n0:
        return events, firing
    # means of integer-valued sums far below 2^53: exact, hence equal to the streaming np.mean
    D = M[:, :n0].mean(axis=1)
    B = H[:, :n0].mean(axis=1)
    a_adapt, a_recover = params.rates()
    for t in range(n0, T):
        m, h = M[:, t], H[:, t]
        event = ~(m <= params.alpha * D)
        fire = event[:, None] & (h > params.beta * B)
        # discarded: D follows M with adapt_s, B scales with D (not when D was 0, as streaming)
        D_discard = D + (m - D) * a_adapt
        scale = np.divide(D_discard, D, out=np.ones_like(D), where=D > 0)
        B_discard = B * scale[:, None]
        # event: D with recover_s, B_n with recover_s where the taxel fired, adapt_s elsewhere
        D_event = D + (m - D) * a_recover
        B_event = B + (h - B) * np.where(fire, a_recover, a_adapt)
        D = np.where(event, D_event, D_discard)
        B = np.where(event[:, None], B_event, B_discard)
        events[:, t], firing[:, t] = event, fire
    return events, firing


def batched_features(H: np.ndarray, Sx: np.ndarray, Sy: np.ndarray, centres_px: np.ndarray, firing: np.ndarray) -> np.ndarray:
    """:func:`dllm.features.taxel_features` over any leading dimensions.

    Parameters
    ----------
    H, Sx, Sy : (..., N) float64
        Taxel sums.
    centres_px : (N, 2) float64
        Taxel centres (column, row).
    firing : (..., N) bool

    Returns
    -------
    (..., N, 3) float64
        Z = (H_n, l_n px, omega_n deg in [0, 360)) for firing taxels with H_n > 0, zeros elsewhere.
    """
    H, Sx, Sy = (np.asarray(a, dtype=np.float64) for a in (H, Sx, Sy))
    z = np.zeros(H.shape + (3,))
    ok = np.asarray(firing, bool) & (H > 0)
    if ok.any():
        cx = np.broadcast_to(centres_px[:, 0], H.shape)[ok]
        cy = np.broadcast_to(centres_px[:, 1], H.shape)[ok]
        dx = Sx[ok] / H[ok] - cx
        dy = Sy[ok] / H[ok] - cy
        z[ok, 0] = H[ok]
        z[ok, 1] = np.hypot(dx, dy)
        z[ok, 2] = np.degrees(np.arctan2(-dy, dx)) % 360.0
    return z


def _check_episodes(frames, shape_hw: tuple[int, int]):
    """frames as (E, T, H, W, 3) uint8 (numpy or tensor) and whether a single episode was given."""
    is_tensor = isinstance(frames, torch.Tensor)
    f = frames if is_tensor else np.asarray(frames)
    if f.dtype != (torch.uint8 if is_tensor else np.uint8):
        floating = f.is_floating_point() if is_tensor else np.issubdtype(f.dtype, np.floating)
        nan = bool(torch.isnan(f).any()) if is_tensor and floating else (floating and bool(np.isnan(f).any()))
        raise ValueError(f"frames has dtype {f.dtype}{' (NaN values)' if nan else ''}: the detector reads 8-bit camera "
                         "frames (uint8); convert with np.clip(x, 0, 255).astype(np.uint8)")
    shape = tuple(f.shape)
    if len(shape) not in (4, 5) or shape[-1] != 3 or min(shape[-3:-1]) < 8:
        raise ValueError(f"frames has shape {shape}: must be (E, T, H, W, 3) episodes or (T, H, W, 3) one episode of RGB "
                         "frames, at least 8 x 8 (grey frames: np.repeat(g[..., None], 3, axis=-1) gives the same grey levels)")
    if shape[-3:-1] != tuple(shape_hw):
        raise ValueError(f"frames are of {shape[-3:-1]} pixels, but the calibration is of {tuple(shape_hw)}: "
                         "calibrate on a frame of this camera")
    return (f if len(shape) == 5 else f[None]), len(shape) == 4


def dllm_batched(frames, index: TaxelIndex, params: DllmParams | None = None, chunk_frames: int = 16,
                 opencv: bool | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The streaming detector's output for each of E episodes, each from a fresh state.

    Parameters
    ----------
    frames : (E, T, H, W, 3) or (T, H, W, 3) uint8, numpy array or tensor
        RGB camera frames; (T, H, W, 3) is one episode.
    index : TaxelIndex
        The taxels (:func:`dllm.features.taxel_index` of the calibration).
    params : DllmParams, optional
        Default ``DllmParams()``.
    chunk_frames : int
        Frames per chunk of the per-pixel pass (:func:`frame_statistics`).
    opencv : bool, optional
        See :func:`frame_statistics`.

    Returns
    -------
    events : (E, T) bool, or (T,) for one episode
    features : (E, T, N, 3) float64, or (T, N, 3)
        Z = (H_n, l_n px, omega_n deg): what ``Dllm(calibration, params).run(episode)`` returns.

    Raises
    ------
    ValueError
        When frames are not uint8, not RGB of at least 8 x 8, or not of the calibration's size.
    """
    params = params if params is not None else DllmParams()
    if not (isinstance(chunk_frames, (int, np.integer)) and chunk_frames >= 1):
        raise ValueError(f"chunk_frames = {chunk_frames!r}: must be an integer >= 1")
    episodes, single = _check_episodes(frames, index.shape_hw)
    E, T, n = episodes.shape[0], episodes.shape[1], index.n_taxels
    M = np.empty((E, T))
    sums = np.empty((E, T, n, 3))
    for e in range(E):  # an episode at a time: a non-contiguous batch is never copied whole
        if T:
            M[e], sums[e] = frame_statistics(episodes[e], index, chunk_frames, opencv)
    events, firing = threshold_gates(M, sums[..., 0], params)
    features = batched_features(sums[..., 0], sums[..., 1], sums[..., 2], index.centres_px, firing)
    return (events[0], features[0]) if single else (events, features)


@dataclass
class BatchedDllm:
    """:func:`dllm_batched` with the calibration's :class:`TaxelIndex` built once.

    ``run(frames)`` takes (E, T, H, W, 3) or (T, H, W, 3) uint8 frames and returns what
    :meth:`dllm.detector.Dllm.run` returns for each episode."""

    calibration: Calibration
    params: DllmParams = field(default_factory=DllmParams)
    chunk_frames: int = 16

    def __post_init__(self):
        self.index: TaxelIndex = taxel_index(self.calibration)

    def run(self, frames) -> tuple[np.ndarray, np.ndarray]:
        return dllm_batched(frames, self.index, self.params, self.chunk_frames)
