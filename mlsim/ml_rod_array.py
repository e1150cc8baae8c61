"""The ``ml_rod_array`` sensor kind: the mechanoluminescent rod array of SPEC 1 and its stages, in
the order of the flow of data (geometry -> mesh -> solve -> emission -> render -> camera; calibration
-> DLLM -> classify). Imported by :func:`mlsim.stage.kind` on first use, which then adds the stages of
the studies run as this kind's outputs (:data:`mlsim.stage.BUILTIN_STUDY_STAGES`: the verification
case of SPEC 1.4)."""

from __future__ import annotations

from classifiers.stage import CLASSIFY
from dllm.stage import DLLM
from fem.finite_strain import dynamics_step_problems
from fem.stages import GEOMETRY, MESH, SOLVE
from mlsim.emission.stage import EMISSION
from mlsim.render.stage import CALIBRATION, CAMERA, RENDER
from mlsim.scene import SensorSpec
from mlsim.stage import register_kind

KIND = register_kind("ml_rod_array", SensorSpec, [GEOMETRY, MESH, SOLVE, EMISSION, RENDER, CAMERA, CALIBRATION, DLLM, CLASSIFY],
                     check=dynamics_step_problems)
