"""Interaction classifier (SPEC 1.7): windows, channels, labels, the CNN, training, scores, files, CLI.

The episodes here are a TEST FIXTURE (:func:`synthetic_episodes`), not simulated sensor data: each
class draws a distinct, noisy pattern of DLLM features (l, omega; H follows l) over a class-specific
set of taxels, with person-to-person differences, so a classifier can learn it and a held-out
person can be recognised. They test the machinery, not what accuracy the real sensor gives.
"""

from __future__ import annotations

import argparse
import json
import sys
import types

import numpy as np
import pytest
import torch

from classifiers.interaction_cnn import InteractionCNN, predict_proba, softmax_probabilities
from classifiers.train import (
    ablation,
    classification_metrics,
    evaluate,
    heldout_experiment,
    load_model,
    plot_confusion,
    predict_windows,
    save_model,
    split_people,
    split_validation,
    train,
)
from classifiers.windows import (
    CLASS_NAMES_4,
    CLASS_NAMES_8,
    ClassifierInputError,
    Standardizer,
    channel_names,
    channels,
    cut_windows,
    fit_standardizer,
    robot_command,
    standardize,
    stream_windows,
    to_four_class,
)

# --- the synthetic fixture -------------------------------------------------------------------

_ROW, _COL = np.divmod(np.arange(25), 5)
_X, _Y = _COL - 2.0, 2.0 - _ROW  # taxel positions, pitch units, +y up
_CENTRE = np.hypot(_X, _Y) <= 1.5  # the 9 central taxels


def _wrap(a):
    return np.angle(np.exp(1j * a))  # (-pi, pi]


def synthetic_episodes(people=range(4), per_class=8, T=24, action=(12, 16), seed=0) -> list[dict]:
    """TEST FIXTURE: episodes with a learnable, noisy pattern per class (not sensor physics).

    Per class during the action (progress s in [0, 1], envelope sin(pi s)):
    push / pull / oblique push / oblique pull: the central taxels, offsets pointing along 0, pi,
    pi/4, -3pi/4; sliding left / right: a band of two columns sweeping right to left / left to
    right, offsets along pi/2 / -pi/2; rotation cw / ccw: the outer ring, offsets tangential
    (clockwise / anticlockwise). Each frame drops 20 % of the active taxels; angles carry 0.3 rad
    noise; each person has an amplitude (2.5-4 px) and an angle bias (+-0.25 rad). Frames outside
    the action and inactive taxels are zeros. ``action`` is the (min, max) action length in frames.
    """
    rng = np.random.default_rng(seed)
    episodes = []
    for p in people:
        amp = 2.5 + 1.5 * rng.random()
        bias = rng.uniform(-0.25, 0.25)
        for c in range(8):
            for _ in range(per_class):
                n = int(rng.integers(action[0], action[1] + 1))
                start = int(rng.integers(2, T - n + 1))
                f = np.zeros((T, 25, 3), np.float32)
                fl = np.full(T, -1, np.int64)
                fl[start:start + n] = c
                for k in range(n):
                    s = k / max(n - 1, 1)
                    env = np.sin(np.pi * (0.1 + 0.8 * s))
                    if c < 4:
                        active = _CENTRE.copy()
                        omega = np.full(25, (0.0, np.pi, np.pi / 4, -3 * np.pi / 4)[c])
                    elif c < 6:
                        band = 4.0 * (1 - s) if c == 4 else 4.0 * s
                        active = np.abs(_COL - band) <= 1.0
                        omega = np.full(25, np.pi / 2 if c == 4 else -np.pi / 2)
                    else:
                        active = ~_CENTRE
                        omega = np.arctan2(_Y, _X) + (-np.pi / 2 if c == 6 else np.pi / 2)
                    active &= rng.random(25) > 0.2
                    l = amp * env * (1 + 0.2 * rng.standard_normal(25))
                    w = _wrap(omega + bias + 0.3 * rng.standard_normal(25))
                    H = 300.0 * l * (1 + 0.1 * rng.standard_normal(25)) + 100.0
                    f[start + k, active] = np.stack([H, np.abs(l), w], axis=1)[active]
                episodes.append({"dllm_features": f, "frame_label": fl, "label": c, "person": int(p)})
    return episodes


