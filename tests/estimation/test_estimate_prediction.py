"""StateEstimate.predicted: guidance carries the autopilot's last sample forward to its tick
([mission] estimate_predict_max_s), and leaves a stale estimate stale."""

from __future__ import annotations

import pytest

from companion.config import ConfigError, load_config, shipped_params_path
from companion.estimation.types import StateEstimate


def _est(t: float = 10.0) -> StateEstimate:
    return StateEstimate(t, 1.0, -2.0, -5.0, 0.4, -0.2, 0.5, 0.01, -0.02, 1.2, source="fused", gps_bias_north_m=0.3)


def test_position_advances_by_velocity_times_the_age() -> None:
    p = _est().predicted(10.15, 0.25)
    # 1 + 0.4 x 0.15, -2 - 0.2 x 0.15, -5 + 0.5 x 0.15
    assert (p.time_s, p.north_m, p.east_m, p.down_m) == pytest.approx((10.15, 1.06, -2.03, -4.925), abs=1e-12)
    e = _est()
    # everything else is the sample's
    assert (p.velocity_ned, p.roll_rad, p.pitch_rad, p.yaw_rad) == (e.velocity_ned, e.roll_rad, e.pitch_rad, e.yaw_rad)
    assert (p.source, p.gps_bias_north_m) == ("fused", 0.3)


@pytest.mark.parametrize(
    ("now", "max_s"),
    [
        (10.0, 0.25),  # same instant
        (9.9, 0.25),  # a sample newer than the tick
        (10.3, 0.25),  # older than the horizon: keeps its own time, so its age shows
        (10.1, 0.0),  # off
    ],
)
def test_unchanged_outside_the_horizon(now: float, max_s: float) -> None:
    e = _est()
    assert e.predicted(now, max_s) is e


def test_the_horizon_must_be_shorter_than_the_estimate_timeout() -> None:
    expected = r"mission.estimate_predict_max_s \(1.0\) must be < mission.estimate_timeout_s \(0.8\)"
    with pytest.raises(ConfigError, match=expected):
        load_config(
            shipped_params_path("sitl_short.toml"),
            overrides={"mission": {"estimate_predict_max_s": 1.0, "estimate_timeout_s": 0.8}},
        )
