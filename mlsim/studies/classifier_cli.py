"""Sub-commands ``mlsim train | evaluate | ablation`` of the interaction classifier (SPEC 1.7).

``add_parsers(subparsers)`` adds them to the ``mlsim`` parser; each handler returns an exit code
(0 success, 2 bad input: the message names the field). Datasets are read with
``mlsim.dataset.reader.load_episodes`` (imported when a command runs).

    mlsim train DATASET --out DIR [--classes 8|4|both] [--seed N] [--epochs N] [--features distance,angle] [--workers N]
    mlsim evaluate DATASET --model FILE --out DIR [--people held-out|all|3,7]
    mlsim ablation DATASET --out DIR [--seed N] [--epochs N]
"""

from __future__ import annotations

import sys
from pathlib import Path

from classifiers.windows import DEFAULT_STRIDE, ClassifierInputError, feature_set_of

__all__ = ["add_parsers", "cmd_train", "cmd_evaluate", "cmd_ablation"]

EXIT_OK, EXIT_BAD_INPUT = 0, 2


def _load_dataset(path: str) -> list[dict]:
    from mlsim.dataset.reader import load_episodes  # lazily: the dataset package is optional here

    if not Path(path).exists():
        raise ClassifierInputError(f"DATASET {path}: not found; make one with 'mlsim dataset'")
    try:
        episodes = load_episodes(path)
    except FileNotFoundError as exc:  # a directory without a dataset store
        raise ClassifierInputError(f"DATASET {exc}") from None
    if not episodes:
        raise ClassifierInputError(f"DATASET {path}: holds no episodes")
    return episodes


def _held_out(text: str):
    """"0.2" -> 0.2 (a fraction of people); "3,7" -> [3, 7] (these people)."""
    try:
        if "," in text or text.strip().isdigit():
            return [int(t) for t in text.split(",") if t.strip()]
        return float(text)
    except ValueError:
        raise ClassifierInputError(f"--held-out = {text!r}: give a fraction of people (0.2) or person ids (3,7)") from None


def _log(args):
    return (lambda msg: None) if args.quiet else (lambda msg: print(msg, file=sys.stderr))


def _guard(handler):
    """Run a handler; input errors become a message and exit code 2."""

    def run(args) -> int:
        try:
            return handler(args)
        except ClassifierInputError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return EXIT_BAD_INPUT

    run.__name__ = handler.__name__
    run.__doc__ = handler.__doc__
    return run


def _metrics_line(label: str, m, seconds: float | None = None, epochs: str = "") -> str:
    s = f"{label:<10} {100 * m.accuracy:>8.2f} % {100 * m.episode_accuracy:>8.2f} % {m.macro_f1:>8.3f} {m.n_windows:>8d}"
    if seconds is not None:
        s += f" {seconds:>8.1f} {epochs:>7}"
    return s


def _per_class(m) -> str:
    return "\n".join(
        f"  {name:<14} precision {m.precision[k]:.3f}  recall {m.recall[k]:.3f}  F1 {m.f1[k]:.3f}  ({int(m.support[k])} windows)"
        for k, name in enumerate(m.class_names)
    )


