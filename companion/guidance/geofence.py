"""Is the planned path inside the geofence? (docs/go-no-go.md)

Pure: the fence polygons of ``[fence]`` in the local NED frame of home, and the check of one leg
of the 5-section path (delivery 4.1) against them. Seen from above the whole leg is the straight
segment from where it starts to where it ends (the climb and the descents are vertical, the arcs
lie in the vertical plane), so the check is exact in the horizontal: the segment must lie inside
every inclusion polygon and outside every exclusion polygon, ``margin_m`` clear of every edge;
its cruise height must stay ``margin_m`` below the ceiling. The companion's own setpoint clamp
(``[limits] geofence_radius_m`` / ``geofence_max_alt_m``, ``guidance.limits.clamp_velocity``)
is checked the same way: a path beyond it would stop at the clamp and never finish.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from companion.config import FenceConfig, LimitsConfig, MissionConfig
from companion.geometry.earth import GeoPoint, geo_to_ned, ned_to_geo
from companion.geometry.polygon import (
    Point2,
    edges,
    point_in_polygon,
    point_segment_distance,
    segment_crossing_t,
)

SAMPLE_STEP_M = 0.5  # spacing of the points tested along a leg (crossings are also found exactly)


@dataclass(frozen=True, slots=True)
class FencePolygonNed:
    """A fence polygon in the local NED frame: (north, east) vertices in metres."""

    index: int
    inclusion: bool
    vertices_ne_m: tuple[Point2, ...]

    @property
    def name(self) -> str:
        return f"{'inclusion' if self.inclusion else 'exclusion'} polygon {self.index}"


@dataclass(frozen=True, slots=True)
class FenceNed:
    polygons: tuple[FencePolygonNed, ...]
    max_alt_rel_m: float | None  # ceiling above home
    margin_m: float


@dataclass(frozen=True, slots=True)
class FenceViolation:
    """Where a leg leaves the fence: which leg, which section of the path, how far along it
    (horizontally), where (local NED and lat/lon) and why."""

    leg: str  # "outbound" or "return"
    section: str  # "S3 cruise", ...
    along_m: float
    north_m: float
    east_m: float
    lat_deg: float
    lon_deg: float
    reason: str

    def __str__(self) -> str:
        return (
            f"the {self.leg} leg leaves the fence in {self.section}, {self.along_m:.1f} m along it "
            f"(N {self.north_m:.1f} m, E {self.east_m:.1f} m; {self.lat_deg:.7f}, {self.lon_deg:.7f}): {self.reason}"
        )


def fence_in_ned(cfg: FenceConfig, home: GeoPoint, home_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> FenceNed:
    """The configured polygons in the local frame whose origin is ``home_ned`` below ``home``
    (the same flat-earth model the pad goes through: ``delivery.planning.pad_position_ned``)."""
    polys = []
    for inclusion, group in ((True, cfg.inclusion), (False, cfg.exclusion)):
        for i, p in enumerate(group):
            pts = []
            for lat, lon in p.vertices_deg:
                n, e, _ = geo_to_ned(home, GeoPoint(lat, lon, home.alt_amsl_m))
                pts.append((home_ned[0] + n, home_ned[1] + e))
            polys.append(FencePolygonNed(i, inclusion, tuple(pts)))
    return FenceNed(tuple(polys), cfg.max_alt_rel_m, cfg.margin_m)


def section_at(along_m: float, d: float, r: float, leg: str) -> str:
    """The path section over the point ``along_m`` metres (horizontally) from the leg's start."""
    outbound = leg == "outbound"
    if along_m <= 1e-6:
        return "S1 climb from home" if outbound else "S5 climb from the pad"
    if along_m >= d - 1e-6:
        return "S5 descent to the pad" if outbound else "S1 descent home"
    if along_m < r:
        return "S2 arc" if outbound else "S4 arc"
    if along_m <= d - r:
        return "S3 cruise"
    return "S4 arc" if outbound else "S2 arc"


def _point_problem(p: Point2, fence: FenceNed) -> str | None:
    for poly in fence.polygons:
        inside = point_in_polygon(p, poly.vertices_ne_m)
        if poly.inclusion and not inside:
            return f"outside {poly.name}"
        if not poly.inclusion and inside:
            return f"inside {poly.name}"
        if fence.margin_m > 0.0:
            dist = min(point_segment_distance(p, a, b) for a, b in edges(poly.vertices_ne_m))
            if dist < fence.margin_m:
                return f"{dist:.1f} m from the edge of {poly.name}, closer than fence.margin_m = {fence.margin_m:g} m"
    return None


