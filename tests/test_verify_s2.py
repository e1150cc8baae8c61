"""The SPEC 1.4 verification case: its set-up (fem/verify_s2.py: meshes, loads, solves) and its study
(mlsim/studies/verify_s2.py: the run over tiers and forces, ratios, outputs; the ``verify_s2`` stage).

Coarse meshes (edge 1 mm) keep the file fast; the default spec's 0.5 mm is run by hand.
"""

from __future__ import annotations

import csv
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fem import verify_s2 as v
from fem.elasticity import dof_components, solve_static
from fem.mesh import boundary_faces, signed_volumes
from mlsim.materials import SHIPPED_MATERIALS
from mlsim.scene import VerifyS2Spec, scene_from_dict
from mlsim.studies import verify_s2 as study

ROOT = Path(__file__).resolve().parents[1]
EDGE_MM = 1.0
SPEC = VerifyS2Spec(edge_length_mm=EDGE_MM, forces_n=(1.0, 2.0, 4.0), profile_points=41)
GEOM = v.Geometry.from_spec(SPEC)
MATERIALS = {0: SHIPPED_MATERIALS["PDMS"], 1: SHIPPED_MATERIALS["steel"]}
G = v.GRAVITY_M_S2


@pytest.fixture(scope="module")
def pressing():
    return v.build_system(v.pressing_mesh(GEOM, EDGE_MM * 1e-3), GEOM, MATERIALS)


@pytest.fixture(scope="module")
def sliding():
    return v.build_system(v.sliding_mesh(GEOM, EDGE_MM * 1e-3), GEOM, MATERIALS)


@pytest.fixture(scope="module")
def linear_run(tmp_path_factory):
    """run() of the linear tier on the coarse spec, written out: (result, summary, paths)."""
    spec = SPEC.model_copy(update={"tiers": ("linear",)})
    result = study.run(spec, log=lambda m: None)
    out = tmp_path_factory.mktemp("verify_s2")
    return result, study.summary(result), study.write(result, out)


# ------------------------------------------------------------------------------------- meshes
def test_pressing_mesh_is_conforming_with_an_exact_block():
    mesh = v.pressing_mesh(GEOM, EDGE_MM * 1e-3)
    vol = signed_volumes(mesh.points, mesh.tets)
    assert np.all(vol > 0)
    assert vol.sum() * 1e9 == pytest.approx(10 * 10 * 2 + 2 * 2 * 4, rel=1e-12)
    assert vol[mesh.label == 1].sum() * 1e9 == pytest.approx(16.0, rel=1e-12)
    # the block's tets fill exactly [4, 6]^2 x [2, 6] mm
    block_pts = mesh.points[mesh.tets[mesh.label == 1]].reshape(-1, 3) * 1e3
    assert block_pts.min(axis=0) == pytest.approx([4.0, 4.0, 2.0], abs=1e-12)
    assert block_pts.max(axis=0) == pytest.approx([6.0, 6.0, 6.0], abs=1e-12)
    # conforming: every face is shared by two tets or on the boundary, and the boundary's area is
    # the union's surface (a hanging node would leave interior faces unpaired and add area)
    faces = boundary_faces(mesh.tets)
    p = mesh.points[faces]
    area_mm2 = 0.5 * np.linalg.norm(np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), axis=1).sum() * 1e6
    assert area_mm2 == pytest.approx(2 * 100 + 4 * 10 * 2 + 4 * 2 * 4, rel=1e-12)
    # the slab/block interface: faces shared by a slab tet and a block tet, all at z = 2 mm, 4 mm^2
    tri = np.sort(mesh.tets[:, [[1, 2, 3], [0, 3, 2], [0, 1, 3], [0, 2, 1]]].reshape(-1, 3), axis=1)
    owner = np.repeat(mesh.label, 4)
    _, inv, counts = np.unique(tri, axis=0, return_inverse=True, return_counts=True)
    inv = inv.ravel()
    labels_per_face = np.zeros((counts.size, 2))
    np.add.at(labels_per_face[:, 0], inv, owner)
    np.add.at(labels_per_face[:, 1], inv, 1)
    interface = np.flatnonzero((labels_per_face[:, 1] == 2) & (labels_per_face[:, 0] == 1))
    first = np.zeros(counts.size, dtype=np.int64)
    first[inv[::-1]] = np.arange(len(inv))[::-1]
    q = mesh.points[tri[first[interface]]] * 1e3
    assert np.abs(q[:, :, 2] - 2.0).max() == 0.0
    assert 0.5 * np.linalg.norm(np.cross(q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]), axis=1).sum() == pytest.approx(4.0, rel=1e-12)


