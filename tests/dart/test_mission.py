"""The Dart mission (dart sec. 5): hover, straight approach with a triangular velocity profile,
hover at 1.5 m; and the Dart parameter file."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.dart.mission import (
    DartMission,
    DartMissionConfig,
    DartParamsError,
    DartPhase,
    load_mission_config,
    triangular_profile,
)

PARAMS = Path(__file__).resolve().parents[2] / "params" / "dart_hover.toml"


def test_triangular_profile_by_hand() -> None:
    # D = 2.5 m (4 m -> 1.5 m), v = 0.1 m/s: T = 2 D / v = 50 s, a = v^2 / D = 0.004 m/s^2
    assert triangular_profile(0.0, 2.5, 0.1) == (0.0, 0.0)
    s, v = triangular_profile(10.0, 2.5, 0.1)
    assert s == pytest.approx(0.5 * 0.004 * 100.0) and v == pytest.approx(0.04)
    s, v = triangular_profile(25.0, 2.5, 0.1)  # mid-path: peak speed, half the distance
    assert s == pytest.approx(1.25) and v == pytest.approx(0.1)
    s, v = triangular_profile(40.0, 2.5, 0.1)  # symmetric: 10 s before the end
    assert s == pytest.approx(2.5 - 0.2) and v == pytest.approx(0.04)
    assert triangular_profile(50.0, 2.5, 0.1) == (2.5, 0.0)
    assert triangular_profile(80.0, 2.5, 0.1) == (2.5, 0.0)
    with pytest.raises(ValueError):
        triangular_profile(1.0, 0.0, 0.1)


def test_mission_hover_approach_hover_with_a_triangular_speed() -> None:
    cfg = DartMissionConfig(hover_s=5.0)
    m = DartMission(cfg)
    dt = 1.0 / 22.0  # the control task rate
    times = np.arange(0.0, 70.0, dt)
    steps = [m.update(float(t), True) for t in times]
    phases = [s.phase for s in steps]
    assert phases[0] is DartPhase.HOVER_START
    assert [p for _, p in m.transitions] == [DartPhase.HOVER_START, DartPhase.APPROACH, DartPhase.HOVER_END]
    hover = [s for s in steps if s.phase is DartPhase.HOVER_START]
    assert all(s.setpoint is not None and s.setpoint.z_m == 4.0 and s.speed_m_s == 0.0 for s in hover)
    assert hover[-1].time_s < 5.0 + 1e-9
    app = [s for s in steps if s.phase is DartPhase.APPROACH]
    z = np.array([s.setpoint.z_m for s in app])  # type: ignore[union-attr]
    v = np.array([s.speed_m_s for s in app])
    t = np.array([s.time_s for s in app])
    # straight towards the marker, x and y unchanged, never backwards, never faster than 0.1 m/s
    assert all(s.setpoint.x_m == 0.0 and s.setpoint.y_m == 0.0 for s in app)  # type: ignore[union-attr]
    assert np.all(np.diff(z) < 0.0) and v.max() <= 0.1 + 1e-12 and v.max() > 0.099
    # triangular: speed rises linearly to the peak at mid-approach, then falls linearly
    peak = t[np.argmax(v)] - 5.0
    assert peak == pytest.approx(25.0, abs=dt)
    rising = (t - 5.0) < 24.0
    assert np.allclose(v[rising], 0.004 * (t[rising] - 5.0), atol=1e-12)
    # the speed is the derivative of the setpoint
    assert np.allclose(-np.diff(z) / dt, 0.5 * (v[1:] + v[:-1]), atol=2e-4)
    # approach takes 2 D / v = 50 s, then hovers at 1.5 m
    end = [s for s in steps if s.phase is DartPhase.HOVER_END]
    assert end[0].time_s == pytest.approx(55.0, abs=dt)
    assert all(s.setpoint is not None and s.setpoint.z_m == 1.5 and s.speed_m_s == 0.0 for s in end)


def test_switch_off_is_manual_and_re_engaging_restarts_with_the_hover() -> None:
    m = DartMission(DartMissionConfig(hover_s=2.0))
    assert m.update(0.0, False).phase is DartPhase.MANUAL
    assert m.update(0.0, False).setpoint is None
    assert m.update(1.0, True).phase is DartPhase.HOVER_START
    assert m.update(3.5, True).phase is DartPhase.APPROACH
    off = m.update(4.0, False)
    assert off.phase is DartPhase.MANUAL and off.setpoint is None
    again = m.update(5.0, True)
    assert again.phase is DartPhase.HOVER_START and again.setpoint is not None and again.setpoint.z_m == 4.0
    assert m.update(6.9, True).phase is DartPhase.HOVER_START
    assert m.update(7.1, True).phase is DartPhase.APPROACH


def test_hover_only_never_approaches() -> None:
    m = DartMission(DartMissionConfig(approach=False, hover_s=0.0))
    assert {m.update(t, True).phase for t in np.arange(0.0, 100.0, 0.5)} == {DartPhase.HOVER_START}


def test_mission_config_rules() -> None:
    with pytest.raises(ValueError, match="end_distance_m"):
        DartMissionConfig(start_distance_m=1.0, end_distance_m=1.5)
    with pytest.raises(ValueError, match="max_speed_m_s"):
        DartMissionConfig(max_speed_m_s=0.0)
    with pytest.raises(ValueError, match="hover_s"):
        DartMissionConfig(hover_s=math.nan)
    assert DartMissionConfig().approach_duration_s == pytest.approx(50.0)
    with pytest.raises(ValueError, match="time_s"):
        DartMission().update(math.nan, True)


def test_shipped_params_load_and_bad_values_name_file_key_value_rule(tmp_path: Path) -> None:
    cfg = load_mission_config(PARAMS)
    assert cfg.start_distance_m == 4.0 and cfg.end_distance_m == 1.5 and cfg.max_speed_m_s == 0.1
    bad = tmp_path / "bad.toml"
    bad.write_text("[mission]\nmax_speed_m_s = -0.1\n")
    with pytest.raises(DartParamsError) as err:
        load_mission_config(bad)
    msg = str(err.value)
    assert str(bad) in msg and "[mission]" in msg and "max_speed_m_s" in msg and "-0.1" in msg and "than 0" in msg
    bad.write_text("[mission]\nspeed = 1.0\n")
    with pytest.raises(DartParamsError, match=r"\[mission\] speed = 1.0: unknown key"):
        load_mission_config(bad)
    bad.write_text('[mission]\nhover_s = "long"\n')
    with pytest.raises(DartParamsError, match="hover_s = 'long': Input should be a valid number"):
        load_mission_config(bad)
    bad.write_text("[mission\n")
    with pytest.raises(DartParamsError, match="not valid TOML"):
        load_mission_config(bad)