@pytest.fixture(scope="module")
def episodes():
    return synthetic_episodes()


@pytest.fixture(scope="module")
def experiment(episodes):
    """8-class model trained on three synthetic people, tested on the fourth."""
    return heldout_experiment(episodes, 8, seed=0, held_out=[3], epochs=15, patience=None)


def _episode(T, start, stop, label=0, person=0, value=None):
    f = np.zeros((T, 25, 3), np.float32) if value is None else value
    fl = np.full(T, -1, np.int64)
    fl[start:stop] = label
    return {"dllm_features": f, "frame_label": fl, "label": label, "person": person}


# --- windows and channels --------------------------------------------------------------------


def test_window_counts_and_frames_by_hand():
    T = 20
    f = np.zeros((T, 25, 3), np.float32)
    f[:, :, 1] = np.arange(T, dtype=np.float32)[:, None]  # l = frame index: shows which frames a window holds
    ep = _episode(T, 5, 17, label=3, person=7, value=f)  # action: frames 5..16, 12 frames
    short = _episode(T, 2, 9, label=1, person=4)  # 7 frames: no 8-frame window
    # stride 4: starts 5, 9 (9 + 8 = 17 <= 17), not 13 -> 2 windows ending at 12 and 16
    X, y, person, episode, last = cut_windows([ep, short], length=8, stride=4)
    assert X.shape == (2, 50, 8) and X.dtype == np.float32
    np.testing.assert_array_equal(last, [12, 16])
    np.testing.assert_array_equal(y, [3, 3])
    np.testing.assert_array_equal(person, [7, 7])
    np.testing.assert_array_equal(episode, [0, 0])
    np.testing.assert_array_equal(X[0, 0], np.arange(5, 13))  # channel 0 = l of taxel 0 over frames 5..12
    np.testing.assert_array_equal(X[1, 24], np.arange(9, 17))
    # stride 1: starts 5..9 -> 5 windows; stride 3: starts 5, 8 -> 2; length 12: exactly one
    assert len(cut_windows([ep], stride=1)) == 5
    np.testing.assert_array_equal(cut_windows([ep], stride=3).last_frame, [12, 15])
    np.testing.assert_array_equal(cut_windows([ep], length=12, stride=4).last_frame, [16])
    # the short episode alone: window longer than every action
    with pytest.raises(ValueError, match=r"length = 8: longer than every action span \(the longest has 7 frames"):
        cut_windows([short])


def test_channel_layout():
    n = np.arange(25, dtype=np.float32)
    f = np.stack([1000 + n, 10 + n, 0.01 * n], axis=-1)[None]  # (1, 25, 3)
    c = channels(f)  # default: distance, angle
    assert c.shape == (1, 50)
    np.testing.assert_allclose(c[0, :25], 10 + n)
    np.testing.assert_allclose(c[0, 25:], 0.01 * n)
    c3 = channels(f, ("intensity", "distance", "angle"))
    assert c3.shape == (1, 75)
    np.testing.assert_allclose(c3[0, [0, 24, 25, 49, 50, 74]], [1000, 1024, 10, 34, 0.0, 0.24], rtol=1e-6)
    # the order given is the order of the blocks
    np.testing.assert_allclose(channels(f, ("angle", "intensity"))[0, [0, 25]], [0.0, 1000.0])
    names = channel_names(("distance", "angle"))
    assert names[0] == "l[0]" and names[24] == "l[24]" and names[25] == "omega[0]" and len(names) == 50
    assert channels(f, "intensity,angle").shape == (1, 50)  # comma-separated names


def test_four_class_merge_and_robot_commands():
    np.testing.assert_array_equal(to_four_class(np.arange(8)), [0, 0, 0, 0, 1, 1, 2, 3])
    assert to_four_class(5) == 1
    assert [CLASS_NAMES_4[k] for k in to_four_class(np.arange(8))] == [
        "push_pull", "push_pull", "push_pull", "push_pull", "sliding", "sliding", "rotation_cw", "rotation_ccw"]
    assert [robot_command(k) for k in range(8)] == [
        "toggle_bite"] * 4 + ["forward"] * 2 + ["turn_right", "turn_left"]
    assert [robot_command(k, n_classes=4) for k in range(4)] == ["toggle_bite", "forward", "turn_right", "turn_left"]
    assert robot_command("sliding_left") == "forward" and robot_command("rotation_ccw") == "turn_left"
    with pytest.raises(ValueError, match='"spin" is not an interaction'):
        robot_command("spin")
    with pytest.raises(ValueError, match="0..3 for 4 classes"):
        robot_command(5, n_classes=4)
    with pytest.raises(ValueError, match="0..7"):
        to_four_class([8])