def check_leg(
    fence: FenceNed | None,
    limits: LimitsConfig,
    home: GeoPoint,
    start_ned: tuple[float, float, float],
    end_ned: tuple[float, float, float],
    cruise_down_m: float,
    arc_radius_m: float,
    leg: str = "outbound",
    home_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> FenceViolation | None:
    """The first place where the leg from ``start_ned`` to ``end_ned`` (cruising at NED down
    ``cruise_down_m``) leaves the fence or the companion's clamp, or None when it stays inside.
    Points are in the local NED frame; ``home_ned`` is home in it (the clamp's centre and the
    ceiling's zero)."""
    a: Point2 = (float(start_ned[0]), float(start_ned[1]))
    b: Point2 = (float(end_ned[0]), float(end_ned[1]))
    d = math.hypot(b[0] - a[0], b[1] - a[1])

    def at(t: float, reason: str) -> FenceViolation:
        n, e = a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
        g = ned_to_geo(home, n - home_ned[0], e - home_ned[1], 0.0)
        return FenceViolation(leg, section_at(t * d, d, arc_radius_m, leg), t * d, n, e, g.lat_deg, g.lon_deg, reason)

    # the top of the leg: the arcs and the cruise
    height = home_ned[2] - cruise_down_m
    t_top = min(1.0, arc_radius_m / d) if d > 0 else 0.0
    if fence is not None and fence.max_alt_rel_m is not None and height > fence.max_alt_rel_m - fence.margin_m:
        return at(
            t_top,
            f"cruise at {height:.1f} m above home, above the ceiling fence.max_alt_rel_m = {fence.max_alt_rel_m:g} m "
            f"less fence.margin_m = {fence.margin_m:g} m",
        )
    if height > limits.geofence_max_alt_m:
        return at(
            t_top,
            f"cruise at {height:.1f} m above home, above limits.geofence_max_alt_m = {limits.geofence_max_alt_m:g} m",
        )
    # the companion's radius clamp: a segment is farthest from a point at one of its ends
    for t in (0.0, 1.0):
        n, e = a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])
        r = math.hypot(n - home_ned[0], e - home_ned[1])
        if r > limits.geofence_radius_m:
            return at(t, f"{r:.1f} m from home, beyond limits.geofence_radius_m = {limits.geofence_radius_m:g} m")
    if fence is None:
        return None
    # the polygons: the first failing point along the leg, then the exact crossings (an edge
    # thinner than the sample spacing)
    n_steps = max(1, math.ceil(d / SAMPLE_STEP_M))
    for i in range(n_steps + 1):
        t = i / n_steps
        why = _point_problem((a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])), fence)
        if why is not None:
            return at(t, why)
    first: tuple[float, str] | None = None
    for poly in fence.polygons:
        for q1, q2 in edges(poly.vertices_ne_m):
            t_cross = segment_crossing_t(a, b, q1, q2)
            if t_cross is not None and (first is None or t_cross < first[0]):
                first = (t_cross, f"crosses the edge of {poly.name}")
    return at(*first) if first is not None else None


def legs_problem(
    fence: FenceNed | None,
    limits: LimitsConfig,
    home: GeoPoint,
    home_ned: tuple[float, float, float],
    start_ned: Any,
    pad_ned: Any,
    cfg: MissionConfig,
    legs: tuple[str, ...] = ("outbound", "return"),
) -> str:
    """Why the mission ``cfg``'s legs between ``start_ned`` (home) and ``pad_ned`` leave the fence
    or the companion's clamp ("" when they stay inside)."""
    cruise_down = float(pad_ned[2]) - cfg.height_m
    for leg in legs:
        a, b = (start_ned, pad_ned) if leg == "outbound" else (pad_ned, start_ned)
        v = check_leg(
            fence,
            limits,
            home,
            (float(a[0]), float(a[1]), float(a[2])),
            (float(b[0]), float(b[1]), float(b[2])),
            cruise_down,
            cfg.arc_radius_m,
            leg,
            home_ned,
        )
        if v is not None:
            return str(v)
    return ""
