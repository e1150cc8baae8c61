"""The ambient-light threshold study: ``mlsim ambient SCENE``.

For each ambient setting (no lamp; the 50 W daylight lamp 1.5 m above, SPEC 1.1; the same with
100 Hz mains flicker; the lamp switched on during the episode; and the three over a sensor without
its absorber, where the lamp is some 1000 times brighter inside; first, the scene's own lamp when it has
one, as in ``scenes/ambient.toml``; each other setting starts from the scene's ``[ambient]`` reset:
:func:`setting_scenes`) the scene is simulated twice through the pipeline: the *interaction* episode (the scene's
load) and an *idle* episode (the same frames without ML light: sensor noise and the lamp). The DLLM
then runs on both for every (alpha, beta) of a grid, each time after its 1 s of idle frames before
the episode (:mod:`dllm.episode`). The camera frames depend on the lamp, not on the thresholds, so
each setting renders once and the grid costs only detector time.

Measures per setting and (alpha, beta):

- ``detection``: the share of *touch frames* that are events; a touch frame is one whose brightest
  rod receives at least ``touch_share`` (5 %) of the episode's peak ML signal (the camera stage's
  noiseless per-rod signal: ground truth the real sensor does not have);
- ``false_rate``: the share of the idle episode's frames that are events (false triggers);
- ``taxel_detection``: in touch frames, the share of lit rods (at least ``touch_share`` of that
  frame's brightest) whose taxel fires.

Recommended thresholds: among the grid points without a false trigger under every setting (leaving
out the settings where no grid point avoids them, which are listed: there the detector fires until
its thresholds recover, ``dllm.recover_s``), the one with the highest worst-case detection (ties:
the higher alpha, then beta: more margin). The idle episode lasts ``idle_s`` (3 s) or the
interaction episode, whichever is longer.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["DEFAULT_SETTINGS", "SCENE_SETTING", "AmbientRow", "ambient_study", "setting_scenes", "write"]

#: name -> scene overrides of each ambient setting.
DEFAULT_SETTINGS: dict[str, dict] = {
    "dark": {"ambient.lamp": "none"},
    "daylight 50 W": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5},
    "daylight 50 W, 100 Hz flicker": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5,
                                      "ambient.flicker_hz": 100.0, "ambient.flicker_depth": 0.3},
    "daylight 50 W switched on at 0.2 s": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5,
                                           "ambient.switch_on_s": 0.2},
    "daylight 50 W, no absorber": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5,
                                   "optics.absorber": "none"},
    "daylight 50 W, no absorber, 100 Hz flicker": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5,
                                                   "optics.absorber": "none", "ambient.flicker_hz": 100.0, "ambient.flicker_depth": 0.3},
    "daylight 50 W, no absorber, switched on at 0.2 s": {"ambient.lamp": "daylight", "ambient.power_w": 50.0, "ambient.height_m": 1.5,
                                                         "optics.absorber": "none", "ambient.switch_on_s": 0.2},
}


#: the name of the setting that is the scene's own lamp (``[ambient]`` of a scene such as scenes/ambient.toml).
SCENE_SETTING = "the scene's lamp"


def setting_scenes(scene, settings: dict | None = None) -> dict:
    """``{setting name: scene}``: each setting applied to the scene with its ``[ambient]`` reset, so that a
    setting's lamp is exactly the one it names (a scene's flicker or switching does not leak into the
    steady "daylight 50 W"). With the default settings, a scene that has a lamp of its own adds it first,
    as it is (:data:`SCENE_SETTING`)."""
    chosen = DEFAULT_SETTINGS if settings is None else settings
    out = {SCENE_SETTING: scene} if settings is None and scene.ambient.lamp != "none" else {}
    for name, overrides in chosen.items():
        out[name] = scene.with_values({"ambient": {}, **overrides})
    return out


@dataclass
class AmbientRow:
    setting: str
    alpha: float
    beta: float
    detection: float
    false_rate: float
    taxel_detection: float
    touch_frames: int
    idle_frames: int


def _frames(scene, cache, progress, idle_s: float = 3.0):
    """(interaction CameraFrames, idle frames (max(T, idle_s fps), H, W, 3) from t = 0, pre-roll
    frames, calibration rgb)."""
    from dllm.detector import DllmParams
    from mlsim import pipeline
    from mlsim.render.output import idle_frames

    res = pipeline.run(scene.with_values({"outputs": ["camera", "calibration", "render"]}), out_dir=None, cache=cache, progress=progress,
                       log=lambda m: None)
    cam, render = res.results["camera"], res.results["render"]
    pre = idle_frames(scene, render, DllmParams.from_scene(scene).init_frames)
    n_idle = max(len(cam.frames), int(round(idle_s * scene.camera.fps)))
    idle = idle_frames(scene, render, n_idle, start_s=float(cam.windows_s[0, 0]), stream=1)
    return cam, idle, pre, res.results["calibration"].rgb


def ambient_study(scene, settings: dict | None = None, alphas=(1.01, 1.02, 1.05, 1.1, 1.2), betas=(1.1, 1.3, 1.5, 2.0),
                  touch_share: float = 0.05, idle_s: float = 3.0, out_dir=None, cache=None, progress: bool = True,
                  log=print) -> tuple[list[AmbientRow], dict]:
    """Run the study (module docstring); returns (rows, recommendation) and writes CSV, JSON and one
    heatmap per setting to ``out_dir`` when given."""
    from dataclasses import replace

    from dllm.detector import DllmParams
    from dllm.episode import calibrate_scene, detect

    if scene.load is None:
        raise ValueError("load: the ambient study needs a scene with a [load] section (its interaction episode)")
    rows: list[AmbientRow] = []
    for name, s in setting_scenes(scene, settings).items():
        log(f"[ambient] {name}")
        cam, idle, pre, cal_rgb = _frames(s, cache, progress, idle_s)
        cal, rod_of_taxel = calibrate_scene(s, cal_rgb)
        signal = cam.rod_signal_e  # (T, R) noiseless ML signal per rod
        touch = signal.max(axis=1) >= touch_share * signal.max() if signal.max() > 0 else np.zeros(len(signal), bool)
        lit = signal >= touch_share * np.maximum(signal.max(axis=1, keepdims=True), 1e-30)
        base = DllmParams.from_scene(s)
        for a in alphas:
            for b in betas:
                p = replace(base, alpha=float(a), beta=float(b))
                ev, feats, _ = detect(cal, p, pre, cam.frames)
                ev_idle, _, _ = detect(cal, p, pre, idle)
                fired_rod = np.zeros_like(lit)
                fired_rod[:, rod_of_taxel] = feats[..., 0] > 0
                want = lit & touch[:, None]
                rows.append(AmbientRow(name, float(a), float(b), float(ev[touch].mean()) if touch.any() else float("nan"),
                                       float(ev_idle.mean()), float(fired_rod[want].mean()) if want.any() else float("nan"),
                                       int(touch.sum()), int(len(idle))))
    rec = _recommend(rows)
    if out_dir is not None:
        write(rows, rec, Path(out_dir))
    return rows, rec


def _recommend(rows: list[AmbientRow]) -> dict:
    """The grid point without false triggers under every setting where some grid point has none,
    with the highest worst-case detection there; settings where every point false-triggers are
    listed apart (no threshold helps: the detector fires until its thresholds recover)."""
    grid = sorted({(r.alpha, r.beta) for r in rows})
    settings = list(dict.fromkeys(r.setting for r in rows))
    hopeless = [s for s in settings if all(r.false_rate > 0 for r in rows if r.setting == s)]
    feasible = [r for r in rows if r.setting not in hopeless]
    best, best_key = None, None
    for a, b in grid:
        sel = [r for r in feasible if (r.alpha, r.beta) == (a, b)]
        if not sel or any(r.false_rate > 0 for r in sel):
            continue
        key = (min(r.detection for r in sel), min(r.taxel_detection for r in sel), a, b)
        if best_key is None or key > best_key:
            best, best_key = (a, b), key
    if best is None:
        return {"alpha": None, "beta": None, "false_triggers_at_any_threshold": hopeless,
                "why": "no grid point is free of false triggers under the settings where some point is: widen the grid"}
    sel = {r.setting: {"detection": r.detection, "false_rate": r.false_rate, "taxel_detection": r.taxel_detection}
           for r in rows if (r.alpha, r.beta) == best}
    return {"alpha": best[0], "beta": best[1], "worst_detection": best_key[0], "per_setting": sel,
            "false_triggers_at_any_threshold": hopeless,
            "why": "no false trigger under any setting where a threshold can avoid them, the highest worst-case detection"}


def write(rows: list[AmbientRow], rec: dict, out_dir: Path) -> list[Path]:
    """``ambient_study.csv``, ``ambient_study.json`` and ``ambient_<setting>.png`` heatmaps."""
    from mlsim.io import atomic_bytes

    out_dir.mkdir(parents=True, exist_ok=True)
    lines = ["setting,alpha,beta,detection,false_rate,taxel_detection,touch_frames,idle_frames"]
    lines += [f"{r.setting},{r.alpha:g},{r.beta:g},{r.detection:.4f},{r.false_rate:.4f},{r.taxel_detection:.4f},{r.touch_frames},"
              f"{r.idle_frames}" for r in rows]
    files = [atomic_bytes(out_dir / "ambient_study.csv", ("\n".join(lines) + "\n").encode()),
             atomic_bytes(out_dir / "ambient_study.json", json.dumps({"recommended": rec, "rows": [r.__dict__ for r in rows]},
                                                                     indent=1, default=float).encode())]
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    alphas = sorted({r.alpha for r in rows})
    betas = sorted({r.beta for r in rows})
    for name in dict.fromkeys(r.setting for r in rows):
        sel = {(r.alpha, r.beta): r for r in rows if r.setting == name}
        fig, axes = plt.subplots(1, 2, figsize=(9, 3.8), constrained_layout=True)
        for ax, what, cmap in ((axes[0], "detection", "viridis"), (axes[1], "false_rate", "magma")):
            z = np.array([[getattr(sel[(a, b)], what) for b in betas] for a in alphas])
            im = ax.imshow(z, origin="lower", cmap=cmap, vmin=0, vmax=1, aspect="auto")
            for i in range(len(alphas)):
                for j in range(len(betas)):
                    ax.text(j, i, f"{z[i, j]:.2f}", ha="center", va="center", fontsize=7, color="w" if z[i, j] < 0.6 else "k")
            ax.set_xticks(range(len(betas)), [f"{b:g}" for b in betas])
            ax.set_yticks(range(len(alphas)), [f"{a:g}" for a in alphas])
            ax.set_xlabel("beta")
            ax.set_ylabel("alpha")
            ax.set_title(f"{what.replace('_', ' ')}", fontsize=9)
            if rec.get("alpha") is not None:
                ax.plot(betas.index(rec["beta"]), alphas.index(rec["alpha"]), "s", mfc="none", mec="tab:red", ms=18, mew=2)
            fig.colorbar(im, ax=ax)
        fig.suptitle(f"DLLM under ambient light: {name}", fontsize=10)
        path = out_dir / f"ambient_{''.join(c if c.isalnum() else '_' for c in name)}.png"
        fig.savefig(path, dpi=110)
        plt.close(fig)
        files.append(path)
    return files
