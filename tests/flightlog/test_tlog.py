"""MAVLink .tlog: written by TlogWriter, read back by pymavlink's own reader."""

from __future__ import annotations

import asyncio
import json
import math
import multiprocessing as mp
import os
import struct
import threading
from typing import Any

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.autopilot.mavlink_messages import DirectPacker, MavlinkPacker
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    LandedState,
    PositionNed,
    StatusText,
    VehicleStatus,
)
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.flightlog.tlog import read_tlog, record_time_s, tlog_timestamp_us
from companion.flightlog.tlog_encoder import TelemetryEncoder
from companion.flightlog.tlog_writer import PACKED_RECORDS_PER_CHUNK, TlogWriter
from companion.guidance.setpoint import VelocitySetpoint
from companion_lab.demo import run_demo
from companion_sitl.autopilot import SIM_TLOG_EPOCH_S, SimAutopilot
from companion_sitl.clock import run_virtual
from companion_sitl.mavlink.px4 import px4_custom_mode
from companion_sitl.params import load_simulated_config

T0 = 1_700_000_000.0


def f32(x: float) -> float:
    return float(np.float32(x))


def random_messages(rng: np.random.Generator, n: int) -> list[tuple[Any, int, int]]:
    """(message, system, component): several types, float32-exact values, three sources."""
    out = []
    sources = [(1, 1), (255, 191), (42, 200)]
    for k in range(n):
        u = lambda lo, hi: f32(rng.uniform(lo, hi))  # noqa: E731
        i = int(rng.integers(0, 2**31 - 1))
        choice = k % 6
        if choice == 0:
            m = mav2.MAVLink_heartbeat_message(2, 12, int(rng.integers(0, 256)), i, 4, 3)
        elif choice == 1:
            m = mav2.MAVLink_attitude_message(i, u(-3, 3), u(-3, 3), u(-3, 3), u(-1, 1), u(-1, 1), u(-1, 1))
        elif choice == 2:
            m = mav2.MAVLink_global_position_int_message(
                i,
                int(rng.integers(-900_000_000, 900_000_000)),
                int(rng.integers(-1_800_000_000, 1_800_000_000)),
                850000,
                12000,
                150,
                -20,
                3,
                27000,
            )
        elif choice == 3:
            m = mav2.MAVLink_statustext_message(int(rng.integers(0, 8)), f"text {k} {i}".encode(), 0, 0)
        elif choice == 4:
            m = mav2.MAVLink_set_position_target_local_ned_message(
                i, 1, 1, 1, 2503, 0, 0, 0, u(-5, 5), u(-5, 5), u(-2, 2), 0, 0, 0, u(-3, 3), 0
            )
        else:
            m = mav2.MAVLink_command_long_message(1, 1, 176, 0, 1, 6, 0, 0, 0, 0, u(0, 100))
        out.append((m, *sources[int(rng.integers(0, 3))]))
    return out


def fields(m) -> dict:
    d = m.to_dict()
    d.pop("mavpackettype")
    return d


def test_packets_read_back_by_pymavlink_with_the_same_messages_in_order(tmp_path):
    rng = np.random.default_rng(7)
    msgs = random_messages(rng, 300)
    packer = MavlinkPacker()
    times = T0 + np.cumsum(rng.uniform(0.001, 0.05, len(msgs)))
    path = tmp_path / "a.tlog"
    with TlogWriter(path) as w:
        for (m, sysid, compid), t in zip(msgs, times, strict=True):
            assert w.write(packer.pack(m, sysid, compid), float(t))
    assert (w.written, w.dropped) == (len(msgs), 0)

    # pymavlink's own reader, as MAVExplorer opens a .tlog
    conn = mavutil.mavlink_connection(str(path))
    back = []
    while (r := conn.recv_match()) is not None:
        back.append(r)
    conn.close()
    assert len(back) == len(msgs)
    seqs: dict[tuple[int, int], list[int]] = {}
    for (m, sysid, compid), t, r in zip(msgs, times, back, strict=True):
        assert r.get_type() == m.get_type()
        assert (r.get_srcSystem(), r.get_srcComponent()) == (sysid, compid)
        assert fields(r) == fields(m)
        assert record_time_s(r) == pytest.approx(tlog_timestamp_us(float(t)) * 1e-6, abs=1e-6)
        seqs.setdefault((sysid, compid), []).append(r.get_seq())
    for s in seqs.values():  # one sequence counter per source, no gaps
        assert s == [k % 256 for k in range(len(s))]


