"""The swing foot's landing: the LIPM's leg carrying the step's momentum into the cells' compliance
and damping, read at the skin's 250 Hz ticks (SPEC 4's "early contact").

SPEC 4's step-feasibility rules act on early contact, when the swing foot lands; the static
placement of :func:`other_sensors.sole.contact.height_for_load` is this module's slow limit. The
model (every parameter's source is in :class:`other_sensors.sole.schema.LandingSpec`):

- Heave. The foot keeps its commanded roll, pitch, yaw and horizontal position (the ankle's and
  the leg's position servos hold them over the impact's tens of milliseconds; the ground's friction
  holds the foot in place, a simplification: no slip, no tilt of the foot against its servos). Its
  sink u below first contact obeys
      m_L u'' = F_L - F_c(u, u'),   u(0) = 0,  u'(0) = v_0,
  m_L the landing mass (the swing leg's), F_L the share of the robot's weight the landing leg takes
  over (the early-contact load; the trailing leg carries the rest), v_0 the swing foot's descent
  speed at first contact.
- Contact. The skin is a tensionless Kelvin-Voigt Winkler layer: at each quadrature point of the
  cells (area w_i, clearance g_i at first contact), depth d_i = max(0, u - g_i) and pressure
  p_i = max(0, k (d_i + tau d_i')) once d_i >= 0 (Johnson, *Contact Mechanics*, 1985, sec. 5.9, with
  a dashpot per spring; the max keeps a separating layer from pulling). F_c = sum_i p_i w_i. tau = 0
  gives back the elastic layer of :mod:`other_sensors.sole.contact`.
- The step's momentum. The LIPM's leg is a massless strut from the ankle to the centre of mass
  (Kajita et al., 2001): the ground's reaction on the foot passes through the CoM, so its horizontal
  part is f = F_c (x_c, y_c) / z_com, with (x_c, y_c) the CoM relative to the ankle, moving on the
  LIPM's closed form x_c(t) = x_0 cosh(omega t) + (v_0 / omega) sinh(omega t), omega = sqrt(g / z_com),
  from the periodic gait's touchdown state (:func:`touchdown_com`). The sole's friction carries f
  (the cells do not measure it); the ankle F/T, ``ankle_height`` above the sole, reads the normal
  pressure's moment plus the friction's lever: M = (M_x + h f_y, M_y - h f_x). This is what puts a
  moment on the ankle of a foot landing flat on a flat floor, where the static placement gave 0.
- Swing speed. The swing foot descends on a cosine profile z(t) = H/2 (1 + cos(pi t / T)) from the
  swing height H to the planned ground (z = 0) in T; at first contact at height z_0 its speed is
  v_0 = (pi / T) sqrt(z_0 (H - z_0)) (:func:`swing_speed`): an obstacle is met while the foot still
  falls, a planned touchdown at rest.

Readings: the cells and the F/T sample at ``rate_hz`` from first contact; "at impact" is the tick of
the largest normal force within the early-contact window, where the rules are assessed.
Integration: classical Runge-Kutta on (u, u') at a fixed step (``dt_s``), exact for the
closed-form landing of a flat sole to O(dt^4) (``tests/test_sole_landing.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .contact import FootPose, SoleContact, _sample_clearance, cell_sampling
from .estimators import G

__all__ = ["LandingParams", "Landing", "swing_speed", "touchdown_com", "lipm_com", "first_contact_height", "simulate_landing"]


def swing_speed(contact_height_m: float, swing_height_m: float, descent_s: float) -> float:
    """Descent speed (m/s, >= 0) of the cosine swing profile of the module docstring at the height
    ``contact_height_m`` above the planned ground: (pi / T) sqrt(z (H - z)); 0 at or below the planned
    ground (the foot arrives at rest and is lowered by the load). An obstacle above H is refused."""
    z, h, t = float(contact_height_m), float(swing_height_m), float(descent_s)
    if not (np.isfinite(z) and h > 0 and t > 0):
        raise ValueError(f"swing_speed: contact height {z} m, swing height {h} m, descent {t} s: need finite, H > 0, T > 0")
    if z > h:
        raise ValueError(f"sensor.landing.swing_height_mm = {1e3 * h:g}: the terrain meets the sole {1e3 * z:.1f} mm above the "
                         "planned ground, above the swing's apex; raise swing_height_mm or give sensor.landing.speed_mm_s")
    return float(np.pi / t * np.sqrt(max(z, 0.0) * (h - max(z, 0.0))))


def touchdown_com(step_length_m: float, step_width_m: float, single_support_s: float, z_com_m: float, side: str = "left"):
    """The CoM relative to the landing ankle at touchdown of a periodic LIPM gait, and its velocity:
    (x_0, y_0) m and (vx_0, vy_0) m/s.

    Sagittal: the CoM goes from -L/2 to +L/2 over each single support, symmetric, so at touchdown
    x_0 = -L/2 and vx_0 = (L/2) omega coth(omega T / 2). Lateral: it swings between the feet,
    y(t) = (W/2) cosh(omega (t - T/2)) / cosh(omega T / 2) from the stance foot, so it reaches the
    new foot's side at (W/2) omega tanh(omega T / 2), from W/2 across (to -y for a left foot)."""
    if side not in ("left", "right"):
        raise ValueError(f'sensor.landing.side = "{side}": choose one of: left, right')
    omega = np.sqrt(G / z_com_m)
    sign = -1.0 if side == "left" else 1.0  # the CoM lies toward the other foot
    half = omega * single_support_s / 2.0
    pos = np.array([-step_length_m / 2.0, sign * step_width_m / 2.0])
    vel = np.array([step_length_m / 2.0 * omega / np.tanh(half) if step_length_m else 0.0,
                    -sign * step_width_m / 2.0 * omega * np.tanh(half)])
    return pos, vel


