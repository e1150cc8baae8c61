"""Atomic file output: every file mlsim writes appears whole or not at all (base layer)."""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["atomic_bytes"]


def atomic_bytes(path: Path, data: bytes) -> Path:
    """Write ``data`` to ``path`` under a temporary name and rename: never a half-written file."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.part")
    tmp.write_bytes(data)
    os.replace(tmp, path)
    return path
