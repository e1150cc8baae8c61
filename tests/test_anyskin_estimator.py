"""The AnySkin estimator (issue 19, SPEC 2): the causal CNN's and the whole estimator's causality, the
chunked pipeline against sample-by-sample, labels from prominence peaks, seeded training, the push
study's drift (bounded with re-baselining, growing without), the face-pitch criteria, and bad input."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from classifiers.anyskin_contact_cnn import ContactCNN, causal_features, causal_padding
from classifiers.anyskin_force_lstm import ForceLSTM, predict_forces
from mlsim.scene import load_scene
from other_sensors.anyskin.estimate import make_estimator, estimate_contacts
from other_sensors.anyskin.labels import contact_runs, event_labels
from other_sensors.anyskin.signals import simulate_helmet
from other_sensors.anyskin.stream import StreamError, check_stream
from other_sensors.anyskin.study import count_above, snr_xy

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "scenes" / "anyskin" / "headon_push.toml"


@pytest.fixture(scope="module")
def sensor():
    return load_scene(SCENE).sensor


def _short(sensor, seconds: float, **drift):
    return sensor.model_copy(update={"trajectory": sensor.trajectory.model_copy(update={"duration_s": seconds}),
                                     "drift": sensor.drift.model_copy(update=drift)})


@pytest.fixture(scope="module")
def run6(sensor):
    """A 6 s run of the shipped scene (drift on, seed 3) and the shipped estimator."""
    s = _short(sensor, 6.0)
    sig = simulate_helmet(s, 3)
    return sig, sig.readings.reshape(len(sig.t), 20, 3), make_estimator(s)


# ------------------------------------------------------------------------------------- the CNN
def _newest_input(n: int, layers) -> np.ndarray:
    """The newest input sample each output position of a stack of causal convolutions sees."""
    newest = np.arange(n)
    for k, stride in layers:
        pad, n_out = causal_padding(len(newest), k, stride)
        idx = np.arange(n_out) * stride + (k - 1) - pad
        newest = np.where(idx >= 0, newest[np.maximum(idx, 0)], -1)  # -1: the position sees only the padding
    return newest


def test_the_cnn_convolutions_are_causal_and_see_the_newest_sample():
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = ContactCNN(50, scale=10.0).eval()
    rng = np.random.default_rng(1)
    x = rng.normal(0, 10, 200)
    base = causal_features(model, x)
    newest = _newest_input(200, [(5, 2), (3, 2)])
    assert base.shape == (16, len(newest)) and newest[-1] == 199  # the stride grid ends on the newest sample
    for t in (37, 100, 150, 198):
        y = x.copy()
        y[t + 1:] += rng.normal(0, 50, 200 - t - 1)
        pert = causal_features(model, y)
        seen = newest <= t
        np.testing.assert_array_equal(pert[:, seen], base[:, seen])  # nothing after t reaches positions that end by t
        z = x.copy()
        z[t] += 50.0
        moved = causal_features(model, z)
        first = np.argmax(newest >= t)
        assert not np.array_equal(moved[:, first], base[:, first])  # the sample t itself does
    # the window's classifier reads the newest slope: changing only g[-1] changes the logits
    g = torch.as_tensor(rng.normal(0, 10, (1, 50)), dtype=torch.float32)
    h = g.clone()
    h[0, -1] += 30.0
    with torch.no_grad():
        assert not torch.equal(model(g), model(h))
    with pytest.raises(ValueError, match="L = 50"):
        model(torch.zeros(2, 49))


def test_the_lstm_force_map_is_causal():
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(0)
        model = ForceLSTM().eval()
    x = np.random.default_rng(2).normal(0, 50, (2, 120, 15))
    y = x.copy()
    y[:, 61:] = 0.0
    a, b = predict_forces(model, x), predict_forces(model, y)
    np.testing.assert_array_equal(a[:, :61], b[:, :61])
    assert not np.allclose(a[:, 61:], b[:, 61:])


# ------------------------------------------------------------------------------- the estimator
def test_the_whole_estimator_is_causal(run6):
    sig, readings, est = run6
    assert est.name == "causal CNN + LSTM-MLP"
    base = est.run(readings, sig.t)
    assert base.track.rebaselines.any()  # the run re-baselines, so the test covers the offsets' feedback
    rng = np.random.default_rng(4)
    commits = np.flatnonzero(base.track.rebaselines.any(axis=1))
    for t in (200, int(commits[0]), int(commits[0]) + 3, 700):
        pert = readings.copy()
        pert[t + 1:] += rng.normal(0, 80.0, pert[t + 1:].shape)
        out = est.run(pert, sig.t)
        for name in ("signal", "slope", "event", "state", "offsets", "rebaselines"):
            np.testing.assert_array_equal(getattr(out.track, name)[: t + 1], getattr(base.track, name)[: t + 1], err_msg=f"{name} at t={t}")
        np.testing.assert_array_equal(out.force[: t + 1], base.force[: t + 1])
        assert not np.allclose(out.force[t + 2:], base.force[t + 2:])


def test_chunked_batches_give_the_sample_by_sample_outputs(run6):
    sig, readings, est = run6
    one = est.run(readings[:450], sig.t[:450], chunk=1)  # the detector called once per sample
    for chunk in (7, 150, 10_000):
        other = est.run(readings[:450], sig.t[:450], chunk=chunk)
        for name in ("event", "state", "rebaselines"):
            np.testing.assert_array_equal(getattr(other.track, name), getattr(one.track, name))
        np.testing.assert_allclose(other.force, one.force, rtol=0, atol=1e-9)


def test_the_shipped_cnn_tracks_the_pushes_of_a_run_it_did_not_train_on(run6):
    sig, readings, est = run6
    out = est.run(readings, sig.t)
    contact = (sig.normal_n > 20.0)[:, :, None].repeat(5, axis=2).reshape(len(sig.t), 20)  # pressed hard
    free = (sig.normal_n == 0)[:, :, None].repeat(5, axis=2).reshape(len(sig.t), 20)
    k0 = out.track.start + 50  # after the first slope window
    centre = np.flatnonzero((sig.normal_n.max(axis=0) > 20.0).repeat(5) & (np.arange(20) % 5 == 0))  # loaded sensors' centre chips
    hard, rest, state = contact[k0:, centre], free[k0:, centre], out.track.state[k0:, centre]
    assert len(centre) >= 2 and state[hard].mean() > 0.9  # in contact while pressed hard
    assert state[rest].mean() < 0.35  # and mostly released while free (a detector that never releases: 1; outer chips, which see
    # less, are worse: see anyskin_train.json)


# ------------------------------------------------------------------------------------- labels
def test_labels_come_from_prominent_peaks_of_the_ground_truth():
    t = np.arange(600)
    f = np.zeros(600)
    f[100:200] = 40 * np.sin(np.pi * (t[100:200] - 100) / 100) ** 2  # a push: prominence 40 N
    f[150] = 25.0  # a dip inside it is no new contact
    f[300:340] = 6.0 * np.sin(np.pi * (t[300:340] - 300) / 40) ** 2  # a touch under the 10 N prominence
    f[450:600] = 30.0  # a push still on at the end: no release
    runs = contact_runs(f)
    above = np.flatnonzero(f[100:200] > 2.0) + 100
    np.testing.assert_array_equal(runs, [[above[0], above[-1] + 1], [450, 600]])
    lab = event_labels(runs, 600, span=15, guard=30, release_delay=15)
    np.testing.assert_array_equal(lab[above[0]:above[0] + 15], 1)
    np.testing.assert_array_equal(lab[above[-1] + 16:above[-1] + 31], 2)
    np.testing.assert_array_equal(lab[above[0] - 30:above[0]], -1)
    assert lab[0] == 0 and lab[170] == -1 or lab[170] == 0
    assert (lab[450:465] == 1).all() and not (lab[465:] == 2).any()


# ----------------------------------------------------------------------------------- training
def test_training_is_seeded_and_reproduces_its_weights(sensor):
    from classifiers.anyskin_train import simulate_training_data, train_contact_cnn, train_force_lstm

    data = simulate_training_data(sensor, seed=5, runs=4, duration_s=4.0)
    assert len(data.slopes) == 4 and data.drift == [True, True, False, False]
    assert {0, 1, 2} <= set(np.unique(np.concatenate([lab.ravel() for lab in data.labels])))
    previous = torch.get_num_threads()
    torch.set_num_threads(1)  # weights reproduce for one thread count
    try:
        a, ma = train_contact_cnn(data, seed=5, epochs=1)
        b, _ = train_contact_cnn(data, seed=5, epochs=1)
        c, _ = train_contact_cnn(data, seed=6, epochs=1)
        la, _ = train_force_lstm(data, seed=5, steps=3, crop=50)
        lb, _ = train_force_lstm(data, seed=5, steps=3, crop=50)
    finally:
        torch.set_num_threads(previous)
    for k, v in a.state_dict().items():
        assert torch.equal(v, b.state_dict()[k])
    assert not torch.equal(a.head.weight, c.head.weight)
    assert ma["scale_ut_s"] > 0 and len(ma["val_recall"]) == 3
    assert all(torch.equal(v, lb.state_dict()[k]) for k, v in la.state_dict().items())


# ------------------------------------------------------------------------------ the push study
def test_without_rebaselining_the_error_grows_and_with_it_stays_bounded(sensor):
    s = _short(sensor, 40.0, set_fraction=0.5)  # 16 push cycles, the set twice the scene's
    sig = simulate_helmet(s, 11)
    est = estimate_contacts(s, sig, 11, make_estimator(s))
    rb, st = est.cycle_mae("rebaselined")[:-1, 2], est.cycle_mae("static")[:-1, 2]  # complete cycles, z
    assert len(rb) == 15
    assert st[-3:].mean() > 2.5 * st[:3].mean()  # static: drifts away over the cycles
    assert rb[-3:].mean() < 1.6 * rb[:3].mean()  # re-baselined: bounded
    assert est.mae("rebaselined", 2) < 0.6 * est.mae("static", 2)
    assert est.rebaselines.sum() > 0 and np.all(np.isfinite(est.rebaselined))


def test_pitch_criteria_on_known_forces():
    rng = np.random.default_rng(0)
    n = 20000
    force = np.zeros((n, 2, 3))
    force[:, 0, :2] = [3.0, -4.0] + rng.normal(0, [1.0, 2.0], (n, 2))  # |m| = 5, trace(Sigma) = 5
    force[:, 1, :2] = rng.normal(0, 1.0, (n, 2))  # no mean: SNR ~ 0
    normal = np.full((n, 2), 60.0)
    normal[: n // 2, 1] = 10.0
    snr = snr_xy(force, normal)
    assert snr[0] == pytest.approx(5.0 / np.sqrt(5.0), rel=0.02) and snr[1] < 0.05
    np.testing.assert_array_equal(count_above(normal), [n, n // 2])
    normal[:, 1] = 1.0  # never in contact: no ratio
    assert np.isnan(snr_xy(force, normal)[1])


# ---------------------------------------------------------------------------------- bad input
def test_bad_streams_are_refused_with_the_field_named(run6):
    sig, readings, est = run6
    with pytest.raises(StreamError, match=r"readings.shape = \(900, 19, 3\)"):
        est.run(readings[:, :19], sig.t)
    t = sig.t.copy()
    t[400] = t[398]
    with pytest.raises(StreamError, match=r"t_s\[400\]"):
        est.run(readings, t)
    with pytest.raises(StreamError, match=r"t_s.shape"):
        est.run(readings, sig.t[:-1])
    bad = readings.copy()
    bad[:150, 7] = np.nan
    with pytest.raises(StreamError, match=r"readings\[:150, 7\]"):
        est.run(bad, sig.t)
    assert isinstance(StreamError([("x", 1, "y")]), ValueError)  # the CLI's bad-input exit (2)


def test_nan_readings_are_flagged_and_held(run6):
    sig, readings, est = run6
    bad = readings.copy()
    bad[300:304, 3, 1] = np.nan
    bad[500, :, :] = np.inf
    held, dropped = check_stream(bad, sig.t, 20, 150)
    np.testing.assert_array_equal(np.flatnonzero(dropped.any(axis=1)), [300, 301, 302, 303, 500])
    assert dropped[300:304, 3].all() and not dropped[300:304, 4].any() and dropped[500].all()
    np.testing.assert_array_equal(held[300:304, 3], np.repeat(readings[299:300, 3], 4, axis=0))  # the last finite reading
    np.testing.assert_array_equal(held[500], readings[499])
    clean, out = est.run(readings, sig.t), est.run(bad, sig.t)
    assert np.isfinite(out.force).all() and out.dropped.sum() == 4 + 20
    np.testing.assert_array_equal(out.force[:300], clean.force[:300])  # nothing changes before the drop (causal)


def test_quiet_spans_test_the_last_r_samples_against_the_baseline_range():
    from other_sensors.anyskin.contact_state import quiet_spans

    rng = np.random.default_rng(7)
    calib = rng.uniform(-1, 1, (150, 2, 3))  # range < 2 on each axis
    med = rng.uniform(-1, 1, (400, 2, 3))
    med[200, 0, 1] = 9.0  # a jump on one axis of channel 0
    q = quiet_spans(med, calib, 75, factor=2.0)
    limit = 2.0 * np.ptp(calib, axis=0)
    ref = np.array([[(k >= 74) and (np.ptp(med[k - 74:k + 1, c], axis=0) <= limit[c]).all() for c in range(2)] for k in range(400)])
    np.testing.assert_array_equal(q, ref)
    assert not q[200:275, 0].any() and q[275, 0] and q[200:275, 1].all()  # quiet again once the jump leaves the span
