"""Non-finite input to the compiled kernels is refused with the array named, where its first bad entry
is, and what to check (issue 40): the rasteriser's radiance and vertices
(mlsim.render.direct_raster.DirectRaster.images), the transport matrix's product
(mlsim.render.transport.TransportMatrix.apply) and the ADMM contact solve's right-hand side
(fem.contact_admm.admm_contact). Each test first checks the finite case against its reference, so
the refusal is not a kernel that refuses everything."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from fem import contact_admm as ca
from mlsim.errors import SolverError, require_finite
from mlsim.render.direct_raster import DirectRaster
from mlsim.render.transport import TransportMatrix

N = 12  # a 12 x 12 grid of vertices, one on each pixel centre of a 12 x 12 image


def _grid_raster() -> tuple[DirectRaster, np.ndarray]:
    """A DirectRaster of a flat N x N grid sheet 1 mm above the core's bottom, seen straight on: the
    tangent table is 1 everywhere and the pixel map puts the vertex at (i, j) mm on the centre of
    pixel (i, j), so each pixel reads exactly its vertex's radiance (throughput 1). No Mitsuba."""
    yy, xx = np.mgrid[0:N, 0:N]
    V = np.stack([xx.ravel(), yy.ravel(), np.ones(N * N)], axis=1) * 1e-3  # m
    idx = np.arange(N * N).reshape(N, N)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)]).astype(np.int64)
    raster = DirectRaster(throughput=np.ones((N, N), np.float32), per_side=1, pixel_map=np.array([[0.5, 1.0, 0.0], [0.5, 0.0, 1.0]]),
                          inv_length=np.ones((4, 4)), r2_step_mm2=2 * N * N / 3, z_step_mm=1.0, faces=faces, orientation=-1.0,
                          n_vertices=N * N, height_px=N, width_px=N)
    return raster, V


def test_require_finite_names_the_array_the_first_bad_entry_and_the_fix():
    require_finite(np.zeros((2, 3)), "x", "fix it")  # finite: nothing
    with pytest.raises(ValueError, match=r"x \(a, b\): 2 of 6 entries are NaN or infinite \(the first at index \(0, 2\), .*inf.*\); fix it"):
        require_finite(np.array([[0.0, 1.0, np.inf], [np.nan, 0.0, 0.0]]), "x (a, b)", "fix it")
    with pytest.raises(SolverError, match="1 of 1 entries"):
        require_finite(np.float64(np.nan), "s", "f", SolverError)


def test_the_rasteriser_refuses_nan_radiance_and_nan_vertices():
    raster, V = _grid_raster()
    e = np.random.default_rng(1).uniform(1e14, 1e15, (2, N * N)).astype(np.float32)
    images = raster.images(np.stack([V, V]), e)
    np.testing.assert_allclose(images, e.reshape(2, N, N), rtol=1e-6)  # each pixel is its vertex's radiance
    bad = e.copy()
    bad[1, 37] = np.nan
    with pytest.raises(ValueError, match=r"radiance \(frames, vertices\) to rasterise: 1 of 288 entries .* index \(1, 37\).*emission"):
        raster.images(np.stack([V, V]), bad)
    moved = np.stack([V, V])
    moved[0, 5, 2] = np.nan
    with pytest.raises(ValueError, match=r"vertices_m .*: 1 of 864 entries .* index \(0, 5, 2\).*solve"):
        raster.images(moved, e)


def test_the_transport_product_refuses_nan_radiance():
    rng = np.random.default_rng(2)
    A = sp.random(6 * 5, 40, density=0.2, random_state=3, format="csr", dtype=np.float32)
    T = TransportMatrix(A, 6, 5, 16, 0.0, 0.0)
    e = rng.random((3, 40)).astype(np.float32)
    np.testing.assert_allclose(T.apply(e), (e.astype(np.float64) @ A.toarray().T).reshape(3, 6, 5), rtol=1e-5)
    e[2, 11] = np.inf
    with pytest.raises(ValueError, match=r"transport matrix's product: 1 of 120 entries .* index \(2, 11\)"):
        T.apply(e)
    with pytest.raises(ValueError, match=r"index \(0, 11\)"):
        T.apply(e[2])  # one frame


def test_the_contact_solve_refuses_a_nan_right_hand_side():
    """One point, body compliance c and penalty 1/k in series: f_n = delta / (c + 1/k) when finite;
    a NaN in the gap is a SolverError that names it, not a NaN force after the iteration bound."""
    G = ca.DenseDelassus(np.eye(3) * 2e-4, np.array([1e5]))
    n = np.array([[0.0, 0.0, 1.0]])
    f, *_ = ca.admm_contact(G, np.array([[0.0, 0.0, -1e-4]]), n, 0.8, rtol=1e-10, max_iterations=5000)
    np.testing.assert_allclose(f[0], [0.0, 0.0, 1e-4 / (2e-4 + 1e-5)], rtol=1e-8)
    with pytest.raises(SolverError, match=r"contact right-hand side b .*: 1 of 3 entries .* index \(0, 2\).*load"):
        ca.admm_contact(G, np.array([[0.0, 0.0, np.nan]]), n, 0.8)
    with pytest.raises(SolverError, match=r"contact normals"):
        ca.admm_contact(G, np.array([[0.0, 0.0, -1e-4]]), np.array([[0.0, np.nan, 1.0]]), 0.8)
