"""Geometrically exact rod kinematics for the linear tiers (``fidelity.solve.rod_kinematics = "cosserat"``).

The ``linear`` and ``reduced`` tiers solve the sensor as a small-strain, small-rotation body: the
contact points move by u = u_0 + E f (E the body's point compliance). The sensor's rods turn by
tens of degrees while their strains stay at a few per cent (issue 38), so what a linear body misses
is the rods' large rotation: their tips drop and turn, and an axial force on a bent rod adds its
moment (P-delta). :mod:`fem.rod_kinematics` adds the second-order terms of that; this module adds
all of it, by a geometrically exact rod per rod:

    x_k = X_k + u_0,k + (E (f + f_pd))_k + q_k(f),

    q_k(f) = p_k(f) - [X_k + u_r + theta_r x (X_k - X_r) + (G (f + f_pd))_k].

- p_k(f): where point k sits on the rod's discrete Cosserat rod (:mod:`fem.cosserat_rod`: exact for
  any rotation) in equilibrium under the rod's contact forces f (dead), clamped at the root where the
  body puts it: root translation u_r and rotation theta_r are the body's linear response
  (``obs_0 + A f``, the least-squares motion of the rod's root ring of vertices), the root frame
  exp(theta_r) exactly;
- G f: the same rod's linear response (its Hessian at the straight state), and u_r + theta_r x r the
  root's motion to first order: what E f already holds of the rod. The bracket is the Cosserat rod
  linearised; q is the rod's nonlinear part alone, so at small loads the tier is the linear body's,
  whatever the rod model's own small-load error;
- f_pd: the P-delta load, the horizontal force on the rod's loaded points whose moment about the
  root is the difference between the root moment in the bent rod, sum (p_k - x_r) x f_k, and in the
  straight one, sum (X_k - X_r) x f_k. The body carries it, so the base turns under the bent rod's
  true root moment and the stresses hold it; its own rod deflection G f_pd is taken out of q (p_k holds
  the rod's P-delta already).

The rods' section: the layered round section (E A, E I, G J summed over the layers, shear
kappa G A with Cowper's coefficient of the core's Poisson ratio, :func:`layered_section`). It enters
only through q, the nonlinear part, and through the P-delta moment, so its small-load error (against
the rod's 3-D FEM) enters the answer times how nonlinear the step is. Where the mesh's rods are
systematically stiffer or softer sideways than it (beyond their own scatter), its bending and shear
stiffnesses are identified from them (:func:`stiffened`, :func:`fem.rod_error.identified_section_scales`;
fem.quasistatic does it once the contact operator is built): the bending stiffness from their tip compliance to a
couple on the tip face, the shear stiffness from that to a sideways force (the tiny scene's 2.5 mm mesh: 5 % stiffer
sideways; the 2 mm meshes' rods answer a couple about 0.81 of the section's). A flat face that grips the tip guides the
rod, whose deflection is then the difference of the two: with the force's alone the 2 x 4 swipe's rods deflected half the
body's, and the P-delta load with them (docs/stages/solve.md, solve stage 25).

Stresses: the linear body's under f + f_pd, plus in each loaded rod Saint-Venant's recovery of the
difference between the bent rod's section resultants (in the section's own frame) and the linear
body's, through the rod's responses to six unit tip loads (:meth:`CosseratKinematics.stress_correction`).
Exact for a prismatic rod away from the loads; a section's stress is not turned with it (von Mises,
which the emission reads, is invariant under the turn).

The contact loop (:func:`fem.contact_admm.solve_step`) treats q and f_pd as the second-order kinematics'
h: frozen over a linearisation, re-evaluated at its solution. How the rods take the round's forces in
their solves (``fidelity.solve.rod_coupling``):

- ``"dead"`` (the default): as dead loads. A rod past its free Euler load then buckles in its own solve
  whatever holds its tip, and the rounds diverge (the default demo's flat punch, rods at 1.18 x: 2.8 N
  against the reference's 18.4 N; the tiny scene's flat press at about 1 x: 83 % off in force), so a rod past
  ``fidelity.solve.buckling_limit`` x that load is refused in every round (``CosseratKinematics.guard``).
- ``"held"`` (the default demo's): also **held by the contact** (a Robin coupling, :meth:`CosseratKinematics.solve_rods`):
  each touching point carries its round's force f_k and a spring of the contact's penalty to where the round
  put it. At the rounds' fixed point the rods sit there and the springs carry nothing, so the answer is the
  dead-load one; before it, the springs hold what the contact holds, and a rod pressed past its free Euler
  load by a face that grips its tip stands: the tiny scene's flat press at 1 x is 1.4 / 1.5 / 1.6 % off the
  nonlinear tier (rod-base von Mises, force, tip displacement; solve stage 22), and the screw scene 2.8 / 2.3 / 4.8 %
  (photons 2.2 %). The springs' pull enters the linear rod and the P-delta moment as its resultant about the bent rod's
  tip (:meth:`_rod_answers`); the rounds are under-relaxed (``round_relaxation``) to ``round_rtol`` of their residual. On
  the default demo 6.6 / 5.8 / 5.7 % off on one mesh realisation, 11.4 / 4.7 / 21.6 % on another, where after
  the second release step three rods stay bent against the face by friction (the reference lets go; the tip
  within 9 % in the other frames but one, 25 %). Why the rounds need that much damping: their gain grows with
  the contact's penalty (rounds that took one rod Newton step each converged at a tenth of it and diverged at
  the default), the contact pinning the tip face's points against the rods' nonlinear part, which the Delassus
  operator does not see. Putting the rods' dead-load tangent compliance into that operator (tried) is no cure:
  past the free Euler load it is negative, the operator indefinite. The cure is the nonlinear tier's: the rods' nonlinear
  internal forces as loads on the linear body, so one operator carries both (docs/stages/solve.md).

The rods' axial law is neo-Hookean (:data:`AXIAL_LAW`, :func:`fem.cosserat_rod.axial_force`), as the nonlinear
tier's material: the demo's press compresses its rods by about 11 %, where that law is 12.9 % stiffer than the
linear one, and the recovered section stress is Cauchy's (on the current area, x lambda).

Dynamics (``fidelity.solve.dynamics = "backward_euler"``): each rod's solve is its backward Euler step
(:mod:`fem.cosserat_dynamics`: lumped masses, mass-proportional damping at the nonlinear tier's ratio at the first
mode), from the last step's nodes and velocities (:meth:`CosseratKinematics.end_step`); a rod released from the
contact keeps moving and is solved until it rests; the body carries the rods' inertial reaction in the P-delta
load and the roots turn under it; its contact rounds also settle to a tenth of the force each step moved
(``CosseratKinematics.ROUND_STEP_FRACTION``: else the held rods never rest and a hold lights). The base has no inertia. The tiny scene's rods released from a drag ring as the
nonlinear tier's dynamics: 3.3 / 2.7 / 2.0 % over the frames, the tips' history after the release 9.9 %
(tests/test_rod_exact.py).

Its own error estimate (:func:`fem.rod_error.force_error_estimate`, the run log's and ``summary.json``'s
``geometric_error_estimate``): the rods' ends' linear response turned with their tips, the section's mismatch with the
mesh's rod and the rounds' residual, through each rod's secant stiffness; and the releases of bent rods, where it does
not hold (docs/stages/solve.md).

What this is not: a finite-strain body; the base is linear.

About 690 lines: the rods' batched solve, the contact rounds' interface (q, the P-delta load, the hold) and the
fields' corrections (vertices, Saint-Venant's stresses) all read the same per-rod padded points, attachments, unit
responses and answers that :class:`CosseratKinematics` keeps; the error estimate, which only reads them, is
:mod:`fem.rod_error`.
Tiny scene's press and slide against the nonlinear tier (docs/stages/solve.md): 2.8 / 1.5 / 1.5 %
on rod-base von Mises, per-rod force and tip displacement on the tests' shipped mesh (tests/test_rod_exact.py,
solve stage 22; 2.2 / 3.3 / 3.0 % on another mesh realisation of the scene, 3.6 / 5.7 / 5.2 % there before the
section was identified from the mesh's rods).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import scipy.sparse as sp

from fem import cosserat_dynamics as cd
from fem import cosserat_rod as cr
from fem.rod_kinematics import RodSections, _face_rotation_rows, resultant_change

__all__ = ["SEGMENTS", "layered_section", "stiffened", "root_observation", "attachments", "CosseratKinematics"]

#: the rods' axial law: the nonlinear tier's material is neo-Hookean, and the default demo's flat punch
#: compresses the rods by about 11 %, where that law is 12.9 % stiffer than the linear one
AXIAL_LAW = "neo_hookean"

#: segments per rod. Bisshopp and Drucker's cantilever at alpha = 3 is within 0.3 % at 8 segments
#: (second order: 0.07 % at 32, tests/test_cosserat_rod.py), below the tiers' stated errors
SEGMENTS = 8

#: under inertia the rods' roots turn under the loads the body carries (:meth:`CosseratKinematics._rod_answers`), found
#: by a fixed point on those loads, to this fraction of the rods' total resultant, in at most ROOT_ITERATIONS solves
ROOT_RTOL = 1e-3
ROOT_ITERATIONS = 4



def layered_section(radius_m: float, height_m: float, young_pa, poisson, thickness_m, axial_law: str = AXIAL_LAW) -> cr.RodSection:
    """The Cosserat section of a round rod coated by layers (outside in; the last the core):
    E A = sum E_i A_i, E I = sum E_i I_i, G J = sum G_i 2 I_i (each layer's annulus), kappa G A =
    kappa(nu_core) sum G_i A_i with Cowper's shear coefficient of a solid round section of the core's
    Poisson ratio (a simplification: the layered section's own coefficient is not modelled); the axial
    force against the stretch by ``axial_law`` (:class:`fem.cosserat_rod.RodSection`).

    young_pa, poisson (k,); thickness_m (k - 1,) of all but the core."""
    from fem.beam_theory import circular_shear_coefficient

    E = np.asarray(young_pa, dtype=float)
    nu = np.asarray(poisson, dtype=float)
    t = np.asarray(thickness_m, dtype=float)
    if len(t) != len(E) - 1 or len(nu) != len(E) or np.any(t < 0) or np.any(E <= 0) or radius_m <= 0 or height_m <= 0:
        raise ValueError(f"layered_section: radius {radius_m} m, height {height_m} m, moduli {E} Pa, Poisson ratios {nu}, thicknesses {t} m: "
                         "need positive sizes and moduli and one thickness per layer outside the core")
    outer = (radius_m - np.concatenate([[0.0], np.cumsum(t)])).clip(min=0.0)
    inner = np.append(outer[1:], 0.0)
    area = np.pi * (outer**2 - inner**2)
    inertia = 0.25 * np.pi * (outer**4 - inner**4)
    G = E / (2.0 * (1.0 + nu))
    ei = float(np.sum(E * inertia))
    return cr.RodSection(height_m, float(np.sum(E * area)), circular_shear_coefficient(float(nu[-1])) * float(np.sum(G * area)),
                         (ei, ei), float(np.sum(G * 2.0 * inertia)), axial_law)


def stiffened(section: cr.RodSection, bending_scale: float, shear_scale: float | None = None) -> cr.RodSection:
    """``section`` with its bending stiffnesses times ``bending_scale`` and its shear stiffness times ``shear_scale``
    (default: the same; axial and torsion kept): the section identified from the mesh's rods' tip compliances
    (:func:`fem.rod_error.identified_section_scales`)."""
    shear_scale = bending_scale if shear_scale is None else shear_scale
    return dataclasses.replace(section, shear_n=section.shear_n * shear_scale, bending_n_m2=tuple(b * bending_scale for b in section.bending_n_m2))


def root_observation(points: np.ndarray, sections: RodSections, tol: float = 1e-7) -> sp.csr_matrix:
    """O (6 R, 3 P) on vertex displacements (vertex-major): per rod j of ``sections.rods``, the mean
    translation (rows 6 j .. 6 j + 2) and the rotation (rows 6 j + 3 .. 6 j + 5: the plane's tilt and
    twist, :func:`fem.rod_kinematics._face_rotation_rows`) of the rod's vertices on the base's top
    (its root ring)."""
    rows, cols, vals = [], [], []
    for j, verts in enumerate(sections.vertices):
        ring = verts[np.abs(points[verts, 2] - sections.base_z_m) <= tol]
        if len(ring) < 3:
            raise ValueError(f"rod {sections.rods[j]}: {len(ring)} vertices at the base's top z = {sections.base_z_m:.9g} m: "
                             "the mesh has no root ring there")
        for c in range(3):
            rows.append(np.full(len(ring), 6 * j + c))
            cols.append(3 * ring + c)
            vals.append(np.full(len(ring), 1.0 / len(ring)))
        rr, cc, vv = _face_rotation_rows(points, ring)
        rows.append(6 * j + 3 + rr)
        cols.append(cc)
        vals.append(vv)
    R = len(sections.rods)
    return sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(6 * R, 3 * len(points)))


def attachments(X: np.ndarray, centre_xy: np.ndarray, base_z_m: float, length_m: float, segments: int):
    """Where points X (m, 3) m sit on a straight rod along z from (centre_xy, base_z_m): segment (m,),
    the fraction along it (m,) and the offset from the axis (m, 3) m (in the reference frame, the
    segments' frame). Points above the tip (none on a mesh) are put on the tip face."""
    l = length_m / segments
    height = np.clip(X[:, 2] - base_z_m, 0.0, length_m)
    segment = np.minimum((height / l).astype(int), segments - 1)
    along = np.clip(height / l - segment, 0.0, 1.0)
    offset = np.zeros_like(X)
    offset[:, :2] = X[:, :2] - centre_xy
    return segment, along, offset


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (3), broadcast: np.cross's arithmetic without its per-call overhead (the rounds call it
    on small arrays thousands of times an episode)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _rotation_quaternion(theta: np.ndarray) -> np.ndarray:
    """exp(theta) as unit quaternions (..., 4) for rotation vectors theta (..., 3)."""
    angle = np.linalg.norm(theta, axis=-1, keepdims=True)
    half = 0.5 * angle
    # sin(a/2)/a -> 1/2 as a -> 0
    factor = np.where(angle > 1e-12, np.sin(half) / np.where(angle > 1e-12, angle, 1.0), 0.5)
    return np.concatenate([np.cos(half), factor * theta], axis=-1)


class CosseratKinematics:
    """The per-episode operators of the geometrically exact rod kinematics (the interface of
    :class:`fem.rod_kinematics.RodKinematics`, which the contact loop and the tiers call).

    sections: the rods carrying contact points; section: their Cosserat section; A (6 R, 3 m) the root
    observation's response per unit point force and obs_0 (6 R,) its value without contact (gravity),
    both of :func:`root_observation`; X (m, 3) m the contact points; point_rod (m,) their mesh rods (-1:
    the base)."""

    pdelta = True
    #: the contact loop holds the loaded points by its stiffness in the rods' solve (the Robin coupling,
    #: :meth:`solve_rods`; ``fidelity.solve.rod_coupling = "held"``); False: dead loads between rounds (refused
    #: past ``buckling_limit``, the guard). Set per episode by fem.quasistatic
    holds = False
    #: the contact rounds (fem.contact_admm.solve_step) of Cosserat rods: under-relaxed by this factor (Anderson's
    #: rule, second order's, diverged on the default demo's press: the rounds flip points between stick and slip,
    #: and 0.5 cycled between two stick patterns), until the force the last round moved, over this factor (the
    #: fixed point's residual), is round_rtol of the total normal force (second order's 1e-2 left the tiny scene's
    #: flat press 11 % off in tip displacement, 1e-3 1.9 %), in at most MAX_ROUNDS rounds. On one mesh of the
    #: default demo at 0.3 a held rod (13, at 2.3 x its free Euler load) buckled sideways in its solve (tip
    #: displacement 86 % off); at 0.15 none did (21.6 %: within 9 % in all frames but two, 25 % in one and the
    #: last release frame)
    round_relaxation = 0.15
    round_rtol = 1e-3
    #: under the rods' inertia the rounds also settle to this fraction of the force the step moved (summed per rod,
    #: from the last step's), down to ROUND_RTOL_LEAST of the normal force: what a step's rounds leave unsettled the
    #: next step's inertial prediction carries on, so where a step moves little (a hold) a fixed tolerance is noise
    #: the rods keep (an inexact Newton's forcing term relative to the step's change, Eisenstat and Walker, SIAM J.
    #: Sci. Comput. 17, 1996). The tiny scene's rods under the swipe's flat probe (mu 0.3), pressed 0.1 mm, slid 2 mm
    #: at 200 mm/s and held 30 ms at 300 frames/s, 5 steps a frame: at 1e-3 of the normal force alone the held rods'
    #: forces alternated step by step, growing from 0.2 to 2 mN of 353, and the 2 x 2 swipe held 50 ms at 480
    #: frames/s lit up to 5.7 % of the press's brightest frame in each 2 ms frame of the hold (the nonlinear tier
    #: 1.4e-6, its afterglow), 10.1 % off in light over the episode. A fixed tighter tolerance did not serve: 1e-4
    #: grew too (0.05 to 0.2 mN), and relaxed by 0.3 to 1e-4 the tiny scene's drag ring cycled 60-180 rounds in 60
    #: of its steps (61 s, 9 s before) and the 5 x 5 swipe did not settle to 1e-5 in 30 steps (tests/test_rod_exact.py)
    ROUND_STEP_FRACTION = 0.1
    ROUND_RTOL_LEAST = 1e-5
    max_rounds = 60
    #: the rods' backward Euler inertia (fem.cosserat_dynamics; ``fidelity.solve.dynamics = "backward_euler"``), or
    #: None: each step an equilibrium. Set per episode by fem.quasistatic, which calls :meth:`end_step` after each step
    inertia: cd.RodInertia | None = None
    #: a rod leaves the moving set (solved without contact) when its nodes' speed is below this (m/s) and it
    #: carries no force: backward Euler then takes it to rest within a step's travel of 1e-9 m at the sensor's steps
    REST_SPEED_M_S = 1e-6
    #: the linear body's compliance among a rod's points (a callable: point indices (k,) -> (3 k, 3 k) m/N,
    #: :meth:`fem.contact_admm._Delassus.elastic_block`), set by fem.quasistatic with the contact operator: the
    #: error estimate's (:func:`fem.rod_error.force_error_estimate`). None: no estimate
    local_compliance = None

    @property
    def round_step_fraction(self) -> float | None:
        """Under inertia, ROUND_STEP_FRACTION: the contact rounds (fem.contact_admm.solve_step) settle to that fraction
        of the force their step moved, down to ROUND_RTOL_LEAST of the normal force; in statics None."""
        return None if self.inertia is None else self.ROUND_STEP_FRACTION

    def __init__(self, sections: RodSections, section: cr.RodSection, A: np.ndarray, obs_0: np.ndarray, X: np.ndarray, point_rod: np.ndarray,
                 segments: int = SEGMENTS):
        self.sections = sections
        self.section = section
        self.segments = segments
        self.A = np.ascontiguousarray(A, dtype=float)
        self.obs_0 = np.asarray(obs_0, dtype=float)
        self.X = np.asarray(X, dtype=float)
        index = {int(r): j for j, r in enumerate(sections.rods)}
        self.point_rod = np.array([index.get(int(r), -1) for r in point_rod], dtype=int)
        R = len(sections.rods)
        self.root_X = np.column_stack([sections.centre[:, :2], np.full(R, sections.base_z_m)])
        self._points = [np.flatnonzero(self.point_rod == j) for j in range(R)]
        self._attach = [attachments(self.X[p], sections.centre[j, :2], sections.base_z_m, sections.length_m, segments)
                        for j, p in enumerate(self._points)]
        # the straight rod's Hessian (the same for every rod: a rod's place does not change it)
        self._straight = cr.straight_rod(section, segments)
        _, H0 = cr.gradient_and_hessian(self._straight, section, np.array([1.0, 0.0, 0.0, 0.0]))
        self._H0_factor = np.linalg.cholesky(H0)
        self._responses = [self._unit_responses(j) for j in range(R)]
        # the rods' points, attachments and unit responses padded to the most points a rod has (K), so that the rounds
        # treat the loaded rods as one batch (padded points carry nothing); the per-rod loops cost the default demo's
        # held rounds 14 ms each in numpy's small-array overhead
        K = max((len(p) for p in self._points), default=0)
        self._mask_p = np.zeros((R, K), dtype=bool)
        self._index_p = np.zeros((R, K), dtype=np.int64)
        self._segment_p, self._along_p = np.zeros((R, K), dtype=np.int64), np.zeros((R, K))
        self._offset_p, self._X_p = np.zeros((R, K, 3)), np.zeros((R, K, 3))
        self._points_resp_p = np.zeros((R, 6 * segments, 3 * K))
        self._tip_resp_p = np.zeros((R, 6 * segments, 6))
        for j, pts in enumerate(self._points):
            k = len(pts)
            self._mask_p[j, :k], self._index_p[j, :k], self._X_p[j, :k] = True, pts, self.X[pts]
            self._segment_p[j, :k], self._along_p[j, :k], self._offset_p[j, :k] = self._attach[j]
            self._points_resp_p[j, :, : 3 * k], self._tip_resp_p[j] = self._responses[j]
        self._warm: dict[int, cr.RodState] = {}
        self._last_answers = (None, [])  # (forces, _answers' list): the field recovery asks twice per distinct load
        self._held: dict[bytes, list] = {}  # the contact loop's held answers by their forces (the field recovery's)
        # under inertia: the last step's rods, {rod: (nodes x_n (N + 1, 3) m, velocities v_n (N + 1, 3) m/s)}, of the
        # rods loaded or moving then, and each step's answers (the field recovery's: a rod swinging free after its
        # release carries no force, so its answers are not a function of the forces)
        self._motion: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        self._by_step: dict[int, list] = {}
        self._local: dict[int, np.ndarray] = {}  # rod -> its local compliance (3 k, 3 k) m/N (fem.rod_error.local_block)
        # guard(f): raises where the forces f (m, 3) N load a rod past what dead loads can follow (the tier's
        # buckling check, fem.quasistatic._check_buckling), before any rod is solved under them
        self.guard = None
        # the largest axial (compressive) contact load (R,) N each rod was solved under since fem.quasistatic last
        # cleared it (a step's solves): what a failed step is judged by, a collapse or a solver's failure
        self.axial_peak_n = np.zeros(len(sections.rods))

    # --- the pieces -----------------------------------------------------------------------------------

    def resultant_change(self, df: np.ndarray) -> float:
        """sum over rods of |sum of df (m, 3) N over the rod's points|, plus |df| of points off the rods (N)."""
        return resultant_change(df, self.point_rod, len(self.sections.rods))

    def root_motion(self, f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The roots' translation (R, 3) m and rotation vector (R, 3) rad at point forces f (m, 3) N."""
        obs = (self.obs_0 + self.A @ f.ravel()).reshape(-1, 6)
        return obs[:, :3], obs[:, 3:]

    def _linear_dofs(self, j: int, forces: np.ndarray, tip_force_n=(0.0, 0.0, 0.0), tip_moment_n_m=(0.0, 0.0, 0.0)) -> np.ndarray:
        """The straight rod j's linear response (6 N,) to dead forces (k, 3) N on its points and a tip force and
        moment: its precomputed responses to unit loads (:meth:`_unit_responses`)."""
        points, tip = self._responses[j]
        return points @ np.asarray(forces, dtype=float).ravel() + tip @ np.concatenate([tip_force_n, tip_moment_n_m])

    def _unit_responses(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The straight rod's linear dofs (6 N, 3 k) per unit force on each of rod j's k points and (6 N, 6) per unit
        tip force and moment: -H_0^-1 of the loads' gradient at the straight state, where it is linear in them (one
        batch of :func:`fem.cosserat_rod.gradient_and_hessian`, a unit load per rod of the batch). The contact rounds
        ask for it twice per loaded rod per round (the straight rod's gradient each time: an eighth of the default
        demo's held run)."""
        segment, along, offset = self._attach[j]
        k = len(segment)
        cases = 3 * k + 6
        unit = np.eye(cases)
        straight = cr.straight_rod(self.section, self.segments, np.zeros((cases, 3)))
        loads = None
        if k:
            force = unit[:, : 3 * k].reshape(cases, k, 3)  # case 3 i + c: a unit force along c on point i
            loads = cr.PointLoads(np.broadcast_to(segment, (cases, k)), np.broadcast_to(along, (cases, k)),
                                  np.broadcast_to(offset, (cases, k, 3)), force)
        g, _ = cr.gradient_and_hessian(straight, self.section, np.broadcast_to([1.0, 0.0, 0.0, 0.0], (cases, 4)),
                                       unit[:, 3 * k : 3 * k + 3], unit[:, 3 * k + 3 :], loads=loads, hessian=False)
        responses = -cr._cho_solve(self._H0_factor, g).T  # (6 N, cases)
        return responses[:, : 3 * k], responses[:, 3 * k :]

    @staticmethod
    def _linear_positions(d: np.ndarray, segment: np.ndarray, along: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """The displacement (k, 3) of attached points for the linear dofs d (6 N,) of a rod clamped at the origin."""
        return CosseratKinematics._linear_positions_batch(d[None], segment[None], along[None], offset[None])[0]

    def _linear_dofs_batch(self, rows: np.ndarray, forces: np.ndarray, tip_loads: np.ndarray | None = None) -> np.ndarray:
        """:meth:`_linear_dofs` of the rods ``rows`` (B,) at once: forces (B, K, 3) N on their padded points, tip_loads
        (B, 6) (force N, moment N m) or None; (B, 6 N)."""
        B = len(rows)
        d = np.matmul(self._points_resp_p[rows], forces.reshape(B, -1, 1))[..., 0]
        if tip_loads is not None:
            d += np.matmul(self._tip_resp_p[rows], tip_loads[..., None])[..., 0]
        return d

    @staticmethod
    def _linear_positions_batch(d: np.ndarray, segment: np.ndarray, along: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """The displacement (B, K, 3) m of attached points for the linear dofs d (B, 6 N) of rods clamped at the origin
        (segment, along (B, K), offset (B, K, 3)): the nodes' moves interpolated along the chord, the frame's turn
        psi x offset."""
        blocks = d.reshape(len(d), -1, 6)
        node = np.concatenate([np.zeros((len(d), 1, 3)), blocks[:, :, 3:]], axis=1)  # x_0 .. x_N
        e = segment[..., None]
        psi = np.take_along_axis(blocks[:, :, :3], e, axis=1)
        s = along[..., None]
        return (1.0 - s) * np.take_along_axis(node, e, axis=1) + s * np.take_along_axis(node, e + 1, axis=1) + _cross(psi, offset)

    def _linear_points_batch(self, rows: np.ndarray, u_r: np.ndarray, th_r: np.ndarray, d_lin: np.ndarray) -> np.ndarray:
        """The padded points (B, K, 3) m of the rods ``rows`` where the linearised rod puts them: X + u_r + theta_r x (X - X_r)
        plus the straight rod's linear dofs d_lin (B, 6 N) at their attachments (u_r, th_r (B, 3))."""
        Y = self._X_p[rows]
        return (Y + u_r[:, None] + _cross(th_r[:, None], Y - self.root_X[rows][:, None])
                + self._linear_positions_batch(d_lin, self._segment_p[rows], self._along_p[rows], self._offset_p[rows]))

    def solve_rods(self, f: np.ndarray, hold=None, root_load: np.ndarray | None = None) -> dict[int, tuple[cr.RodState, cr.PointLoads, np.ndarray, np.ndarray, np.ndarray]]:
        """Each loaded rod in equilibrium under its points' forces f (m, 3) N, clamped where the body puts its
        root, all in one batch (:func:`fem.cosserat_rod.solve_static`), each from its last answer:
        {rod: (state, its loads, root translation, root rotation, its nodes' inertial forces (N + 1, 3) N)}.

        Under :attr:`inertia` the solve is the step's backward Euler one (:mod:`fem.cosserat_dynamics`: a spring per
        node to its inertial prediction from the last step's :meth:`end_step`), and the rods still moving from it
        are solved too, loaded or not; without, the inertial forces are zero. ``root_load`` (m, 3) N: the roots where
        the body puts them under f + root_load (default f).

        ``hold`` = (q_frozen (m, 3) m, f_pd (m, 3) N, K (m, 3, 3) N/m), the Robin coupling: each point is
        also held by the contact's stiffness K to where the contact round put it, a = X + u_r + theta_r x
        (X - X_r) + (G (f + f_pd)) + q_frozen (the rod's linear position under the round's forces and P-delta
        load, plus the nonlinear part the round froze). At the rounds' fixed point the rod sits there and the
        springs carry nothing; before it, they hold a rod pressed past its free Euler load by a face that
        grips its tip, as the face does. Without: dead loads, and the guard (if set) runs first."""
        batch = self._solve_batch(f, hold, root_load)
        if batch is None:
            return {}
        rows, state, loads, u_r, th_r, inertial = batch
        out = {}
        for b, j in enumerate(rows):
            k = len(self._points[j])
            springs = (None, None) if loads.stiffness_n_m is None else (loads.stiffness_n_m[b, :k], loads.anchor_m[b, :k])
            out[int(j)] = (cr.RodState(state.x[b], state.q[b]), cr.PointLoads(loads.segment[b, :k], loads.along[b, :k], loads.offset_m[b, :k],
                                                                               loads.force_n[b, :k], *springs), u_r[b], th_r[b], inertial[b])
        return out

    def _solve_batch(self, f: np.ndarray, hold=None, root_load: np.ndarray | None = None):
        """:meth:`solve_rods` as one batch: (rows (B,), the rods' state (B, ...), their loads on the padded points (B, K),
        root translations and rotations (B, 3), the nodes' inertial forces (B, N + 1, 3) N), or None where no rod is
        loaded or moving."""
        if self.guard is not None and hold is None:
            self.guard(f)
        u_r, th_r = self.root_motion(f if root_load is None else f + root_load)
        loaded = [j for j, pts in enumerate(self._points) if len(pts) and (np.any(f[pts]) or j in self._motion)]
        if not loaded:
            return None
        rows = np.array(loaded, dtype=np.int64)
        mask = self._mask_p[rows][..., None]
        index = self._index_p[rows]
        u_r, th_r = u_r[rows], th_r[rows]
        segment, along, offset = self._segment_p[rows], self._along_p[rows], self._offset_p[rows]
        force = np.where(mask, f[index], 0.0)
        self.axial_peak_n[rows] = np.maximum(self.axial_peak_n[rows], -force[..., 2].sum(axis=1))
        stiffness = anchor = None
        if hold is not None:
            q_frozen, f_pd, K_pts = hold
            d_lin = self._linear_dofs_batch(rows, np.where(mask, force + f_pd[index], 0.0))
            anchor = np.where(mask, self._linear_points_batch(rows, u_r, th_r, d_lin) + q_frozen[index], 0.0)
            stiffness = np.where(mask[..., None], K_pts[index], 0.0)
        roots, clamps, straight = self._at_rest(rows, u_r, th_r)
        x, q = straight.x.copy(), straight.q.copy()
        for b, j in enumerate(loaded):
            warm = self._warm.get(j)
            if warm is not None:  # the last answer, carried to today's root
                x[b], q[b] = warm.x - warm.x[:1] + roots[b], warm.q
        loads = cr.PointLoads(segment, along, offset, force, stiffness, anchor)
        solve_loads, nodes = loads, None
        if self.inertia is not None:
            # the last step's nodes and velocities; a rod at rest then: straight where the body puts its root now
            x_n, v_n = straight.x.copy(), np.zeros_like(straight.x)
            for b, j in enumerate(loaded):
                if j in self._motion:
                    x_n[b], v_n[b] = self._motion[j]
            nodes = self.inertia.springs(self.section, x_n, v_n)
            solve_loads = cd.joined(loads, nodes)
        try:
            state = cr.solve_static(self.section, self.segments, loads=solve_loads, clamp=clamps, root_m=roots, start=cr.RodState(x, q), rtol=1e-8)
        except cr.SolverError:
            # a last answer on another branch or too far: from the straight rods, in increments; then in finer ones with
            # longer trust-region walks (12 x 3 mm rods pressed by the sweep's 5 N flat probe, at 5 x their free Euler
            # load: the 4 increments' 60 iterations ended 3.3 N out of balance, 16 of up to 200 converge)
            try:
                state = cr.solve_static(self.section, self.segments, loads=solve_loads, clamp=clamps, root_m=roots, start=straight, increments=4, rtol=1e-8)
            except cr.SolverError:
                state = cr.solve_static(self.section, self.segments, loads=solve_loads, clamp=clamps, root_m=roots, start=straight, increments=16,
                                        rtol=1e-8, max_iterations=200)
        inertial = np.zeros_like(state.x) if nodes is None else self.inertia.nodal_forces(nodes, state)
        for b, j in enumerate(loaded):
            self._warm[j] = cr.RodState(state.x[b], state.q[b])
        return rows, state, loads, u_r, th_r, inertial

    def _at_rest(self, rods, u_r: np.ndarray, th_r: np.ndarray) -> tuple[np.ndarray, np.ndarray, cr.RodState]:
        """(roots (B, 3) m, clamp frames (B, 4), the straight rods) of the rods ``rods`` where the body puts their
        roots (translations u_r (B, 3) m, rotations th_r (B, 3) rad): a rod's start in its solve, and under
        inertia the last step's state of a rod then at rest."""
        roots = self.root_X[rods] + u_r
        clamps = _rotation_quaternion(th_r)
        return roots, clamps, cr.straight_rod(self.section, self.segments, roots, clamps)

    def end_step(self, step: int, f: np.ndarray) -> None:
        """Under :attr:`inertia`, after the contact loop's step ``step`` converged at point forces f (m, 3) N: its
        rods' nodes and velocities become the next step's start (a rod unloaded and slower than REST_SPEED_M_S
        is at rest), and its answers are kept for the field recovery (:meth:`vertex_correction`,
        :meth:`stress_correction` with ``step``). Without inertia: nothing."""
        if self.inertia is None:
            return
        f = np.asarray(f, dtype=float)
        answers = self._answers(f)
        self._by_step[step] = answers
        motion = {}
        for j, state, u_r, th_r, *_ in answers:
            x_n = self._motion[j][0] if j in self._motion else self._at_rest([j], u_r[None], th_r[None])[2].x[0]
            v = self.inertia.velocity(state.x, x_n)
            if np.any(f[self._points[j]]) or np.abs(v).max() > self.REST_SPEED_M_S:
                motion[j] = (state.x.copy(), v)
        self._motion = motion
        # the answers by forces hold within a step only: the same forces at another step meet other velocities
        self._held.clear()
        self._last_answers = (None, [])

    # --- the interface of the contact loop --------------------------------------------------------------

    def _answers(self, f: np.ndarray, hold=None, step: int | None = None) -> list:
        """:meth:`_rod_answers` as a list, reused when asked again for the same forces. A held answer (the
        contact loop's, ``hold`` as :meth:`solve_rods`) is kept per forces for the episode: the field recovery
        asks for it again after the steps, without the hold (under dead loads alone a rod past its free Euler
        load would buckle in its solve). Under inertia the field recovery asks by ``step`` (:meth:`end_step`)."""
        if step is not None and self.inertia is not None:
            return self._by_step[step]
        if hold is not None:
            answers = list(self._rod_answers(f, hold))
            self._held[f.tobytes()] = answers
            self._last_answers = (f.copy(), answers)
            return answers
        held = self._held.get(f.tobytes())
        if held is not None:
            return held
        last_f, last = self._last_answers
        if last_f is None or not np.array_equal(last_f, f):
            self._last_answers = (f.copy(), list(self._rod_answers(f)))
        return self._last_answers[1]

    def _rod_answers(self, f: np.ndarray, hold=None):
        """Per loaded rod j: (j, state, root translation, root rotation, P-delta load on its points (k, 3) N,
        the straight rod's linear dofs under its forces, that load and the springs' pull, its nodes' inertial
        forces (N + 1, 3) N).

        Where held, the springs' pull enters the linear rod and the P-delta moment as its resultant, the force
        F_s and the moment M_s about the tip in the bent rod (where the springs act), at the straight rod's tip:
        the pulls are single points' penalty forces that nearly cancel, and their moment about the straight
        rod's points is not the one the bent rod carries (a face turned by 0.2 rad misplaces it by 40 x).

        Under inertia the body carries the rod's inertial forces as their resultant on the loaded points and
        their moment about the root in the bent rod within the P-delta load's (the base moves under the rod's
        whole root reaction); they stay out of the linear rod, so q holds the rod's dynamic shape. And the roots
        turn under those loads too (the rods' free vibration sees the base's compliance): a fixed point on them,
        from the round's own (held) or none, to ROOT_RTOL. Without it the tiny scene's rods, released from a drag,
        rang about 6 % fast, their tips' history after the release 19 % off the nonlinear tier's (10 % with).
        In statics the roots turn under f alone, as measured in the figures of the module's docstring (under the
        loads too, the tiny scene's flat press at 1 x moved by 0.3-0.5 points, to 2.3 / 2.2 / 1.6 % from 1.8 / 1.7 /
        1.9 %)."""
        if self.inertia is None:
            return list(self._rod_answers_at(f, hold, None))
        pd = np.array(hold[1], dtype=float) if hold is not None else np.zeros_like(f)
        for _ in range(ROOT_ITERATIONS):
            answers = list(self._rod_answers_at(f, hold, pd))
            new = np.zeros_like(f)
            for j, _, _, _, load, _, _ in answers:
                new[self._points[j]] = load
            done = self.resultant_change(new - pd) <= max(ROOT_RTOL * (self.resultant_change(f) + self.resultant_change(new)), 1e-12)
            pd = new
            if done:
                break
        return answers

    def _rod_answers_at(self, f: np.ndarray, hold, root_load):
        """:meth:`_rod_answers` with the roots under f + root_load (the loaded rods as one batch, padded points
        carrying nothing)."""
        batch = self._solve_batch(f, hold, root_load)
        if batch is None:
            return
        rows, state, loads, u_r, th_r, f_in = batch
        mask = self._mask_p[rows]
        Y = self._X_p[rows] - self.root_X[rows][:, None]  # the points from the root, at rest
        x_r = (self.root_X[rows] + u_r)[:, None]
        p = loads.positions(state)
        fj = loads.force_n
        pull = loads.carried(state, p) - fj
        F_s = pull.sum(axis=1)
        tip = state.x[:, -1]
        M_s = _cross(p - tip[:, None], pull).sum(axis=1)
        # the root moment in the bent rod less the straight one's, of the forces and the springs' resultant
        moment = ((_cross(p - x_r, fj) - _cross(Y, fj)).sum(axis=1)
                  + _cross(tip - x_r[:, 0] - np.array([0.0, 0.0, self.sections.length_m]), F_s) + _cross(state.x - x_r, f_in).sum(axis=1))
        # the inertial resultant and a horizontal load on the loaded points (weights |f_k|) whose root moment is
        # the rest of the horizontal difference
        w = np.linalg.norm(fj, axis=2)
        total = w.sum(axis=1, keepdims=True)
        w = np.where(total > 0.0, w / np.where(total > 0.0, total, 1.0), mask / mask.sum(axis=1, keepdims=True))
        F_in = f_in.sum(axis=1)
        moment = moment - _cross(np.einsum("bk,bkc->bc", w, Y), F_in)
        lever = np.einsum("bk,bk->b", w, Y[..., 2])
        f_pd = np.zeros_like(F_in)
        up = lever > 0.0
        f_pd[up, 0], f_pd[up, 1] = moment[up, 1] / lever[up], -moment[up, 0] / lever[up]  # -z x (M_x, M_y, 0) / lever
        load = w[..., None] * (f_pd + F_in)[:, None]
        d_lin = self._linear_dofs_batch(rows, fj + load, np.concatenate([F_s, M_s], axis=1))
        for b, j in enumerate(rows):
            k = len(self._points[j])
            yield int(j), cr.RodState(state.x[b], state.q[b]), u_r[b], th_r[b], load[b, :k], d_lin[b], f_in[b]

    def _nonlinear_part(self, j: int, state: cr.RodState, u_r, th_r, d_lin, Y: np.ndarray) -> np.ndarray:
        """Points Y (k, 3) m of rod j carried by the rod in ``state`` less the same rod linearised (q's rule)."""
        sec = self.sections
        segment, along, offset = attachments(Y, sec.centre[j, :2], sec.base_z_m, sec.length_m, self.segments)
        placed = cr.PointLoads(segment, along, offset, np.zeros_like(Y)).positions(state)
        linear = Y + u_r + np.cross(th_r, Y - self.root_X[j]) + self._linear_positions(d_lin, segment, along, offset)
        return placed - linear

    def q_and_load(self, f_points: np.ndarray, hold=None) -> tuple[np.ndarray, np.ndarray]:
        """q (m, 3) m and the P-delta load f_pd (m, 3) N at point forces f_points (m, 3) N (``hold``: the
        Robin coupling's (q_frozen, f_pd, K), :meth:`solve_rods`)."""
        f = np.asarray(f_points, dtype=float)
        q = np.zeros_like(f)
        load = np.zeros_like(f)
        answers = self._answers(f, hold)
        if not answers:
            return q, load
        # the nonlinear part of every loaded rod at once (q's rule, :meth:`_nonlinear_part`, at its own points)
        rows = np.array([a[0] for a in answers], dtype=np.int64)
        state = cr.RodState(np.stack([a[1].x for a in answers]), np.stack([a[1].q for a in answers]))
        placed = cr.PointLoads(self._segment_p[rows], self._along_p[rows], self._offset_p[rows], np.zeros(self._X_p[rows].shape)).positions(state)
        linear = self._linear_points_batch(rows, np.stack([a[2] for a in answers]), np.stack([a[3] for a in answers]),
                                           np.stack([a[5] for a in answers]))
        q_rods = placed - linear
        for b, (j, *_, load_j, _, _) in enumerate(answers):
            pts = self._points[j]
            load[pts] = load_j
            q[pts] = q_rods[b, : len(pts)]
        return q, load

    def q(self, f: np.ndarray) -> np.ndarray:
        return self.q_and_load(f)[0]

    def vertex_correction(self, U: np.ndarray, points: np.ndarray, forces: np.ndarray | None = None, step: int | None = None) -> np.ndarray:
        """The nonlinear part (P, 3) m of the rods' vertex displacements at point forces ``forces`` (m, 3) N
        (U (P, 3), the linear displacement, only gives the shape): per loaded rod, each vertex carried by the
        Cosserat rod as a point of it (its height's segment, its offset from the axis) less the same rod
        linearised, q's rule at every vertex. Without forces: zero."""
        out = np.zeros_like(np.asarray(U, dtype=float))
        if forces is None:
            return out
        sec = self.sections
        for j, state, u_r, th_r, _, d_lin, _ in self._answers(np.asarray(forces, dtype=float), step=step):
            verts = sec.vertices[j]
            verts = verts[points[verts, 2] >= sec.base_z_m - 1e-7]
            out[verts] = self._nonlinear_part(j, state, u_r, th_r, d_lin, points[verts])
        return out

    # --- the stresses: Saint-Venant's recovery of the bent rod's section resultants ------------------------

    def unit_tip_loads(self, area_m2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Point loads (J, 6, m, 3) N of the rods J (mesh-rod indices into sections.rods, those with tip-face
        points): per rod, a unit force along x, y, z and a unit moment about x, y, z at its tip centre, spread
        over its tip-face points by area (the moments as linear tractions: about x and y by vertical forces
        in proportion to the lever, about z by forces along the circle)."""
        tip_z = self.sections.base_z_m + self.sections.length_m
        rods, out = [], []
        for j, pts in enumerate(self._points):
            face = pts[self.X[pts, 2] >= tip_z - 1e-7]
            if len(face) < 3:
                continue
            a = area_m2[face]
            r = self.X[face, :2] - self.sections.centre[j, :2]
            loads = np.zeros((6, len(self.X), 3))
            for c in range(3):
                loads[c, face, c] = a / a.sum()
            # M_x = sum y f_z, M_y = -sum x f_z, M_z = sum (x f_y - y f_x)
            loads[3, face, 2] = a * r[:, 1] / np.sum(a * r[:, 1] ** 2)
            loads[4, face, 2] = -a * r[:, 0] / np.sum(a * r[:, 0] ** 2)
            J = np.sum(a * (r**2).sum(axis=1))
            loads[5, face, 0] = -a * r[:, 1] / J
            loads[5, face, 1] = a * r[:, 0] / J
            rods.append(j)
            out.append(loads)
        return (np.array(out) if out else np.zeros((0, 6, len(self.X), 3))), np.array(rods, dtype=int)

    def stress_correction(self, f: np.ndarray, unit_stress: np.ndarray, rods: np.ndarray, tet_z: np.ndarray, tet_rod: np.ndarray,
                          step: int | None = None) -> np.ndarray:
        """The stress (6, T) Pa to add to the linear body's under f + f_pd (f (m, 3) N the contact forces):
        in each loaded rod's tets, Saint-Venant's recovery of the difference between the bent rod's section
        resultants (in the section's own frame) and those the linear body carries, through the rod's own
        responses to unit tip loads, ``unit_stress`` (J, 6, 6, T) of the rods ``rods`` (J,) (from
        :meth:`unit_tip_loads`). tet_z (T,) m the tets' centroid heights, tet_rod (T,) their mesh rods.

        A tet at height z sees the resultant (F, M) of the loads above it (under inertia, and of the nodes'
        inertial forces above it, :meth:`solve_rods`). The unit tip load k gives there
        the resultant T(z) e_k, T = [[I, 0], [(z_tip - z) [e_z]x, I]], so the section's response to a
        resultant r is unit_stress T(z)^-1 r. Exact for a prismatic rod away from the loads (Saint-Venant's
        principle); near the tip face the loads' local stress is the linear body's, and the resultants'
        difference, with short levers, small."""
        out = np.zeros(unit_stress.shape[2:])
        if not len(rods):
            return out
        answers = {j: (state, load, f_in) for j, state, _, _, load, _, f_in in self._answers(np.asarray(f, dtype=float), step=step)}
        sec = self.sections
        tip_z = sec.base_z_m + sec.length_m
        l = sec.length_m / self.segments
        for i, j in enumerate(rods):
            if j not in answers:
                continue
            state, load, f_in = answers[j]
            pts = self._points[j]
            fk = np.asarray(f, dtype=float)[pts]
            on = np.flatnonzero((tet_rod == sec.rods[j]) & (tet_z >= sec.base_z_m))
            z = tet_z[on]
            h = np.clip(z - sec.base_z_m, 0.0, sec.length_m)
            e = np.minimum((h / l).astype(int), self.segments - 1)
            s = (h / l - e)[:, None]
            centre = (1.0 - s) * state.x[e] + s * state.x[e + 1]  # the axis at each tet's height
            R = cr.rotation_matrix(state.q[e])  # (n, 3, 3) the sections' frames
            p = cr.PointLoads(*self._attach[j], np.zeros((len(pts), 3))).positions(state)
            above = self.X[pts, 2][None, :] > z[:, None]  # (n, k)
            F_ex = above @ fk
            M_ex = np.einsum("nk,nkc->nc", above, np.cross(p[None, :, :] - centre[:, None, :], fk[None]))
            if self.inertia is not None:  # the inertial forces of the nodes above the section (at arc length i l)
                node_above = (np.arange(self.segments + 1) * l)[None, :] > h[:, None]
                F_ex = F_ex + node_above @ f_in
                M_ex = M_ex + np.einsum("ni,nic->nc", node_above, np.cross(state.x[None, :, :] - centre[:, None, :], f_in[None]))
            r_ex = np.concatenate([np.einsum("nji,nj->ni", R, F_ex), np.einsum("nji,nj->ni", R, M_ex)], axis=1)
            g = fk + load
            axis = np.column_stack([np.broadcast_to(sec.centre[j, :2], (len(z), 2)), z])
            F_lin = above @ g
            M_lin = np.einsum("nk,nkc->nc", above, np.cross(self.X[pts][None, :, :] - axis[:, None, :], g[None]))
            dM = r_ex[:, 3:] - M_lin
            dF = r_ex[:, :3] - F_lin
            lever = (tip_z - z)[:, None]

            def t_inverse(F, M):  # T(z)^-1 (F, M): the resultant as the unit tip loads' coefficients
                return np.concatenate([F, M - lever * np.cross([0.0, 0.0, 1.0], F)], axis=1)

            coeff = t_inverse(dF, dM)
            if self.section.axial_law == "neo_hookean":
                # Cauchy's stress on the section's current area: an incompressible section stretched by lambda has
                # area A_0 / lambda, so the whole section's stress, unit_stress T^-1 r (nominal), times lambda
                chord = np.einsum("nji,nj->ni", R, state.x[e + 1] - state.x[e])[:, 2] / l  # lambda of each tet's segment
                coeff = coeff + (chord - 1.0)[:, None] * t_inverse(r_ex[:, :3], r_ex[:, 3:])
            out[:, on] += np.einsum("ksn,nk->sn", unit_stress[i][:, :, on], coeff)
        return out
