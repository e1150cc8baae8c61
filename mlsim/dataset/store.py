"""The dataset on disk: one Zarr (v3) group per episode, each written whole or not at all.

Layout of ``DIR/dataset.zarr``::

    dataset.zarr/                 group; attrs: the spec, the base scene, versions (packages, stages), the people
      episodes/                   group
        push_00000/               one episode: arrays (frames x ...) and attrs (labels, seeds, timings)
        ...

Why a group per episode written under a temporary name and renamed into ``episodes/``: a rename
within one file system is atomic, so a reader, or a rerun after a kill, sees an episode either
complete or not at all; the rerun clears what a killed run left in ``DIR/.partial`` and does the
episodes that are missing. Each array is one chunk per frame (frames) or one chunk (the rest),
compressed with Zarr's default (Zstandard).
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["STORE_NAME", "EPISODE_ARRAYS", "create_or_open", "complete_episodes", "episode_ids", "write_episode", "read_episode", "read_attrs",
           "DatasetMismatch", "FAILURES_NAME", "read_failures", "write_failures"]

STORE_NAME = "dataset.zarr"
#: The episodes that raised or whose worker was killed in the last run, beside the store (issue 39):
#: {episode id: {"kind", "error_type", "message"}}. A rerun retries them (they are not stored) and
#: drops each that then succeeds; the file is removed once none is left.
FAILURES_NAME = "failures.json"
_PARTIAL = ".partial"

#: The arrays of an episode: name -> (dtype, shape after the frame axis, unit and meaning).
EPISODE_ARRAYS: dict[str, tuple[str, str, str]] = {
    "dllm_features": ("float32", "(T, N, 3)", "per frame and taxel (row-major in the image): H (summed DN8 in the disk), l (px), omega (rad in "
                      "(-pi, pi], from the image's +x axis towards its -y axis); zeros where the taxel or the frame did not fire (SPEC 1.6)"),
    "dllm_event": ("bool", "(T,)", "the frame passed the DLLM's global gate (M > alpha D)"),
    "frame_label": ("int64", "(T,)", "the action's class id on the frames of the stroke, -1 elsewhere (mlsim.interactions)"),
    "rod_force_n": ("float32", "(T, R, 3)", "contact force of the screw on each rod (N, sensor axes; R = rows x cols, row-major)"),
    "wrench": ("float32", "(T, 6)", "total contact force on the sensor (N) and its moment about the array's centre at the tips' height "
               "(N m; each rod's force taken at its tip's centre)"),
    "screw_pose": ("float32", "(T, 4)", "the screw's reference point x, y, z (m) and yaw (rad)"),
    "rod_signal_e": ("float32", "(T, R)", "noiseless ML signal per rod at the camera (electrons, the rod's paraxial disk)"),
    "frames": ("uint8", "(T, H, W, 3)", "camera frames (only when the spec stores frames)"),
}


class DatasetMismatch(ValueError):
    """The output directory holds a dataset made from another spec."""


def _partial_dir(root: Path) -> Path:
    return root / _PARTIAL


def create_or_open(out_dir: str | Path, attrs: dict[str, Any], spec_hash: str):
    """The dataset's root group in ``out_dir``: created with ``attrs``, or opened if it was made from
    the same spec (``spec_hash``) by the same stages' code (``attrs["stage_versions"]``, where both the store
    and ``attrs`` have it: a stage's version rises when its bytes may change, and a resumed dataset would
    mix the two). A half-written episode of an interrupted run is removed."""
    import zarr

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / STORE_NAME
    if (path / "zarr.json").is_file():
        root = zarr.open_group(str(path), mode="r+")
        found = root.attrs.get("spec_hash")
        if found != spec_hash:
            raise DatasetMismatch(f"{out} holds a dataset of another spec (spec hash {str(found)[:12]}, this spec {spec_hash[:12]}): "
                                  "give a new --out, or delete that directory to regenerate it")
        stored, now = root.attrs.get("stage_versions"), attrs.get("stage_versions")
        if stored is not None and now is not None and dict(stored) != dict(now):
            changed = sorted(k for k in set(stored) | set(now) if stored.get(k) != now.get(k))
            raise DatasetMismatch(f"{out} was made by other versions of the stages {', '.join(changed)} ("
                                  + ", ".join(f"{k} {stored.get(k, '-')} there, {now.get(k, '-')} here" for k in changed)
                                  + "): its episodes and this code's could differ in their bytes; give a new --out, or delete that "
                                  "directory to regenerate it")
    else:
        root = zarr.open_group(str(path), mode="w")
        root.create_group("episodes")
        root.attrs.update(attrs | {"spec_hash": spec_hash})
    shutil.rmtree(_partial_dir(out), ignore_errors=True)
    return root


def complete_episodes(out_dir: str | Path) -> set[str]:
    """Names of the episodes stored whole (every group under ``episodes/``: they arrive by rename)."""
    episodes = Path(out_dir) / STORE_NAME / "episodes"
    if not episodes.is_dir():
        return set()
    return {p.name for p in episodes.iterdir() if p.is_dir() and (p / "zarr.json").is_file() and not p.name.startswith(".")}


def episode_ids(path: str | Path) -> list[str]:
    """The ids of the complete episodes in a dataset directory, sorted. (Here rather than in
    :mod:`mlsim.dataset.reader`, which imports torch: the driver's Parquet export needs the ids
    only, and importing torch cost it 1.6 s of CPU at the end of every run.)"""
    path = Path(path)
    if not (path / STORE_NAME / "zarr.json").is_file():
        raise FileNotFoundError(f"{path} holds no dataset (no {STORE_NAME}); make one with: mlsim dataset SPEC --out {path}")
    return sorted(complete_episodes(path))


def write_episode(out_dir: str | Path, episode_id: str, arrays: dict[str, np.ndarray], attrs: dict[str, Any]) -> Path:
    """Write one episode's group under a temporary name, then rename it into place (atomic)."""
    out = Path(out_dir)
    final = out / STORE_NAME / "episodes" / episode_id
    if final.exists():
        raise FileExistsError(f"episode {episode_id} is already stored in {out}")
    partial = _partial_dir(out)
    partial.mkdir(exist_ok=True)
    tmp = partial / f"{episode_id}.{os.getpid()}"
    shutil.rmtree(tmp, ignore_errors=True)
    for name in arrays:
        if name not in EPISODE_ARRAYS:
            raise ValueError(f'"{name}" is not an episode array; choose one of: {", ".join(EPISODE_ARRAYS)}')
    attributes = json.loads(json.dumps(attrs, default=_jsonable))
    try:
        _zarr_sync(_write_group(str(tmp), arrays, attributes))
        os.replace(tmp, final)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return final


