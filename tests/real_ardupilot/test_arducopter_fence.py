"""The companion's fence round trip on the real ArduCopter SITL: uploaded with the MAVLink mission
protocol (mission_type = FENCE), read back identical, replaced by a second upload; a polygon of two
vertices is refused by ArduPilot itself."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.fence import AutopilotFence, FencePolygon, fence_mismatch
from companion.autopilot.interface import AutopilotError
from companion_firmware.ardupilot_sitl import CMAC_HOME

from .conftest import arducopter

LAT, LON = round(CMAC_HOME[0] * 1e7), round(CMAC_HOME[1] * 1e7)
D = 20000  # 1e-7 deg: ~220 m
FENCE = AutopilotFence(
    (
        FencePolygon(True, ((LAT - D, LON - D), (LAT + D, LON - D), (LAT + D, LON + D), (LAT - D, LON + D))),
        FencePolygon(False, ((LAT + 5000, LON + 5000), (LAT + 8000, LON + 5000), (LAT + 6500, LON + 9000))),
    )
)


async def test_fence_round_trip_on_arducopter(ardupilot_root, tmp_path):
    with arducopter(ardupilot_root, tmp_path, truth=False) as (sitl, _):
        ap = ArduPilotAutopilot(sitl.connection)
        await ap.connect(timeout_s=30.0)
        try:
            await ap.upload_fence(FENCE)
            got = await ap.download_fence()
            assert fence_mismatch(FENCE, got) is None and got == FENCE
            smaller = AutopilotFence(FENCE.polygons[:1])
            await ap.upload_fence(smaller)
            assert await ap.download_fence() == smaller
            with pytest.raises(AutopilotError, match="refused by the vehicle"):
                await ap.upload_fence(AutopilotFence((FencePolygon(True, ((LAT, LON), (LAT + D, LON))),)))
            assert await ap.download_fence() == smaller  # the stored fence stays
        finally:
            await ap.close()
