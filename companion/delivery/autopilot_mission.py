"""The delivery an operator planned in the GCS: the pad read from the mission uploaded to the
autopilot (``mission.destination = "autopilot_mission"``, docs/gcs.md).

The rule, applied to the items the backend downloaded (companion.autopilot.mission_plan):

- a delivery item is a NAV_PAYLOAD_PLACE (94), or a NAV_WAYPOINT (16) or NAV_LAND (21)
  immediately followed by DO_GRIPPER (211) with param2 = 0 (release); its latitude and longitude
  are the pad's;
- the first delivery item is the pad, a second one the alternate pad; none, or more than two, or
  two within the pad's size of each other, is refused;
- a DO_GRIPPER release anywhere else (not right after a waypoint or a landing) is refused: it would
  drop the parcel at a place the companion cannot tell;
- the delivery item's frame must be global: MAV_FRAME_GLOBAL, _GLOBAL_INT (altitude AMSL) or
  MAV_FRAME_GLOBAL_RELATIVE_ALT, _RELATIVE_ALT_INT (altitude above home); anything else (local,
  terrain, body frames) is refused;
- the pad's ground altitude: a NAV_LAND's altitude is the ground it lands on (MAVLink: "landing
  altitude, ground level in current frame"), so a NAV_LAND in an AMSL frame gives the pad's
  altitude AMSL, and one relative to home must be at 0 (the home's ground). A waypoint's or a
  payload-place's altitude is where the vehicle flies, not the ground: the pad is then taken at the
  home's ground altitude (as a ``[mission.pad]`` without ``alt_amsl_m``), and the companion flies
  its own ``mission.height_m`` above it.
Every refusal names the item (as the GCS numbers it), its command, and what is expected.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from companion.autopilot.interface import Autopilot, AutopilotError
from companion.autopilot.mission_plan import (
    GRIPPER_ACTION_RELEASE,
    MAV_CMD_DO_GRIPPER,
    MAV_CMD_NAV_LAND,
    MAV_CMD_NAV_PAYLOAD_PLACE,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL,
    MAV_FRAME_GLOBAL_INT,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    PlanItem,
    command_name,
    frame_name,
)
from companion.config import CompanionConfig
from companion.delivery.destination import Destination, DestinationError, GeoPad, config_for_destination
from companion.geometry.earth import GeoPoint, geo_to_ned

log = logging.getLogger(__name__)

AMSL_FRAMES = (MAV_FRAME_GLOBAL, MAV_FRAME_GLOBAL_INT)
RELATIVE_FRAMES = (MAV_FRAME_GLOBAL_RELATIVE_ALT, MAV_FRAME_GLOBAL_RELATIVE_ALT_INT)
LAND_REL_ALT_TOLERANCE_M = 0.5  # a NAV_LAND relative to home "at the home's ground"

EXPECTED = (
    "expected a NAV_PAYLOAD_PLACE (94) at the pad, or a NAV_WAYPOINT (16) or NAV_LAND (21) at the "
    "pad immediately followed by DO_GRIPPER (211) with param2 = 0 (release)"
)


class MissionPlanError(DestinationError):
    """The autopilot's mission names no delivery the companion can fly; ``reason`` says which item
    and what is expected."""


def _is_release(item: PlanItem, where: str) -> bool:
    if item.command != MAV_CMD_DO_GRIPPER:
        return False
    if not math.isfinite(item.param2):  # neither release nor grab: the parcel's fate unknown
        raise MissionPlanError(
            f"{where} {item.describe()}: gripper action {item.param2}: expected 0 (release) or 1 (grab)"
        )
    return round(item.param2) == GRIPPER_ACTION_RELEASE


def delivery_items(items: Sequence[PlanItem], where: str = "autopilot mission") -> list[PlanItem]:
    """The delivery items of a mission, in order (the rule in the module's docstring); a release
    that follows no waypoint or landing is refused. ``where`` names the mission in errors."""
    found: list[PlanItem] = []
    for i, it in enumerate(items):
        if it.command == MAV_CMD_NAV_PAYLOAD_PLACE:
            found.append(it)
        elif _is_release(it, where):
            prev = items[i - 1] if i > 0 else None
            if prev is None or prev.command not in (MAV_CMD_NAV_WAYPOINT, MAV_CMD_NAV_LAND):
                after = f"follows {prev.describe()}" if prev is not None else "is the mission's first item"
                raise MissionPlanError(
                    f"{where} {it.describe()} (release) {after}: the companion cannot tell where "
                    f"it would drop the parcel; {EXPECTED}"
                )
            found.append(prev)
    return found


def _pad(item: PlanItem, mission: str) -> GeoPad:
    where = f"{mission} {item.describe()}"
    frame = item.frame
    if frame not in AMSL_FRAMES + RELATIVE_FRAMES:
        raise MissionPlanError(
            f"{where} is in {frame_name(frame)} ({frame}): expected a global frame, MAV_FRAME_GLOBAL (0), "
            "MAV_FRAME_GLOBAL_RELATIVE_ALT (3), MAV_FRAME_GLOBAL_INT (5) or MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (6)"
        )
    lat, lon = item.x / 1e7, item.y / 1e7
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0) or (item.x == 0 and item.y == 0):
        raise MissionPlanError(
            f"{where} is at latitude {lat:.7f}, longitude {lon:.7f}: expected the pad's position "
            "(a position left at 0, 0 was never set)"
        )
    alt: float | None = None
    if item.command == MAV_CMD_NAV_LAND:
        if not math.isfinite(item.z):
            raise MissionPlanError(f"{where}: landing altitude {item.z}: expected a finite altitude in metres")
        if frame in AMSL_FRAMES:
            alt = float(item.z)
        elif abs(item.z) > LAND_REL_ALT_TOLERANCE_M:
            raise MissionPlanError(
                f"{where}: landing altitude {item.z:g} m above home in {frame_name(frame)}: expected 0 (the pad "
                "on the home's ground), or the pad's ground altitude in MAV_FRAME_GLOBAL (AMSL)"
            )
    return GeoPad(lat, lon, alt)


def _whole(where: str) -> str:
    """The mission as a whole, in an error: the autopilot's, or a plan file's."""
    return "the autopilot's mission" if where == "autopilot mission" else where


def destination_from_mission(
    items: Sequence[PlanItem], min_separation_m: float = 1.0, where: str = "autopilot mission"
) -> Destination:
    """The delivery the mission plans: its pad (and alternate), ``source`` naming the items; a
    :class:`MissionPlanError` when the mission plans none the companion can fly. ``where`` names
    the mission in the errors and the source ("autopilot mission", or a plan file's)."""
    if not items:
        empty = (
            "the autopilot holds no mission: upload one from the GCS"
            if where == "autopilot mission"
            else f"{where} has no mission items"
        )
        raise MissionPlanError(f"{empty}; {EXPECTED}")
    found = delivery_items(items, where)
    if not found:
        listed = ", ".join(f"{it.index} {command_name(it.command)}" for it in items[:12])
        more = f" and {len(items) - 12} more" if len(items) > 12 else ""
        raise MissionPlanError(f"{_whole(where)} (items {listed}{more}) has no delivery item: {EXPECTED}")
    if len(found) > 2:
        names = ", ".join(it.describe() for it in found)
        raise MissionPlanError(
            f"{_whole(where)} has {len(found)} delivery items ({names}): ambiguous; expected one (the pad) "
            "or two (the pad, then the alternate pad)"
        )
    pad = _pad(found[0], where)
    source = f"{where} {found[0].describe()}"
    alternate = None
    if len(found) == 2:
        alternate = _pad(found[1], where)
        n, e, _ = geo_to_ned(
            GeoPoint(pad.lat_deg, pad.lon_deg, 0.0), GeoPoint(alternate.lat_deg, alternate.lon_deg, 0.0)
        )
        apart = math.hypot(n, e)
        if apart < min_separation_m:
            raise MissionPlanError(
                f"{where} {found[0].describe()} and {found[1].describe()} are {apart:.2f} m apart: "
                f"ambiguous; expected the second (the alternate pad) at least {min_separation_m:g} m from the "
                "first, or one delivery item"
            )
        source += f", alternate {found[1].describe()}"
    return Destination(pad=pad, source=source, alternate=alternate)


class MissionDownloadError(AutopilotError):
    """The autopilot did not hand its mission over (no answer, a broken transfer)."""


def _describe_pad(p: GeoPad) -> str:
    alt = "the home's ground" if p.alt_amsl_m is None else f"{p.alt_amsl_m:.1f} m AMSL"
    return f"{p.lat_deg:.7f}, {p.lon_deg:.7f} at {alt}"


async def config_from_autopilot_mission(config: CompanionConfig, autopilot: Autopilot) -> tuple[CompanionConfig, str]:
    """Download the autopilot's mission and return ``config`` with its pad (and alternate) and
    a line saying where they came from (for the events). Raises :class:`MissionDownloadError` or
    :class:`MissionPlanError` (a plan without a delivery, or one the parameters refuse: a pad
    outside the fence, too far)."""
    try:
        items = await autopilot.download_mission()
    except AutopilotError as err:
        raise MissionDownloadError(f"downloading the autopilot's mission: {err}") from None
    dest = destination_from_mission(items, min_separation_m=config.mission.pad.size_m)
    try:
        flown = config_for_destination(config, dest)
    except DestinationError as err:
        raise MissionPlanError(f"{dest.source}: {err.reason}") from None
    said = f"destination: {dest.source}: pad {_describe_pad(dest.pad)}"
    if dest.alternate is not None:
        said += f", alternate pad {_describe_pad(dest.alternate)}"
    log.info("%s (%d mission items)", said, len(items))
    return flown, said
