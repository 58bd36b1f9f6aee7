"""DirectPacker packs field values into the very bytes pymavlink's message objects give
(MavlinkPacker), and x25crc is pymavlink's checksum."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.autopilot.mavlink_messages import DirectPacker, MavlinkPacker, x25crc


def _f32(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.float32(rng.uniform(lo, hi)))


def _cases(rng: np.random.Generator) -> list[tuple[object, tuple[object, ...]]]:
    """Every message the simulator's tlog encoder writes, with random values (zeros included, so
    trailing-zero stripping is exercised), extension fields left to their defaults."""
    i32 = lambda: int(rng.integers(-(2**31), 2**31 - 1))  # noqa: E731
    u32 = lambda: int(rng.integers(0, 2**32 - 1))  # noqa: E731
    f = lambda: _f32(rng, -100, 100) if rng.random() < 0.8 else 0.0  # noqa: E731
    return [
        (mav2.MAVLink_attitude_message, (u32(), f(), f(), f(), f(), f(), f())),
        (mav2.MAVLink_attitude_message, (0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)),  # all zeros: one byte stays
        (
            mav2.MAVLink_highres_imu_message,
            (int(rng.integers(0, 2**63)), f(), f(), f(), f(), f(), f(), *[0.0] * 7, 63, 0),
        ),
        (mav2.MAVLink_local_position_ned_message, (u32(), f(), f(), f(), f(), f(), f())),
        (
            mav2.MAVLink_global_position_int_message,
            (u32(), i32(), i32(), i32(), i32(), int(rng.integers(-3000, 3000)), 0, -20, int(rng.integers(0, 36000))),
        ),
        (
            mav2.MAVLink_gps_raw_int_message,
            (int(rng.integers(0, 2**40)), 3, i32(), i32(), i32(), 120, 65535, 65535, 65535, 12),
        ),
        (
            mav2.MAVLink_home_position_message,
            (i32(), i32(), i32(), f(), f(), f(), [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, 17),
        ),
        (mav2.MAVLink_statustext_message, (int(rng.integers(0, 8)), b"low battery", 0, 0)),
        (mav2.MAVLink_statustext_message, (6, b"x" * 50, 0, 0)),
        (mav2.MAVLink_heartbeat_message, (2, 12, 129, u32(), 4, 3)),
        (mav2.MAVLink_sys_status_message, (2**28, 2**28, 0, 0, 65535, -1, 87, 0, 0, 0, 0, 0, 0)),
        (mav2.MAVLink_battery_status_message, (0, 0, 1, 32767, [65535] * 10, -1, -1, -1, 87)),
        (mav2.MAVLink_extended_sys_state_message, (0, 2)),
        (
            mav2.MAVLink_set_position_target_local_ned_message,
            (u32(), 1, 1, 1, 2503, 0.0, 0.0, 0.0, f(), f(), f(), 0.0, 0.0, 0.0, f(), 0.0),
        ),
        (mav2.MAVLink_command_long_message, (1, 1, 176, 0, f(), f(), 0.0, 0.0, 0.0, 0.0, f())),
        (mav2.MAVLink_command_ack_message, (176, 0, 0, 0, 1, 191)),
    ]


def test_same_bytes_as_pymavlink_for_every_message_and_source_over_sequence_wraps() -> None:
    rng = np.random.default_rng(7)
    direct, reference = DirectPacker(), MavlinkPacker()
    sources = [(1, 1), (1, 191), (42, 200)]
    n = 0
    for _ in range(40):  # 40 x 16 packets: each source's sequence wraps past 255
        for cls, args in _cases(rng):
            src = sources[int(rng.integers(0, 3))]
            assert direct.pack(cls, args, *src) == reference.pack(cls(*args), *src), cls.msgname
            n += 1
    assert n == 640


def test_wrong_number_of_values_is_refused_naming_the_message() -> None:
    with pytest.raises(TypeError, match=r"ATTITUDE: 3 values for 7\.\.7 fields"):
        DirectPacker().pack(mav2.MAVLink_attitude_message, (1, 0.1, 0.2), 1, 1)
    with pytest.raises(TypeError, match="GPS_RAW_INT"):  # fewer than its base fields
        DirectPacker().pack(mav2.MAVLink_gps_raw_int_message, (1, 3, 0), 1, 1)


def test_x25crc_is_pymavlinks_checksum() -> None:
    rng = np.random.default_rng(3)
    for n in [1, 2, 7, 40, 280]:
        data = rng.integers(0, 256, n, dtype=np.uint8).tobytes()
        assert x25crc(data) == mav2.x25crc(data).crc
        assert x25crc(data[n // 2 :], x25crc(data[: n // 2])) == mav2.x25crc(data).crc  # continued
    assert x25crc(b"123456789") == 0x6F91  # CRC-16/MCRF4XX check value


def test_packing_from_fields_gives_the_object_paths_bytes_and_shares_its_sequence() -> None:
    fields = {"time_boot_ms": 1234, "roll": 0.25, "pitch": None, "yaw": -1.0, "rollspeed": 0.0}
    a, b = MavlinkPacker(), MavlinkPacker()
    msg = MavlinkPacker.message_from_fields("ATTITUDE", fields)
    assert a.pack_fields("ATTITUDE", fields, 1, 1) == b.pack(msg, 1, 1)
    # one counter per source whichever path packs: seq 1 then 2 on both
    assert a.pack(msg, 1, 1) == b.pack_fields("ATTITUDE", fields, 1, 1)
    assert a.pack_json("ATTITUDE", '{"time_boot_ms": 1234, "roll": 0.25, "pitch": null, "yaw": -1.0}', 1, 1)[4] == 2
