"""Yaw with a pad that has a heading (docs/pad-heading.md): at the approach height (hold, search)
and in the final descent onto it, the yaw setpoint turns from where it was to the pad's heading
the shortest way, at most limits.max_yaw_rate_deg_s, so the vehicle touches down aligned.
Elsewhere the path's heading (delivery 4.3) is kept."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace

from companion.delivery.mission.types import MissionInputs
from companion.delivery.padlock import PAD_DATA_FRESH_S
from companion.events import Phase
from companion.geometry.heading import heading_difference_rad, yaw_toward
from companion.geometry.rotations import wrap_angle
from companion.guidance.setpoint import VelocitySetpoint

ALIGNED_RAD = math.radians(1.0)  # the yaw setpoint has finished its turn this close
ALIGN_PHASES = (Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH)


class PadYawAlignment:
    def __init__(self, max_yaw_rate_rad_s: float, hold_min_height_m: float):
        self.max_yaw_rate_rad_s = max_yaw_rate_rad_s
        self.hold_min_height_m = hold_min_height_m
        self.last: tuple[float, float] | None = None  # (time, yaw) of the last setpoint

    def apply(
        self,
        phase: Phase,
        inp: MissionInputs,
        sp: VelocitySetpoint | None,
        height_above_ground: Callable[[], float],
    ) -> VelocitySetpoint | None:
        """The setpoint with its yaw turned (or as it was). Once turned, below
        descent.hold_min_height_m with the pad's heading out of sight (no camera observation
        within PAD_DATA_FRESH_S: the camera too close), the setpoint is the autopilot's own yaw:
        its yaw estimate drifts against the truth, and a held setpoint (or the fusion's yaw, which
        converges on the autopilot's once blind) would turn the vehicle by that drift, in the last
        metre and on the ground until the land detector fires (PX4 SIH)."""
        target = inp.pad_heading_rad
        if sp is None or target is None or phase not in ALIGN_PHASES:
            self.last = (inp.time_s, sp.yaw_rad) if sp is not None else None
            return sp
        prev = self.last
        est, ap_yaw = inp.estimate, inp.autopilot_yaw_rad
        if (
            phase is Phase.LANDING_PAD
            and est is not None
            and ap_yaw is not None
            and math.isfinite(ap_yaw)
            and prev is not None
            and abs(heading_difference_rad(prev[1], target)) <= ALIGNED_RAD
            and inp.pad_heading_age_s > PAD_DATA_FRESH_S
            and height_above_ground() < self.hold_min_height_m
        ):
            self.last = (inp.time_s, target)  # still turned: the test above holds on the next tick
            return replace(sp, yaw_rad=wrap_angle(ap_yaw))
        if prev is None:
            start = est.yaw_rad if est is not None else sp.yaw_rad
            step = 0.0
        else:
            start = prev[1]
            step = self.max_yaw_rate_rad_s * min(max(inp.time_s - prev[0], 0.0), 1.0)
        yaw = yaw_toward(start, target, step)
        self.last = (inp.time_s, yaw)
        return replace(sp, yaw_rad=yaw)