def test_record_layout_is_big_endian_microseconds_then_the_packet(tmp_path):
    packet = MavlinkPacker().pack(mav2.MAVLink_attitude_message(5, 0.1, 0.2, 0.3, 0, 0, 0), 1, 1)
    path = tmp_path / "b.tlog"
    with TlogWriter(path) as w:
        w.write(packet, T0 + 0.123457)
    data = path.read_bytes()
    assert data[8:] == packet
    (usec,) = struct.unpack(">Q", data[:8])
    assert usec == round((T0 + 0.123457) * 1e6) & ~3  # pymavlink clears the link bits too
    assert [m.get_type() for m in read_tlog(path)] == ["ATTITUDE"]


def test_deferred_packets_are_built_on_the_writer_thread_in_order_and_failures_counted(tmp_path):
    packer = MavlinkPacker()
    threads = set()

    def build(k):
        def f():
            threads.add(threading.current_thread().name)
            if k == 3:
                raise ValueError("cannot encode")
            return packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1)

        return f

    path = tmp_path / "c.tlog"
    with TlogWriter(path, clock=lambda: T0) as w:
        for k in range(6):
            w.write(build(k))
        w.write(lambda: None)  # nothing to log
    assert threads == {f"tlog-{path.name}"}
    assert (w.written, w.encode_errors) == (5, 1)
    assert [m.custom_mode for m in read_tlog(path)] == [0, 1, 2, 4, 5]


def test_a_full_queue_drops_and_counts_instead_of_blocking(tmp_path):
    started, release = threading.Event(), threading.Event()
    packer = MavlinkPacker()
    hb = lambda k: packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1)  # noqa: E731

    def stuck():
        started.set()
        release.wait(10)
        return hb(0)

    path = tmp_path / "d.tlog"
    w = TlogWriter(path, max_queue=1, clock=lambda: T0)
    try:
        w.write(stuck)
        assert started.wait(10)  # the writer thread is busy with the first packet
        assert w.write(hb(1))  # fills the queue
        assert not w.write(hb(2))  # dropped, the caller does not wait
        assert w.dropped == 1
    finally:
        release.set()
        w.close()
    assert [m.custom_mode for m in read_tlog(path)] == [0, 1]


def test_drop_when_full_false_waits_and_loses_nothing(tmp_path):
    packer = MavlinkPacker()
    path = tmp_path / "e.tlog"
    with TlogWriter(path, max_queue=4, drop_when_full=False, clock=lambda: T0) as w:
        for k in range(500):
            assert w.write(packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1))
    assert (w.written, w.dropped) == (500, 0)
    assert [m.custom_mode for m in read_tlog(path)] == list(range(500))


def test_flush_puts_everything_on_disk_while_the_log_stays_open(tmp_path):
    packer = MavlinkPacker()
    path = tmp_path / "f.tlog"
    with TlogWriter(path, clock=lambda: T0) as w:
        packets = [packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1) for k in range(50)]
        for p in packets:
            w.write(p)
        assert w.flush()
        assert path.stat().st_size == sum(8 + len(p) for p in packets)
        assert len(list(read_tlog(path))) == 50


def test_packed_records_go_in_chunks_and_flush_and_close_hand_over_the_rest(tmp_path):
    packer = DirectPacker()
    hb = lambda k: packer.pack(mav2.MAVLink_heartbeat_message, (2, 12, 0, k, 4, 3), 1, 1)  # noqa: E731
    path = tmp_path / "p.tlog"
    size = len(hb(0)) + 8
    t = [T0]
    w = TlogWriter(path, clock=lambda: t[0])
    n = PACKED_RECORDS_PER_CHUNK + 10
    for k in range(n):
        t[0] = T0 + k * 0.01
        w.write_packed(hb(k))
    w.flush()  # the chunk and the ten kept by the producer
    assert path.stat().st_size == size * n
    w.write_packed(hb(n))
    w.write(hb(n + 1))  # write() after write_packed() on the same thread: still in order
    w.write_packed(hb(n + 2))
    w.close()
    msgs = list(read_tlog(path))
    assert [m.custom_mode for m in msgs] == list(range(n + 3))
    assert record_time_s(msgs[5]) == pytest.approx(T0 + 0.05, abs=1e-5)
    w.write_packed(hb(0))  # closed: refused and counted
    assert w.dropped == 1 and w.written == n + 3


def _crash_after(path, n_flushed, n_more):
    packer = MavlinkPacker()
    w = TlogWriter(path, clock=lambda: T0)
    for k in range(n_flushed + n_more):
        w.write(packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1))
        if k == n_flushed - 1:
            assert w.flush()
    os._exit(1)  # a crash: no close(), no atexit, writer thread killed wherever it is


