"""The ``ml_rod_array`` sensor kind: the mechanoluminescent rod array of SPEC 1 and its stages, in
the order of the flow of data (geometry -> mesh -> solve -> emission -> render -> camera; calibration
-> DLLM -> classify; and the verification case of SPEC 1.4). Imported by :func:`mlsim.stage.kind`
on first use."""

from __future__ import annotations

from classifiers.stage import CLASSIFY
from dllm.stage import DLLM
from fem.finite_strain import dynamics_step_problems
from fem.stages import GEOMETRY, MESH, SOLVE, VERIFY_S2
from mlsim.emission.stage import EMISSION
from mlsim.render.stage import CALIBRATION, CAMERA, RENDER
from mlsim.scene import SensorSpec
from mlsim.stage import register_kind

KIND = register_kind("ml_rod_array", SensorSpec, [GEOMETRY, MESH, SOLVE, EMISSION, RENDER, CAMERA, CALIBRATION, DLLM, CLASSIFY, VERIFY_S2],
                     check=dynamics_step_problems)
