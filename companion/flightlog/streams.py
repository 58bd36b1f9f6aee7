"""The flight recorder's streams: which CSV files a run folder holds, their columns, and how a
row is built from what the core sees and read back (the codecs replay and the reports share).

Autopilot samples get one file per sample type (columns ``time_s, seq``, then the dataclass
fields, whose names carry their units; enums as their value, flags as 0/1); the other streams'
columns are listed here with the functions that build their rows. Floats are written as shortest
round-trip decimals, so they read back as the same doubles.
"""

from __future__ import annotations

import dataclasses
import enum
import math
import operator
import typing
from typing import Any

import numpy as np

from companion.autopilot.types import (
    Attitude,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    PositionNed,
    StatusText,
    VehicleStatus,
)
from companion.geometry.rotations import rotmat_to_euler
from companion.geometry.se3 import Transform
from companion.guidance.setpoint import VelocitySetpoint

FORMAT = "companion.flightlog/1"
META_FILE = "run.json"

# ---------------------------------------------------------------------------------------------
# autopilot samples: one file per sample type; columns time_s, seq, then the dataclass fields
# (whose names carry their units)

SAMPLE_FILES: dict[type, str] = {
    PositionNed: "ap_position.csv",
    Attitude: "ap_attitude.csv",
    GlobalPosition: "ap_global.csv",
    GpsRaw: "ap_gps.csv",
    Imu: "ap_imu.csv",
    VehicleStatus: "ap_status.csv",
    HomePosition: "ap_home.csv",
    StatusText: "ap_statustext.csv",
}


def sample_fields(cls: type) -> list[tuple[str, Any]]:
    """(name, type) of a sample dataclass's fields after ``time_s``, in column order."""
    hints = typing.get_type_hints(cls)
    return [(f.name, hints[f.name]) for f in dataclasses.fields(cls) if f.name != "time_s"]


SAMPLE_FIELDS = {cls: sample_fields(cls) for cls in SAMPLE_FILES}


def sample_columns(cls: type) -> tuple[str, ...]:
    return ("time_s", "seq", *(name for name, _ in SAMPLE_FIELDS[cls]))


class _EnumValues(dict[enum.Enum, object]):
    """``member.value`` by ``self[member]``: a dict lookup once seen (``Enum.value`` is a Python
    property, two frames deep: the guidance and flight.csv rows run every tick)."""

    def __missing__(self, member: enum.Enum) -> object:
        v = self[member] = member.value
        return v


ENUM_VALUE = _EnumValues()


def _sample_encoder(cls: type) -> Any:
    """A fast row builder for one sample type (called at the telemetry rate on the loop thread):
    enums as their value, flags as 0/1, numbers as they are."""
    fields_ = SAMPLE_FIELDS[cls]
    get = operator.attrgetter(*(n for n, _ in fields_))
    conv = [
        (i, ENUM_VALUE.__getitem__ if isinstance(t, type) and issubclass(t, enum.Enum) else (lambda v: int(bool(v))))
        for i, (_, t) in enumerate(fields_)
        if t is bool or (isinstance(t, type) and issubclass(t, enum.Enum))
    ]
    if not conv:
        if len(fields_) == 1:
            return lambda seq, s: (s.time_s, seq, get(s))
        return lambda seq, s: (s.time_s, seq, *get(s))

    def encode(seq: int, s: Any) -> tuple[object, ...]:
        vals = list(get(s))
        for i, f in conv:
            vals[i] = f(vals[i])
        return (s.time_s, seq, *vals)

    return encode


SAMPLE_ENCODERS = {cls: _sample_encoder(cls) for cls in SAMPLE_FILES}


def decode_value(text: str, typ: Any) -> object:
    """A CSV cell back into a field of type ``typ`` (float, int, bool, str or an Enum)."""
    if typ is float:
        return float(text)
    if typ is bool:
        if text not in ("0", "1"):
            raise ValueError("expected 0 or 1")
        return text == "1"
    if typ is int:
        return int(text)
    if typ is str:
        return text
    if isinstance(typ, type) and issubclass(typ, enum.Enum):
        return typ(text)
    raise TypeError(f"no CSV codec for {typ!r}")


# ---------------------------------------------------------------------------------------------
# the other streams

