"""The ``transport`` tier: light transport as one sparse matrix, traced once per geometry.

The camera's radiance is linear in the sheet's per-vertex radiance e (N,): image = T e with T a
(pixels x vertices) matrix. Each column of T is the image of one vertex's hat function, so the
issue's "one image per emitting patch" is T's columns; tracing them one by one would cost N
renders (16,829 on the default sensor). Instead every camera path is traced once and, at each
point where it meets the emitting sheet from the core side, adds its throughput times the hit
point's barycentric weights to the three vertices of the face it hit:

    T[p, v] = (1 / spp) sum over paths s of pixel p, sum over sheet hits k of beta_sk b_v(x_sk),

which is the path tracer's estimator of the pixel (pure BSDF sampling: the emitter is the whole
sheet, so every diffuse bounce on it is also an emission hit) with the emission left symbolic.
The tracer is a wavefront loop over Mitsuba's own pieces (the scene's camera rays, ray
intersection, the dielectric and diffuse BSDFs' ``sample``, Russian roulette from ``rr_depth``),
so ``path`` and ``transport`` estimate the same integral and differ only by Monte Carlo noise
(tested) and by the geometry: transport uses the rest shape of the sheet, path the deformed one.

Storage: scipy CSR float32. A pixel sees the face under it directly and, through the diffuse
bounces, a few others of the same rod, so T is sparse: about 1.7 M non-zeros at 16 spp on the
default 350 x 350 view. Entries below ``drop`` times the largest are removed; the share of the
total that this removes (for uniform emission) is reported as ``dropped_fraction``. A frame is a
sparse matrix-vector product; a batch of frames one sparse-dense product (scipy, one core).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from mlsim.errors import require_finite

__all__ = ["TransportMatrix", "trace_transport", "RADIANCE_FIX"]

#: What to do about a non-finite radiance handed to a compiled render kernel (it comes from the
#: emission stage's photons, which come from the solve's stresses).
RADIANCE_FIX = ("the radiance comes from the emission stage's photons (mlsim.render.radiance_of): check the emission (emission.csv) and "
                "the solve's stresses (solve_forces.csv) that feed it")


@dataclass
class TransportMatrix:
    """T (H W, N) CSR float32: image = (T e).reshape(H, W) for per-vertex radiance e (N,).

    ``first_depth``: the depth from which the paths' sheet hits were recorded (0: every hit, the
    full transport; 3: the bounces only, :func:`mlsim.render.reprojection.split_transport`)."""

    matrix: sp.csr_matrix
    height_px: int
    width_px: int
    spp: int
    dropped_fraction: float
    seconds: float
    first_depth: int = 0

    @property
    def n_vertices(self) -> int:
        return self.matrix.shape[1]

    def apply(self, radiance, add_to: np.ndarray | None = None) -> np.ndarray:
        """Images (F, H, W) float32 of per-vertex radiance (F, N) (or (N,) -> (H, W)).

        ``add_to`` (F, H, W) float32, C-contiguous: the images are added to it, in place, and it is
        returned (the deformed tier's rasterised direct light gets its bounces)."""
        e = np.asarray(radiance, dtype=np.float32)
        single = e.ndim == 1
        e2 = e[None] if single else e
        if e2.ndim != 2 or e2.shape[1] != self.n_vertices:
            raise ValueError(f"radiance of shape {e.shape}: must be (frames, {self.n_vertices}) or ({self.n_vertices},)")
        require_finite(e2, "radiance (frames, vertices) into the transport matrix's product", RADIANCE_FIX)
        shape = (len(e2), self.height_px, self.width_px)
        if add_to is not None and (add_to.shape != shape or add_to.dtype != np.float32 or not add_to.flags.c_contiguous):
            raise ValueError(f"add_to {add_to.shape} {add_to.dtype}: must be C-contiguous float32 {shape}")
        from mlsim.render.kernels import SPARSE_LIT_FRACTION, csr_times_dense_into, lit_columns_product

        m = self.matrix
        columns = self._columns()
        # frames with few lit vertices (a third of the screw scene's lit frames have 0.2 %): only
        # their lit vertices' columns, the same bits (lit_columns_product)
        sparse = (np.count_nonzero(e2, axis=1) < SPARSE_LIT_FRACTION * e2.shape[1]) if columns is not None else np.zeros(len(e2), bool)
        dense = np.flatnonzero(~sparse)
        images = add_to if add_to is not None else np.zeros(shape, np.float32)
        flat = images.reshape(len(e2), -1)
        if len(dense):
            # numba on every core, one pass over the matrix for the whole batch (scipy's product uses
            # one core: 1.44 against 0.74 ms per frame for 21 frames of the default demo, 2 cores)
            e_dense = e2 if len(dense) == len(e2) else e2[dense]
            # the product's rows summed in blocks and added to their frames' images where they go
            # (the bits of a (P, F) product added to the images: csr_times_dense_into)
            csr_times_dense_into(m.indptr, m.indices, m.data, np.ascontiguousarray(e_dense.T), dense, flat)
        if len(dense) < len(e2):
            lit = np.flatnonzero(sparse)
            out = np.zeros((len(lit), m.shape[0]), np.float32)
            lit_columns_product(*columns, np.ascontiguousarray(e2[lit]), out)
            for j, row in zip(lit, out):
                flat[j] += row
        return images[0] if single else images

    def _columns(self):
        """The matrix by columns (CSC: pointers, rows, values) for :func:`mlsim.render.kernels.lit_columns_product`,
        or None where that product would not give the row product's bits (rows not in scipy's
        canonical form, or an entry not finite)."""
        if getattr(self, "_columns_of", None) is not self.matrix:
            m = self.matrix
            ok = m.has_canonical_format and bool(np.isfinite(m.data).all())
            c = m.tocsc() if ok else None
            self._columns_cache = (c.indptr, c.indices, np.ascontiguousarray(c.data, dtype=np.float32)) if ok else None
            self._columns_of = m
        return self._columns_cache

    def save(self, path) -> None:
        m = self.matrix
        np.savez(path, data=m.data, indices=m.indices, indptr=m.indptr, shape=np.array(m.shape),
                 meta=np.array([self.height_px, self.width_px, self.spp]), dropped_fraction=self.dropped_fraction, seconds=self.seconds,
                 first_depth=self.first_depth)

    @classmethod
    def load(cls, path) -> "TransportMatrix":
        z = np.load(path)
        m = sp.csr_matrix((z["data"], z["indices"], z["indptr"]), shape=tuple(z["shape"]))
        h, w, spp = (int(v) for v in z["meta"])
        return cls(m, h, w, spp, float(z["dropped_fraction"]), float(z["seconds"]), int(z["first_depth"]) if "first_depth" in z.files else 0)


def _barycentric(points, tri):
    """Barycentric weights (n, 3) of points (n, 3) in triangles (n, 3, 3), clipped into the triangle
    (a hit on an edge may land a rounding error outside)."""
    from trimesh.triangles import points_to_barycentric

    w = np.clip(points_to_barycentric(tri, points), 0.0, 1.0)
    return w / w.sum(1, keepdims=True)


def _hits(si, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(face (k,) int64, point (k, 3) float64 mm) of the evaluated surface interactions ``si`` where
    ``mask`` (n,) bool holds."""
    prim = np.array(si.prim_index)[mask].astype(np.int64)
    return prim, np.stack([np.array(si.p.x)[mask], np.array(si.p.y)[mask], np.array(si.p.z)[mask]], axis=1).astype(np.float64)


def trace_transport(sensor_scene, spp: int = 64, seed: int = 0, drop: float = 1e-4, pass_spp: int = 16,
                    progress: bool = False, first_depth: int = 0, one_vertex: bool = False) -> TransportMatrix:
    """Trace the transport matrix of a :class:`mlsim.render.sensor_scene.SensorScene` (module docstring).

    spp: samples per pixel, traced in passes of ``pass_spp`` (memory: about 100 bytes per ray);
    seed: the sampler's seed (same seed, same matrix); drop: relative threshold for small entries.
    first_depth: record only the sheet hits at this path depth or deeper (0: every hit; 3: only the
    paths with a bounce, :data:`mlsim.render.reprojection.DIRECT_DEPTH`). The paths and their random
    numbers do not depend on it, so the matrices of two depths ranges add up to the full one.
    one_vertex: each recorded hit goes to one vertex of its face, drawn with its barycentric weight
    (a seeded generator of its own: the paths do not change), instead of to all three by weight.
    Unbiased (the draw's mean is the interpolation), and a third of the entries per hit: for the
    bounces, whose pixels each sum many diffuse hits, the demo's matrix at 64 spp has 2.6 M entries
    instead of 6.4 M at the same error against a 512 spp trace (per rod 0.39 %, per pixel 25 %, both
    the Monte Carlo noise of 64 spp). Not for direct light: a pixel's few direct hits would turn
    its smooth interpolation into noise.
    """
    from mlsim.render.sensor_scene import use_variant

    if getattr(sensor_scene, "spectra", None) is not None:
        raise ValueError("trace_transport needs a mono SensorScene (the spectral shortcut applies the spectra afterwards); "
                         "build the scene without spectra=")
    mi = use_variant(sensor_scene.variant)  # the scene's device: the CPU, or the GPU where it was built there
    import drjit as dr

    if spp < 1 or pass_spp < 1:
        raise ValueError(f"spp = {spp}, pass_spp = {pass_spp}: must be >= 1")
    t0 = time.perf_counter()
    view = sensor_scene.view
    W, H = int(view.width_px), int(view.height_px)
    n_pix = W * H
    N = sensor_scene.n_vertices
    faces = sensor_scene.faces.astype(np.int64)
    verts = sensor_scene.vertices_mm.astype(np.float64)
    scene = sensor_scene.scene
    camera = scene.sensors()[0]
    ctx = mi.BSDFContext()
    total = sp.csr_matrix((n_pix, N), dtype=np.float64)
    passes = [pass_spp] * (spp // pass_spp) + ([spp % pass_spp] if spp % pass_spp else [])
    from tqdm.auto import tqdm

    bar = tqdm(total=len(passes), desc="transport passes", unit="pass", disable=None if progress else True, leave=False)
    for k, n_s in enumerate(passes):
        n_rays = n_pix * n_s
        sampler = mi.load_dict({"type": "independent"})
        sampler.seed((int(seed) * 1000003 + k) & 0xFFFFFFFF, n_rays)  # 32 bits: the scene seed may be up to 2**63
        idx = dr.arange(mi.UInt32, n_rays)
        pixel = idx // n_s
        pos = mi.Point2f((mi.Float(pixel % W) + sampler.next_1d()) / W, (mi.Float(pixel // W) + sampler.next_1d()) / H)
        ray, weight = camera.sample_ray(0.0, 0.0, pos, mi.Point2f(0.5, 0.5))
        beta = mi.Float(weight[0])
        active = mi.Bool(True)
        pixel_np = np.arange(n_rays, dtype=np.int64) // n_s
        rows, cols, vals = [], [], []
        for depth in range(sensor_scene.max_depth):
            si = scene.ray_intersect(ray, active)
            active &= si.is_valid()
            hit = active & (si.shape.emitter() != None) & (mi.Frame3f.cos_theta(si.wi) > 0)  # noqa: E711 (Dr.Jit mask)
            dr.eval(hit, si.prim_index, si.p, beta)
            m = np.array(hit, dtype=bool)
            if depth >= first_depth and m.any():
                prim, p = _hits(si, m)
                b = _barycentric(p, verts[faces[prim]])
                weight = np.array(beta)[m] / spp  # the mean over all spp
                if one_vertex:
                    u = np.random.default_rng([int(seed) & 0xFFFFFFFF, k, depth]).random(len(b))
                    pick = np.minimum((u[:, None] >= np.cumsum(b, axis=1)).sum(axis=1), 2)
                    rows.append(pixel_np[m])
                    cols.append(faces[prim][np.arange(len(pick)), pick])
                    vals.append(weight)
                else:
                    rows.append(np.repeat(pixel_np[m], 3))
                    cols.append(faces[prim].ravel())
                    vals.append((b * weight[:, None]).ravel())
            if depth == sensor_scene.max_depth - 1:
                break
            bsdf = si.bsdf(ray)
            bs, value = bsdf.sample(ctx, si, sampler.next_1d(active), sampler.next_2d(active), active)
            beta = beta * mi.Float(value[0])
            active &= (bs.pdf > 0) & (beta > 0)
            ray = si.spawn_ray(si.to_world(bs.wo))
            if depth + 1 >= sensor_scene.rr_depth:  # the path integrator's Russian roulette
                q = dr.minimum(beta, 0.95)
                active &= sampler.next_1d(active) < q
                beta = beta / dr.maximum(q, 1e-8)
        if rows:
            r, c, v = np.concatenate(rows), np.concatenate(cols), np.concatenate(vals)
            total = total + sp.csr_matrix((v, (r, c)), shape=(n_pix, N))
        del rows, cols, vals
        bar.update(1)
    bar.close()
    dropped = _drop_small(total, drop)
    return TransportMatrix(total.astype(np.float32), H, W, int(spp), dropped, time.perf_counter() - t0, int(first_depth))


def _drop_small(m: sp.csr_matrix, drop: float) -> float:
    """Remove entries below ``drop`` x max in place; the removed share of the matrix's sum."""
    m.sum_duplicates()
    if drop <= 0 or m.nnz == 0:
        return 0.0
    total = float(m.data.sum())
    small = m.data < drop * float(m.data.max())
    removed = float(m.data[small].sum())
    m.data[small] = 0.0
    m.eliminate_zeros()
    return removed / total if total > 0 else 0.0
