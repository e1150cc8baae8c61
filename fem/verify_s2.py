"""The published FEM verification case of SPEC 1.4: "sliding" (rod on a slab) against "pressing"
(steel block bonded to a slab) under the same lateral force. The set-up: geometry, meshes, loads,
the two tiers' solves, the strain measures and the result they fill.

The driver that runs it (both meshes, every tier and force, the material's range) and its report
(summary, CSV, plot), with the ``verify_s2`` stage, are the study :mod:`mlsim.studies.verify_s2`.

SPEC 1.4: two bodies, both PDMS (E 550 kPa, nu 0.49, density 970 kg/m^3), each a 10 x 10 x 2 mm
slab with a fixed bottom; gravity on.

- "sliding": a cylinder rod 8 mm tall, 4 mm diameter, stands on the slab; a lateral force acts
  on the rod 2 mm above the slab's top surface;
- "pressing": a steel block 2 x 2 x 4 mm is bonded on the slab; the same lateral force acts on
  the block 2 mm above the slab's top surface.

Forces 1 to 16 N. Output: the displacement along the slab's top (SPEC x from 0 to 8 mm, the rod
between 2 and 6 mm) and the ratio of sliding to pressing displacement at each force.

Modelling choices (not given by SPEC 1.4):

- Coordinates: the slab spans x, y in [0, size] and z in [0, thickness]; rod and block stand at
  the slab's centre. SPEC's profile coordinate is ``x_spec = x_slab - (centre_x - 4 mm)``: the
  rod's centre at SPEC x = 4 mm.
- Meshes: "pressing" is a structured tet mesh (each hexahedron of a tensor grid split into six)
  whose grid lines contain the block's faces and the load band's edges, so the slab/block
  interface and the loaded band are exact. "sliding" is tetrahedralised by fTetWild from the
  union of the slab box and a 64-gon cylinder, its boundary nodes snapped onto the exact box and
  cylinder (straight faces between them: chords of the circle).
- Elements: Taylor-Hood P2P1 (:mod:`fem.elasticity`): PDMS at nu = 0.49 locks with P1.
- The lateral force: a uniform traction along +x over the rod's (block's) side within a band of
  half-width ``max(edge / 2, 0.25 mm)`` around the force height, all around the perimeter, scaled
  so that its resultant is exactly F along +x (its moment arm about the slab's top is then the
  band's centre height). A dead load (its direction does not follow the deformation).
- Steel: E 200 GPa, nu 0.3 (``mlsim.materials``), elastic: a stiffness contrast of about 4e5
  with PDMS. The linear solve is refined until its componentwise backward error is at round-off
  (the plain relative residual cannot drop below ~1e-8 with such a contrast; see
  :func:`_solve_accurately`).
- Readings (:class:`Reading`): SPEC 1.4 leaves open where the displacement is measured
  (:data:`MEASURES`), how the force is spread (:data:`LOAD_DISTRIBUTIONS`) and whether it acts at
  the given height or the body's top (:data:`FORCE_AT`); what is bonded to what is
  ``block_material`` (steel, or PDMS for the "both PDMS" reading). Default: the slab's top profile
  (the one surface both cases share, made of the same elastomer, and the SPEC's output), a band
  traction all around the side, at ``force_height_mm`` (as SPEC 1.4 says). The ratio is then of
  the chosen measure; the slab's top profile is written whatever the measure.
- Tiers: ``linear`` (small strain; the response is affine in F with gravity on, so gravity and a
  unit force are solved once and superposed) and ``nonlinear`` (the mixed neo-Hookean solid of
  :mod:`fem.nonlinear`, dead loads, gravity first and then the force continued through all the
  forces with a secant predictor, on a coarser mesh: :data:`NONLINEAR_EDGE_MM`). The Newton loop is
  the full-step Newton of :mod:`fem.nonlinear` (:class:`fem.nonlinear.FullStepNewton`): :func:`fem.nonlinear.solve_nonlinear` backtracks on the
  residual norm, which a tilting steel block defeats from the first increment. A force at which
  Newton fails is recorded as not converged: NaN in the outputs and a message, never a silent
  number; the larger forces are then not attempted (their load path passes through it).
- Ratios: sliding over pressing, of the maximum and of the mean displacement magnitude along the
  profile, per tier and force.
- The material's range: per tier, case and force, the elastomer's largest principal strain and the
  volume strained beyond its elongation at break (:func:`strain_beyond_break`; PDMS < 63.1 %, SPEC
  1.2). SPEC 1.4's forces all exceed it with these sizes (a rod 4 mm across bent by 1 N at 2 mm
  already sees a beam-theory surface strain of 32 F h / (pi d^3 E) = 58 %, before the bonded rim's
  concentration): such ratios describe an elastomer that would have torn, and the run says so
  rather than reporting them as predictions.

Shapes: ``points`` (P, 3) m; ``tets`` (T, 4); DOF vectors are scikit-fem's ``[u; p / scale]``.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from typing import Callable, Mapping

import numpy as np
import scipy.sparse as sp
import skfem
from skfem import FacetBasis, Functional, LinearForm

from fem.elasticity import Discretisation, _per_qp, assemble, discretise, dof_components, skfem_mesh
from fem.materials.linear_elastic import lame_parameters
from fem.nonlinear import FullStepNewton
from mlsim.errors import MeshingError, MlsimError

__all__ = [
    "CASES",
    "TIERS",
    "MEASURES",
    "LOAD_DISTRIBUTIONS",
    "FORCE_AT",
    "Reading",
    "measure_points",
    "measure_stats",
    "lateral_load",
    "slice_load",
    "nonlinear_edge_length_mm",
    "materials_by_label",
    "GRAVITY_M_S2",
    "SPEC_ROD_CENTRE_X_MM",
    "Geometry",
    "CaseMesh",
    "CaseSystem",
    "VerifyS2Result",
    "grid_coordinates",
    "pressing_mesh",
    "sliding_mesh",
    "element_materials",
    "gravity_load",
    "band_facets",
    "lateral_band_load",
    "fixed_bottom_dofs",
    "build_system",
    "solve_linear_tier",
    "solve_nonlinear_tier",
    "profile_points",
    "sample_displacement",
    "reactions",
    "strain_magnitude",
    "principal_strain",
    "strain_beyond_break",
    "min_det_f",
]

CASES = ("sliding", "pressing")
TIERS = ("linear", "nonlinear")
GRAVITY_M_S2 = 9.80665  # standard gravity, along -z
#: SPEC 1.4 draws its profile from 0 to 8 mm with the rod between 2 and 6 mm: its centre at 4 mm.
SPEC_ROD_CENTRE_X_MM = 4.0
#: Polygon segments of the rod's input surface (fTetWild); boundary nodes are then snapped onto the circle.
ROD_SEGMENTS = 64
#: Load increments per force step of the nonlinear tier (halved on failure by the solver).
NONLINEAR_INCREMENTS = 8
#: The smallest force step (N) the nonlinear tier's continuation may cut down to before it
#: reports the force as not converged.
NONLINEAR_MIN_STEP_N = 1e-3
#: The nonlinear tier's default mesh size (mm): at 0.5 mm its Newton iterations cost 4-8 times
#: more and the elements at the bonded sharp edges crush at smaller forces; the ratio's force
#: dependence, which the tier is for, is a global (bending, tilting) effect that 1 mm resolves.
NONLINEAR_EDGE_MM = 1.0
#: From a state already strained past the elastomer's elongation at break, the continuation ends as a
#: physical limit (:func:`_load_path`) when a failing step is cut below 1 / 2^this of the path's first
#: step: the material is past its range and the path only creeps (1 / 8: 31 mN of S2's 2 -> 4 N).
PAST_RANGE_HALVINGS = 3
#: Newton iterations per load step: near the bonded edges, where det F approaches 0, Newton's
#: convergence is slow but steady (measured: 18 iterations for the 1 N step of the 1 mm block),
#: and a genuinely diverging step stops earlier (:class:`fem.nonlinear.FullStepNewton`).
NONLINEAR_MAX_ITERATIONS = 30
#: A converged nonlinear state whose det F falls below this at a quadrature point is flagged: an
#: element crushed near a sharp bonded edge (PDMS at nu 0.49 is nearly incompressible), so the
#: numbers there depend on the mesh.
MIN_DET_F_WARNING = 0.2
#: The linear solves must reach this componentwise backward error (after iterative refinement).
LINEAR_BACKWARD_ERROR = 1e-12

# ------------------------------------------------------------------------------------ geometry
# ------------------------------------------------------------------------------------ readings
#: Where the displacement is measured (:func:`measure_points`): the slab's top along the profile
#: (SPEC 1.4's plot), the loaded body's cross-section at the force's height, the loaded body's top
#: face, or anywhere in the model (slab and body).
MEASURES = ("slab_top", "load_height", "body_top", "anywhere")
#: How the lateral force is spread (:func:`lateral_load`): a traction band all around the body's
#: side; the same band only on the side facing -x (where a pusher touches it); a body force in the
#: body's slice at the force's height (the force "at the centre").
LOAD_DISTRIBUTIONS = ("band", "pushed_side", "slice")
#: Where the force acts: ``force_height_mm`` above the slab's top, or at the body's top.
FORCE_AT = ("height", "top")


@dataclass(frozen=True)
class Reading:
    """One reading of SPEC 1.4's loosely given set-up: where the displacement is measured, how the
    force is spread and where it acts (the choices are explained at :data:`MEASURES`,
    :data:`LOAD_DISTRIBUTIONS`, :data:`FORCE_AT`). What is bonded to what is the existing
    ``block_material`` (steel, or the "both PDMS" reading with ``"PDMS"``).
    Validated at construction: a bad value raises ``ValueError`` naming the scene field."""

    measure: str = "slab_top"
    load_distribution: str = "band"
    force_at: str = "height"

    def __post_init__(self):
        for name, allowed in (("measure", MEASURES), ("load_distribution", LOAD_DISTRIBUTIONS), ("force_at", FORCE_AT)):
            value = getattr(self, name)
            if value not in allowed:
                raise ValueError(f"verify_s2.{name} = {value!r}: not a valid choice; choose one of: {', '.join(allowed)}")

    @classmethod
    def from_spec(cls, spec) -> "Reading":
        """The reading a :class:`mlsim.scene.VerifyS2Spec` asks for."""
        return cls(spec.measure, spec.load_distribution, spec.force_at)

    @property
    def label(self) -> str:
        return f"{self.measure}/{self.load_distribution}/{self.force_at}"


@dataclass(frozen=True)
class Geometry:
    """The SPEC 1.4 set-up in metres. The slab spans x, y in [0, slab_m[:2]], z in [0, slab_m[2]];
    rod and block stand on its top at its centre; the force acts at ``force_z_m`` (absolute)."""

    slab_m: tuple[float, float, float]
    rod_radius_m: float
    rod_height_m: float
    block_m: tuple[float, float, float]
    force_z_m: float
    band_half_width_m: float
    force_at: str = "height"  # "top": the band ends at the body's top instead (Reading.force_at)

    @classmethod
    def from_spec(cls, spec, edge_length_m: float | None = None, reading: Reading | None = None) -> "Geometry":
        """From a :class:`mlsim.scene.VerifyS2Spec` (mm); the band half-width follows the edge length."""
        reading = Reading.from_spec(spec) if reading is None else reading
        edge_m = spec.edge_length_mm * 1e-3 if edge_length_m is None else edge_length_m
        slab = tuple(float(v) * 1e-3 for v in spec.slab_size_mm)
        return cls(
            slab_m=slab,
            rod_radius_m=0.5e-3 * spec.rod_diameter_mm,
            rod_height_m=1e-3 * spec.rod_height_mm,
            block_m=tuple(float(v) * 1e-3 for v in spec.block_size_mm),
            force_z_m=slab[2] + 1e-3 * spec.force_height_mm,
            band_half_width_m=max(0.5 * edge_m, 0.25e-3),
            force_at=reading.force_at,
        )

    @property
    def top_m(self) -> float:
        """z of the slab's top surface."""
        return self.slab_m[2]

    @property
    def centre_m(self) -> tuple[float, float]:
        """(x, y) of the slab's centre, where the rod and the block stand."""
        return 0.5 * self.slab_m[0], 0.5 * self.slab_m[1]

    def body_top_m(self, case: str) -> float:
        """z of the rod's ("sliding") or the block's ("pressing") top."""
        return self.top_m + (self.rod_height_m if case == "sliding" else self.block_m[2])

    def band_m(self, case: str) -> tuple[float, float]:
        """(z_low, z_high) of the loaded band, clipped to the body's side; with ``force_at = "top"``
        the band of width 2 half-widths that ends at the body's top."""
        if self.force_at == "top":
            hi = self.body_top_m(case)
            return max(hi - 2.0 * self.band_half_width_m, self.top_m), hi
        lo = max(self.force_z_m - self.band_half_width_m, self.top_m)
        hi = min(self.force_z_m + self.band_half_width_m, self.body_top_m(case))
        return lo, hi

    def load_z_m(self, case: str) -> float:
        """z of the load's line of action: the loaded band's centre."""
        return 0.5 * sum(self.band_m(case))

    def volume_m3(self, case: str) -> float:
        """Analytic volume of slab + rod ("sliding") or slab + block ("pressing")."""
        slab = self.slab_m[0] * self.slab_m[1] * self.slab_m[2]
        if case == "sliding":
            return slab + math.pi * self.rod_radius_m**2 * self.rod_height_m
        return slab + self.block_m[0] * self.block_m[1] * self.block_m[2]


