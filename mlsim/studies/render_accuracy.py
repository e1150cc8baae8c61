"""Error against run time of the render's fidelity knobs: ``mlsim accuracy SCENE --stage render``.

The scene's episode (from the pipeline's cache) gives the emission and the deformed sheet;
``frames`` of its glowing frames, evenly spread over them (so a press-and-slide episode is seen in
every phase), are rendered by every configuration and compared with a reference:

- ``path`` at each ``spps`` (the sheet deformed per frame), spectral shortcut (mono x channel factors);
- ``path`` at each ``spps`` rendered spectrally (``llvm_ad_spectral``, :mod:`mlsim.render.spectral`)
  when ``spectral`` is on: what the shortcut saves;
- ``transport`` traced at each ``transport_spps`` (rest shape), spectral shortcut;
- ``transport+path``: the transport tier with ``fidelity.render.transport_max_displacement_mm``,
  which path-traces (at ``fidelity.render.spp``) the frames in which the sheet moved more;
- ``deformed``: the direct light rasterised on the deformed sheet at each of ``direct_per_sides``
  (samples per pixel side), plus the bounces' matrix traced at each ``transport_spps``.

The reference is the spectral path tracer at ``reference_spp`` on the deformed sheet: the most
physical render the code has. Errors, relative Frobenius norms over frames x rods x channels (R, G,
B) and over frames x pixels x channels (:func:`mlsim.studies.accuracy.relative_error`):

- ``rod_intensity``: each rod's signal, the sum over its disk (:func:`mlsim.render.rod_disks_px`);
- ``image``: every pixel.

The reference's own Monte Carlo noise is the floor under every error: it is estimated from a second
reference render with another seed (the relative norm of the two renders' difference over
sqrt(2)) and reported as ``reference_noise_*``. Run time is the median time per frame (for the
transport tier the sparse product, for the deformed tier the rasteriser and the product, over all
the frames as one batch; their one-off trace is ``precompute_s``). The Pareto front (no
other configuration both faster and more accurate) is marked per error.
"""

from __future__ import annotations

import csv
import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

__all__ = ["RENDER_ERRORS", "RenderRow", "render_accuracy", "write"]

RENDER_ERRORS = ("rod_intensity", "image")


@dataclass
class RenderRow:
    tier: str
    spp: int
    spectral: bool
    per_frame_ms: float = float("nan")
    precompute_s: float = 0.0
    errors: dict = field(default_factory=dict)
    #: the deformed tier's samples per pixel side of its direct light (0: another tier)
    direct_per_side: int = 0


def _rod_sums(images, masks) -> np.ndarray:
    """(F, H, W, C) -> (F, R, C) sums over each rod's disk."""
    F, H, W, C = images.shape
    return np.einsum("rp,fpc->frc", masks, images.reshape(F, H * W, C).astype(np.float64))


def _errors(images, reference, masks) -> dict:
    from mlsim.studies.accuracy import relative_error

    return {"rod_intensity": relative_error(_rod_sums(images, masks), _rod_sums(reference, masks)),
            "image": relative_error(np.asarray(images, np.float64), np.asarray(reference, np.float64))}


