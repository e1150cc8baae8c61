"""The dataset's Parquet table (mlsim.dataset.parquet): read back with pandas, every stored number
and label comes back exactly, a row per frame in episode id order, with the units in its metadata."""

from __future__ import annotations

import json

import numpy as np
import pytest

from mlsim.dataset import store
from mlsim.dataset.parquet import PARQUET_NAME, export_parquet


def _episode(rng, action, label, T):
    feats = rng.normal(size=(T, 25, 3)).astype(np.float32)
    feats[rng.random((T, 25)) < 0.5] = 0.0
    arrays = {"dllm_features": feats, "dllm_event": rng.random(T) < 0.4, "frame_label": np.where(np.arange(T) > 2, label, -1),
              "wrench": rng.normal(size=(T, 6)).astype(np.float32), "rod_force_n": np.zeros((T, 25, 3), np.float32)}
    return arrays


@pytest.fixture
def dataset(tmp_path):
    rng = np.random.default_rng(7)
    store.create_or_open(tmp_path, {"class_names": ["push", "pull"]}, "abc123")
    written = {}
    for eid, action, label, T, person in (("pull_00001", "pull", 1, 9, 1), ("push_00000", "push", 0, 12, 0), ("push_00001", "push", 0, 7, 1)):
        arrays = _episode(rng, action, label, T)
        store.write_episode(tmp_path, eid, arrays, {"episode_id": eid, "action": action, "label": label, "label_4": 0, "person": person,
                                                    "sample_index": int(eid[-1]), "fps": 30.0})
        written[eid] = (arrays, person, label)
    return tmp_path, written


def test_parquet_round_trips_through_pandas(dataset):
    import pandas as pd
    import pyarrow.parquet as pq

    out, written = dataset
    path = export_parquet(out)
    assert path == out / PARQUET_NAME
    df = pd.read_parquet(path)
    assert len(df) == 9 + 12 + 7 and len(df.columns) == 6 + 4 + 75 + 6
    assert list(df["episode_id"].unique()) == ["pull_00001", "push_00000", "push_00001"]  # episode id order
    for eid, (arrays, person, label) in written.items():
        rows = df[df["episode_id"] == eid]
        T = len(arrays["dllm_event"])
        assert rows["frame"].tolist() == list(range(T))
        np.testing.assert_array_equal(rows["t_s"].to_numpy(), np.arange(T) / 30.0)
        assert (rows["person"] == person).all() and (rows["label"] == label).all() and (rows["action"] == eid.split("_")[0]).all()
        np.testing.assert_array_equal(rows["event"].to_numpy(), arrays["dllm_event"])
        np.testing.assert_array_equal(rows["frame_label"].to_numpy(), arrays["frame_label"])
        for n in (0, 13, 24):
            for k, name in enumerate(("H", "l_px", "omega_rad")):
                col = rows[f"taxel{n}_{name}"].to_numpy()
                assert col.dtype == np.float32
                np.testing.assert_array_equal(col, arrays["dllm_features"][:, n, k])  # exactly the stored float32
        np.testing.assert_array_equal(rows[["fx_n", "fy_n", "fz_n", "mx_n_m", "my_n_m", "mz_n_m"]].to_numpy(), arrays["wrench"])
    meta = json.loads(pq.read_schema(path).metadata[b"mlsim"])
    assert meta["spec_hash"] == "abc123" and "omega" in meta["units"]["dllm_features"]


def test_the_same_store_gives_the_same_bytes_and_an_empty_one_is_refused(dataset, tmp_path_factory):
    out, _ = dataset
    first = export_parquet(out).read_bytes()
    assert export_parquet(out).read_bytes() == first
    empty = tmp_path_factory.mktemp("empty")
    store.create_or_open(empty, {}, "x")
    with pytest.raises(ValueError, match="no complete episode"):
        export_parquet(empty)


def test_the_export_does_not_import_torch(dataset):
    """The driver exports the table at the end of every run: it reads the episode ids from the store
    (mlsim.dataset.store.episode_ids), not from the reader, whose torch import cost it 1.6 s of CPU
    (issue 40). A fresh process exports without importing torch; the reader's ids are the store's."""
    import subprocess
    import sys

    from mlsim.dataset import reader

    path, _ = dataset
    code = ("import sys; from mlsim.dataset.parquet import export_parquet; "
            f"export_parquet({str(path)!r}); print('torch' in sys.modules)")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.strip() == "False"
    assert reader.episode_ids is store.episode_ids and store.episode_ids(path) == ["pull_00001", "push_00000", "push_00001"]
