"""The emission models of :mod:`mlsim.emission` over a batch of episodes at once, in torch.

The same physics as :func:`mlsim.emission.detrapping.detrapped_fraction` (piezoelectrically induced
de-trapping with first-order refilling, [Chandra2013]_) and
:func:`mlsim.emission.stress_rate.stress_rate_fraction` (the stress-rate limit, [Xu1999]_), the same
exact integration on the merged grid of solve steps and exposure edges, vectorised over episodes
and patches instead of one episode at a time, on any torch device (``device=``).

Episodes of one batch may have different step times and frame counts: each episode's merged grid
is built on the host (:func:`merged_grids`: sorting and ``searchsorted``, microseconds) and padded
to the longest with intervals of zero length; on such an interval the rate is zero, the traps do
not move and no photon is counted (``h = 0`` gives ``n(t + h) = n`` and an integral of zero in the
closed form), so padding changes no result.

Agreement with the per-episode numpy path (``tests/test_batched_chain.py``): the same float64
operations in the same order except ``exp``/``expm1`` (torch's and numpy's libm may differ by one
unit in the last place) and the cumulative sum (a parallel scan on a GPU): relative differences
of the order of the number of merged intervals times 1e-16, asserted at 1e-12.

References
----------
.. [Chandra2013] V. K. Chandra, B. P. Chandra, P. Jha, "Strong luminescence induced by elastic
   deformation of piezoelectric crystals", Appl. Phys. Lett. 102, 241105 (2013).
.. [Xu1999] C.-N. Xu, T. Watanabe, M. Akiyama, X.-G. Zheng, "Direct view of stress distribution in
   solid by mechanoluminescence", Appl. Phys. Lett. 74, 2414 (1999).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

__all__ = ["MergedGrids", "merged_grids", "von_mises_batched", "fraction_batched", "photon_radiance_batched"]

#: the models this module integrates (``emission.model``), as :data:`mlsim.emission.EMISSION_MODELS`
MODELS = ("detrapping", "stress_rate")


@dataclass(frozen=True)
class MergedGrids:
    """Each episode's merged grid of step times and exposure edges, padded to one length G.

    times (B, G) float64 s; lo, hi (B, G) int64: the steps before and after each merged time;
    w (B, G) float64: its linear weight between them (the stress is held before the first and after
    the last step); ranges (B, F, 2) int64: each window's [a, b) of merged intervals (padded frames:
    an empty range); frames (B,) int64: each episode's frame count; length_s (B, F) float64: the
    windows' lengths (1 on padded frames)."""

    times: torch.Tensor
    lo: torch.Tensor
    hi: torch.Tensor
    w: torch.Tensor
    ranges: torch.Tensor
    frames: torch.Tensor
    length_s: torch.Tensor

    def to(self, device) -> "MergedGrids":
        return MergedGrids(*(getattr(self, f).to(device) for f in ("times", "lo", "hi", "w", "ranges", "frames", "length_s")))


