"""Training, evaluation, storage and ablation of the interaction classifier (SPEC 1.7).

Protocol
    People, not samples, are held out: :func:`split_people` keeps whole people for the test (10
    people -> 8 train, 2 test by default), so the accuracy says how the classifier does on a person
    it has never seen. Inside the training people, SPEC 1.7's 80/20 train/validation split is made
    over episodes (stratified by class; every window of an episode falls on one side, so
    overlapping windows never straddle the split). The validation set picks the epoch whose weights
    are kept (the best validation accuracy, ties to the lower validation loss) and stops training
    after ``patience`` epochs without improvement.

Optimisation (not given in SPEC 1.7)
    Adam, lr 1e-3, weight decay 1e-4, batches of 64 windows, at most 40 epochs with patience 10;
    cross-entropy on the logits. On a paper-sized set (800 episodes of 45 frames, 8 people trained
    on: about 3,900 windows) an epoch takes about 0.15 s on one CPU thread.

Determinism
    One seed drives everything through explicit generators: ``numpy.random.default_rng((seed, 0))``
    splits people, ``(seed, 1)`` splits validation episodes, and a ``torch.Generator`` seeded with
    ``seed`` draws the initial weights and the batch order. Training runs with
    ``torch.use_deterministic_algorithms(True)`` and ``torch.set_num_threads(n_threads)``, both
    restored afterwards. The thread count is fixed because a CPU reduction split over another
    number of threads may sum in another order: the same seed gives bit-identical weights for the
    same ``n_threads`` and torch build, whatever the machine's core count. The default is ONE
    thread: the net is small (52 k weights, batches of 64 x 8 frames), so intra-op threads cost more
    in synchronisation than they save; on a 2-core machine shared with other jobs, 2 threads
    trained 5-10x slower than 1 (spinning OpenMP workers). No global seed is set.
"""

from __future__ import annotations

import contextlib
import csv
import json
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple, Sequence

import numpy as np
import torch
from torch import nn

from classifiers.interaction_cnn import InteractionCNN, predict_proba
from classifiers.windows import (
    DEFAULT_FEATURE_SET,
    DEFAULT_STRIDE,
    WINDOW_LENGTH,
    ClassifierInputError,
    Standardizer,
    class_names,
    cut_windows,
    feature_set_of,
    robot_command,
    stream_windows,
    to_four_class,
)
from mlsim.plots import save_png

__all__ = [
    "ABLATION_FEATURE_SETS",
    "MODEL_FORMAT",
    "TrainResult",
    "Metrics",
    "Experiment",
    "AblationRow",
    "StreamPrediction",
    "split_people",
    "split_validation",
    "train",
    "classification_metrics",
    "evaluate",
    "heldout_experiment",
    "episodes_of_people",
    "plot_confusion",
    "plot_history",
    "save_model",
    "load_model",
    "ablation",
    "write_ablation",
    "metrics_json",
    "predict_windows",
]

#: The ablation of SPEC 1.7: each DLLM feature alone and each pair.
ABLATION_FEATURE_SETS = (
    ("intensity",),
    ("distance",),
    ("angle",),
    ("intensity", "distance"),
    ("intensity", "angle"),
    ("distance", "angle"),
)
#: Tag of a saved model file (checked on load).
MODEL_FORMAT = "mlsim.interaction_cnn"
_MODEL_VERSION = 1

Log = Callable[[str], None]


def _quiet(msg: str) -> None:
    pass


# --- splits ----------------------------------------------------------------------------------