async def _write_group(path: str, arrays: dict[str, np.ndarray], attributes: dict[str, Any]) -> None:
    """An episode's group at ``path``: its arrays (one chunk per frame for frames, one chunk for the
    rest) created and written together, then its attributes in one update. In one pass through
    Zarr's event loop: the synchronous API's round trip per array and per attribute (each
    attribute rewrote the group's zarr.json) cost the driver 39 ms of CPU an episode, about 1 ms a
    frame beside the workers' 8. The same files, byte for byte, as that API's
    (tests/test_dataset.py)."""
    import asyncio

    import zarr.api.asynchronous as zarr_async

    group = await zarr_async.open_group(path, mode="w")
    made = []
    for name, data in arrays.items():
        data = np.ascontiguousarray(data)
        chunks = (1,) + data.shape[1:] if name == "frames" else data.shape
        made.append(group.create_array(name, data=data, chunks=tuple(max(int(c), 1) for c in chunks)))
    await asyncio.gather(*made)
    if attributes:
        await group.update_attributes(attributes)


def _zarr_sync(coroutine):
    """Run a coroutine on Zarr's event loop thread (the one its synchronous API uses)."""
    from zarr.core.sync import sync as zarr_sync

    return zarr_sync(coroutine)


def read_failures(out_dir: str | Path) -> dict[str, dict[str, str]]:
    """The failed episodes recorded in ``out_dir`` ({} when none)."""
    path = Path(out_dir) / FAILURES_NAME
    return json.loads(path.read_text()) if path.is_file() else {}


def write_failures(out_dir: str | Path, failures: dict[str, dict[str, str]]) -> None:
    """Record the failed episodes (atomic: written whole, then renamed), or remove the file if none."""
    from mlsim.io import atomic_bytes

    path = Path(out_dir) / FAILURES_NAME
    if failures:
        atomic_bytes(path, json.dumps(dict(sorted(failures.items())), indent=2).encode())
    else:
        path.unlink(missing_ok=True)


def read_attrs(out_dir: str | Path) -> dict[str, Any]:
    import zarr

    return dict(zarr.open_group(str(Path(out_dir) / STORE_NAME), mode="r").attrs)


def read_episode(out_dir: str | Path, episode_id: str, arrays: tuple[str, ...] | None = None) -> dict[str, Any]:
    """One episode as a dict of numpy arrays plus its attributes (``arrays``: only these)."""
    import zarr

    group = zarr.open_group(str(Path(out_dir) / STORE_NAME / "episodes" / episode_id), mode="r")
    out: dict[str, Any] = dict(group.attrs)
    for name in group.array_keys():
        if arrays is None or name in arrays:
            out[name] = group[name][...]
    return out


def _jsonable(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"cannot store {type(value).__name__} as an attribute")
