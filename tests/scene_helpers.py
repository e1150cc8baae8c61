"""Edits of a shipped scene file that the scene model must refuse naming the field (the bad-input
tests of the sibling sensors' richer models)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mlsim.scene import SceneError, load_scene


def assert_edits_refused(scene_file: Path, edits, tmp_path: Path) -> None:
    """Each (old text, new text, dotted field) of ``edits`` applied alone to ``scene_file`` is refused by
    :func:`mlsim.scene.load_scene` with a :class:`SceneError` naming the field."""
    text = Path(scene_file).read_text()
    for old, new, field in edits:
        assert old in text, f"{scene_file} no longer holds {old!r}: update the test's edit"
        path = tmp_path / "bad.toml"
        path.write_text(text.replace(old, new, 1))
        with pytest.raises(SceneError, match=field.replace(".", r"\.")):
            load_scene(path)
