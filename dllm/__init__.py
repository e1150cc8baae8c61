"""DLLM: the event-driven detector of SPEC 1.6 that turns camera frames into per-rod features.

- :mod:`dllm.calibration`: the rods' disks found on the calibration frame (Hough circles);
- :mod:`dllm.detector`: the streaming detector (thresholds from idle frames, events, features l, d, omega);
- :mod:`dllm.batched`: the same detector over a batch of episodes (kornia + torch);
- :mod:`dllm.features`: the feature conventions (angles in degrees and radians);
- :mod:`dllm.episode`: the detector over one episode's frames, its files and summary;
- :mod:`dllm.stage`: the ``dllm`` stage of the ``ml_rod_array`` sensor kind;
- :mod:`dllm.direction`: the direction estimator (SPEC 1.5).

The studies that run the detector through the pipeline (``mlsim direction``, ``mlsim ambient``) are
orchestration, in :mod:`mlsim.studies`.
"""