def merged_grids(t_s: list, windows_s: list, device="cpu") -> MergedGrids:
    """The :class:`MergedGrids` of B episodes: ``t_s[b]`` (S_b,) strictly increasing step times,
    ``windows_s[b]`` (F_b, 2) exposure windows [start, end) with start < end. The grid of one
    episode is :func:`mlsim.emission.detrapping.merged_grid`'s."""
    if len(t_s) != len(windows_s) or not len(t_s):
        raise ValueError(f"t_s and windows_s: one array per episode, got {len(t_s)} and {len(windows_s)}")
    per = []
    for b, (t, win) in enumerate(zip(t_s, windows_s)):
        t = np.asarray(t, dtype=float)
        win = np.asarray(win, dtype=float)
        if t.ndim != 1 or len(t) < 1 or np.any(np.diff(t) <= 0) or not np.all(np.isfinite(t)):
            raise ValueError(f"t_s[{b}]: must be a 1-D array of finite, strictly increasing times (the solve's steps)")
        if win.ndim != 2 or win.shape[1] != 2 or not np.all(np.isfinite(win)) or np.any(win[:, 1] <= win[:, 0]):
            raise ValueError(f"windows_s[{b}] of shape {win.shape}: must be finite (F, 2) [start, end) pairs with start < end")
        times = np.unique(np.concatenate([t, win.ravel()]))
        lo = np.clip(np.searchsorted(t, times, side="right") - 1, 0, len(t) - 1)
        hi = np.minimum(lo + 1, len(t) - 1)
        span = t[hi] - t[lo]
        w = np.where(span > 0, np.clip((times - t[lo]) / np.where(span > 0, span, 1.0), 0.0, 1.0), 0.0)
        ranges = np.stack([np.searchsorted(times, win[:, 0]), np.searchsorted(times, win[:, 1])], axis=1)
        per.append((times, lo, hi, w, ranges, win[:, 1] - win[:, 0]))
    B, G, F = len(per), max(len(p[0]) for p in per), max(len(p[4]) for p in per)
    times = np.empty((B, G))
    lo = np.empty((B, G), np.int64)
    hi = np.empty((B, G), np.int64)
    w = np.zeros((B, G))
    ranges = np.zeros((B, F, 2), np.int64)
    length = np.ones((B, F))
    for b, (tm, l, h, ww, rg, ln) in enumerate(per):
        g, f = len(tm), len(rg)
        # padding repeats the last merged time and stress: intervals of zero length, no light
        times[b, :g], times[b, g:] = tm, tm[-1]
        lo[b, :g], lo[b, g:] = l, l[-1]
        hi[b, :g], hi[b, g:] = h, h[-1]
        w[b, :g], w[b, g:] = ww, ww[-1]
        ranges[b, :f] = rg
        length[b, :f] = ln
    frames = np.array([len(p[4]) for p in per], np.int64)
    return MergedGrids(*(torch.from_numpy(a).to(device) for a in (times, lo, hi, w, ranges, frames, length)))


def von_mises_batched(stress: torch.Tensor, tet: torch.Tensor | None = None) -> torch.Tensor:
    """sqrt(3 J2) (B, S, N) float64 Pa of the Voigt stress (B, S, 6, T) Pa (xx, yy, zz, yz, xz, xy) at
    the tets ``tet`` (N,) int64 (None: every tet, the stress already gathered at the patches):
    :func:`mlsim.emission.kernels.von_mises_at` of each episode, the same float64 operations in the
    same order ([Hill1950] in :mod:`mlsim.emission.equivalent_stress`)."""
    if stress.ndim != 4 or stress.shape[2] != 6:
        raise ValueError(f"stress of shape {tuple(stress.shape)}: must be (episodes, steps, 6, tets)")
    s = (stress if tet is None else stress.index_select(3, tet)).to(torch.float64)
    xx, yy, zz, yz, xz, xy = s.unbind(2)
    a, b, c = xx - yy, yy - zz, zz - xx
    return torch.sqrt(0.5 * (a * a + b * b + c * c) + 3.0 * (yz * yz + xz * xz + xy * xy))


def _on_grid(sigma: torch.Tensor, grids: MergedGrids) -> torch.Tensor:
    """sigma (B, S, N) interpolated onto the merged times: (B, G, N)."""
    n = sigma.shape[2]
    lo = sigma.gather(1, grids.lo[:, :, None].expand(-1, -1, n))
    hi = sigma.gather(1, grids.hi[:, :, None].expand(-1, -1, n))
    w = grids.w[:, :, None]
    return lo * (1.0 - w) + hi * w


