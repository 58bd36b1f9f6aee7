"""Seed MAVLink bytes for the fuzz modules: valid packets an autopilot sends (to the backends)
and a ground station or companion sends (to the sim vehicle), MAVLink 1 and 2, plus
known-nasty packets (bad CRC, a length beyond the payload, an unknown message id, a signed
packet of an unknown key, a v2 header cut after the magic)."""

from __future__ import annotations

import math

from pymavlink.dialects.v20 import ardupilotmega as mavlink

import companion.autopilot.ardupilot.dialect  # noqa: F401  (MAVLINK20 before pymavlink's mavutil)


def _packer(system: int, component: int) -> mavlink.MAVLink:
    return mavlink.MAVLink(None, srcSystem=system, srcComponent=component)


def _pack(mav: mavlink.MAVLink, msgs: list[object]) -> bytes:
    return b"".join(m.pack(mav) for m in msgs)  # type: ignore[attr-defined]


def from_autopilot() -> list[bytes]:
    """Streams of an ArduCopter (system 1, component 1) as the backends receive them."""
    mav = _packer(1, 1)
    hb = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 209, 5, mavlink.MAV_STATE_ACTIVE, 3
    )
    stream = [
        hb,
        mavlink.MAVLink_attitude_message(1000, 0.01, -0.02, 1.2, 0.0, 0.0, 0.1),
        mavlink.MAVLink_local_position_ned_message(1000, 1.0, 2.0, -10.0, 0.1, 0.2, -0.3),
        mavlink.MAVLink_global_position_int_message(1000, -198683612, -439631248, 895000, 10000, 1, 2, 3, 9000),
        mavlink.MAVLink_gps_raw_int_message(1000, 3, -198683612, -439631248, 895000, 80, 65535, 0, 0, 14),
        mavlink.MAVLink_sys_status_message(0x10000000, 0x10000000, 0x10000000, 10, 12000, -1, 76, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_extended_sys_state_message(0, 2),
        mavlink.MAVLink_home_position_message(-198683612, -439631248, 895000, 0, 0, 0, [1, 0, 0, 0], 0, 0, 0),
        mavlink.MAVLink_statustext_message(6, b"Takeoff detected"),
        mavlink.MAVLink_command_ack_message(400, 0),
        mavlink.MAVLink_param_value_message(b"GRIP_ENABLE", 1.0, 9, 900, 12),
        mavlink.MAVLink_system_time_message(1_700_000_000_000_000, 1000),
        mavlink.MAVLink_highres_imu_message(1, 0.1, 0.2, -9.8, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_servo_output_raw_message(1, 0, *[1500] * 8),
        mavlink.MAVLink_rc_channels_message(1, 8, *[1500] * 18, 255),
        mavlink.MAVLink_battery_status_message(0, 0, 0, 2500, [4000] * 10, -1, -1, -1, 80),
    ]
    odd = [
        mavlink.MAVLink_attitude_message(1000, math.nan, math.inf, -math.inf, 0.0, 0.0, 0.0),
        mavlink.MAVLink_statustext_message(6, bytes(range(128, 178))),
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0, 3),
    ]
    other = _packer(2, 1)
    return [
        _pack(mav, stream),
        _pack(mav, [hb, *odd]),
        _pack(other, [hb, stream[1]]) + _pack(mav, stream[:3]),
        *nasty(_pack(mav, [hb, stream[1]])),
    ]


def from_ground() -> list[bytes]:
    """What a companion or ground station sends a vehicle (system 255, component 191)."""
    mav = _packer(255, 191)
    msgs = [
        mavlink.MAVLink_heartbeat_message(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 4, 3),
        mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, 10),
        mavlink.MAVLink_command_long_message(1, 1, mavlink.MAV_CMD_DO_GRIPPER, 0, 1, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_command_long_message(1, 1, 65000, 0, math.nan, math.inf, 0, 0, 0, 0, 0),
        mavlink.MAVLink_set_mode_message(1, 1, 4),
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0b0000_1111_1100_0111, 0, 0, 0, 1.0, 0.5, -0.2, 0, 0, 0, 0, 0
        ),
        mavlink.MAVLink_set_position_target_local_ned_message(
            0, 1, 1, mavlink.MAV_FRAME_LOCAL_NED, 0, math.nan, math.inf, 1e38, 1e38, -1e38, 0, 0, 0, 0, 0, 0
        ),
        mavlink.MAVLink_param_request_list_message(1, 1),
        mavlink.MAVLink_param_request_read_message(1, 1, b"GRIP_ENABLE", -1),
        mavlink.MAVLink_param_set_message(1, 1, b"GRIP_ENABLE", 1.0, 9),
        mavlink.MAVLink_param_set_message(1, 1, b"\xff\xfe", math.nan, 9),
        mavlink.MAVLink_landing_target_message(0, 0, 0, 0.01, -0.02, 5.0, 0, 0),
        mavlink.MAVLink_rc_channels_override_message(1, 1, *[1500] * 8),
        mavlink.MAVLink_request_data_stream_message(1, 1, 0, 10, 1),
        mavlink.MAVLink_command_int_message(1, 1, 0, 192, 0, 0, -1, 0, 0, 0, 0, 0, 0),
    ]
    return [_pack(mav, msgs[:4]), _pack(mav, msgs[4:10]), _pack(mav, msgs[10:]), *nasty(_pack(mav, msgs[:2]))]


def nasty(good: bytes) -> list[bytes]:
    """Known-nasty variants of ``good`` (a v2 packet first)."""
    bad_crc = bytearray(good)
    bad_crc[good[1] + 10] ^= 0xFF
    long_len = bytearray(good)
    long_len[1] = 0xFF
    unknown = bytearray(good)
    unknown[7:10] = b"\xff\xff\xff"
    signed = bytearray(good[: good[1] + 12])
    signed[2] |= 0x01
    signed += bytes(13)
    return [bytes(bad_crc), bytes(long_len), bytes(unknown), bytes(signed), b"\xfd", b"\xfe\x09", b"\x00" * 64]
