"""What the solve tiers share (:mod:`fem.quasistatic`'s linear and reduced tiers and
:mod:`fem.finite_strain`'s nonlinear tier): the settings of a solve, the layers' materials, the
linear elastic body, the indenter's set-up and path, and the :class:`Episode` every tier returns."""

from __future__ import annotations

import functools
import json
import time
from dataclasses import dataclass, field

import numpy as np
import skfem
from skfem import LinearForm

from fem import elasticity, fields, trajectory
from fem.indenters import IndenterShape, Pose, shape_from_scene
from fem.indenters import gap as indenter_gap
from fem.nonlinear import SolverError

__all__ = ["GRAVITY_M_S2", "STEP_CAP", "CONTACT_MAX_ITERATIONS", "SMOOTHING", "SolveSettings", "layer_materials", "LinearBody", "Episode", "path_points", "tip_height_m", "ContactSetup"]

GRAVITY_M_S2 = 9.80665
# The contact Newton (fem.condensed._newton_points): its trust region in edge lengths, and the
# iterations after which a step is halved instead (measured on the demo load: 50 iterations cost
# 636 Newton iterations in all, 200 cost 1016, 30 cost 745; a step that has not converged by then
# is usually cycling between stick and slip, which a half step resolves)
STEP_CAP = 0.25
CONTACT_MAX_ITERATIONS = 50
# The Newton solvers' smoothing length of the penalty, in edge lengths. It must be far below the
# penetration of the smallest load of interest: at 1e-4 h (0.25 um on the tiny mesh) a 5 um press
# carried 15 % more force than the exact penalty law (the smoothed law pushes at positive gaps), and
# the nonlinear tier did not agree with the ADMM linear tier at small loads; at 1e-7 h they agree
# to 0.02 % and the nonlinear Newton still converges in 6-7 iterations per step.
SMOOTHING = 1e-7


@dataclass(frozen=True)
class SolveSettings:
    """Numerical choices of a solve (from the scene's ``fidelity.solve``)."""

    tier: str = "linear"  # "reduced" | "linear"
    element: str = "P2P1"  # "P1" | "P2" | "P2P1"
    substeps: int = 1
    contact_band_m: float = 2.0e-3  # rod side faces this far below the tips can be touched
    penalty_factor: float = 100.0  # eps_n = eps_t = factor * E_contact / h
    patches_per_tip: int = 7
    patches_per_side: int = 8
    gravity: bool = True
    backend: str = "auto"
    path_margin_m: float = 1.0e-3  # linear tier: contact points within this of the swept indenter
    small_strain_limit: float = 0.5  # refuse a step where a contact point moves more than this x rod height
    buckling_limit: float = 0.5  # second-order kinematics: refuse a rod's axial load beyond this x its Euler load
    contact_solver: str = "admm"  # "admm" (fem.contact_admm) | "newton" (fem.condensed._newton_points)
    contact_max_iterations: int = 200  # ADMM iterations per linearisation
    nonlinear_newton: str = "condensed"  # the nonlinear tier's step solver: "condensed" | "penalty" (fem.finite_strain)
    rod_kinematics: str = "first_order"  # "first_order" | "second_order" | "cosserat" (fem.rod_kinematics, fem.rod_exact; admm only)
    rod_coupling: str = "dead"  # cosserat: "dead" | "held" (the rods held by the contact in their solves, fem.rod_exact)
    dynamics: str = "quasi_static"  # nonlinear tier: "quasi_static" | "backward_euler" (fem.dynamics)
    loss_factor: float = 0.1  # dynamics: damping ratio loss_factor / 2 at the rods' first bending mode
    steps_per_period: float = 4.0  # dynamics: the least steps per period of the rods' first bending mode

    @classmethod
    def from_scene(cls, scene) -> "SolveSettings":
        f = scene.fidelity.solve
        nu_max = max(scene.material(r).poisson_ratio.value for r in ("core", "ml_layer", "absorber"))
        if f.element_order == 1:
            element = "P1"
        else:
            element = "P2P1" if (f.formulation == "mixed" or (f.formulation == "auto" and nu_max >= 0.45)) else "P2"
        return cls(tier=f.tier, element=element, substeps=f.substeps, contact_band_m=f.contact_band_mm * 1e-3,
                   penalty_factor=f.penalty_factor, patches_per_tip=f.patches_per_tip, patches_per_side=f.patches_per_side,
                   gravity=f.gravity, small_strain_limit=f.small_strain_limit, buckling_limit=f.buckling_limit, contact_solver=f.contact_solver,
                   contact_max_iterations=f.contact_max_iterations, rod_kinematics=f.rod_kinematics, rod_coupling=f.rod_coupling,
                   nonlinear_newton=f.nonlinear_newton, dynamics=f.dynamics, loss_factor=f.loss_factor,
                   steps_per_period=f.steps_per_period)


