"""Against a real ArduCopter SITL build: the backend flies it (arm waits for EKF3, take off,
GUIDED velocity, LAND), SIM_STATE ground truth matches its GLOBAL_POSITION_INT, and GUIDED
velocity control times out on the vehicle when the setpoints stop. One SITL for the module."""

from __future__ import annotations

import asyncio
import math
import time

import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20.ardupilotmega import MAV_CMD_SET_MESSAGE_INTERVAL

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.types import FlightMode, LandedState
from companion.geometry.earth import GeoPoint, LocalTangentPlane
from companion.guidance.setpoint import VelocitySetpoint
from companion_firmware.ardupilot_sitl import CMAC_HOME, ArduPilotNotFound, find_ardupilot

from .conftest import arducopter, wait_for

pytestmark = pytest.mark.firmware


def test_find_ardupilot_reports_where_it_looked(tmp_path):
    with pytest.raises(ArduPilotNotFound, match="no ArduCopter SITL build at"):
        find_ardupilot(tmp_path)


@pytest.fixture(scope="module")
def copter(ardupilot_root, tmp_path_factory):
    with arducopter(ardupilot_root, tmp_path_factory.mktemp("arducopter")) as (sitl, truth):
        yield sitl, truth


def test_fast_boot_leaves_a_real_time_sitl_on_the_wall_clock(copter):
    """ArduCopterSitl boots at 10x until EKF3 uses GPS (41 s of simulated time in ~4 s), then runs
    in real time with its UTC on the wall clock (started early by what the boot gains)."""
    sitl, _truth = copter
    assert abs(sitl.clock_offset_s) < 1.0, sitl.clock_offset_s
    link = mavutil.mavlink_connection(sitl.connection, source_system=251)
    try:
        assert link.wait_heartbeat(timeout=5.0) is not None
        sysid, compid = link.target_system, link.target_component
        link.mav.command_long_send(sysid, compid, MAV_CMD_SET_MESSAGE_INTERVAL, 0, 2, 100_000, 0, 0, 0, 0, 0)
        samples = []
        t_end = time.monotonic() + 3.0
        while time.monotonic() < t_end:
            m = link.recv_match(type="SYSTEM_TIME", blocking=True, timeout=1.0)
            if m is not None:
                samples.append((time.monotonic(), time.time(), m.time_boot_ms * 1e-3, m.time_unix_usec * 1e-6))
        link.mav.command_long_send(sysid, compid, MAV_CMD_SET_MESSAGE_INTERVAL, 0, 2, 0, 0, 0, 0, 0, 0)
    finally:
        link.close()
    assert len(samples) > 10
    (w0, _, b0, _), (w1, wall1, b1, utc1) = samples[0], samples[-1]
    # simulated time runs at the wall clock's rate (SIM_SPEEDUP back to 1) and reads the same UTC
    assert (b1 - b0) / (w1 - w0) == pytest.approx(1.0, abs=0.05)
    assert b0 > 40.0  # booted past the EKF's GPS wait
    assert abs(utc1 - wall1) < 1.0


async def _airborne(ap: ArduPilotAutopilot, alt_m: float) -> None:
    await ap.arm()  # GUIDED; refused ("Need Position Estimate") until EKF3 uses GPS, retried
    await ap.takeoff(alt_m)
    await wait_for(
        lambda: ap.telemetry.global_position is not None and ap.telemetry.global_position.alt_rel_m > alt_m - 0.3,
        20.0,
        f"take off to {alt_m} m",
    )


async def _land(ap: ArduPilotAutopilot) -> float:
    await ap.land()
    return await wait_for(
        lambda: (st := ap.telemetry.status) is not None and st.landed is LandedState.ON_GROUND and not st.armed,
        40.0,
        "landed and disarmed",
    )


def _gpi_ned(ap: ArduPilotAutopilot, origin: GeoPoint) -> tuple[float, float, float]:
    g = ap.telemetry.global_position
    assert g is not None
    return LocalTangentPlane(origin).to_ned(GeoPoint(g.lat_deg, g.lon_deg, g.alt_amsl_m))


