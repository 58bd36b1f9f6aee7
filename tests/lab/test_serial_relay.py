"""The serial link emulator (companion_lab.serial_relay): pacing at the baud rate each way, the
counters, the seeded drops and corruptions. No firmware: the tests open the two pty slaves
themselves."""

from __future__ import annotations

import os
import random
import select
import threading
import time

import pytest

from companion_lab.serial_relay import FrameClock, SerialRelay, SerialRelayError, _Direction, frame_summary


def _open(path: str) -> int:
    return os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)


def _write_all(fd: int, data: bytes) -> None:
    while data:
        select.select([], [fd], [], 1.0)
        try:
            data = data[os.write(fd, data) :]
        except BlockingIOError:
            continue


def _read(fd: int, n: int, timeout_s: float) -> tuple[bytes, float]:
    """Up to ``n`` bytes (fewer if nothing more came for ``timeout_s``) and the time of the last."""
    out = bytearray()
    last = time.monotonic()
    while len(out) < n:
        ready, _, _ = select.select([fd], [], [], timeout_s)
        if not ready:
            break
        try:
            out += os.read(fd, n - len(out))
        except BlockingIOError:
            continue
        last = time.monotonic()
    return bytes(out), last


def _payload(n: int, seed: int) -> bytes:
    return random.Random(seed).randbytes(n)


def test_each_direction_is_paced_at_the_baud_rate_on_its_own():
    """9600 baud 8N1 is 960 bytes/s: 480 bytes take 0.5 s, each way at the same time (full
    duplex), and every byte arrives unchanged, in order."""
    n = 480
    up, down = _payload(n, 1), _payload(n, 2)
    with SerialRelay(baud=9600) as relay:
        ap, co = _open(relay.autopilot_device), _open(relay.companion_device)
        try:
            got: dict[str, tuple[bytes, float]] = {}
            t0 = time.monotonic()
            _write_all(ap, down)
            _write_all(co, up)
            reader = threading.Thread(target=lambda: got.__setitem__("up", _read(ap, n, 2.0)))
            reader.start()
            got["down"] = _read(co, n, 2.0)
            reader.join()
        finally:
            os.close(ap)
            os.close(co)
        assert got["down"][0] == down and got["up"][0] == up
        for key in ("down", "up"):
            elapsed = got[key][1] - t0
            # 0.5 s of line time, not the pty's instant (the upper bound leaves room for a loaded machine)
            assert 0.45 < elapsed < 1.5, (key, elapsed)
        # the relay counts a byte once its write returns, which can be just after the reader has it
        deadline = time.monotonic() + 1.0
        while relay.to_companion.delivered < n or relay.to_autopilot.delivered < n:
            assert time.monotonic() < deadline, (relay.to_companion, relay.to_autopilot)
            time.sleep(0.01)
        assert relay.to_companion.delivered == n and relay.to_autopilot.delivered == n
        assert relay.to_companion.line == n and relay.to_autopilot.read == n
        assert relay.to_companion.dropped == relay.to_companion.corrupted == 0
        # no whole second carried more than the line's 960 bytes
        assert 0 < relay.to_companion.peak_bytes_per_s <= 960


def test_a_faster_line_is_faster_and_the_backlog_stays_within_the_fifo():
    """At 96000 baud (9600 bytes/s) 4800 bytes take 0.5 s; the relay never holds more than its queue
    limit (the sender's bytes wait in its own pty buffer, as behind a UART's FIFO)."""
    n = 4800
    data = _payload(n, 3)
    with SerialRelay(baud=96000, queue_limit=256) as relay:
        ap, co = _open(relay.autopilot_device), _open(relay.companion_device)
        try:
            t0 = time.monotonic()
            writer = threading.Thread(target=_write_all, args=(ap, data))
            writer.start()
            got, last = _read(co, n, 2.0)
            writer.join()
        finally:
            os.close(ap)
            os.close(co)
    assert got == data
    assert 0.45 < last - t0 < 1.5, last - t0  # 4800 bytes at 9600 bytes/s
    assert relay.to_companion.max_backlog <= 256
    assert relay.to_autopilot.line == 0


def test_seeded_drops_and_corruptions_at_their_fractions():
    """5 % dropped and 5 % corrupted of 20000 bytes: the receiver gets 20000 minus the drops,
    the counters match what arrived, the fractions are within binomial bounds (4 sigma), and the
    same seed gives the same bytes again while another seed does not."""
    n = 20000
    data = _payload(n, 4)

    def run(seed: int) -> tuple[bytes, SerialRelay]:
        with SerialRelay(baud=4_000_000, drop=0.05, corrupt=0.05, seed=seed) as relay:
            ap, co = _open(relay.autopilot_device), _open(relay.companion_device)
            try:
                writer = threading.Thread(target=_write_all, args=(ap, data))
                writer.start()
                got, _ = _read(co, n, 0.2)
                writer.join()
            finally:
                os.close(ap)
                os.close(co)
        return got, relay

    got, relay = run(11)
    st = relay.to_companion
    assert st.line == n and st.overrun == 0
    assert len(got) == n - st.dropped == st.delivered
    sigma = (n * 0.05 * 0.95) ** 0.5
    for count in (st.dropped, st.corrupted):
        assert abs(count - 0.05 * n) < 4 * sigma, (st.dropped, st.corrupted)
    assert got != data
    again, _ = run(11)
    assert again == got
    other, _ = run(12)
    assert other != got


