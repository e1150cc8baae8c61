"""The AnySkin helmet's richer world (issue 43, SPEC 2): the rectangular prism's closed form against
the quadrature and the point dipole far away, the magnet-volume skin (its table against the direct sum,
a uniformly pressed skin against the thinner prism, its far field against the dipole of its moment),
the chips' read-out (noise statistics, the sensitivity matrix, quantisation), the calibration bench's
forces, and bad input refused with its field named."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import stats

from mlsim.errors import SceneError
from other_sensors.anyskin.bench import PEAK_MIN_N, TANGENT_RATIO, bench_forces, simulate_bench
from other_sensors.anyskin.dipoles import MU0, dipole_field
from other_sensors.anyskin.magnet_volume import body_field, slab_body
from other_sensors.anyskin.magnetometer import chip_errors, read_chips
from other_sensors.anyskin.prism_field import prism_field
from other_sensors.anyskin.schema import AnySkinSensor
from other_sensors.anyskin.signals import simulate_helmet
from other_sensors.anyskin.skin_volume import column_fields, column_strains, volume_field, volume_skin
from other_sensors.anyskin.truth import skin_fields, truth_model

SIDE, THICK, GAP, M = 0.028, 0.0025, 0.001, 2.0e4
LO, HI = [-SIDE / 2, -SIDE / 2, GAP], [SIDE / 2, SIDE / 2, GAP + THICK]
CHIPS = np.array([[0, 0, 0], [0.009, 0, 0], [-0.009, 0, 0], [0, 0.009, 0], [0, -0.009, 0]], dtype=float)


# ------------------------------------------------------------------------------ the prism's closed form
def test_the_prism_closed_form_is_the_quadratures_limit_and_the_on_axis_formula():
    points = np.array([[0.0, 0.0, 0.0], [0.009, 0.0, 0.0], [0.02, 0.013, -0.004], [0.003, 0.002, 0.006]])
    for m in ((0.0, 0.0, M), (1e4, -5e3, 3e3)):  # along the thickness, and oblique (the permuted faces)
        exact = prism_field(points, LO, HI, m)
        fine = body_field(slab_body(SIDE, SIDE, THICK, GAP, (56, 56, 2), m), points)
        np.testing.assert_allclose(fine, exact, rtol=0, atol=5e-5 * np.abs(exact).max())
    # on the axis of a z-magnetised a x b x t cuboid: B_z = mu0 M / pi [atan(ab / (2 z sqrt(4 z^2 + a^2 + b^2)))]_{z=d+t}^{z=d}
    a, b = SIDE, 0.8 * SIDE
    term = lambda z: np.arctan(a * b / (2 * z * np.sqrt(4 * z * z + a * a + b * b)))  # noqa: E731
    bz = prism_field([[0.0, 0.0, 0.0]], [-a / 2, -b / 2, GAP], [a / 2, b / 2, GAP + THICK], (0.0, 0.0, M))[0]
    assert bz[2] == pytest.approx(MU0 * M / np.pi * (term(GAP) - term(GAP + THICK)), rel=1e-12)
    assert abs(bz[0]) < 1e-15 and abs(bz[1]) < 1e-15


def test_far_away_the_prism_is_the_dipole_of_its_moment_and_falls_as_r_cubed():
    m = np.array([3e3, -1e4, 2e4])
    moment = m * SIDE * SIDE * THICK
    centre = np.array([0.0, 0.0, GAP + THICK / 2])
    direction = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    errors, magnitudes = [], []
    for r in (0.25, 0.5, 1.0):
        p = centre + r * direction
        exact = prism_field(p[None], LO, HI, m)[0]
        dip = dipole_field(p[None], centre[None], moment[None])[0]
        errors.append(np.linalg.norm(exact - dip) / np.linalg.norm(dip))
        magnitudes.append(np.linalg.norm(exact))
    # the quadrupole vanishes by symmetry: the correction falls as (L / r)^2, a factor 4 per doubling
    assert errors[-1] < 1e-3 and 3.5 < errors[0] / errors[1] < 4.5 and 3.5 < errors[1] / errors[2] < 4.5
    np.testing.assert_allclose(np.array(magnitudes[:-1]) / magnitudes[1:], 8.0, rtol=4 * errors[0])  # 1 / r^3, to O((L / r)^2)


# ------------------------------------------------------------------------------- the magnet-volume skin
@pytest.fixture(scope="module")
def vskin():
    return volume_skin(SIDE, THICK, GAP, 14, M, 0.009, 5e5, 0.008)


def test_the_rest_field_is_the_prisms_and_the_table_matches_the_direct_sum(vskin):
    np.testing.assert_allclose(volume_field(vskin), prism_field(CHIPS, LO, HI, (0, 0, M)) * 1e6, rtol=1e-12)
    force = np.array([[0.0, 0.0, -50.0], [20.0, -10.0, -150.0], [30.0, 0.0, -80.0], [0.0, 0.0, 0.0]])
    h = column_strains(vskin, force)
    table, direct = volume_field(vskin, h, direct=False), volume_field(vskin, h, direct=True)
    change = np.abs(direct[:3] - vskin.rest_ut).max()
    assert change > 300.0  # uT: the presses move the field by hundreds of uT
    assert np.abs(table - direct).max() < 2e-3 * change  # the trilinear table, 9 nodes per axis
    np.testing.assert_array_equal(table[3], vskin.rest_ut)  # no force: the exact rest field
    # incompressible thin layer: the centre column under p shortens to lambda with mu l^3 + p l^2 = mu
    lam = 1 + h[1, np.argmin((vskin.centres**2).sum(axis=1)), 2]
    p = 150.0 * np.exp(-(vskin.centres**2).sum(axis=1).min() / (2 * 0.008**2)) / (2 * np.pi * 0.008**2)
    assert vskin.shear_modulus * lam**3 + p * lam**2 == pytest.approx(vskin.shear_modulus, rel=1e-10)


def test_a_uniformly_pressed_skin_reads_the_prism_of_its_compressed_thickness():
    """Every column at stretch lambda: a prism of thickness lambda t whose magnetisation per current
    volume is still M (m = F M~ dV0 = lambda M dV0 in lambda dV0): the closed form at the chips."""
    fine = volume_skin(SIDE, THICK, GAP, 28, M, 0.009, 5e5, 0.008)
    lam = 0.7
    f = column_fields(fine, np.array([[0.0, 0.0, 0.0], [0.0, 0.0, lam - 1.0]]))  # (2, N, 5, 3)
    pressed = fine.rest_ut + 1e6 * (f[1] - f[0]).sum(axis=0)
    exact = 1e6 * prism_field(CHIPS, LO, [SIDE / 2, SIDE / 2, GAP + lam * THICK], (0, 0, M))
    change = np.abs(exact - fine.rest_ut).max()
    assert change > 100.0 and np.abs(pressed - exact).max() < 0.02 * change


def test_far_away_a_sheared_skin_is_the_dipole_of_its_moment(vskin):
    """A uniform strain h gives each column F = [[1, 0, h_x], [0, 1, h_y], [0, 0, 1 + h_z]]: the skin's
    moment is F M~ V; far away its field is that dipole's at the deformed centroid, to O((L / r)^2)."""
    h = np.array([0.3, -0.2, -0.25])
    moment = np.array([h[0], h[1], 1 + h[2]]) * M * SIDE * SIDE * THICK
    centroid = np.array([h[0], h[1], 1 + h[2]]) * THICK / 2 + [0.0, 0.0, GAP]
    errors = []
    for r in (0.3, 0.6, 1.2):
        far = dataclasses.replace(vskin, magnetometers=np.tile(centroid + r * np.array([0.48, 0.6, 0.64]), (5, 1)))
        b = column_fields(far, h[None]).sum(axis=1)[0, 0]
        dip = dipole_field(far.magnetometers[:1], centroid[None], moment[None])[0]
        errors.append(np.linalg.norm(b - dip) / np.linalg.norm(dip))
    assert errors[-1] < 1e-3 and errors[0] / errors[2] > 10.0  # the error falls as r^-2 (16 x over 4 x in r)


