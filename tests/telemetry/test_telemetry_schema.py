"""Schema ``companion.telemetry/1``: every message round-trips; malformed payloads raise
SchemaError (never another exception type)."""

from __future__ import annotations

import json
import math
import threading
import time
from dataclasses import dataclass

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from companion.autopilot.types import FlightMode, GlobalPosition, GpsRaw, LandedState, StatusText, VehicleStatus
from companion.estimation.types import StateEstimate
from companion.events import EventKind, MissionEvent, Phase
from companion.telemetry import schema
from companion.telemetry.schema import (
    ESTIMATE_STATES,
    MAX_PAYLOAD_BYTES,
    SCHEMA,
    EstimateMessage,
    HealthMessage,
    LandingMessage,
    LogMessage,
    MissionMessage,
    RejectionCount,
    SchemaError,
    SensorHealth,
    StateMessage,
    TaskHealth,
    Topic,
    alive_key,
    command_key,
    decode,
    encode,
    info_key,
    message_from_dict,
    message_to_dict,
    parse_key,
    topic_key,
    topic_of,
)

EST = StateEstimate(
    time_s=12.5, north_m=10.0, east_m=-4.0, down_m=-45.0, north_m_s=3.0, east_m_s=4.0, down_m_s=-0.5,
    roll_rad=0.01, pitch_rad=-0.02, yaw_rad=1.2, source="ekf",
    gps_bias_north_m=0.4, gps_bias_east_m=-0.3, gps_bias_down_m=0.1,
)  # fmt: skip

STATE = StateMessage.from_samples(
    EST,
    GlobalPosition(12.4, -19.8683612, -43.9631248, 895.0, 45.0),
    VehicleStatus(12.3, True, FlightMode.OFFBOARD, LandedState.IN_AIR, True, 76.5, False),
    GpsRaw(12.2, -19.8683612, -43.9631248, 895.1, 3, 14, 0.8),
)
MESSAGES = [
    STATE,
    StateMessage(1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0),  # minimal: ints for floats are accepted
    EstimateMessage.from_estimate(
        EST,
        covariance_diag=tuple(0.01 * (i + 1) for i in range(12)),
        gyro_bias_rad_s=(1e-3, -2e-3, 5e-4),
        fused_count=1000,
        rejected_count=3,
    ),
    EstimateMessage(2.0, "passthrough", 1.0, 2.0, 3.0, 0.0, 0.0, 0.5),
    MissionMessage(
        3.0, Phase.OUTBOUND, sector=3, lyapunov_v_m2=0.25, speed_ref_m_s=5.0, sense=1, distance_to_pad_m=60.0
    ),
    MissionMessage.for_event(MissionEvent(4.0, EventKind.SECTOR, Phase.OUTBOUND, "S4"), sector=4),
    MissionMessage(5.0, Phase.PILOT, event=MissionEvent(5.0, EventKind.PILOT_TAKEOVER, Phase.PILOT)),
    LandingMessage(
        6.0,
        True,
        markers_seen=(0, 7, 42),
        pad_rel_north_m=0.3,
        pad_rel_east_m=-0.1,
        pad_rel_down_m=2.5,
        observation_age_s=0.03,
        landing_error_m=0.32,
        uwb_fix_ok=True,
        uwb_anchors_used=4,
        uwb_residual_m=0.05,
        uwb_fix_age_s=0.1,
    ),
    LandingMessage(7.0, False),
    HealthMessage(
        8.0,
        True,
        heartbeat_age_s=0.2,
        sensors=(SensorHealth("camera", True, 30.0), SensorHealth("uwb", False, None, "no fix")),
        tasks=(TaskHealth("fusion", 200.0, overruns=2, max_duration_ms=4.5), TaskHealth("vision", 30.0)),
        rejected=(RejectionCount("aruco", 5), RejectionCount("uwb", 1)),
        telemetry_dropped=0,
        cpu_pct=35.0,
    ),
    LogMessage(9.0, 4, "GPS glitch — ünïcödé ok", source="autopilot"),
    LogMessage.from_status_text(StatusText(10.0, 6, "Takeoff detected")),
]


@pytest.mark.parametrize("msg", MESSAGES, ids=lambda m: type(m).__name__)
def test_round_trip(msg) -> None:
    payload = encode("drone-1", msg, seq=7, sent_unix_s=1.7e9)
    env = decode(payload, key=topic_key("drone-1", topic_of(msg)))
    assert env.msg == msg
    assert type(env.msg) is type(msg)
    assert (env.vehicle_id, env.topic, env.seq, env.sent_unix_s) == ("drone-1", topic_of(msg), 7, 1.7e9)
    doc = json.loads(payload)
    assert doc["schema"] == SCHEMA == "companion.telemetry/1"
    assert message_from_dict(topic_of(msg), message_to_dict(msg)) == msg