def layer_materials(scene):
    """[(lambda, mu), ...] Pa and densities kg/m^3 of the absorber, ML and core layers, and the
    contact layer's Young's modulus (the absorber's, or the ML layer's if there is no absorber)."""
    from fem.materials.linear_elastic import lame_parameters

    lame, rho = [], []
    for region in ("absorber", "ml_layer", "core"):
        mat = scene.material(region)
        lame.append(tuple(float(v) for v in lame_parameters(mat.young_modulus_pa.value, mat.poisson_ratio.value)))
        rho.append(float(mat.density_kg_m3.value or 0.0))
    outer = "absorber" if scene.sensor.layers.absorber_mm > 0 else "ml_layer"
    return lame, rho, float(scene.material(outer).young_modulus_pa.value)


@LinearForm
def _gravity_form(v, w):
    return -w.rho * GRAVITY_M_S2 * v[2]


class LinearBody:
    """The assembled and factorised linear elastic sensor, base bottom clamped.

    mesh: :class:`fem.mesh.TetMesh`; lame_by_layer: three (lambda, mu) Pa (absorber, ML, core);
    density_by_layer: three kg/m^3 (gravity acts along -z when ``gravity``).
    """

    def __init__(self, mesh, lame_by_layer, density_by_layer, element: str = "P2P1", gravity: bool = True, backend: str = "auto", log=None,
                 factorise: bool = True):
        from fem.geometry import FaceTag
        from fem.linsolve import factorise as factorise_matrix

        t0 = time.perf_counter()
        self.mesh = mesh
        self.element = element
        curved = element != "P1"
        self.skmesh = elasticity.skfem_mesh(mesh.points, mesh.tets, mesh.edge_nodes if curved else None, mesh.tet_edges if curved else None)
        self.d = elasticity.discretise(self.skmesh, element)
        self.lam, self.mu = elasticity.element_lame(mesh.layer_fraction, lame_by_layer)
        self.rho = mesh.layer_fraction @ np.asarray(density_by_layer, dtype=float)
        self.K = elasticity.assemble(self.d, self.lam, self.mu)
        bottom = elasticity.facet_indices(self.skmesh, mesh.faces[mesh.face_tag == FaceTag.BASE_BOTTOM])
        self.fixed = np.unique(self.d.u.get_dofs(facets=bottom).all())
        self.free = np.setdiff1d(np.arange(self.d.n_dofs), self.fixed)
        self.seconds = {"assemble": time.perf_counter() - t0}
        t0 = time.perf_counter()
        self.factor = factorise_matrix(self.K[self.free][:, self.free], definite=self.d.p is None, backend=backend) if factorise else None
        self.seconds["factorise"] = time.perf_counter() - t0
        self.S = fields.stress_operator(self.d, self.lam, self.mu)
        self.f_gravity = np.zeros(self.d.n_dofs)
        if gravity:
            self.f_gravity[: self.d.n_u] = skfem.asm(_gravity_form, self.d.u, rho=elasticity._per_qp(self.rho, self.d.u))
        # vertex DOFs (for displacements at the mesh's vertices)
        self.vertex_dofs = self.d.u.nodal_dofs.T.copy()  # (P, 3)

    @property
    def n_dofs(self) -> int:
        return self.d.n_dofs

    @functools.cached_property
    def x_gravity(self) -> np.ndarray:
        """(n,) the state under gravity alone (zero without gravity)."""
        return self.solve(self.f_gravity)

    def weight_n(self) -> np.ndarray:
        """(3,) N the body's weight: the resultant of the gravity load."""
        comp = elasticity.dof_components(self.d.u)
        return np.bincount(comp, weights=self.f_gravity[: self.d.n_u], minlength=3)

    def solve(self, F: np.ndarray) -> np.ndarray:
        """K x = F with the base clamped: F (n,) or (n, k) -> x, same shape."""
        X = np.zeros_like(F, dtype=float)
        X[self.free] = self.factor.solve(F[self.free])
        return X

    def stress(self, X: np.ndarray) -> np.ndarray:
        """Centroid stress (6, T) Pa (or (k, 6, T) for X (n, k))."""
        T = self.mesh.n_tets
        s = self.S @ X
        return s.reshape(6, T) if X.ndim == 1 else s.T.reshape(-1, 6, T)

    def reaction(self, X: np.ndarray, F: np.ndarray) -> np.ndarray:
        """Force (3,) N (or (k, 3)) that the clamp exerts on the body: sum over fixed DOFs of K x - F."""
        r = (self.K @ X - F)[self.fixed]
        comp = elasticity.dof_components(self.d.u)[self.fixed]
        if X.ndim == 1:
            return np.array([r[comp == c].sum() for c in range(3)])
        return np.stack([r[comp == c].sum(axis=0) for c in range(3)], axis=-1)


