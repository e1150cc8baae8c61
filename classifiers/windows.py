"""Classes, input channels and 8-frame windows of the interaction classifier (SPEC 1.7).

The classifier reads the DLLM time series (SPEC 1.6): per frame t and taxel n the features
Z_n(t) = (H_n, l_n, omega_n) -- H the summed intensity in the taxel's disk (linear camera units),
l the centroid offset length (px), omega its angle (rad, in (-pi, pi]). Taxels under threshold and
frames without an event are (0, 0, 0).

Channel layout
    ``channels(features, feature_set)`` puts the features side by side in the order of
    ``feature_set``, 25 taxels (row-major, as the DLLM sorts them) per feature: column
    ``k * N + n`` is feature ``feature_set[k]`` of taxel ``n``. SPEC 1.7's input is
    ``("distance", "angle")``: 50 channels, columns 0-24 l, columns 25-49 omega.

Angle
    omega is kept as given (radians, one channel per taxel), which matches the 50 channels of the
    paper and keeps 25 channels per feature so the ablation compares like with like. Its wrap at
    +-pi splits pushes whose offset points along -x image axis between two ends of the channel, and
    an idle taxel's omega = 0 reads like an offset along +x; both are left to the network: the
    distance channel tells an idle taxel (l = 0) from a firing one, and the per-channel
    standardisation treats omega like any other channel. (A (cos, sin) encoding would remove the
    wrap but give 50 channels for the angle alone and change the paper's input.)

Windows
    ``cut_windows`` cuts windows of ``length`` (8, SPEC 1.7) consecutive frames that lie wholly
    inside an action span (a run of frames with the same label >= 0), starting at the span's first
    frame and every ``stride`` frames after it. The default stride 4 (half a window) is not given in
    SPEC 1.7: it gives about six windows per 30-frame action, so each frame is seen twice and
    neighbouring windows are not near-copies of each other.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from mlsim.interactions import ACTION_TO_4, ACTIONS, ACTIONS_4

__all__ = [
    "CLASS_NAMES_8",
    "CLASS_NAMES_4",
    "MERGE_8_TO_4",
    "ROBOT_COMMANDS",
    "FEATURE_NAMES",
    "DEFAULT_FEATURE_SET",
    "WINDOW_LENGTH",
    "DEFAULT_STRIDE",
    "N_TAXELS",
    "ClassifierInputError",
    "check_features",
    "class_names",
    "to_four_class",
    "robot_command",
    "feature_set_of",
    "channels",
    "channel_names",
    "fit_standardizer",
    "standardize",
    "Standardizer",
    "Windows",
    "action_spans",
    "window_starts",
    "cut_windows",
    "stream_windows",
]

#: The eight interactions of SPEC 1.5 in class-id order, and the four-class version of SPEC 1.7
#: (defined with the interactions themselves, mlsim.interactions).
CLASS_NAMES_8 = ACTIONS
CLASS_NAMES_4 = ACTIONS_4
#: 8-class id -> 4-class id (index with the 8-class id).
MERGE_8_TO_4 = np.array([ACTION_TO_4[a] for a in ACTIONS], dtype=np.int64)
#: 4-class name -> robot command (SPEC 1.7: Push/Pull toggles bite/release).
ROBOT_COMMANDS = {
    "push_pull": "toggle_bite",
    "sliding": "forward",
    "rotation_cw": "turn_right",
    "rotation_ccw": "turn_left",
}

#: DLLM feature name -> column of Z_n = (H, l, omega).
FEATURE_NAMES = {"intensity": 0, "distance": 1, "angle": 2}
#: SPEC 1.7's input: (l_n, omega_n) for the 25 taxels = 50 channels.
DEFAULT_FEATURE_SET = ("distance", "angle")
#: Frames per window (SPEC 1.7).
WINDOW_LENGTH = 8
#: Frames between window starts (not given in SPEC 1.7; see the module docstring).
DEFAULT_STRIDE = 4
#: Taxels of the MAVIG (5 x 5 rods).
N_TAXELS = 25

_SHORT = {"intensity": "H", "distance": "l", "angle": "omega"}
# omega is atan2's output: (-pi, pi]; the slack lets a float32 round-trip of pi through
_ANGLE_SLACK = 1e-4


class ClassifierInputError(ValueError):
    """Input the classifier cannot use; the message names the field and how to fix it."""


def class_names(n_classes: int) -> tuple[str, ...]:
    """The class names of the 8- or 4-class problem."""
    if n_classes == 8:
        return CLASS_NAMES_8
    if n_classes == 4:
        return CLASS_NAMES_4
    raise ClassifierInputError(f"n_classes = {n_classes!r}: must be 8 (the interactions) or 4 (merged, SPEC 1.7)")


def to_four_class(ids) -> np.ndarray:
    """Map 8-class ids to 4-class ids.

    Parameters
    ----------
    ids : int or array_like of int, any shape
        8-class ids in 0..7.

    Returns
    -------
    np.ndarray of int64, same shape
        push, pull, oblique push, oblique pull -> 0 (push_pull); sliding left/right -> 1 (sliding);
        rotation cw -> 2; rotation ccw -> 3.
    """
    a = np.asarray(ids)
    if a.size and (not np.issubdtype(a.dtype, np.integer) or a.min() < 0 or a.max() > 7):
        raise ClassifierInputError(f"ids = {a!r}: 8-class ids must be integers in 0..7")
    return MERGE_8_TO_4[a.astype(np.int64)]


def robot_command(cls, n_classes: int = 8) -> str:
    """The robot command of a class (SPEC 1.7).

    Parameters
    ----------
    cls : int or str
        A class id of the ``n_classes`` problem, or a class name of either problem.
    n_classes : {8, 4}
        How to read an integer ``cls``.

    Returns
    -------
    str
        "forward", "turn_right", "turn_left" or "toggle_bite".
    """
    if isinstance(cls, str):
        if cls in CLASS_NAMES_8:
            cls4 = CLASS_NAMES_4[int(MERGE_8_TO_4[CLASS_NAMES_8.index(cls)])]
        elif cls in CLASS_NAMES_4:
            cls4 = cls
        else:
            raise ClassifierInputError(
                f'class "{cls}" is not an interaction; choose one of: {", ".join(CLASS_NAMES_8 + CLASS_NAMES_4[:2])}'
            )
        return ROBOT_COMMANDS[cls4]
    names = class_names(n_classes)
    if not isinstance(cls, (int, np.integer)) or not 0 <= int(cls) < n_classes:
        raise ClassifierInputError(f"class id = {cls!r}: must be an integer in 0..{n_classes - 1} for {n_classes} classes")
    return robot_command(names[int(cls)])


def feature_set_of(feature_set) -> tuple[str, ...]:
    """Validate a feature set: a non-empty tuple of distinct names of :data:`FEATURE_NAMES`.

    A comma-separated string ("distance,angle") is accepted too.
    """
    if isinstance(feature_set, str):
        feature_set = tuple(s.strip() for s in feature_set.split(",") if s.strip())
    try:
        fs = tuple(feature_set)
    except TypeError:
        raise ClassifierInputError(f"feature_set = {feature_set!r}: must be a tuple of names, e.g. ('distance', 'angle')") from None
    if not fs:
        raise ClassifierInputError("feature_set = (): name at least one of: " + ", ".join(FEATURE_NAMES))
    for name in fs:
        if name not in FEATURE_NAMES:
            raise ClassifierInputError(f'feature_set: "{name}" is not a DLLM feature; choose from: {", ".join(FEATURE_NAMES)}')
    if len(set(fs)) != len(fs):
        raise ClassifierInputError(f"feature_set = {fs!r}: a feature is named twice; name each once")
    return fs


def channels(features: np.ndarray, feature_set=DEFAULT_FEATURE_SET) -> np.ndarray:
    """Classifier input channels of DLLM features.

    Parameters
    ----------
    features : np.ndarray, shape (..., N, 3)
        DLLM features (H, l px, omega rad) of N taxels (N = 25 on the MAVIG).
    feature_set : tuple of str
        Names from {"intensity", "distance", "angle"}, in the order wanted.

    Returns
    -------
    np.ndarray of float32, shape (..., len(feature_set) * N)
        Column ``k * N + n`` is feature ``feature_set[k]`` of taxel ``n``.
    """
    fs = feature_set_of(feature_set)
    f = np.asarray(features)
    if f.ndim < 2 or f.shape[-1] != 3:
        raise ClassifierInputError(f"features: shape {f.shape} should be (..., N taxels, 3) with (H, l, omega) last")
    cols = [f[..., FEATURE_NAMES[name]] for name in fs]
    return np.concatenate(cols, axis=-1).astype(np.float32, copy=False)


def channel_names(feature_set=DEFAULT_FEATURE_SET, n_taxels: int = N_TAXELS) -> list[str]:
    """Names of the columns of :func:`channels`, e.g. ``["l[0]", ..., "omega[24]"]``."""
    return [f"{_SHORT[name]}[{n}]" for name in feature_set_of(feature_set) for n in range(n_taxels)]


# --- standardisation -------------------------------------------------------------------------


def fit_standardizer(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-channel mean and standard deviation of windows.

    Parameters
    ----------
    X : np.ndarray, shape (N, C, L)
        Training windows.

    Returns
    -------
    mean, std : np.ndarray of float32, shape (C,)
        Over windows and frames. A channel that never varies (a taxel that never fires) gets
        std = 1, so it stays 0 after standardisation instead of dividing by zero.
    """
    X = np.asarray(X, dtype=np.float64)
    if X.ndim != 3 or X.shape[0] == 0:
        raise ClassifierInputError(f"X: shape {X.shape} should be (N windows >= 1, C channels, L frames)")
    mean = X.mean(axis=(0, 2))
    std = X.std(axis=(0, 2))
    # relative floor: float32 sums of a constant channel leave a std of ~1e-7 * |mean|
    std = np.where(std > 1e-6 * np.maximum(1.0, np.abs(mean)), std, 1.0)
    return mean.astype(np.float32), std.astype(np.float32)


