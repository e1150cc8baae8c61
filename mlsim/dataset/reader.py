"""Read an interaction dataset: episodes as dicts of numpy arrays, or as a torch ``Dataset``.

>>> from mlsim.dataset.reader import load_episodes, EpisodeDataset
>>> episodes = load_episodes("out/paper")          # list of dicts (arrays + labels), id order
>>> ds = EpisodeDataset("out/paper", arrays=("dllm_features", "frame_label"))
>>> item = ds[0]                                   # dict of tensors plus "label", "person", "action"

Arrays and their units: :data:`mlsim.dataset.store.EPISODE_ARRAYS`.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mlsim.dataset import store
from mlsim.dataset.store import episode_ids

__all__ = ["load_episodes", "episode_ids", "EpisodeDataset"]

_DEFAULT_ARRAYS = ("dllm_features", "dllm_event", "frame_label")


def load_episodes(path: str | Path, arrays: tuple[str, ...] | None = _DEFAULT_ARRAYS) -> list[dict[str, Any]]:
    """Every complete episode of the dataset as a dict: the chosen ``arrays`` (None: all, frames
    included) and the episode's attributes (``label``, ``label_4``, ``person``, ``action``, ...)."""
    return [store.read_episode(path, e, arrays) for e in episode_ids(path)]


try:
    from torch.utils.data import Dataset as _TorchDataset
except ImportError:  # pragma: no cover - torch is a dependency; this keeps the module importable without it
    _TorchDataset = object


class EpisodeDataset(_TorchDataset):
    """A torch ``Dataset`` over a dataset directory: item ``i`` is episode ``i`` (id order) as a dict
    of tensors (the chosen ``arrays``) plus its ``label``, ``label_4``, ``person``, ``action`` and
    ``episode_id``. Episodes are read lazily, one Zarr group per item, so workers of a DataLoader
    each open their own. ``transform`` (optional) maps the dict."""

    def __init__(self, path: str | Path, arrays: tuple[str, ...] = _DEFAULT_ARRAYS, transform=None):
        unknown = [a for a in arrays if a not in store.EPISODE_ARRAYS]
        if unknown:
            raise ValueError(f"arrays: {', '.join(unknown)} not stored; choose from: {', '.join(store.EPISODE_ARRAYS)}")
        self.path = Path(path)
        self.arrays = tuple(arrays)
        self.ids = episode_ids(self.path)
        self.transform = transform

    def __len__(self) -> int:
        return len(self.ids)

    def __getitem__(self, i: int) -> dict[str, Any]:
        import torch

        raw = store.read_episode(self.path, self.ids[i], self.arrays)
        item: dict[str, Any] = {k: torch.from_numpy(raw[k]) for k in self.arrays if k in raw}
        for key in ("label", "label_4", "person", "action", "episode_id"):
            item[key] = raw[key]
        return self.transform(item) if self.transform is not None else item