def test_faults_do_not_depend_on_how_the_bytes_were_chunked():
    """One draw per faulty byte from the direction's own generator: the same bytes in one piece or
    in odd pieces give the same output; a corrupted byte always differs from the original and the
    surviving bytes keep their order."""
    data = _payload(5000, 5)
    relay = SerialRelay(drop=0.02, corrupt=0.03, seed=9)

    def through(pieces: list[int]) -> tuple[bytes, _Direction]:
        d = _Direction(relay, "t", -1, -1, seed=9)
        out, i = bytearray(), 0
        for k in pieces:
            out += d.apply_faults(data[i : i + k])
            i += k
        out += d.apply_faults(data[i:])
        return bytes(out), d

    whole, d1 = through([])
    sliced, d2 = through([1, 7, 300, 2, 999, 13])
    assert whole == sliced
    assert (d1.stats.dropped, d1.stats.corrupted) == (d2.stats.dropped, d2.stats.corrupted)
    assert d1.stats.dropped > 0 and d1.stats.corrupted > 0
    assert len(whole) == len(data) - d1.stats.dropped
    # without drops, every corrupted byte differs and every other one is the same
    clean = SerialRelay(corrupt=0.03, seed=9)
    d = _Direction(clean, "t", -1, -1, seed=9)
    out = d.apply_faults(data)
    changed = sum(a != b for a, b in zip(out, data, strict=True))
    assert changed == d.stats.corrupted > 0


def test_no_faults_leave_the_bytes_alone():
    d = _Direction(SerialRelay(), "t", -1, -1, seed=0)
    data = _payload(1000, 6)
    assert d.apply_faults(data) == data and d.stats.dropped == d.stats.corrupted == 0


@pytest.mark.parametrize(
    "kwargs",
    [{"baud": 0}, {"drop": -0.1}, {"corrupt": 1.5}, {"drop": 0.6, "corrupt": 0.6}, {"queue_limit": 0}],
)
def test_bad_settings_are_refused(kwargs):
    with pytest.raises(SerialRelayError):
        SerialRelay(**kwargs)


def test_the_command_line_prints_both_devices_and_the_counters(capsys):
    from companion_lab import serial_relay

    assert serial_relay.main(["--baud", "115200", "--duration", "0.3", "--report-s", "0.1"]) == 0
    out = capsys.readouterr().out
    assert "--serial2 uart:/dev/pts/" in out and "serial:///dev/pts/" in out and "11520 bytes/s" in out
    assert out.count("to_companion: 0 bytes") >= 2 and "to_autopilot: 0 bytes" in out
    assert serial_relay.main(["--baud", "0"]) == 2


def _setpoint_frames(n: int) -> tuple[bytes, int]:
    """``n`` MAVLink 2 SET_POSITION_TARGET_LOCAL_NED frames (with heartbeats between them, which
    are not watched) and one setpoint frame's length."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    out, size = bytearray(), 0
    for i in range(n):
        sp = mav.set_position_target_local_ned_encode(i, 1, 1, 1, 0xFC7, 0, 0, 0, 1.0 + i, -2.0, 0.5, 0, 0, 0, 0, 0)
        frame = sp.pack(mav)
        size = len(frame)
        out += frame + mavlink.MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3).pack(mav)
    return bytes(out), size


def test_watched_frames_are_timed_from_the_write_to_the_delivery():
    """At 9600 baud (960 bytes/s) a burst of 10 setpoints (and 10 heartbeats) written at once:
    each setpoint is delivered after every byte before it crossed the line, so the k-th waits k
    frames' line time; the heartbeats are not timed; the intervals are one setpoint + one
    heartbeat of line time."""
    data, size = _setpoint_frames(10)
    with SerialRelay(baud=9600, watch=(84,)) as relay:
        ap, co = _open(relay.autopilot_device), _open(relay.companion_device)
        try:
            _write_all(co, data)
            got, _ = _read(ap, len(data), 2.0)
        finally:
            os.close(ap)
            os.close(co)
        frames = relay.frame_times("to_autopilot")
        assert relay.frame_times("to_companion") == []
    assert got == data
    assert [f.msgid for f in frames] == [84] * 10
    pair_s = (len(data) / 10) / 960  # one setpoint and one heartbeat on the line
    for k, f in enumerate(frames):
        # written at once: frame k ends after k pairs and its own bytes (the reads may be split)
        expected = k * pair_s + size / 960
        assert expected - 0.05 < f.latency_s < expected + 0.05, (k, f.latency_s, expected)
    s = frame_summary(frames, 84)
    # line times are the wire's: a setpoint + heartbeat apart exactly, whatever the relay's lag
    assert s["n"] == 10 and abs(s["interval_mean_ms"] - 1e3 * pair_s) < 0.01, s
    assert s["interval_std_ms"] < 0.01 and s["pauses"] == 0 and s["relay_lag_max_ms"] >= 0.0
    assert s["latency_p50_ms"] <= s["latency_p99_ms"] <= s["latency_max_ms"]
    assert frame_summary(frames, 0) == {}  # heartbeats were not watched


def test_the_frame_clock_finds_frames_split_across_reads_and_skips_noise():
    data, _size = _setpoint_frames(3)
    clock = FrameClock(frozenset({84}))
    noise = b"\x00\x11garbage"
    stream = noise + data
    for i in range(0, len(stream), 7):  # 7-byte reads: headers and frames split everywhere
        clock.on_read(stream[i : i + 7], float(i))
    clock.on_delivered(len(stream), 1000.0, 0, 900.0, 0.001)
    assert [f.msgid for f in clock.frames] == [84, 84, 84]
    assert all(f.delivered_s == 1000.0 for f in clock.frames)
    pair = len(data) // 3
    ends = [len(noise) + k * pair + _size for k in range(3)]  # each setpoint's last byte
    assert [round(f.line_s, 6) for f in clock.frames] == [round(900.0 + e * 0.001, 6) for e in ends]
    with pytest.raises(ValueError, match="direction"):
        SerialRelay().frame_times("sideways")