CAMERA_COLUMNS = (
    "time_s",  # exposure time
    "seq",
    "arrival_s",
    "t_x_m",  # T_camera_pad translation: the pad centre in the camera frame
    "t_y_m",
    "t_z_m",
    "r00",  # T_camera_pad rotation matrix, row-major (unitless)
    "r01",
    "r02",
    "r10",
    "r11",
    "r12",
    "r20",
    "r21",
    "r22",
    "roll_rad",  # ZYX Euler angles of the same rotation (for plotting; replay uses r..)
    "pitch_rad",
    "yaw_rad",
    "ambiguous",
    "markers",
    "reprojection_error_px",
)
UWB_COLUMNS = (
    "time_s",
    "seq",
    "arrival_s",
    "x_m",
    "y_m",
    "z_m",
    "pdop",
    "residual_rms_m",
    "anchors_used",
    "frame",
    "hdop",  # horizontal / vertical DOP in the anchor frame (NaN when the solver gave none)
    "vdop",
    "vertical_weak",  # coplanar anchors: the EKF weights the vertical by vdop
)
_AXES12 = (
    ("north", "m"),
    ("east", "m"),
    ("down", "m"),
    ("roll", "rad"),
    ("pitch", "rad"),
    ("yaw", "rad"),
    ("bias_north", "m"),
    ("bias_east", "m"),
    ("bias_down", "m"),
    ("gyro_bias_x", "rad_s"),
    ("gyro_bias_y", "rad_s"),
    ("gyro_bias_z", "rad_s"),
)
_VAR_UNIT = {"m": "m2", "rad": "rad2", "rad_s": "rad2_s2"}
EKF_COLUMNS = (
    "time_s",  # the time the filter state is valid at
    "seq",  # the guidance tick's seq
    "tick_s",
    *(f"{n}_{u}" for n, u in _AXES12),
    "north_m_s",  # the velocity input held by the filter (world NED)
    "east_m_s",
    "down_m_s",
    *(f"var_{n}_{_VAR_UNIT[u]}" for n, u in _AXES12),
    "xi",
    "markers_used",
    "uwb_used",
)
GUIDANCE_COLUMNS = (
    "time_s",
    "seq",
    "link_ok",
    "est_source",
    "est_time_s",
    "est_north_m",
    "est_east_m",
    "est_down_m",
    "est_north_m_s",
    "est_east_m_s",
    "est_down_m_s",
    "est_roll_rad",
    "est_pitch_rad",
    "est_yaw_rad",
    "est_bias_north_m",
    "est_bias_east_m",
    "est_bias_down_m",
    "phase",
    "sector",
    "lyapunov_m2",
    "cmd_north_m_s",
    "cmd_east_m_s",
    "cmd_down_m_s",
    "cmd_yaw_rad",
    "sp_north_m_s",
    "sp_east_m_s",
    "sp_down_m_s",
    "sp_yaw_rad",
    "clamped",
    "request",
    "request_id",
    "request_alt_m",
)
SETPOINT_COLUMNS = ("time_s", "north_m_s", "east_m_s", "down_m_s", "yaw_rad")
REQUEST_COLUMNS = ("time_s", "seq", "id", "kind", "ok", "error", "permanent")
COMMAND_COLUMNS = ("time_s", "seq", "source", "kind", "detail", "reply")
EVENT_COLUMNS = ("time_s", "kind", "phase", "detail")

# The wind estimate each guidance tick handed the mission (MissionInputs.wind; NaN: none), keyed by
# the tick's seq. Written only when the mission reads it (go_no_go.wind_limit_m_s > 0): the
# autopilot's wind is no telemetry sample (no listener sees it), so without this replay cannot
# know what the wind go/no-go saw.
WIND_FILE = "wind.csv"
WIND_COLUMNS = ("time_s", "seq", "wind_time_s", "north_m_s", "east_m_s")

# The winch's report each guidance tick handed the mission (MissionInputs.winch; NaN: none), keyed
# by the tick's seq; written only for a winch delivery (mission.delivery = "winch"), which also
# writes wind.csv (the hover's wind correction reads the wind). Like the wind, no listener sees it.
WINCH_FILE = "winch.csv"
WINCH_COLUMNS = ("time_s", "seq", "winch_time_s", "line_length_m", "speed_m_s", "flags", "tension_kg")
WINCH_COLUMNS_BEFORE_TENSION = WINCH_COLUMNS[:-1]  # a run folder from before the tension was logged

# The drop-zone verdict each guidance tick handed the mission (MissionInputs.drop_zone: "clear",
# "occupied", "motion_in_margin", "unknown"; "" none), keyed by the tick's seq; written only with
# [landing.drop_zone] on. The check judges the frames, which the run folder does not keep, so
# without this replay cannot know what the mission saw.
DROP_ZONE_FILE = "drop_zone.csv"
DROP_ZONE_COLUMNS = ("time_s", "seq", "verdict")

# The camera's newest sighting of the parcel each guidance tick handed the mission
# (MissionInputs.parcel: the exposure's time, the tag in the camera frame, the parcel's bottom above
# the pad; NaN none), keyed by the tick's seq; written only with [winch.camera] on a winch delivery.
PARCEL_FILE = "parcel.csv"
PARCEL_COLUMNS = ("time_s", "seq", "sighting_time_s", "tag_x_m", "tag_y_m", "tag_z_m", "bottom_above_pad_m")