def split_people(people, held_out=0.2, rng: np.random.Generator | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Split person ids into training and held-out test people.

    Parameters
    ----------
    people : array_like of int
        Person ids (repeats allowed, e.g. one per episode).
    held_out : float in (0, 1) or sequence of int
        The fraction of people to hold out (rounded half up, at least 1, at most all but one), or
        the held-out ids themselves.
    rng : numpy.random.Generator
        Draws the held-out people when ``held_out`` is a fraction.

    Returns
    -------
    train_ids, test_ids : np.ndarray int64, sorted, disjoint
        E.g. 10 people and 0.2 -> 8 and 2.
    """
    ids = np.unique(np.asarray(people, dtype=np.int64))
    if ids.size < 2:
        raise ClassifierInputError(f"people: {ids.size} distinct person(s); holding people out needs at least 2")
    if isinstance(held_out, (float, np.floating)):
        if not 0.0 < held_out < 1.0:
            raise ClassifierInputError(f"held_out = {held_out}: a fraction of people must be in (0, 1), e.g. 0.2")
        if rng is None:
            raise ClassifierInputError("rng: a fraction of people is drawn at random; pass rng=np.random.default_rng(seed)")
        n_test = int(np.clip(np.floor(held_out * ids.size + 0.5), 1, ids.size - 1))
        test = np.sort(rng.choice(ids, size=n_test, replace=False))
    else:
        test = np.unique(np.asarray(list(held_out), dtype=np.int64))
        missing = np.setdiff1d(test, ids)
        if missing.size:
            raise ClassifierInputError(f"held_out: person(s) {missing.tolist()} not in the data (people: {ids.tolist()})")
        if test.size == 0 or test.size == ids.size:
            raise ClassifierInputError(f"held_out = {test.tolist()}: hold out at least one person and keep at least one for training")
    return np.setdiff1d(ids, test), test


def split_validation(labels, fraction: float = 0.2, rng: np.random.Generator | None = None) -> np.ndarray:
    """Validation mask over episodes, stratified by class (SPEC 1.7: 80/20).

    Parameters
    ----------
    labels : array_like of int, shape (E,)
        Class of each training episode.
    fraction : float in [0, 1)
        Share of each class's episodes for validation, rounded half up; a class keeps at least one
        episode for training.
    rng : numpy.random.Generator

    Returns
    -------
    np.ndarray bool, shape (E,)
        True for validation episodes.
    """
    labels = np.asarray(labels)
    if not 0.0 <= fraction < 1.0:
        raise ClassifierInputError(f"val_fraction = {fraction}: must be in [0, 1), SPEC 1.7 uses 0.2")
    mask = np.zeros(labels.shape, dtype=bool)
    if fraction == 0.0:
        return mask
    if rng is None:
        raise ClassifierInputError("rng: the validation episodes are drawn at random; pass rng=np.random.default_rng(seed)")
    for c in np.unique(labels):
        idx = np.flatnonzero(labels == c)
        n_val = int(min(np.floor(fraction * idx.size + 0.5), idx.size - 1))
        if n_val > 0:
            mask[rng.choice(idx, size=n_val, replace=False)] = True
    return mask


# --- results ---------------------------------------------------------------------------------


@dataclass
class TrainResult:
    """A trained classifier and how it was trained.

    Attributes
    ----------
    state_dict : dict of str -> torch.Tensor
        Weights of the selected epoch (:class:`InteractionCNN`).
    model_config : dict
        Arguments of :class:`InteractionCNN` (n_channels, n_classes, window, kernel_size, dense).
    standardizer : Standardizer
        Per-channel statistics of the training windows.
    feature_set : tuple of str
    n_classes : int
    class_names : tuple of str
    window, stride : int
        Frames per window and between training windows.
    history : dict of str -> list of float
        Per epoch: "train_loss", "val_loss", "val_accuracy" (NaN without validation).
    best_epoch : int
        0-based epoch whose weights were kept.
    train_seconds : float
        Wall time of :func:`train` (windowing, fitting, selection).
    seed : int
    train_people, test_people : tuple of int
        People trained on; people held out (empty when :func:`train` was called directly).
    n_train_windows, n_val_windows : int
    """

    state_dict: dict
    model_config: dict
    standardizer: Standardizer
    feature_set: tuple
    n_classes: int
    class_names: tuple
    window: int
    stride: int
    history: dict
    best_epoch: int
    train_seconds: float
    seed: int
    train_people: tuple = ()
    test_people: tuple = ()
    n_train_windows: int = 0
    n_val_windows: int = 0
    _module: InteractionCNN | None = field(default=None, init=False, repr=False, compare=False)

    def module(self) -> InteractionCNN:
        """The network in eval mode (built once, then reused)."""
        if self._module is None:
            m = InteractionCNN(**self.model_config)
            m.load_state_dict(self.state_dict)
            m.eval()
            self._module = m
        return self._module


@dataclass(frozen=True)
class Metrics:
    """Window-level scores on a test set.

    Attributes
    ----------
    accuracy : float
        Correct windows / windows.
    precision, recall, f1, support : np.ndarray, shape (K,)
        Per class; a class never predicted has precision 0 (and never present, recall 0).
    confusion : np.ndarray int64, shape (K, K)
        Counts; row = true class, column = predicted class.
    class_names : tuple of str
    episode_accuracy : float
        Accuracy of whole episodes, each classified by the mean probabilities of its windows (NaN if
        not computed).
    """

    accuracy: float
    precision: np.ndarray
    recall: np.ndarray
    f1: np.ndarray
    support: np.ndarray
    confusion: np.ndarray
    class_names: tuple
    episode_accuracy: float = float("nan")

    @property
    def n_windows(self) -> int:
        return int(self.confusion.sum())

    @property
    def macro_f1(self) -> float:
        return float(np.mean(self.f1))

    def to_dict(self) -> dict:
        return {
            "accuracy": self.accuracy,
            "episode_accuracy": None if np.isnan(self.episode_accuracy) else self.episode_accuracy,
            "macro_f1": self.macro_f1,
            "n_windows": self.n_windows,
            "class_names": list(self.class_names),
            "per_class": {
                name: {
                    "precision": float(self.precision[k]),
                    "recall": float(self.recall[k]),
                    "f1": float(self.f1[k]),
                    "support": int(self.support[k]),
                }
                for k, name in enumerate(self.class_names)
            },
            "confusion": self.confusion.tolist(),
        }


def classification_metrics(y_true, y_pred, n_classes: int, names: Sequence[str] | None = None) -> Metrics:
    """Accuracy, per-class precision / recall / F1 and the confusion matrix.

    Parameters
    ----------
    y_true, y_pred : array_like of int, shape (M,)
        Classes in 0..n_classes-1.
    n_classes : int
    names : sequence of str, optional
        Class names (default "0", "1", ...).

    Returns
    -------
    Metrics
        precision_k = C[k, k] / sum_i C[i, k], recall_k = C[k, k] / sum_j C[k, j],
        F1 = 2 P R / (P + R); a zero denominator gives 0.
    """
    yt = np.asarray(y_true, dtype=np.int64)
    yp = np.asarray(y_pred, dtype=np.int64)
    if yt.shape != yp.shape or yt.ndim != 1:
        raise ClassifierInputError(f"y_true {yt.shape} and y_pred {yp.shape}: must be 1-D and of one length")
    for name, y in (("y_true", yt), ("y_pred", yp)):
        if y.size and (y.min() < 0 or y.max() >= n_classes):
            raise ClassifierInputError(f"{name}: classes {y.min()}..{y.max()} outside 0..{n_classes - 1}")
    C = np.bincount(yt * n_classes + yp, minlength=n_classes * n_classes).reshape(n_classes, n_classes)
    tp = np.diag(C).astype(np.float64)
    predicted = C.sum(axis=0)
    support = C.sum(axis=1)
    precision = np.divide(tp, predicted, out=np.zeros(n_classes), where=predicted > 0)
    recall = np.divide(tp, support, out=np.zeros(n_classes), where=support > 0)
    pr = precision + recall
    f1 = np.divide(2 * precision * recall, pr, out=np.zeros(n_classes), where=pr > 0)
    accuracy = float(tp.sum() / C.sum()) if C.sum() else float("nan")
    names = tuple(names) if names is not None else tuple(str(k) for k in range(n_classes))
    return Metrics(accuracy, precision, recall, f1, support.astype(np.int64), C.astype(np.int64), names)


# --- training --------------------------------------------------------------------------------


@contextlib.contextmanager
def _deterministic_torch(n_threads: int):
    """Fixed thread count and deterministic kernels for the duration, then the caller's settings."""
    if not isinstance(n_threads, (int, np.integer)) or n_threads < 1:
        raise ClassifierInputError(f"n_threads = {n_threads!r}: must be a positive integer, e.g. 2")
    threads = torch.get_num_threads()
    det = torch.are_deterministic_algorithms_enabled()
    warn_only = torch.is_deterministic_algorithms_warn_only_enabled()
    torch.set_num_threads(int(n_threads))
    torch.use_deterministic_algorithms(True)
    try:
        yield
    finally:
        torch.set_num_threads(threads)
        torch.use_deterministic_algorithms(det, warn_only=warn_only)


def _labels(y8: np.ndarray, n_classes: int) -> np.ndarray:
    return y8 if n_classes == 8 else to_four_class(y8)


def _check_seed(seed):
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ClassifierInputError(f"seed = {seed!r}: must be a non-negative integer")


def _positive(name, v, kind=int):
    ok = isinstance(v, (int, np.integer)) if kind is int else isinstance(v, (int, float, np.number))
    if not ok or v <= 0:
        raise ClassifierInputError(f"{name} = {v!r}: must be a positive {'integer' if kind is int else 'number'}")


def train(
    episodes: Sequence[dict],
    n_classes: int = 8,
    feature_set=DEFAULT_FEATURE_SET,
    seed: int = 0,
    epochs: int = 40,
    batch_size: int = 64,
    lr: float = 1e-3,
    weight_decay: float = 1e-4,
    val_fraction: float = 0.2,
    patience: int | None = 10,
    stride: int = DEFAULT_STRIDE,
    length: int = WINDOW_LENGTH,
    n_threads: int = 1,
    log: Log | None = None,
) -> TrainResult:
    """Train an :class:`InteractionCNN` on the windows of ``episodes``.

    Parameters
    ----------
    episodes : sequence of dict
        Training episodes (see :func:`classifiers.windows.cut_windows`); hold test people out
        before calling (:func:`split_people`, or use :func:`heldout_experiment`).
    n_classes : {8, 4}
        8 interactions, or SPEC 1.7's merged four.
    feature_set : tuple of str
        Input channels (default SPEC 1.7's ("distance", "angle"), 50 channels).
    seed : int
        Drives the validation split, the initial weights and the batch order.
    epochs : int
        Upper limit of passes over the training windows.
    batch_size : int
    lr, weight_decay : float
        Adam's learning rate and L2 weight decay.
    val_fraction : float
        Share of each class's episodes kept for validation (0: none; the last epoch is kept).
    patience : int or None
        Stop after this many epochs without a better validation score (None: run all epochs).
    stride, length : int
        Window stride and length in frames.
    n_threads : int
        torch CPU threads while training (restored afterwards).
    log : callable(str), optional
        Receives one line per epoch.

    Returns
    -------
    TrainResult
    """
    log = log or _quiet
    t0 = time.perf_counter()
    names = class_names(n_classes)
    fs = feature_set_of(feature_set)
    _check_seed(seed)
    _positive("epochs", epochs)
    _positive("batch_size", batch_size)
    _positive("lr", lr, float)
    if patience is not None:
        _positive("patience", patience)
    win = cut_windows(episodes, length=length, stride=stride, feature_set=fs)
    ep_labels = np.array([int(ep["label"]) for ep in episodes])
    val_ep = split_validation(ep_labels, val_fraction, np.random.default_rng((seed, 1)))
    is_val = val_ep[win.episode]
    tr, va = win.select(~is_val), win.select(is_val)
    if len(tr) == 0:
        raise ClassifierInputError("episodes: no training windows left after the validation split; lower val_fraction")
    std = Standardizer.fit(tr.X)
    Xtr = torch.from_numpy(std.transform(tr.X))
    ytr = torch.from_numpy(_labels(tr.y, n_classes))
    Xva = torch.from_numpy(std.transform(va.X)) if len(va) else None
    yva = torch.from_numpy(_labels(va.y, n_classes)) if len(va) else None

    history = {"train_loss": [], "val_loss": [], "val_accuracy": []}
    with _deterministic_torch(n_threads):
        gen = torch.Generator().manual_seed(int(seed))
        model = InteractionCNN(Xtr.shape[1], n_classes, window=length, generator=gen)
        opt = torch.optim.Adam(model.parameters(), lr=lr, weight_decay=weight_decay)
        loss_fn = nn.CrossEntropyLoss()
        best, best_state, best_epoch, stale = None, None, 0, 0
        n = len(ytr)
        for epoch in range(epochs):
            model.train()
            perm = torch.randperm(n, generator=gen)
            total = 0.0
            for a in range(0, n, batch_size):
                idx = perm[a:a + batch_size]
                if idx.numel() < 2:  # BatchNorm cannot normalise a batch of one window of one position
                    continue
                opt.zero_grad(set_to_none=True)
                loss = loss_fn(model(Xtr[idx]), ytr[idx])
                loss.backward()
                opt.step()
                total += loss.item() * idx.numel()
            history["train_loss"].append(total / n)
            if Xva is not None:
                model.eval()
                with torch.no_grad():
                    logits = model(Xva)
                    vl = float(loss_fn(logits, yva))
                    vacc = float((logits.argmax(1) == yva).double().mean())
                history["val_loss"].append(vl)
                history["val_accuracy"].append(vacc)
                score = (vacc, -vl)
                if best is None or score > best:
                    best, best_epoch, stale = score, epoch, 0
                    best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
                else:
                    stale += 1
                log(f"epoch {epoch + 1:3d}: train loss {history['train_loss'][-1]:.4f}, val loss {vl:.4f}, val accuracy {vacc:.3f}")
                if patience is not None and stale >= patience:
                    log(f"no better validation score for {patience} epochs: stopped; kept epoch {best_epoch + 1}")
                    break
            else:
                history["val_loss"].append(float("nan"))
                history["val_accuracy"].append(float("nan"))
                log(f"epoch {epoch + 1:3d}: train loss {history['train_loss'][-1]:.4f}")
        if best_state is None:
            best_state = {k: v.detach().clone() for k, v in model.state_dict().items()}
            best_epoch = len(history["train_loss"]) - 1
    return TrainResult(
        state_dict=best_state,
        model_config=dict(model.config),
        standardizer=std,
        feature_set=fs,
        n_classes=n_classes,
        class_names=names,
        window=length,
        stride=stride,
        history=history,
        best_epoch=best_epoch,
        train_seconds=time.perf_counter() - t0,
        seed=int(seed),
        train_people=tuple(int(p) for p in np.unique(win.person)),
        n_train_windows=len(tr),
        n_val_windows=len(va),
    )


# --- evaluation ------------------------------------------------------------------------------


def evaluate(result: TrainResult, episodes: Sequence[dict], stride: int | None = None) -> Metrics:
    """Scores of a trained classifier on the windows of ``episodes``.

    Parameters
    ----------
    result : TrainResult
    episodes : sequence of dict
        Test episodes (held-out people).
    stride : int, optional
        Window stride (default: the training stride).

    Returns
    -------
    Metrics
        Window-level accuracy, per-class precision / recall / F1, confusion counts, and the
        accuracy over whole episodes (mean window probabilities).
    """
    win = cut_windows(episodes, length=result.window, stride=stride or result.stride, feature_set=result.feature_set)
    if win.X.shape[1] != result.standardizer.n_channels:
        raise ClassifierInputError(
            f"episodes: {win.X.shape[1]} channels, the model was trained on {result.standardizer.n_channels}; "
            "the data come from a sensor with another number of taxels"
        )
    probs = predict_proba(result.module(), result.standardizer.transform(win.X))
    y = _labels(win.y, result.n_classes)
    m = classification_metrics(y, probs.argmax(axis=1), result.n_classes, result.class_names)
    # episodes: mean probability over their windows
    eps = np.unique(win.episode)
    sums = np.zeros((eps.size, result.n_classes))
    np.add.at(sums, np.searchsorted(eps, win.episode), probs)
    ep_true = _labels(np.array([int(episodes[e]["label"]) for e in eps]), result.n_classes)
    ep_acc = float(np.mean(sums.argmax(axis=1) == ep_true))
    return Metrics(m.accuracy, m.precision, m.recall, m.f1, m.support, m.confusion, m.class_names, ep_acc)


class Experiment(NamedTuple):
    """A held-out-people experiment: the trained classifier and its scores on the test people."""

    result: TrainResult
    metrics: Metrics
    train_people: np.ndarray
    test_people: np.ndarray


def _people_of(episodes) -> list[int]:
    """Person of each episode; names the first episode without an integer person."""
    people = []
    for i, ep in enumerate(episodes):
        p = ep.get("person") if isinstance(ep, dict) else None
        if not isinstance(p, (int, np.integer)):
            raise ClassifierInputError(f"episodes[{i}].person = {p!r}: each episode needs an integer person id")
        people.append(int(p))
    return people


def episodes_of_people(episodes, people) -> list[dict]:
    """The episodes whose person is one of ``people``, in their order."""
    keep = set(int(p) for p in people)
    return [ep for ep in episodes if int(ep["person"]) in keep]


def heldout_experiment(
    episodes: Sequence[dict],
    n_classes: int = 8,
    feature_set=DEFAULT_FEATURE_SET,
    seed: int = 0,
    held_out=0.2,
    **train_kw,
) -> Experiment:
    """Hold out people (:func:`split_people`, rng ``default_rng((seed, 0))``), train on the rest, test.

    ``train_kw`` go to :func:`train`. Returns an :class:`Experiment`; its result records the people.
    """
    _check_seed(seed)
    train_ids, test_ids = split_people(_people_of(episodes), held_out, np.random.default_rng((seed, 0)))
    result = train(episodes_of_people(episodes, train_ids), n_classes=n_classes, feature_set=feature_set, seed=seed, **train_kw)
    result.test_people = tuple(int(p) for p in test_ids)
    metrics = evaluate(result, episodes_of_people(episodes, test_ids))
    return Experiment(result, metrics, train_ids, test_ids)


# --- plots -----------------------------------------------------------------------------------


def plot_confusion(matrix, class_names: Sequence[str], path, title: str | None = None) -> Path:
    """Write a confusion matrix as PNG: colour = row-normalised share, text = counts.

    Parameters
    ----------
    matrix : array_like of int, shape (K, K)
        Counts; row = true class, column = predicted class.
    class_names : sequence of str, length K
    path : str or Path
        PNG file to write (its directory is created).

    Returns
    -------
    Path
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    C = np.asarray(matrix)
    K = len(class_names)
    if C.shape != (K, K):
        raise ClassifierInputError(f"matrix: shape {C.shape} should be ({K}, {K}) for {K} class names")
    rows = C.sum(axis=1, keepdims=True)
    share = np.divide(C, rows, out=np.zeros(C.shape), where=rows > 0)
    fig, ax = plt.subplots(figsize=(1.0 + 0.8 * K, 0.8 + 0.7 * K))
    im = ax.imshow(share, cmap="Blues", vmin=0.0, vmax=1.0)
    for i in range(K):
        for j in range(K):
            ax.text(j, i, str(int(C[i, j])), ha="center", va="center", fontsize=8,
                    color="white" if share[i, j] > 0.5 else "black")
    ax.set_xticks(range(K), [n.replace("_", " ") for n in class_names], rotation=45, ha="right")
    ax.set_yticks(range(K), [n.replace("_", " ") for n in class_names])
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    if title:
        ax.set_title(title)
    fig.colorbar(im, ax=ax, label="share of the true class")
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_png(fig, path, dpi=120)


def plot_history(history: dict, path, best_epoch: int | None = None, title: str | None = None) -> Path:
    """Write the training curve as PNG: losses (left axis) and validation accuracy (right) per epoch."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ep = np.arange(1, len(history["train_loss"]) + 1)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    ax.plot(ep, history["train_loss"], label="train loss")
    ax.plot(ep, history["val_loss"], label="validation loss")
    ax.set_xlabel("epoch")
    ax.set_ylabel("cross-entropy")
    losses = np.asarray(history["train_loss"] + history["val_loss"], dtype=float)
    if np.all(losses[np.isfinite(losses)] > 0):
        ax.set_yscale("log")  # losses fall by decades once the classes separate
    ax2 = ax.twinx()
    ax2.plot(ep, history["val_accuracy"], color="tab:green", label="validation accuracy")
    ax2.set_ylabel("validation accuracy")
    ax2.set_ylim(0, 1.02)
    if best_epoch is not None:
        ax.axvline(best_epoch + 1, color="grey", ls=":", label="kept")
    lines = ax.get_legend_handles_labels()
    lines2 = ax2.get_legend_handles_labels()
    ax.legend(lines[0] + lines2[0], lines[1] + lines2[1], loc="center right", fontsize=8)
    if title:
        ax.set_title(title)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    return save_png(fig, path, dpi=120)


# --- storage ---------------------------------------------------------------------------------


def save_model(result: TrainResult, path) -> Path:
    """Write a trained classifier to one file (``torch.save`` of a dict of tensors and plain values)."""
    payload = {
        "format": MODEL_FORMAT,
        "version": _MODEL_VERSION,
        "state_dict": {k: v.detach().cpu() for k, v in result.state_dict.items()},
        "model_config": dict(result.model_config),
        "standardizer": {"mean": torch.from_numpy(result.standardizer.mean), "std": torch.from_numpy(result.standardizer.std)},
        "feature_set": list(result.feature_set),
        "n_classes": int(result.n_classes),
        "class_names": list(result.class_names),
        "window": int(result.window),
        "stride": int(result.stride),
        "history": {k: [float(x) for x in v] for k, v in result.history.items()},
        "best_epoch": int(result.best_epoch),
        "train_seconds": float(result.train_seconds),
        "seed": int(result.seed),
        "train_people": [int(p) for p in result.train_people],
        "test_people": [int(p) for p in result.test_people],
        "n_train_windows": int(result.n_train_windows),
        "n_val_windows": int(result.n_val_windows),
    }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(payload, path)
    return path


def load_model(path) -> TrainResult:
    """Read a file written by :func:`save_model`.

    Raises
    ------
    ClassifierInputError (a ValueError)
        If the file is missing, not a torch file, not an interaction classifier, or inconsistent.
    """
    path = Path(path)
    if not path.is_file():
        raise ClassifierInputError(f"model file {path}: not found; train one with 'mlsim train DATASET --out DIR'")
    try:
        # weights_only: a model file holds tensors and plain values; nothing in it is executed
        d = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as exc:  # torch raises several types (UnpicklingError, RuntimeError, EOFError)
        raise ClassifierInputError(
            f"model file {path}: not a torch file written by mlsim ({type(exc).__name__}); give a .pt from 'mlsim train'"
        ) from None
    if not isinstance(d, dict) or d.get("format") != MODEL_FORMAT:
        raise ClassifierInputError(f"model file {path}: not an interaction classifier (format tag should be '{MODEL_FORMAT}'); "
                                   "give a .pt from 'mlsim train'")
    if d.get("version") != _MODEL_VERSION:
        raise ClassifierInputError(f"model file {path}: version {d.get('version')!r}, this mlsim reads {_MODEL_VERSION}; retrain it")
    try:
        fs = feature_set_of(tuple(d["feature_set"]))
        n_classes = int(d["n_classes"])
        names = tuple(d["class_names"])
        if names != class_names(n_classes):
            raise ClassifierInputError(f"class_names {names} do not match n_classes = {n_classes}")
        std = Standardizer(d["standardizer"]["mean"].numpy(), d["standardizer"]["std"].numpy())
        result = TrainResult(
            state_dict=d["state_dict"],
            model_config=dict(d["model_config"]),
            standardizer=std,
            feature_set=fs,
            n_classes=n_classes,
            class_names=names,
            window=int(d["window"]),
            stride=int(d["stride"]),
            history=dict(d["history"]),
            best_epoch=int(d["best_epoch"]),
            train_seconds=float(d["train_seconds"]),
            seed=int(d["seed"]),
            train_people=tuple(d["train_people"]),
            test_people=tuple(d["test_people"]),
            n_train_windows=int(d["n_train_windows"]),
            n_val_windows=int(d["n_val_windows"]),
        )
        if std.n_channels != result.model_config["n_channels"] or result.model_config["n_classes"] != n_classes:
            raise ClassifierInputError("the standardizer, the network and n_classes disagree")
        result.module()  # load_state_dict checks every tensor's name and shape
    except (KeyError, TypeError, AttributeError, RuntimeError, ValueError) as exc:
        raise ClassifierInputError(f"model file {path}: damaged or inconsistent ({exc}); retrain it") from None
    return result


# --- streams ---------------------------------------------------------------------------------


class StreamPrediction(NamedTuple):
    """Classes of the windows of a stream.

    classes : (M,) int64; probabilities : (M, K) float64, rows sum to 1; last_frame : (M,) int64,
    the frame each window ends at; commands : list of M robot commands (SPEC 1.7).
    """

    classes: np.ndarray
    probabilities: np.ndarray
    last_frame: np.ndarray
    commands: list


def predict_windows(result: TrainResult, features: np.ndarray, stride: int = 1) -> StreamPrediction:
    """Classify every window of a DLLM stream (the closed robot loop).

    Parameters
    ----------
    result : TrainResult
    features : np.ndarray, shape (T, N, 3)
        DLLM features (H, l px, omega rad) of consecutive frames.
    stride : int
        Frames between the ends of consecutive windows (1: a decision at every frame from frame
        ``window - 1`` on). The last window ends at frame T-1.

    Returns
    -------
    StreamPrediction
        classes (M,), probabilities (M, n_classes), last_frame (M,), commands; M = 0 while T < window.
    """
    X, last = stream_windows(features, length=result.window, stride=stride, feature_set=result.feature_set)
    if X.shape[1] != result.standardizer.n_channels:
        raise ClassifierInputError(
            f"features: {X.shape[1]} channels, the model was trained on {result.standardizer.n_channels}; "
            f"give (T, {result.standardizer.n_channels // len(result.feature_set)}, 3) features"
        )
    probs = predict_proba(result.module(), result.standardizer.transform(X))
    classes = probs.argmax(axis=1).astype(np.int64)
    return StreamPrediction(classes, probs, last, [robot_command(int(c), result.n_classes) for c in classes])


# --- ablation --------------------------------------------------------------------------------


@dataclass(frozen=True)
class AblationRow:
    """One feature set of the ablation: held-out accuracies of the 8- and 4-class models."""

    feature_set: tuple
    n_channels: int
    accuracy_8: float
    accuracy_4: float
    train_seconds_8: float
    train_seconds_4: float

    @property
    def name(self) -> str:
        return "+".join(self.feature_set)


def ablation(
    episodes: Sequence[dict],
    feature_sets: Sequence[Sequence[str]] = ABLATION_FEATURE_SETS,
    seed: int = 0,
    held_out=0.2,
    out_dir=None,
    log: Log | None = None,
    **train_kw,
) -> list[AblationRow]:
    """Held-out accuracy of each feature set, 8 and 4 classes (SPEC 1.7's ablation).

    Every feature set uses the same held-out people and the same seed, so the rows differ only by
    their input channels. ``train_kw`` go to :func:`train`. With ``out_dir``, writes
    ``ablation.csv`` and ``ablation.md`` there (:func:`write_ablation`).

    Returns
    -------
    list of AblationRow
    """
    log = log or _quiet
    sets = [feature_set_of(fs) for fs in feature_sets]
    if not sets:
        raise ClassifierInputError("feature_sets: empty; give at least one feature set")
    _check_seed(seed)
    train_ids, test_ids = split_people(_people_of(episodes), held_out, np.random.default_rng((seed, 0)))
    log(f"people: train {train_ids.tolist()}, test {test_ids.tolist()}")
    rows = []
    for fs in sets:
        accs, secs = {}, {}
        for k in (8, 4):
            exp = heldout_experiment(episodes, k, fs, seed, held_out=test_ids.tolist(), **train_kw)
            accs[k], secs[k] = exp.metrics.accuracy, exp.result.train_seconds
            n_ch = exp.result.standardizer.n_channels
        rows.append(AblationRow(fs, n_ch, accs[8], accs[4], secs[8], secs[4]))
        log(f"{rows[-1].name}: {n_ch} channels, accuracy {accs[8]:.3f} (8 classes), {accs[4]:.3f} (4 classes)")
    if out_dir is not None:
        write_ablation(rows, out_dir)
    return rows


def write_ablation(rows: Sequence[AblationRow], out_dir) -> tuple[Path, Path]:
    """Write ``ablation.csv`` and ``ablation.md`` (a markdown table) to ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    header = ["feature_set", "n_channels", "accuracy_8", "accuracy_4", "train_seconds_8", "train_seconds_4"]
    csv_path = out / "ablation.csv"
    with csv_path.open("w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(header)
        for r in rows:
            w.writerow([r.name, r.n_channels, f"{r.accuracy_8:.4f}", f"{r.accuracy_4:.4f}",
                        f"{r.train_seconds_8:.2f}", f"{r.train_seconds_4:.2f}"])
    md = ["| feature set | channels | accuracy, 8 classes | accuracy, 4 classes | train s (8 / 4) |",
          "|---|---:|---:|---:|---:|"]
    for r in rows:
        md.append(f"| {', '.join(r.feature_set)} | {r.n_channels} | {100 * r.accuracy_8:.2f} % | {100 * r.accuracy_4:.2f} % "
                  f"| {r.train_seconds_8:.1f} / {r.train_seconds_4:.1f} |")
    md.append("")
    md.append("Held-out people; SPEC 1.7 reference on real data with distance + angle: 92.68 % (8 classes), 97.37 % (4 classes).")
    md_path = out / "ablation.md"
    md_path.write_text("\n".join(md) + "\n")
    return csv_path, md_path


def metrics_json(experiments: dict, path) -> Path:
    """Write {name: {"metrics": ..., "train": ...}} of several experiments as JSON."""
    out = {}
    for name, exp in experiments.items():
        r = exp.result
        out[name] = {
            "metrics": exp.metrics.to_dict(),
            "train": {
                "feature_set": list(r.feature_set),
                "n_channels": r.standardizer.n_channels,
                "seed": r.seed,
                "train_people": list(r.train_people),
                "test_people": list(r.test_people),
                "n_train_windows": r.n_train_windows,
                "n_val_windows": r.n_val_windows,
                "epochs_run": len(r.history["train_loss"]),
                "best_epoch": r.best_epoch + 1,
                "train_seconds": r.train_seconds,
            },
        }
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(out, indent=2) + "\n")
    return path