def test_sliding_mesh_volume_and_exact_top(sliding):
    mesh = sliding.mesh
    exact_mm3 = 200.0 + math.pi * 2.0**2 * 8.0
    assert signed_volumes(mesh.points, mesh.tets).sum() * 1e9 == pytest.approx(exact_mm3, rel=0.01)
    # boundary nodes were snapped: those on the slab's top lie on z = 2 mm exactly, those on the
    # rod's side on r = 2 mm (to round-off)
    nodes = np.unique(boundary_faces(mesh.tets))
    x, y, z = (mesh.points[nodes] * 1e3).T
    r = np.hypot(x - 5.0, y - 5.0)
    top = np.abs(z - 2.0) < 0.1
    assert np.abs(z[top] - 2.0).max() == 0.0
    side = (z > 2.1) & (z < 9.9) & (r < 2.5)
    assert side.sum() > 50
    assert np.abs(r[side] - 2.0).max() < 1e-12


# -------------------------------------------------------------------------------------- loads
@pytest.mark.parametrize("case", v.CASES)
def test_lateral_load_has_resultant_f_at_the_force_height(case, pressing, sliding):
    s = pressing if case == "pressing" else sliding
    comp = dof_components(s.d.u)
    f = s.unit_force[: s.d.n_u]
    resultant = np.array([f[comp == c].sum() for c in range(3)])
    assert resultant == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
    assert np.all(s.unit_force[s.d.n_u :] == 0.0)
    # moment about the slab's top (y axis): P2 functions reproduce z, so sum f_x z = int t_x z dA
    z_rel_mm = (s.d.u.doflocs[2, comp == 0] - GEOM.top_m) * 1e3
    assert float(f[comp == 0] @ z_rel_mm) == pytest.approx(SPEC.force_height_mm, rel=0.01)
    # band of half-width max(edge / 2, 0.25 mm) = 0.5 mm all around the side
    perimeter_mm = 8.0 if case == "pressing" else math.pi * 4.0
    assert s.band_area_m2 * 1e6 == pytest.approx(perimeter_mm * 1.0, rel=1e-12 if case == "pressing" else 0.02)


def test_gravity_is_the_weight_of_slab_and_block(pressing):
    comp = dof_components(pressing.d.u)
    g = pressing.gravity[: pressing.d.n_u]
    weight_n = G * (970.0 * 200e-9 + 7850.0 * 16e-9)
    assert g[comp == 2].sum() == pytest.approx(-weight_n, rel=1e-12)
    assert np.abs(g[comp != 2]).max() == 0.0


# ------------------------------------------------------------------------------ linear tier
@pytest.mark.parametrize("case", v.CASES)
def test_linear_superposition_equals_a_direct_solve(case, pressing, sliding):
    """The affine superposition x_g + F x_1 against an independent solve at each force."""
    s = pressing if case == "pressing" else sliding
    forces = np.array([1.0, 4.0])
    states, report = v.solve_linear_tier(s, forces)
    assert max(report["backward_error"].values()) < 1e-12
    gravity_only, _ = v.solve_linear_tier(s, [0.0])
    for f, x in zip(forces, states):
        direct = solve_static(s.matrix, s.gravity + f * s.unit_force, s.fixed)
        assert np.abs(x - direct)[: s.d.n_u].max() <= 1e-8 * np.abs(direct[: s.d.n_u]).max()
    per_newton = (states - gravity_only) / forces[:, None]
    assert np.abs(per_newton[1] - per_newton[0]).max() <= 1e-8 * np.abs(per_newton[0]).max()


@pytest.mark.parametrize("case", v.CASES)
def test_reactions_balance_the_force_and_the_weight(case, pressing, sliding):
    s = pressing if case == "pressing" else sliding
    force = 2.0
    (x,), _ = v.solve_linear_tier(s, [force])
    ext = s.gravity + force * s.unit_force
    vol = signed_volumes(s.mesh.points, s.mesh.tets)
    weight_n = G * float(s.rho @ vol)
    reaction = v.reactions(s, x, ext)
    assert reaction[0] == pytest.approx(-force, rel=1e-8)
    assert abs(reaction[1]) < 1e-8 * force
    assert reaction[2] == pytest.approx(weight_n, rel=1e-6)