def test_every_topic_has_a_round_trip_case() -> None:
    assert {topic_of(m) for m in MESSAGES} == set(Topic)


def test_from_samples_copies_units_and_enums() -> None:
    assert STATE.mode is FlightMode.OFFBOARD and STATE.landed is LandedState.IN_AIR
    assert STATE.gps_satellites == 14 and STATE.battery_pct == 76.5 and STATE.source == "ekf"
    assert STATE.ground_speed_m_s == pytest.approx(5.0)
    doc = json.loads(encode("d", STATE, 0, 0.0))["msg"]
    assert doc["mode"] == "offboard" and doc["lat_deg"] == -19.8683612


@settings(max_examples=50, deadline=None, derandomize=True, database=None)
@given(
    st.lists(st.floats(allow_nan=False, allow_infinity=False, width=64), min_size=10, max_size=10),
    st.one_of(st.none(), st.floats(min_value=0, max_value=100)),
)
def test_state_round_trip_any_finite_floats(values: list[float], battery: float | None) -> None:
    msg = StateMessage(*values, battery_pct=battery)
    assert decode(encode("v", msg, 0, 0.0)).msg == msg


def test_keys() -> None:
    assert topic_key("drone1", Topic.STATE) == "companion/drone1/state"
    assert alive_key("drone1") == "companion/drone1/alive"
    assert info_key("drone1") == "companion/drone1/info"
    assert command_key("drone1") == "companion/drone1/command"
    assert parse_key("companion/drone1/health") == ("drone1", "health")
    for bad in ("companion/a/b/c", "other/drone1/state", "companion/../state", "companion/*/state"):
        with pytest.raises(SchemaError):
            parse_key(bad)
    for bad_id in ("", "a/b", "a*", "x" * 65, "a.b"):
        with pytest.raises(SchemaError):
            topic_key(bad_id, Topic.STATE)


def _good_doc() -> dict:
    return json.loads(encode("drone1", MESSAGES[0], 3, 1.0))


def _mutate(path: tuple, value) -> bytes:
    doc = _good_doc()
    target = doc
    for p in path[:-1]:
        target = target[p]
    if value is KeyError:
        del target[path[-1]]
    else:
        target[path[-1]] = value
    return json.dumps(doc).encode()


MALFORMED = {
    "not json": b"{nope",
    "not utf8": b"\xff\xfe\x00",
    "json array": b"[1, 2]",
    "empty": b"",
    "nan literal": json.dumps(_good_doc()).replace("-45.0", "NaN", 1).encode(),
    "infinity literal": json.dumps(_good_doc()).replace("-45.0", "Infinity", 1).encode(),
    "no schema": _mutate(("schema",), KeyError),
    "other schema": _mutate(("schema",), "other.thing/1"),
    "future major": _mutate(("schema",), "companion.telemetry/2"),
    "schema not str": _mutate(("schema",), 1),
    "bad vehicle id": _mutate(("vehicle_id",), "a/b"),
    "unknown topic": _mutate(("topic",), "weather"),
    "negative seq": _mutate(("seq",), -1),
    "float seq": _mutate(("seq",), 1.5),
    "bool seq": _mutate(("seq",), True),
    "missing msg": _mutate(("msg",), KeyError),
    "msg not object": _mutate(("msg",), [1, 2]),
    "missing required field": _mutate(("msg", "north_m"), KeyError),
    "string for float": _mutate(("msg", "north_m"), "10"),
    "bool for float": _mutate(("msg", "north_m"), True),
    "null for required float": _mutate(("msg", "north_m"), None),
    "float for int": _mutate(("msg", "gps_satellites"), 14.5),
    "int for bool": _mutate(("msg", "armed"), 1),
    "unknown enum": _mutate(("msg", "mode"), "warp"),
    "huge number": json.dumps(_good_doc()).replace("-45.0", "1e999", 1).encode(),
    "integer of 5000 digits": json.dumps(_good_doc()).replace("-45.0", "9" * 5000, 1).encode(),
    "seq of 5000 digits": _mutate(("seq",), 0).replace(b'"seq": 0', b'"seq": ' + b"1" * 5000),
    "oversize": b'{"schema":"companion.telemetry/1","pad":"' + b"x" * MAX_PAYLOAD_BYTES + b'"}',
}


