"""mlsim.render.reprojection: the transport split into direct paths and bounces, and the direct light
read from the camera's primary rays on the sheet as it is. Checked on a 2 x 2 rod sheet against
the transport tracer: exact splits, agreement within Monte Carlo error, and a bent rod."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("mitsuba")

from mlsim.render import reprojection as rp  # noqa: E402
from mlsim.render.transport import trace_transport  # noqa: E402
from render_helpers import bent as _bent, blocks as _blocks, small_sheet as _sheet  # noqa: E402


def _quadrants(img):
    return _blocks(img, 2)


def test_the_split_adds_up_to_the_full_transport_and_the_direct_part_is_direct():
    """direct + bounces = the full matrix traced with the same seed (the direct paths cancel), the
    bounces carry less light than the direct part (a reflectance-0.5 sheet), and both are >= 0."""
    _, V, _, sheet = _sheet(32)
    D, B = rp.split_transport(sheet, spp=8, seed=4, drop=0.0)
    full = trace_transport(sheet, spp=8, seed=4, drop=0.0)
    e = np.full(len(V), 1e15)
    np.testing.assert_allclose(D.apply(e) + B.apply(e), full.apply(e), rtol=1e-4, atol=1e-6 * full.apply(e).max())
    assert 0.0 < B.apply(e).sum() < D.apply(e).sum()
    assert D.matrix.data.min() >= 0.0 and B.matrix.data.min() > -1e-6 * B.matrix.data.max()
    assert sheet.max_depth > rp.DIRECT_DEPTH  # restored


def test_primary_samples_give_the_direct_transport_on_rest_and_bent_sheets():
    """The direct light from the primary rays (3 x 3 per pixel, deterministic) against the direct
    transport traced at 64 spp on the same sheet: per quadrant (rod) within 3 % at rest and with
    rod 0 bent by 2.5 mm; over 8 x 8 blocks the bend moves the image by more than 2 % of its norm
    (3.5 %), and the samples' image is within 0.3 of that distance of the bent sheet's (0.12)."""
    g, V, F, sheet = _sheet(48)
    rng = np.random.default_rng(0)
    e = 1e15 * (0.5 + rng.random(len(V))) * np.where(g.rod_of(V) == 0, 1.0, 0.2)  # rod 0, the bent one, brightest
    rest_T = rp.split_transport(sheet, spp=64, seed=1)[0].apply(e)
    got_rest = rp.direct_image(rp.primary_samples(sheet, 3), sheet.faces, e)
    np.testing.assert_allclose(_quadrants(got_rest), _quadrants(rest_T), rtol=0.03)
    sheet.set_vertices(_bent(g, V, 2.5e-3))
    bent_T = rp.split_transport(sheet, spp=64, seed=1)[0].apply(e)
    got_bent = rp.direct_image(rp.primary_samples(sheet, 3), sheet.faces, e)
    np.testing.assert_allclose(_quadrants(got_bent), _quadrants(bent_T), rtol=0.03)
    # within the image (8 x 8 blocks) the bend moves the light; the samples follow it, the rest shape does not
    follows = np.linalg.norm(_blocks(got_bent, 8) - _blocks(bent_T, 8))
    rest_off = np.linalg.norm(_blocks(rest_T, 8) - _blocks(bent_T, 8))
    assert rest_off > 0.02 * np.linalg.norm(_blocks(bent_T, 8)) and follows < 0.3 * rest_off, (follows, rest_off)


def test_bad_input_is_refused():
    _, _, _, sheet = _sheet(16)
    with pytest.raises(ValueError, match="per_side"):
        rp.primary_samples(sheet, 0)
