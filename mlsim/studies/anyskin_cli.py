"""``mlsim anyskin-train``: train the AnySkin helmet's causal contact CNN and LSTM-MLP force map (SPEC 2).

    mlsim anyskin-train SCENE [--out DIR] [--seed N] [--runs 12] [--cnn-epochs N] [--lstm-steps N] [--workers N] [--set PATH=VALUE] [--dry-run]

SCENE is an AnySkin scene (``sensor.kind = "anyskin"``); its sensor, trajectory and estimator
settings shape the simulated training runs (:mod:`classifiers.anyskin_train`). Writes
``anyskin_contact_cnn.pt``, ``anyskin_force_lstm.pt`` and ``anyskin_train.json``; name the two files
in the scene's ``[sensor.estimator]`` (``contact_model``, ``force_model``) to use them. Exit codes:
0 success, 2 bad input (the message names the field).
"""

from __future__ import annotations

import sys
from pathlib import Path

__all__ = ["add_parsers", "cmd_anyskin_train"]

EXIT_OK, EXIT_BAD_INPUT = 0, 2


def cmd_anyskin_train(args) -> int:
    """Simulate training runs of the scene's helmet, train both nets, print their held-out scores."""
    from mlsim.scene import load_scene

    from mlsim.cli_grammar import parse_sets

    scene = load_scene(args.scene, overrides=parse_sets(args.set))
    if scene.kind != "anyskin":
        print(f"error: sensor.kind = {scene.kind!r} in {args.scene}: anyskin-train needs an AnySkin scene "
              "(e.g. scenes/anyskin/headon_push.toml)", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.runs < 4 or args.runs % 2:
        print(f"error: --runs = {args.runs}: give an even number >= 4 (half with drift, half without; one of each held out)",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    out = Path(args.out) if args.out else Path("out") / "anyskin_train"
    if args.dry_run:
        print(f"would simulate {args.runs} training runs of {args.scene}'s helmet (seed {args.seed}), train the contact CNN "
              f"({args.cnn_epochs} epochs) and the LSTM-MLP ({args.lstm_steps} steps) on {args.workers} thread(s); writes to {out}")
        return EXIT_OK
    from classifiers.anyskin_train import train_anyskin

    log = (lambda m: None) if args.quiet else (lambda m: print(m, file=sys.stderr))
    m = train_anyskin(scene.sensor, out, seed=args.seed, runs=args.runs, cnn_epochs=args.cnn_epochs, lstm_steps=args.lstm_steps,
                      threads=args.workers, log=log)
    c, f = m["contact_cnn"], m["force_lstm"]
    names = ("idle", "onset", "release")
    print(f"contact CNN: held-out windows {c['val_windows']}; " + ", ".join(
        f"{n} recall {100 * r:.1f} % precision {100 * p:.1f} %" for n, r, p in zip(names, c["val_recall"], c["val_precision"])))
    print("force LSTM-MLP: held-out MAE x, y, z = " + ", ".join(f"{v:.2f}" for v in f["val_mae_xyz_n"]) + " N (drift-free run)")
    print(f"seconds: simulate {m['seconds']['simulate']:.1f}, CNN {m['seconds']['cnn']:.1f}, LSTM {m['seconds']['lstm']:.1f} "
          f"on {args.workers} thread(s)")
    print(f"wrote {out / 'anyskin_contact_cnn.pt'}, {out / 'anyskin_force_lstm.pt'}, {out / 'anyskin_train.json'}")
    return EXIT_OK


def add_parsers(subparsers) -> None:
    """Add ``anyskin-train`` to an argparse sub-parsers object (``func`` = handler)."""
    import argparse

    from mlsim.cli_grammar import Formatter, add_shared, examples_epilog

    what = "train the AnySkin helmet's causal contact CNN and LSTM-MLP force map (SPEC 2)"
    p = subparsers.add_parser("anyskin-train", help=what, description=what, epilog=examples_epilog("anyskin-train"), formatter_class=Formatter)
    p.add_argument("scene", metavar="SCENE", help="an AnySkin scene, e.g. scenes/anyskin/headon_push.toml")
    # the trained weights go to --out; scenes/anyskin/models (the shipped ones) only when named
    add_shared(p, "anyskin-train", out_default="out/anyskin_train", workers_default=1,
               workers_help="torch CPU threads (default 1: the weights reproduce for one count)")
    p.add_argument("--seed", type=int, default=0, help="seed of the runs, the idle draws, the crops, the weights and batch orders")
    p.add_argument("--runs", type=int, default=12, help="simulated 12 s runs (even; half with the skin's set)")
    p.add_argument("--cnn-epochs", type=int, default=16, help="CNN epochs (the best on the held-out runs is kept)")
    p.add_argument("--lstm-steps", type=int, default=400, help="LSTM-MLP steps (the best on the held-out run is kept)")
    p.add_argument("--threads", dest="workers", type=int, default=argparse.SUPPRESS, help=argparse.SUPPRESS)  # the old name of --workers
    p.set_defaults(func=cmd_anyskin_train)
