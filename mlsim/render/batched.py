"""The render's part that is linear in the radiance, over a batch of episodes at once, in torch.

The ``transport`` and ``deformed`` tiers (:mod:`mlsim.render.transport`,
:mod:`mlsim.render.reprojection`) hold light transport as a sparse pixels x vertices matrix T: an
image is T e for per-vertex radiance e. A batch of frames of many episodes is then one sparse
times dense product, T (P, N) times E^T (N, B F), which is what a GPU does well (cuSPARSE SpMM)
and what :meth:`mlsim.render.transport.TransportMatrix.apply` does frame batch by frame batch on
the CPU (numba, :func:`mlsim.render.kernels.csr_times_dense`).

The deformed tier's direct light is not linear in anything a batch shares: it is rasterised on
each frame's own deformed sheet (:mod:`mlsim.render.direct_raster`, a z-buffer in numba). It enters
here as images (``direct``), computed by that rasteriser, to which the bounces are added; the
measured split of the costs is in ``docs/uses/datasets.md``, "The batched chain" (the raster is most of the
render, and stays per frame on the CPU).

Agreement with :meth:`TransportMatrix.apply` (``tests/test_batched_chain.py``): both sum float32
products of non-negative numbers, in different orders, so each pixel agrees to a few float32
roundings of its own value: asserted at a relative 1e-5 per pixel.
"""

from __future__ import annotations

import warnings

import numpy as np
import torch

__all__ = ["transport_operator", "transport_batched"]


def transport_operator(indptr, indices, data, shape: tuple[int, int], device="cpu") -> torch.Tensor:
    """The transport matrix (P, N) as a torch sparse CSR float32 tensor on ``device``, from its CSR
    arrays (``TransportMatrix.matrix.indptr``, ``.indices``, ``.data``; P = H W pixels, N vertices)."""
    indptr, indices, data = (np.asarray(a) for a in (indptr, indices, data))
    if not np.all(np.isfinite(data)):
        raise ValueError("transport matrix data: contains NaN or Inf; trace the matrix again (a corrupt cache entry?)")
    if len(indptr) != shape[0] + 1:
        raise ValueError(f"indptr of length {len(indptr)}: must be pixels + 1 = {shape[0] + 1}")
    with warnings.catch_warnings():
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta state")
        return torch.sparse_csr_tensor(torch.from_numpy(indptr.astype(np.int64)), torch.from_numpy(indices.astype(np.int64)),
                                       torch.from_numpy(data.astype(np.float32)), size=tuple(shape), dtype=torch.float32,
                                       device=device, check_invariants=False)


def transport_batched(T: torch.Tensor, radiance: torch.Tensor, height_px: int, width_px: int, direct: torch.Tensor | None = None
                      ) -> torch.Tensor:
    """Radiance images (..., H, W) float32 of per-vertex radiance (..., N) through the transport
    matrix T (H W, N) (:func:`transport_operator`), plus ``direct`` (..., H, W) float32 when given
    (the deformed tier's rasterised direct light).

    radiance: photons s^-1 m^-2 sr^-1 per vertex, finite and >= 0 (float32 or float64, rounded to
    float32 first as :meth:`mlsim.render.transport.TransportMatrix.apply` does)."""
    lead = tuple(radiance.shape[:-1])
    if radiance.shape[-1] != T.shape[1]:
        raise ValueError(f"radiance of shape {tuple(radiance.shape)}: the last axis must be the matrix's {T.shape[1]} vertices")
    if T.shape[0] != height_px * width_px:
        raise ValueError(f"the matrix has {T.shape[0]} pixel rows, not {height_px} x {width_px}: it was traced for another view")
    e = radiance.to(torch.float32).reshape(-1, T.shape[1])
    if not bool(torch.isfinite(e).all()):
        raise ValueError("radiance (..., vertices) into the transport matrix's product: contains NaN or Inf; it comes from the emission "
                         "stage's photons: check the emission and the solve's stresses that feed it")
    images = (T @ e.T).T.reshape(lead + (height_px, width_px))
    if direct is not None:
        if tuple(direct.shape) != lead + (height_px, width_px):
            raise ValueError(f"direct of shape {tuple(direct.shape)}: must be {lead + (height_px, width_px)}")
        if not bool(torch.isfinite(direct).all()):
            raise ValueError("direct (the rasterised direct light): contains NaN or Inf; check the raster's radiance and vertices")
        images = direct.to(torch.float32) + images
    return images