def test_standardizer_function_and_class_agree():
    rng = np.random.default_rng(1)
    X = rng.normal(3.0, 2.0, size=(40, 3, 8)).astype(np.float32)
    X[:, 1] *= 1000.0  # an intensity-like channel
    X[:, 2] = 0.0  # a taxel that never fires
    mean, std = fit_standardizer(X)
    np.testing.assert_allclose(mean[:2], X[:, :2].mean(axis=(0, 2)), rtol=1e-5)
    assert std[2] == 1.0 and mean[2] == 0.0
    s = Standardizer.fit(X)
    Z = s.transform(X)
    np.testing.assert_array_equal(Z, standardize(X, mean, std))
    np.testing.assert_allclose(Z[:, :2].mean(axis=(0, 2)), 0.0, atol=1e-5)
    np.testing.assert_allclose(Z[:, :2].std(axis=(0, 2)), 1.0, rtol=1e-4)
    assert np.all(Z[:, 2] == 0.0)


# --- splits ----------------------------------------------------------------------------------


def test_split_people_holds_out_whole_people():
    rng = np.random.default_rng(0)
    per_episode = np.repeat(np.arange(10), 80)
    tr, te = split_people(per_episode, 0.2, rng)
    assert len(tr) == 8 and len(te) == 2
    assert not set(tr) & set(te) and set(tr) | set(te) == set(range(10))
    tr2, te2 = split_people(per_episode, 0.2, np.random.default_rng(0))
    np.testing.assert_array_equal(te, te2)  # the generator decides
    tr3, te3 = split_people(per_episode, [3, 7])
    np.testing.assert_array_equal(te3, [3, 7])
    assert len(split_people(range(3), 0.2, rng)[1]) == 1  # 0.6 rounds up to 1 person
    with pytest.raises(ValueError, match=r"person\(s\) \[11\] not in the data"):
        split_people(per_episode, [11])
    with pytest.raises(ValueError, match="pass rng"):
        split_people(per_episode, 0.2)


def test_validation_split_is_stratified_by_class():
    labels = np.repeat(np.arange(8), 10)
    mask = split_validation(labels, 0.2, np.random.default_rng(0))
    np.testing.assert_array_equal(np.bincount(labels[mask], minlength=8), [2] * 8)
    assert not split_validation(labels, 0.0).any()


def test_experiment_trains_on_no_test_person(experiment, episodes):
    r = experiment.result
    assert r.train_people == (0, 1, 2) and r.test_people == (3,)
    # validation windows come from the training people's episodes
    tr_eps = [ep for ep in episodes if ep["person"] != 3]
    assert r.n_train_windows + r.n_val_windows == len(cut_windows(tr_eps))
    # 24 episodes per class x 0.2 = 4.8 -> 5 per class: 40 of 192 episodes (about 21 % of the windows)
    assert 0.15 < r.n_val_windows / (r.n_train_windows + r.n_val_windows) < 0.27


# --- the network -----------------------------------------------------------------------------