@_guard
def cmd_train(args) -> int:
    """Hold people out, train the 8- and/or 4-class classifiers, score them on the held-out people."""
    from classifiers.train import heldout_experiment, metrics_json, plot_confusion, plot_history, save_model

    fs = feature_set_of(args.features)
    if args.dry_run:
        return _dry_run(args, f"train the {args.classes}-class classifier(s) on {', '.join(fs)} with {args.workers} thread(s)",
                        "out/interaction_train")
    episodes = _load_dataset(args.dataset)
    out = Path(args.out) if args.out else Path("out") / "interaction_train"
    log = _log(args)
    classes = {"8": (8,), "4": (4,), "both": (8, 4)}[args.classes]
    experiments, written = {}, []
    for k in classes:
        log(f"training the {k}-class classifier on {', '.join(fs)}")
        exp = heldout_experiment(episodes, k, fs, args.seed, held_out=_held_out(args.held_out), epochs=args.epochs,
                                 batch_size=args.batch_size, lr=args.lr, stride=args.stride, n_threads=args.workers, log=log)
        experiments[f"{k}class"] = exp
        tag = f"{k}class"
        written.append(save_model(exp.result, out / f"interaction_{tag}.pt"))
        written.append(plot_confusion(exp.metrics.confusion, exp.metrics.class_names, out / f"confusion_{tag}.png",
                                      title=f"{k} classes, people {exp.test_people.tolist()} held out: "
                                            f"{100 * exp.metrics.accuracy:.1f} %"))
        written.append(plot_history(exp.result.history, out / f"training_{tag}.png", exp.result.best_epoch,
                                    title=f"{k} classes, {'+'.join(fs)}"))
    written.append(metrics_json(experiments, out / "metrics.json"))
    first = next(iter(experiments.values()))
    print(f"features {'+'.join(fs)} ({first.result.standardizer.n_channels} channels); "
          f"train people {first.train_people.tolist()}, held out {first.test_people.tolist()}")
    print(f"{'model':<10} {'accuracy':>10} {'episodes':>10} {'macro F1':>8} {'windows':>8} {'train s':>8} {'epochs':>7}")
    for tag, exp in experiments.items():
        r = exp.result
        print(_metrics_line(tag, exp.metrics, r.train_seconds, f"{r.best_epoch + 1}/{len(r.history['train_loss'])}"))
    print("(SPEC 1.7 reference on real data: 92.68 % with 8 classes, 97.37 % with 4)")
    print("wrote " + ", ".join(str(p) for p in written))
    return EXIT_OK


@_guard
def cmd_evaluate(args) -> int:
    """Score a saved classifier on a dataset (by default on the people it held out)."""
    import json

    from classifiers.train import episodes_of_people, evaluate, load_model, plot_confusion

    if args.dry_run:
        if not Path(args.model).is_file():
            raise ClassifierInputError(f"--model {args.model}: not found; train one with 'mlsim train'")
        return _dry_run(args, f"score {args.model} (people: {args.people})", "out/interaction_evaluate")
    result = load_model(args.model)
    episodes = _load_dataset(args.dataset)
    if args.people == "held-out":
        if not result.test_people:
            raise ClassifierInputError(f"--people held-out: {args.model} records no held-out people; use --people all or ids (3,7)")
        people = list(result.test_people)
    elif args.people == "all":
        people = sorted({int(ep["person"]) for ep in episodes})
    else:
        people = _held_out(args.people)
        if not isinstance(people, list):
            raise ClassifierInputError(f"--people = {args.people!r}: give held-out, all, or person ids (3,7)")
    chosen = episodes_of_people(episodes, people)
    if not chosen:
        raise ClassifierInputError(f"--people {args.people}: no episode of people {people} in {args.dataset}")
    overlap = sorted(set(people) & set(result.train_people))
    if overlap:
        print(f"warning: people {overlap} were trained on; their scores are optimistic", file=sys.stderr)
    m = evaluate(result, chosen, stride=args.stride)
    out = Path(args.out) if args.out else Path("out") / "interaction_evaluate"
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps({"model": str(args.model), "people": people, "metrics": m.to_dict()}, indent=2) + "\n")
    png = plot_confusion(m.confusion, m.class_names, out / "confusion.png",
                         title=f"{result.n_classes} classes, people {people}: {100 * m.accuracy:.1f} %")
    print(f"model {args.model}: {result.n_classes} classes, features {'+'.join(result.feature_set)}; people {people}")
    print(f"{'model':<10} {'accuracy':>10} {'episodes':>10} {'macro F1':>8} {'windows':>8}")
    print(_metrics_line(f"{result.n_classes}class", m))
    print(_per_class(m))
    print(f"wrote {out / 'metrics.json'}, {png}")
    return EXIT_OK


