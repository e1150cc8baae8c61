"""MkDocs hook: the generated reference pages (mlsim.docgen) join the site when it is built.

They are made in memory from the code (the scene models, the stage registry, the CLI parser), never
written into docs/, so they cannot go stale in git.
"""

from __future__ import annotations

from mkdocs.structure.files import File

GENERATED = {
    "reference/scene.md": "scene_reference",
    "reference/outputs.md": "outputs_reference",
    "reference/cli.md": "cli_reference",
    "reference/dataset.md": "dataset_reference",
    "validation.md": "validation_reference",
    "benchmarks.md": "benchmarks_reference",
}


def on_files(files, config):
    from mlsim import docgen

    for path, maker in GENERATED.items():
        files.append(File.generated(config, path, content=getattr(docgen, maker)()))
    return files


def on_page_markdown(markdown, page, config, files):
    """``<!-- measured: NAME -->`` on a page becomes the table of a recorded output (mlsim.docgen.RECORDINGS)."""
    from mlsim import docgen

    return docgen.expand_measured(markdown)