def test_steel_block_moves_rigidly_while_the_slab_deforms(pressing):
    """E 200 GPa on 550 kPa: the block's strain is ~1e-5 of the slab's, its motion a rigid one."""
    s = pressing
    (x,), _ = v.solve_linear_tier(s, [1.0])
    strain = v.strain_magnitude(s, x)
    block, slab = s.mesh.label == 1, s.mesh.label == 0
    assert strain[block].max() / strain[slab].max() < 1e-4
    assert strain[slab].max() > 0.1  # 1 N on a 2 x 2 mm footprint of PDMS: large strain indeed
    # least-squares rigid motion u = a + w x (X - c) of the block's vertices fits to 1e-4 of its size
    nodes = np.unique(s.mesh.tets[block])
    X = s.mesh.points[nodes] - s.mesh.points[nodes].mean(axis=0)
    u = x[s.d.u.nodal_dofs[:, nodes]].T  # (nodes, 3)
    A = np.zeros((3 * len(nodes), 6))
    for c in range(3):
        A[c::3, c] = 1.0
    # w x X = (w1 X2 - w2 X1, w2 X0 - w0 X2, w0 X1 - w1 X0), w = coef[3:]
    A[0::3, 4], A[0::3, 5] = X[:, 2], -X[:, 1]
    A[1::3, 3], A[1::3, 5] = -X[:, 2], X[:, 0]
    A[2::3, 3], A[2::3, 4] = X[:, 1], -X[:, 0]
    coef, *_ = np.linalg.lstsq(A, u.ravel(), rcond=None)
    misfit = np.abs(A @ coef - u.ravel()).max()
    assert misfit < 1e-4 * np.abs(u).max()
    assert np.abs(coef[4]) > 0.1  # and it tilts about y (a large rotation for 1 N: see the report)


def test_profile_under_the_block_is_a_rigid_tilt(linear_run):
    """Along the slab's top under the bonded block (SPEC x 3..5 mm) ux is uniform and uz linear in x."""
    result, *_ = linear_run
    u = result.displacement_mm[("linear", "pressing")][0]  # 1 N: (3, N) mm
    under = (result.x_slab_mm > 4.0 + 1e-9) & (result.x_slab_mm < 6.0 - 1e-9)
    assert under.sum() >= 9
    x = result.x_slab_mm[under]
    assert np.ptp(u[0, under]) < 1e-4 * np.abs(u[0]).max()
    slope, offset = np.polyfit(x, u[2, under], 1)
    assert np.abs(slope * x + offset - u[2, under]).max() < 1e-4 * np.abs(u[2]).max()
    assert slope < 0  # a +x push tips the block's leading (+x) edge down


