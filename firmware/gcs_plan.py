"""A delivery planned in the operator's GCS, as the real-firmware tests upload it through
:class:`~companion_firmware.gcs_probe.GcsProbe` (docs/gcs.md): take-off, a waypoint at the pad,
a gripper release, return to launch (QGroundControl's items for a drop), and where the
autopilot's own global position said the vehicle was when the parcel went."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from companion.geometry.earth import GeoPoint, geo_to_ned, ned_to_geo
from companion_firmware.gcs_probe import MAV_FRAME_GLOBAL_RELATIVE_ALT, GcsMissionItem

MAV_FRAME_MISSION = 2
MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_TAKEOFF, MAV_CMD_DO_GRIPPER = 16, 20, 22, 211


def delivery_plan(
    home_lat_deg: float, home_lon_deg: float, north_m: float, east_m: float, alt_rel_m: float = 8.0
) -> tuple[list[GcsMissionItem], GeoPoint]:
    """The plan's items and its pad (``north_m``, ``east_m`` from home; altitudes relative)."""
    pad = ned_to_geo(GeoPoint(home_lat_deg, home_lon_deg, 0.0), north_m, east_m, 0.0)
    rel = MAV_FRAME_GLOBAL_RELATIVE_ALT
    items = [
        GcsMissionItem(rel, MAV_CMD_NAV_TAKEOFF, 0.0, 0.0, alt_rel_m),
        GcsMissionItem(rel, MAV_CMD_NAV_WAYPOINT, pad.lat_deg, pad.lon_deg, alt_rel_m),
        GcsMissionItem(MAV_FRAME_MISSION, MAV_CMD_DO_GRIPPER, 0.0, 0.0, 0.0, param1=1.0, param2=0.0),  # release
        GcsMissionItem(MAV_FRAME_MISSION, MAV_CMD_NAV_RETURN_TO_LAUNCH, 0.0, 0.0, 0.0),  # PX4: no other frame
    ]
    return items, pad


@dataclass
class ReleaseWhere:
    """A shell's ``on_tick``: the autopilot's global position when the mission first reaches the
    release (its own estimate: the pad the companion flew to, independent of the companion's
    local-frame arithmetic)."""

    position: Any = None

    def __call__(self, shell: Any, out: Any) -> None:
        if self.position is None and out.phase.value == "release":
            self.position = shell.autopilot.telemetry.global_position

    def distance_m(self, pad: GeoPoint) -> float:
        """Horizontal metres from ``pad``; inf when the release was never reached."""
        if self.position is None:
            return math.inf
        n, e, _ = geo_to_ned(pad, GeoPoint(self.position.lat_deg, self.position.lon_deg, 0.0))
        return math.hypot(n, e)