STREAM_FILES: dict[str, tuple[str, ...]] = {
    **{f: sample_columns(cls) for cls, f in SAMPLE_FILES.items()},
    "camera.csv": CAMERA_COLUMNS,
    "uwb.csv": UWB_COLUMNS,
    "ekf.csv": EKF_COLUMNS,
    "guidance.csv": GUIDANCE_COLUMNS,
    "setpoints.csv": SETPOINT_COLUMNS,
    "requests.csv": REQUEST_COLUMNS,
    "commands.csv": COMMAND_COLUMNS,
    "events.csv": EVENT_COLUMNS,
}

_NAN = math.nan


@dataclasses.dataclass(frozen=True, slots=True)
class PadObservation:
    """A pad observation as the fusion consumes it (what replay feeds back; the live one is a
    :class:`companion.vision.MarkerObservation`)."""

    time_s: float
    T_camera_pad: Transform
    ambiguous: bool
    markers: tuple[str, ...] = ()
    reprojection_error_px: float = _NAN


def camera_row(seq: int, arrival_s: float, obs: Any) -> tuple[object, ...]:
    T = obs.T_camera_pad
    R = np.asarray(T.R, dtype=float)
    roll, pitch, yaw = rotmat_to_euler(R)
    return (
        float(obs.time_s),
        seq,
        float(arrival_s),
        *(float(v) for v in np.asarray(T.t, dtype=float).reshape(3)),
        *(float(v) for v in R.reshape(9)),
        float(roll),
        float(pitch),
        float(yaw),
        int(bool(getattr(obs, "ambiguous", False))),
        " ".join(getattr(obs, "markers", ())),
        float(getattr(obs, "reprojection_error_px", _NAN)),
    )


def uwb_row(seq: int, arrival_s: float, fix: Any) -> tuple[object, ...]:
    return (
        float(fix.time_s),
        seq,
        float(arrival_s),
        float(fix.x_m),
        float(fix.y_m),
        float(fix.z_m),
        float(fix.pdop),
        float(getattr(fix, "residual_rms_m", _NAN)),
        " ".join(getattr(fix, "anchors_used", ())),
        str(getattr(fix, "frame", "")),
        float(getattr(fix, "hdop", _NAN)),
        float(getattr(fix, "vdop", _NAN)),
        int(bool(getattr(fix, "vertical_weak", False))),
    )


def ekf_row(seq: int, tick_s: float, fusion: Any) -> tuple[object, ...] | None:
    """The fusion's EKF state, or None before the filter is initialised (no row then)."""
    ekf = fusion.ekf
    if not ekf.initialized:
        return None
    # the paper's twelve states (a moving pad's filter has two more, the pad's velocity: not in
    # this file's columns, which every log keeps)
    x = ekf.x[0:12]
    d = np.diag(ekf.P)[0:12]
    return (
        float(fusion.buffer.now_s),
        seq,
        float(tick_s),
        *(float(v) for v in x),
        *(float(v) for v in ekf.last_input[:3]),
        *(float(v) for v in d),
        int(bool(ekf.xi)),
        int(fusion.counters.markers_used),
        int(fusion.counters.uwb_used),
    )


def guidance_row(seq: int, inp: Any, out: Any, setpoint: VelocitySetpoint | None, clamped: bool) -> tuple[object, ...]:
    """One guidance tick: the mission's inputs (``MissionInputs``) and output (``MissionOutput``),
    and the clamped setpoint the shell streams (None when the mission gave none)."""
    e = inp.estimate
    cmd = out.setpoint
    req = out.request
    return (
        (inp.time_s, seq, int(bool(inp.link_ok)))
        + (
            (
                e.source,
                e.time_s,
                e.north_m,
                e.east_m,
                e.down_m,
                e.north_m_s,
                e.east_m_s,
                e.down_m_s,
                e.roll_rad,
                e.pitch_rad,
                e.yaw_rad,
                e.gps_bias_north_m,
                e.gps_bias_east_m,
                e.gps_bias_down_m,
            )
            if e is not None
            else _NO_ESTIMATE
        )
        + (ENUM_VALUE[out.phase], out.sector, float(out.lyapunov))
        + ((cmd.north_m_s, cmd.east_m_s, cmd.down_m_s, cmd.yaw_rad) if cmd is not None else _NAN4)
        + (
            (setpoint.north_m_s, setpoint.east_m_s, setpoint.down_m_s, setpoint.yaw_rad)
            if setpoint is not None
            else _NAN4
        )
        + (
            (int(bool(clamped)), ENUM_VALUE[req.kind], req.id, float(req.alt_rel_m))
            if req is not None
            else (int(bool(clamped)), "", 0, _NAN)
        )
    )


_NO_ESTIMATE = ("", *([_NAN] * 13))
_NAN4 = (_NAN, _NAN, _NAN, _NAN)


def transform_json(T: Transform) -> dict[str, list[Any]]:
    return {"R": np.asarray(T.R, dtype=float).tolist(), "t": np.asarray(T.t, dtype=float).tolist()}


def transform_from_json(d: dict[str, Any]) -> Transform:
    return Transform(np.array(d["R"], dtype=float).reshape(3, 3), np.array(d["t"], dtype=float).reshape(3))