@dataclass
class Episode:
    """Results at every solve step (frames are the steps ``frame_step``). Units: SI.

    The episode carries its mesh (vertices, tets, rod index and layer fractions per tet), so a saved
    episode is self-contained. Per step: t_s (S,), indenter pose (S, 4) x, y, z m and yaw rad, force target (S,) N (NaN under
    displacement control); stress (S, 6, T) Pa float32, von_mises (S, T), sed (S, T) J/m^3;
    vertex displacement (S, P, 3) m float32; contact force on the body per rod (S, R, 3) N and in
    total (S, 3), normal force (S,) N, reaction at the base (S, 3) N, contact iterations (S,).
    """

    tier: str
    element: str
    t_s: np.ndarray
    frame_step: np.ndarray
    pose: np.ndarray
    force_target_n: np.ndarray
    stress: np.ndarray
    von_mises: np.ndarray
    sed: np.ndarray
    displacement: np.ndarray
    rod_force_n: np.ndarray
    contact_force_n: np.ndarray
    normal_force_n: np.ndarray
    reaction_n: np.ndarray
    iterations: np.ndarray
    stick_fraction: np.ndarray
    mesh_points: np.ndarray  # (P, 3) m: the vertices the displacement is given at
    mesh_tets: np.ndarray  # (T, 4): the tets the stress is given on (the linear mesh)
    tet_rod: np.ndarray  # (T,) rod index, -1 for the base
    layer_fraction: np.ndarray  # (T, 3) absorber, ML, core
    seconds: dict = field(default_factory=dict)

    @property
    def n_frames(self) -> int:
        return len(self.frame_step)

    def rod_peaks(self) -> dict[str, list[float]]:
        """Per rod, over all steps: peak von Mises stress in the whole rod and in its ML layer (tets
        with an ML fraction of at least one half) in kPa, peak normal (-z) and total contact force in N."""
        R = self.rod_force_n.shape[1]
        vm_peak = self.von_mises.max(axis=0)  # (T,)
        ml = self.layer_fraction[:, 1] >= 0.5
        out: dict[str, list[float]] = {"von_mises_kpa": [], "ml_von_mises_kpa": [], "normal_force_n": [], "contact_force_n": []}
        for r in range(R):
            on = self.tet_rod == r
            out["von_mises_kpa"].append(float(vm_peak[on].max() / 1e3) if on.any() else 0.0)
            out["ml_von_mises_kpa"].append(float(vm_peak[on & ml].max() / 1e3) if (on & ml).any() else 0.0)
        out["normal_force_n"] = [float(v) for v in np.maximum(-self.rod_force_n[:, :, 2].min(axis=0), 0.0)]
        out["contact_force_n"] = [float(v) for v in np.linalg.norm(self.rod_force_n, axis=2).max(axis=0)]
        return out

    def summary(self) -> dict:
        """Headline numbers of the episode for a run's JSON summary (units in the keys)."""
        return {
            "tier": self.tier,
            "element": self.element,
            "n_frames": self.n_frames,
            "n_steps": len(self.t_s),
            "per_frame_ms": self.seconds.get("per_frame_ms"),
            "precompute_s": self.seconds.get("precompute"),
            "peak_normal_force_n": float(self.normal_force_n.max()),
            "peak_von_mises_kpa": float(self.von_mises.max() / 1e3),
            "max_displacement_mm": float(np.linalg.norm(self.displacement, axis=2).max() * 1e3),
            "contact_iterations": {"total": int(self.iterations.sum()), "max_per_step": int(self.iterations.max())},
            "contact_worst_residual_n": self.seconds.get("contact_worst_residual_n"),  # ADMM: the largest force residual left
            # linear tiers: how far the rods bend, and the per-rod contact force error that implies (fem.quasistatic)
            "rod_bending_ratio": self.seconds.get("rod_bending_ratio"),
            "geometric_error_estimate": self.seconds.get("geometric_error_estimate"),
            # Cosserat rods: the bent rods let go, [step, mesh rod], where that estimate does not hold (fem.rod_exact)
            "geometric_error_releases": self.seconds.get("geometric_error_releases"),
            # and the rods dragged over near buckling, [first step, mesh rod], where it does not hold either (fem.rod_error.BENT_AXIAL)
            "geometric_error_bent": self.seconds.get("geometric_error_bent"),
            "per_rod_peak": self.rod_peaks(),
        }

    def frames(self, name: str) -> np.ndarray:
        """A per-step array at the frames only."""
        return getattr(self, name)[self.frame_step]

    def rate(self, name: str) -> np.ndarray:
        """Backward-difference rate per second of a per-step array, at the frames (frame 0: zero)."""
        a = getattr(self, name).astype(np.float64)
        out = np.zeros((self.n_frames,) + a.shape[1:])
        k = self.frame_step
        dt = np.diff(self.t_s)
        for i, s in enumerate(k):
            if s > 0:
                out[i] = (a[s] - a[s - 1]) / dt[s - 1]
        return out

    def save(self, path) -> None:
        np.savez_compressed(path, tier=self.tier, element=self.element, seconds_json=json.dumps(self.seconds),
                            **{k: getattr(self, k) for k in _EPISODE_ARRAYS})

    @classmethod
    def load(cls, path) -> "Episode":
        with np.load(path) as z:
            kw = {k: z[k] for k in _EPISODE_ARRAYS}
            return cls(tier=str(z["tier"]), element=str(z["element"]), seconds=json.loads(str(z["seconds_json"])), **kw)