def test_the_truth_models_differ_and_the_point_dipole_path_is_kept():
    force = np.zeros((6, 1, 3))
    force[2:, 0] = [[0.0, 0.0, -20.0], [0.0, 0.0, -60.0], [15.0, 0.0, -60.0], [0.0, 0.0, 5.0]]
    fields = {}
    for truth in ("magnet_volume", "point_dipole"):
        s = AnySkinSensor(skin={"truth": truth}, drift={"enabled": False})
        out = skin_fields(s, force, 1 / 150)
        assert out.skin.shape == (6, 1, 5, 3)
        np.testing.assert_array_equal(out.skin[[0, 1, 5], 0], np.broadcast_to(out.baseline, (3, 5, 3)))  # pulling: no contact
        fields[truth] = out.skin[:, 0] - out.baseline
    mv, pd = fields["magnet_volume"], fields["point_dipole"]
    assert np.abs(mv[3]).max() > 100.0 and np.abs(pd[3]).max() > 100.0
    assert np.abs(mv[2:5] - pd[2:5]).max() > 0.2 * np.abs(pd[2:5]).max()  # a different world, not a rescaling of the same
    with pytest.raises(ValueError, match=r"sensor\.skin\.truth = 'foo' is not a truth model; choose one of: magnet_volume"):
        truth_model("foo")


