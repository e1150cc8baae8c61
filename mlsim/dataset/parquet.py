"""Export a dataset's per-frame DLLM features and labels as one Parquet table beside its Zarr store.

``DIR/dllm_frames.parquet`` (Apache Parquet through pyarrow, Zstandard-compressed) holds one row per
frame of every stored episode, in episode id order, so that tools that read tables (pandas, polars,
DuckDB, Spark) need neither Zarr nor mlsim:

- ``episode_id``, ``action`` (dictionary-encoded strings), ``label`` (8 classes), ``label_4``,
  ``person``, ``sample_index``: the episode's attributes, repeated on its frames;
- ``frame`` (index in the episode), ``t_s`` (frame start, frame / fps), ``event`` (the DLLM's global
  gate), ``frame_label`` (the action's class on the stroke's frames, -1 elsewhere);
- ``taxel{n}_H``, ``taxel{n}_l_px``, ``taxel{n}_omega_rad``: the DLLM features of taxel n (float32,
  exactly the store's ``dllm_features``; zeros where the taxel or the frame did not fire);
- ``fx_n``, ``fy_n``, ``fz_n``, ``mx_n_m``, ``my_n_m``, ``mz_n_m``: the contact wrench (the store's ``wrench``);
- with domain randomisation, one column per randomised scene field (``camera.gain_db``, ...): the
  episode's drawn value (:mod:`mlsim.dataset.randomize`).

The table's schema metadata holds the spec hash and the units (:data:`mlsim.dataset.store.EPISODE_ARRAYS`).
The Zarr store stays the dataset; this table is derived from it and rewritten whole (atomically) when
the dataset completes.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from mlsim.dataset import store

__all__ = ["PARQUET_NAME", "export_parquet", "episode_table"]

PARQUET_NAME = "dllm_frames.parquet"

_ATTRS = (("episode_id", str), ("action", str), ("label", np.int64), ("label_4", np.int64), ("person", np.int64),
          ("sample_index", np.int64))
_WRENCH = ("fx_n", "fy_n", "fz_n", "mx_n_m", "my_n_m", "mz_n_m")


def episode_table(episode: dict) -> dict[str, np.ndarray]:
    """The columns (name -> (T,) array) of one episode as read by :func:`mlsim.dataset.store.read_episode`."""
    features = np.asarray(episode["dllm_features"], np.float32)
    T, N, _ = features.shape
    cols: dict[str, np.ndarray] = {name: np.full(T, kind(episode[name]), dtype=object if kind is str else kind) for name, kind in _ATTRS}
    cols["frame"] = np.arange(T, dtype=np.int64)
    cols["t_s"] = np.arange(T, dtype=np.float64) / float(episode["fps"])
    cols["event"] = np.asarray(episode["dllm_event"], bool)
    cols["frame_label"] = np.asarray(episode["frame_label"], np.int64)
    for n in range(N):
        for k, name in enumerate(("H", "l_px", "omega_rad")):
            cols[f"taxel{n}_{name}"] = features[:, n, k]
    wrench = np.asarray(episode["wrench"], np.float32)
    for k, name in enumerate(_WRENCH):
        cols[name] = wrench[:, k]
    for path, value in sorted(episode.get("randomized", {}).items()):  # the episode's drawn sensor (mlsim.dataset.randomize)
        cols[path] = np.full(T, float(value))
    return cols


def export_parquet(out_dir: str | Path) -> Path:
    """Write ``out_dir/dllm_frames.parquet`` from the dataset's stored episodes (module docstring)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    from mlsim.dataset.store import episode_ids
    from mlsim.io import atomic_bytes

    out = Path(out_dir)
    arrays = ("dllm_features", "dllm_event", "frame_label", "wrench")
    tables = []
    for e in episode_ids(out):
        cols = episode_table(store.read_episode(out, e, arrays))
        tables.append(pa.table({k: pa.array(v, type=pa.string() if v.dtype == object else None) for k, v in cols.items()}))
    if not tables:
        raise ValueError(f"{out} holds no complete episode to export")
    table = pa.concat_tables(tables)
    for name in ("episode_id", "action"):
        table = table.set_column(table.schema.get_field_index(name), name, table[name].dictionary_encode())
    attrs = store.read_attrs(out)
    meta = {"spec_hash": attrs.get("spec_hash"), "class_names": attrs.get("class_names"),
            "units": {k: v[2] for k, v in store.EPISODE_ARRAYS.items() if k in arrays}}
    table = table.replace_schema_metadata({b"mlsim": json.dumps(meta).encode()})
    buf = io.BytesIO()
    pq.write_table(table, buf, compression="zstd")
    return atomic_bytes(out / PARQUET_NAME, buf.getvalue())
