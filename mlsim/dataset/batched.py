"""The per-frame chain after the solve, for many episodes of one sensor at once (issue 40, items 3-4).

A dataset runs each episode's stages one after the other (:mod:`mlsim.dataset.generate`). The
stages after the solve are array work over frames that every episode of a sensor shares the
shape of, so a batch of episodes can run them as a few large tensor operations, on the CPU or on
a GPU (``device=``), through the pure torch functions of each stage:

1. emission (:mod:`mlsim.emission.batched`): the solve's stress at the emitting patches' tets ->
   von Mises -> de-trapping on each episode's merged grid -> Lambertian radiance per vertex;
2. render (:mod:`mlsim.render.batched`): the deformed tier's bounces, one sparse product with the
   rest shape's matrix for all frames of all episodes, added to the direct light that the numba
   rasteriser draws on each frame's deformed sheet on the host
   (:meth:`mlsim.render.direct_raster.DirectRaster.images`; the direct part depends on each
   frame's own geometry, so there is nothing to batch in it: see ``docs/uses/datasets.md`` (the batched chain)
   for the measured split);
3. camera (:mod:`mlsim.camera_batched`): the DLLM's idle frames before each episode (SPEC 1.6)
   and its frames, photon transfer, noise from one seeded ``torch.Generator`` per episode, ADC,
   demosaic;
4. DLLM (:mod:`dllm.batched`): the per-pixel sums of every frame, the threshold recursion over
   the episodes side by side, the features.

:class:`BatchedChain` is the thin wrapper: it holds the sensor's parts (patches, matrix, raster,
camera constants, the DLLM's taxels), made once from a scene through the pipeline's cache, and
runs a list of solved episodes. Its scope: the deformed render tier without an ambient lamp
change per episode (the lamp's leak is one image, its level per frame follows the windows), the
episodes sharing the scene (sensor, view, camera, emission; only the load and the noise seed
differ, as in a dataset without randomisation).

Against the per-episode chain: deterministic stages equal to float tolerance, the camera's noise
the same model from another generator (torch's, not numpy's), so its frames and the DLLM's
features agree in distribution, not in bytes (``tests/test_batched_chain.py``,
``benchmarks/bench_batched_chain.py``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import partial

import numpy as np
import torch

from mlsim.camera_batched import CameraConstants, capture_mono_batched
from mlsim.emission.batched import fraction_batched, merged_grids, photon_radiance_batched, von_mises_batched
from mlsim.render.batched import transport_batched, transport_operator

__all__ = ["BatchedChain", "ChainOutput", "resolve_device"]


def resolve_device(requested: str = "auto", cuda_available: bool | None = None) -> tuple[str, str]:
    """The torch device the batched chain runs on, and why (for the run log):
    :func:`mlsim.render.sensor_scene.choose_device` by torch's answer (``torch.cuda.is_available()`` when
    ``cuda_available`` is None)."""
    from mlsim.render.sensor_scene import choose_device

    def status():
        if torch.cuda.is_available() if cuda_available is None else bool(cuda_available):
            return True, f"torch finds CUDA ({torch.cuda.get_device_name(0) if torch.cuda.is_available() else 'a device'})"
        return False, (f"torch finds no CUDA device here (torch {torch.__version__}, CUDA build {torch.version.cuda or 'none'}, "
                       "torch.cuda.is_available() is False)")

    return choose_device(requested, "device", status)


@dataclass
class ChainOutput:
    """Per episode: radiance (F, H, W) float32 (when kept), frames (F, H, W, 3) uint8 (when kept),
    DLLM events (F,) bool and features (F, N, 3) float64 (H_n, l_n px, omega_n deg); seconds per part."""

    radiance: list
    frames: list
    events: list
    features: list
    seconds: dict = field(default_factory=dict)


class BatchedChain:
    """The chain after the solve for a batch of episodes of one scene's sensor.

    ``BatchedChain.from_scene(scene, first_episode, cache, device="cpu")``; then
    ``run(episodes, noise_seeds)``. See the module docstring."""

    def __init__(self, *, tet, area_m2, vertices_m, located, model, params, brightness, scale, fps, exposure_s, transport, raster,
                 camera: CameraConstants, k_ml, ambient, ambient_level, k_ambient, taxels, dllm_params, n_idle, device="cpu",
                 rod_of_taxel=None):
        self.device = torch.device(device)
        self.tet = torch.as_tensor(np.asarray(tet, np.int64), device=self.device)
        self.area = torch.as_tensor(np.asarray(area_m2, np.float64), device=self.device)
        self.vertices_m, self.located = vertices_m, located
        self.model, self.params, self.brightness, self.scale = model, params, float(brightness), float(scale)
        self.fps, self.exposure_s = float(fps), float(exposure_s)
        m = transport.matrix
        self.T = transport_operator(m.indptr, m.indices, m.data, m.shape, self.device)
        self.height_px, self.width_px = int(transport.height_px), int(transport.width_px)
        self.raster = raster
        self.camera = camera
        self.k_ml = torch.as_tensor(np.asarray(k_ml, np.float32), device=self.device)
        self.ambient = None if ambient is None else torch.as_tensor(np.asarray(ambient, np.float32), device=self.device)
        self.ambient_level = ambient_level  # (windows (F, 2) s) -> (F,) lamp level
        self.k_ambient = torch.as_tensor(np.asarray(k_ambient, np.float32), device=self.device)
        self.taxels, self.dllm_params, self.n_idle = taxels, dllm_params, int(n_idle)
        self.rod_of_taxel = rod_of_taxel  # (N,) the rod each taxel sees (the DLLM's calibration), for a dataset's record

    @classmethod
    def from_scene(cls, scene, first_episode, cache, device="cpu", log=lambda _m: None) -> "BatchedChain":
        """The sensor's parts of ``scene`` (deformed render tier) from the pipeline's cache (built
        there if missing): patches, the bounces' matrix and the raster, the camera, the DLLM's
        calibration. ``first_episode``: a solved episode of the sensor (its mesh locates the sheet)."""
        from dllm.detector import DllmParams
        from dllm.features import taxel_index
        from dllm.stage import _calibration_of
        from mlsim import emission, pipeline
        from mlsim.materials import phosphor_relative_brightness
        from mlsim.render import ambient as ambient_mod
        from mlsim.render.optics import camera_params, channel_factors_of, ml_channel_factors
        from mlsim.render.stage import _ambient_image, _deformed_parts, _sheet
        from mlsim.emission.stage import patches_in_mesh, patches_of

        if scene.fidelity.render.tier != "deformed":
            raise ValueError(f'fidelity.render.tier = "{scene.fidelity.render.tier}": the batched chain runs the deformed tier; '
                             'set fidelity.render.tier = "deformed" or run the episodes one by one')
        res = pipeline.run(scene, cache=cache, outputs=("geometry", "mesh", "calibration"), progress=False, log=log)
        geometry, (mesh, _) = res.results["geometry"], res.results["mesh"]
        ctx = pipeline.RunContext(scene, cache, None, False, log)
        patches = patches_of(scene, geometry, mesh, ctx)
        sheet = _sheet(scene, patches, ctx)
        transport, raster = _deformed_parts(scene, sheet, ctx)
        located = patches_in_mesh(scene, first_episode.mesh_points, first_episode.mesh_tets, patches, ctx)
        spec = scene.emission
        m = emission.emission_model(spec.model)
        if spec.equivalent_stress != "von_mises":
            raise ValueError(f'emission.equivalent_stress = "{spec.equivalent_stress}": the batched chain computes von Mises only; '
                             "run the episodes one by one for the others")
        scale = float(scene.material("ml_layer").relative_ml_peak.value) * float(phosphor_relative_brightness(scene.sensor.phosphor.loading_wt_pct))
        params = camera_params(scene)
        amb = level_of = None
        k_amb = np.zeros(3, np.float32)
        if scene.ambient.lamp != "none":
            amb = _ambient_image(scene, patches, sheet, transport, raster)[0]
            a = scene.ambient
            sd = ambient_mod.leaked_photon_sd(a.lamp, scene.optics.absorber, scene.sensor.layers.absorber_mm)
            k_amb = channel_factors_of(scene, sd).astype(np.float32)
            level_of = partial(ambient_mod.lamp_level, flicker_hz=a.flicker_hz, flicker_depth=a.flicker_depth, switch_on_s=a.switch_on_s,
                               switch_off_s=a.switch_off_s)
        cal, rod_of_taxel = _calibration_of(scene, res.results["calibration"].rgb)
        dp = DllmParams.from_scene(scene)
        return cls(tet=patches.tet, area_m2=patches.area_m2, vertices_m=patches.vertices_m, located=located, model=spec.model,
                   params=m.params_from(spec), brightness=spec.brightness_photons_per_m2, scale=scale, fps=scene.camera.fps,
                   exposure_s=scene.camera.exposure_ms * 1e-3, transport=transport, raster=raster, camera=CameraConstants.of(params),
                   k_ml=ml_channel_factors(scene), ambient=amb, ambient_level=level_of, k_ambient=k_amb, taxels=taxel_index(cal),
                   dllm_params=dp, n_idle=dp.init_frames, device=device, rod_of_taxel=rod_of_taxel)

    # ----------------------------------------------------------------------------------- parts
    def windows(self, n_frames: int, start_s: float = 0.0) -> np.ndarray:
        """Exposure windows (n, 2) s from ``start_s``: frame k over [k / fps, k / fps + t_exp)."""
        from mlsim.camera import exposure_windows_s

        return exposure_windows_s(n_frames, self.fps, self.exposure_s) + start_s

    def radiance(self, stress_at_patches: list, t_s: list, windows_s: list) -> torch.Tensor:
        """Per-vertex radiance (B, F, N) float32 on the device (computed in float64, rounded as the
        render rounds it) of each episode's stress at the patches' tets (S_b, 6, N) Pa, its step
        times (S_b,) and windows (F_b, 2); zero on an episode's padded frames."""
        B, N = len(stress_at_patches), stress_at_patches[0].shape[2]
        out = torch.zeros((B, max(len(w) for w in windows_s), N), dtype=torch.float32, device=self.device)
        # a CPU works episode by episode (its temporaries then stay small enough for the allocator to
        # reuse, instead of fresh pages for every operation on a batch), a GPU on the whole batch
        step = 1 if self.device.type == "cpu" else B
        p = self.params
        for b0 in range(0, B, step):
            part = slice(b0, min(B, b0 + step))
            grids = merged_grids(t_s[part], windows_s[part], self.device)
            group = stress_at_patches[part]
            S = max(len(s) for s in group)
            stress = torch.empty((len(group), S, 6, N), dtype=torch.float32, device=self.device)
            for b, s in enumerate(group):
                st = torch.as_tensor(np.asarray(s), device=self.device)
                stress[b, : len(s)] = st
                stress[b, len(s):] = st[-1]  # padded steps repeat the last (never read past the merged grid)
            fraction, _ = fraction_batched(von_mises_batched(stress), grids, self.model, p.detrapping_per_pa, getattr(p, "recovery_time_s", 1.0))
            rad = photon_radiance_batched(fraction, grids, self.area, self.brightness, self.scale)
            out[part, : rad.shape[1]] = rad.to(torch.float32)
        return out

    def direct(self, radiance: np.ndarray, vertices_m: np.ndarray) -> np.ndarray:
        """Direct light (F, H, W) float32 of one episode on the host: the numba rasteriser on its lit
        frames (a dark frame is zero, as :func:`mlsim.render.render_frames` leaves it)."""
        e = np.ascontiguousarray(radiance, dtype=np.float32)
        out = np.zeros((len(e), self.height_px, self.width_px), np.float32)
        lit = np.flatnonzero(e.max(axis=1) > 0)
        if len(lit):
            out[lit] = self.raster.images(vertices_m[lit], e[lit])
        return out

    def frames(self, images: torch.Tensor, n_frames: list, noise_seeds: list, noise: bool = True) -> torch.Tensor:
        """Camera frames (B, n_idle + F, H, W, 3) uint8: each episode's idle frames (no ML light) and
        its frames of ``images`` (B, F, H, W) (padded frames dark). Episode b's noise from
        ``torch.Generator(device).manual_seed(noise_seeds[b])``."""
        B, F = images.shape[:2]
        rad = torch.zeros((B, self.n_idle + F, self.height_px, self.width_px), dtype=torch.float32, device=self.device)
        rad[:, self.n_idle:] = images
        level = None
        if self.ambient is not None:
            lv = np.zeros((B, self.n_idle + F))
            for b, n in enumerate(n_frames):
                lv[b, : self.n_idle] = self.ambient_level(self.windows(self.n_idle, -self.n_idle / self.fps))
                lv[b, self.n_idle: self.n_idle + n] = self.ambient_level(self.windows(n))
            level = torch.as_tensor(lv, device=self.device)
        gens = [torch.Generator(device=self.device).manual_seed(int(s)) for s in noise_seeds] if noise else None
        # a CPU works a few frames at a time (the temporaries stay in its cache), a GPU all at once
        chunk = 2 if self.device.type == "cpu" else None
        return capture_mono_batched(rad, self.k_ml, self.camera, gens, [self.n_idle + n for n in n_frames] if noise else None, noise,
                                    self.ambient, level, self.k_ambient, chunk_frames=chunk)

    def dllm(self, frames: torch.Tensor) -> tuple[np.ndarray, np.ndarray]:
        """DLLM events (B, F) and features (B, F, N, 3) of camera frames (B, n_idle + F, H, W, 3):
        the thresholds initialised on the idle frames, as :func:`dllm.episode.detect`."""
        from dllm.batched import batched_features, frame_statistics, threshold_gates

        B, T = frames.shape[:2]
        M, sums = frame_statistics(frames.reshape((B * T,) + tuple(frames.shape[2:])), self.taxels, chunk_frames=64)
        M, sums = M.reshape(B, T), sums.reshape(B, T, -1, 3)
        events, firing = threshold_gates(M, sums[..., 0], self.dllm_params)
        feats = batched_features(sums[..., 0], sums[..., 1], sums[..., 2], self.taxels.centres_px, firing)
        return events[:, self.n_idle:], feats[:, self.n_idle:]

    # ------------------------------------------------------------------------------------- run
    def run(self, episodes: list, noise_seeds: list, keep_radiance: bool = False, keep_frames: bool = False, noise: bool = True) -> ChainOutput:
        """The chain for solved episodes (:class:`fem.episode.Episode`, one per noise seed): the
        direct light of each frame rasterised on its deformed sheet on the host."""
        from mlsim.render import deformed_vertices

        if len(episodes) != len(noise_seeds) or not episodes:
            raise ValueError(f"episodes ({len(episodes)}) and noise_seeds ({len(noise_seeds)}): one seed per episode, at least one")
        tet = self.tet.cpu().numpy()

        def direct(b, radiance_host):
            return self.direct(radiance_host, deformed_vertices(episodes[b], self.vertices_m, self.located))

        return self.run_arrays([ep.stress[:, :, tet] for ep in episodes], [ep.t_s for ep in episodes], noise_seeds, direct,
                               keep_radiance, keep_frames, noise, [ep.n_frames for ep in episodes])

    def run_arrays(self, stress_at_patches: list, t_s: list, noise_seeds: list, direct, keep_radiance: bool = False,
                   keep_frames: bool = False, noise: bool = True, n_frames: list | None = None) -> ChainOutput:
        """The chain from arrays: per episode its stress at the patches' tets (S_b, 6, N) float32 Pa
        (``Episode.stress[:, :, tet]``), step times (S_b,) s and noise seed; ``direct(b, radiance)``
        gives episode b's direct light (F_b, H, W) float32 on the host from its per-vertex radiance
        (F_b, N) float32 (the rasteriser; or images computed before). ``n_frames``: frames per
        episode (default: the stress's steps, as a solve whose every step is a frame)."""
        import time

        sync = torch.cuda.synchronize if self.device.type == "cuda" else (lambda: None)
        n_frames = [len(s) for s in stress_at_patches] if n_frames is None else [int(n) for n in n_frames]
        sec = {}
        t0 = time.perf_counter()
        rad32 = self.radiance(stress_at_patches, t_s, [self.windows(n) for n in n_frames])
        sync()
        sec["emission"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        host = rad32.cpu().numpy()
        shape = tuple(rad32.shape[:2]) + (self.height_px, self.width_px)
        lit = None
        on_device = {}
        for b, n in enumerate(n_frames):
            d = direct(b, host[b, :n])
            if isinstance(d, torch.Tensor):  # already on the device (a benchmark's resident images)
                on_device[b] = d
            else:
                lit = np.zeros(shape, np.float32) if lit is None else lit
                lit[b, :n] = d
        sec["raster"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        # the host's direct light goes over in one copy
        lit_t = torch.zeros(shape, dtype=torch.float32, device=self.device) if lit is None else torch.as_tensor(lit, device=self.device)
        for b, d in on_device.items():
            lit_t[b, : n_frames[b]] = d
        images = transport_batched(self.T, rad32, self.height_px, self.width_px, lit_t)
        sync()
        sec["bounces"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        frames = self.frames(images, n_frames, noise_seeds, noise)
        sync()
        sec["camera"] = time.perf_counter() - t0
        t0 = time.perf_counter()
        events, feats = self.dllm(frames)
        sec["dllm"] = time.perf_counter() - t0
        out = ChainOutput([], [], [], [], sec)
        for b, n in enumerate(n_frames):
            out.events.append(events[b, :n])
            out.features.append(feats[b, :n])
            if keep_radiance:
                out.radiance.append(images[b, :n].cpu().numpy())
            if keep_frames:
                out.frames.append(frames[b, self.n_idle: self.n_idle + n].cpu().numpy())
        return out