def render_accuracy(scene, spps=(1, 4, 16, 64), transport_spps=(16, 64), reference_spp: int = 256, frames: int = 4,
                    spectral: bool = True, out_dir=None, cache=None, progress: bool = True, log=print,
                    direct_per_sides=(1, 2, 3)) -> tuple[list[RenderRow], dict]:
    """Run every configuration and the reference on ``frames`` of the scene's glowing frames; return
    (rows, reference info) and write CSV, JSON and PNG to ``out_dir`` when given."""
    from mlsim import pipeline, render
    from mlsim.render import spectral as spectral_mod
    from mlsim.render.optics import disk_masks

    if scene.load is None:
        raise ValueError("load: the accuracy of the render needs a scene with a [load] section")
    if frames < 1 or reference_spp < 1 or min(list(spps) + list(transport_spps) or [1]) < 1:
        raise ValueError("frames, reference_spp and every spp must be >= 1")
    res = pipeline.run(scene.with_values({"outputs": ["emission", "solve"]}), out_dir=None, cache=cache, progress=progress,
                       log=lambda m: None)
    em, episode = res.results["emission"], res.results["solve"]
    # frames with at least 1e-3 of the brightest frame's light: the settling of gravity or a last touch
    # can leave frames at 1e-21 or 1e-6 of it, whose images are a few stray paths (their Monte Carlo
    # error does not fall at the 1/sqrt(spp) rate the study measures, and nobody sees them)
    total = em.photons_per_s.sum(axis=1)
    lit = np.flatnonzero(total >= 1e-3 * total.max()) if total.max() > 0 else np.array([], dtype=int)
    if not len(lit):
        raise ValueError("the scene's episode never glows (no emission in any frame): nothing to render")
    # spread over the glowing frames (press, slide, twist ...), not only the brightest (all in one phase)
    chosen = np.unique(lit[np.round(np.linspace(0, len(lit) - 1, min(frames, len(lit)))).astype(int)])
    radiance = render.radiance_of(em.photons_per_s[chosen], em.patches.area_m2).astype(np.float32)
    vertices = render.deformed_vertices(episode, em.patches.vertices_m)[chosen]
    sheet = render.sensor_scene_for(scene, em.patches)
    spectra = spectral_mod.ml_render_spectra(scene)
    k = render.ml_channel_factors(scene)
    centres, radius = render.rod_disks_px(scene)
    view = sheet.view
    masks = disk_masks(view.height_px, view.width_px, centres, radius).reshape(len(centres), -1).astype(np.float64)

    def spectral_path(spp, seed):
        out, seconds = [], []
        for f in range(len(chosen)):
            sheet.set_vertices(vertices[f])
            twin = spectral_mod.spectral_twin(sheet, spectra)  # built once per geometry, as the path tier's scene
            twin.set_radiance(radiance[f])
            t0 = time.perf_counter()
            out.append(twin.render(spp, seed + f))
            seconds.append(time.perf_counter() - t0)
        return np.array(out), float(np.median(seconds))

    log(f"[accuracy] reference: spectral path tracing at {reference_spp} spp, {len(chosen)} frames (twice, for its noise)")
    reference, ref_s = spectral_path(reference_spp, 10_000)
    second, _ = spectral_path(reference_spp, 20_000)
    noise = {f"reference_noise_{k_}": v / math.sqrt(2.0) for k_, v in _errors(second, reference, masks).items()}
    info = {"reference_spp": int(reference_spp), "frames": chosen.tolist(), "reference_ms_per_frame": ref_s * 1e3, **noise}

    rows: list[RenderRow] = []
    for spp in spps:
        log(f"[accuracy] path, {spp} spp (shortcut)")
        imgs, seconds = [], []
        for f in range(len(chosen)):
            sheet.set_vertices(vertices[f])
            sheet.set_radiance(radiance[f])
            t0 = time.perf_counter()  # the render alone (render_frames' times include the BVH rebuild)
            imgs.append(sheet.render(spp, 30_000 + 97 * spp + f))
            seconds.append(time.perf_counter() - t0)
        images = np.array(imgs)[..., None] * k
        rows.append(RenderRow("path", int(spp), False, float(np.median(seconds)) * 1e3, 0.0, _errors(images, reference, masks)))
        if spectral:
            log(f"[accuracy] path, {spp} spp (spectral)")
            images, seconds = spectral_path(spp, 40_000 + 97 * spp)
            rows.append(RenderRow("path", int(spp), True, seconds * 1e3, 0.0, _errors(images, reference, masks)))
    sheet.set_vertices(sheet.rest_vertices_m)
    for spp in transport_spps:
        log(f"[accuracy] transport, traced at {spp} spp")
        t0 = time.perf_counter()
        T = render.trace_transport(sheet, spp=spp, seed=50_000 + spp, drop=scene.fidelity.render.transport_drop, progress=progress)
        trace_s = time.perf_counter() - t0
        seconds = []
        for _ in range(5):
            t0 = time.perf_counter()
            mono = T.apply(radiance)
            seconds.append((time.perf_counter() - t0) / len(chosen))
        rows.append(RenderRow("transport", int(spp), False, float(np.median(seconds)) * 1e3, trace_s,
                              _errors(mono[..., None] * k, reference, masks)))
        limit_mm = scene.fidelity.render.path_above_mm
        if limit_mm is not None:  # the tier as shipped: frames where the sheet moved more are path-traced
            log(f"[accuracy] transport traced at {spp} spp, path-tracing frames that moved > {limit_mm:g} mm")
            t0 = time.perf_counter()
            hybrid = render.render_frames(sheet, radiance, "transport", transport=T, spp=scene.fidelity.render.spp, seed=60_000 + spp,
                                          vertices_m=vertices, path_above_m=limit_mm * 1e-3).radiance
            per_frame = (time.perf_counter() - t0) / len(chosen)
            rows.append(RenderRow("transport+path", int(spp), False, per_frame * 1e3, trace_s, _errors(hybrid[..., None] * k, reference, masks)))
        if direct_per_sides:
            from mlsim.render.direct_raster import direct_raster
            from mlsim.render.reprojection import trace_bounces

            log(f"[accuracy] deformed: bounces traced at {spp} spp, direct light rasterised at {', '.join(f'{n}x{n}' for n in direct_per_sides)}")
            t0 = time.perf_counter()
            bounces = trace_bounces(sheet, spp=spp, seed=50_000 + spp, drop=scene.fidelity.render.transport_drop, progress=progress)
            bounce_s = time.perf_counter() - t0
            for n in direct_per_sides:
                t0 = time.perf_counter()
                raster = direct_raster(sheet, n)
                build_s = time.perf_counter() - t0
                render.render_frames(sheet, radiance, "deformed", transport=bounces, raster=raster, vertices_m=vertices)  # compiled, warm
                seconds = []
                for _ in range(5):
                    t0 = time.perf_counter()
                    mono = render.render_frames(sheet, radiance, "deformed", transport=bounces, raster=raster, vertices_m=vertices).radiance
                    seconds.append((time.perf_counter() - t0) / len(chosen))
                rows.append(RenderRow("deformed", int(spp), False, float(np.median(seconds)) * 1e3, bounce_s + build_s,
                                      _errors(mono[..., None] * k, reference, masks), direct_per_side=int(n)))
    from mlsim.studies.accuracy import pareto_front

    for e in RENDER_ERRORS:
        front = pareto_front([r.per_frame_ms for r in rows], [r.errors[e] for r in rows])
        for r, f in zip(rows, front):
            r.errors[f"{e}_pareto"] = bool(f)
    if out_dir is not None:
        write(rows, info, Path(out_dir), scene)
    return rows, info