# --------------------------------------------------------------------------------------- the chips
def test_chip_noise_has_its_rms_per_axis_within_chi_square_bounds():
    n = 40000
    clean = np.full((n, 2, 3), 250.0)
    noise = np.array([1.5, 1.5, 2.42])
    r = read_chips(clean, np.zeros((2, 3)), np.broadcast_to(np.eye(3), (2, 3, 3)), noise, (0.0, 0.0, 0.0), np.random.default_rng(7))
    dev = (r - clean).reshape(-1, 2 * 3)  # per chip and axis, (n, 6)
    sigma = np.tile(noise, 2)
    lo, hi = stats.chi2.ppf([5e-4, 1 - 5e-4], n - 1)  # 99.9 % two-sided, for each of the 6 variances
    var = dev.var(axis=0, ddof=1)
    assert np.all((n - 1) * var / sigma**2 > lo) and np.all((n - 1) * var / sigma**2 < hi)
    assert np.all(np.abs(dev.mean(axis=0)) < 3.3 * sigma / np.sqrt(n))  # the mean: 99.9 % normal bound
    # per-chip errors: the offsets' spread and the matrices' off-diagonal spread are as set
    offsets, sens = chip_errors(4000, 10.0, 2.0, 1.0, np.random.default_rng(3))
    lo, hi = stats.chi2.ppf([5e-4, 1 - 5e-4], offsets.size)
    assert lo < (offsets**2).sum() / 10.0**2 < hi
    off = sens[:, ~np.eye(3, dtype=bool)]
    assert np.all(np.diagonal(sens, axis1=1, axis2=2) != 1.0) and stats.chi2.ppf(5e-4, off.size) < (off**2).sum() / 0.01**2
    assert (off**2).sum() / 0.01**2 < stats.chi2.ppf(1 - 5e-4, off.size)


def test_the_sensitivity_matrix_offset_and_quantisation_are_applied_per_chip():
    rng = np.random.default_rng(1)
    offsets, sens = chip_errors(3, 10.0, 2.0, 1.0, rng)
    clean = rng.normal(0, 300.0, (50, 3, 3))
    r = read_chips(clean, offsets, sens, (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), rng)
    for c in range(3):  # r = S_c b + o_c, chip by chip
        np.testing.assert_allclose(r[:, c], clean[:, c] @ sens[c].T + offsets[c], rtol=1e-13, atol=1e-10)
    # a field along x alone shows on y and z by the cross-axis terms
    along_x = read_chips(np.tile([100.0, 0.0, 0.0], (1, 3, 1)), np.zeros((3, 3)), sens, 0.0, 0.0, rng)[0]
    np.testing.assert_allclose(along_x[:, 1:], 100.0 * sens[:, 1:, 0], rtol=1e-13)
    q = read_chips(clean, offsets, sens, (1.5, 1.5, 2.42), (0.150, 0.150, 0.242), rng)
    for axis, lsb in enumerate((0.150, 0.150, 0.242)):
        codes = q[..., axis] / lsb
        np.testing.assert_allclose(codes, np.round(codes), atol=1e-9)
    # the helmet's readings with no noise: each chip's matrix and offset applied to its clean field
    quiet = AnySkinSensor(trajectory={"duration_s": 2.5}, skin={"truth": "point_dipole"},  # the chips are the same in both worlds
                          noise={"rms_ut": 0.0, "rms_z_ut": 0.0, "lsb_ut": 0.0, "lsb_z_ut": 0.0})
    sig = simulate_helmet(quiet, 2)
    expect = np.einsum("scij,tscj->tsci", sig.chip_sensitivity, sig.clean) + sig.chip_offsets
    np.testing.assert_allclose(sig.readings, expect, rtol=1e-12, atol=1e-9)


def test_bad_noise_is_refused_naming_the_field():
    with pytest.raises(ValueError, match=r"sensor\.noise\.rms_ut = .*must be finite and >= 0"):
        read_chips(np.zeros((2, 1, 3)), np.zeros((1, 3)), np.eye(3)[None], (1.0, np.nan, 1.0), 0.0, np.random.default_rng(0))
    with pytest.raises(ValueError, match=r"sensor\.noise\.cross_axis_pct"):
        chip_errors(2, 1.0, 0.0, -0.1, np.random.default_rng(0))
    for field, value in (("rms_z_ut", -1.0), ("offset_ut", float("inf")), ("gain_error_pct", -0.1)):
        with pytest.raises(ValueError, match=f"noise.{field}"):
            AnySkinSensor(noise={field: value})