@_guard
def cmd_ablation(args) -> int:
    """Held-out accuracy of each DLLM feature set alone and in pairs (SPEC 1.7)."""
    from classifiers.train import ABLATION_FEATURE_SETS, ablation

    sets = [feature_set_of(s.replace("+", ",")) for s in args.sets] if args.sets else list(ABLATION_FEATURE_SETS)
    if args.dry_run:
        return _dry_run(args, f"train {2 * len(sets)} classifiers ({len(sets)} feature sets x 8 and 4 classes)", "out/interaction_ablation")
    episodes = _load_dataset(args.dataset)
    out = Path(args.out) if args.out else Path("out") / "interaction_ablation"
    rows = ablation(episodes, sets, seed=args.seed, held_out=_held_out(args.held_out), out_dir=out, log=_log(args),
                    epochs=args.epochs, stride=args.stride, n_threads=args.workers)
    print(f"{'feature set':<20} {'channels':>8} {'8 classes':>10} {'4 classes':>10} {'train s':>8}")
    for r in rows:
        print(f"{r.name:<20} {r.n_channels:>8d} {100 * r.accuracy_8:>8.2f} % {100 * r.accuracy_4:>8.2f} % "
              f"{r.train_seconds_8 + r.train_seconds_4:>8.1f}")
    print(f"wrote {out / 'ablation.csv'}, {out / 'ablation.md'}")
    return EXIT_OK


def _dry_run(args, what: str, out_default: str) -> int:
    """``--dry-run``: the dataset's stored episodes and what the command would do with them; nothing is trained."""
    from mlsim.dataset.store import complete_episodes

    if not Path(args.dataset).exists():
        raise ClassifierInputError(f"DATASET {args.dataset}: not found; make one with 'mlsim dataset'")
    episodes = complete_episodes(args.dataset)
    if not episodes:
        raise ClassifierInputError(f"DATASET {args.dataset}: holds no episodes")
    print(f"would {what} on {len(episodes)} episodes of {args.dataset}; writes to {args.out or out_default}")
    return EXIT_OK


def add_parsers(subparsers) -> None:
    """Add ``train``, ``evaluate`` and ``ablation`` to an argparse sub-parsers object (``func`` = handler)."""
    import argparse

    from mlsim.cli_grammar import Formatter, add_shared, examples_epilog

    def parser(name: str, help: str):
        return subparsers.add_parser(name, help=help, description=help, epilog=examples_epilog(name), formatter_class=Formatter)

    def common(p, name: str, training: bool = True):
        p.add_argument("dataset", metavar="DATASET", help="dataset folder of 'mlsim dataset' (read by mlsim.dataset.reader.load_episodes)")
        add_shared(p, name, out_default=f"out/interaction_{name}", workers_default=1,
                   workers_help="torch CPU threads (default 1: the weights reproduce for one count)")
        p.add_argument("--stride", type=int, default=None if not training else DEFAULT_STRIDE,
                       help=f"frames between window starts (default {DEFAULT_STRIDE}" + ("" if training else ", the model's") + ")")
        if training:
            p.add_argument("--seed", type=int, default=0, help="seed of the people split, validation split, weights, batch order")
            p.add_argument("--epochs", type=int, default=40, help="most epochs (early stopping after 10 without improvement)")
            p.add_argument("--held-out", default="0.2", help="held-out people: a fraction (0.2 of 10 people = 2) or ids (3,7)")
            p.add_argument("--threads", dest="workers", type=int, default=argparse.SUPPRESS, help=argparse.SUPPRESS)  # the old name of --workers

    p = parser("train", "train the interaction classifier (SPEC 1.7) on held-in people, score the held-out")
    common(p, "train")
    p.add_argument("--classes", default="both", choices=["8", "4", "both"], help="8 interactions, the merged 4, or both")
    p.add_argument("--features", default="distance,angle", help="channels: comma-separated from intensity, distance, angle")
    p.add_argument("--batch-size", type=int, default=64)
    p.add_argument("--lr", type=float, default=1e-3, help="Adam learning rate")
    p.set_defaults(func=cmd_train)

    p = parser("evaluate", "score a trained interaction classifier on a dataset")
    common(p, "evaluate", training=False)
    p.add_argument("--model", required=True, help="model file written by 'mlsim train' (interaction_8class.pt)")
    p.add_argument("--people", default="held-out", help="held-out (the model's test people), all, or ids (3,7)")
    p.set_defaults(func=cmd_evaluate)

    p = parser("ablation", "accuracy of each DLLM feature and pair (SPEC 1.7 ablation)")
    common(p, "ablation")
    p.add_argument("--sets", nargs="+", metavar="SET",
                   help="feature sets, e.g. intensity distance+angle (default: each feature and each pair)")
    p.set_defaults(func=cmd_ablation)
