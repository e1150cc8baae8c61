"""The studies: orchestration (layer 2) that runs the pipeline and reports on it.

Each study is a driver and its report; the physics it measures stays in its stage's package (the
direction estimator in :mod:`dllm.direction`, the detector in :mod:`dllm.episode`, the render tiers in
:mod:`mlsim.render`), and no stage package imports this one (``tests/test_layers.py``).

- :mod:`mlsim.studies.accuracy`: ``mlsim accuracy``, the solve tiers against the reference (and the
  error measures the other accuracy studies share);
- :mod:`mlsim.studies.render_accuracy`: ``mlsim render-accuracy``, the render tiers against path tracing;
- :mod:`mlsim.studies.direction`: ``mlsim direction``, the DLLM's angle against the push direction;
- :mod:`mlsim.studies.ambient`: ``mlsim ambient``, the detector's thresholds under ambient light;
- :mod:`mlsim.studies.classifier_cli`: ``mlsim train | evaluate | ablation`` of the interaction classifier;
- :mod:`mlsim.studies.anyskin_cli`: ``mlsim anyskin-train``, the AnySkin helmet's estimators;
- :mod:`mlsim.studies.verify_s2`: the published FEM set-up of SPEC 1.4 (its set-up in :mod:`fem.verify_s2`),
  run as the ``verify_s2`` output of ``ml_rod_array`` through its stage in :mod:`mlsim.studies.stages`,
  which the registry adds to the kind (:data:`mlsim.stage.BUILTIN_STUDY_STAGES`).

Beside it, the two job drivers: :mod:`mlsim.dataset` (datasets of episodes) and :mod:`mlsim.sweep`
(design sweeps).
"""
