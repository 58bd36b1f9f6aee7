"""The companion's fence round trip on the real PX4 SIH through MAVSDK's geofence plugin (the
MAVLink mission protocol, mission_type = FENCE): uploaded, read back identical, replaced; a
polygon of two vertices refused, the stored fence kept."""

from __future__ import annotations

import pytest

from companion.autopilot.fence import AutopilotFence, FencePolygon, fence_mismatch
from companion.autopilot.interface import AutopilotError
from companion.autopilot.px4 import Px4Autopilot
from companion_firmware.px4_sitl import Px4Sitl

pytestmark = pytest.mark.firmware

LAT, LON = 473977420, 85455940  # PX4 SIH's default home (Zurich)
D = 20000  # 1e-7 deg: ~220 m
FENCE = AutopilotFence(
    (
        FencePolygon(True, ((LAT - D, LON - D), (LAT + D, LON - D), (LAT + D, LON + D), (LAT - D, LON + D))),
        FencePolygon(False, ((LAT + 5000, LON + 5000), (LAT + 8000, LON + 5000), (LAT + 6500, LON + 9000))),
    )
)


async def test_fence_round_trip_on_px4(px4_root, tmp_path):
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"):
        ap = Px4Autopilot("udpin://127.0.0.1:14540")
        await ap.connect(timeout_s=15.0)
        try:
            await ap.upload_fence(FENCE)
            got = await ap.download_fence()
            assert fence_mismatch(FENCE, got) is None, got
            smaller = AutopilotFence(FENCE.polygons[:1])
            await ap.upload_fence(smaller)
            assert fence_mismatch(smaller, await ap.download_fence()) is None
            with pytest.raises(AutopilotError, match="fence upload refused"):  # a polygon of 2 vertices
                await ap.upload_fence(AutopilotFence((FencePolygon(True, ((LAT, LON), (LAT + D, LON))),)))
            assert fence_mismatch(smaller, await ap.download_fence()) is None  # the stored fence stays
        finally:
            await ap.close()
