"""PX4's fence through MAVSDK's geofence plugin (upload_geofence / download_geofence), which speaks
the MAVLink mission protocol with mission_type = MAV_MISSION_TYPE_FENCE. PX4 keeps the polygons in
its dataman and acts on a breach with GF_ACTION (checked by ``companion preflight``)."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from companion.autopilot.fence import AutopilotFence, FencePolygon
from companion.autopilot.interface import AutopilotError

log = logging.getLogger(__name__)

TRANSFER_TIMEOUT_S = 30.0
# MAVSDK's geofence plugin answers BUSY while its last download's work item is still alive, done
# or not (geofence_impl.cpp checks the weak pointer only; mission_raw also checks is_done()), so a
# download right after another transfer can be refused once. Real PX4 SIH hit it in CI.
BUSY_RETRY_S = 0.2


class Px4Fence:
    """Mixin of the PX4 backend (uses its MAVSDK ``_system``)."""

    _system: Any
    _geofence: Any = None
    _geofence_system: Any = None  # the system it was built on (a reconnect makes a new one)

    def _geofence_plugin(self, what: str) -> Any:
        if self._system is None:
            raise AutopilotError(f"fence {what}: not connected")
        if self._geofence is None or self._geofence_system is not self._system:
            from mavsdk.asyncio.plugins.geofence import GeofenceAsync

            self._geofence = GeofenceAsync(self._system)
            self._geofence_system = self._system
        return self._geofence

    async def upload_fence(self, fence: AutopilotFence) -> None:
        from mavsdk.plugins.geofence import FenceType, GeofenceData, Point, Polygon

        plugin = self._geofence_plugin("upload")
        polygons = [
            Polygon(
                [Point(lat / 1e7, lon / 1e7) for lat, lon in p.vertices_e7],
                FenceType.INCLUSION if p.inclusion else FenceType.EXCLUSION,
            )
            for p in fence.polygons
        ]
        try:
            await asyncio.wait_for(plugin.upload_geofence(GeofenceData(polygons, [])), TRANSFER_TIMEOUT_S)
        except TimeoutError:
            raise AutopilotError(f"fence upload: no end within {TRANSFER_TIMEOUT_S:g} s") from None
        except Exception as err:  # MAVSDK's GeofenceError
            raise AutopilotError(f"fence upload refused: {err}") from None
        log.info("fence uploaded: %s", fence.describe())

    async def download_fence(self) -> AutopilotFence:
        from mavsdk.plugins.geofence import FenceType

        plugin = self._geofence_plugin("download")
        try:
            data = await asyncio.wait_for(self._download_past_busy(plugin), TRANSFER_TIMEOUT_S)
        except TimeoutError:
            raise AutopilotError(f"fence download: no end within {TRANSFER_TIMEOUT_S:g} s") from None
        except Exception as err:
            raise AutopilotError(f"fence download failed: {err}") from None
        if data.circles:
            raise AutopilotError(f"fence read back: {len(data.circles)} circles the companion never sent")
        return AutopilotFence(
            tuple(
                FencePolygon(
                    p.fence_type == FenceType.INCLUSION,
                    tuple((round(pt.latitude_deg * 1e7), round(pt.longitude_deg * 1e7)) for pt in p.points),
                )
                for p in data.polygons
            )
        )

    @staticmethod
    async def _download_past_busy(plugin: Any) -> Any:
        """download_geofence(), asked again while MAVSDK answers BUSY (the caller's timeout ends it)."""
        from mavsdk.plugins.geofence import GeofenceResult

        while True:
            try:
                return await plugin.download_geofence()
            except Exception as err:
                if getattr(err, "result", None) != GeofenceResult.BUSY:
                    raise
                log.debug("fence download: MAVSDK busy, asking again in %g s", BUSY_RETRY_S)
                await asyncio.sleep(BUSY_RETRY_S)