def write(rows: list[RenderRow], info: dict, out_dir: Path, scene) -> list[Path]:
    """``accuracy_render.csv``, ``accuracy_render.json`` and ``accuracy_render.png`` in ``out_dir``."""
    from mlsim.io import atomic_bytes

    out_dir.mkdir(parents=True, exist_ok=True)
    header = (["tier", "spp", "spectral", "direct_per_side", "per_frame_ms", "precompute_s"]
              + [k for e in RENDER_ERRORS for k in (f"error_{e}", f"pareto_{e}")])
    import io

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(header)
    for r in rows:
        w.writerow([r.tier, r.spp, r.spectral, r.direct_per_side, f"{r.per_frame_ms:.6g}", f"{r.precompute_s:.6g}",
                    *[v for e in RENDER_ERRORS for v in (f"{r.errors[e]:.6g}", r.errors[f"{e}_pareto"])]])
    paths = [atomic_bytes(out_dir / "accuracy_render.csv", buf.getvalue().encode()),
             atomic_bytes(out_dir / "accuracy_render.json",
                          json.dumps({"scene": scene.name, "errors": list(RENDER_ERRORS), "reference": info,
                                      "rows": [r.__dict__ for r in rows]}, indent=2, default=float).encode())]
    png = out_dir / "accuracy_render.png"
    _plot(rows, info, png)
    return paths + [png]


def _plot(rows: list[RenderRow], info: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    style = {("path", False): ("o", "tab:blue", "path, shortcut"), ("path", True): ("^", "tab:green", "path, spectral"),
             ("transport", False): ("s", "tab:orange", "transport, rest shape (per-frame cost)"),
             ("transport+path", False): ("D", "tab:red", "transport + path above the displacement limit"),
             ("deformed", False): ("v", "tab:purple", "deformed (label: bounce spp / direct samples per side)")}
    fig, axes = plt.subplots(1, len(RENDER_ERRORS), figsize=(5.2 * len(RENDER_ERRORS), 4.2), constrained_layout=True)
    for ax, e in zip(axes, RENDER_ERRORS):
        for key, (marker, colour, label) in style.items():
            sel = [r for r in rows if (r.tier, r.spectral) == key]
            if not sel:
                continue
            ax.loglog([r.per_frame_ms for r in sel], [r.errors[e] for r in sel], marker + "-", color=colour, label=label, mfc="none")
            for r in sel:
                label = f"{r.spp}/{r.direct_per_side}" if r.direct_per_side else f"{r.spp}"
                ax.annotate(label, (r.per_frame_ms, r.errors[e]), fontsize=7, xytext=(4, 2), textcoords="offset points")
                if r.errors[f"{e}_pareto"]:
                    ax.loglog(r.per_frame_ms, r.errors[e], marker, color=colour)
        ax.axhline(info[f"reference_noise_{e}"], color="grey", ls=":", label="reference noise")
        ax.set_xlabel("time per frame (ms)")
        ax.set_ylabel(f"relative error, {e.replace('_', ' ')}")
        ax.set_title(f"{e.replace('_', ' ')} vs the spectral reference ({info['reference_spp']} spp)", fontsize=9)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.savefig(path, dpi=120)
    plt.close(fig)
