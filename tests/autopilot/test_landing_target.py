"""LANDING_TARGET contents (interop with PX4's and ArduPilot's own precision landing)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.autopilot.landing_target import LandingTargetBuilder, LandingTargetError
from companion.estimation.types import StateEstimate
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.geometry.se3 import Transform


def _estimate(bias=(0.0, 0.0, 0.0)) -> StateEstimate:
    return StateEstimate(
        1.0, 0.0, 0.0, -10.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, "ekf",
        gps_bias_north_m=bias[0], gps_bias_east_m=bias[1], gps_bias_down_m=bias[2],
    )  # fmt: skip


def _pad_in_camera(mount: Transform, v_body: tuple[float, float, float]) -> Transform:
    """The pad pose in the camera frame whose centre lies at ``v_body`` (FRD) from the body."""
    return Transform(np.eye(3), mount.inverse().apply(np.asarray(v_body, dtype=float)))


@pytest.mark.parametrize("offset", [(0.0, 0.0, 0.0), (0.05, -0.02, 0.08)])
def test_body_angles_follow_ardupilots_line_of_sight(offset):
    mount = downward_mount(offset)
    b = LandingTargetBuilder("body_angles", mount, pad_pose_ned(), 0.8)
    lt = b.build(2.5, _pad_in_camera(mount, (1.0, 0.5, 10.0)), None)
    # hand-computed: angle_x = atan2(right, down), angle_y = atan2(-forward, down)
    assert lt.angle_x_rad == pytest.approx(math.atan2(0.5, 10.0), abs=1e-12)
    assert lt.angle_y_rad == pytest.approx(math.atan2(-1.0, 10.0), abs=1e-12)
    assert lt.distance_m == pytest.approx(math.sqrt(1.0 + 0.25 + 100.0), abs=1e-12)
    # AC_PrecLand_Companion rebuilds the body line of sight as (-tan(angle_y), tan(angle_x), 1)
    los = np.array([-math.tan(lt.angle_y_rad), math.tan(lt.angle_x_rad), 1.0]) * 10.0
    np.testing.assert_allclose(los, [1.0, 0.5, 10.0], atol=1e-9)
    assert lt.size_x_rad == pytest.approx(2 * math.atan2(0.4, lt.distance_m))
    assert not lt.position_valid and lt.time_s == 2.5


def test_local_ned_is_the_configured_pad_moved_by_the_gps_bias():
    mount = downward_mount()
    b = LandingTargetBuilder("local_ned", mount, pad_pose_ned(12.0, -3.0, 0.5), 0.8)
    lt = b.build(3.0, _pad_in_camera(mount, (0.0, 0.0, 8.0)), _estimate((1.5, -0.7, 0.2)))
    assert lt.position_valid
    assert (lt.north_m, lt.east_m, lt.down_m) == pytest.approx((13.5, -3.7, 0.7))
    assert lt.angle_x_rad == pytest.approx(0.0) and lt.angle_y_rad == pytest.approx(0.0)


def test_bad_inputs_are_refused_with_the_reason():
    mount = downward_mount()
    b = LandingTargetBuilder("local_ned", mount, pad_pose_ned(), 0.8)
    with pytest.raises(LandingTargetError, match="no fused estimate"):
        b.build(0.0, _pad_in_camera(mount, (0.0, 0.0, 5.0)), None)
    with pytest.raises(LandingTargetError, match="not below"):
        b.build(0.0, _pad_in_camera(mount, (0.0, 0.0, -5.0)), _estimate())
    with pytest.raises(LandingTargetError, match="not finite"):
        b.build(0.0, Transform(np.eye(3), np.array([0.0, math.nan, 4.0])), _estimate())
    with pytest.raises(LandingTargetError, match="not finite"):
        b.build(0.0, _pad_in_camera(mount, (0.0, 0.0, 5.0)), _estimate((math.inf, 0.0, 0.0)))
