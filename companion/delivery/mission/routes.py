"""The legs the mission plans: the delivery before take-off, the way home from where the
vehicle landed, the divert to the alternate pad and the way home from it; each inside the fence
and the setpoint clamp (guidance.geofence), or refused with the reason."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from companion.config import FenceConfig, LimitsConfig
from companion.delivery.mission.types import FailureKind
from companion.delivery.planning import pad_config_ned, plan_delivery, plan_leg
from companion.events import EventKind, Phase
from companion.geometry.earth import GeoPoint
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.geofence import FenceNed, fence_in_ned, legs_problem
from companion.guidance.path import DeliveryPath, PathGeometryError

if TYPE_CHECKING:
    from companion.autopilot.types import HomePosition
    from companion.delivery.mission.base import MissionBase
    from companion.estimation.types import StateEstimate


class RoutePlanner:
    def __init__(self, mission: MissionBase, fence: FenceConfig | None, limits: LimitsConfig | None):
        self.m = mission
        self.fence_cfg = fence
        self.limits = limits
        self.start_ned: np.ndarray | None = None  # where the outbound started (home, on the ground)
        self.home_geo: GeoPoint | None = None
        self.home_ned = (0.0, 0.0, 0.0)
        self.return_planned = False
        self.home_planned = False  # after a divert: the way home has been planned
        self._fence_ned: FenceNed | None = None

    def plan_delivery(self, home: HomePosition, est: StateEstimate) -> bool:
        """The delivery's path from where the vehicle stands; False when it cannot be flown (the
        mission has failed or been refused, said in an event)."""
        m = self.m
        try:
            frame, path, z_start = plan_delivery(
                m.cfg,
                GeoPoint(home.lat_deg, home.lon_deg, home.alt_amsl_m),
                np.array(est.position_ned),
                (home.north_m, home.east_m, home.down_m),
            )
        except (PathGeometryError, ValueError) as err:
            m.summary.fail(FailureKind.PATH_PLANNING, f"path planning failed: {err}")
            m.emit(EventKind.WARNING, m.summary.failure)
            m.goto(Phase.FAILED)
            return False
        m.frame, m.path, m.z_start = frame, path, z_start
        self.start_ned = np.array(est.position_ned, dtype=float)
        m.pad_ned = np.array(frame.pad_ned, dtype=float)  # kept when the way home is replanned
        self.home_geo = GeoPoint(home.lat_deg, home.lon_deg, home.alt_amsl_m)
        self.home_ned = (home.north_m, home.east_m, home.down_m)
        violation = self.fence_violation(self.start_ned, m.pad_ned)
        if violation:
            m.refuse(m.now, violation)
            return False
        m.set_route(frame, path, z_start)
        m.emit(
            EventKind.PHASE,
            f"path planned: d = {path.d:.2f} m, h = {path.h} m, r = {path.r} m, "
            f"heading {math.degrees(frame.heading_rad):.1f} deg",
        )
        return True

    def plan_return(self, est: StateEstimate) -> None:
        """The way home starts where the vehicle stands (the pad as it was found, which can lie metres
        from the configured one: GPS bias, a displaced pad), not at the configured pad: otherwise the
        vector field pulls the climb sideways onto the outbound path. Same h and r, home as before."""
        m, c = self.m, self.m.cfg
        self.return_planned = self.home_planned = True
        # after a divert the path flown last starts at the first pad, not home: always replanned
        if not (c.return_from_landing_point or m.pad_index) or self.start_ned is None or m.frame is None:
            return
        # horizontally where the vehicle is (it has just armed there); the ground at the pad's level
        land = np.array([est.position_ned[0], est.position_ned[1], m.frame.pad_ned[2]], dtype=float)
        try:
            frame = MissionFrame.from_start_and_pad(self.start_ned, land)
            path = DeliveryPath(h=c.height_m, r=c.arc_radius_m, d=math.hypot(*(land - self.start_ned)[:2]))
            z_start = float(frame.point_from_ned(self.start_ned)[2])
            if z_start >= c.height_m - c.arc_radius_m:
                raise PathGeometryError(f"home is {z_start:.1f} m above the landing point, at or above the arcs")
            violation = self.fence_violation(land, self.start_ned, legs=("return",))
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            if m.pad_index:
                m.abort(m.now, f"no way home from the alternate pad: {err}")
                return
            m.emit(
                EventKind.WARNING, f"return path from the landing point failed ({err}): flying the outbound path back"
            )
            return
        moved = math.hypot(*(land[:2] - m.frame.pad_ned[:2]))
        m.set_route(frame, path, z_start)
        m.emit(
            EventKind.PHASE,
            f"return path planned from the landing point ({moved:.2f} m from the planned pad): d = {path.d:.2f} m, "
            f"heading {math.degrees(frame.heading_rad):.1f} deg",
        )

    def plan_divert(self, est: StateEstimate, reason: str) -> bool:
        """The path from where the vehicle is (over the first pad's ground) to the alternate pad,
        with the mission's height and arcs, inside the fence both ways; on success the mission's
        route and pad are the alternate's (the shell points the landing fusion at it). False (said
        in an event) when it cannot be flown."""
        m, c = self.m, self.m.cfg
        assert c.alternate_pad is not None and m.pad_ned is not None
        if self.home_geo is None or self.start_ned is None:
            return False
        alt_ned = np.asarray(self.home_ned, dtype=float) + pad_config_ned(c.alternate_pad, self.home_geo)
        start = np.array([est.north_m, est.east_m, float(m.pad_ned[2])], dtype=float)
        try:
            frame, path, z_start = plan_leg(c, start, alt_ned)
            violation = self.fence_violation(start, alt_ned, legs=("outbound",)) or self.fence_violation(
                self.start_ned, alt_ned, legs=("return",)
            )
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            m.emit(EventKind.PAD_LOCK, f"{reason}: cannot divert to the alternate pad ({err})")
            return False
        m.set_route(frame, path, z_start)
        m.pad_ned = np.array(frame.pad_ned, dtype=float)
        m.pad_index = 1
        self.home_planned = self.return_planned = False  # the way home starts at the alternate
        m.emit(
            EventKind.PAD_LOCK,
            f"{reason}: diverting to the alternate pad, {path.d:.1f} m away at {c.height_m} m, "
            "to land there under the same policy",
        )
        m.emit(
            EventKind.PHASE,
            f"divert path planned: d = {path.d:.2f} m, h = {path.h} m, r = {path.r} m, "
            f"heading {math.degrees(frame.heading_rad):.1f} deg",
        )
        return True

    def plan_home_from(self, est: StateEstimate) -> None:
        """After a divert, the way home in the air: from the ground under the vehicle to where the
        outbound started (the divert's path starts at the first pad). No path: hold, then land."""
        m = self.m
        self.home_planned = True
        assert m.frame is not None and self.start_ned is not None
        below = np.array([est.north_m, est.east_m, float(m.frame.pad_ned[2])], dtype=float)
        try:
            # the leg flown backwards (s = -1): from home (its start) to the ground under the vehicle
            frame, path, z_start = plan_leg(m.cfg, self.start_ned, below)
            violation = self.fence_violation(below, self.start_ned, legs=("return",))
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            m.abort(m.now, f"no way home from the alternate pad: {err}")
            return
        m.set_route(frame, path, z_start)
        m.emit(EventKind.PHASE, f"return path planned from the divert: d = {path.d:.2f} m")

    def fence_violation(
        self, start_ned: np.ndarray, pad_ned: np.ndarray, legs: tuple[str, ...] = ("outbound", "return")
    ) -> str:
        """Why the legs between ``start_ned`` (home) and ``pad_ned`` leave the fence or the
        setpoint clamp ("" when they stay inside)."""
        if self.limits is None or self.home_geo is None:
            return ""
        if self.fence_cfg is not None and self._fence_ned is None:
            self._fence_ned = fence_in_ned(self.fence_cfg, self.home_geo, self.home_ned)
        return legs_problem(
            self._fence_ned, self.limits, self.home_geo, self.home_ned, start_ned, pad_ned, self.m.cfg, legs
        )
