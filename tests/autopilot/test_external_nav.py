"""External navigation, backend-neutral and ArduPilot's pre-flight rules (docs/external-nav.md)."""

from __future__ import annotations

import dataclasses
import math

import pytest

from companion.autopilot.external_nav import ExternalNavError, ExternalNavPose, GnssWatch
from companion.autopilot.preflight.ardupilot import ardupilot_param_names, check_ardupilot
from companion.autopilot.preflight.external_nav import check_ardupilot_external_nav, external_nav_param_names
from companion.autopilot.preflight.report import ParamUnavailable, Requirements, Status
from companion.autopilot.types import GpsRaw

AP = Requirements("ardupilot", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold",))
AP_EXT = dataclasses.replace(AP, external_nav_source_set=2)
GOOD = {
    "VISO_TYPE": 1.0,
    "ARMING_CHECK": 1835006.0,
    "EK3_SRC2_POSXY": 6.0,
    "EK3_SRC2_VELXY": 0.0,
    "EK3_SRC2_POSZ": 1.0,
    "EK3_SRC2_YAW": 1.0,
    "FS_EKF_ACTION": 1.0,
}
POSE = ExternalNavPose(1.0, 2.0, -3.0, -4.0, 0.01, -0.02, 1.5, 0.05, 0.06, 0.5, 0.02)


def gps(t: float, fix: int = 3, sats: int = 10) -> GpsRaw:
    return GpsRaw(t, -35.0, 149.0, 584.0, fix, sats, 0.8)


def test_covariance_is_the_upper_triangle_with_the_variances_where_ardupilot_reads_them() -> None:
    cov = POSE.covariance_upper()
    assert len(cov) == 21
    assert cov[0] == pytest.approx(0.05**2) and cov[6] == pytest.approx(0.06**2) and cov[11] == pytest.approx(0.25)
    assert cov[15] == cov[18] == cov[20] == pytest.approx(0.02**2)
    assert sum(v != 0.0 for v in cov) == 6


@pytest.mark.parametrize(
    "change", [{"north_m": math.nan}, {"yaw_rad": math.inf}, {"sigma_east_m": 0.0}, {"sigma_attitude_rad": -1.0}]
)
def test_a_bad_pose_is_refused_with_what_is_wrong(change: dict[str, float]) -> None:
    with pytest.raises(ExternalNavError, match=r"not finite|standard deviations"):
        dataclasses.replace(POSE, **change).validate()


def test_gnss_is_lost_only_after_it_was_good_and_stayed_bad_long_enough() -> None:
    w = GnssWatch(min_fix_type=3, min_satellites=5, lost_after_s=0.5)
    assert not w.update(0.0, None)  # never good: nothing to lose (before the first fix)
    assert not w.update(0.1, gps(0.1, fix=1))
    assert not w.update(0.2, gps(0.2))
    assert not w.update(0.3, gps(0.3, fix=1))
    assert w.reason == "GPS fix type 1 (< 3)"
    assert not w.update(0.7, gps(0.7, fix=1))
    assert w.update(0.8, gps(0.8, fix=1))
    assert not w.update(0.9, gps(0.9))  # good again


def test_gnss_lost_by_satellites_and_by_silence() -> None:
    w = GnssWatch(min_fix_type=3, min_satellites=5, lost_after_s=0.0)
    w.update(0.0, gps(0.0))
    assert w.update(0.1, gps(0.1, sats=4)) and "4 satellites" in w.reason
    w = GnssWatch(min_fix_type=3, min_satellites=5, lost_after_s=0.0, silent_after_s=2.0)
    w.update(0.0, gps(0.0))
    assert not w.update(1.9, gps(0.0))
    assert w.update(2.1, gps(0.0)) and "no GPS_RAW_INT" in w.reason


def test_gnss_watch_refuses_bad_settings() -> None:
    with pytest.raises(ValueError, match="min_fix_type"):
        GnssWatch(min_fix_type=9, min_satellites=5, lost_after_s=0.5)


def test_external_nav_params_are_read_only_when_enabled() -> None:
    assert external_nav_param_names(AP) == [] and check_ardupilot_external_nav(AP, GOOD) == []
    names = ardupilot_param_names(AP_EXT)
    assert set(GOOD) <= set(names)
    rows = {r.name: r for r in check_ardupilot(AP_EXT, GOOD)}
    assert all(rows[k].status is Status.OK for k in GOOD)


@pytest.mark.parametrize(
    ("name", "value", "status", "words"),
    [
        ("VISO_TYPE", 0.0, Status.WRONG, "set VISO_TYPE = 1"),
        ("EK3_SRC2_POSXY", 3.0, Status.WRONG, "set EK3_SRC2_POSXY = 6"),
        ("EK3_SRC2_VELXY", 6.0, Status.WRONG, "set EK3_SRC2_VELXY = 0"),
        ("EK3_SRC2_POSZ", 6.0, Status.WRONG, "set EK3_SRC2_POSZ = 1"),
        ("EK3_SRC2_YAW", 6.0, Status.WRONG, "set EK3_SRC2_YAW = 1"),
        ("ARMING_CHECK", 1.0, Status.WRONG, "set ARMING_CHECK = 1835006"),
        ("ARMING_CHECK", 262150.0, Status.WRONG, "set ARMING_CHECK = 6"),
        ("ARMING_CHECK", 0.0, Status.WARN, "every pre-arm check is off"),
        ("FS_EKF_ACTION", 2.0, Status.WARN, "AltHold drifts"),
        ("FS_EKF_ACTION", 0.0, Status.WRONG, "set FS_EKF_ACTION = 1"),
        ("FS_EKF_ACTION", 3.0, Status.OK, "lands"),
    ],
)
def test_each_external_nav_param_says_what_to_set(name: str, value: float, status: Status, words: str) -> None:
    rows = {r.name: r for r in check_ardupilot_external_nav(AP_EXT, {**GOOD, name: value})}
    assert rows[name].status is status and words in rows[name].detail, rows[name]


def test_source_set_three_reads_its_own_params_and_an_unread_one_is_unknown() -> None:
    req = dataclasses.replace(AP, external_nav_source_set=3)
    params: dict[str, object] = {k.replace("SRC2", "SRC3"): v for k, v in GOOD.items()}
    params["EK3_SRC3_POSXY"] = ParamUnavailable("no answer")
    rows = {r.name: r for r in check_ardupilot_external_nav(req, params)}  # type: ignore[arg-type]
    assert rows["EK3_SRC3_POSXY"].status is Status.UNKNOWN
    assert rows["EK3_SRC3_VELXY"].status is Status.OK


@pytest.mark.parametrize(
    ("overrides", "words"),
    [
        ({"landing": {"fusion": False}}, "needs landing.fusion = true"),
        ({"landing": {"use_camera": False, "use_uwb": False}}, "needs landing.fusion = true"),
        ({"external_nav": {"enabled": True, "rate_hz": 30.0}}, "must be <= runtime.guidance_rate_hz"),
    ],
)
def test_the_configuration_refuses_what_external_nav_cannot_do(overrides: dict[str, object], words: str) -> None:
    from companion.config import CompanionConfig

    data: dict[str, object] = {"autopilot": "ardupilot", "external_nav": {"enabled": True}}
    data.update(overrides)
    if "external_nav" in overrides:
        data["external_nav"] = {"enabled": True, **overrides["external_nav"]}  # type: ignore[dict-item]
    with pytest.raises(ValueError, match=words):
        CompanionConfig.model_validate(data)
    assert not CompanionConfig().external_nav.enabled  # off by default
