"""Stiff and extreme cases of the linear solve on the layered rod array (issue #3, stability).

Each case either gives finite numbers that obey a bound we can state, or raises a clear error."""

from __future__ import annotations

import warnings

import numpy as np
import pytest
import skfem
from skfem import FacetBasis, LinearForm

from fem.elasticity import assemble, discretise, element_lame, facet_indices, skfem_mesh, solve_static, split
from fem.geometry import FaceTag, RodArray
from fem.materials.linear_elastic import lame_parameters
from fem.mesh import MeshParams, build_mesh

YOUNG = 1.5e6


@pytest.fixture(scope="module")
def layered(tiny_mesh):
    _, g, mesh, _ = tiny_mesh
    return _problem(mesh)


def _problem(mesh):
    sk = skfem_mesh(mesh.points, mesh.tets, mesh.edge_nodes, mesh.tet_edges)
    tips = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.ROD_TIP])
    bottom = facet_indices(sk, mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM])
    return mesh, sk, tips, bottom


def _lateral_tip_deflection(layered, element, layer_young, nu=0.49, load_pa=1e3):
    mesh, sk, tips, bottom = layered
    d = discretise(sk, element)
    lam, mu = element_lame(mesh.layer_fraction, [lame_parameters(e, nu) for e in layer_young])
    fb = FacetBasis(sk, d.u.elem, facets=tips, intorder=4)

    @LinearForm
    def shear(v, w):
        return load_pa * v[0]

    rhs = np.concatenate([skfem.asm(shear, fb), np.zeros(d.n_dofs - d.n_u)])
    x = solve_static(assemble(d, lam, mu), rhs, d.u.get_dofs(facets=bottom).all())
    assert np.all(np.isfinite(x))
    u, _ = split(d, x)
    area = skfem.Functional(lambda w: 1.0 + 0 * w.x[0]).assemble(fb)
    return skfem.Functional(lambda w: w.u[0]).assemble(fb, u=fb.interpolate(u)) / area


def test_thousandfold_stiffness_contrast_between_layers_is_bounded(layered):
    """An absorber 1000x stiffer than the rest: finite, and between the all-soft and all-stiff bodies."""
    soft = _lateral_tip_deflection(layered, "P2P1", [YOUNG] * 3)
    stiff = _lateral_tip_deflection(layered, "P2P1", [1000 * YOUNG] * 3)
    contrast = _lateral_tip_deflection(layered, "P2P1", [1000 * YOUNG, YOUNG, YOUNG])
    assert stiff == pytest.approx(soft / 1000, rel=1e-6)  # linearity in E
    assert stiff < contrast < soft
    assert contrast < 0.5 * soft  # a stiff outer skin carries most of the bending


def test_nearly_incompressible_layers_do_not_lock(layered):
    at_049 = _lateral_tip_deflection(layered, "P2P1", [YOUNG] * 3, nu=0.49)
    at_04999 = _lateral_tip_deflection(layered, "P2P1", [YOUNG] * 3, nu=0.4999)
    assert at_04999 == pytest.approx(at_049, rel=0.05)


def test_zero_load_gives_exactly_zero(layered):
    assert _lateral_tip_deflection(layered, "P2", [YOUNG] * 3, load_pa=0.0) == 0.0


def test_unclamped_body_is_refused_not_nan(layered):
    """No boundary condition: six rigid-body modes make the matrix singular; the solve must say so
    rather than return NaN or a huge meaningless field."""
    mesh, sk, tips, bottom = layered
    d = discretise(sk, "P1")
    lam, mu = lame_parameters(YOUNG, 0.3)
    rhs = np.random.default_rng(5).normal(size=d.n_dofs)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # SuperLU may warn before we raise
        with pytest.raises(FloatingPointError, match="singular"):
            solve_static(assemble(d, lam, mu), rhs, np.array([], dtype=int))


def test_thin_ml_layer_of_a_tenth_of_a_millimetre():
    g = RodArray(2, 2, 7.2e-3, 7.2e-3, 2.5e-3, 9e-3, 2e-3, 0.3e-3, 0.1e-3)
    mesh, report = build_mesh(g, MeshParams(edge_length_m=2.5e-3, envelope_m=2.5e-3 / 40), progress=False)
    np.testing.assert_allclose(mesh.layer_fraction.sum(axis=1), 1.0, atol=1e-12)
    assert abs(report["layer_volume_rel_error"]["ml"]) < 0.03
    deflection = _lateral_tip_deflection(_problem(mesh), "P2P1", [YOUNG, 10 * YOUNG, YOUNG])
    assert np.isfinite(deflection) and deflection > 0
