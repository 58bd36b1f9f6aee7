"""On the real ArduCopter 4.7 SITL with the shipped parameters (params/ardupilot_quad.toml over the
short delivery's geometry) and the vehicle parameters the companion's pre-flight check expects
(FS_GCS_ENABLE = 5, a servo gripper, a battery failsafe): `companion fly` is SIGKILLed over the pad
at 5 m in the descent. ArduCopter's GCS failsafe (the companion's heartbeat is the one it watches)
must land it by itself near the pad and disarm; the gripper is never released.
"""

from __future__ import annotations

import asyncio
import time

import pytest

from companion.autopilot.ardupilot.modes import COPTER_MODES
from companion.config import shipped_params_path
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.companion_kill import SHORT_MISSION, fly_and_kill, log_line_after_s, write_fly_params
from companion_firmware.real_vehicle import ARDUCOPTER_GRIPPER_SERVO9
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.udp_relay import UdpRelay
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.firmware

# What `companion preflight` asks of the vehicle with params/ardupilot_quad.toml: the gripper on an
# output, a battery failsafe that acts, and the GCS failsafe landing where it is.
VEHICLE = {
    **ARDUCOPTER_GRIPPER_SERVO9,
    "FS_GCS_ENABLE": 5,
    "BATT_FS_LOW_ACT": 2,
    "BATT_FS_CRT_ACT": 1,
    "BATT_CRT_VOLT": 10.0,
}
GRIP_RELEASE_PWM = 1100  # GRIP_RELEASE default
STOP_S = 15.0  # how long the companion's loop hangs, or the whole process is frozen
MAV_CMD_SET_MESSAGE_INTERVAL = 511
SERVO_OUTPUT_RAW = 36
_NAMES = {v: k for k, v in COPTER_MODES.items()}


async def _fly_and_stop(ardupilot_root, tmp_path, how: str):
    """The short delivery on ArduCopter SITL, `companion fly` stopped (``how``) over the pad at 5 m
    in the descent; the outcome and the gripper output (time, PWM) seen on the truth link."""
    relay_port, port, truth_port = free_udp_port(), free_udp_port(), free_udp_port()
    overrides = {"mission": {**SHORT_MISSION, "ready_timeout_s": 120.0}}  # EKF3 uses GPS ~41 s after boot
    params = write_fly_params(shipped_params_path("ardupilot_quad.toml"), tmp_path / "fly.toml", overrides)
    sitl = ArduCopterSitl(
        ardupilot_root,
        extra_params=VEHICLE,
        serials={1: f"udpclient:127.0.0.1:{truth_port}", 2: f"udpclient:127.0.0.1:{relay_port}"},
        log_path=tmp_path / "arducopter.log",
    )
    relay = UdpRelay(relay_port, port, watch_commands=True)
    truth = MavlinkTruth(f"udpin:127.0.0.1:{truth_port}", message="SIM_STATE", watch=("HEARTBEAT", "SERVO_OUTPUT_RAW"))
    with relay, sitl, truth:
        await asyncio.to_thread(truth.wait, 15.0)
        await asyncio.to_thread(truth.command, MAV_CMD_SET_MESSAGE_INTERVAL, SERVO_OUTPUT_RAW, 200_000)
        r = await asyncio.to_thread(
            fly_and_kill,
            params,
            f"udpin://127.0.0.1:{port}",
            truth,
            relay,
            lambda m: _NAMES.get(m, str(m)),
            tmp_path / "run",
            how=how,
            stop_s=STOP_S,
        )
        grip = [(t, m.servo9_raw) for t, m in truth.watched_messages("SERVO_OUTPUT_RAW")]
    return r, grip