def test_cnn_shapes_probabilities_and_seeded_init():
    g = torch.Generator().manual_seed(3)
    before = torch.get_rng_state().clone()
    m = InteractionCNN(50, 8, generator=g)
    assert torch.equal(before, torch.get_rng_state())  # the global generator is untouched
    x = torch.randn(5, 50, 8, generator=torch.Generator().manual_seed(0))
    m.eval()
    assert m(x).shape == (5, 8)
    p = predict_proba(m, x.numpy())
    assert p.shape == (5, 8)
    np.testing.assert_allclose(p.sum(axis=1), 1.0, atol=1e-12)
    assert InteractionCNN(75, 4)(torch.zeros(2, 75, 8)).shape == (2, 4)
    m2 = InteractionCNN(50, 8, generator=torch.Generator().manual_seed(3))
    for (k, a), b in zip(m.state_dict().items(), m2.state_dict().values()):
        assert torch.equal(a, b), k
    # layer sequence of SPEC 1.7: conv 32 -> ReLU -> BN -> pool -> conv 128 -> ReLU | dense 64, 32, n
    kinds = [type(l).__name__ for l in m.features] + [type(l).__name__ for l in m.head]
    assert kinds == ["Conv1d", "ReLU", "BatchNorm1d", "MaxPool1d", "Conv1d", "ReLU",
                     "Flatten", "Linear", "ReLU", "Linear", "ReLU", "Linear"]
    assert m.features[0].out_channels == 32 and m.features[4].out_channels == 128 and m.head[1].in_features == 512
    with pytest.raises(ValueError, match=r"should be \(N, 50 channels, 8 frames\)"):
        m(torch.zeros(2, 49, 8))
    np.testing.assert_allclose(softmax_probabilities(np.array([[0.0, np.log(3.0)], [1000.0, 1000.0]])),
                               [[0.25, 0.75], [0.5, 0.5]])


# --- training --------------------------------------------------------------------------------


def test_training_is_deterministic(episodes):
    few = [ep for ep in episodes if ep["person"] == 0]
    kw = dict(epochs=3, patience=None)
    threads, det = torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()
    a, b = train(few, seed=5, **kw), train(few, seed=5, **kw)
    c = train(few, seed=6, **kw)
    assert a.state_dict.keys() == b.state_dict.keys()
    for k in a.state_dict:
        assert torch.equal(a.state_dict[k], b.state_dict[k]), k
    assert a.history == b.history
    assert any(not torch.equal(a.state_dict[k], c.state_dict[k]) for k in a.state_dict if a.state_dict[k].is_floating_point())
    assert (torch.get_num_threads(), torch.are_deterministic_algorithms_enabled()) == (threads, det)  # restored


def test_heldout_person_accuracy_well_above_chance(experiment):
    m = experiment.metrics
    assert m.accuracy > 0.8, m.to_dict()  # chance: 1/8
    assert m.episode_accuracy > 0.8
    assert experiment.result.history["val_accuracy"][experiment.result.best_epoch] == max(experiment.result.history["val_accuracy"])


def test_four_class_model(episodes):
    exp = heldout_experiment(episodes, 4, seed=0, held_out=[3], epochs=15, patience=None)
    assert exp.result.class_names == CLASS_NAMES_4
    assert exp.metrics.confusion.shape == (4, 4)
    assert exp.metrics.accuracy > 0.8  # chance: about 1/2 (half the windows are push_pull)
    test = [ep for ep in episodes if ep["person"] == 3]
    np.testing.assert_array_equal(exp.metrics.support, np.bincount(to_four_class(cut_windows(test).y), minlength=4))


def test_confusion_rows_sum_to_support(experiment, episodes):
    test = [ep for ep in episodes if ep["person"] == 3]
    y = cut_windows(test).y
    m = experiment.metrics
    np.testing.assert_array_equal(m.confusion.sum(axis=1), np.bincount(y, minlength=8))
    np.testing.assert_array_equal(m.support, np.bincount(y, minlength=8))
    assert m.n_windows == len(y)
    assert m.accuracy == pytest.approx(np.trace(m.confusion) / len(y))
    assert m.class_names == CLASS_NAMES_8


def test_precision_recall_by_hand():
    #            true: 0 0 0 1 1 2     confusion (row true, column predicted):
    #       predicted: 0 0 1 1 2 2     [[2 1 0], [0 1 1], [0 0 1]]
    m = classification_metrics([0, 0, 0, 1, 1, 2], [0, 0, 1, 1, 2, 2], 3)
    np.testing.assert_array_equal(m.confusion, [[2, 1, 0], [0, 1, 1], [0, 0, 1]])
    np.testing.assert_allclose(m.precision, [1.0, 0.5, 0.5])
    np.testing.assert_allclose(m.recall, [2 / 3, 0.5, 1.0])
    np.testing.assert_allclose(m.f1, [0.8, 0.5, 2 / 3])
    assert m.accuracy == pytest.approx(4 / 6)
    # a class never predicted and never present: precision, recall, F1 0, not NaN
    m = classification_metrics([0, 1], [0, 0], 3)
    np.testing.assert_allclose(m.precision, [0.5, 0.0, 0.0])
    np.testing.assert_allclose(m.recall, [1.0, 0.0, 0.0])


