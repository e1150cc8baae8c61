"""The dataset card (``DIR/README.md``) written beside the data: what it holds, how it was made,
how to read it, and what it does not model (after Gebru et al., "Datasheets for Datasets", 2021)."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

from mlsim.dataset import store

__all__ = ["write_card"]


def write_card(out_dir: str | Path, spec, base, summary: dict) -> Path:
    from mlsim.io import atomic_bytes

    out = Path(out_dir)
    attrs = store.read_attrs(out)
    per_action = Counter(e.rsplit("_", 1)[0] for e in store.complete_episodes(out))
    fid = base.fidelity
    lines = [
        f"# Dataset card: {spec.name}",
        "",
        spec.description or "Synthetic episodes of the SPEC 1.5 interaction test, simulated by mlsim.",
        "",
        "## What it holds",
        f"- {summary['episodes_stored']} episodes: {len(spec.actions)} actions x {spec.samples_per_action} samples, "
        f"performed by {spec.people} simulated people (sample k of an action is person k mod {spec.people}).",
        "- Episodes per action: " + ", ".join(f"{a} {per_action.get(a, 0)}" for a in spec.actions) + ".",
    ]
    failures = summary.get("failures") or {}
    if failures:  # an incomplete dataset: which episodes are missing and why (issue 39)
        lines += [f"- **Incomplete: {len(failures)} of {summary['episodes_planned']} episodes failed** (rerun the same command to retry "
                  f"only them; listed in `{store.FAILURES_NAME}`):"]
        lines += [f"  - `{k}`: {v['kind']}, {v['error_type']}: {v['message'][:300]}" for k, v in sorted(failures.items())]
    lines += [
        f"- Camera frames stored: {'yes' if spec.store_frames else 'no'}. Frame rate {base.camera.fps:g} FPS, "
        f"{base.camera.width_px} x {base.camera.height_px} px.",
        "",
        "| array | dtype | shape | meaning |",
        "|---|---|---|---|",
    ]
    lines += [f"| `{k}` | {d} | {s} | {m} |" for k, (d, s, m) in store.EPISODE_ARRAYS.items()]
    lines += [
        "",
        "Each episode's attributes: `episode_id`, `action`, `label` (8 classes, in the order of `class_names`), `label_4` "
        "(push_pull, sliding, rotation_cw, rotation_ccw), `person`, `sample_index`, `noise_seed`, `sample` (the drawn stroke, "
        "duration, direction, onset, tremor), `rod_of_taxel`, timings.",
        "",
        "## How it was made",
        f"- Spec hash `{summary['spec_hash'][:16]}`, seed {spec.seed}; base scene `{spec.scene}` (hash `{attrs['base_scene_hash'][:16]}`).",
        f"- Tiers: solve `{fid.solve.tier}` with {fid.solve.rod_kinematics.replace('_', '-')} rods ("
        + ("the spec's `rod_kinematics`, the datasets' rate" if spec.rod_kinematics == "first_order" else "the base scene's own")
        + f"), render `{fid.render.tier}` ({_render_tier_detail(fid.render)}), mesh edge {fid.mesh.edge_length_mm:g} mm; "
        f"DLLM alpha {base.dllm.alpha:g}, beta {base.dllm.beta:g}.",
        f"- The interactions: `mlsim.interactions` (clamp at {spec.interaction.grip_force_n:g} N, then one minimum-jerk stroke "
        "with tremor; the action definitions are in that module's docstring).",
        f"- Mesh cache key `{summary['mesh_key'][:16]}`. fTetWild does not give the same mesh twice: the same spec and seed give "
        "byte-identical features on the same mesh; with a separately built mesh the numbers differ in their last bits.",
        f"- Generated with {summary['workers']} {summary['executor']} worker(s) from a driver on {summary.get('machine', 'an unrecorded machine')}: "
        f"{summary.get('episodes_per_s')} episodes/s, {summary.get('frames_per_s')} frames/s end to end in the last run "
        f"(precompute {summary.get('precompute_s')} s); versions: "
        + ", ".join(f"{k} {v}" for k, v in summary["versions"].items()) + ".",
        *_randomized_lines(spec),
        "",
        "## How to read it",
        "```python",
        "from mlsim.dataset.reader import load_episodes, EpisodeDataset",
        f'episodes = load_episodes("{out}")            # list of dicts',
        f'ds = EpisodeDataset("{out}")                  # torch Dataset',
        "```",
        "`mlsim train DIR --out MODEL_DIR` trains the SPEC 1.7 CNN on it. The per-frame DLLM features, labels and wrench "
        "are also one Parquet table, `dllm_frames.parquet` (a row per frame; `pandas.read_parquet`; columns: `mlsim.dataset.parquet`).",
        "",
        "## What it does not model",
        "- The person's force on the screw is not simulated: the screw's motion is prescribed (displacement control after the clamp), "
        "so `wrench` is the sensor's reaction, not the hand's wrench.",
        f"- {_render_tier_limit(fid.render.tier)} The emission, camera and detector models are those of mlsim, with the constants "
        "documented in their modules.",
        "- People differ only by the parameters in `people` (`dataset.zarr` attributes); real people differ in more ways.",
        "",
    ]
    path = out / "README.md"
    atomic_bytes(path, "\n".join(lines).encode())
    return path


def _randomized_lines(spec) -> list[str]:
    """The domain randomisation's ranges (mlsim.dataset.randomize), or nothing without it."""
    if not spec.randomize:
        return []
    from mlsim.dataset.randomize import RANDOMIZABLE

    lines = ["", "## Randomised per episode",
             f"Drawn uniformly per episode from the spec's seed ({spec.seed}; stream 4, by action and sample), stored in each episode's "
             "`randomized` attribute and as columns of `dllm_frames.parquet`:", "",
             "| scene field | low | high | why it varies |", "|---|---|---|---|"]
    return lines + [f"| `{p}` | {lo:g} | {hi:g} | {RANDOMIZABLE[p]} |" for p, (lo, hi) in sorted(spec.randomize.items())]


def _render_tier_detail(render) -> str:
    """What the render tier's knobs were, in words."""
    if render.tier == "deformed":
        return (f"direct light rasterised on the deformed sheet at {render.direct_samples_per_side}^2 samples per pixel, bounces traced "
                f"at {render.transport_spp} spp on the rest shape")
    if render.tier == "transport":
        return f"transport traced at {render.transport_spp} spp, path above: {render.transport_max_displacement_mm}"
    return f"path traced at {render.spp} spp"


def _render_tier_limit(tier: str) -> str:
    """What the render tier leaves out, in words."""
    if tier == "deformed":
        return ("The deformed render tier takes the light's bounces inside the rods from the rest shape of the sheet (the direct "
                "light follows the deformation; see `max_sheet_displacement_mm` per episode).")
    if tier == "transport":
        return "The transport tier renders the rest shape of the sheet (see `max_sheet_displacement_mm` per episode)."
    return "The path tier renders every frame on the deformed sheet (Monte Carlo noise at its spp)."
