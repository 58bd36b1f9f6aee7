"""The landing fusion's outcome counters: keyed "sensor.outcome" by the enums' values (as
written to campaign JSON), with accepted and rejected totals counted from the enums."""

from __future__ import annotations

import math

from companion.autopilot.types import Attitude, PositionNed
from companion.delivery.fusion import FusionCounters, FusionSetup, LandingFusion
from companion.estimation.ekf import EkfSensor, UpdateOutcome
from companion.geometry.mounts import pad_pose_ned
from companion.geometry.se3 import Transform


def test_keys_are_the_enum_values_and_the_totals_follow_the_outcomes() -> None:
    c = FusionCounters()
    c.count(EkfSensor.SDK, UpdateOutcome.ACCEPTED)
    c.count(EkfSensor.SDK, UpdateOutcome.ACCEPTED)
    c.count(EkfSensor.ARUCO, UpdateOutcome.REJECTED_GATE)
    c.count(EkfSensor.UWB, UpdateOutcome.REJECTED_TOO_OLD)
    assert c.outcomes == {"sdk.accepted": 2, "aruco.rejected_gate": 1, "uwb.rejected_too_old": 1}
    assert (c.accepted, c.rejected) == (2, 2)


class _Fix:
    def __init__(self, t: float, z_m: float) -> None:
        self.time_s, self.x_m, self.y_m, self.z_m, self.pdop = t, 0.0, 0.0, z_m, 1.0


def test_a_fusion_counts_what_it_fed_the_ekf() -> None:
    f = LandingFusion(FusionSetup(T_world_pad=pad_pose_ned(0.0, 0.0, 0.0), T_body_camera=Transform.identity()), 0.0)
    f.on_uwb(_Fix(0.01, 3.0))  # before the first pose: refused, the EKF is not initialised
    for k in range(1, 11):
        t = 0.02 * k
        f.on_sample(Attitude(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        f.on_sample(PositionNed(t, 0.0, 0.0, -3.0, 0.0, 0.0, 0.0))
    assert f.on_uwb(_Fix(0.2, math.nan)) is UpdateOutcome.REJECTED_NONFINITE
    c = f.counters
    assert c.outcomes == {"uwb.rejected_uninitialized": 1, "sdk.accepted": 10, "uwb.rejected_nonfinite": 1}
    # the totals the telemetry publishes, as they were summed from the keys' text
    assert c.accepted == sum(n for k, n in c.outcomes.items() if k.endswith(".accepted")) == 10
    assert c.rejected == sum(n for k, n in c.outcomes.items() if ".rejected" in k) == 2
