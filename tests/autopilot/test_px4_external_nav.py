"""PX4's external navigation (companion.autopilot.px4.external_nav): the ODOMETRY MavlinkDirect
packs, its pre-flight rule (EKF2_EV_CTRL) and the configuration that now takes it."""

from __future__ import annotations

import dataclasses
import json
import math

import pytest
from pymavlink.dialects.v20 import common as mavlink

from companion.autopilot.external_nav import ExternalNavPose
from companion.autopilot.preflight.external_nav import check_px4_external_nav
from companion.autopilot.preflight.px4 import check_px4, px4_param_types
from companion.autopilot.preflight.report import ParamUnavailable, Requirements, Status
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4.external_nav import UNKNOWN_VARIANCE, odometry_fields
from companion.config import CompanionConfig

POSE = ExternalNavPose(12.5, 3.0, -4.0, -2.5, 0.02, -0.01, 1.2, 0.05, 0.07, 0.4, 0.03)
PX4 = Requirements("px4", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold",))
PX4_EXT = dataclasses.replace(PX4, external_nav_source_set=2)


def test_odometry_is_local_ned_position_with_its_variances_and_packs_as_mavlink() -> None:
    text = odometry_fields(POSE, 12_500_000)
    assert "NaN" not in text  # MavlinkDirect's JSON cannot carry one
    f = json.loads(text)
    assert f["frame_id"] == mavlink.MAV_FRAME_LOCAL_NED and f["estimator_type"] == mavlink.MAV_ESTIMATOR_TYPE_VISION
    assert (f["x"], f["y"], f["z"], f["time_usec"]) == (3.0, -4.0, -2.5, 12_500_000)
    cov = f["pose_covariance"]
    assert cov[0] == pytest.approx(0.05**2) and cov[6] == pytest.approx(0.07**2) and cov[11] == pytest.approx(0.16)
    assert cov[15] == cov[18] == cov[20] == pytest.approx(0.03**2) and sum(v != 0.0 for v in cov) == 6
    assert f["velocity_covariance"][0] == UNKNOWN_VARIANCE and (f["vx"], f["vy"], f["vz"]) == (0.0, 0.0, 0.0)
    w, x, y, z = f["q"]
    assert math.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z)) == pytest.approx(1.2)  # the pose's yaw
    # every field is one of ODOMETRY's, with its length: pymavlink packs it as MavlinkDirect would
    msg = mavlink.MAVLink_odometry_message(**f)
    assert len(msg.pack(mavlink.MAVLink(None, 1, 191))) > 200
    assert set(f) == set(mavlink.MAVLink_odometry_message.fieldnames)


def test_odometry_refuses_a_pose_that_is_not_finite() -> None:
    bad = dataclasses.replace(POSE, north_m=math.inf)
    with pytest.raises(ValueError):
        odometry_fields(bad, 0)


@pytest.mark.parametrize(
    ("value", "status", "words"),
    [
        (1.0, Status.OK, "horizontal position only"),
        (0.0, Status.WRONG, "set EKF2_EV_CTRL = 1"),
        (15.0, Status.WRONG, "velocity (bit 2)"),  # everything on: position, height, velocity and yaw
        (9.0, Status.WRONG, "yaw (bit 3)"),
        (3.0, Status.WRONG, "vertical position (bit 1)"),
        (4.0, Status.WRONG, "horizontal position (bit 0)"),
        (1.5, Status.WRONG, "not a bitmask"),
    ],
)
def test_ekf2_ev_ctrl_says_what_to_set(value: float, status: Status, words: str) -> None:
    rows = {r.name: r for r in check_px4_external_nav(PX4_EXT, {"EKF2_EV_CTRL": value, "COM_POSCTL_NAVL": 1.0})}
    row = rows["EKF2_EV_CTRL"]
    assert row.status is status and words in row.detail, row
    assert rows["COM_POSCTL_NAVL"].status is Status.OK


@pytest.mark.parametrize(
    ("value", "status", "words"),
    [
        (1.0, Status.OK, "lands where it is"),
        (0.0, Status.WARN, "Altitude mode"),  # PX4's default
        (3.0, Status.WRONG, "set COM_POSCTL_NAVL = 1"),
    ],
)
def test_com_posctl_navl_says_what_px4_does_with_gnss_lost_far_out(value: float, status: Status, words: str) -> None:
    rows = {r.name: r for r in check_px4_external_nav(PX4_EXT, {"EKF2_EV_CTRL": 1.0, "COM_POSCTL_NAVL": value})}
    row = rows["COM_POSCTL_NAVL"]
    assert row.status is status and words in row.detail, row


def test_the_rule_is_read_only_with_external_nav_on() -> None:
    assert {"EKF2_EV_CTRL", "COM_POSCTL_NAVL"} <= set(px4_param_types(PX4_EXT))
    assert "EKF2_EV_CTRL" not in px4_param_types(PX4) and "COM_POSCTL_NAVL" not in px4_param_types(PX4)
    assert check_px4_external_nav(PX4, {}) == []
    rows = {r.name: r for r in check_px4(PX4_EXT, {"EKF2_EV_CTRL": ParamUnavailable("no answer")})}
    assert rows["EKF2_EV_CTRL"].status is Status.UNKNOWN
    assert "EKF2_EV_CTRL" not in {r.name for r in check_px4(PX4, {})}


def test_px4_takes_external_nav_and_drops_poses_without_a_link() -> None:
    cfg = CompanionConfig.model_validate({"autopilot": "px4", "external_nav": {"enabled": True}})
    assert cfg.external_nav.enabled
    ap = Px4Autopilot("udpin://127.0.0.1:1")
    ap.send_external_nav(POSE)  # not connected: counted, never raised
    assert (ap.external_nav_sent, ap.external_nav_dropped) == (0, 1)
    assert "EKF2" in ap.external_nav_source_name(2)
