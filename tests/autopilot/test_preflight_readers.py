"""The backends' readers behind the pre-flight check, against the MAVLink sim vehicle on loopback:
PX4 parameters through MAVSDK's Param plugin (byte-wise int32, the other type on WRONG_TYPE, a
missing one as unavailable), ArduPilot by PARAM_REQUEST_READ, SYSTEM_TIME on both."""

from __future__ import annotations

import asyncio
import time

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.preflight.report import ParamUnavailable
from companion.autopilot.px4 import Px4Autopilot
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimConfig


def test_px4_reads_by_type_and_names_a_missing_parameter() -> None:
    port = free_udp_port()
    sim = mavlink_sim_vehicle(
        SimConfig(ready_delay_s=0.0),
        "px4",
        remote=("127.0.0.1", port),
        params={"COM_OBL_RC_ACT": 5.0},
        clock_offset_s=2.0,
    ).start()

    async def go() -> tuple[dict[str, object], tuple[int, float] | None]:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{port}")
        await ap.connect(5.0)
        try:
            values = await ap.read_params(
                {"COM_OBL_RC_ACT": "int", "COM_OF_LOSS_T": "int", "EKF2_GPS_CTRL": "int", "NO_SUCH_PARAM": "float"}
            )
            return values, await ap.system_time(2.0)
        finally:
            await ap.close()

    try:
        values, st = asyncio.run(go())
    finally:
        sim.stop()
    assert values["COM_OBL_RC_ACT"] == 5.0  # byte-wise int32, decoded by MAVSDK
    assert values["COM_OF_LOSS_T"] == 1.0  # a float asked as int: WRONG_TYPE, then read as float
    assert values["EKF2_GPS_CTRL"] == 7.0
    missing = values["NO_SUCH_PARAM"]
    assert isinstance(missing, ParamUnavailable) and "TIMEOUT" in missing.reason
    assert st is not None and abs(st[0] / 1e6 - st[1] - 2.0) < 0.5  # the vehicle's UTC runs 2 s ahead


def test_ardupilot_reads_parameters_and_system_time() -> None:
    port = free_udp_port()
    sim = mavlink_sim_vehicle(SimConfig(ready_delay_s=0.0), "ardupilot", remote=("127.0.0.1", port)).start()

    async def go() -> tuple[list[float | None], tuple[int, float] | None]:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{port}")
        await ap.connect(5.0)
        try:
            names = ["GUID_TIMEOUT", "RC_OVERRIDE_TIME", "FS_GCS_ENABLE", "SERVO1_FUNCTION", "NO_SUCH_PARAM"]
            return [await ap.read_param(n) for n in names], await ap.system_time(2.0)
        finally:
            await ap.close()

    try:
        values, st = asyncio.run(go())
    finally:
        sim.stop()
    assert values == [3.0, 3.0, 0.0, 33.0, None]  # copter.parm defaults; SERVO1 drives motor 1
    assert st is not None and abs(st[0] / 1e6 - st[1]) < 0.5 and abs(st[1] - time.time()) < 10.0