def test_a_crash_keeps_every_flushed_record_and_only_whole_records(tmp_path):
    path = tmp_path / "crash.tlog"
    proc = mp.get_context("fork").Process(target=_crash_after, args=(path, 100, 400))
    proc.start()
    proc.join(30)
    assert proc.exitcode == 1
    modes = [m.custom_mode for m in read_tlog(path)]
    assert modes[:100] == list(range(100))  # everything flushed before the crash
    assert modes == list(range(len(modes))) and len(modes) <= 500  # then a clean prefix of the rest
    size = len(MavlinkPacker().pack(mav2.MAVLink_heartbeat_message(2, 12, 0, 0, 4, 3), 1, 1)) + 8
    assert path.stat().st_size == size * len(modes)  # no torn record at the end


class _FailingFile:
    """Stands in for the log file: the next write fails like a full disk."""

    def __init__(self, real):
        self.real = real

    def write(self, data):
        raise OSError(28, "No space left on device")

    def fileno(self):
        return self.real.fileno()

    def close(self):
        self.real.close()


def test_a_dead_writer_keeps_everything_before_and_refuses_the_rest(tmp_path, caplog):
    packer = MavlinkPacker()
    hb = lambda k: packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1)  # noqa: E731
    path = tmp_path / "g.tlog"
    w = TlogWriter(path, clock=lambda: T0)
    for k in range(20):
        w.write(hb(k))
    assert w.flush()
    w._fh = _FailingFile(w._fh)  # type: ignore[assignment]  # the disk fills up
    w.write(hb(20))
    assert not w.flush()
    assert w.error is not None and "No space left" in w.error
    assert not w.write(hb(21))  # refused and counted, never raised into the control path
    w.close()
    assert w.dropped == 2
    assert [m.custom_mode for m in read_tlog(path)] == list(range(20))
    assert "MAVLink log writer stopped" in caplog.text


