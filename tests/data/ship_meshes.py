"""Ship the meshes the test suite uses, so that every test run sees the same meshes.

fTetWild is not deterministic: every fresh build of a scene gives a different mesh (even with one
thread), and a test that passes on one mesh can fail on another (an element inverting in a
nonlinear slide, say). The suite therefore loads its meshes from ``tests/data/meshes/<key>/``
(``conftest.py`` copies them into the session's cache before any test runs); ``key`` is the mesh
stage's cache key (:func:`mlsim.pipeline.stage_key`), which changes with the mesh stage's version
and with the scene fields it reads.

Regenerate after such a change (``tests/test_shipped_meshes.py`` fails and says so)::

    MLSIM_CACHE_DIR=/tmp/mesh_cache MLSIM_TEST_KEEP_CACHE=1 .venv/bin/pytest -x -q
    .venv/bin/python tests/data/ship_meshes.py /tmp/mesh_cache

The second command replaces the shipped set with every mesh that run built or loaded.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

SHIPPED = Path(__file__).resolve().parent / "meshes"
FILES = ("mesh.npz", "report.json")


def seed_cache(cache_root: Path) -> int:
    """Copy the shipped meshes into a pipeline cache (as completed ``mesh`` entries); returns how many."""
    n = 0
    for entry in sorted(SHIPPED.iterdir()) if SHIPPED.is_dir() else ():
        target = Path(cache_root) / "mesh" / entry.name
        if (target / "COMPLETE").is_file():
            continue
        target.mkdir(parents=True, exist_ok=True)
        for name in FILES:
            shutil.copyfile(entry / name, target / name)
        (target / "COMPLETE").write_text(entry.name)
        n += 1
    return n


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("cache", type=Path, help="the pipeline cache a full test run used (MLSIM_CACHE_DIR)")
    args = ap.parse_args()
    built = sorted(d for d in (args.cache / "mesh").iterdir() if (d / "COMPLETE").is_file())
    if not built:
        raise SystemExit(f"no completed mesh entries under {args.cache / 'mesh'}; run the suite with that cache first")
    shutil.rmtree(SHIPPED, ignore_errors=True)
    for d in built:
        (SHIPPED / d.name).mkdir(parents=True)
        for name in FILES:
            shutil.copyfile(d / name, SHIPPED / d.name / name)
    size = sum(f.stat().st_size for f in SHIPPED.rglob("*"))
    print(f"shipped {len(built)} meshes ({size / 1e6:.1f} MB) to {SHIPPED}")


if __name__ == "__main__":
    main()