# --------------------------------------------------------------------------------- bad magnet volumes
def test_a_magnet_volume_that_would_invert_is_refused_naming_the_field(tmp_path):
    from pathlib import Path

    from mlsim.scene import load_scene

    scene = Path(__file__).resolve().parents[1] / "scenes" / "anyskin" / "push_study.toml"
    bad = tmp_path / "bad.toml"
    bad.write_text(scene.read_text().replace("[sensor.drift]\nenabled = true", "[sensor.drift]\nenabled = true\nset_fraction = 1.0")
                   .replace("[sensor.push]\npeak_n = 150.0", "[sensor.push]\npeak_n = 600.0"))
    with pytest.raises(SceneError, match=r"sensor\.drift\.set_fraction.*magnet volume inverts"):
        load_scene(bad)
    # the same load in the point-dipole world is no inversion (its strains saturate)
    load_scene(tmp_path / "bad.toml", overrides={"sensor.skin.truth": "point_dipole"})
    # at run time too: a set that reaches the thickness is refused before any field is summed
    s = AnySkinSensor(drift={"enabled": True, "set_fraction": 1.0, "tau_set_s": 0.01})
    force = np.zeros((300, 1, 3))
    force[:, 0, 2] = -2000.0
    with pytest.raises(SceneError, match=r"sensor\.drift\.set_fraction"):
        skin_fields(s, force, 1 / 150)
    with pytest.raises(SceneError, match=r"sensor\.skin\.truth"):
        load_scene(scene, overrides={"sensor.skin.truth": "voxels"})
    with pytest.raises(SceneError, match=r"sensor\.estimator\.contact_model.*bench.* needs the causal CNN"):
        load_scene(scene, overrides={"sensor.estimator.contact_model": None})


# ------------------------------------------------------------------------------------ the bench
def test_the_bench_presses_within_its_cone_and_reads_its_chips():
    t = np.arange(4500) / 150
    f = bench_forces(t, 1.0, 1.5, 1.0, 180.0, np.random.default_rng(0))
    normal, tangent = -f[:, 2], np.linalg.norm(f[:, :2], axis=1)
    assert np.all(normal >= 0) and normal[t < 1.0].max() == 0.0 and PEAK_MIN_N < normal.max() <= 180.0
    assert np.all(tangent <= TANGENT_RATIO * normal + 1e-12) and tangent.max() > 0.3 * normal.max()
    with pytest.raises(ValueError, match=r"sensor\.push\.peak_n"):
        bench_forces(t, 1.0, 1.5, 1.0, 1.0, np.random.default_rng(0))
    quiet = AnySkinSensor(noise={"rms_ut": 0.0, "rms_z_ut": 0.0, "lsb_ut": 0.0, "lsb_z_ut": 0.0})
    run = simulate_bench(quiet, 5, duration_s=3.0)
    assert run.readings.shape == (450, 5, 3) and np.all(run.force[:150] == 0)
    np.testing.assert_allclose(run.readings[:150], np.broadcast_to(run.readings[0], (150, 5, 3)), rtol=0, atol=1e-9)  # still
    loaded = np.argmax(-run.force[:, 2])
    assert np.abs(run.readings[loaded] - run.readings[0]).max() > 50.0  # uT: the press moves the field
    np.testing.assert_array_equal(simulate_bench(quiet, 5, duration_s=3.0).readings, run.readings)  # seeded


def test_the_truth_comparison_trains_on_the_bench_and_scores_both_worlds(tmp_path):
    from other_sensors.anyskin.stages import BENCH
    from other_sensors.anyskin.study import truth_comparison

    s = AnySkinSensor(trajectory={"duration_s": 3.0})
    rows = truth_comparison(s, 3, bench_runs=2, bench_s=3.0, steps=5)
    assert [r.truth for r in rows] == ["magnet_volume", "point_dipole"]
    for r in rows:  # a few steps of training: errors of the order of the forces, finite, per axis
        assert r.bench_mae.shape == r.mae_rebaselined.shape == r.mae_static.shape == (3,)
        assert np.all(np.isfinite(np.concatenate([r.bench_mae, r.mae_rebaselined, r.mae_static])))
        assert np.all(r.mae_static > 0) and r.mae_static.max() < 150.0
    md = BENCH.write(rows, tmp_path, None)[1].read_text()
    assert "| magnet_volume |" in md and "| point_dipole |" in md and "bench_mae_z_n" in md
