"""Interaction classifier of the MAVIG (SPEC 1.7): a 1D CNN on 8-frame windows of DLLM features.

- :mod:`classifiers.windows`: class names and the 4-class merge, robot commands, input channels,
  standardisation, windows of episodes and streams (pure numpy);
- :mod:`classifiers.interaction_cnn`: the network;
- :mod:`classifiers.train`: held-out-people training, evaluation, model files, ablation, stream
  prediction.

Their commands, ``mlsim train | evaluate | ablation`` and ``mlsim anyskin-train``, are orchestration:
:mod:`mlsim.studies.classifier_cli` and :mod:`mlsim.studies.anyskin_cli`.

Names are imported on first use, so ``from mlsim.studies.classifier_cli import add_parsers`` (done by the
``mlsim`` command line at start-up) does not import torch. ``classifiers.train`` is the module
(its function: ``from classifiers.train import train``).
"""

from __future__ import annotations

import importlib

_WHERE = {
    "classifiers.windows": (
        "CLASS_NAMES_4", "CLASS_NAMES_8", "DEFAULT_FEATURE_SET", "DEFAULT_STRIDE", "MERGE_8_TO_4", "ROBOT_COMMANDS",
        "WINDOW_LENGTH", "ClassifierInputError", "Standardizer", "Windows", "channel_names", "channels", "class_names",
        "cut_windows", "robot_command", "stream_windows", "to_four_class",
    ),
    "classifiers.interaction_cnn": ("InteractionCNN", "predict_proba", "softmax_probabilities"),
    "classifiers.train": (
        "ABLATION_FEATURE_SETS", "AblationRow", "Experiment", "Metrics", "StreamPrediction", "TrainResult", "ablation",
        "classification_metrics", "evaluate", "heldout_experiment", "load_model", "plot_confusion", "plot_history",
        "predict_windows", "save_model", "split_people", "split_validation", "write_ablation",
    ),
}
_MODULE_OF = {name: module for module, names in _WHERE.items() for name in names}

__all__ = sorted(_MODULE_OF)


def __getattr__(name: str):
    module = _MODULE_OF.get(name)
    if module is None:
        raise AttributeError(f"module 'classifiers' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__():
    return sorted(set(globals()) | set(__all__))
