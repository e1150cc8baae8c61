"""dllm.round_trip: the tolerance of a lossy recording's DLLM reading against the lossless frames'.
A reading equal to the reference is within every rule at 0; an error of a known size sits at its
known fraction of each rule's tolerance (H, l, omega, a flipped event, a flipped taxel); mismatched
readings and a recording without frames after its idle second are refused."""

from __future__ import annotations

import numpy as np
import pytest

from dllm.calibration import calibrate, grey
from dllm.detector import DllmParams
from dllm.round_trip import CODEC_DN, GATE_DN, agreement, replay
from test_detect import _grid_photo


@pytest.fixture(scope="module")
def episode():
    """(calibration, params, frames): 30 idle frames at 12 DN, then 6 with a glow off the centre
    taxel's centre (frames 1-4 brighter and brighter, frame 5 dark again)."""
    cal = calibrate(_grid_photo())
    frames = np.full((36, 350, 350, 3), 12, np.uint8)
    cy, cx = (int(round(v)) for v in cal.centres_px[12][::-1])
    for k, level in zip(range(31, 35), (120, 170, 220, 250)):  # 30 x 30 px: M over alpha D from the first
        frames[k, cy - 8 : cy + 22, cx - 5 : cx + 25] = level
    return cal, DllmParams(), frames


def test_the_reference_itself_is_within_every_rule_at_zero(episode):
    cal, params, frames = episode
    ref = replay(frames, cal, params)
    assert ref.events.tolist() == [False, True, True, True, True, False] and ref.pixels == 350 * 350
    assert ref.gate_m[0] == pytest.approx(params.alpha * 12.0 * 350 * 350)  # alpha D of the idle frames
    r = agreement(ref, ref.events, ref.features, cal)
    assert r["worst"] == {"events": 0.0, "firing": 0.0, "H": 0.0, "l": 0.0, "omega": 0.0}
    assert r["event_frames_agree"] == 6 and r["firing_jaccard"] == 1.0 and r["l_px_max"] == 0.0


def test_errors_of_known_size_sit_at_their_fraction_of_the_tolerance(episode):
    cal, params, frames = episode
    ref = replay(frames, cal, params)
    N, R = np.pi * cal.radius_px**2, cal.radius_px
    t = 2  # an event frame; the centre taxel fires
    H, l, w = ref.features[t, 12]
    assert H > 0 and l > 1.0
    z = ref.features.copy()
    z[t, 12, 0] = H + 0.5 * (CODEC_DN * N + 0.02 * H)
    assert agreement(ref, ref.events, z, cal)["worst"]["H"] == pytest.approx(0.5)
    dl_max = CODEC_DN * N * (R + l) / H
    z = ref.features.copy()
    z[t, 12, 1] = l + 0.25 * dl_max
    assert agreement(ref, ref.events, z, cal)["worst"]["l"] == pytest.approx(0.25)
    z = ref.features.copy()
    assert l > dl_max  # 5.1 px against 0.67: the angle has a tolerance
    z[t, 12, 2] = (w + 2.0 * np.degrees(np.arcsin(dl_max / l))) % 360.0  # twice what the offset's error can turn
    assert agreement(ref, ref.events, z, cal)["worst"]["omega"] == pytest.approx(2.0)
    # frame 1 read as no event: its distance from the global gate, over 0.5 DN per pixel
    ev = ref.events.copy()
    ev[1] = False
    z = ref.features.copy()
    z[1] = 0.0
    M = float(grey(frames[31]).astype(np.float64).sum())
    expected = abs(M - params.alpha * 12.0 * 350 * 350) / (GATE_DN * 350 * 350)
    r = agreement(ref, ev, z, cal)
    assert r["worst"]["events"] == pytest.approx(expected) and r["event_frames_agree"] == 5
    # the centre taxel read as not firing in frame 3: its H against its gate beta B, over 3 DN per disk pixel
    z = ref.features.copy()
    z[3, 12] = 0.0
    flip = abs(ref.taxel_sums[3, 12] - ref.gate_h[3, 12]) / (CODEC_DN * N)
    assert agreement(ref, ref.events, z, cal)["worst"]["firing"] == pytest.approx(flip) and flip > 1.0  # a bright taxel may not vanish


def test_bad_input_is_refused(episode):
    cal, params, frames = episode
    ref = replay(frames, cal, params)
    with pytest.raises(ValueError, match="need the same frames and taxels"):
        agreement(ref, ref.events[:-1], ref.features[:-1], cal)
    with pytest.raises(ValueError, match="codec_dn = 0.*must be > 0"):
        agreement(ref, ref.events, ref.features, cal, codec_dn=0.0)
    with pytest.raises(ValueError, match="none after the 30 idle ones"):
        replay(frames[:30], cal, params)
