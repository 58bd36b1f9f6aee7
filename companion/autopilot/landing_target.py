"""LANDING_TARGET interop: our pad observations for the autopilot's own precision landing.

A user may prefer PX4's precision landing (``landing_target_estimator`` + AUTO.PRECLAND) or
ArduPilot's (``PLND_TYPE = 1``, companion computer) to do the descent while this companion only
sees the pad. MAVLink's LANDING_TARGET (#149) carries it in two forms, and the two autopilots read
different ones:

- ``local_ned`` (PX4): ``position_valid = 1``, ``frame = MAV_FRAME_LOCAL_NED`` and x, y, z the
  pad's centre in the *autopilot's* local NED frame. Our fused frame puts the configured pad where
  the camera and UWB see it and the EKF's GPS-bias state b_p is what separates the two frames
  (delivery eq 12: the autopilot reports p + b_p), so the pad lies at ``p_pad + b_p`` in the
  autopilot's frame. Using the fused estimate rather than one raw detection gives the autopilot a
  smooth target that already carries the UWB and the outer/inner marker agreement.
- ``body_angles`` (ArduPilot ``AC_PrecLand_Companion``): ``position_valid = 0``, angle_x /
  angle_y / distance of the pad's centre from this frame's exposure. ArduPilot rebuilds the body-
  frame line of sight as (-tan(angle_y), tan(angle_x), 1), so with v the pad centre in body FRD:
  angle_x = atan2(v_y, v_z), angle_y = atan2(-v_x, v_z), distance = |v|. Computed in the body
  frame, not the camera's, so any camera mount gives the convention ArduPilot expects.

Both carry the exposure time; ``size_x``/``size_y`` are the pad's angular size at that distance.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from companion.autopilot.types import LandingTarget
from companion.estimation.types import StateEstimate
from companion.geometry.se3 import Transform

LandingTargetOutput = Literal["off", "local_ned", "body_angles"]


class LandingTargetError(ValueError):
    """An observation or estimate that cannot become a LANDING_TARGET (the reason says why)."""


@dataclass(frozen=True)
class LandingTargetBuilder:
    """Builds LANDING_TARGET contents from an exposure-stamped pad observation.

    ``T_body_camera``: the camera mount; ``T_world_pad``: the configured pad in the fused frame
    (as the EKF uses it); ``pad_size_m``: the outer marker's side, for the angular size.
    """

    mode: LandingTargetOutput
    T_body_camera: Transform
    T_world_pad: Transform
    pad_size_m: float

    def build(self, obs_time_s: float, T_camera_pad: Transform, estimate: StateEstimate | None) -> LandingTarget:
        t_cam = np.asarray(T_camera_pad.t, dtype=float)
        if not np.all(np.isfinite(t_cam)):
            raise LandingTargetError(f"pad position in the camera frame is not finite: {t_cam.tolist()}")
        v = self.T_body_camera.apply(t_cam)  # pad centre in body FRD
        dist = float(np.linalg.norm(v))
        if v[2] <= 0.0 or dist <= 1e-3:
            raise LandingTargetError(f"pad is not below the vehicle (body FRD {np.round(v, 3).tolist()})")
        angle_x = math.atan2(float(v[1]), float(v[2]))
        angle_y = math.atan2(-float(v[0]), float(v[2]))
        size = 2.0 * math.atan2(self.pad_size_m / 2.0, dist)
        if self.mode == "body_angles":
            return LandingTarget(obs_time_s, angle_x, angle_y, dist, size, size, 0.0, 0.0, 0.0, False)
        if self.mode != "local_ned":
            raise LandingTargetError(f"landing target output {self.mode!r} sends nothing")
        if estimate is None:
            raise LandingTargetError("no fused estimate yet: the pad's position in the autopilot frame is unknown")
        b = (estimate.gps_bias_north_m, estimate.gps_bias_east_m, estimate.gps_bias_down_m)
        p_pad = self.T_world_pad.t
        n, e, d = (float(p_pad[i]) + float(b[i]) for i in range(3))
        if not all(math.isfinite(x) for x in (n, e, d)):
            raise LandingTargetError(f"pad position in the autopilot frame is not finite: {(n, e, d)}")
        return LandingTarget(obs_time_s, angle_x, angle_y, dist, size, size, n, e, d, True)
