"""The fence round trip over MAVLink against the MAVLink sim vehicle (its fence protocol answered
as the firmware answers it): ArduPilot's mission protocol client and MAVSDK's geofence plugin."""

from __future__ import annotations

import asyncio

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.fence import AutopilotFence, FencePolygon, fence_mismatch
from companion.autopilot.interface import AutopilotError
from companion.autopilot.px4 import Px4Autopilot
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimConfig

LAT, LON = -198690000, -439638000
D = 20000  # 1e-7 deg: 220 m
FENCE = AutopilotFence(
    (
        FencePolygon(True, ((LAT - D, LON - D), (LAT + D, LON - D), (LAT + D, LON + D), (LAT - D, LON + D))),
        FencePolygon(False, ((LAT + 5000, LON + 5000), (LAT + 8000, LON + 5000), (LAT + 6500, LON + 9000))),
    )
)


def _round_trip(dialect: str, make: object, second: AutopilotFence | None = None) -> tuple[AutopilotFence, object]:
    port = free_udp_port()
    sim = mavlink_sim_vehicle(SimConfig(ready_delay_s=0.0), dialect, remote=("127.0.0.1", port)).start()  # type: ignore[arg-type]

    async def go() -> AutopilotFence:
        ap = make(port)  # type: ignore[operator]
        await ap.connect(5.0)
        try:
            await ap.upload_fence(FENCE)
            if second is not None:
                await ap.upload_fence(second)  # replaces the first
            return await ap.download_fence()
        finally:
            await ap.close()

    try:
        got = asyncio.run(go())
    finally:
        sim.stop()
    return got, sim


def test_ardupilot_fence_round_trip() -> None:
    got, sim = _round_trip("ardupilot", lambda port: ArduPilotAutopilot(f"udpin:127.0.0.1:{port}"))
    assert fence_mismatch(FENCE, got) is None
    assert got == FENCE
    assert len(sim.fence) == 7 and sim.fence_uploads == 1  # type: ignore[attr-defined]


def test_ardupilot_fence_replaced_by_a_second_upload() -> None:
    smaller = AutopilotFence(FENCE.polygons[:1])
    got, sim = _round_trip("ardupilot", lambda port: ArduPilotAutopilot(f"udpin:127.0.0.1:{port}"), smaller)
    assert got == smaller and sim.fence_uploads == 2  # type: ignore[attr-defined]


def test_px4_fence_round_trip_through_mavsdk() -> None:
    got, sim = _round_trip("px4", lambda port: Px4Autopilot(f"udpin://127.0.0.1:{port}"))
    assert fence_mismatch(FENCE, got) is None
    assert len(sim.fence) == 7  # type: ignore[attr-defined]


@pytest.mark.parametrize(
    "dialect, answer",
    [
        # ArduPilot takes every item and fails the whole upload (write_fence's validation)
        ("ardupilot", "refused by the vehicle: MAV_MISSION_ERROR"),
        # PX4 refuses the vertex itself (mavlink_mission.cpp); MAVSDK names it an invalid argument
        ("px4", "fence upload refused"),
    ],
)
def test_a_two_vertex_polygon_is_refused_as_the_firmware_refuses_it(dialect: str, answer: str) -> None:
    bad = AutopilotFence((FencePolygon(True, ((LAT, LON), (LAT + 1, LON))),))
    port = free_udp_port()
    sim = mavlink_sim_vehicle(SimConfig(ready_delay_s=0.0), dialect, remote=("127.0.0.1", port)).start()  # type: ignore[arg-type]

    async def go() -> None:
        ap = (
            ArduPilotAutopilot(f"udpin:127.0.0.1:{port}")
            if dialect == "ardupilot"
            else Px4Autopilot(f"udpin://127.0.0.1:{port}")
        )
        await ap.connect(5.0)
        try:
            await ap.upload_fence(FENCE)
            await ap.upload_fence(bad)
        finally:
            await ap.close()

    try:
        with pytest.raises(AutopilotError, match=answer):
            asyncio.run(go())
    finally:
        sim.stop()
    assert len(sim.fence) == 7  # the fence stored before stays
