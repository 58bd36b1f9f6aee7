"""QGroundControl plan files (``.plan``, QGC's JSON: docs/gcs.md#qgroundcontrol-plan-files).

Read: the mission's items become :class:`~companion.autopilot.mission_plan.PlanItem` and the pad
(and alternate) is found by the same rule as a mission uploaded to the autopilot
(:func:`~companion.delivery.autopilot_mission.destination_from_mission`); the geofence's polygons
and circles become ``[fence]`` polygons (a circle as a polygon on its safe side: inscribed for an
inclusion, circumscribed for an exclusion); a rally point is the alternate pad when the mission
names none (the one nearest the pad). What QGC writes and the companion cannot fly is refused with
the key or item named: a complex item (survey, corridor scan, structure scan) or a geofence
without a shape.

Written: the delivery as QGC plans a drop: NAV_TAKEOFF at home to ``mission.height_m``, a
NAV_WAYPOINT at the pad, DO_GRIPPER release, NAV_RETURN_TO_LAUNCH (PX4 refuses NAV_PAYLOAD_PLACE at
upload; both firmwares take these); the fence's polygons; the alternate pad as the rally point.
Reading what it writes gives the same pad, alternate and fence back.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TypeVar

from companion.autopilot.mission_plan import (
    GRIPPER_ACTION_RELEASE,
    MAV_CMD_DO_GRIPPER,
    MAV_CMD_NAV_TAKEOFF,
    MAV_CMD_NAV_WAYPOINT,
    MAV_FRAME_GLOBAL_RELATIVE_ALT,
    MAV_FRAME_MISSION,
    PlanItem,
)
from companion.config import CompanionConfig, ConfigError, validate_config
from companion.delivery.autopilot_mission import MissionPlanError, destination_from_mission
from companion.delivery.destination import Destination, DestinationError, GeoPad
from companion.geometry.earth import GeoPoint, geo_to_ned, ned_to_geo

MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
QGC_FIRMWARE_GENERIC = 0  # MAV_AUTOPILOT_GENERIC: QGC's "any firmware"
QGC_VEHICLE_MULTIROTOR = 2  # MAV_TYPE_QUADROTOR
CIRCLE_SIDES = 32  # a fence circle's polygon: within 0.5 % of the radius of the circle

_C = TypeVar("_C", bound=CompanionConfig)


class PlanFileError(DestinationError):
    """A plan file that is not QGC's JSON or describes no delivery: ``reason`` names the key or item."""


@dataclass(frozen=True, slots=True)
class FenceCircle:
    lat_deg: float
    lon_deg: float
    radius_m: float
    inclusion: bool


@dataclass(frozen=True, slots=True)
class QgcPlan:
    """What a plan file holds that a delivery uses."""

    path: str
    items: tuple[PlanItem, ...]
    polygons: tuple[tuple[bool, tuple[tuple[float, float], ...]], ...]  # (inclusion, [(lat, lon), ...])
    circles: tuple[FenceCircle, ...]
    rally_points: tuple[tuple[float, float, float], ...]  # (lat, lon, alt above home)
    planned_home: tuple[float, float, float] | None  # (lat, lon, alt AMSL)


def _number(v: Any, key: str, path: str, *, allow_null: bool = False) -> float:
    if v is None and allow_null:
        return math.nan  # QGC writes null for "unused" (yaw: keep the heading)
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise PlanFileError(f"{path}: {key} = {v!r}: expected a finite number")
    return float(v)


def _table(v: Any, key: str, path: str) -> dict[str, Any]:
    if not isinstance(v, dict):
        raise PlanFileError(f"{path}: {key}: expected a JSON object, got {type(v).__name__}")
    return v


def _list(v: Any, key: str, path: str) -> list[Any]:
    if not isinstance(v, list):
        raise PlanFileError(f"{path}: {key}: expected a JSON array, got {type(v).__name__}")
    return v


