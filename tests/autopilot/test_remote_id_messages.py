"""The OpenDroneID messages from ``[remote_id]`` (companion.autopilot.remote_id.messages): every
field's encoding as MAVLink common.xml gives it, checked on the wire (packed and parsed back by
pymavlink's ardupilotmega dialect, the one the ArduPilot backend packs with)."""

from __future__ import annotations

import struct

import pytest

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.remote_id.messages import (
    ALT_UNKNOWN_M,
    ODID_EPOCH_UNIX_S,
    OdidMessage,
    OperatorLocation,
    OperatorLocationType,
    basic_id,
    chars,
    deg_e7,
    odid_timestamp,
    operator_id,
    operator_location,
    padded,
    self_id,
    static_messages,
    system,
    system_update,
)
from companion.autopilot.types import HomePosition
from companion.config import RemoteIdConfig

CFG = RemoteIdConfig(
    enabled=True,
    uas_id="1581F0000TEST0042",
    operator_id="FIN87astrdge12k8",
    self_id="parcel delivery",
    operator_location="fixed",
    operator_lat_deg=47.3977419,
    operator_lon_deg=-8.5455938,
    operator_alt_m=488.5,
)
T_UNIX = 1764650000.0  # 2025-12-02


def wire(msg: OdidMessage) -> mavlink.MAVLink_message:
    """``msg`` packed as the backend sends it and parsed back."""
    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=191)
    packet = getattr(mavlink, f"MAVLink_{msg.name.lower()}_message")(**msg.fields)
    back = mav.decode(bytearray(packet.pack(mav)))
    assert back.get_type() == msg.name
    return back


def test_text_fields() -> None:
    assert padded("AB", 5) == [65, 66, 0, 0, 0]
    assert len(padded("", 20)) == 20 and not any(padded("", 20))
    assert padded("x" * 20, 20) == [120] * 20
    with pytest.raises(ValueError, match="holds 20"):
        padded("x" * 21, 20)
    with pytest.raises(UnicodeEncodeError):
        padded("é", 20)
    assert chars("abc", 23) == b"abc"
    with pytest.raises(ValueError, match="holds 23"):
        chars("y" * 24, 23)


def test_degrees_and_time() -> None:
    assert deg_e7(47.3977419) == 473977419
    assert deg_e7(-8.5455938) == -85455938
    assert deg_e7(-35.36326) == -353632600  # rounded, not truncated
    assert deg_e7(180.0) == 1800000000 and deg_e7(-180.0) == -1800000000
    with pytest.raises(ValueError):
        deg_e7(float("nan"))
    assert odid_timestamp(ODID_EPOCH_UNIX_S) == 0
    assert odid_timestamp(ODID_EPOCH_UNIX_S + 3600.9) == 3600  # whole seconds since 2019-01-01 UTC
    with pytest.raises(ValueError, match="epoch"):
        odid_timestamp(0.0)


def test_basic_id_on_the_wire() -> None:
    m = wire(basic_id(CFG, 7))
    assert (m.target_system, m.target_component) == (7, 1)  # the autopilot handles it, not routed on
    assert list(m.id_or_mac) == [0] * 20
    assert m.id_type == mavlink.MAV_ODID_ID_TYPE_SERIAL_NUMBER
    assert m.ua_type == mavlink.MAV_ODID_UA_TYPE_HELICOPTER_OR_MULTIROTOR
    assert bytes(m.uas_id) == b"1581F0000TEST0042\0\0\0"  # uint8_t[20], NUL padded


def test_self_id_and_operator_id_on_the_wire() -> None:
    s = self_id(CFG, 1)
    assert s is not None
    m = wire(s)
    assert m.description_type == mavlink.MAV_ODID_DESC_TYPE_TEXT and m.description == "parcel delivery"
    o = operator_id(CFG, 1)
    assert o is not None
    m = wire(o)
    assert m.operator_id_type == mavlink.MAV_ODID_OPERATOR_ID_TYPE_CAA and m.operator_id == "FIN87astrdge12k8"
    # a full-length text fills its char array exactly
    full = CFG.model_copy(update={"self_id": "z" * 23, "operator_id": "q" * 20})
    assert wire(self_id(full, 1)).description == "z" * 23  # type: ignore[arg-type]
    assert wire(operator_id(full, 1)).operator_id == "q" * 20  # type: ignore[arg-type]
    empty = CFG.model_copy(update={"self_id": "", "operator_id": ""})
    assert self_id(empty, 1) is None and operator_id(empty, 1) is None


def test_system_on_the_wire() -> None:
    where = operator_location(CFG, None)
    assert where == OperatorLocation(OperatorLocationType.FIXED, 47.3977419, -8.5455938, 488.5)
    m = wire(system(where, T_UNIX, 1))
    assert m.operator_location_type == mavlink.MAV_ODID_OPERATOR_LOCATION_TYPE_FIXED
    assert m.classification_type == mavlink.MAV_ODID_CLASSIFICATION_TYPE_UNDECLARED
    assert (m.operator_latitude, m.operator_longitude) == (473977419, -85455938)  # int32 1e-7 deg
    assert (m.area_count, m.area_radius) == (1, 0)
    assert m.area_ceiling == m.area_floor == ALT_UNKNOWN_M
    assert (m.category_eu, m.class_eu) == (0, 0)
    assert m.operator_altitude_geo == pytest.approx(488.5)
    assert m.timestamp == int(T_UNIX) - 1546300800
    # the field order on the wire: MAVLink sorts by size, so check one raw offset too
    raw = mavlink.MAVLink_open_drone_id_system_message(**system(where, T_UNIX, 1).fields)
    payload = raw.pack(mavlink.MAVLink(None))[10:-2]
    assert struct.unpack_from("<ii", payload, 0) == (473977419, -85455938)


def test_system_update_on_the_wire() -> None:
    where = OperatorLocation(OperatorLocationType.TAKEOFF, -35.3632621, 149.1652374, 584.0)
    m = wire(system_update(where, T_UNIX, 1))
    assert (m.operator_latitude, m.operator_longitude) == (-353632621, 1491652374)
    assert m.operator_altitude_geo == pytest.approx(584.0)
    assert m.timestamp == int(T_UNIX - ODID_EPOCH_UNIX_S)
    assert (m.target_system, m.target_component) == (1, 1)


def test_operator_at_home_waits_for_home() -> None:
    cfg = CFG.model_copy(update={"operator_location": "home"})
    assert operator_location(cfg, None) is None
    names = [m.name for m in static_messages(cfg, None, T_UNIX, 1)]
    assert names == ["OPEN_DRONE_ID_BASIC_ID", "OPEN_DRONE_ID_SELF_ID", "OPEN_DRONE_ID_OPERATOR_ID"]
    home = HomePosition(0.0, -35.3632621, 149.1652374, 584.0)
    where = operator_location(cfg, home)
    assert where == OperatorLocation(OperatorLocationType.TAKEOFF, -35.3632621, 149.1652374, 584.0)
    last = static_messages(cfg, home, T_UNIX, 1)[-1]
    assert last.name == "OPEN_DRONE_ID_SYSTEM"
    assert wire(last).operator_location_type == mavlink.MAV_ODID_OPERATOR_LOCATION_TYPE_TAKEOFF