def lipm_com(t: np.ndarray, com0: np.ndarray, vel0: np.ndarray, z_com_m: float) -> np.ndarray:
    """The LIPM's CoM (T, 2) m over the ankle at times t (T,) s from (com0, vel0): the closed form
    of x'' = omega^2 x (the ZMP at the ankle)."""
    omega = np.sqrt(G / z_com_m)
    t = np.asarray(t, dtype=float)[:, None]
    return np.asarray(com0) * np.cosh(omega * t) + np.asarray(vel0) / omega * np.sinh(omega * t)


@dataclass(frozen=True)
class LandingParams:
    """One landing's physics in SI units (the scene's :class:`other_sensors.sole.schema.LandingSpec`
    converted): landing mass kg, speed m/s at first contact, load N (the weight share taken over),
    Winkler modulus N/m^3, Kelvin-Voigt time s, the CoM at touchdown (2,) m and its velocity (2,) m/s
    relative to the ankle, the CoM's height m, the ankle's height over the sole m, the skin's tick
    rate Hz, the early-contact window s and the integration step s."""

    mass_kg: float
    speed_m_s: float
    load_n: float
    stiffness_n_m3: float
    damping_s: float
    com_m: tuple[float, float]
    com_velocity_m_s: tuple[float, float]
    z_com_m: float
    ankle_height_m: float
    rate_hz: float = 250.0
    window_s: float = 0.04
    dt_s: float = 2e-5

    def __post_init__(self):
        checks = {"mass_kg": self.mass_kg > 0, "speed_m_s": self.speed_m_s >= 0, "load_n": self.load_n >= 0,
                  "stiffness_n_m3": self.stiffness_n_m3 > 0, "damping_s": self.damping_s >= 0, "z_com_m": self.z_com_m > 0,
                  "ankle_height_m": self.ankle_height_m >= 0, "rate_hz": self.rate_hz > 0, "window_s": self.window_s > 0,
                  "dt_s": 0 < self.dt_s <= 1.0 / self.rate_hz}
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (np.isfinite(value) and ok):
                raise ValueError(f"landing {name} = {value}: must be finite and in range (sensor.landing)")
        if not (np.isfinite(self.com_m).all() and np.isfinite(self.com_velocity_m_s).all()):
            raise ValueError(f"landing CoM {self.com_m} m, velocity {self.com_velocity_m_s} m/s: must be finite")


@dataclass(frozen=True)
class Landing:
    """A landing (sole frame, SI units).

    t (T,) s, the fine integration times from first contact; sink (T,) m and sink_rate (T,) m/s the
    foot's u and u'; force_n (T,) N, F_c. ticks (K,) s: the skin's sample times; tick_forces (K, N, 3) N
    the cells' sensors' readings (noise-free); wrench (K, 6): the contact's force (friction Fx, Fy and
    Fz) and its normal pressure's moment about the sole frame's origin; ankle_moment (K, 2) N m, what
    the ankle F/T reads (the friction's lever added); impact: the tick index at impact. pose: the foot
    at first contact (z at touch). gaps (N,) m: the cells' proximity readings at impact.
    """

    t: np.ndarray
    sink: np.ndarray
    sink_rate: np.ndarray
    force_n: np.ndarray
    ticks: np.ndarray
    tick_forces: np.ndarray
    wrench: np.ndarray
    ankle_moment: np.ndarray
    impact: int
    pose: FootPose
    gaps: np.ndarray
    speed_m_s: float

    def contact_at_impact(self, sensor_noise: np.ndarray | None = None) -> SoleContact:
        """The :class:`SoleContact` at impact (its ankle_wrench the F/T's), noise (N, 3) N added when given."""
        k = self.impact
        forces = self.tick_forces[k] + (0.0 if sensor_noise is None else sensor_noise)
        ankle = self.wrench[k].copy()
        ankle[3:5] = self.ankle_moment[k]
        pose = self.pose.with_height(self.pose.position[2] - float(np.interp(self.ticks[k], self.t, self.sink)))
        return SoleContact(forces, forces.sum(axis=1), self.wrench[k].copy(), self.gaps, pose, ankle_wrench=ankle)


