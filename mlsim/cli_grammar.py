"""The command line's one grammar (orchestration layer): the flags every verb shares, their defaults,
and each verb's examples.

Every verb that reads a scene takes it as its first positional argument (``SCENE``; a dataset spec,
``SPEC``, for ``mlsim dataset``; a dataset folder, ``DATASET``, for the classifier's verbs; the
recording, ``RECORDING``, for ``mlsim detect``, whose scene is optional: ``--scene``) and, where
they make sense, the same flags with the same defaults:

==============  =====================================================================================
``--set``       change a field for this run: ``--set sensor.rod.height_mm=12`` (values parsed as TOML)
``--dry-run``   print what would run (the plan, what is cached, the study's grid) and run nothing
``--out``       the output folder (default ``out/<scene name>[_<verb>]``; a rerun into it resumes)
``--workers``   processes (or, for training, torch threads) in parallel: :func:`default_workers`
``--cache``     the stage cache (default ``$MLSIM_CACHE_DIR`` or ``~/.cache/mlsim``)
``--quiet``     no progress bars or log lines
==============  =====================================================================================

``tests/test_cli_grammar.py`` checks every verb against :data:`SHARED_FLAGS` and that each verb's
``--help`` shows an example.
"""

from __future__ import annotations

import argparse
import os
import tomllib

from mlsim.errors import Problem, SceneError

__all__ = ["SHARED_FLAGS", "EXAMPLES", "Formatter", "default_workers", "add_shared", "examples_epilog", "parse_sets"]

#: verb -> the shared flags it takes (the others make no sense for it: ``check`` writes nothing,
#: ``run`` has no parallel work, the classifier's verbs read a dataset, not the stage cache,
#: ``detect`` runs the DLLM on a recording and caches nothing).
SHARED_FLAGS: dict[str, tuple[str, ...]] = {
    "run": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "check": ("--set",),
    "mesh": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "accuracy": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "direction": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "ambient": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "dataset": ("--set", "--dry-run", "--out", "--workers", "--cache", "--quiet"),
    "sweep": ("--set", "--dry-run", "--out", "--workers", "--cache", "--quiet"),
    "detect": ("--set", "--dry-run", "--out", "--quiet"),
    "calibrate": ("--set", "--dry-run", "--out", "--cache", "--quiet"),
    "train": ("--dry-run", "--out", "--workers", "--quiet"),
    "evaluate": ("--dry-run", "--out", "--quiet"),
    "ablation": ("--dry-run", "--out", "--workers", "--quiet"),
    "anyskin-train": ("--set", "--dry-run", "--out", "--workers", "--quiet"),
}

#: verb -> example command lines shown in its ``--help``.
EXAMPLES: dict[str, tuple[str, ...]] = {
    "run": ("mlsim run scenes/mavig_tiny.toml --dry-run", "mlsim run scenes/mavig_default.toml --out out/demo",
            "mlsim run scenes/mavig_default.toml --set sensor.rod.height_mm=12 --outputs mesh",
            "mlsim run scenes/mavig_default.toml --max-memory-gb 8 --max-frames 600"),
    "check": ("mlsim check scenes/mavig_default.toml", "mlsim check scenes/mavig_tiny.toml --set sensor.rows=3"),
    "mesh": ("mlsim mesh scenes/mavig_tiny.toml", "mlsim mesh scenes/mavig_default.toml --set fidelity.mesh.edge_length_mm=1.5 --dry-run"),
    "accuracy": ("mlsim accuracy scenes/mavig_tiny.toml --stage solve --edges 3.0 2.5 --out out/acc",
                 "mlsim accuracy scenes/mavig_default.toml --stage render --dry-run"),
    "direction": ("mlsim direction scenes/direction_test.toml --angles 0 15 30 45 60 75 90",
                  "mlsim direction scenes/direction_test.toml --dry-run"),
    "ambient": ("mlsim ambient scenes/ambient.toml --dry-run", "mlsim ambient scenes/ambient.toml --alphas 1.02 1.05 --betas 1.1 1.3"),
    "dataset": ("mlsim dataset scenes/interactions/small.toml --out out/small --workers 2",
                "mlsim dataset scenes/interactions/paper.toml --set samples_per_action=20 --dry-run"),
    "sweep": ("mlsim sweep scenes/mavig_default.toml --vary sensor.rod.height_mm=6,7.5,9,10.5,12 --out out/sweep_height",
              "mlsim sweep scenes/mavig_default.toml --zip --vary sensor.materials.core=SC37,PDMS --vary sensor.materials.ml_layer=SC37,PDMS --dry-run"),
    "detect": ("mlsim detect recording.mp4 --calibration photo.png --scene scenes/mavig_default.toml --out out/detect",
               "mlsim detect frames/ --calibration photo.png --idle idle.mp4 --model out/model/interaction_8class.pt --dry-run"),
    "calibrate": ("mlsim calibrate scenes/mavig_default.toml --photo photo.png --idle idle.mp4 --out out/my_sensor",
                  "mlsim calibrate scenes/mavig_default.toml --photo photo.png --press press.mp4 --force-n 2 --out out/my_sensor --dry-run"),
    "train": ("mlsim train out/small --out out/model", "mlsim train out/small --classes 8 --features distance,angle --workers 2"),
    "evaluate": ("mlsim evaluate out/small --model out/model/interaction_8class.pt --out out/eval",),
    "ablation": ("mlsim ablation out/small --out out/ablation", "mlsim ablation out/small --sets intensity distance+angle"),
    "anyskin-train": ("mlsim anyskin-train scenes/anyskin/headon_push.toml --out out/anyskin_train",
                      "mlsim anyskin-train scenes/anyskin/headon_push.toml --dry-run"),
}