# ------------------------------------------------------------------------- ratio and outputs
def test_ratio_sliding_over_pressing_from_the_written_profiles(linear_run):
    result, summary, paths = linear_run
    names = sorted(p.name for p in paths)
    assert names == ["verify_s2_profiles.csv", "verify_s2_profiles.png", "verify_s2_ratio.csv"]
    assert all(p.stat().st_size > 0 for p in paths)
    with open(paths[0], newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 2 * 3 * SPEC.profile_points
    x_spec = sorted({float(r["x_mm"]) for r in rows})
    assert x_spec[0] == pytest.approx(0.0, abs=1e-12) and x_spec[-1] == pytest.approx(8.0, abs=1e-12)
    ratio_keys = [k for k in summary if "ratio" in k]
    assert set(ratio_keys) == {"ratio_max_sliding_over_pressing", "ratio_mean_sliding_over_pressing"}
    for f in SPEC.forces_n:
        peak = {c: max(float(r["u_mm"]) for r in rows if r["case"] == c and float(r["force_n"]) == f) for c in v.CASES}
        mean = {c: np.mean([float(r["u_mm"]) for r in rows if r["case"] == c and float(r["force_n"]) == f]) for c in v.CASES}
        assert summary["ratio_max_sliding_over_pressing"]["linear"][f"{f:g}"] == pytest.approx(peak["sliding"] / peak["pressing"], rel=1e-6)
        assert summary["ratio_mean_sliding_over_pressing"]["linear"][f"{f:g}"] == pytest.approx(mean["sliding"] / mean["pressing"], rel=1e-6)
    # u_mm is the magnitude of (ux, uy, uz): never below |ux| or |uz|
    assert all(float(r["u_mm"]) >= max(abs(float(r["ux_mm"])), abs(float(r["uz_mm"]))) - 1e-12 for r in rows)


def test_sliding_moves_the_slab_top_less_than_the_steel_block(linear_run):
    """At the same lateral force, the 2 x 2 mm steel block tilts on its small footprint
    (uz = -+0.9 mm at its edges for 1 N) while the 4 mm rod spreads the force over 3x the area:
    the slab's top moves about half as much under the rod. (SPEC 1.3's "sliding deforms the rods
    far more than pressing" concerns the rods, not this profile.) Gravity alone (~3 mN) hardly
    changes the ratio, which is therefore the same at every force in the linear tier."""
    result, summary, _ = linear_run
    ratios = np.array(list(summary["ratio_max_sliding_over_pressing"]["linear"].values()))
    assert np.all((ratios > 0.3) & (ratios < 0.7))
    assert np.ptp(ratios) < 1e-3 * ratios.mean()
    spread = result.checks["linear_sliding_max_u_per_force_relative_spread"]
    assert 0 < spread < 1e-3  # |u| / F is constant to the gravity's share


# ------------------------------------------------------------------- the elastomer's range
def _affine_state(s, A):
    """A state (n,) whose displacement is u = A X (X in m) and whose pressure is zero."""
    x = np.zeros(s.d.n_dofs)
    comp = dof_components(s.d.u)
    coords = s.d.u.doflocs  # (3, n_u) m
    x[: s.d.n_u] = np.einsum("ij,jn->in", A, coords)[comp, np.arange(s.d.n_u)]
    return x


@pytest.mark.parametrize("finite", [False, True])
def test_principal_strain_of_homogeneous_deformations(finite, pressing):
    """Uniaxial stretch a: a in both measures. Simple shear g: g / 2 in the small strain, and
    the largest principal stretch g / 2 + sqrt(1 + g^2 / 4) minus one at finite strain."""
    a, g = 0.3, 0.8
    stretch = v.principal_strain(pressing, _affine_state(pressing, np.diag([a, 0.0, 0.0])), finite)
    assert stretch == pytest.approx(np.full(stretch.shape, a), abs=1e-12)
    shear = np.zeros((3, 3))
    shear[0, 2] = g
    expected = (g / 2 + math.sqrt(1 + g * g / 4) - 1.0) if finite else g / 2
    got = v.principal_strain(pressing, _affine_state(pressing, shear), finite)
    assert got == pytest.approx(np.full(got.shape, expected), abs=1e-12)


def test_volume_beyond_break_is_the_elastomer_past_the_limit(pressing):
    """u_x = c x^2 strains the slab by 2 c x along x; with the limit reached at x = 7 mm (a grid
    plane) the volume beyond it is the slab's x > 7 mm: 3 x 10 x 2 = 60 mm^3, the steel block
    (label 1, not the elastomer) excluded though it is strained too."""
    limit = 0.631
    c = limit / (2 * 7e-3)
    x = np.zeros(pressing.d.n_dofs)
    comp = dof_components(pressing.d.u)
    loc = pressing.d.u.doflocs
    along_x = comp == 0
    x[: pressing.d.n_u][along_x] = c * loc[0, along_x] ** 2
    largest, volume = v.strain_beyond_break(pressing, x, limit, finite=False)
    assert volume == pytest.approx(60.0, rel=1e-9)
    assert largest == pytest.approx(2 * c * 10e-3, rel=1e-2)  # at the quadrature point nearest x = 10 mm
    assert v.strain_beyond_break(pressing, x, 2 * c * 10e-3, finite=False)[1] == 0.0


def test_a_torn_state_is_stated_as_a_physical_limit(pressing):
    """The continuation's end read physically: with the slab strained past break over x > 7 mm (u_x = c x^2,
    as above) the sentence gives the force, the 60 mm^3 past break, the force it first tore at, the
    largest strain (89 %) at the quadrature point nearest the slab's far end (x = 9.93 mm) and the least det F; within the
    limit there is no physical limit (None), and the solver's failure stays a solver's failure."""
    limit = 0.631
    c = limit / (2 * 7e-3)
    x = np.zeros(pressing.d.n_dofs)
    comp = dof_components(pressing.d.u)
    along_x = comp == 0
    x[: pressing.d.n_u][along_x] = c * pressing.d.u.doflocs[0, along_x] ** 2
    said = v.physical_limit(pressing, x, 4.2, limit, 4.0)
    assert said.startswith("pressing stops at a physical limit near 4.2 N: the elastomer is strained past its elongation at break (63.1%)")
    assert "over 60 mm^3 (first at 4 N)" in said and "largest principal strain 89% at (9.9" in said  # 2 c x at the last point, 9.93 mm
    assert "crushed to det F = 1" in said  # this state only stretches: nothing is crushed
    assert v.physical_limit(pressing, x, 4.2, 0.95, None) is None


def test_the_spec_forces_strain_pdms_beyond_its_break(linear_run):
    """SPEC 1.4's forces on SPEC 1.2's PDMS (elongation at break < 63.1 %): already at 1 N both cases
    strain some PDMS beyond break (at the bonded edges), and the torn volume grows with the force.
    The run says so in its messages, its summary and the ratio table, and marks no force as within."""
    result, summary, paths = linear_run
    assert result.elongation_at_break == pytest.approx(0.631)
    for case in v.CASES:
        volume = np.asarray(result.material_range[("linear", case)]["volume_beyond_break_mm3"])
        assert np.all(volume > 0) and np.all(np.diff(volume) > 0)
        assert summary["material_range"]["linear"][case]["volume_beyond_break_mm3"]["4"] == pytest.approx(volume[-1])
        assert any(m.startswith(f"linear {case}: from 1 N on") and "elongation at break (63.1%)" in m for m in result.messages)
    assert not result.within_break("linear").any()
    assert summary["within_break"]["linear"] == {"1": 0.0, "2": 0.0, "4": 0.0}
    ratio_csv = next(p for p in paths if p.name == "verify_s2_ratio.csv")
    with open(ratio_csv, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [int(r["within_break"]) for r in rows] == [0, 0, 0]
    assert float(rows[1]["pressing_volume_beyond_break_mm3"]) == pytest.approx(result.material_range[("linear", "pressing")]["volume_beyond_break_mm3"][1])


# ---------------------------------------------------------------------------- nonlinear tier
@pytest.mark.parametrize("case", v.CASES)
def test_nonlinear_agrees_with_linear_at_a_small_force(case, pressing, sliding):
    """At 10 mN (tilts of ~0.5 degree) the neo-Hookean and small-strain profiles agree within 2 %."""
    s = pressing if case == "pressing" else sliding
    force = [0.01]
    points = v.profile_points(SPEC, GEOM)
    lin, _ = v.solve_linear_tier(s, force)
    non, (report,) = v.solve_nonlinear_tier(s, force, increments=1)
    assert report["converged"] and report["newton_iterations"] <= 12
    assert 0.99 < report["min_det_f"] < 1.0  # 10 mN barely compresses the PDMS
    u_lin = np.linalg.norm(v.sample_displacement(s, lin, points), axis=1).max()
    u_non = np.linalg.norm(v.sample_displacement(s, non, points), axis=1).max()
    assert u_non == pytest.approx(u_lin, rel=0.02)
    assert u_non != pytest.approx(u_lin, rel=1e-6)  # a different model, not the linear answer again
    # the finite principal strain is the small strain's to first order: 1 % at these ~1 % strains
    eps_lin = v.principal_strain(s, lin[0], finite=False)
    eps_non = v.principal_strain(s, non[0], finite=True)
    assert np.abs(eps_non - eps_lin).max() < 0.03 * np.abs(eps_lin).max()


def test_a_force_that_does_not_converge_is_nan_with_a_message(pressing):
    """One Newton iteration per solve cannot converge: the force and the larger ones are NaN, named."""
    states, reports = v.solve_nonlinear_tier(pressing, [2.0, 1.0], increments=1, max_iterations=1)
    assert np.all(np.isnan(states))
    by_force = dict(zip([2.0, 1.0], reports))
    assert not by_force[1.0]["converged"] and "pressing (nonlinear) at 1 N" in by_force[1.0]["message"]
    assert not by_force[2.0]["converged"] and "not attempted" in by_force[2.0]["message"]
    points = v.profile_points(SPEC, GEOM)
    assert np.all(np.isnan(v.sample_displacement(pressing, states, points)))


def test_summary_reports_not_converged_forces_as_null():
    forces = np.array([1.0, 2.0])
    x = np.linspace(1.0, 9.0, 3)
    result = v.VerifyS2Result(SPEC, forces, x, x - 1.0)
    ok = np.ones((2, 3, 3))
    bad = ok.copy()
    bad[1] = np.nan
    result.displacement_mm = {("linear", "sliding"): ok, ("linear", "pressing"): 2 * ok, ("nonlinear", "sliding"): bad, ("nonlinear", "pressing"): 2 * ok}
    result.converged = {k: np.all(np.isfinite(u), axis=(1, 2)) for k, u in result.displacement_mm.items()}
    summary = study.summary(result)
    assert summary["ratio_max_sliding_over_pressing"]["linear"] == {"1": 0.5, "2": 0.5}
    assert summary["ratio_max_sliding_over_pressing"]["nonlinear"] == {"1": 0.5, "2": None}
    assert summary["not_converged"] == [{"tier": "nonlinear", "case": "sliding", "force_n": 2.0}]


# -------------------------------------------------------------------------------------- scene
def test_the_study_is_an_output_of_the_rod_array_through_the_registry():
    """The ``verify_s2`` stage is declared with the study (mlsim.studies.stages), not by the kind's
    module: the registry adds it to ``ml_rod_array`` after the kind's own stages, and a scene can ask
    for it as an output."""
    from mlsim import stage
    from mlsim.studies.stages import VERIFY_S2

    kind = stage.kind("ml_rod_array")
    assert kind.stages[-1] is VERIFY_S2 and "verify_s2" in kind.outputs
    assert stage.stages("ml_rod_array")["verify_s2"].run is VERIFY_S2.run


def test_scene_file_holds_the_spec_defaults():
    data = tomllib.loads((ROOT / "scenes" / "verify_fem_s2.toml").read_text())
    assert data["name"] == "verify_fem_s2" and data["outputs"] == ["verify_s2"]
    scene = scene_from_dict(data)
    assert scene.verify_s2 == VerifyS2Spec()
    assert set(data["verify_s2"]) == set(VerifyS2Spec.model_fields)  # every default written out


# --------------------------------------------------------------------------- readings of SPEC 1.4
def test_reading_is_validated_and_read_from_the_scene():
    with pytest.raises(ValueError, match=r"verify_s2.measure = 'rod'.*choose one of: slab_top, load_height, body_top, anywhere"):
        v.Reading(measure="rod")
    with pytest.raises(ValueError, match=r"verify_s2.force_at"):
        v.Reading(force_at="middle")
    assert v.Reading.from_spec(SPEC) == v.Reading() == v.Reading(measure="slab_top", load_distribution="band", force_at="height")
    spec = VerifyS2Spec(measure="body_top", load_distribution="slice", force_at="top")
    assert v.Reading.from_spec(spec) == v.Reading("body_top", "slice", "top")
    # the scene refuses a reading it does not know, naming the field
    with pytest.raises(ValueError, match="measure"):
        VerifyS2Spec(measure="rod")


def _resultant_and_arm(s, geom, case):
    comp = dof_components(s.d.u)
    f = s.unit_force[: s.d.n_u]
    resultant = np.array([f[comp == c].sum() for c in range(3)])
    arm_mm = float(f[comp == 0] @ ((s.d.u.doflocs[2, comp == 0] - geom.top_m) * 1e3))
    return resultant, arm_mm


@pytest.mark.parametrize("distribution", ["pushed_side", "slice"])
def test_other_load_distributions_keep_the_resultant_and_its_line(distribution, pressing):
    """On the block's exact mesh: 1 N along +x with the same moment arm (2 mm) as the band;
    the pushed side is the block's -x face only (2 mm x 1 mm), the slice the block's 4 mm^2 x 1 mm."""
    s = v.build_system(pressing.mesh, GEOM, MATERIALS, distribution)
    resultant, arm_mm = _resultant_and_arm(s, GEOM, "pressing")
    assert resultant == pytest.approx([1.0, 0.0, 0.0], abs=1e-12)
    assert arm_mm == pytest.approx(2.0, rel=1e-9)
    assert s.band_area_m2 * (1e9 if distribution == "slice" else 1e6) == pytest.approx(4.0 if distribution == "slice" else 2.0, rel=1e-12)
    if distribution == "pushed_side":  # every loaded DOF lies on the block's -x face
        loaded = np.abs(s.unit_force[: s.d.n_u]) > 0
        assert np.abs(s.d.u.doflocs[0, loaded] * 1e3 - 4.0).max() < 1e-12


def test_force_at_the_top_moves_the_band_to_the_bodys_top(pressing):
    geom = v.Geometry.from_spec(SPEC, reading=v.Reading(force_at="top"))
    assert geom.band_m("pressing") == pytest.approx((5.0e-3, 6.0e-3)) and geom.band_m("sliding") == pytest.approx((9.0e-3, 10.0e-3))
    mesh = v.pressing_mesh(geom, EDGE_MM * 1e-3)
    s = v.build_system(mesh, geom, MATERIALS)
    resultant, arm_mm = _resultant_and_arm(s, geom, "pressing")
    assert resultant[0] == pytest.approx(1.0, abs=1e-12)
    assert arm_mm == pytest.approx(3.5, rel=1e-9)  # the band's centre, 0.5 mm below the 4 mm block's top


def test_measures_of_the_linear_tier(pressing, sliding):
    """Each measure is affine in F (the linear tier); the maximum anywhere bounds every sampled
    measure; the rigid block's top moves more than the slab's top under it (it tilts)."""
    forces = np.array([0.0, 1.0, 3.0])
    stats = {}
    for case, s in (("pressing", pressing), ("sliding", sliding)):
        states, _ = v.solve_linear_tier(s, forces)
        for m in v.MEASURES:
            stats[case, m] = v.measure_stats(s, states, GEOM, m, SPEC)
        for m in ("load_height", "body_top"):
            u = v.sample_displacement(s, states, v.measure_points(GEOM, case, m, SPEC))
            per_n = (u[1:] - u[0]) / forces[1:, None, None]
            assert np.abs(per_n[1] - per_n[0]).max() <= 1e-9 * np.abs(per_n).max()
        for m in ("slab_top", "load_height", "body_top"):
            assert np.all(stats[case, "anywhere"]["max"][1:] >= stats[case, m]["max"][1:] * (1 - 1e-3))
    assert np.all(stats["pressing", "body_top"]["max"][1:] > 2 * stats["pressing", "slab_top"]["max"][1:])


def test_run_honours_the_reading(tmp_path):
    spec = SPEC.model_copy(update={"tiers": ("linear",), "forces_n": (1.0, 2.0)})
    result = study.run(spec, log=lambda m: None, reading=v.Reading(measure="body_top"))
    summary = study.summary(result)
    assert summary["reading"] == {"measure": "body_top", "load_distribution": "band", "force_at": "height"}
    top = {c: summary["measured_displacement_mm"]["linear"][c]["max"] for c in v.CASES}
    assert summary["ratio_max_sliding_over_pressing"]["linear"]["2"] == pytest.approx(top["sliding"]["2"] / top["pressing"]["2"], rel=1e-12)
    # the profile along the slab's top (SPEC 1.4's plot) is written whatever the measure
    assert result.displacement_mm[("linear", "sliding")].shape == (2, 3, SPEC.profile_points)
    rows = (study.write(result, tmp_path)[1]).read_text().splitlines()
    assert rows[0].startswith("tier,measure,") and rows[1].startswith("linear,body_top,1,")


def test_nonlinear_block_tilts_as_a_rigid_body(pressing):
    """At 0.3 N the steel block tilts by about 15 degrees on the PDMS: its vertices still follow a
    finite rigid motion x = R X + t (Kabsch fit) to 1e-4 of their displacement, and the tilt is
    about y and tips the +x edge down (the linear tier's sense)."""
    states, (report,) = v.solve_nonlinear_tier(pressing, [0.3], increments=2)
    assert report["converged"]
    x = states[0]
    nodes = np.unique(pressing.mesh.tets[pressing.mesh.label == 1])
    X = pressing.mesh.points[nodes]
    u = x[pressing.d.u.nodal_dofs[:, nodes]].T
    P, Q = X - X.mean(axis=0), X + u - (X + u).mean(axis=0)
    U, _, Vt = np.linalg.svd(P.T @ Q)
    R = (U @ np.diag([1.0, 1.0, np.sign(np.linalg.det(U @ Vt))]) @ Vt).T
    misfit = np.abs(P @ R.T - Q).max()
    assert misfit < 1e-4 * np.abs(u).max()
    tilt = math.atan2(R[0, 2], R[2, 2])  # rotation about y: +x edge down is a positive angle
    assert 0.05 < tilt < 1.0
    # about y only, to the mesh's asymmetry (six tets per hexahedron are not mirror-symmetric in y)
    assert abs(R[1, 0]) < 0.02 * tilt and abs(R[1, 2]) < 0.02 * tilt
