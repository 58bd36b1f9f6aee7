"""Turn the configured pad and the vehicle's home/start into a mission frame and a path."""

from __future__ import annotations

import math

import numpy as np

from companion.config import PAD_OFFSET_MAX_M, MissionConfig, PadConfig
from companion.geometry.earth import GeoPoint, geo_to_ned
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.path import DeliveryPath, PathGeometryError


def pad_position_ned(cfg: MissionConfig, home: GeoPoint) -> np.ndarray:
    """The configured pad centre (ground level) in the local NED frame whose origin is home.

    A pad given as lat/lon goes through the flat-earth model (delivery 4.1) from the home the
    autopilot reports, so a GPS bias in that home shifts the pad exactly as it does in flight.
    """
    return pad_config_ned(cfg.pad, home)


def pad_config_ned(pad: PadConfig, home: GeoPoint) -> np.ndarray:
    """A pad's centre (ground level) in the local NED frame whose origin is home (see
    :func:`pad_position_ned`); also the alternate pad's."""
    if pad.lat_deg is not None and pad.lon_deg is not None:
        alt = pad.alt_amsl_m if pad.alt_amsl_m is not None else home.alt_amsl_m
        return np.array(geo_to_ned(home, GeoPoint(pad.lat_deg, pad.lon_deg, alt)))
    assert pad.north_m is not None and pad.east_m is not None
    return np.array([pad.north_m, pad.east_m, -pad.up_m])


def plan_delivery(
    cfg: MissionConfig, home: GeoPoint, start_ned: np.ndarray, home_ned: tuple[float, float, float] = (0.0, 0.0, 0.0)
) -> tuple[MissionFrame, DeliveryPath, float]:
    """Mission frame F_I, the path, and the start's height z_s in F_I. ``home_ned``: home in the
    autopilot's local NED frame (HOME_POSITION x/y/z), which is where the pad's offsets start."""
    pad_from_home = pad_position_ned(cfg, home)
    if max(abs(pad_from_home[0]), abs(pad_from_home[1])) > PAD_OFFSET_MAX_M:  # a lat/lon pad far from this home
        raise PathGeometryError(
            f"the pad lies {pad_from_home[0]:.0f} m north, {pad_from_home[1]:.0f} m east of home: each must be "
            f"within +-{PAD_OFFSET_MAX_M:g} m (mission.pad)"
        )
    pad_ned = np.asarray(home_ned, dtype=float) + pad_from_home
    start = np.asarray(start_ned, dtype=float)
    d = math.hypot(pad_ned[0] - start[0], pad_ned[1] - start[1])
    if d < 1e-3:
        raise PathGeometryError("the pad is where the vehicle stands: nothing to fly")
    frame = MissionFrame.from_start_and_pad(start, pad_ned)
    path = DeliveryPath(h=cfg.height_m, r=cfg.arc_radius_m, d=d)
    z_start = float(frame.point_from_ned(start)[2])
    if z_start >= cfg.height_m - cfg.arc_radius_m:
        raise PathGeometryError(
            f"the start is {z_start:.1f} m above the pad, at or above the arcs (h - r = "
            f"{cfg.height_m - cfg.arc_radius_m:.1f} m): raise height_m"
        )
    return frame, path, z_start


def plan_leg(
    cfg: MissionConfig, start_ned: np.ndarray, target_ned: np.ndarray
) -> tuple[MissionFrame, DeliveryPath, float]:
    """The 5-sector path of the mission's height and arcs from ``start_ned`` (on the ground) to
    ``target_ned`` (a pad on the ground), both in the local NED frame: the divert to the alternate
    pad, and the way home from it. Raises :class:`PathGeometryError` when the arcs do not fit."""
    start = np.asarray(start_ned, dtype=float)
    target = np.asarray(target_ned, dtype=float)
    d = math.hypot(target[0] - start[0], target[1] - start[1])
    if d < 1e-3:
        raise PathGeometryError("the target is where the leg starts: nothing to fly")
    frame = MissionFrame.from_start_and_pad(start, target)
    path = DeliveryPath(h=cfg.height_m, r=cfg.arc_radius_m, d=d)
    z_start = float(frame.point_from_ned(start)[2])
    if z_start >= cfg.height_m - cfg.arc_radius_m:
        raise PathGeometryError(
            f"the start is {z_start:.1f} m above the target, at or above the arcs (h - r = "
            f"{cfg.height_m - cfg.arc_radius_m:.1f} m)"
        )
    return frame, path, z_start