_HELP = {
    "--set": "change a scene field for this run, e.g. sensor.rod.height_mm=12 (repeat; values parsed as TOML)",
    "--dry-run": "print what would run (the plan, what is cached) and run nothing",
    "--cache": "stage cache folder (default $MLSIM_CACHE_DIR or ~/.cache/mlsim)",
    "--quiet": "no progress bars or log lines",
}

#: the verbs whose --dry-run also prints each stage's cost estimate (issue 39: mlsim.run_budget)
_DRY_RUN_HELP = {v: "print the plan, what is cached and each stage's cost estimate (frames, steps, tets, memory, time); run nothing"
                 for v in ("run", "mesh")}


def default_workers() -> int:
    """The shared default of ``--workers``: every CPU this process may use."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def examples_epilog(verb: str) -> str:
    return "examples:\n" + "\n".join(f"  {line}" for line in EXAMPLES.get(verb, ()))


class Formatter(argparse.RawDescriptionHelpFormatter):
    """Keeps the examples' lines; ``--outputs`` lists its choices when help is shown (the sensor kinds
    are imported then, not on every command)."""

    def _expand_help(self, action):
        text = super()._expand_help(action)
        if action.dest == "outputs":
            from mlsim.stage import kinds, outputs

            text += "; choose from: " + "; ".join(f"{k}: {', '.join(outputs(k))}" for k in kinds())
        return text


def add_shared(p: argparse.ArgumentParser, verb: str, *, out_default: str = "", workers_default: int | None = None,
               workers_help: str = "") -> None:
    """Add the verb's shared flags (:data:`SHARED_FLAGS`) to its parser ``p``. ``workers_default``: only
    where the shared default does not fit (training: one torch thread, so that weights reproduce)."""
    flags = SHARED_FLAGS[verb]
    if "--set" in flags:
        p.add_argument("--set", action="append", metavar="PATH=VALUE", help=_HELP["--set"])
    if "--dry-run" in flags:
        p.add_argument("--dry-run", action="store_true", help=_DRY_RUN_HELP.get(verb, _HELP["--dry-run"]))
    if "--out" in flags:
        p.add_argument("--out", metavar="DIR", help=f"output folder (default {out_default})")
    if "--workers" in flags:
        p.add_argument("--workers", type=int, default=workers_default or default_workers(), metavar="N",
                       help=workers_help or "processes in parallel, one thread each (default: the CPU count)")
    if "--cache" in flags:
        p.add_argument("--cache", metavar="DIR", help=_HELP["--cache"])
    if "--quiet" in flags:
        p.add_argument("--quiet", action="store_true", help=_HELP["--quiet"])


def parse_sets(items: list[str] | None) -> dict:
    """``--set sensor.rod.height_mm=12`` -> {"sensor.rod.height_mm": 12} (values parsed as TOML)."""
    out = {}
    for item in items or []:
        if "=" not in item:
            raise SceneError([Problem("--set", item, "expected DOTTED.PATH=VALUE, e.g. sensor.rod.height_mm=12")])
        key, _, raw = item.partition("=")
        try:
            value = tomllib.loads(f"v = {raw}")["v"]
        except tomllib.TOMLDecodeError:
            value = raw  # a bare word: a string (e.g. fidelity.solve.tier=linear)
        out[key.strip()] = value
    return out
