"""The companion's fence round trip on the real firmware (PX4 SIH through MAVSDK's geofence plugin,
ArduCopter SITL through pymavlink; both the MAVLink mission protocol, mission_type = FENCE):
uploaded, read back identical, replaced by a second upload; a polygon of two vertices refused by
the autopilot, the stored fence kept."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from companion.autopilot.fence import AutopilotFence, FencePolygon, fence_mismatch
from companion.autopilot.interface import AutopilotError
from companion_firmware.ardupilot_sitl import CMAC_HOME

pytestmark = pytest.mark.firmware

# each SITL's default home, 1e-7 deg: PX4 SIH's (Zurich), ArduCopter's (CMAC)
HOME = {"px4": (473977420, 85455940), "ardupilot": (round(CMAC_HOME[0] * 1e7), round(CMAC_HOME[1] * 1e7))}
D = 20000  # 1e-7 deg: ~220 m
# how each refuses the 2-vertex polygon: MAVSDK's upload result, ArduPilot's MISSION_ACK
REFUSED = {"px4": "fence upload refused", "ardupilot": "refused by the vehicle"}


def _fence(lat: int, lon: int) -> AutopilotFence:
    return AutopilotFence(
        (
            FencePolygon(True, ((lat - D, lon - D), (lat + D, lon - D), (lat + D, lon + D), (lat - D, lon + D))),
            FencePolygon(False, ((lat + 5000, lon + 5000), (lat + 8000, lon + 5000), (lat + 6500, lon + 9000))),
        )
    )


@contextlib.contextmanager
def _autopilot(name: str, root: Path, tmp_path: Path) -> Iterator[tuple[Any, float]]:
    """The started SITL's autopilot (not connected) and its connect timeout."""
    if name == "px4":
        from companion.autopilot.px4 import Px4Autopilot
        from companion_firmware.px4_sitl import Px4Sitl

        with Px4Sitl(root, log_path=tmp_path / "px4.log"):
            yield Px4Autopilot("udpin://127.0.0.1:14540"), 15.0
        return
    from companion.autopilot.ardupilot import ArduPilotAutopilot
    from companion_firmware.ardupilot_sitl import ArduCopterSitl

    with ArduCopterSitl(root, extra_params={}, serials={}, log_path=tmp_path / "arducopter.log") as sitl:
        yield ArduPilotAutopilot(sitl.connection), 30.0


async def test_fence_round_trip(firmware, tmp_path):
    name, root = firmware
    lat, lon = HOME[name]
    fence = _fence(lat, lon)
    with _autopilot(name, root, tmp_path) as (ap, connect_timeout_s):
        await ap.connect(timeout_s=connect_timeout_s)
        try:
            await ap.upload_fence(fence)
            got = await ap.download_fence()
            assert fence_mismatch(fence, got) is None, got
            if name == "ardupilot":  # ArduPilot gives the very polygons back
                assert got == fence
            smaller = AutopilotFence(fence.polygons[:1])
            await ap.upload_fence(smaller)
            back = await ap.download_fence()
            assert fence_mismatch(smaller, back) is None
            if name == "ardupilot":
                assert back == smaller
            with pytest.raises(AutopilotError, match=REFUSED[name]):  # a polygon of 2 vertices
                await ap.upload_fence(AutopilotFence((FencePolygon(True, ((lat, lon), (lat + D, lon))),)))
            kept = await ap.download_fence()
            assert fence_mismatch(smaller, kept) is None  # the stored fence stays
            if name == "ardupilot":
                assert kept == smaller
        finally:
            await ap.close()