def test_an_unwritable_path_fails_at_once_naming_it(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    with pytest.raises(OSError, match=r"cannot open MAVLink log .*file/x\.tlog"):
        TlogWriter(blocker / "x.tlog")


# MAVSDK's decoded messages (Mavsdk::subscribe_*_messages_json), as the PX4 backend receives them
MAVSDK_JSON = [
    (
        "COMMAND_LONG",
        '{"message_id":76,"message_name":"COMMAND_LONG","command":511,"confirmation":0,"param1":245.0,'
        '"param2":1000000.0,"param3":null,"param4":null,"param5":null,"param6":null,"param7":null,'
        '"target_component":1,"target_system":1}',
    ),
    (
        "BATTERY_STATUS",
        '{"message_id":147,"message_name":"BATTERY_STATUS","battery_function":1,"battery_remaining":100,'
        '"charge_state":0,"current_battery":50,"current_consumed":-1,"energy_consumed":-1,"fault_bitmask":0,'
        '"id":0,"mode":0,"temperature":32767,"time_remaining":0,"type":1,'
        '"voltages":[4200,4200,4200,65535,65535,65535,65535,65535,65535,65535],"voltages_ext":[0,0,0,0]}',
    ),
    (
        "PARAM_SET",
        '{"message_id":23,"message_name":"PARAM_SET","param_id":"MIS_TAKEOFF_ALT","param_type":9,'
        '"param_value":3.0,"target_component":1,"target_system":1}',
    ),
    (
        "SET_POSITION_TARGET_LOCAL_NED",
        '{"message_id":84,"message_name":"SET_POSITION_TARGET_LOCAL_NED","afx":0.0,"afy":0.0,"afz":0.0,'
        '"coordinate_frame":1,"target_component":1,"target_system":1,"time_boot_ms":2504,"type_mask":2503,'
        '"vx":0.5,"vy":0.0,"vz":0.0,"x":0.0,"y":0.0,"yaw":0.10000000149011612,"yaw_rate":0.0,"z":0.0}',
    ),
    ("STATUSTEXT", '{"message_id":253,"message_name":"STATUSTEXT","chunk_seq":0,"id":0,"severity":6,"text":"armed"}'),
]


def test_mavsdk_json_messages_are_re_encoded_with_their_field_values(tmp_path):
    packer = MavlinkPacker()
    path = tmp_path / "h.tlog"
    with TlogWriter(path, clock=lambda: T0) as w:
        for name, js in MAVSDK_JSON:
            w.write(packer.pack_json(name, js, 1, 195))
    back = list(read_tlog(path))
    assert [m.get_type() for m in back] == [n for n, _ in MAVSDK_JSON]
    for m, (_, js) in zip(back, MAVSDK_JSON, strict=True):
        want = json.loads(js)
        assert (m.get_srcSystem(), m.get_srcComponent()) == (1, 195)
        for k, v in fields(m).items():
            if want.get(k) is None:
                assert isinstance(v, float) and math.isnan(v), k  # MAVSDK writes NaN as null
            else:
                assert v == want[k], k
    with pytest.raises(KeyError, match="NOT_A_MESSAGE"):
        packer.pack_json("NOT_A_MESSAGE", '{"message_name":"NOT_A_MESSAGE"}', 1, 1)


def test_telemetry_encoder_maps_samples_and_companion_messages(tmp_path):
    path = tmp_path / "i.tlog"
    clock = [100.0]
    with TlogWriter(path, clock=lambda: T0 + clock[0]) as w:
        enc = TelemetryEncoder(w, boot_s=90.0, clock=lambda: clock[0], custom_mode=px4_custom_mode)
        enc.sample(Attitude(0.0, 0.1, -0.2, 1.5, 0.01, 0.02, 0.03))
        enc.sample(PositionNed(0.0, 10.0, -5.0, -20.0, 1.0, 2.0, -0.5))
        enc.sample(GlobalPosition(0.0, -19.869, -43.9638, 870.0, 20.0))
        enc.sample(VehicleStatus(0.0, True, FlightMode.OFFBOARD, LandedState.IN_AIR, True, 87.4, False))
        enc.sample(StatusText(0.0, 4, "low battery"))
        clock[0] = 100.5
        enc.setpoint(VelocitySetpoint(1.0, -2.0, 0.5, 0.25))
        enc.command(176, (1.0, 6.0))
        enc.command_ack(176, 0)
    m: dict[str, Any] = {}
    for msg in read_tlog(path):
        m.setdefault(msg.get_type(), msg)
    assert m["ATTITUDE"].time_boot_ms == 10000 and m["ATTITUDE"].yaw == pytest.approx(1.5)
    assert (m["LOCAL_POSITION_NED"].x, m["LOCAL_POSITION_NED"].z) == (10.0, -20.0)
    g = m["GLOBAL_POSITION_INT"]
    assert (g.lat, g.lon, g.alt, g.relative_alt) == (-198690000, -439638000, 870000, 20000)
    assert (g.vx, g.vy, g.vz, g.hdg) == (100, 200, -50, round(math.degrees(1.5) * 100))
    hb = m["HEARTBEAT"]
    assert hb.base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED and hb.autopilot == mav2.MAV_AUTOPILOT_PX4
    assert hb.custom_mode == px4_custom_mode(FlightMode.OFFBOARD)
    assert m["EXTENDED_SYS_STATE"].landed_state == mav2.MAV_LANDED_STATE_IN_AIR
    assert m["SYS_STATUS"].battery_remaining == 87 and m["BATTERY_STATUS"].battery_remaining == 87
    assert m["STATUSTEXT"].text == "low battery" and m["STATUSTEXT"].severity == 4
    sp = m["SET_POSITION_TARGET_LOCAL_NED"]
    assert (sp.vx, sp.vy, sp.vz, sp.yaw, sp.type_mask) == (1.0, -2.0, 0.5, 0.25, 2503)
    assert sp.get_srcComponent() == mav2.MAV_COMP_ID_ONBOARD_COMPUTER and sp.time_boot_ms == 10500
    assert (m["COMMAND_LONG"].command, m["COMMAND_LONG"].param2) == (176, 6.0)
    assert m["COMMAND_ACK"].target_component == mav2.MAV_COMP_ID_ONBOARD_COMPUTER
    assert record_time_s(m["SET_POSITION_TARGET_LOCAL_NED"]) == pytest.approx(T0 + 100.5, abs=1e-5)


# ------------------------------------------------------------------ simulated flights (virtual time)
def sim_config():
    return load_simulated_config(shipped_params_path("sitl_short.toml"), overrides={"sim": {"seed": 4}})


def summarize(path):
    counts: dict[tuple[int, int, str], int] = {}
    for m in read_tlog(path):
        k = (m.get_srcSystem(), m.get_srcComponent(), m.get_type())
        counts[k] = counts.get(k, 0) + 1
    return counts


@pytest.mark.flight
def test_demo_flight_writes_a_tlog_with_heartbeats_positions_and_our_setpoints(tmp_path):
    r = run_demo(sim_config(), run_dir=tmp_path / "a", fusion=False)
    assert r.delivered and r.returned, r.failure
    path = tmp_path / "a" / "flight.tlog"
    c = summarize(path)
    vehicle, companion = (1, 1), (1, mav2.MAV_COMP_ID_ONBOARD_COMPUTER)
    assert c[(*vehicle, "HEARTBEAT")] > 100 and c[(*vehicle, "LOCAL_POSITION_NED")] > 500
    assert c[(*vehicle, "GLOBAL_POSITION_INT")] > 500 and c[(*vehicle, "ATTITUDE")] > 1000
    for t in ("GPS_RAW_INT", "SYS_STATUS", "BATTERY_STATUS", "EXTENDED_SYS_STATE", "HOME_POSITION", "COMMAND_ACK"):
        assert c[(*vehicle, t)] > 0, t
    assert c[(*companion, "SET_POSITION_TARGET_LOCAL_NED")] == r.setpoints_sent
    assert c[(*companion, "COMMAND_LONG")] == c[(*vehicle, "COMMAND_ACK")] >= 6  # arm, takeoff, offboard, land...
    hbs = list(read_tlog(path, ["HEARTBEAT"]))
    assert any(h.custom_mode == px4_custom_mode(FlightMode.OFFBOARD) and h.base_mode & 128 for h in hbs)
    assert not hbs[-1].base_mode & mav2.MAV_MODE_FLAG_SAFETY_ARMED  # landed and disarmed at home
    ts = [record_time_s(m) for m in read_tlog(path)]
    assert ts == sorted(ts)  # the loop's clock, mapped onto the fixed epoch
    assert SIM_TLOG_EPOCH_S <= ts[0] < SIM_TLOG_EPOCH_S + 1.0
    assert ts[-1] - ts[0] == pytest.approx(r.sim_time_s, abs=0.5)

    # the same seed gives the same file, byte for byte
    run_demo(sim_config(), run_dir=tmp_path / "b", fusion=False)
    assert (tmp_path / "b" / "flight.tlog").read_bytes() == path.read_bytes()


class _Crash(RuntimeError):
    pass


@pytest.mark.flight
def test_an_exception_mid_flight_leaves_a_readable_tlog_with_everything_before(tmp_path):
    config = sim_config()
    crash_at = 15.0

    async def flight(path, crash):
        ap = SimAutopilot(config.sim, tlog_path=path)

        def on_tick(shell, out):
            if crash and asyncio.get_running_loop().time() >= crash_at:
                raise _Crash("control task crashed")

        shell = DeliveryShell(config, ap, on_tick=on_tick)
        try:
            await shell.run(timeout_s=300.0)
        finally:
            await ap.close()
        return ap

    ref = tmp_path / "ref.tlog"
    run_virtual(flight(ref, crash=False))
    crashed = tmp_path / "crash.tlog"
    with pytest.raises(_Crash):
        run_virtual(flight(crashed, crash=True))

    before = SIM_TLOG_EPOCH_S + crash_at - 0.2
    ref_msgs = [m for m in read_tlog(ref) if record_time_s(m) < before]
    got = list(read_tlog(crashed))
    assert record_time_s(got[-1]) >= before  # logged up to the crash
    got_before = [m for m in got if record_time_s(m) < before]
    assert len(got_before) == len(ref_msgs) > 1000  # nothing before the crash is missing...
    for a, b in zip(got_before, ref_msgs, strict=True):  # ...or different from the uncrashed flight
        assert a.get_msgbuf() == b.get_msgbuf()


def test_a_message_the_dialect_lacks_is_left_out_counted_and_named_once(tmp_path, caplog):
    # PX4 sends messages newer than pymavlink's ardupilotmega dialect (e.g. CURRENT_MODE, 436)
    packer = MavlinkPacker()
    attitude = {"time_boot_ms": 5, "roll": 0.1, "pitch": 0.2, "yaw": 0.3}
    path = tmp_path / "c.tlog"
    caplog.set_level("INFO", logger="companion.flightlog.tlog_writer")
    with TlogWriter(path, clock=lambda: T0) as w:
        for _ in range(3):
            assert w.write(lambda: packer.pack_fields(99999, {}, 1, 1))
            assert w.write(lambda: packer.pack_fields("ATTITUDE", attitude, 1, 1))
    assert w.unknown_messages == {"99999": 3} and w.encode_errors == 0
    assert not [r for r in caplog.records if r.exc_info]  # no traceback
    said = [r.getMessage() for r in caplog.records if "does not define" in r.getMessage()]
    assert len(said) == 1 and "99999 x 3" in said[0]
    conn = mavutil.mavlink_connection(str(path))
    got = []
    while (r := conn.recv_match()) is not None:
        got.append(r.get_type())
    conn.close()
    assert got == ["ATTITUDE"] * 3
