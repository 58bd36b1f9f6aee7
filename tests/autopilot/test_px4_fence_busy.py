"""Px4Autopilot's fence download asks again while MAVSDK's geofence plugin answers BUSY (its last
download still alive) and passes every other refusal on at once."""

import pytest
from mavsdk.plugins.geofence import FenceType, GeofenceData, GeofenceError, GeofenceResult, Point, Polygon

from companion.autopilot.fence import AutopilotFence, FencePolygon
from companion.autopilot.interface import AutopilotError
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4 import fence as px4_fence

SQUARE = ((10, 20), (30, 20), (30, 40), (10, 40))


class Plugin:
    def __init__(self, refusals: list[GeofenceResult]) -> None:
        self.refusals = refusals
        self.calls = 0

    async def download_geofence(self) -> GeofenceData:
        self.calls += 1
        if self.refusals:
            raise GeofenceError(self.refusals.pop(0), "download_geofence()")
        points = [Point(lat / 1e7, lon / 1e7) for lat, lon in SQUARE]
        return GeofenceData([Polygon(points, FenceType.INCLUSION)], [])


def _autopilot(plugin: Plugin) -> Px4Autopilot:
    ap = Px4Autopilot("udpin://127.0.0.1:14599")
    ap._system = object()
    ap._geofence, ap._geofence_system = plugin, ap._system
    return ap


async def test_busy_is_asked_again_until_the_fence_comes(monkeypatch):
    monkeypatch.setattr(px4_fence, "BUSY_RETRY_S", 0.001)
    plugin = Plugin([GeofenceResult.BUSY, GeofenceResult.BUSY])
    got = await _autopilot(plugin).download_fence()
    assert got == AutopilotFence((FencePolygon(True, SQUARE),)) and plugin.calls == 3


async def test_another_refusal_is_not_asked_again(monkeypatch):
    monkeypatch.setattr(px4_fence, "BUSY_RETRY_S", 0.001)
    plugin = Plugin([GeofenceResult.BUSY, GeofenceResult.ERROR])
    with pytest.raises(AutopilotError, match="fence download failed: ERROR"):
        await _autopilot(plugin).download_fence()
    assert plugin.calls == 2


async def test_busy_for_ever_ends_at_the_transfer_timeout(monkeypatch):
    monkeypatch.setattr(px4_fence, "BUSY_RETRY_S", 0.001)
    monkeypatch.setattr(px4_fence, "TRANSFER_TIMEOUT_S", 0.3)  # long enough for a loaded core to ask a few times
    plugin = Plugin([GeofenceResult.BUSY] * 10**6)
    with pytest.raises(AutopilotError, match=r"no end within 0\.3 s"):
        await _autopilot(plugin).download_fence()
    assert plugin.calls > 3
