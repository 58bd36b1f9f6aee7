"""Ground telemetry key space, message schema and JSON codec (schema ``companion.telemetry/1``).

Key space (every key starts with :data:`KEY_ROOT`, ``vehicle_id`` matches
:data:`VEHICLE_ID_PATTERN`)::

    companion/<vehicle_id>/state     StateMessage      pose, velocity, attitude, GPS, mode, battery
    companion/<vehicle_id>/estimate  EstimateMessage   EKF state, covariance diagonal, GPS bias
    companion/<vehicle_id>/mission   MissionMessage    phase, sector, V, and mission events
    companion/<vehicle_id>/landing   LandingMessage    pad observations, UWB fix quality
    companion/<vehicle_id>/health    HealthMessage     link, sensors, task overruns, rejections
    companion/<vehicle_id>/log       LogMessage        status text
    companion/<vehicle_id>/alive     liveliness token  (presence; no payload)
    companion/<vehicle_id>/info      queryable         identity, versions, params (JSON)
    companion/<vehicle_id>/command   queryable         ground commands (off by default; see auth.py)

Encoding: one UTF-8 JSON object per Zenoh sample (Zenoh encoding ``application/json``), the
*envelope*::

    {"schema": "companion.telemetry/1", "vehicle_id": "drone1", "topic": "state",
     "seq": 42, "sent_unix_s": 1763750000.123, "msg": {...}}

``seq`` counts messages per vehicle and topic from 0 (a gap means a lost message);
``sent_unix_s`` is the wall clock when the vehicle encoded the message (for latency only).
``msg`` holds the fields of the topic's dataclass below, by name. Units and frames are in the
field names (SI, radians, world NED metres; degrees only in ``*_deg``). Enums travel as their
string values, tuples as arrays, optional fields as ``null``. Non-finite floats are not valid.

Versioning: ``schema`` is ``companion.telemetry/<major>``. Within one major version fields are
only ever *added*, with defaults, so a decoder ignores unknown fields and fills missing optional
ones; removing or re-typing a field bumps the major version, and a decoder refuses other majors.

Anything that does not follow these rules raises :class:`SchemaError` (never a bare
``KeyError``/``TypeError``), so a receiver can count and drop malformed payloads.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
import numbers
import re
import threading
import types
import typing
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.autopilot.types import (
    FlightMode,
    GlobalPosition,
    GpsRaw,
    LandedState,
    StatusText,
    VehicleStatus,
)
from companion.estimation.types import StateEstimate
from companion.events import MissionEvent, Phase

SCHEMA_NAME = "companion.telemetry"
SCHEMA_MAJOR = 1
SCHEMA = f"{SCHEMA_NAME}/{SCHEMA_MAJOR}"
KEY_ROOT = "companion"
VEHICLE_ID_PATTERN = re.compile(r"^[A-Za-z0-9_-]{1,64}$")
MAX_PAYLOAD_BYTES = 64 * 1024
MAX_STR_CHARS = 4096
MAX_ARRAY_ITEMS = 256


class SchemaError(ValueError):
    """A telemetry payload or key does not follow ``companion.telemetry/1``."""


class Topic(enum.Enum):
    STATE = "state"
    ESTIMATE = "estimate"
    MISSION = "mission"
    LANDING = "landing"
    HEALTH = "health"
    LOG = "log"


# ---------------------------------------------------------------------------------------------
# Keys


def check_vehicle_id(vehicle_id: str) -> str:
    if not isinstance(vehicle_id, str) or not VEHICLE_ID_PATTERN.match(vehicle_id):
        raise SchemaError(
            f"vehicle_id {vehicle_id!r} must match {VEHICLE_ID_PATTERN.pattern} "
            "(letters, digits, '_' and '-'; no '/', '*', '$')"
        )
    return vehicle_id


def topic_key(vehicle_id: str, topic: Topic) -> str:
    return f"{KEY_ROOT}/{check_vehicle_id(vehicle_id)}/{topic.value}"


def alive_key(vehicle_id: str) -> str:
    return f"{KEY_ROOT}/{check_vehicle_id(vehicle_id)}/alive"


def info_key(vehicle_id: str) -> str:
    return f"{KEY_ROOT}/{check_vehicle_id(vehicle_id)}/info"


def command_key(vehicle_id: str) -> str:
    return f"{KEY_ROOT}/{check_vehicle_id(vehicle_id)}/command"


def order_key(vehicle_id: str) -> str:
    """The queryable a vehicle takes delivery orders on (:mod:`companion.telemetry.orders`)."""
    return f"{KEY_ROOT}/{check_vehicle_id(vehicle_id)}/order"


ALL_VEHICLES_KEY = f"{KEY_ROOT}/**"
ALL_ALIVE_KEY = f"{KEY_ROOT}/*/alive"


def parse_key(key: str) -> tuple[str, str]:
    """``companion/<vehicle_id>/<leaf>`` -> ``(vehicle_id, leaf)``; anything else: SchemaError."""
    parts = str(key).split("/")
    if len(parts) != 3 or parts[0] != KEY_ROOT:
        raise SchemaError(f"key {key!r} is not {KEY_ROOT}/<vehicle_id>/<leaf>")
    return check_vehicle_id(parts[1]), parts[2]


# ---------------------------------------------------------------------------------------------
# Messages


@dataclass(frozen=True, slots=True)
class StateMessage:
    """Vehicle state at ``time_s`` (the shell's monotonic clock): world NED pose and velocity,
    attitude, the autopilot's global position and GPS quality, arming, mode and battery.

    ``*_age_s``: how old the autopilot sample behind those fields was when the message was
    built (``status_age_s``: armed, mode, landed, battery; ``gps_age_s``: the GPS fields;
    ``global_position_age_s``: lat/lon/alt). None when the sample never arrived; then its fields
    keep their defaults (mode ``unknown``, GPS fix 0, None)."""

    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    lat_deg: float | None = None
    lon_deg: float | None = None
    alt_amsl_m: float | None = None
    alt_rel_m: float | None = None
    gps_fix_type: int = 0
    gps_satellites: int = 0
    gps_eph_m: float | None = None
    armed: bool = False
    mode: FlightMode = FlightMode.UNKNOWN
    landed: LandedState = LandedState.UNKNOWN
    battery_pct: float | None = None
    source: str = "autopilot"
    status_age_s: float | None = None
    gps_age_s: float | None = None
    global_position_age_s: float | None = None

    @property
    def ground_speed_m_s(self) -> float:
        return math.hypot(self.north_m_s, self.east_m_s)

    @classmethod
    def from_samples(
        cls,
        estimate: StateEstimate,
        position: GlobalPosition | None = None,
        status: VehicleStatus | None = None,
        gps: GpsRaw | None = None,
        now_s: float | None = None,
    ) -> StateMessage:
        """``now_s`` (the shell's clock when the message is built) fills the ``*_age_s`` fields."""

        def age(sample: GlobalPosition | VehicleStatus | GpsRaw | None) -> float | None:
            return None if sample is None or now_s is None else max(0.0, now_s - sample.time_s)

        return cls(
            time_s=estimate.time_s,
            north_m=estimate.north_m,
            east_m=estimate.east_m,
            down_m=estimate.down_m,
            north_m_s=estimate.north_m_s,
            east_m_s=estimate.east_m_s,
            down_m_s=estimate.down_m_s,
            roll_rad=estimate.roll_rad,
            pitch_rad=estimate.pitch_rad,
            yaw_rad=estimate.yaw_rad,
            lat_deg=position.lat_deg if position else None,
            lon_deg=position.lon_deg if position else None,
            alt_amsl_m=position.alt_amsl_m if position else None,
            alt_rel_m=position.alt_rel_m if position else None,
            gps_fix_type=gps.fix_type if gps else 0,
            gps_satellites=gps.satellites if gps else 0,
            gps_eph_m=gps.eph_m if gps else None,
            armed=status.armed if status else False,
            mode=status.mode if status else FlightMode.UNKNOWN,
            landed=status.landed if status else LandedState.UNKNOWN,
            battery_pct=status.battery_pct if status else None,
            source=estimate.source,
            status_age_s=age(status),
            gps_age_s=age(gps),
            global_position_age_s=age(position),
        )


#: Order of the 12 EKF states (delivery paper) in ``EstimateMessage.covariance_diag``;
#: variances in SI units squared (m^2, rad^2, (rad/s)^2).
ESTIMATE_STATES: tuple[str, ...] = (
    "north_m", "east_m", "down_m",
    "roll_rad", "pitch_rad", "yaw_rad",
    "gps_bias_north_m", "gps_bias_east_m", "gps_bias_down_m",
    "gyro_bias_x_rad_s", "gyro_bias_y_rad_s", "gyro_bias_z_rad_s",
)  # fmt: skip


@dataclass(frozen=True, slots=True)
class EstimateMessage:
    """The fused estimate (12-state EKF): state, covariance diagonal (order
    :data:`ESTIMATE_STATES`, empty when the source has none) and measurement bookkeeping."""

    time_s: float
    source: str
    north_m: float
    east_m: float
    down_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    gps_bias_north_m: float = 0.0
    gps_bias_east_m: float = 0.0
    gps_bias_down_m: float = 0.0
    gyro_bias_x_rad_s: float = 0.0
    gyro_bias_y_rad_s: float = 0.0
    gyro_bias_z_rad_s: float = 0.0
    covariance_diag: tuple[float, ...] = ()
    fused_count: int = 0
    rejected_count: int = 0

    def __post_init__(self) -> None:
        if self.covariance_diag and len(self.covariance_diag) != len(ESTIMATE_STATES):
            raise SchemaError(
                f"covariance_diag has {len(self.covariance_diag)} values, "
                f"expected {len(ESTIMATE_STATES)} (ESTIMATE_STATES) or none"
            )

    @classmethod
    def from_estimate(
        cls,
        estimate: StateEstimate,
        covariance_diag: tuple[float, ...] = (),
        gyro_bias_rad_s: tuple[float, float, float] = (0.0, 0.0, 0.0),
        fused_count: int = 0,
        rejected_count: int = 0,
    ) -> EstimateMessage:
        return cls(
            time_s=estimate.time_s,
            source=estimate.source,
            north_m=estimate.north_m,
            east_m=estimate.east_m,
            down_m=estimate.down_m,
            roll_rad=estimate.roll_rad,
            pitch_rad=estimate.pitch_rad,
            yaw_rad=estimate.yaw_rad,
            gps_bias_north_m=estimate.gps_bias_north_m,
            gps_bias_east_m=estimate.gps_bias_east_m,
            gps_bias_down_m=estimate.gps_bias_down_m,
            gyro_bias_x_rad_s=gyro_bias_rad_s[0],
            gyro_bias_y_rad_s=gyro_bias_rad_s[1],
            gyro_bias_z_rad_s=gyro_bias_rad_s[2],
            covariance_diag=tuple(float(v) for v in covariance_diag),
            fused_count=fused_count,
            rejected_count=rejected_count,
        )


@dataclass(frozen=True, slots=True)
class MissionMessage:
    """Mission progress: phase, path sector S1..S5 (None outside the vector field), the
    vector field's Lyapunov value V = (a1^2 + a2^2)/2 (delivery eq 18), the sector reference
    speed v_i, the sense s (+1 outbound, -1 inbound, 0 otherwise), the horizontal distance from
    the position estimate the mission flies on to the *configured* pad (the fused distance to the pad as
    found is ``LandingMessage.landing_error_m``) and, when the message carries one, a mission
    event. Fields the mission has no value for this tick are absent (None); messages with an
    ``event`` are never dropped."""

    time_s: float
    phase: Phase
    sector: int | None = None
    lyapunov_v_m2: float | None = None
    speed_ref_m_s: float | None = None
    sense: int = 0
    distance_to_pad_m: float | None = None
    event: MissionEvent | None = None

    @classmethod
    def for_event(cls, event: MissionEvent, sector: int | None = None) -> MissionMessage:
        return cls(time_s=event.time_s, phase=event.phase, sector=sector, event=event)


@dataclass(frozen=True, slots=True)
class LandingMessage:
    """Landing, published while the landing fusion runs (absent with GPS only).

    ``pad_visible``: an observation of the pad was fused within the last 0.5 s.
    ``markers_seen`` (ArUco ids) / ``marker_names`` ("outer", "inner"), ``pad_rel_*_m`` (the pad
    centre relative to the vehicle, world NED axes, metres) describe the last *fused* pad
    observation, ``observation_age_s`` old (all absent before the first one).
    ``landing_error_m``: the estimated horizontal distance from the vehicle to the pad centre
    (fused estimate), absent until pad data (camera or UWB) has been fused.
    ``uwb_fix_ok``: a UWB fix was fused within the last 0.5 s; ``uwb_anchors_used`` and
    ``uwb_residual_m`` describe the last fused fix, ``uwb_fix_age_s`` old (absent/0 before one)."""

    time_s: float
    pad_visible: bool
    markers_seen: tuple[int, ...] = ()
    pad_rel_north_m: float | None = None
    pad_rel_east_m: float | None = None
    pad_rel_down_m: float | None = None
    observation_age_s: float | None = None
    landing_error_m: float | None = None
    uwb_fix_ok: bool = False
    uwb_anchors_used: int = 0
    uwb_residual_m: float | None = None
    uwb_fix_age_s: float | None = None
    marker_names: tuple[str, ...] = ()


@dataclass(frozen=True, slots=True)
class SensorHealth:
    name: str
    ok: bool
    rate_hz: float | None = None
    detail: str = ""


@dataclass(frozen=True, slots=True)
class TaskHealth:
    name: str
    rate_hz: float
    overruns: int = 0
    max_duration_ms: float | None = None


@dataclass(frozen=True, slots=True)
class RejectionCount:
    source: str
    count: int


@dataclass(frozen=True, slots=True)
class HealthMessage:
    """Link and sensor health, task overruns, rejected measurements, and the telemetry
    publisher's own dropped-sample count. ``heartbeat_age_s``: since the autopilot's last
    HEARTBEAT (absent without one); ``cpu_pct``: the companion process's CPU time over wall time
    since the previous health message, in % of one core (absent in the first)."""

    time_s: float
    link_ok: bool
    heartbeat_age_s: float | None = None
    sensors: tuple[SensorHealth, ...] = ()
    tasks: tuple[TaskHealth, ...] = ()
    rejected: tuple[RejectionCount, ...] = ()
    telemetry_dropped: int = 0
    cpu_pct: float | None = None


@dataclass(frozen=True, slots=True)
class LogMessage:
    """Status text; ``severity`` is the MAVLink/syslog scale (0 emergency .. 7 debug)."""

    time_s: float
    severity: int
    text: str
    source: str = "companion"

    @classmethod
    def from_status_text(cls, status: StatusText, source: str = "autopilot") -> LogMessage:
        return cls(time_s=status.time_s, severity=status.severity, text=status.text, source=source)


Message = StateMessage | EstimateMessage | MissionMessage | LandingMessage | HealthMessage | LogMessage

MESSAGE_TYPES: dict[Topic, type] = {
    Topic.STATE: StateMessage,
    Topic.ESTIMATE: EstimateMessage,
    Topic.MISSION: MissionMessage,
    Topic.LANDING: LandingMessage,
    Topic.HEALTH: HealthMessage,
    Topic.LOG: LogMessage,
}
TOPIC_OF: dict[type, Topic] = {cls: topic for topic, cls in MESSAGE_TYPES.items()}


def topic_of(msg: object) -> Topic:
    try:
        return TOPIC_OF[type(msg)]
    except KeyError:
        raise SchemaError(f"{type(msg).__name__} is not a telemetry message") from None


@dataclass(frozen=True, slots=True)
class Envelope:
    """One decoded sample: who sent it, which topic, its sequence number and the message."""

    vehicle_id: str
    topic: Topic
    seq: int
    sent_unix_s: float
    msg: Message


# ---------------------------------------------------------------------------------------------
# Generic, validating codec driven by the dataclasses' type hints (built once per class).

_Conv = Callable[[Any, str], Any]
_decoders: dict[type, _Conv] = {}
_encoders: dict[type, _Conv] = {}
# Building a codec registers a forwarding stub first (recursive types); another thread must wait for
# the finished codec, not call the stub (endless recursion), so lookups and builds hold this lock.
_codec_lock = threading.RLock()


def _dec_float(v: Any, path: str) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float):
        raise SchemaError(f"{path}: expected a number, got {type(v).__name__}")
    f = float(v)
    if not math.isfinite(f):
        raise SchemaError(f"{path}: {v!r} is not finite")
    return f


def _dec_int(v: Any, path: str) -> int:
    if isinstance(v, bool) or not isinstance(v, int):
        raise SchemaError(f"{path}: expected an integer, got {type(v).__name__}")
    return v


def _dec_bool(v: Any, path: str) -> bool:
    if not isinstance(v, bool):
        raise SchemaError(f"{path}: expected true/false, got {type(v).__name__}")
    return v


def _dec_str(v: Any, path: str) -> str:
    if not isinstance(v, str):
        raise SchemaError(f"{path}: expected a string, got {type(v).__name__}")
    if len(v) > MAX_STR_CHARS:
        raise SchemaError(f"{path}: string longer than {MAX_STR_CHARS} characters")
    return v


def _converters(tp: Any) -> tuple[_Conv, _Conv]:
    """(decoder, encoder) for one annotated type."""
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is float:
        return _dec_float, _enc_float
    if tp is bool:
        return _dec_bool, _enc_bool
    if tp is int:
        return _dec_int, _enc_int
    if tp is str:
        return _dec_str, _enc_str
    if isinstance(tp, type) and issubclass(tp, enum.Enum):
        return _enum_dec(tp), _enc_enum
    if dataclasses.is_dataclass(tp) and isinstance(tp, type):
        return _dataclass_decoder(tp), _dataclass_encoder(tp)
    if origin in (typing.Union, types.UnionType) and len(args) == 2 and type(None) in args:
        inner = args[0] if args[1] is type(None) else args[1]
        dec, enc = _converters(inner)
        return _optional(dec), _optional(enc)
    if origin is tuple:
        if len(args) == 2 and args[1] is Ellipsis:
            dec, enc = _converters(args[0])
            return _var_tuple_dec(dec), _tuple_enc([enc], variadic=True)
        pairs = [_converters(a) for a in args]
        return _fixed_tuple_dec([p[0] for p in pairs]), _tuple_enc([p[1] for p in pairs])
    raise TypeError(f"telemetry codec cannot handle type {tp!r}")


def _optional(conv: _Conv) -> _Conv:
    def f(v: Any, path: str) -> Any:
        return None if v is None else conv(v, path)

    return f


def _enum_dec(cls: type[enum.Enum]) -> _Conv:
    def f(v: Any, path: str) -> Any:
        try:
            return cls(v)
        except ValueError:
            allowed = ", ".join(repr(m.value) for m in cls)
            raise SchemaError(f"{path}: {v!r} is not one of {allowed}") from None

    return f


def _var_tuple_dec(item: _Conv) -> _Conv:
    def f(v: Any, path: str) -> tuple[Any, ...]:
        if not isinstance(v, list):
            raise SchemaError(f"{path}: expected an array, got {type(v).__name__}")
        if len(v) > MAX_ARRAY_ITEMS:
            raise SchemaError(f"{path}: more than {MAX_ARRAY_ITEMS} items")
        return tuple(item(x, f"{path}[{i}]") for i, x in enumerate(v))

    return f


def _fixed_tuple_dec(items: list[_Conv]) -> _Conv:
    def f(v: Any, path: str) -> tuple[Any, ...]:
        if not isinstance(v, list) or len(v) != len(items):
            raise SchemaError(f"{path}: expected an array of {len(items)} items")
        return tuple(conv(x, f"{path}[{i}]") for i, (conv, x) in enumerate(zip(items, v, strict=True)))

    return f


def _dataclass_decoder(cls: type) -> _Conv:
    with _codec_lock:
        return _build_dataclass_decoder(cls)


def _build_dataclass_decoder(cls: type) -> _Conv:
    if cls in _decoders:
        return _decoders[cls]
    hints = typing.get_type_hints(cls)
    specs: list[tuple[str, _Conv, bool]] = []
    # Register a forwarding stub first so recursive types terminate.
    _decoders[cls] = lambda v, p: _decoders[cls](v, p)
    for fld in dataclasses.fields(cls):
        required = fld.default is dataclasses.MISSING and fld.default_factory is dataclasses.MISSING
        specs.append((fld.name, _converters(hints[fld.name])[0], required))

    def f(v: Any, path: str) -> Any:
        if not isinstance(v, dict):
            raise SchemaError(f"{path}: expected an object, got {type(v).__name__}")
        kwargs: dict[str, Any] = {}
        for name, conv, required in specs:
            if name in v:
                kwargs[name] = conv(v[name], f"{path}.{name}")
            elif required:
                raise SchemaError(f"{path}: missing field {name!r}")
        try:
            return cls(**kwargs)
        except SchemaError:
            raise
        except (TypeError, ValueError) as e:
            raise SchemaError(f"{path}: {e}") from None

    _decoders[cls] = f
    return f


def _enc_float(v: Any, path: str) -> float:
    # numbers.Real admits numpy scalars (the EKF's output) as well as Python floats.
    if isinstance(v, bool) or not isinstance(v, numbers.Real):
        raise SchemaError(f"{path}: expected a number, got {type(v).__name__}")
    f = float(v)
    if not math.isfinite(f):
        raise SchemaError(f"{path}: {v!r} is not finite")
    return f


def _enc_int(v: Any, path: str) -> int:
    if isinstance(v, bool) or not isinstance(v, numbers.Integral):
        raise SchemaError(f"{path}: expected an integer, got {type(v).__name__}")
    return int(v)


def _enc_bool(v: Any, path: str) -> bool:
    if not isinstance(v, bool):
        raise SchemaError(f"{path}: expected a bool, got {type(v).__name__}")
    return v


def _enc_str(v: Any, path: str) -> str:
    if not isinstance(v, str):
        raise SchemaError(f"{path}: expected a string, got {type(v).__name__}")
    if len(v) > MAX_STR_CHARS:
        raise SchemaError(f"{path}: string longer than {MAX_STR_CHARS} characters")
    return v


def _enc_enum(v: Any, path: str) -> Any:
    if not isinstance(v, enum.Enum):
        raise SchemaError(f"{path}: expected an enum member, got {v!r}")
    return v.value


def _tuple_enc(items: list[_Conv], variadic: bool = False) -> _Conv:
    def f(v: Any, path: str) -> list[Any]:
        if not isinstance(v, tuple | list):
            raise SchemaError(f"{path}: expected a tuple, got {type(v).__name__}")
        convs = items * len(v) if variadic else items
        if len(convs) != len(v):
            raise SchemaError(f"{path}: expected {len(items)} items")
        return [conv(x, f"{path}[{i}]") for i, (conv, x) in enumerate(zip(convs, v, strict=True))]

    return f


def _dataclass_encoder(cls: type) -> _Conv:
    with _codec_lock:
        return _build_dataclass_encoder(cls)


def _build_dataclass_encoder(cls: type) -> _Conv:
    if cls in _encoders:
        return _encoders[cls]
    _encoders[cls] = lambda v, p: _encoders[cls](v, p)
    hints = typing.get_type_hints(cls)
    specs = [(fld.name, _converters(hints[fld.name])[1]) for fld in dataclasses.fields(cls)]

    def f(v: Any, path: str) -> dict[str, Any]:
        if type(v) is not cls:
            raise SchemaError(f"{path}: expected {cls.__name__}, got {type(v).__name__}")
        return {name: conv(getattr(v, name), f"{path}.{name}") for name, conv in specs}

    _encoders[cls] = f
    return f


# ---------------------------------------------------------------------------------------------
# Public codec


def message_to_dict(msg: Message) -> dict[str, Any]:
    """The JSON-ready ``msg`` object of one message (validated: finite floats, right types)."""
    topic = topic_of(msg)
    return _dataclass_encoder(type(msg))(msg, topic.value)


def message_from_dict(topic: Topic, data: Any) -> Message:
    """Decode and validate the ``msg`` object of one topic."""
    return _dataclass_decoder(MESSAGE_TYPES[topic])(data, topic.value)  # type: ignore[no-any-return]


def encode(vehicle_id: str, msg: Message, seq: int, sent_unix_s: float) -> bytes:
    """The wire bytes (the JSON envelope) of one message."""
    topic = topic_of(msg)
    doc = {
        "schema": SCHEMA,
        "vehicle_id": check_vehicle_id(vehicle_id),
        "topic": topic.value,
        "seq": _enc_int(seq, "seq"),
        "sent_unix_s": _enc_float(sent_unix_s, "sent_unix_s"),
        "msg": message_to_dict(msg),
    }
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def check_schema(value: Any) -> None:
    if not isinstance(value, str) or "/" not in value:
        raise SchemaError(f"schema {value!r} is not '{SCHEMA_NAME}/<major>'")
    name, _, major = value.rpartition("/")
    if name != SCHEMA_NAME:
        raise SchemaError(f"schema {value!r} is not a {SCHEMA_NAME} schema")
    if major != str(SCHEMA_MAJOR):
        raise SchemaError(f"schema {value!r}: this decoder reads major version {SCHEMA_MAJOR}")


def parse_json(payload: bytes | bytearray | memoryview | str) -> Any:
    """Size-check and parse a JSON payload; any failure is a SchemaError."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise SchemaError(f"payload of {len(payload)} bytes exceeds {MAX_PAYLOAD_BYTES}")
    try:
        text = payload if isinstance(payload, str) else bytes(payload).decode("utf-8")
        return json.loads(text, parse_constant=_reject_constant)
    except SchemaError:
        raise
    except (UnicodeDecodeError, json.JSONDecodeError, RecursionError) as e:
        raise SchemaError(f"payload is not valid UTF-8 JSON: {e}") from None
    except ValueError as e:  # an integer of more digits than int() converts (sys.get_int_max_str_digits)
        raise SchemaError(f"payload holds a number JSON parsing refuses: {e}") from None


def _reject_constant(name: str) -> Any:
    raise SchemaError(f"payload contains the non-JSON constant {name}")


def decode(payload: bytes | bytearray | memoryview | str, key: str | None = None) -> Envelope:
    """Decode and validate one envelope. With ``key``, the vehicle id and topic in the payload
    must match the key it arrived on."""
    doc = parse_json(payload)
    if not isinstance(doc, dict):
        raise SchemaError("payload is not a JSON object")
    check_schema(doc.get("schema"))
    for name in ("vehicle_id", "topic", "seq", "sent_unix_s", "msg"):
        if name not in doc:
            raise SchemaError(f"envelope: missing field {name!r}")
    vehicle_id = check_vehicle_id(doc["vehicle_id"])
    topic = _enum_dec(Topic)(doc["topic"], "topic")
    seq = _dec_int(doc["seq"], "seq")
    if seq < 0:
        raise SchemaError("seq must be >= 0")
    sent = _dec_float(doc["sent_unix_s"], "sent_unix_s")
    if key is not None:
        key_vehicle, leaf = parse_key(key)
        if key_vehicle != vehicle_id or leaf != topic.value:
            raise SchemaError(f"payload ({vehicle_id}/{topic.value}) does not match key {key!r}")
    msg = message_from_dict(topic, doc["msg"])
    return Envelope(vehicle_id=vehicle_id, topic=topic, seq=seq, sent_unix_s=sent, msg=msg)
