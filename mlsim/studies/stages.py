"""The stages that orchestration modules add to a sensor kind: a study run as one of the kind's
outputs. Declared here, light (each imports its study inside its functions), and found by the
registry through :data:`mlsim.stage.BUILTIN_STUDY_STAGES`, so that the kind's module (a stage
package) never imports a study.

- ``verify_s2`` (``ml_rod_array``): the published FEM set-up of SPEC 1.4, :mod:`mlsim.studies.verify_s2`.
"""

from __future__ import annotations

from pathlib import Path

from mlsim.scene import Scene
from mlsim.stage import RunContext, Stage, pickle_load, pickle_save

__all__ = ["VERIFY_S2"]


def _verify_s2_run(scene: Scene, inputs: dict, ctx: "RunContext"):
    from mlsim.scene import resolve_material
    from mlsim.studies.verify_s2 import run

    spec = scene.verify_s2
    materials = {name: resolve_material(name, scene.materials) for name in {spec.slab_material, spec.block_material}}
    return run(spec, progress=ctx.progress, log=ctx.log, materials=materials)


def _verify_s2_write(result, out_dir: Path, ctx: "RunContext") -> list[Path]:
    from mlsim.studies.verify_s2 import write

    return write(result, out_dir)


def _verify_s2_summary(result) -> dict:
    from mlsim.studies.verify_s2 import summary

    return summary(result)


VERIFY_S2 = Stage(
    name="verify_s2",
    doc="the published FEM set-up of SPEC 1.4 (rod on a slab vs steel block on a slab); profiles CSV and plot, ratios in the summary",
    reads=("verify_s2", "materials"),
    needs=(),
    run=_verify_s2_run,
    save=pickle_save,  # an internal cache of this code version (the stage key carries the version)
    load=pickle_load,
    write=_verify_s2_write,
    summarize=_verify_s2_summary,
)