async def test_arducopter_lands_by_itself_when_the_companion_dies_in_the_descent(ardupilot_root, tmp_path):
    r, grip = await _fly_and_stop(ardupilot_root, tmp_path, "kill")
    print(f"\nArduCopter SITL, companion killed: {r.story()}; gripper output 9: {sorted({p for _, p in grip})} us")
    assert r.fly_returncode == -9
    assert r.commands_after_kill == 0
    assert r.release_commands == (), r.story()
    assert grip and all(p != GRIP_RELEASE_PWM for _, p in grip), grip
    # FS_GCS_TIMEOUT = 5 s after the companion's last heartbeat (checked at 3.3 Hz, seen on the 1 Hz
    # heartbeat): LAND (measured 5.0 s)
    assert r.modes[0][1] == "GUIDED" and r.changes_after_stop[:1] == ["LAND"], r.story()
    assert r.failsafe_after_s is not None and r.failsafe_after_s <= 7.0, r.story()
    # Until then GUIDED flies the last setpoint for GUID_TIMEOUT = 3 s: from 5 m at WPNAV_SPEED_DN =
    # 1.5 m/s that reaches the ground (measured 3.4 s); from higher it would stop, hold, and LAND
    # (4 s pause, 0.5 m/s) at most ~20 s after the kill. LAND on the ground disarms (measured 7.0 s).
    assert r.touchdown_after_s is not None and r.touchdown_after_s <= 25.0, r.story()
    assert r.touchdown_speed_m_s < 2.0, r.story()  # at most the descent limit, 1.5 m/s
    assert r.disarmed_after_s is not None and r.disarmed_after_s <= 30.0, r.story()
    # GUIDED and LAND hold the horizontal position on ArduCopter's estimate (measured 0.15 m drift,
    # 0.04 m from the pad); the kill point is within 3 m of the pad
    assert r.max_drift_m < 1.5 and r.landed_from_pad_m < 3.0, r.story()


@pytest.mark.parametrize("how", ["hang", "freeze"])
async def test_arducopter_lands_by_itself_while_the_companion_hangs_or_is_frozen(ardupilot_root, tmp_path, how):
    """The loop blocked 15 s (its other threads running: the reader would heartbeat on), or the
    whole process stopped 15 s (SIGSTOP). The companion's heartbeat stops either way (liveness),
    so the GCS failsafe lands it; nothing is released while it cannot supervise."""
    r, grip = await _fly_and_stop(ardupilot_root, tmp_path, how)
    said = log_line_after_s(tmp_path / "run.out", "control loop stalled", r.stopped_at_unix_s)
    print(f"\nArduCopter SITL, companion {how} {STOP_S:.0f} s: {r.story()}; watchdog said it {said} s after")
    stall_s = load_simulated_config(shipped_params_path("ardupilot_quad.toml")).runtime.loop_stall_s
    if how == "hang":  # said from the watchdog's thread while the loop was still blocked
        assert said is not None and stall_s - 0.05 <= said <= stall_s + 0.5, said
    # FS_GCS_TIMEOUT = 5 s after the last heartbeat (the loop's last tick + loop_stall_s on a hang)
    assert r.modes[0][1] == "GUIDED" and r.changes_after_stop[:1] == ["LAND"], r.story()
    assert r.failsafe_after_s is not None and r.failsafe_after_s <= 5.0 + stall_s + 2.0, r.story()
    assert r.touchdown_after_s is not None and r.touchdown_after_s <= 25.0, r.story()
    assert r.touchdown_speed_m_s < 2.0, r.story()
    assert r.disarmed_after_s is not None and r.disarmed_after_s <= 30.0, r.story()
    assert r.max_drift_m < 1.5 and r.landed_from_pad_m < 3.0, r.story()
    # the failsafe's landing released nothing: the gripper closed until the companion was back
    t_back = r.stopped_at_unix_s - time.time() + time.monotonic() + STOP_S
    assert grip and all(p != GRIP_RELEASE_PWM for t, p in grip if t < t_back), grip
    # back after the failsafe's landing, the companion released nothing: that landing was not its own
    assert not r.release_commands, r.story()
    assert all(p != GRIP_RELEASE_PWM for _, p in grip), grip
