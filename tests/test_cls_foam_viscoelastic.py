"""The CLS foam's hysteresis (issue 43): the Maxwell arm against the standard linear solid's closed
forms (relaxation after a ramp, the loop's dissipated energy per cycle), the elastic limit, and
that the estimator's elastic law then misses the force by the hysteresis."""

from __future__ import annotations

import numpy as np
import pytest

from other_sensors.cls.foam_viscoelastic import maxwell_stress, viscoelastic_wrench
from other_sensors.cls.ltv import default_layout
from other_sensors.cls.shell import Foam, pose_wrench

LAYOUT = default_layout()
FOAM = Foam()


def test_a_ramp_then_hold_relaxes_exponentially():
    e1, tau, eps0, ramp = 15.0, 0.2, 0.1, 0.01
    t = np.concatenate([np.linspace(0.0, ramp, 11), ramp + np.linspace(0.0, 1.0, 501)[1:]])
    strain = np.minimum(t / ramp, 1.0) * eps0
    sigma = maxwell_stress(strain, t, e1, tau)
    # during a ramp of rate r: E1 r tau (1 - e^{-t/tau}); after it, that value decays as e^{-(t - ramp)/tau}
    peak = e1 * eps0 / ramp * tau * (1 - np.exp(-ramp / tau))
    np.testing.assert_allclose(sigma[t <= ramp], e1 * eps0 / ramp * tau * (1 - np.exp(-t[t <= ramp] / tau)), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(sigma[t >= ramp], peak * np.exp(-(t[t >= ramp] - ramp) / tau), rtol=1e-12)


@pytest.mark.parametrize("omega_tau", [0.3, 1.0, 3.0])
def test_the_loop_dissipates_pi_eps0_squared_times_the_loss_modulus_per_cycle(omega_tau):
    e1, tau, eps0 = 15.0, 0.2, 0.05
    omega = omega_tau / tau
    period = 2 * np.pi / omega
    t = np.linspace(0.0, 12 * period, 12 * 4000 + 1)
    strain = eps0 * np.sin(omega * t)
    sigma = maxwell_stress(strain, t, e1, tau)
    last = t >= 11 * period - 1e-12  # steady state: the start's transient has decayed by e^{-11 * 2 pi / omega_tau}
    work = np.sum(0.5 * (sigma[last][1:] + sigma[last][:-1]) * np.diff(strain[last]))
    loss = e1 * omega_tau / (1 + omega_tau**2)
    assert work == pytest.approx(np.pi * eps0**2 * loss, rel=2e-3)


def test_without_the_arm_the_foam_is_the_elastic_law_and_with_it_the_force_leads():
    t = np.arange(0.0, 4.0, 5e-4)
    pose = np.column_stack([3.0 * np.sin(2 * np.pi * 0.5 * t), 40.0 - 5.0 * (1 - np.cos(2 * np.pi * 0.5 * t)), 0.02 * np.sin(np.pi * t)])
    elastic = pose_wrench(pose, FOAM, LAYOUT)
    np.testing.assert_array_equal(viscoelastic_wrench(pose, t, FOAM, LAYOUT, 0.0, 0.2), elastic)
    visco = viscoelastic_wrench(pose, t, FOAM, LAYOUT, 15.0, 0.2)
    # over a closed cycle (t from 2 s to 4 s: every component's period is 2 s) the wrench holding the
    # shell does work on the foam, W = sum F . dq > 0, which the elastic law returns in full (W = 0)
    cycle = t >= 2.0

    def work(w):
        dq = np.diff(pose[cycle], axis=0)
        mid = 0.5 * (w[cycle][1:] + w[cycle][:-1])
        return float(np.sum(mid[:, 0] * dq[:, 0] + mid[:, 1] * dq[:, 1]) * 1e-3 + np.sum(mid[:, 2] * dq[:, 2]))  # J

    assert work(visco) > 100 * abs(work(elastic)) and work(visco) > 0
    # and at rest, back where it started, the arm has relaxed: the same force as the elastic law
    hold = np.vstack([pose, np.tile(pose[-1], (4000, 1))])
    th = np.concatenate([t, t[-1] + 5e-4 * np.arange(1, 4001)])
    assert viscoelastic_wrench(hold, th, FOAM, LAYOUT, 15.0, 0.2)[-1] == pytest.approx(pose_wrench(hold[-1], FOAM, LAYOUT), abs=1e-3)


def test_bad_arms_are_refused_naming_the_field():
    t = np.arange(3.0)
    with pytest.raises(ValueError, match="sensor.foam.maxwell_kpa"):
        maxwell_stress(np.zeros(3), t, -1.0, 0.2)
    with pytest.raises(ValueError, match="sensor.foam.relaxation_s"):
        maxwell_stress(np.zeros(3), t, 1.0, float("nan"))
    with pytest.raises(ValueError, match="times increasing"):
        maxwell_stress(np.zeros(3), t[::-1], 1.0, 0.2)