async def test_arm_take_off_guided_velocity_and_land_on_truth(copter):
    sitl, truth = copter
    origin = truth.origin
    # the truth origin is the true home given on the command line
    assert origin.lat_deg == pytest.approx(CMAC_HOME[0], abs=2e-7) and origin.lon_deg == pytest.approx(
        CMAC_HOME[1], abs=2e-7
    )
    ap = ArduPilotAutopilot(sitl.connection, arm_timeout_s=90.0)
    await ap.connect(timeout_s=15.0)
    try:
        t0 = time.monotonic()
        await _airborne(ap, 5.0)
        t_air = time.monotonic() - t0
        assert truth.pd == pytest.approx(-5.0, abs=0.5)
        await ap.start_offboard()
        for _ in range(60):  # 3 s north at 2 m/s
            ap.set_velocity_ned(VelocitySetpoint(2.0, 0.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        assert ap.mode is FlightMode.OFFBOARD
        assert truth.pn > 3.5 and abs(truth.pe) < 0.5, (truth.pn, truth.pe)
        # noise-free SITL: the vehicle's own estimate is the truth within centimetres
        n, e, d = _gpi_ned(ap, origin)
        assert math.hypot(n - truth.pn, e - truth.pe) < 0.3 and abs(d - truth.pd) < 0.3, ((n, e, d), truth._state)
        t_land = await _land(ap)
        assert ap.mode is FlightMode.LAND  # ArduCopter stays in LAND, disarmed
        print(f"arm+takeoff {t_air:.1f} s, land {t_land:.1f} s, truth samples {truth.samples}")
    finally:
        await ap.close()


async def test_guided_velocity_times_out_and_the_vehicle_stops(copter):
    """GUID_TIMEOUT (3 s): the last velocity is flown for that long, then the vehicle brakes and
    holds, still in GUIDED."""
    sitl, truth = copter
    ap = ArduPilotAutopilot(sitl.connection, arm_timeout_s=90.0)
    await ap.connect(timeout_s=15.0)
    try:
        await _airborne(ap, 4.0)  # arm() leaves LAND for GUIDED first ("LAND mode not armable")
        await ap.start_offboard()
        for _ in range(40):
            ap.set_velocity_ned(VelocitySetpoint(0.0, 2.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        t_stop = time.monotonic()
        samples = []
        while time.monotonic() - t_stop < 6.5:
            samples.append((time.monotonic() - t_stop, truth.pe))
            await asyncio.sleep(0.05)
        # east speed over 0.25 s windows, stamped at their middle
        speed = [
            ((t0 + t1) / 2, (e1 - e0) / (t1 - t0)) for (t0, e0), (t1, e1) in zip(samples, samples[5:], strict=False)
        ]
        still_fast = [t for t, v in speed if v > 1.5]
        stopped = next(t for t, v in speed if t > 2.0 and abs(v) < 0.1)
        print(f"last setpoint +{max(still_fast):.2f} s still at 2 m/s; stopped at +{stopped:.2f} s")
        assert 2.5 < max(still_fast) < 4.0  # flies the last setpoint for GUID_TIMEOUT = 3 s (+ braking)
        assert stopped < 5.5
        assert ap.mode is FlightMode.OFFBOARD  # still GUIDED
        e_hold = truth.pe
        await asyncio.sleep(1.0)
        assert abs(truth.pe - e_hold) < 0.1  # holds
        await _land(ap)
    finally:
        await ap.close()


async def test_preflight_names_arducopters_default_gripper_as_wrong(copter):
    """`companion preflight --json` as a user runs it against this SITL: copter.parm's defaults
    are right for the companion except the gripper (GRIP_ENABLE = 0, no output with function 28),
    which the shipped parameters release with, and the battery failsafe (BATT_FS_LOW_ACT and
    BATT_FS_CRT_ACT 0: nothing acts with the companion gone): exit 6, those rows wrong."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    sitl, _truth = copter
    params = Path(__file__).resolve().parents[2] / "params" / "ardupilot_quad.toml"
    cmd = [sys.executable, "-m", "companion", "preflight", "--params", str(params), "--connection", sitl.connection]
    proc = await asyncio.to_thread(subprocess.run, [*cmd, "--json"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 6, proc.stderr
    rows = {r["check"]: r for r in json.loads(proc.stdout)["checks"]}
    assert rows["GRIP_ENABLE"]["status"] == "wrong" and "set GRIP_ENABLE = 1" in rows["GRIP_ENABLE"]["detail"]
    assert rows["gripper output"]["status"] == "wrong"
    assert rows["battery failsafe"]["status"] == "wrong" and "BATT_FS_LOW_ACT = 2" in rows["battery failsafe"]["detail"]
    for name in ("FENCE_ENABLE", "BATT_FS_LOW_ACT", "BATT_FS_CRT_ACT", "DID_ENABLE"):
        assert rows[name]["status"] == "ok", rows[name]
    for name in ("GUID_TIMEOUT", "RC_OVERRIDE_TIME", "FS_OPTIONS", "FLTMODE_CH", "attitude rate"):
        assert rows[name]["status"] == "ok", rows[name]
    # copter.parm leaves the GCS failsafe off: a dead companion would leave the vehicle hovering
    assert rows["FS_GCS_ENABLE"]["status"] == "warn" and "FS_GCS_ENABLE = 5" in rows["FS_GCS_ENABLE"]["detail"]
    # ok once the EKF has an origin and GPS time (after the flights above); on a fresh boot nothing
    # arrives yet: unknown, never wrong
    for name in ("local position rate", "clock"):
        assert rows[name]["status"] in ("ok", "unknown"), rows[name]