def standardize(X: np.ndarray, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(X - mean) / std per channel: X (N, C, L) or (C, L); mean, std (C,). Returns float32."""
    X = np.asarray(X, dtype=np.float32)
    if X.ndim < 2 or X.shape[-2] != len(mean):
        raise ClassifierInputError(f"X: shape {X.shape} should have {len(mean)} channels on axis -2 (the fitted standardizer's)")
    return ((X - mean[:, None]) / std[:, None]).astype(np.float32, copy=False)


@dataclass(frozen=True)
class Standardizer:
    """Per-channel standardisation fitted on training windows (wraps :func:`fit_standardizer`).

    Attributes
    ----------
    mean, std : np.ndarray of float32, shape (C,)
    """

    mean: np.ndarray
    std: np.ndarray

    @classmethod
    def fit(cls, X: np.ndarray) -> "Standardizer":
        """Fit on windows X (N, C, L)."""
        return cls(*fit_standardizer(X))

    def transform(self, X: np.ndarray) -> np.ndarray:
        """Standardise X (N, C, L) or (C, L) -> float32 of the same shape."""
        return standardize(X, self.mean, self.std)

    @property
    def n_channels(self) -> int:
        return len(self.mean)


# --- windows ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Windows:
    """Windows cut from episodes.

    Attributes
    ----------
    X : np.ndarray float32, shape (M, C, L)
        Channels (:func:`channels`) over the window's frames.
    y : np.ndarray int64, shape (M,)
        8-class label of the window.
    person : np.ndarray int64, shape (M,)
        Person of the window's episode.
    episode : np.ndarray int64, shape (M,)
        Index of the window's episode in the list given.
    last_frame : np.ndarray int64, shape (M,)
        Frame index (in its episode) of the window's last frame.
    """

    X: np.ndarray
    y: np.ndarray
    person: np.ndarray
    episode: np.ndarray
    last_frame: np.ndarray

    def __len__(self) -> int:
        return len(self.y)

    def __iter__(self):  # X, y, person, episode, last_frame = cut_windows(...)
        return iter((self.X, self.y, self.person, self.episode, self.last_frame))

    def select(self, mask: np.ndarray) -> "Windows":
        """The windows where the boolean (M,) mask holds."""
        return Windows(self.X[mask], self.y[mask], self.person[mask], self.episode[mask], self.last_frame[mask])


def action_spans(frame_label: np.ndarray) -> list[tuple[int, int, int]]:
    """Runs of equal labels >= 0: a list of (start, stop, label) with frames start..stop-1."""
    fl = np.asarray(frame_label)
    if fl.size == 0:
        return []
    change = np.flatnonzero(np.diff(fl)) + 1
    starts = np.concatenate(([0], change))
    stops = np.concatenate((change, [fl.size]))
    return [(int(a), int(b), int(fl[a])) for a, b in zip(starts, stops) if fl[a] >= 0]


def window_starts(start: int, stop: int, length: int, stride: int) -> np.ndarray:
    """First frames of the windows of ``length`` frames inside frames start..stop-1, ``stride`` apart.

    The first window starts at ``start``; there are max(0, (stop - start - length) // stride + 1).
    """
    if stop - start < length:
        return np.zeros(0, dtype=np.int64)
    return np.arange(start, stop - length + 1, stride, dtype=np.int64)


def _check_length_stride(length, stride):
    if not isinstance(length, (int, np.integer)) or length < 1:
        raise ClassifierInputError(f"length = {length!r}: must be a positive number of frames (SPEC 1.7: 8)")
    if not isinstance(stride, (int, np.integer)) or stride < 1:
        raise ClassifierInputError(f"stride = {stride!r}: must be a positive number of frames, e.g. {DEFAULT_STRIDE}")


def check_features(f, where: str) -> np.ndarray:
    """Validate DLLM features (T, N, 3): finite, l >= 0, omega in radians (-pi, pi]. Returns the array."""
    f = np.asarray(f)
    if f.ndim != 3 or f.shape[-1] != 3:
        raise ClassifierInputError(f"{where}: shape {f.shape} should be (T frames, N taxels = {N_TAXELS}, 3) with (H, l, omega) last")
    if not np.issubdtype(f.dtype, np.floating) and not np.issubdtype(f.dtype, np.integer):
        raise ClassifierInputError(f"{where}: dtype {f.dtype} should be float32")
    if not np.isfinite(f).all():
        t, n, k = np.argwhere(~np.isfinite(f))[0]
        raise ClassifierInputError(
            f"{where}[{t}, {n}, {k}] = {f[t, n, k]}: features must be finite; "
            "non-firing taxels and frames without an event are zeros (SPEC 1.6)"
        )
    if f.size and f[..., 1].min() < 0:
        raise ClassifierInputError(f"{where}[..., 1] (l) has {f[..., 1].min():g}: the offset length must be >= 0 px")
    if f.size and np.abs(f[..., 2]).max() > np.pi + _ANGLE_SLACK:
        raise ClassifierInputError(
            f"{where}[..., 2] (omega) reaches {f[..., 2].min():g}..{f[..., 2].max():g}: must be radians in (-pi, pi]; "
            "wrap radians with np.angle(np.exp(1j * omega)), after np.deg2rad if the DLLM gave degrees"
        )
    return f


def _check_episode(i: int, ep, n_classes: int = 8):
    if not isinstance(ep, dict):
        raise ClassifierInputError(f"episodes[{i}]: a {type(ep).__name__}; each episode must be a dict with "
                                   "dllm_features, frame_label, label, person")
    for key in ("dllm_features", "frame_label", "label", "person"):
        if key not in ep:
            raise ClassifierInputError(f"episodes[{i}] has no '{key}': each episode needs dllm_features, frame_label, label, person")
    f = check_features(ep["dllm_features"], f"episodes[{i}].dllm_features")
    fl = np.asarray(ep["frame_label"])
    if fl.shape != (f.shape[0],):
        raise ClassifierInputError(f"episodes[{i}].frame_label: shape {fl.shape} should be ({f.shape[0]},), one label per frame")
    if fl.size and not np.issubdtype(fl.dtype, np.integer):
        raise ClassifierInputError(f"episodes[{i}].frame_label: dtype {fl.dtype} should be int64 (class id, -1 outside the action)")
    label = ep["label"]
    if not isinstance(label, (int, np.integer)) or not 0 <= int(label) < n_classes:
        raise ClassifierInputError(f"episodes[{i}].label = {label!r}: must be a class id in 0..{n_classes - 1}")
    bad = fl[(fl != -1) & (fl != label)]
    if bad.size:
        raise ClassifierInputError(
            f"episodes[{i}].frame_label has {int(bad[0])}: frames are the episode's label {int(label)} inside the action, -1 outside"
        )
    if not isinstance(ep["person"], (int, np.integer)):
        raise ClassifierInputError(f"episodes[{i}].person = {ep['person']!r}: must be an integer person id")
    return f, fl


def cut_windows(
    episodes: Sequence[dict],
    length: int = WINDOW_LENGTH,
    stride: int = DEFAULT_STRIDE,
    feature_set=DEFAULT_FEATURE_SET,
) -> Windows:
    """Windows of ``length`` consecutive frames wholly inside each episode's action span.

    Parameters
    ----------
    episodes : sequence of dict
        Each with "dllm_features" (T, N, 3) float (H, l px, omega rad), "frame_label" (T,) int
        (the class inside the action, -1 outside), "label" int 0..7, "person" int.
    length : int
        Frames per window (SPEC 1.7: 8).
    stride : int
        Frames between the starts of consecutive windows of one span (default 4).
    feature_set : tuple of str
        Channels, see :func:`channels`.

    Returns
    -------
    Windows
        X (M, C, length) float32, y (M,), person (M,), episode (M,), last_frame (M,); unpacks as
        ``X, y, person, episode, last_frame = cut_windows(...)``.

    Raises
    ------
    ClassifierInputError (a ValueError)
        Naming the episode and field: missing keys, wrong shapes, non-finite features, omega not in
        radians, labels out of range, an unknown feature name, or a window longer than every action.
    """
    fs = feature_set_of(feature_set)
    _check_length_stride(length, stride)
    if len(episodes) == 0:
        raise ClassifierInputError("episodes: empty; give at least one episode")
    Xs, ys, ps, es, lasts = [], [], [], [], []
    n_taxels, longest = None, 0
    for i, ep in enumerate(episodes):
        f, fl = _check_episode(i, ep)
        if n_taxels is None:
            n_taxels = f.shape[1]
        elif f.shape[1] != n_taxels:
            raise ClassifierInputError(f"episodes[{i}].dllm_features: {f.shape[1]} taxels, but episodes[0] has {n_taxels}; "
                                       "all episodes must come from one sensor")
        ch = channels(f, fs)  # (T, C)
        for a, b, lab in action_spans(fl):
            longest = max(longest, b - a)
            starts = window_starts(a, b, length, stride)
            if starts.size == 0:
                continue
            idx = starts[:, None] + np.arange(length)[None, :]  # (w, L)
            Xs.append(np.transpose(ch[idx], (0, 2, 1)))  # (w, C, L)
            ys.append(np.full(starts.size, lab, dtype=np.int64))
            ps.append(np.full(starts.size, int(ep["person"]), dtype=np.int64))
            es.append(np.full(starts.size, i, dtype=np.int64))
            lasts.append(starts + length - 1)
    if not Xs:
        raise ClassifierInputError(
            f"length = {length}: longer than every action span (the longest has {longest} frames with frame_label >= 0); "
            "use a shorter window or episodes with longer actions"
        )
    return Windows(
        np.ascontiguousarray(np.concatenate(Xs), dtype=np.float32),
        np.concatenate(ys),
        np.concatenate(ps),
        np.concatenate(es),
        np.concatenate(lasts),
    )


def stream_windows(
    features: np.ndarray, length: int = WINDOW_LENGTH, stride: int = 1, feature_set=DEFAULT_FEATURE_SET
) -> tuple[np.ndarray, np.ndarray]:
    """Windows of a stream, ignoring labels: the last one ends at the last frame.

    Parameters
    ----------
    features : np.ndarray, shape (T, N, 3)
        DLLM features of consecutive frames.
    length, stride : int
        Frames per window; frames between the ends of consecutive windows.

    Returns
    -------
    X : np.ndarray float32, shape (M, C, length)
    last_frame : np.ndarray int64, shape (M,)
        Windows end at frames T-1, T-1-stride, ... down to >= length - 1, in increasing order.
        M = 0 when T < length (too few frames yet).
    """
    _check_length_stride(length, stride)
    f = check_features(features, "features")
    ch = channels(f, feature_set)  # (T, C)
    T = f.shape[0]
    if T < length:
        return np.zeros((0, ch.shape[1], length), np.float32), np.zeros(0, np.int64)
    # anchored at the end: the newest frame is always classified
    last = np.arange(T - 1, length - 2, -stride, dtype=np.int64)[::-1].copy()
    idx = last[:, None] - (length - 1) + np.arange(length)[None, :]
    return np.ascontiguousarray(np.transpose(ch[idx], (0, 2, 1))), last
