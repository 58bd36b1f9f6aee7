"""The simulated autopilot's GNSS loss and external navigation (sitl/gnss_loss.py)."""

from __future__ import annotations

import pytest

from companion_sitl.gnss_loss import EKF_FAILSAFE_AFTER_S, PX4_FAILSAFE_AFTER_S, GnssLossError, SimGnss


def test_without_a_position_source_the_failsafe_fires_once_after_the_measured_delay() -> None:
    g = SimGnss("arducopter-sitl")
    assert not g.step(5.0)  # GNSS still good
    g.lose(10.0, (0.1, -0.2))
    assert not g.step(10.0 + EKF_FAILSAFE_AFTER_S - 0.01)
    assert g.step(10.0 + EKF_FAILSAFE_AFTER_S)
    assert not g.step(30.0)  # once


def test_on_external_nav_no_failsafe_while_poses_come_and_one_when_they_stop() -> None:
    g = SimGnss("arducopter-sitl")
    g.lose(0.0, (0.0, 0.0))
    g.use_source_set(2)
    for k in range(200):  # 20 Hz for 10 s
        t = k * 0.05
        g.on_pose(t, 1.0, 2.0, -3.0)
        assert not g.step(t) and g.external_fresh(t)
    t_last = 199 * 0.05
    assert not g.external_fresh(t_last + 0.6)
    assert not g.step(t_last + 0.6)  # unaided from here
    assert g.step(t_last + 0.6 + EKF_FAILSAFE_AFTER_S + 1e-9)


def test_poses_on_source_set_one_are_not_navigated_on() -> None:
    g = SimGnss("arducopter-sitl")
    g.lose(0.0, (0.0, 0.0))
    g.on_pose(0.0, 1.0, 2.0, -3.0)
    assert not g.external_fresh(0.0)


def test_px4_sih_fuses_poses_without_a_switch_and_blind_lands_after_its_delay() -> None:
    g = SimGnss("px4-sih")
    assert g.model is not None and (g.model.lost_fix_type, g.model.lost_satellites) == (0, 255)
    g.lose(0.0, (0.0, 0.0))
    g.on_pose(0.0, 1.0, 2.0, -3.0)
    assert g.external_fresh(0.0)  # source set 1 still: EKF2 has no sets
    assert not g.step(0.0) and not g.external_fresh(0.6)
    assert not g.step(0.6)  # the poses stopped at 0: unaided from here
    assert not g.step(0.6 + PX4_FAILSAFE_AFTER_S - 0.01)
    assert g.step(0.6 + PX4_FAILSAFE_AFTER_S)


def test_profiles_that_do_not_model_it_refuse_with_the_reason() -> None:
    g = SimGnss("ideal")
    with pytest.raises(GnssLossError, match="does not model it"):
        g.lose(0.0, (0.0, 0.0))
    with pytest.raises(GnssLossError, match="does not model it"):
        g.on_pose(0.0, 1.0, 2.0, 3.0)


def test_bad_inputs_are_refused() -> None:
    g = SimGnss("arducopter-sitl")
    with pytest.raises(GnssLossError, match="sets 1, 2 and 3"):
        g.use_source_set(4)
    with pytest.raises(GnssLossError, match="not finite"):
        g.on_pose(0.0, float("nan"), 0.0, 0.0)