def _latlon(v: Any, key: str, path: str, n: int = 2) -> tuple[float, ...]:
    pair = _list(v, key, path)
    if len(pair) < n:
        raise PlanFileError(f"{path}: {key} = {pair!r}: expected [latitude, longitude{', altitude' if n > 2 else ''}]")
    lat, lon = _number(pair[0], f"{key}[0]", path), _number(pair[1], f"{key}[1]", path)
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise PlanFileError(f"{path}: {key} = {pair!r}: latitude within +-90, longitude within +-180 deg")
    return (lat, lon, *(_number(x, f"{key}[{i + 2}]", path) for i, x in enumerate(pair[2:n])))


def _pair(v: Any, key: str, path: str) -> tuple[float, float]:
    lat, lon = _latlon(v, key, path)[:2]
    return lat, lon


def _item(raw: Any, number: int, path: str) -> PlanItem:
    key = f"mission.items[{number - 1}]"
    it = _table(raw, key, path)
    kind = it.get("type")
    if kind == "ComplexItem":
        what = it.get("complexItemType", "complex item")
        raise PlanFileError(
            f"{path}: mission item {number} is a {what}: the companion flies its own path (climb, arc, cruise, "
            "arc, descend) to the pad; remove it, or plan the delivery as simple items"
        )
    if kind != "SimpleItem":
        raise PlanFileError(f"{path}: {key}.type = {kind!r}: expected 'SimpleItem'")
    command = it.get("command")
    frame = it.get("frame")
    for name, v in (("command", command), ("frame", frame)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            raise PlanFileError(f"{path}: {key}.{name} = {v!r}: expected a MAVLink number")
    params = _list(it.get("params"), f"{key}.params", path)
    if len(params) != 7:
        raise PlanFileError(f"{path}: {key}.params has {len(params)} values: expected 7 (param1-4, lat, lon, alt)")
    p = [_number(v, f"{key}.params[{i}]", path, allow_null=True) for i, v in enumerate(params)]
    lat, lon = (0.0 if math.isnan(v) else v for v in p[4:6])
    if not (-90.0 <= lat <= 90.0 and -180.0 <= lon <= 180.0):
        raise PlanFileError(f"{path}: {key}.params[4:6] = {lat}, {lon}: latitude within +-90, longitude within +-180")
    assert isinstance(command, int) and isinstance(frame, int)
    return PlanItem(
        index=number,  # QGC numbers its items from 1 (0 is the planned home)
        seq=number,
        frame=frame,
        command=command,
        param1=p[0],
        param2=p[1],
        param3=p[2],
        param4=p[3],
        x=round(lat * 1e7),
        y=round(lon * 1e7),
        z=p[6],
    )


def parse_plan(data: Any, path: str) -> QgcPlan:
    """A plan file's JSON, checked key by key."""
    top = _table(data, "the file", path)
    if top.get("fileType") != "Plan":
        raise PlanFileError(f"{path}: fileType = {top.get('fileType')!r}: expected 'Plan' (a QGroundControl .plan)")
    mission = _table(top.get("mission"), "mission", path)
    if mission.get("version") != 2:
        raise PlanFileError(f"{path}: mission.version = {mission.get('version')!r}: expected 2 (QGC 3.3 and later)")
    items = tuple(_item(raw, i + 1, path) for i, raw in enumerate(_list(mission.get("items"), "mission.items", path)))
    home = mission.get("plannedHomePosition")
    planned_home = None
    if home is not None:
        lat, lon, alt = _latlon(home, "mission.plannedHomePosition", path, n=3)
        planned_home = (lat, lon, alt)
    polygons: list[tuple[bool, tuple[tuple[float, float], ...]]] = []
    circles: list[FenceCircle] = []
    fence = top.get("geoFence")
    if fence is not None:
        fence = _table(fence, "geoFence", path)
        for i, raw in enumerate(_list(fence.get("polygons", []), "geoFence.polygons", path)):
            key = f"geoFence.polygons[{i}]"
            poly = _table(raw, key, path)
            verts = _list(poly.get("polygon"), f"{key}.polygon", path)
            if len(verts) < 3:
                raise PlanFileError(f"{path}: {key}.polygon has {len(verts)} vertices: expected at least 3")
            pts = tuple(_pair(v, f"{key}.polygon[{j}]", path) for j, v in enumerate(verts))
            polygons.append((bool(poly.get("inclusion", True)), pts))
        for i, raw in enumerate(_list(fence.get("circles", []), "geoFence.circles", path)):
            key = f"geoFence.circles[{i}]"
            c = _table(raw, key, path)
            body = _table(c.get("circle"), f"{key}.circle", path)
            lat, lon = _latlon(body.get("center"), f"{key}.circle.center", path)
            radius = _number(body.get("radius"), f"{key}.circle.radius", path)
            if radius <= 0:
                raise PlanFileError(f"{path}: {key}.circle.radius = {radius:g}: expected metres > 0")
            circles.append(FenceCircle(lat, lon, radius, bool(c.get("inclusion", True))))
    rally: list[tuple[float, float, float]] = []
    rp = top.get("rallyPoints")
    if rp is not None:
        for i, raw in enumerate(_list(_table(rp, "rallyPoints", path).get("points", []), "rallyPoints.points", path)):
            lat, lon, alt = _latlon(raw, f"rallyPoints.points[{i}]", path, n=3)
            rally.append((lat, lon, alt))
    return QgcPlan(path, items, tuple(polygons), tuple(circles), tuple(rally), planned_home)


def read_plan(path: str | Path) -> QgcPlan:
    p = Path(path)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as err:
        raise PlanFileError(f"{p}: cannot read: {err.strerror or err}") from None
    except UnicodeDecodeError as err:
        raise PlanFileError(f"{p}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    try:
        data = json.loads(text)
    except json.JSONDecodeError as err:
        raise PlanFileError(f"{p}: not JSON: {err.msg} at line {err.lineno} column {err.colno}") from None
    return parse_plan(data, str(p))


def circle_polygon(c: FenceCircle, sides: int = CIRCLE_SIDES) -> tuple[tuple[float, float], ...]:
    """The circle as a regular polygon on the fence's safe side: inscribed (inside the circle) for
    an inclusion, circumscribed (around it) for an exclusion."""
    r = c.radius_m if c.inclusion else c.radius_m / math.cos(math.pi / sides)
    centre = GeoPoint(c.lat_deg, c.lon_deg, 0.0)
    out = []
    for k in range(sides):
        a = 2.0 * math.pi * k / sides
        g = ned_to_geo(centre, r * math.cos(a), r * math.sin(a), 0.0)
        out.append((g.lat_deg, g.lon_deg))
    return tuple(out)


def plan_destination(plan: QgcPlan, min_separation_m: float) -> Destination:
    """The pad and alternate the plan names: the mission's delivery items, else its nearest rally
    point as the alternate."""
    where = f"{plan.path}: mission"
    try:
        dest = destination_from_mission(plan.items, min_separation_m=min_separation_m, where=where)
    except MissionPlanError as err:
        raise PlanFileError(err.reason) from None
    if dest.alternate is not None or not plan.rally_points:
        return dest
    pad = GeoPoint(dest.pad.lat_deg, dest.pad.lon_deg, 0.0)

    def distance(rp: tuple[float, float, float]) -> float:
        n, e, _ = geo_to_ned(pad, GeoPoint(rp[0], rp[1], 0.0))
        return math.hypot(n, e)

    i, best = min(enumerate(plan.rally_points), key=lambda kv: distance(kv[1]))
    if distance(best) < min_separation_m:
        raise PlanFileError(
            f"{plan.path}: rallyPoints.points[{i}] lies {distance(best):.2f} m from the pad: expected the alternate "
            f"pad at least {min_separation_m:g} m from it"
        )
    return Destination(dest.pad, f"{dest.source}, alternate rallyPoints.points[{i}]", GeoPad(best[0], best[1]))


def config_from_plan(config: _C, plan: QgcPlan) -> tuple[_C, str]:
    """``config`` with the plan's pad, alternate and fence (when the plan has one), and a line
    saying what came from the plan. Refused with :class:`PlanFileError` naming the item or key,
    or the parameter the result breaks (a pad outside the fence, too far)."""
    dest = plan_destination(plan, config.mission.pad.size_m)
    data = config.model_dump()
    mission = data["mission"]
    mission["pad"] = dest.pad.as_table(config.mission.pad.size_m)
    if dest.alternate is not None:
        size = (config.mission.alternate_pad or config.mission.pad).size_m
        mission["alternate_pad"] = dest.alternate.as_table(size)
    said = f"destination: {dest.source}"
    if plan.polygons or plan.circles:
        fence = data["fence"]
        fence["enabled"] = True
        fence["inclusion"] = [{"vertices_deg": [list(v) for v in pts]} for inc, pts in plan.polygons if inc]
        fence["exclusion"] = [{"vertices_deg": [list(v) for v in pts]} for inc, pts in plan.polygons if not inc]
        for c in plan.circles:
            (fence["inclusion"] if c.inclusion else fence["exclusion"]).append(
                {"vertices_deg": [list(v) for v in circle_polygon(c)]}
            )
        said += f"; fence: {len(plan.polygons)} polygon(s), {len(plan.circles)} circle(s) from the plan"
    try:
        return validate_config(type(config), data, plan.path), said
    except ConfigError as err:
        raise PlanFileError(f"{plan.path}: " + "; ".join(err.problems)) from None


def _simple(number: int, command: int, frame: int, params: list[float | None], altitude: float) -> dict[str, Any]:
    return {
        "AMSLAltAboveTerrain": None,
        "Altitude": altitude,
        "AltitudeMode": 1,  # relative to home
        "autoContinue": True,
        "command": command,
        "doJumpId": number,
        "frame": frame,
        "params": params,
        "type": "SimpleItem",
    }


def _geo(pad: Any, home: GeoPoint) -> tuple[float, float]:
    if pad.lat_deg is not None and pad.lon_deg is not None:
        return float(pad.lat_deg), float(pad.lon_deg)
    g = ned_to_geo(home, float(pad.north_m), float(pad.east_m), 0.0)
    return g.lat_deg, g.lon_deg


def export_plan(config: CompanionConfig, home: GeoPoint) -> dict[str, Any]:
    """The delivery of ``config`` from ``home`` as a QGC plan (see the module's docstring)."""
    m = config.mission
    h = float(m.height_m)
    pad_lat, pad_lon = _geo(m.pad, home)
    rel = MAV_FRAME_GLOBAL_RELATIVE_ALT
    items = [
        _simple(1, MAV_CMD_NAV_TAKEOFF, rel, [0, 0, 0, None, home.lat_deg, home.lon_deg, h], h),
        _simple(2, MAV_CMD_NAV_WAYPOINT, rel, [0, 0, 0, None, pad_lat, pad_lon, h], h),
        _simple(3, MAV_CMD_DO_GRIPPER, MAV_FRAME_MISSION, [1, GRIPPER_ACTION_RELEASE, 0, 0, 0, 0, 0], 0),
        _simple(4, MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_FRAME_MISSION, [0, 0, 0, 0, 0, 0, 0], 0),
    ]
    for it in items[2:]:  # a command without a position: QGC writes no altitude keys
        for k in ("AMSLAltAboveTerrain", "Altitude", "AltitudeMode"):
            it.pop(k)
    f = config.fence
    polygons = [
        {"inclusion": inc, "polygon": [list(v) for v in poly.vertices_deg], "version": 1}
        for inc, polys in ((True, f.inclusion), (False, f.exclusion))
        for poly in polys
    ]
    speed = float(max(m.sector_speed_m_s))
    rally = []
    if m.alternate_pad is not None:
        lat, lon = _geo(m.alternate_pad, home)
        rally.append([lat, lon, h])
    return {
        "fileType": "Plan",
        "geoFence": {"circles": [], "polygons": polygons if f.enabled else [], "version": 2},
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": speed,
            "firmwareType": QGC_FIRMWARE_GENERIC,
            "globalPlanAltitudeMode": 1,
            "hoverSpeed": speed,  # QGC's time estimate: the companion's cruise (sector) speed
            "items": items,
            "plannedHomePosition": [home.lat_deg, home.lon_deg, home.alt_amsl_m],
            "vehicleType": QGC_VEHICLE_MULTIROTOR,
            "version": 2,
        },
        "rallyPoints": {"points": rally, "version": 2},
        "version": 1,
    }