@dataclass(frozen=True, eq=False)
class CaseMesh:
    """A linear tet mesh of one case. points: (P, 3) m; tets: (T, 4) positively oriented;
    label: (T,) 0 elastomer (slab, rod), 1 steel block; info: sizes and checks (JSON-able)."""

    case: str
    points: np.ndarray
    tets: np.ndarray
    label: np.ndarray
    info: dict = field(default_factory=dict)


def grid_coordinates(breaks_m, edge_m: float) -> np.ndarray:
    """Sorted 1-D grid (n,) m through every break, each gap split evenly at spacing <= ``edge_m``.

    breaks_m: the coordinates that must be grid lines (faces of the block, edges of the band).
    """
    b = np.unique(np.round(np.asarray(breaks_m, dtype=float), 12))  # merge coincident breaks (1 pm)
    out = [b[:1]]
    for lo, hi in zip(b[:-1], b[1:]):
        n = max(1, math.ceil((hi - lo) / edge_m - 1e-9))
        out.append(np.linspace(lo, hi, n + 1)[1:])
    return np.concatenate(out)


def _drop_unused(points: np.ndarray, tets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = np.unique(tets)
    remap = np.full(len(points), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    return points[used], remap[tets]


def pressing_mesh(geom: Geometry, edge_m: float) -> CaseMesh:
    """Conforming tet mesh of the slab with the bonded block ("pressing", SPEC 1.4).

    A tensor grid whose lines contain the slab's top, the block's faces and the load band's edges,
    each hexahedron split into six tets (scikit-fem ``MeshTet.init_tensor``); the tets above the
    slab and outside the block are removed. The interface and the band are therefore exact.
    """
    from fem.mesh import orient_tets, signed_volumes

    sx, sy, t = geom.slab_m
    bx, by, bz = geom.block_m
    cx, cy = geom.centre_m
    zlo, zhi = geom.band_m("pressing")
    x = grid_coordinates([0.0, cx - bx / 2, cx + bx / 2, sx], edge_m)
    y = grid_coordinates([0.0, cy - by / 2, cy + by / 2, sy], edge_m)
    z = grid_coordinates([0.0, t, zlo, zhi, t + bz], edge_m)
    full = skfem.MeshTet.init_tensor(x, y, z)
    p, tt = full.p.T, full.t.T
    c = p[tt].mean(axis=1)
    in_block = (np.abs(c[:, 0] - cx) < bx / 2) & (np.abs(c[:, 1] - cy) < by / 2) & (c[:, 2] < t + bz)
    keep = (c[:, 2] < t) | in_block
    points, tets = _drop_unused(p, tt[keep].astype(np.int64))
    # init_tensor's tets come in both orientations: make each positive, then validate
    negative = signed_volumes(points, tets) < 0
    tets[negative] = tets[negative][:, [0, 1, 3, 2]]
    tets = orient_tets(points, tets)
    label = (points[tets].mean(axis=1)[:, 2] > t).astype(np.int64)
    info = {"kind": "structured (tensor grid, 6 tets per hexahedron)", "grid_cells": [len(x) - 1, len(y) - 1, len(z) - 1]}
    return CaseMesh("pressing", points, tets, label, _mesh_info(geom, "pressing", points, tets, label, info))


@dataclass(frozen=True)
class _RodOnSlabSurface:
    """The exact boundary of slab + rod, for :func:`fem.mesh._snap_boundary` (metres)."""

    geom: Geometry

    def project_to_surface(self, points: np.ndarray, edge_tol_m: float = 0.0) -> np.ndarray:
        # Coordinate-wise snaps: a node within the tolerance of several pieces (an edge or a corner of
        # the body) lands on all of them; the pieces that meet (box faces, the slab top and the rod's
        # side at their circle) are snapped independently, so their order does not matter.
        g, tol = self.geom, edge_tol_m
        sx, sy, t = g.slab_m
        cx, cy = g.centre_m
        out = np.array(points, dtype=float)
        for axis, planes in ((0, (0.0, sx)), (1, (0.0, sy)), (2, (0.0,))):
            for v in planes:
                near = np.abs(out[:, axis] - v) <= tol
                out[near, axis] = v
        dx, dy = out[:, 0] - cx, out[:, 1] - cy
        r = np.hypot(dx, dy)
        top = (np.abs(out[:, 2] - t) <= tol) & (r >= g.rod_radius_m - tol)
        out[top, 2] = t
        rod_top = np.abs(out[:, 2] - (t + g.rod_height_m)) <= tol
        out[rod_top, 2] = t + g.rod_height_m
        side = (np.abs(r - g.rod_radius_m) <= tol) & (out[:, 2] >= t - tol) & (r > 0)
        scale = g.rod_radius_m / np.where(side, r, 1.0)
        out[side, 0] = cx + dx[side] * scale[side]
        out[side, 1] = cy + dy[side] * scale[side]
        return out

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) distance of points on or near the boundary to the nearest boundary piece."""
        g = self.geom
        sx, sy, t = g.slab_m
        cx, cy = g.centre_m
        x, y, z = np.asarray(points, dtype=float).T
        r = np.hypot(x - cx, y - cy)
        R, H = g.rod_radius_m, t + g.rod_height_m
        d = [np.abs(x), np.abs(x - sx), np.abs(y), np.abs(y - sy), np.abs(z)]
        d.append(np.where(r >= R, np.abs(z - t), np.hypot(np.abs(z - t), R - r)))  # the slab's top around the rod
        d.append(np.where(r <= R, np.abs(z - H), np.hypot(np.abs(z - H), r - R)))  # the rod's top
        d.append(np.where((z >= t) & (z <= H), np.abs(r - R), np.inf))  # the rod's side
        return np.min(np.stack(d), axis=0)


def _rod_on_slab_surface_mm(geom: Geometry, segments: int) -> tuple[np.ndarray, np.ndarray]:
    """Watertight union of the slab box and a ``segments``-gon rod: vertices (V, 3) mm, faces (F, 3)."""
    import manifold3d as m3

    sx, sy, t = (v * 1e3 for v in geom.slab_m)
    cx, cy = (v * 1e3 for v in geom.centre_m)
    r, h = geom.rod_radius_m * 1e3, geom.rod_height_m * 1e3
    # the rod starts inside the slab so that the union is one solid without a coplanar seam
    rod = m3.Manifold.cylinder(h + 0.5 * t, r, r, segments).translate([cx, cy, 0.5 * t])
    body = m3.Manifold.cube([sx, sy, t]) + rod
    mesh = body.to_mesh()
    return np.asarray(mesh.vert_properties, dtype=float)[:, :3], np.asarray(mesh.tri_verts, dtype=np.int32)


def sliding_mesh(geom: Geometry, edge_m: float, segments: int = ROD_SEGMENTS, timeout_s: float = 300.0, retries: int = 3) -> CaseMesh:
    """Unstructured tet mesh of the slab with the rod standing on it ("sliding", SPEC 1.4).

    fTetWild (through :func:`fem.mesh._run_tetwild`, in a subprocess in a temporary directory) on
    the union of the slab box and a ``segments``-gon cylinder, envelope ``edge / 40``; boundary
    nodes are then snapped onto the exact box and cylinder (:func:`fem.mesh._snap_boundary`, which
    keeps any node whose move would squash a tet). A failed attempt is retried with a slightly
    perturbed edge length, as :func:`fem.mesh.build_mesh` does. Raises :class:`MeshingError`.
    """
    from fem.mesh import _run_tetwild, _snap_boundary, boundary_faces, orient_tets, signed_volumes

    vertices_mm, faces = _rod_on_slab_surface_mm(geom, segments)
    diag_mm = float(np.linalg.norm(vertices_mm.max(0) - vertices_mm.min(0)))
    envelope_m = edge_m / 40.0
    # fTetWild keeps its surface within the envelope of the polygon, itself within the sag of the circle
    sag_m = geom.rod_radius_m * (1.0 - math.cos(math.pi / segments))
    snap_tol_m = 2.0 * envelope_m + sag_m
    surface = _RodOnSlabSurface(geom)
    failures = []
    for k in range(retries + 1):
        edge_try_m = edge_m * (1.0 + 0.04 * math.ceil(k / 2) * (-1) ** k)
        try:
            pts_mm, tets = _run_tetwild(vertices_mm, faces, edge_try_m * 1e3, envelope_m * 1e3 / diag_mm, True, timeout_s)
            points, tets = _drop_unused(np.asarray(pts_mm, dtype=float) * 1e-3, np.asarray(tets, dtype=np.int64))
            tets = orient_tets(points, tets)
            bfaces = boundary_faces(tets)
            points = _snap_boundary(surface, points, tets, bfaces, snap_tol_m)
            tets = orient_tets(points, tets)
            volume = float(signed_volumes(points, tets).sum())
            exact = geom.volume_m3("sliding")
            if abs(volume / exact - 1.0) > 0.01:
                raise MeshingError(f"mesh volume {volume * 1e9:.4g} mm^3 is {100 * (volume / exact - 1):+.2f} % off the analytic {exact * 1e9:.4g} mm^3")
            stray_m = float(surface.distance(points[np.unique(bfaces)]).max())
            if stray_m > 0.25 * edge_m:
                raise MeshingError(f"a boundary node lies {stray_m * 1e3:.3g} mm from the exact surface: hole or cavity")
        except MeshingError as exc:
            failures.append(f"edge {edge_try_m * 1e3:.3g} mm: {exc}")
            continue
        label = np.zeros(len(tets), dtype=np.int64)
        info = {
            "kind": "fTetWild, boundary snapped onto the exact box and cylinder",
            "rod_segments": segments,
            "edge_length_mm": edge_try_m * 1e3,
            "boundary_stray_mm": stray_m * 1e3,
            "attempts": len(failures) + 1,
        }
        return CaseMesh("sliding", points, tets, label, _mesh_info(geom, "sliding", points, tets, label, info))
    raise MeshingError(f"the sliding mesh (slab + rod) failed after {len(failures)} attempts ({'; '.join(failures)}); try another edge_length_mm")


def _mesh_info(geom: Geometry, case: str, points, tets, label, extra: dict) -> dict:
    from fem.mesh import quality_report, signed_volumes

    vol = signed_volumes(points, tets)
    q = quality_report(points, tets)
    return {
        **extra,
        "points": int(len(points)),
        "tets": int(len(tets)),
        "volume_mm3": float(vol.sum() * 1e9),
        "analytic_volume_mm3": float(geom.volume_m3(case) * 1e9),
        "block_volume_mm3": float(vol[label == 1].sum() * 1e9),
        "min_dihedral_deg": q["min_dihedral_deg"],
    }


# -------------------------------------------------------------------------------- loads and system
def element_materials(label: np.ndarray, materials: Mapping[int, object]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-element (lambda Pa, mu Pa, density kg/m^3), each (T,), from labels (T,) and a material per label.

    materials: {label: :class:`mlsim.materials.Material`} with young_modulus_pa, poisson_ratio and
    density_kg_m3 known.
    """
    lam, mu, rho = (np.empty(len(label)) for _ in range(3))
    for k in np.unique(label):
        m = materials[int(k)]
        for prop in ("young_modulus_pa", "poisson_ratio", "density_kg_m3"):
            if getattr(m, prop).value is None:
                raise ValueError(f"material {m.name!r} has no {prop}: give it in the scene's [materials.{m.name}]")
        lam_k, mu_k = lame_parameters(m.young_modulus_pa.value, m.poisson_ratio.value)
        sel = label == k
        lam[sel], mu[sel], rho[sel] = lam_k, mu_k, m.density_kg_m3.value
    return lam, mu, rho


@LinearForm
def _weight_form(v, w):
    return -w.rho * GRAVITY_M_S2 * v[2]


def gravity_load(d: Discretisation, rho: np.ndarray) -> np.ndarray:
    """(n,) load vector of gravity (-z) with per-element density rho (T,) kg/m^3; zero pressure rows."""
    f = skfem.asm(_weight_form, d.u, rho=_per_qp(rho, d.u))
    return np.concatenate([f, np.zeros(d.n_dofs - d.n_u)])


def band_facets(skmesh, geom: Geometry, case: str, pushed_side_only: bool = False) -> np.ndarray:
    """Boundary facets (B,) on the rod's or block's side that overlap the loaded band.

    The side: boundary facets above the slab's top whose normal is within 30 degrees of horizontal
    (the rod's chords and the block's faces are vertical; the tops are horizontal).
    pushed_side_only: only those whose outward normal points to -x (the face a +x pusher touches).
    """
    facets = skmesh.boundary_facets()
    xyz = skmesh.p[:, skmesh.facets[:, facets]]  # (3, 3 vertices, B)
    normal = np.cross(xyz[:, 1] - xyz[:, 0], xyz[:, 2] - xyz[:, 0], axis=0)
    horizontal = np.abs(normal[2]) < 0.5 * np.linalg.norm(normal, axis=0)
    if pushed_side_only:  # orient each normal outward: away from its tet's centroid
        inward = skmesh.p[:, skmesh.t[:, skmesh.f2t[0, facets]]].mean(axis=1) - xyz.mean(axis=1)
        normal = normal * -np.sign(np.einsum("ib,ib->b", normal, inward))
        horizontal &= normal[0] < -1e-6 * np.linalg.norm(normal, axis=0)
    zlo, zhi = geom.band_m(case)
    zmin, zmax = xyz[2].min(axis=0), xyz[2].max(axis=0)
    eps = 1e-9 * geom.slab_m[2]
    above = xyz[2].mean(axis=0) > geom.top_m + eps
    overlaps = (zmax > zlo + eps) & (zmin < zhi - eps)
    return facets[horizontal & above & overlaps]


def lateral_band_load(d: Discretisation, facets: np.ndarray, geom: Geometry, case: str, intorder: int = 16) -> tuple[np.ndarray, float]:
    """Unit (1 N along +x) uniform traction over the band of the body's side: ((n,) vector, band area m^2).

    The traction is 1 / A on the part of ``facets`` with z in the band (an indicator evaluated at
    the quadrature points, exact where the band's edges are mesh lines) and A is the band's area
    by the same quadrature, so the x components of the vector sum to exactly 1 N (P2 functions sum
    to one) and its moment arm is the quadrature mean height of the band.
    """
    zlo, zhi = geom.band_m(case)
    fb = FacetBasis(d.u.mesh, d.u.elem, facets=facets, intorder=intorder)

    f, area = _unit_x_load(fb, lambda x: (x[2] >= zlo) & (x[2] <= zhi),
                           f"{case}: no side facets in the load band z = {zlo * 1e3:.3g}..{zhi * 1e3:.3g} mm: check force_height_mm")
    return np.concatenate([f, np.zeros(d.n_dofs - d.n_u)]), area


def _unit_x_load(basis, inside, empty_message: str) -> tuple[np.ndarray, float]:
    """1 N along +x spread uniformly over where ``inside(x)`` holds on ``basis`` (facets: a traction;
    the volume: a body force): (load vector over the basis's DOFs, that area or volume). The indicator
    and the measure use the same quadrature, so the resultant is exactly 1 N."""
    measure = float(Functional(lambda w: inside(w.x).astype(float)).assemble(basis))
    if not measure > 0:
        raise MlsimError(empty_message)

    @LinearForm
    def unit(v, w):
        return inside(w.x).astype(float) * v[0] / measure

    return skfem.asm(unit, basis), measure


def slice_load(d: Discretisation, geom: Geometry, case: str, intorder: int = 7) -> tuple[np.ndarray, float]:
    """Unit (1 N along +x) uniform body force over the loaded body's slice z in ``geom.band_m(case)``:
    ((n,) vector, slice volume m^3). The force "at the body's centre": its line of action passes
    through the body's axis at the band's centre, and it loads the body through its volume, not
    through a patch of its surface. The indicator is evaluated at the quadrature points and the
    volume by the same quadrature, so the resultant is exactly 1 N. Order 7 (24 points, positive
    weights) has no point on a face: the orders 5, 6 and 8 rules of scikit-fem do, and would count
    the elements next to a band edge that is a mesh plane (the block's mesh)."""
    zlo, zhi = geom.band_m(case)
    basis = skfem.Basis(d.u.mesh, d.u.elem, intorder=intorder)

    f, volume = _unit_x_load(basis, lambda x: (x[2] >= zlo) & (x[2] <= zhi) & (x[2] > geom.top_m),
                             f"{case}: no part of the body in the load slice z = {zlo * 1e3:.3g}..{zhi * 1e3:.3g} mm")
    return np.concatenate([f, np.zeros(d.n_dofs - d.n_u)]), volume


def lateral_load(d: Discretisation, skmesh, geom: Geometry, case: str, distribution: str = "band") -> tuple[np.ndarray, float]:
    """The unit lateral load (n,) spread as ``distribution`` (:data:`LOAD_DISTRIBUTIONS`), and the
    loaded area m^2 (a band) or volume m^3 (a slice)."""
    if distribution == "slice":
        return slice_load(d, geom, case)
    if distribution not in ("band", "pushed_side"):
        raise ValueError(f"{distribution!r} is not a load distribution; choose one of: {', '.join(LOAD_DISTRIBUTIONS)}")
    return lateral_band_load(d, band_facets(skmesh, geom, case, pushed_side_only=distribution == "pushed_side"), geom, case)


def fixed_bottom_dofs(d: Discretisation) -> np.ndarray:
    """Displacement DOFs (m,) of the slab's bottom (z = 0): all three components fixed."""
    bottom = d.u.mesh.facets_satisfying(lambda x: np.abs(x[2]) < 1e-12, boundaries_only=True)
    return d.u.get_dofs(facets=bottom).all()


@dataclass(eq=False)
class CaseSystem:
    """Everything one case's solves need: the P2P1 discretisation, materials per element (T,),
    the linear operator (n, n), gravity and the unit lateral force (n,), the fixed DOFs."""

    case: str
    mesh: CaseMesh
    d: Discretisation
    lam: np.ndarray
    mu: np.ndarray
    rho: np.ndarray
    matrix: sp.csr_matrix
    gravity: np.ndarray
    unit_force: np.ndarray
    fixed: np.ndarray
    band_area_m2: float


def build_system(mesh: CaseMesh, geom: Geometry, materials: Mapping[int, object], load_distribution: str = "band") -> CaseSystem:
    """Discretise (P2P1), assemble the linear operator and the loads of one case.

    load_distribution: :data:`LOAD_DISTRIBUTIONS` (``band_area_m2`` is then the slice's volume for "slice")."""
    sk = skfem_mesh(mesh.points, mesh.tets)
    d = discretise(sk, "P2P1")
    lam, mu, rho = element_materials(mesh.label, materials)
    K = assemble(d, lam, mu)
    unit, area = lateral_load(d, sk, geom, mesh.case, load_distribution)
    return CaseSystem(mesh.case, mesh, d, lam, mu, rho, K, gravity_load(d, rho), unit, fixed_bottom_dofs(d), area)


# ------------------------------------------------------------------------------------- solves
def _solve_accurately(K_free: sp.csr_matrix, rhs: np.ndarray, what: str) -> tuple[np.ndarray, dict]:
    """Solve K_free X = rhs (n, k) with a direct factorisation plus iterative refinement.

    Returns (X, report). The report has, per column, the relative residual ||r|| / ||b|| and the
    componentwise backward error max_i |r_i| / (|K| |x| + |b|)_i [Higham2002]_ (sec. 7.2). With
    steel on PDMS (contrast 4e5) the relative residual cannot fall below ~1e-8: the steel rows
    of K x cancel terms 4e5 times larger than the PDMS ones (the block moves almost rigidly), so
    their rounding alone is that large; the backward error, which weighs each row by its own
    terms, shows whether the solve is as accurate as the data allow. Raises :class:`MlsimError`
    when the backward error stays above :data:`LINEAR_BACKWARD_ERROR` or the relative residual
    above 1e-6.

    .. [Higham2002] N. J. Higham, "Accuracy and Stability of Numerical Algorithms", 2nd ed., SIAM (2002).
    """
    from fem.linsolve import factorise

    lu = factorise(K_free, definite=False)
    X = lu.solve(rhs)
    absK = abs(K_free)
    norm = np.maximum(np.linalg.norm(rhs, axis=0), 1e-300)

    def measures(X):
        R = rhs - K_free @ X
        scale = np.maximum(absK @ np.abs(X) + np.abs(rhs), 1e-300)
        return R, np.linalg.norm(R, axis=0) / norm, np.max(np.abs(R) / scale, axis=0)

    R, res, berr = measures(X)
    steps = 0
    while steps < 5 and np.any(berr > 0.01 * LINEAR_BACKWARD_ERROR):
        X = X + lu.solve(R)
        R, res, berr = measures(X)
        steps += 1
    if not np.all(np.isfinite(X)) or np.any(berr > LINEAR_BACKWARD_ERROR) or np.any(res > 1e-6):
        raise MlsimError(
            f"{what}: the linear solve reached a backward error of {berr.max():.2e} and a relative residual of "
            f"{res.max():.2e} only (needed {LINEAR_BACKWARD_ERROR:g} and 1e-6)"
        )
    return X, {"relative_residual": res.tolist(), "backward_error": berr.tolist(), "refinement_steps": steps}


def solve_linear_tier(s: CaseSystem, forces_n) -> tuple[np.ndarray, dict]:
    """Small-strain states (K, n) at each force, and a report.

    With gravity on, the response is affine in F: x(F) = x_gravity + F x_unit, each solved once
    with one factorisation. The report has the residuals of the two solves (:func:`_solve_accurately`).
    """
    n = s.d.n_dofs
    free = np.setdiff1d(np.arange(n), s.fixed)
    K_free = s.matrix[free][:, free].tocsr()
    rhs = np.stack([s.gravity[free], s.unit_force[free]], axis=1)
    X, rep = _solve_accurately(K_free, rhs, f"{s.case} (linear)")
    base, unit = np.zeros(n), np.zeros(n)
    base[free], unit[free] = X[:, 0], X[:, 1]
    states = base[None, :] + np.asarray(forces_n, dtype=float)[:, None] * unit[None, :]
    return states, {
        "relative_residual": dict(zip(("gravity", "unit_force"), rep["relative_residual"])),
        "backward_error": dict(zip(("gravity", "unit_force"), rep["backward_error"])),
        "refinement_steps": rep["refinement_steps"],
    }


def _load_path(
    s: CaseSystem,
    x0: np.ndarray,
    external: Callable[[float], np.ndarray],
    lam0: float,
    lam1: float,
    first_step: float,
    min_step: float,
    case: str,
    max_iterations: int = NONLINEAR_MAX_ITERATIONS,
    history: list | None = None,
    max_step: float | None = None,
    log: Callable[[str], None] = lambda m: None,
    past_range: Callable[[np.ndarray], bool] | None = None,
) -> tuple[np.ndarray, dict]:
    """Continue the equilibrium in the load parameter from lam0 (state x0) to lam1 (external(lam)
    -> (n,)), in steps starting at ``first_step``, halved on failure down to ``min_step`` (then
    :class:`fem.nonlinear.SolverError`, whose ``load_factor_reached`` is the last converged
    fraction of the way), grown by 1.5 after an easy step up to ``max_step``. A step that fails from
    a state ``past_range`` says is outside the material's range (torn) ends the path there once the
    step would fall below ``first_step`` / 2^:data:`PAST_RANGE_HALVINGS`: creeping on into a torn solid
    costs minutes and answers nothing physical (the S2 slide crept from 4 N to 4.07 N in 30 minutes).

    Predictor: the secant through the last two converged states (``history``, a list of (lam, x)
    shared by successive calls: the path is continued across the forces), which follows a body
    that tilts or bends over far better than starting Newton from the last state; a predicted
    state that inverts an element is replaced by the last state. Report: increments, Newton
    iterations, cuts, the smallest step taken."""
    from fem.nonlinear import SolverError

    newton = FullStepNewton(s.d, s.lam, s.mu, s.fixed, max_iterations=max_iterations)
    history = [] if history is None else history
    max_step = abs(lam1 - lam0) if max_step is None else max_step
    x, lam, step = x0.copy(), lam0, min(first_step, max_step)
    report = {"increments": 0, "newton_iterations": 0, "cuts": 0, "smallest_step": None}
    while lam < lam1 - 1e-12 * max(1.0, abs(lam1)):
        lam_next = min(lam1, lam + step)
        if lam1 - lam_next < 0.25 * step:  # no sliver of a last step
            lam_next = lam1
        guess = x
        if history and history[-1][0] == lam and len(history) >= 2:
            (l0, x_a), (l1, x_b) = history[-2], history[-1]
            guess = x_b + (lam_next - l1) / (l1 - l0) * (x_b - x_a)
        ok, trial, its, why = newton.solve(guess, external(lam_next))
        if not ok and guess is not x:  # the predictor overshot (or inverted an element): plain start
            report["newton_iterations"] += its
            ok, trial, its, why = newton.solve(x, external(lam_next))
        report["newton_iterations"] += its
        if ok:
            done = lam_next - lam
            x, lam = trial, lam_next
            history.append((lam, x))
            del history[:-2]
            report["increments"] += 1
            report["smallest_step"] = done if report["smallest_step"] is None else min(report["smallest_step"], done)
            if its <= 5:  # an easy increment: take a longer one next
                step = min(1.5 * step, max_step)
            continue
        report["cuts"] += 1
        log(f"verify_s2: {case}: step {lam:.4g} -> {lam_next:.4g} failed ({why}); halving")
        step = 0.5 * (lam_next - lam)
        if past_range is not None and step < first_step / 2**PAST_RANGE_HALVINGS and past_range(x):
            exc = SolverError(f"{case}: the step {lam:.4g} -> {lam_next:.4g} failed ({why}), from a state outside the material's range")
            exc.load_factor_reached = (lam - lam0) / (lam1 - lam0)
            raise exc
        if step < min_step:
            exc = SolverError(f"{case}: Newton did not converge at load {lam_next:.4g} (step {lam_next - lam:.3g}): {why}")
            exc.load_factor_reached = (lam - lam0) / (lam1 - lam0)
            raise exc
    return x, report


def solve_nonlinear_tier(
    s: CaseSystem,
    forces_n,
    increments: int = NONLINEAR_INCREMENTS,
    log: Callable[[str], None] = lambda m: None,
    max_iterations: int = NONLINEAR_MAX_ITERATIONS,
    min_step_n: float = NONLINEAR_MIN_STEP_N,
    elongation_at_break: float | None = None,
) -> tuple[np.ndarray, list[dict]]:
    """Finite-strain states (K, n) at each force (NaN rows where not converged), and a report per force.

    Mixed neo-Hookean (:mod:`fem.nonlinear`) under dead loads: the lateral force keeps its
    direction (+x) and its traction its distribution over the undeformed band as the body bends or
    tilts, as a pusher or a probe dragged along x applies it (a follower traction would turn with
    the face). Gravity is applied first (one ramp, its own increments), then the force is continued
    from 0 through the forces in increasing order (:func:`_load_path`, a secant predictor across the
    whole path), the first step to each force 1 / ``increments`` of the way, halved on failure down to
    ``min_step_n`` newtons (:class:`fem.nonlinear.FullStepNewton`). A force whose solve fails is recorded as not
    converged with the solver's message, and so is every larger one (its load path passes through
    the failure). Report per force: converged, increments, Newton iterations, cuts, seconds,
    ``min_det_f`` (:func:`min_det_f`); if not converged, the message and (for the force that
    failed) the largest force reached, ``reached_n``. max_iterations: per Newton solve.

    Where the continuation ends, the state it reached is read for a physical limit
    (:func:`physical_limit`): with ``elongation_at_break`` given and the elastomer strained past it
    there, the report says so (``physical_limit``: where, at what force it first tore, how crushed
    the worst element is) instead of leaving a bare solver message: past a torn material no solid
    model answers, and the continuation's failure there is the model's edge, not a defect.
    """
    from fem.nonlinear import SolverError

    forces = np.asarray(forces_n, dtype=float)
    order = np.argsort(forces, kind="stable")
    n = s.d.n_dofs
    s.d.pressure_scale = float(np.max(s.mu))  # the scaling of fem.nonlinear.residual_and_tangent's unknowns
    states = np.full((len(forces), n), np.nan)
    reports: list[dict] = [{} for _ in forces]
    failed = None
    t0 = time.perf_counter()
    try:  # gravity alone (a few mN, 3 Newton iterations): the start of the force path; max_iterations is for the forces
        x, rep_g = _load_path(s, np.zeros(n), lambda t: t * s.gravity, 0.0, 1.0, 1.0, 1.0 / 16, f"{s.case} (nonlinear) under gravity")
    except SolverError as exc:
        failed, x, rep_g = 0.0, None, {"message": str(exc)}
    history: list = [(0.0, x)]
    f_prev, pending = 0.0, dict(rep_g)
    torn_at = None  # the first force whose state strains the elastomer past its elongation at break
    stopped_physically = False

    def past_range(x_state):
        return bool(elongation_at_break) and strain_beyond_break(s, x_state, elongation_at_break, finite=True)[1] > 0.0

    for k in order:
        f_k = forces[k]
        if failed is not None:
            why = f"the load path failed on the way to {failed:g} N" if failed > 0 else f"gravity alone did not converge: {rep_g['message']}"
            if failed > 0 and stopped_physically:
                why = f"the path stopped at a physical limit on the way to {failed:g} N (the elastomer tore)"
            reports[k] = {"converged": False, "message": f"not attempted: {why}"}
            continue
        if f_k == f_prev and f_prev > 0:  # a repeated force: the same state
            states[k], reports[k] = x, dict(reports[order[list(order).index(k) - 1]])
            continue
        t0 = time.perf_counter() if f_prev > 0 else t0
        span = f_k - f_prev
        try:
            x_new, rep = _load_path(
                s, x, lambda f: s.gravity + f * s.unit_force, f_prev, f_k, span / increments, min(min_step_n, span / increments),
                f"{s.case} (nonlinear) at {f_k:g} N", max_iterations, history, max_step=max(span / 2, f_prev / 2), log=log,
                past_range=past_range,
            )
        except SolverError as exc:
            failed = f_k
            reached = f_prev + getattr(exc, "load_factor_reached", 0.0) * span
            reports[k] = {"converged": False, "message": str(exc), "reached_n": reached, "seconds": time.perf_counter() - t0}
            limit = physical_limit(s, history[-1][1], history[-1][0], elongation_at_break, torn_at) if elongation_at_break else None
            if limit is not None:
                reports[k].update(physical_limit=limit, message=f"{limit} (the continuation's last word: {exc})")
                stopped_physically = True
            log(f"verify_s2: {reports[k]['message']}")
            continue
        if pending:  # the gravity ramp's work is reported with the first force
            rep = {**rep, "gravity_newton_iterations": pending["newton_iterations"]}
            pending = {}
        x, f_prev = x_new, f_k
        if elongation_at_break and torn_at is None and strain_beyond_break(s, x, elongation_at_break, finite=True)[1] > 0.0:
            torn_at = f_k
        states[k] = x
        reports[k] = {"converged": True, **rep, "min_det_f": min_det_f(s, x), "seconds": time.perf_counter() - t0}
        log(f"verify_s2: {s.case} (nonlinear) at {f_k:g} N: {rep['increments']} increments, {rep['newton_iterations']} Newton iterations")
    return states, reports


def physical_limit(s: CaseSystem, x: np.ndarray, force_n: float, elongation_at_break: float, torn_at_n: float | None) -> str | None:
    """What stops the elastomer at the state x reached under ``force_n`` newtons, or None if nothing does.

    A state that strains the elastomer (label 0) past its elongation at break (the stretch minus one,
    :func:`principal_strain`) is past the material's range: the sentence names the force, the volume
    past break, the largest strain and where it is, the force at which the path first tore it
    (``torn_at_n``, None: not at any of the requested forces) and the smallest det F and where (an
    element crushed at the bonded edge, the next to invert). Points are in mm, slab coordinates."""
    eps = principal_strain(s, x, finite=True)
    elastomer = (s.mesh.label == 0)[:, None] & np.ones_like(eps, dtype=bool)
    beyond = np.asarray(s.d.u.dx)[elastomer.reshape(eps.shape) & (eps > elongation_at_break)].sum() * 1e9
    if beyond <= 0.0:
        return None
    where = np.asarray(s.d.u.mapping.F(s.d.u.quadrature[0])) * 1e3  # (3, T, Q) mm
    e_at = np.unravel_index(np.argmax(np.where(elastomer, eps, -np.inf)), eps.shape)
    J = np.linalg.det(_displacement_gradient(s, x) + np.eye(3))
    j_at = np.unravel_index(np.argmin(J), J.shape)
    first = f"first at {torn_at_n:g} N" if torn_at_n is not None else "already at the first force on the path"
    return (f"{s.case} stops at a physical limit near {force_n:.3g} N: the elastomer is strained past its elongation at break "
            f"({elongation_at_break:.1%}) over {beyond:.3g} mm^3 ({first}), its largest principal strain {eps[e_at]:.0%} at "
            f"({', '.join(f'{c:.2f}' for c in where[:, e_at[0], e_at[1]])}) mm, and an element crushed to det F = {J[j_at]:.2g} at "
            f"({', '.join(f'{c:.2f}' for c in where[:, j_at[0], j_at[1]])}) mm: the material would have torn before this force")


def _displacement_gradient(s: CaseSystem, x: np.ndarray) -> np.ndarray:
    """(T, Q, 3, 3) grad u at every quadrature point of a state x (n,)."""
    return np.moveaxis(np.asarray(s.d.u.interpolate(x[: s.d.n_u]).grad), (0, 1), (-2, -1))


def min_det_f(s: CaseSystem, x: np.ndarray) -> float:
    """The smallest det F = det(I + grad u) over all quadrature points of a state x (n,)."""
    return float(np.linalg.det(_displacement_gradient(s, x) + np.eye(3)).min())


# ------------------------------------------------------------------------------------ outputs
def profile_points(spec, geom: Geometry) -> np.ndarray:
    """(3, N) m: the slab's top (z = thickness) at y = centre, x over ``profile_x_mm`` (slab coordinates)."""
    x = np.linspace(*spec.profile_x_mm, spec.profile_points) * 1e-3
    return np.stack([x, np.full_like(x, geom.centre_m[1]), np.full_like(x, geom.top_m)])


def measure_points(geom: Geometry, case: str, measure: str, spec=None, per_side: int = 17) -> np.ndarray:
    """(3, N) m: where ``measure`` (:data:`MEASURES`, not "anywhere") samples the displacement.

    "slab_top": :func:`profile_points` (needs spec); "load_height" / "body_top": an even grid over
    the loaded body's cross-section at :meth:`Geometry.load_z_m` / on its top face (the rod's disc
    inset to 0.95 of its radius: its side is a polygon of chords), so a grid mean is an area mean.
    """
    if measure == "slab_top":
        return profile_points(spec, geom)
    if measure not in ("load_height", "body_top"):
        raise ValueError(f"{measure!r} is not a point-sampled measure; choose one of: slab_top, load_height, body_top")
    cx, cy = geom.centre_m
    z = geom.load_z_m(case) if measure == "load_height" else geom.body_top_m(case)
    if case == "sliding":
        r = 0.95 * geom.rod_radius_m
        a = np.linspace(-r, r, per_side)
        X, Y = np.meshgrid(a, a, indexing="ij")
        keep = np.hypot(X, Y) <= r * (1 + 1e-12)
        X, Y = X[keep], Y[keep]
    else:
        hx, hy = 0.5 * geom.block_m[0], 0.5 * geom.block_m[1]
        X, Y = (v.ravel() for v in np.meshgrid(np.linspace(-hx, hx, per_side), np.linspace(-hy, hy, per_side), indexing="ij"))
    return np.stack([cx + X, cy + Y, np.full(X.shape, z)])


def measure_stats(s: "CaseSystem", states: np.ndarray, geom: Geometry, measure: str, spec=None) -> dict:
    """{"max": (K,), "mean": (K,)} mm: the displacement magnitude's maximum and mean over ``measure``
    (:data:`MEASURES`) for states (K, n); NaN where a state is NaN.

    "anywhere": the maximum over the P2 nodes (vertices and edge midpoints) and the volume mean over
    the whole model (slab and body) by quadrature.
    """
    if measure != "anywhere":
        mag = np.linalg.norm(sample_displacement(s, states, measure_points(geom, s.case, measure, spec)), axis=1) * 1e3
        return {"max": mag.max(axis=1), "mean": mag.mean(axis=1)}
    nodes = np.concatenate([s.d.u.nodal_dofs, s.d.u.edge_dofs], axis=1)  # (3, P2 nodes)
    volume = float(Functional(lambda w: 1.0 + 0.0 * w.x[0]).assemble(s.d.u))
    out = {"max": np.full(len(states), np.nan), "mean": np.full(len(states), np.nan)}
    for k, x in enumerate(states):
        if not np.all(np.isfinite(x)):
            continue
        out["max"][k] = np.linalg.norm(x[nodes], axis=0).max() * 1e3
        out["mean"][k] = float(Functional(lambda w: np.sqrt(np.einsum("i...,i...", w.u, w.u))).assemble(s.d.u, u=s.d.u.interpolate(x[: s.d.n_u]))) / volume * 1e3
    return out


def _nudged_inside(mesh: CaseMesh, points: np.ndarray, tol: float = 1e-8) -> np.ndarray:
    """(3, N) the points moved by ~1e-9 of an element into the tet that contains them.

    scikit-fem's element finder tolerates only machine epsilon in reference coordinates, and our
    points lie on the slab's top (a boundary, or the rod's interface): a point found in no tet
    would raise. Each point goes to the tet where its smallest barycentric coordinate is largest;
    more than ``tol`` outside every tet is an error (the point is not in the body).
    """
    from fem.mesh import locate_points

    tet, bary = locate_points(mesh.points, mesh.tets, points.T, k=32, exhaustive_below=tol)
    bad = bary.min(axis=1) < -tol
    if bad.any():
        raise MlsimError(f"profile point {points.T[np.argmax(bad)] * 1e3} mm lies outside the mesh of {mesh.case}")
    b = np.clip(bary, 0.0, None)
    b = (1.0 - 1e-9) * b / b.sum(axis=1, keepdims=True) + 1e-9 / 4.0
    return np.einsum("nk,nkd->dn", b, mesh.points[mesh.tets[tet]])


def sample_displacement(s: CaseSystem, states: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Displacement (K, 3, N) m at points (3, N) for states (K, n) (NaN rows stay NaN)."""
    probe = s.d.u.probes(_nudged_inside(s.mesh, points)).tocsr()  # (3 N, n_u), component-major rows
    u = np.stack([probe @ np.nan_to_num(x[: s.d.n_u]) for x in states])
    u = u.reshape(len(states), 3, points.shape[1])
    u[~np.all(np.isfinite(states), axis=1)] = np.nan
    return u


def reactions(s: CaseSystem, x: np.ndarray, external: np.ndarray) -> np.ndarray:
    """(3,) N: the resultant of the reactions at the fixed DOFs of a linear state, (K x - f) summed per component."""
    r = (s.matrix @ x - external)[: s.d.n_u]
    comp = dof_components(s.d.u)
    return np.array([r[s.fixed][comp[s.fixed] == c].sum() for c in range(3)])


def strain_magnitude(s: CaseSystem, x: np.ndarray) -> np.ndarray:
    """(T,) the largest Frobenius norm of the small strain over each element's quadrature points."""
    g = _displacement_gradient(s, x)
    eps = 0.5 * (g + np.swapaxes(g, -1, -2))
    return np.sqrt(np.einsum("tqij,tqij->tq", eps, eps)).max(axis=1)


def principal_strain(s: CaseSystem, x: np.ndarray, finite: bool) -> np.ndarray:
    """(T, Q) the largest principal strain at every quadrature point of a state x (n,).

    finite: the largest principal stretch minus one, sqrt(max eig(C)) - 1 with C = F^T F: the
    engineering strain that an elongation at break is measured in (a uniaxial test's elongation is
    the stretch minus one). Otherwise the largest eigenvalue of the small strain, which is the linear
    tier's estimate of the same number (equal to first order in the displacement gradient).
    """
    g = _displacement_gradient(s, x)
    if finite:
        F = g + np.eye(3)
        return np.sqrt(np.linalg.eigvalsh(np.swapaxes(F, -1, -2) @ F)[..., -1]) - 1.0
    return np.linalg.eigvalsh(0.5 * (g + np.swapaxes(g, -1, -2)))[..., -1]


def strain_beyond_break(s: CaseSystem, x: np.ndarray, elongation_at_break: float, finite: bool, label: int = 0) -> tuple[float, float]:
    """(largest principal strain, volume in mm^3 strained beyond ``elongation_at_break``) over the
    elements of ``label`` (0: the elastomer) of a state x (n,); see :func:`principal_strain`.

    The volume is the quadrature measure of the points beyond the limit. Unlike the largest strain,
    which is singular at the bonded sharp edges (the rod's rim, the block's edges: it grows as the
    mesh is refined), that volume converges with the mesh: it says how much elastomer the load tears.
    """
    eps = principal_strain(s, x, finite)[s.mesh.label == label]
    dx = np.asarray(s.d.u.dx)[s.mesh.label == label]
    return float(eps.max()), float(dx[eps > elongation_at_break].sum() * 1e9)


@dataclass(eq=False)
class VerifyS2Result:
    """Everything the study computed (:func:`mlsim.studies.verify_s2.run`).

    forces_n: (K,); x_slab_mm, x_spec_mm: (N,) profile abscissae; displacement_mm[(tier, case)]:
    (K, 3, N) (ux, uy, uz; NaN where not converged); converged[(tier, case)]: (K,) bool;
    mesh[case], linear[case]: reports; nonlinear[case]: a report per force; checks: derived numbers
    (linearity, block rigidity); seconds: wall time per stage; messages: what went wrong, if anything;
    material_range[(tier, case)]: the elastomer's largest principal strain and the volume strained
    beyond its elongation at break, per force (:func:`strain_beyond_break`).
    """

    spec: object
    forces_n: np.ndarray
    x_slab_mm: np.ndarray
    x_spec_mm: np.ndarray
    displacement_mm: dict = field(default_factory=dict)
    measured_mm: dict = field(default_factory=dict)  # (tier, case) -> {"max": (K,), "mean": (K,)} over reading.measure
    converged: dict = field(default_factory=dict)
    mesh: dict = field(default_factory=dict)
    linear: dict = field(default_factory=dict)
    nonlinear: dict = field(default_factory=dict)
    checks: dict = field(default_factory=dict)
    seconds: dict = field(default_factory=dict)
    messages: list = field(default_factory=list)
    reading: Reading = field(default_factory=lambda: Reading(measure="slab_top"))
    # (tier, case) -> {"max_principal_strain": (K,), "volume_beyond_break_mm3": (K,)} over the elastomer
    material_range: dict = field(default_factory=dict)
    elongation_at_break: float | None = None  # of the elastomer (slab_material); None when unknown

    def within_break(self, tier: str) -> np.ndarray:
        """(K,) bool: neither case strains any elastomer beyond its elongation at break at this force
        (all True when the elongation at break is unknown; False where a state did not converge)."""
        ok = np.ones(len(self.forces_n), dtype=bool)
        for case in CASES:
            rng = self.material_range.get((tier, case))
            if rng is not None:
                ok &= np.asarray(rng["volume_beyond_break_mm3"]) == 0.0
        return ok

    @property
    def tiers(self) -> tuple[str, ...]:
        return tuple(t for t in TIERS if (t, CASES[0]) in self.displacement_mm)

    def magnitude_mm(self, tier: str, case: str) -> np.ndarray:
        """(K, N) displacement magnitude along the profile."""
        return np.linalg.norm(self.displacement_mm[(tier, case)], axis=1)

    def measured(self, tier: str, case: str, stat: str = "max") -> np.ndarray:
        """(K,) mm: the max (``stat="max"``) or mean displacement magnitude over the reading's measure
        (the slab's top profile where ``measured_mm`` has no entry)."""
        if (tier, case) in self.measured_mm:
            return np.asarray(self.measured_mm[(tier, case)][stat])
        reduce = np.max if stat == "max" else np.mean
        return reduce(self.magnitude_mm(tier, case), axis=1)

    def ratio(self, tier: str, stat: str = "max") -> np.ndarray:
        """(K,) sliding over pressing of the measured max (``stat="max"``) or mean displacement magnitude."""
        return self.measured(tier, "sliding", stat) / self.measured(tier, "pressing", stat)


def materials_by_label(spec, materials: Mapping[str, object] | None) -> dict[int, object]:
    """{0: the slab's material, 1: the block's} from ``spec.slab_material`` and ``spec.block_material``,
    looked up in ``materials`` (default: the shipped table); an unknown name lists the known ones."""
    from mlsim.materials import SHIPPED_MATERIALS

    table = SHIPPED_MATERIALS if materials is None else materials
    out = {}
    for label, field_name in ((0, "slab_material"), (1, "block_material")):
        name = getattr(spec, field_name)
        if name not in table:
            raise MlsimError(f"verify_s2.{field_name} = {name!r}: unknown material; choose one of: {', '.join(sorted(table))}")
        out[label] = table[name]
    return out


def nonlinear_edge_length_mm(spec) -> float:
    """The nonlinear tier's mesh size: ``spec.nonlinear_edge_length_mm`` where the schema has it
    and it is set, else :data:`NONLINEAR_EDGE_MM` (coarser than the linear tier's: see there)."""
    value = getattr(spec, "nonlinear_edge_length_mm", None)
    return NONLINEAR_EDGE_MM if value is None else float(value)