_EPISODE_ARRAYS = ("t_s", "frame_step", "pose", "force_target_n", "stress", "von_mises", "sed", "displacement", "rod_force_n",
                   "contact_force_n", "normal_force_n", "reaction_n", "iterations", "stick_fraction", "mesh_points", "mesh_tets",
                   "tet_rod", "layer_fraction")


def path_points(X: np.ndarray, shape: IndenterShape, load, grid: trajectory.TimeGrid, tip_z: float, margin_m: float) -> np.ndarray:
    """Indices of the contact points X (m, 3) within ``margin_m`` of the indenter anywhere on its path.

    The indenter's height under force control is not known before the solve, so every pose is
    taken as low as the deepest displacement-controlled press or, under force control, 3 mm below
    the tips (rod tips under a force press seldom move further)."""
    state = trajectory.initial_state(load, tip_z)
    depth = sum(s.depth_mm for s in load.segments if s.kind == "press" and s.depth_mm is not None) * 1e-3
    low = tip_z - max(depth - load.start_gap_mm * 1e-3, 0.0) - (3e-3 if any(s.kind == "press" and s.force_n is not None for s in load.segments) else 0.0)
    near = np.zeros(len(X), dtype=bool)
    for t in grid.step_times_s:
        state = trajectory.advance(load, state, t)
        x, y, _ = state.position_m
        near |= indenter_gap(shape, Pose((x, y, low), state.yaw_rad), X) < margin_m
    return np.flatnonzero(near)


