"""Hybrid-mode RC mixer (dart sec. 2.2, Fig. 3) and the PX4 attitude mapping."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from companion.dart.control import DartController, DartSetpoint
from companion.dart.mixer import (
    IGNORE,
    RELEASE_HIGH,
    RELEASE_LOW,
    AttitudeMapConfig,
    RcMixer,
    RcMixerConfig,
    attitude_setpoint,
)


@dataclass(frozen=True)
class Contribution:
    roll_us: float = 0.0
    pitch_us: float = 0.0
    thrust_us: float = 0.0
    yaw_rate_us: float = 0.0


def sticks(roll=1500, pitch=1500, throttle=1450, yaw=1500, switch=1000, n=8) -> list[float]:
    ch = [1500.0] * n
    ch[0], ch[1], ch[2], ch[3] = roll, pitch, throttle, yaw
    ch[6] = switch  # channel 7
    return ch


ON, OFF = 1900, 1000


def test_disengaged_releases_the_mixed_channels_and_ignores_the_rest() -> None:
    mixer = RcMixer()
    out = mixer.mix(sticks(switch=OFF), Contribution(roll_us=100.0))
    assert not out.engaged
    assert out.channels[:4] == (RELEASE_LOW,) * 4  # 0: back to the RC radio
    assert out.channels[4:] == (IGNORE,) * 14  # 65535: ignore, the switch channel included
    assert len(out.channels) == 18
    assert out.sticks_us == (1500, 1500, 1450, 1500)


def test_disengaged_echo_mode_is_exactly_the_pilot() -> None:
    mixer = RcMixer(RcMixerConfig(), release_when_disengaged=False)
    out = mixer.mix(sticks(roll=1234, pitch=1777, throttle=990, yaw=2011, switch=OFF), Contribution(50, 50, 50, 50))
    assert out.channels[:4] == (1234, 1777, 990, 2011)


def test_engaged_adds_contribution_with_sign_and_clamps() -> None:
    mixer = RcMixer(RcMixerConfig(stick_reversed=(False, True, False, False)))
    c = Contribution(roll_us=120.4, pitch_us=80.0, thrust_us=-60.0, yaw_rate_us=-30.0)
    out = mixer.mix(sticks(roll=1510, pitch=1490, throttle=1450, yaw=1500, switch=ON), c)
    assert out.engaged
    # roll 1510 + 120.4 = 1630.4 -> 1630; pitch reversed: 1490 - 80 = 1410;
    # throttle 1450 - 60 = 1390; yaw 1500 - 30 = 1470
    assert out.channels[:4] == (1630, 1410, 1390, 1470)
    assert out.channels[6] == IGNORE  # never override the pilot's switch
    # clamping: 1950 + 200 -> 2000, 1050 - 200 -> 1000
    out = mixer.mix(sticks(roll=1950, pitch=1050, switch=ON), Contribution(roll_us=200.0, pitch_us=200.0))
    assert out.channels[0] == 2000 and out.channels[1] == 1000
    assert mixer.clamped_outputs == 2


def test_contribution_is_limited_and_nan_is_rejected() -> None:
    mixer = RcMixer(RcMixerConfig(max_contribution_us=(300.0, 300.0, 250.0, 300.0)))
    out = mixer.mix(sticks(switch=ON), Contribution(roll_us=450.0, thrust_us=-400.0))
    assert out.channels[0] == 1800 and out.channels[2] == 1450 - 250
    assert mixer.clamped_contributions == 1
    out = mixer.mix(sticks(switch=ON), Contribution(roll_us=math.nan, pitch_us=100.0))
    assert out.engaged and out.channels[:4] == (1500, 1500, 1450, 1500)  # pilot only
    assert mixer.rejected_contributions == 1
    out = mixer.mix(sticks(switch=ON), None)
    assert out.channels[:4] == (1500, 1500, 1450, 1500)


def test_switch_threshold() -> None:
    mixer = RcMixer()
    assert not mixer.engaged_from(sticks(switch=1700))  # strictly above 1700
    assert mixer.engaged_from(sticks(switch=1701))
    assert not mixer.mix(sticks(switch=1700), None).engaged
    assert mixer.mix(sticks(switch=1701), None).engaged


def test_pilot_switch_returns_full_manual_within_one_call() -> None:
    ctl = DartController()
    mixer = RcMixer(on_disengage=ctl.disengage)
    setpoint = DartSetpoint(0.0, 0.0, 3.0)

    @dataclass(frozen=True)
    class Pose:
        time_s: float
        x_m: float = -0.4
        y_m: float = 0.1
        z_m: float = 3.3
        yaw_rad: float = 0.05

    t = 0.0
    for _ in range(60):  # engaged for ~2.7 s at 22 Hz
        pilot = sticks(switch=ON)
        cmd = ctl.update(t, Pose(t), setpoint, engaged=mixer.engaged_from(pilot))
        out = mixer.mix(pilot, cmd)
        assert out.engaged and out.channels[0] > 1500
        t += 1 / 22.0
    assert ctl.pid_x.integral > 0.0
    # the pilot flips the switch: this very call releases every mixed channel
    pilot = sticks(roll=1400, switch=OFF)
    out = mixer.mix(pilot, cmd)  # even with the stale engaged command passed in
    assert not out.engaged and out.disengaged_now
    assert out.channels[:4] == (RELEASE_LOW,) * 4
    assert out.sticks_us[0] == 1400
    assert all(p.integral == 0.0 for p in ctl.pids) and not ctl.engaged
    assert mixer.disengagements == 1
    # the next call stays manual, and disengaged_now is only reported once
    out = mixer.mix(pilot, None)
    assert not out.engaged and not out.disengaged_now


def test_invalid_pilot_input_disengages_and_counts() -> None:
    resets = []
    mixer = RcMixer(on_disengage=lambda: resets.append(1))
    assert mixer.mix(sticks(switch=ON), None).engaged
    out = mixer.mix(sticks(roll=math.nan, switch=ON), Contribution(roll_us=100.0))
    assert not out.engaged and resets == [1]
    assert out.channels[0] == RELEASE_LOW and out.sticks_us[0] is None
    assert mixer.invalid_inputs == 1
    # 0 / 65535 (RC_CHANNELS "unused") and a missing switch channel are invalid too
    assert not mixer.mix(sticks(yaw=65535, switch=ON), None).engaged
    assert not mixer.mix(sticks(throttle=0, switch=ON), None).engaged
    assert not mixer.mix(sticks(switch=ON)[:6], None).engaged
    assert mixer.invalid_inputs == 4
    # slightly out of [1000, 2000] but plausible: clamped while engaged
    out = mixer.mix(sticks(throttle=980, switch=ON), None)
    assert out.engaged and out.channels[2] == 1000 and mixer.clamped_inputs == 1


def test_channel_map_and_high_channels() -> None:
    # TAER order, yaw on channel 9 (release value for channels 9-18 is 65534)
    cfg = RcMixerConfig(stick_channels=(2, 3, 1, 9), switch_channel=5)  # roll, pitch, throttle, yaw
    mixer = RcMixer(cfg)
    pilot = [1300.0, 1500.0, 1500.0, 1500.0, 1900.0, 1500.0, 1500.0, 1500.0, 1600.0]
    out = mixer.mix(pilot, Contribution(roll_us=10.0, pitch_us=20.0, thrust_us=30.0, yaw_rate_us=40.0))
    assert out.engaged
    assert out.channels[0] == 1330 and out.channels[1] == 1510 and out.channels[2] == 1520
    assert out.channels[8] == 1640
    assert out.channels[3] == IGNORE
    pilot[4] = 1000.0
    out = mixer.mix(pilot, None)
    assert out.channels[8] == RELEASE_HIGH and out.channels[0] == RELEASE_LOW
    with pytest.raises(ValueError):
        RcMixerConfig(stick_channels=(3, 2, 3, 4))  # roll on throttle's channel
    with pytest.raises(ValueError):
        RcMixerConfig(switch_channel=19)


def test_px4_attitude_setpoint() -> None:
    m = AttitudeMapConfig(max_tilt_deg=30.0, max_yaw_rate_deg_s=100.0)
    # pilot: roll 1600 (+100 us), pitch neutral, throttle 1500, yaw 1450 (-50 us)
    # contribution: roll +50, pitch +100 (nose up), thrust +50, yaw +100
    sp = attitude_setpoint(
        sticks(roll=1600, pitch=1500, throttle=1500, yaw=1450),
        Contribution(roll_us=50.0, pitch_us=100.0, thrust_us=50.0, yaw_rate_us=100.0),
        mapping=m,
    )
    assert sp is not None
    assert sp.roll_rad == pytest.approx(150 / 500 * math.radians(30.0))  # 9 deg
    assert sp.pitch_rad == pytest.approx(100 / 500 * math.radians(30.0))  # 6 deg
    assert sp.yaw_rate_rad_s == pytest.approx(50 / 500 * math.radians(100.0))
    assert sp.thrust == pytest.approx(0.55)
    # reversed pitch channel: stick 1400 means +100 us nose up; clamp at full deflection
    cfg = RcMixerConfig(stick_reversed=(False, True, False, False))
    sp = attitude_setpoint(sticks(pitch=1400, roll=1900), Contribution(roll_us=300.0), cfg, m)
    assert sp is not None
    assert sp.pitch_rad == pytest.approx(0.2 * math.radians(30.0))
    assert sp.roll_rad == pytest.approx(math.radians(30.0))
    # pilot only, throttle clamps to [0, 1]; invalid sticks -> None
    sp = attitude_setpoint(sticks(throttle=1000), Contribution(thrust_us=-200.0))
    assert sp is not None and sp.thrust == 0.0
    assert attitude_setpoint(sticks(roll=math.nan), None) is None