@pytest.mark.parametrize("payload", list(MALFORMED.values()), ids=list(MALFORMED))
def test_malformed_payloads_raise_schema_error(payload: bytes) -> None:
    with pytest.raises(SchemaError):
        decode(payload)


def test_nested_malformed() -> None:
    health = json.loads(encode("d", MESSAGES[9], 0, 0.0))
    health["msg"]["sensors"][0]["ok"] = "yes"
    with pytest.raises(SchemaError, match=r"sensors\[0\]\.ok"):
        decode(json.dumps(health))
    health["msg"]["sensors"] = [{"name": "x", "ok": True}] * 300
    with pytest.raises(SchemaError, match="more than"):
        decode(json.dumps(health))
    mission = json.loads(encode("d", MESSAGES[5], 0, 0.0))
    mission["msg"]["event"]["kind"] = "explode"
    with pytest.raises(SchemaError, match=r"event\.kind"):
        decode(json.dumps(mission))
    est = json.loads(encode("d", MESSAGES[2], 0, 0.0))
    est["msg"]["covariance_diag"] = [1.0, 2.0]
    with pytest.raises(SchemaError, match="covariance_diag"):
        decode(json.dumps(est))


def test_key_must_match_payload() -> None:
    payload = encode("drone1", STATE, 0, 0.0)
    with pytest.raises(SchemaError, match="does not match"):
        decode(payload, key="companion/drone2/state")
    with pytest.raises(SchemaError, match="does not match"):
        decode(payload, key="companion/drone1/health")


def test_unknown_fields_are_ignored_within_a_major_version() -> None:
    doc = _good_doc()
    doc["msg"]["airspeed_m_s"] = 12.0
    doc["added_later"] = {"x": 1}
    assert decode(json.dumps(doc)).msg == MESSAGES[0]


def test_encode_refuses_invalid_messages() -> None:
    with pytest.raises(SchemaError, match="not finite"):
        encode("d", StateMessage(math.nan, 0, 0, 0, 0, 0, 0, 0, 0, 0), 0, 0.0)
    with pytest.raises(SchemaError, match="not finite"):
        encode("d", StateMessage(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, battery_pct=math.inf), 0, 0.0)
    with pytest.raises(SchemaError):
        encode("d", StateMessage(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, mode="offboard"), 0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(SchemaError, match="not a telemetry message"):
        encode("d", EST, 0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(SchemaError, match="covariance_diag"):
        EstimateMessage(0, "ekf", 0, 0, 0, 0, 0, 0, covariance_diag=(1.0,) * 11)
    assert len(ESTIMATE_STATES) == 12


def test_encode_accepts_numpy_scalars_and_refuses_wrong_types() -> None:
    import numpy as np

    msg = StateMessage(np.float64(1.5), np.float32(2.0), 0, 0, 0, 0, 0, 0, 0, 0, gps_satellites=np.int64(9))  # type: ignore[arg-type]
    decoded = decode(encode("d", msg, 0, 0.0)).msg
    assert decoded.time_s == 1.5 and decoded.north_m == 2.0 and decoded.gps_satellites == 9
    with pytest.raises(SchemaError, match="text"):
        encode("d", LogMessage(0.0, 6, 123), 0, 0.0)  # type: ignore[arg-type]
    with pytest.raises(SchemaError, match="armed"):
        encode("d", StateMessage(0, 0, 0, 0, 0, 0, 0, 0, 0, 0, armed=1), 0, 0.0)  # type: ignore[arg-type]


@dataclass(frozen=True)
class _Pair:
    a_m: float
    b_m: float


def test_a_codec_being_built_is_waited_for_not_called(monkeypatch) -> None:
    # A thread that needs a codec another thread is building must wait for it: calling the
    # forwarding stub meanwhile recursed without end (seen with five publisher threads on a slow core).
    building, real_hints = threading.Event(), schema.typing.get_type_hints

    def slow_hints(cls, *args, **kwargs):
        if cls is _Pair:
            building.set()
            time.sleep(0.3)
        return real_hints(cls, *args, **kwargs)

    monkeypatch.setattr(schema.typing, "get_type_hints", slow_hints)
    builder = threading.Thread(target=schema._dataclass_encoder, args=(_Pair,))
    builder.start()
    assert building.wait(5.0)
    try:
        assert schema._dataclass_encoder(_Pair)(_Pair(1.0, 2.0), "pair") == {"a_m": 1.0, "b_m": 2.0}
        assert schema._dataclass_decoder(_Pair)({"a_m": 1.0, "b_m": 2.0}, "pair") == _Pair(1.0, 2.0)
    finally:
        builder.join()
