"""The velocity-bias estimator: rate of the position estimate against the reported velocity."""

import math

import numpy as np
import pytest

from companion.autopilot.types import PositionNed
from companion.guidance.setpoint import VelocitySetpoint
from companion.guidance.velocity_bias import VelocityBiasEstimator


def flight(bias, seconds=6.0, dt=0.05, accel=(0.0, 0.0, 0.0), noise_m=0.0, seed=1):
    """Samples of a vehicle accelerating from rest whose reported velocity is off by -bias."""
    rng = np.random.default_rng(seed)
    out = []
    for k in range(int(seconds / dt) + 1):
        t = k * dt
        v = [a * t + b for a, b in zip(accel, bias, strict=True)]  # true velocity includes the bias drift
        p = [0.5 * a * t * t + b * t for a, b in zip(accel, bias, strict=True)]
        p = [x + noise_m * rng.standard_normal() for x in p]
        rep = [a * t for a in accel]  # the autopilot reports the velocity without the bias
        assert all(math.isfinite(x) for x in v)
        out.append(PositionNed(t, *p, *rep))
    return out


def test_a_constant_bias_is_recovered_with_the_first_order_lag():
    est = VelocityBiasEstimator(tau_s=1.0, max_m_s=1.0)
    for s in flight((0.5, -0.3, 0.1), seconds=5.0):
        b = est.update(s)
    # after 5 tau of a first-order lag: within exp(-5) = 0.7 % of the step
    assert b == pytest.approx((0.5, -0.3, 0.1), rel=0.01)
    assert est.settled


def test_constant_acceleration_with_a_consistent_estimate_gives_no_bias():
    # trapezoid mean of the reported velocities over each interval = the position's exact rate
    est = VelocityBiasEstimator(tau_s=0.5, max_m_s=1.0)
    for s in flight((0.0, 0.0, 0.0), accel=(1.0, -0.5, 0.2)):
        b = est.update(s)
    assert max(abs(x) for x in b) < 1e-9


def test_position_noise_is_averaged_out():
    est = VelocityBiasEstimator(tau_s=2.0, max_m_s=1.0)
    bs = []
    for s in flight((0.4, 0.0, 0.0), seconds=40.0, noise_m=0.02, seed=3):
        bs.append(est.update(s))
    tail = np.array(bs[-400:])
    assert abs(tail[:, 0].mean() - 0.4) < 0.03
    assert abs(tail[:, 1].mean()) < 0.03


def test_the_correction_makes_the_vehicle_fly_the_setpoint_and_is_limited():
    est = VelocityBiasEstimator(tau_s=0.2, max_m_s=1.0)
    sp = VelocitySetpoint(2.0, 0.0, -1.0, 0.3)
    assert est.correct(sp) == sp  # not settled yet: untouched
    for s in flight((0.5, 0.0, 0.0), seconds=3.0):
        est.update(s)
    c = est.correct(sp)
    assert c.north_m_s == pytest.approx(1.5, abs=1e-3)  # the vehicle moves at 1.5 + 0.5 = 2.0
    assert (c.east_m_s, c.down_m_s, c.yaw_rad) == pytest.approx((0.0, -1.0, 0.3), abs=1e-3)
    big = VelocityBiasEstimator(tau_s=0.2, max_m_s=0.3)
    for s in flight((3.0, 4.0, 0.0), seconds=3.0):
        big.update(s)
    c = big.correct(sp)
    assert math.hypot(c.north_m_s - 2.0, c.east_m_s) == pytest.approx(0.3, abs=1e-6)


def test_a_gap_or_a_repeated_sample_restarts_or_is_ignored():
    est = VelocityBiasEstimator(tau_s=0.2, max_m_s=1.0)
    samples = flight((0.5, 0.0, 0.0), seconds=2.0)
    for s in samples:
        est.update(s)
    n = est.samples
    est.update(samples[-1])  # the same sample twice: nothing new
    assert est.samples == n
    late = PositionNed(samples[-1].time_s + 3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)  # a 3 s link gap
    assert est.update(late) == (0.0, 0.0, 0.0)
    assert not est.settled
    assert est.update(None) == (0.0, 0.0, 0.0)


@pytest.mark.parametrize("tau,mx", [(0.0, 1.0), (-1.0, 1.0), (math.nan, 1.0), (1.0, -0.1), (1.0, math.inf)])
def test_bad_parameters_are_refused(tau, mx):
    with pytest.raises(ValueError, match="expected"):
        VelocityBiasEstimator(tau, mx)


def test_the_fusion_source_measures_the_bias_against_the_fused_position():
    """An autopilot whose own position drifts with its velocity bias (PX4 SIH) shows only part of
    the bias in its position's rate; the fused position (held by the pad) shows all of it."""
    from companion.guidance.velocity_bias import VelocityBiasCorrection

    true_v, reported_v = 0.1, -0.3  # m/s north: the bias is +0.4
    ap = VelocityBiasCorrection(1.0, 1.0, "autopilot")
    fu = VelocityBiasCorrection(1.0, 1.0, "fusion")
    dt = 0.05
    for k in range(1, 200):
        t = k * dt
        # the autopilot's position drifts halfway with its velocity: its rate is -0.1
        own = PositionNed(t, 0.5 * (true_v + reported_v) * t, 0.0, 0.0, reported_v, 0.0, 0.0)
        fused = (t, (true_v * t, 0.0, 0.0)) if t >= 2.0 else None  # pad data from 2 s
        ap.update(own)
        b = fu.update(own, lambda f=fused: f)
        if t < 2.0 + 1.0:  # the fused estimator settles tau after it starts
            assert fu.active is fu.autopilot
    assert ap.update(own)[0] == pytest.approx(0.2, abs=1e-3)  # half the bias
    assert fu.active is fu.fused and b[0] == pytest.approx(0.4, abs=0.01)
    sp = VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
    assert fu.correct(sp).north_m_s == pytest.approx(-0.4, abs=0.01)  # the vehicle then hovers
    with pytest.raises(ValueError, match="source"):
        VelocityBiasCorrection(1.0, 1.0, "gps")


def test_the_fused_estimator_counts_only_while_it_is_fed():
    """No fused position in the last update (pad data gone stale, the way home): the autopilot's
    estimator again; a gap of more than MAX_GAP_S starts the fused one afresh."""
    from companion.guidance.velocity_bias import VelocityBiasCorrection

    c = VelocityBiasCorrection(0.2, 1.0, "fusion")
    for k in range(1, 40):
        t = k * 0.05
        c.update(PositionNed(t, 0.0, 0.0, 0.0, -0.3, 0.0, 0.0), lambda t=t: (t, (0.0, 0.0, 0.0)))
    assert c.active is c.fused and c.fused.bias_ned_m_s[0] == pytest.approx(0.3, abs=1e-3)
    c.update(PositionNed(2.0, 0.0, 0.0, 0.0, -0.3, 0.0, 0.0), None)
    assert c.active is c.autopilot
    c.update(PositionNed(4.0, 0.0, 0.0, 0.0, -0.3, 0.0, 0.0), lambda: (4.0, (0.0, 0.0, 0.0)))
    assert c.active is c.autopilot and not c.fused.settled  # restarted after the 2 s gap