def fraction_batched(sigma_eq_pa: torch.Tensor, grids: MergedGrids, model: str = "detrapping", detrapping_per_pa: float = 2e-7,
                     recovery_time_s: float = 1.0, n0: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The fraction of each patch's traps emptied radiatively in each window, for B episodes.

    Parameters
    ----------
    sigma_eq_pa : (B, S, N) float64 tensor
        Equivalent stress of N patches at each episode's S steps (padded steps: any finite value,
        never read past ``grids``), Pa.
    grids : MergedGrids
        :func:`merged_grids` of the episodes, on the same device.
    model : "detrapping" or "stress_rate"
        :mod:`mlsim.emission.detrapping` (k, tau) or :mod:`mlsim.emission.stress_rate` (k only).
    detrapping_per_pa, recovery_time_s : float
        k (1/Pa) and tau (s; ``inf``: no refilling), as the scene's ``emission`` section.
    n0 : (B, N) float64 tensor, optional
        Filled trap fraction at each episode's first step (default 1: rested).

    Returns
    -------
    fraction : (B, F, N) float64
        Per window (zeros on padded frames).
    filled : (B, N) float64 or None
        The filled fraction at the end (None for ``stress_rate``, which has no memory).
    """
    if model not in MODELS:
        raise ValueError(f'"{model}" is not an emission model of the batched chain; choose one of: {", ".join(MODELS)}')
    if not (np.isfinite(detrapping_per_pa) and detrapping_per_pa >= 0):
        raise ValueError(f"detrapping_per_pa = {detrapping_per_pa}: must be finite and >= 0")
    if not recovery_time_s > 0:
        raise ValueError(f"recovery_time_s = {recovery_time_s}: must be > 0 (inf for no refilling)")
    if sigma_eq_pa.ndim != 3 or sigma_eq_pa.shape[0] != grids.times.shape[0]:
        raise ValueError(f"sigma_eq_pa of shape {tuple(sigma_eq_pa.shape)}: must be (episodes, steps, patches) with "
                         f"{grids.times.shape[0]} episodes")
    if not bool(torch.isfinite(sigma_eq_pa).all()):
        raise ValueError("sigma_eq_pa: contains NaN or Inf; the solve's stress history must be finite (check the solve stage)")
    sig = _on_grid(sigma_eq_pa.to(torch.float64), grids)  # (B, G, N)
    B, G, N = sig.shape
    h = (grids.times[:, 1:] - grids.times[:, :-1])[:, :, None]  # (B, G - 1, 1); 0 on padding
    k = float(detrapping_per_pa)
    rise = torch.clamp(sig[:, 1:] - sig[:, :-1], min=0.0)
    if model == "stress_rate":
        per_interval = k * rise
        filled = None
    else:
        inv_tau = 1.0 / float(recovery_time_s)
        pos = h > 0
        safe_h = torch.where(pos, h, torch.ones_like(h))
        rate = torch.where(pos, k * rise / safe_h, torch.zeros_like(rise))  # 1/s, constant on the interval
        n = torch.ones(B, N, dtype=torch.float64, device=sig.device) if n0 is None else n0.to(torch.float64).clone()
        per_interval = torch.empty_like(rate)
        # sequential in time (the recurrence), vectorised over episodes and patches; the same
        # operations as detrapped_fraction's loop
        for j in range(G - 1):
            hj, r = h[:, j], rate[:, j]
            lam = r + inv_tau
            decay = torch.exp(-lam * hj)
            live = lam > 0
            safe = torch.where(live, lam, torch.ones_like(lam))
            mean_factor = torch.where(live, -torch.expm1(-lam * hj) / safe, hj.expand_as(lam))
            n_inf = torch.where(live, inv_tau / safe, n)
            per_interval[:, j] = r * (n_inf * hj + (n - n_inf) * mean_factor)
            n = n_inf + (n - n_inf) * decay
        filled = n
    cumulative = torch.cat([torch.zeros(B, 1, N, dtype=torch.float64, device=sig.device), torch.cumsum(per_interval, dim=1)], dim=1)
    a = grids.ranges[:, :, 0:1].expand(-1, -1, N)
    b = grids.ranges[:, :, 1:2].expand(-1, -1, N)
    return cumulative.gather(1, b) - cumulative.gather(1, a), filled


def photon_radiance_batched(fraction: torch.Tensor, grids: MergedGrids, area_m2: torch.Tensor, brightness_photons_per_m2: float,
                            scale: float) -> torch.Tensor:
    """Lambertian radiance (B, F, N) float64, photons s^-1 m^-2 sr^-1, of each patch per window:
    photons per second B scale fraction A / t_window (:func:`mlsim.emission.photon_rates`) over
    pi A (:func:`mlsim.render.sensor_scene.radiance_of`), in that order of operations.

    fraction (B, F, N): :func:`fraction_batched`; area_m2 (N,) float64 m^2."""
    if not (np.isfinite(brightness_photons_per_m2) and brightness_photons_per_m2 >= 0 and np.isfinite(scale) and scale >= 0):
        raise ValueError(f"brightness_photons_per_m2 = {brightness_photons_per_m2}, scale = {scale}: must be finite and >= 0")
    area = area_m2.to(torch.float64)
    photons = brightness_photons_per_m2 * scale * fraction * area[None, None, :] / grids.length_s[:, :, None]
    return photons / (np.pi * area)[None, None, :]