# --- files and streams -----------------------------------------------------------------------


def test_model_file_round_trip(experiment, episodes, tmp_path):
    path = save_model(experiment.result, tmp_path / "m.pt")
    r = load_model(path)
    assert r.feature_set == ("distance", "angle") and r.n_classes == 8 and r.test_people == (3,)
    np.testing.assert_array_equal(r.standardizer.mean, experiment.result.standardizer.mean)
    test = [ep for ep in episodes if ep["person"] == 3]
    m = evaluate(r, test)
    np.testing.assert_array_equal(m.confusion, experiment.metrics.confusion)


def test_wrong_model_files(tmp_path):
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a model at all")
    with pytest.raises(ValueError, match="not a torch file written by mlsim"):
        load_model(junk)
    other = tmp_path / "other.pt"
    torch.save({"state_dict": {}}, other)
    with pytest.raises(ValueError, match="not an interaction classifier"):
        load_model(other)
    with pytest.raises(ValueError, match="not found"):
        load_model(tmp_path / "missing.pt")


def test_predict_windows_on_a_stream(experiment, episodes):
    ep = next(e for e in episodes if e["person"] == 3 and e["label"] == 6)
    T = len(ep["frame_label"])
    pred = predict_windows(experiment.result, ep["dllm_features"])
    np.testing.assert_array_equal(pred.last_frame, np.arange(7, T))  # one decision per frame from frame 7
    assert pred.probabilities.shape == (T - 7, 8)
    np.testing.assert_allclose(pred.probabilities.sum(axis=1), 1.0, atol=1e-9)
    np.testing.assert_array_equal(pred.classes, pred.probabilities.argmax(axis=1))
    # windows wholly inside the action: mostly rotation_cw -> turn_right
    inside = np.flatnonzero(ep["frame_label"] >= 0)
    ok = (pred.last_frame - 7 >= inside[0]) & (pred.last_frame <= inside[-1])
    assert ok.sum() >= 3 and np.mean(pred.classes[ok] == 6) > 0.5
    assert pred.commands[int(np.flatnonzero(ok)[0])] in ("turn_right", "turn_left", "forward", "toggle_bite")
    # stride 5 from the newest frame back: 23, 18, 13, 8 (a window ending at 3 would start before frame 0)
    assert T == 24
    np.testing.assert_array_equal(predict_windows(experiment.result, ep["dllm_features"], stride=5).last_frame,
                                  [8, 13, 18, 23])
    empty = predict_windows(experiment.result, ep["dllm_features"][:7])
    assert empty.classes.shape == (0,) and empty.probabilities.shape == (0, 8)
    X, last = stream_windows(ep["dllm_features"], stride=1)
    np.testing.assert_array_equal(X[0].T, channels(ep["dllm_features"][:8]))


def test_plot_confusion_writes_png(tmp_path):
    import matplotlib.image as mpimg

    p = plot_confusion(np.array([[5, 1], [0, 4]]), ["a", "b"], tmp_path / "sub" / "c.png")
    assert p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(p)
    assert img.ndim == 3 and img.shape[0] > 100
    with pytest.raises(ValueError, match=r"should be \(3, 3\)"):
        plot_confusion(np.eye(2), ["a", "b", "c"], tmp_path / "x.png")


def test_ablation_table(episodes, tmp_path):
    rows = ablation(episodes, [("intensity",), ("distance", "angle")], seed=0, held_out=[3], out_dir=tmp_path,
                    epochs=8, patience=None)
    assert [r.n_channels for r in rows] == [25, 50]
    # the fixture's directions live in omega: intensity alone tells the three spatial patterns
    # (centre, sweeping band, ring) but not the directions within them (about 0.5 of 8 classes)
    assert rows[0].accuracy_8 < 0.7 and rows[1].accuracy_8 > 0.85
    assert rows[1].accuracy_4 > 0.9
    lines = (tmp_path / "ablation.csv").read_text().splitlines()
    assert lines[0].split(",")[:4] == ["feature_set", "n_channels", "accuracy_8", "accuracy_4"]
    assert lines[2].startswith("distance+angle,50,")
    assert float(lines[2].split(",")[2]) == pytest.approx(rows[1].accuracy_8, abs=1e-4)
    md = (tmp_path / "ablation.md").read_text()
    assert "| distance, angle | 50 |" in md


