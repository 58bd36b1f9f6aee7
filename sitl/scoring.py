"""Path tracking scored on truth against the path the vehicle should fly.

On the way out the vehicle follows the configured path until its landing sensors find the pad,
then the path to the pad as found: a pad lying 1.5 m from its configured position (or a GPS bias)
moves the vehicle 1.5 m off the configured path *correctly*. The reference on the way out is
therefore the nearer of the configured path and the path from home to the true pad; on the way
back the mission's own path (planned from where the vehicle landed, `return_from_landing_point`).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from companion.config import PadConfig
from companion.delivery.mission import DeliveryMission
from companion.events import Phase
from companion.geometry.heading import heading_difference_rad
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.path import DeliveryPath
from companion_sitl.params import SimulatedConfig

REFERENCE = "outbound: nearer of the configured path and the path to the true pad; inbound: the mission's path home"


class PathScorer:
    """Distance of a true position (in the autopilot's local NED frame) to the reference path."""

    def __init__(self, true_pad_local_ne: tuple[float, float] | None):
        self.true_pad_local_ne = true_pad_local_ne
        self._true: tuple[MissionFrame, DeliveryPath] | None = None

    @property
    def true_pad_path(self) -> tuple[MissionFrame, DeliveryPath] | None:
        """The path from home to the true pad (its frame and path), once the mission has planned."""
        return self._true

    def _true_pad_path(self, m: DeliveryMission) -> tuple[MissionFrame, DeliveryPath] | None:
        start = m.start_ned
        if self._true is None and self.true_pad_local_ne is not None and start is not None and m.frame is not None:
            pad = np.array([*self.true_pad_local_ne, m.frame.pad_ned[2]])
            d = math.hypot(pad[0] - start[0], pad[1] - start[1])
            if d > 1e-3 and m.path is not None:
                self._true = (MissionFrame.from_start_and_pad(start, pad), DeliveryPath(m.path.h, m.path.r, d))
        return self._true

    def distance(self, m: DeliveryMission, phase: Phase, p_local_ned: ArrayLike) -> float:
        return self._to_reference(m, phase, p_local_ned, in_plane=False)

    def in_plane_distance(self, m: DeliveryMission, phase: Phase, p_local_ned: ArrayLike) -> float:
        """The distance within the path's vertical plane (along the path and up; the lateral
        alpha_1 of delivery eq 16 left out): how far the vehicle leaves a climb, an arc or a
        descent, apart from a sideways move such as the one onto a displaced pad. Against the
        same reference as :meth:`distance`."""
        return self._to_reference(m, phase, p_local_ned, in_plane=True)

    def _to_reference(self, m: DeliveryMission, phase: Phase, p_local_ned: ArrayLike, in_plane: bool) -> float:
        assert m.frame is not None and m.path is not None
        p = np.asarray(p_local_ned, dtype=float)

        def to(frame: MissionFrame, path: DeliveryPath) -> float:
            q = frame.point_from_ned(p)
            return float(path.distance_in_plane(q) if in_plane else path.distance_to_path(q))

        d = to(m.frame, m.path)
        if phase is Phase.OUTBOUND:
            tp = self._true_pad_path(m)
            if tp is not None:
                d = min(d, to(*tp))
        return d


def rms(xs: list[float]) -> float:
    return math.sqrt(sum(x * x for x in xs) / len(xs)) if xs else math.nan


def simulated_pad(config: SimulatedConfig) -> PadConfig:
    """The configured pad the simulator places: the alternate with ``sim.pad_at_alternate``."""
    alternate = config.mission.alternate_pad
    return alternate if config.sim.pad_at_alternate and alternate is not None else config.mission.pad


def true_pad_heading_rad(config: SimulatedConfig) -> float:
    """The simulated pad's true heading (NED): the configured heading of the pad the simulator
    places plus ``sim.pad_heading_offset_deg``; a pad without a heading lies as it always has
    (heading 0: its up edge north)."""
    pad = simulated_pad(config)
    if pad.heading_deg is None:
        return 0.0
    return math.radians(pad.heading_deg + config.sim.pad_heading_offset_deg)


def heading_error_deg(yaw_rad: float, pad_heading_rad: float) -> float:
    """Touchdown heading error on truth: |vehicle yaw - pad heading|, the short way round (deg)."""
    return abs(math.degrees(heading_difference_rad(yaw_rad, pad_heading_rad)))