def _contact_force(sink, rate, clearance, weights, k, tau):
    """Pressure (N, M) x area at each sample for sink u (m) and rate u' (m/s): the Kelvin-Voigt layer."""
    depth = sink - clearance
    # a point reached (d >= 0) pushes with its spring and dashpot: at d = 0 the dashpot alone (the
    # Kelvin-Voigt layer's force step at first touch, Hunt & Crossley 1975's objection, kept: it is
    # the closed form's and it lasts one sample's onset)
    return np.where(depth >= 0.0, np.maximum(k * (depth + tau * rate), 0.0), 0.0) * weights


def _clearance_at_touch(sampling, pose: FootPose, primitives) -> tuple[float, np.ndarray]:
    """The foot's height (m) when its sole first meets the terrain (x, y and angles held) and the
    samples' clearances (N, M) m there (>= 0; inf over no terrain)."""
    clearance0 = _sample_clearance(sampling, pose.with_height(0.0), primitives)
    if not np.isfinite(clearance0).any():
        raise ValueError("sensor.terrain: no terrain under the sole; add a flat ground or move sensor.foot")
    touch = -float(clearance0[np.isfinite(clearance0)].min())
    return touch, clearance0 + touch


def first_contact_height(layout, pose: FootPose, primitives, subdivisions: int = 6) -> float:
    """The height (m) of the sole frame's origin over the planned ground (z = 0) when the foot, at
    ``pose``'s x, y and angles, first touches the terrain."""
    return _clearance_at_touch(cell_sampling(layout, subdivisions), pose, primitives)[0]


def simulate_landing(layout, pose: FootPose, primitives, params: LandingParams, subdivisions: int = 6) -> Landing:
    """Land ``layout``'s sole, held at ``pose``'s x, y and angles (its height is not used: the foot
    starts at first contact), on ``primitives`` with ``params`` (module docstring)."""
    sampling = cell_sampling(layout, subdivisions)
    touch, clearance = _clearance_at_touch(sampling, pose, primitives)
    w, k, tau, m = sampling.weights, params.stiffness_n_m3, params.damping_s, params.mass_kg

    def total(u, v):
        return float(_contact_force(u, v, clearance, w, k, tau).sum())

    def rhs(u, v):
        return v, (params.load_n - total(u, v)) / m

    steps = int(np.ceil(params.window_s / params.dt_s - 1e-9))
    dt = params.window_s / steps
    t = np.arange(steps + 1) * dt
    u, v = np.zeros(steps + 1), np.zeros(steps + 1)
    v[0] = params.speed_m_s
    for i in range(steps):  # classical RK4
        k1 = rhs(u[i], v[i])
        k2 = rhs(u[i] + dt / 2 * k1[0], v[i] + dt / 2 * k1[1])
        k3 = rhs(u[i] + dt / 2 * k2[0], v[i] + dt / 2 * k2[1])
        k4 = rhs(u[i] + dt * k3[0], v[i] + dt * k3[1])
        u[i + 1] = u[i] + dt / 6 * (k1[0] + 2 * k2[0] + 2 * k3[0] + k4[0])
        v[i + 1] = v[i] + dt / 6 * (k1[1] + 2 * k2[1] + 2 * k3[1] + k4[1])
    force = np.array([total(a, b) for a, b in zip(u, v)])

    ticks = np.arange(1, int(np.floor(params.window_s * params.rate_hz + 1e-9)) + 1) / params.rate_hz
    tu, tv = np.interp(ticks, t, u), np.interp(ticks, t, v)
    x, y = sampling.points[..., 0], sampling.points[..., 1]
    com = lipm_com(ticks, np.asarray(params.com_m), np.asarray(params.com_velocity_m_s), params.z_com_m)
    tick_forces, wrench = np.zeros((len(ticks), layout.n_cells, 3)), np.zeros((len(ticks), 6))
    for j, (a, b) in enumerate(zip(tu, tv)):
        f = _contact_force(a, b, clearance, w, k, tau)
        tick_forces[j] = f @ sampling.split
        fz = float(f.sum())
        friction = fz * com[j] / params.z_com_m  # the reaction's horizontal part, toward the CoM
        wrench[j] = [friction[0], friction[1], fz, float((y * f).sum()), float(-(x * f).sum()), 0.0]
    h = params.ankle_height_m
    ankle = np.column_stack([wrench[:, 3] + h * wrench[:, 1], wrench[:, 4] - h * wrench[:, 0]])
    impact = int(np.argmax(wrench[:, 2]))
    gaps = np.maximum((clearance - tu[impact]).min(axis=1), 0.0)
    return Landing(t, u, v, force, ticks, tick_forces, wrench, ankle, impact, pose.with_height(touch), gaps,
                   float(params.speed_m_s))