# --- bad input -------------------------------------------------------------------------------


def test_bad_inputs_name_the_field():
    good = _episode(20, 5, 17)
    nan = _episode(20, 5, 17)
    nan["dllm_features"] = nan["dllm_features"].copy()
    nan["dllm_features"][6, 3, 1] = np.nan
    with pytest.raises(ValueError, match=r"episodes\[1\]\.dllm_features\[6, 3, 1\] = nan: features must be finite"):
        cut_windows([good, nan])
    wrong = dict(good, dllm_features=np.zeros((20, 25, 2), np.float32))
    with pytest.raises(ValueError, match=r"episodes\[0\]\.dllm_features: shape \(20, 25, 2\) should be"):
        cut_windows([wrong])
    with pytest.raises(ValueError, match='"pressure" is not a DLLM feature; choose from: intensity, distance, angle'):
        cut_windows([good], feature_set=("distance", "pressure"))
    with pytest.raises(ValueError, match=r"episodes\[0\]\.frame_label: shape \(19,\) should be \(20,\)"):
        cut_windows([dict(good, frame_label=good["frame_label"][:19])])
    with pytest.raises(ValueError, match="has no 'person'"):
        cut_windows([{k: v for k, v in good.items() if k != "person"}])
    deg = _episode(20, 5, 17)
    deg["dllm_features"] = deg["dllm_features"].copy()
    deg["dllm_features"][8, 0] = (500.0, 3.0, 270.0)  # omega in degrees
    with pytest.raises(ValueError, match=r"\(omega\) reaches 0\.\.270: must be radians"):
        cut_windows([deg])
    with pytest.raises(ClassifierInputError, match="stride = 0"):  # a ValueError the CLI turns into exit code 2
        cut_windows([good], stride=0)
    with pytest.raises(ValueError, match=r"n_classes = 5: must be 8"):
        train([good], n_classes=5)
    with pytest.raises(ValueError, match="features: shape"):
        stream_windows(np.zeros((10, 25)))


# --- command line ----------------------------------------------------------------------------


def test_cli_train_then_evaluate(episodes, tmp_path, monkeypatch, capsys):
    from mlsim.studies import classifier_cli as cli

    reader = types.ModuleType("mlsim.dataset.reader")
    reader.load_episodes = lambda path: episodes
    monkeypatch.setitem(sys.modules, "mlsim.dataset", types.ModuleType("mlsim.dataset"))
    monkeypatch.setitem(sys.modules, "mlsim.dataset.reader", reader)
    data = tmp_path / "data"
    data.mkdir()
    parser = argparse.ArgumentParser(prog="mlsim")
    cli.add_parsers(parser.add_subparsers(dest="command", required=True))

    out = tmp_path / "train"
    args = parser.parse_args(["train", str(data), "--out", str(out), "--classes", "8", "--epochs", "6",
                              "--held-out", "3", "--quiet"])
    assert args.func(args) == 0
    names = sorted(p.name for p in out.iterdir())
    assert names == ["confusion_8class.png", "interaction_8class.pt", "metrics.json", "training_8class.png"]
    metrics = json.loads((out / "metrics.json").read_text())["8class"]
    assert metrics["train"]["test_people"] == [3] and metrics["train"]["n_channels"] == 50
    assert sum(metrics["metrics"]["confusion"][0]) == metrics["metrics"]["per_class"]["push"]["support"]
    assert "8class" in capsys.readouterr().out

    ev = tmp_path / "eval"
    args = parser.parse_args(["evaluate", str(data), "--model", str(out / "interaction_8class.pt"), "--out", str(ev)])
    assert args.func(args) == 0
    again = json.loads((ev / "metrics.json").read_text())
    assert again["people"] == [3]
    assert again["metrics"]["accuracy"] == pytest.approx(metrics["metrics"]["accuracy"])

    args = parser.parse_args(["train", str(data), "--out", str(out), "--features", "distance,force"])
    assert args.func(args) == 2
    assert '"force" is not a DLLM feature' in capsys.readouterr().err
    args = parser.parse_args(["evaluate", str(data), "--model", str(out / "metrics.json"), "--out", str(ev)])
    assert args.func(args) == 2