def tip_height_m(mesh) -> float:
    """Height (m) of the rod tips: the highest vertex of the faces tagged ROD_TIP."""
    from fem.geometry import FaceTag

    return float(mesh.points[mesh.faces[mesh.face_tag == FaceTag.ROD_TIP]][..., 2].max())


@dataclass(frozen=True)
class ContactSetup:
    """What every tier's contact solve derives from the scene: the indenter, the time grid, and the
    numerical constants of :func:`fem.condensed.solve_path`, all scaled by the mesh's edge length h."""

    shape: IndenterShape
    tip_z_m: float
    grid: trajectory.TimeGrid
    eps_n_pa_m: float  # penalty per area: penalty_factor * E_contact / h
    smooth_m: float  # the Newton solvers' smoothing of the penalty (fem.condensed._contact_law): 1e-7 h
    max_penetration_m: float  # a deeper converged point halves the step: 0.1 h
    max_jump_m: float  # tunnelling guard: min(h / 2, a quarter of the indenter's smallest size)
    max_step_m: float  # Newton's trust region: STEP_CAP h

    @classmethod
    def from_scene(cls, scene, mesh, settings: SolveSettings, e_contact_pa: float) -> "ContactSetup":
        shape = shape_from_scene(scene.load.indenter)
        h = scene.fidelity.mesh.edge_length_mm * 1e-3
        return cls(shape, tip_height_m(mesh), trajectory.time_grid(scene.load, scene.camera.fps, settings.substeps),
                   settings.penalty_factor * e_contact_pa / h, SMOOTHING * h, 0.1 * h, min(0.5 * h, 0.25 * min(shape.size_m)), STEP_CAP * h)

    def penalties(self, area_m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Normal and tangential penalty stiffnesses (N/m) of points with these areas: one isotropic
        penalty (k_t = k_n) for every tier and solver, so that all tiers solve one contact law and the
        Delassus operator of the ADMM solver (:mod:`fem.contact_admm`) does not depend on the contact
        frames."""
        k = self.eps_n_pa_m * area_m2
        return k, k.copy()

    def solve_kw(self) -> dict:
        """The keyword arguments of :func:`fem.condensed.solve_path` these constants set."""
        return {"smooth_m": self.smooth_m, "max_penetration_m": self.max_penetration_m, "max_jump_m": self.max_jump_m,
                "max_step_m": self.max_step_m}


def _check_finite(ep: Episode) -> None:
    for name in _EPISODE_ARRAYS:
        a = getattr(ep, name)
        if name in ("force_target_n", "stick_fraction", "mesh_tets", "tet_rod"):
            continue  # NaN there means "not force controlled" / "no contact"
        if a.dtype.kind == "f" and not np.all(np.isfinite(a)):
            raise SolverError(f"the {ep.tier} solve produced NaN or Inf in {name}")


def _bar(enabled: bool, total: int, desc: str):
    if not enabled:
        return lambda n: None
    from tqdm import tqdm

    bar = tqdm(total=total, desc=desc, unit="step", leave=False)

    def update(n):
        bar.n = n
        bar.refresh()
        if n >= total:
            bar.close()

    return update
