"""Plot pieces the stages share: a per-rod map of a square array and the atomic PNG save."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["rod_map", "save_png"]


def rod_map(fig, ax, values, label: str, title: str, cmap: str = "viridis") -> None:
    """``values`` (n_rods,) drawn as the array (rod r at row r // side, column r % side) when n is a
    square, else as bars."""
    values = np.asarray(values, dtype=float)
    n = len(values)
    side = int(round(np.sqrt(n)))
    if side * side == n:
        im = ax.imshow(values.reshape(side, side), origin="lower", cmap=cmap)
        fig.colorbar(im, ax=ax, label=label)
        ax.set(title=title, xlabel="column", ylabel="row", xticks=range(side), yticks=range(side))
    else:
        ax.bar(np.arange(n), values)
        ax.set(title=title, xlabel="rod", ylabel=label)


def save_png(fig, path: Path, dpi: int = 110) -> Path:
    """Save and close ``fig``; an interrupted write leaves no half file under ``path``'s name."""
    import matplotlib.pyplot as plt

    path = Path(path)
    tmp = path.with_name(f".{path.stem}.part.png")
    fig.savefig(tmp, dpi=dpi)
    plt.close(fig)
    os.replace(tmp, path)
    return path
