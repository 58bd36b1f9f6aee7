"""DWM1001 lec parser and the UART shell driver against a fake device on a pseudo-terminal."""

from __future__ import annotations

import math
import os
import select
import threading
import time
import tty
from typing import ClassVar

import numpy as np
import pytest

from companion.uwb.anchors import load_anchor_layout
from companion.uwb.measurements import UwbFix
from companion.uwb.multilateration import Multilaterator
from companion_plugins.dwm1001 import (
    Dwm1001Driver,
    Dwm1001Error,
    LecParser,
    LineKind,
    classify_lec_line,
    explain_lec_line,
    parse_lec_line,
)

GOOD = (
    "DIST,4,AN0,1151,0.00,0.00,0.00,3.26,AN1,0CA8,0.00,3.35,0.00,2.45,"
    "AN2,111C,3.35,3.35,0.00,1.89,AN3,1150,3.35,0.00,0.00,2.64,POS,1.87,1.49,0.46,53"
)


def test_parse_a_full_line() -> None:
    r = parse_lec_line(GOOD + "\r\n", time_s=12.5)
    assert r is not None
    assert r.time_s == 12.5
    assert [a.anchor_id for a in r.anchors] == ["1151", "0CA8", "111C", "1150"]
    assert r.anchors[1].y_m == 3.35 and r.anchors[2].x_m == 3.35 and r.anchors[0].distance_m == 3.26
    assert r.position_m == (1.87, 1.49, 0.46) and r.quality_factor == 53
    m = r.to_twr_measurement()
    assert m.anchor_ids == ("1151", "0CA8", "111C", "1150") and m.ranges_m == (3.26, 2.45, 1.89, 2.64)


def test_parse_without_position_and_position_only() -> None:
    r = parse_lec_line("DIST,2,AN0,1A01,1.0,2.0,0.5,4.25,AN1,1a02,-1.0,2.0,2.5,3.5")
    assert r is not None and r.position_m is None and r.quality_factor is None
    assert [a.anchor_id for a in r.anchors] == ["1A01", "1A02"]
    r = parse_lec_line("POS,0.10,-0.20,2.00,90")
    assert r is not None and r.anchors == () and r.position_m == (0.1, -0.2, 2.0)
    r = parse_lec_line("DIST,0,POS,0.10,-0.20,2.00,90")
    assert r is not None and r.anchors == () and r.quality_factor == 90
    assert math.isnan(parse_lec_line(GOOD).time_s)  # type: ignore[union-attr]


@pytest.mark.parametrize("cut", [6, 7, 14, 30, 40, 60, 100, len(GOOD) - 12, len(GOOD) - 3])
def test_truncated_lines_are_partial(cut: int) -> None:
    kind, r = classify_lec_line(GOOD[:cut].rstrip(","))
    assert r is None
    assert kind is LineKind.PARTIAL


@pytest.mark.parametrize(
    "line",
    [
        "hello world",
        "DIST,x,AN0",
        "DIST,1,AN1,1151,0,0,0,3.2",  # wrong anchor index
        "DIST,1,AN0,ZZZZ,0,0,0,3.2",  # not a hex id
        "DIST,1,AN0,1151,0,0,0,-3.2",  # negative range
        "DIST,1,AN0,1151,0,0,0,nan",  # non-finite
        "DIST,1,AN0,1151,0,inf,0,3.2",
        "DIST,1,AN0,1151,0,0,0,3.2,EXTRA",
        "DIST,1,AN0,1151,0,0,0,3.2,POS,1,2,3,50,9",  # trailing token
        "DIST,1,AN0,1151,0,0,0,3.2,POS,1,2,3,150",  # quality > 100
        "DIST,99,AN0",
        ",,,,",
        "POS,1,2,3,q",
    ],
)
def test_malformed_lines(line: str) -> None:
    kind, r = classify_lec_line(line)
    assert r is None and kind is LineKind.MALFORMED


@pytest.mark.parametrize(
    ("line", "reason"),
    [
        ("hello world", "starts with 'hello world', not DIST or POS"),
        ("DIST,x,AN0", "anchor count 'x' (field 1): 0-16 expected"),
        ("DIST,1,AN1,1151,0,0,0,3.2", "the AN0 tag (field 2) is 'AN1': 'AN0' expected"),
        ("DIST,1,AN0,ZZZZ,0,0,0,3.2", "AN0 id (field 3) is 'ZZZZ': 1-8 hex digits expected"),
        ("DIST,1,AN0,1151,0,0,0,-3.2", "AN0 distance -3.2 (field 7) is negative"),
        ("DIST,1,AN0,1151,0,inf,0,3.2", "AN0 y (field 5) is 'inf': a finite number expected"),
        ("DIST,1,AN0,1151,0,0,0,3.2,EXTRA", "the field after AN0 (field 8) is 'EXTRA': 'POS' or the end expected"),
        (
            "DIST,1,AN0,1151,0,0,0,3.2,POS,1,2,3,150",
            "POS quality factor (field 12) is '150': an integer 0-100 expected",
        ),
        ("DIST,1,AN0,1151,0,0,0,3.2,POS,1,2,3,50,9", "extra fields after POS's quality factor (from field 13)"),
        ("DIST,1,AN0,1151,0,0,0,3.2,POS,1,2", "line ends before POS z (field 11)"),
        ("DIST,1,AN0,1151,0,0,0,3.2,PO", "line ends inside the field after AN0 ('PO', field 8)"),
        ("DIST,2,AN0,1151,0,0,0,3.2", "line ends before AN1 (field 8)"),
    ],
)
def test_dropped_lines_say_why(line: str, reason: str) -> None:
    kind, r, why = explain_lec_line(line)
    assert r is None and why == reason
    p = LecParser()
    assert p.feed(line) is None and p.last_drop_reason == f"{kind.value}: {reason}"


def test_binary_and_ignored_lines() -> None:
    assert classify_lec_line(b"\xff\xfe\x00DIST")[0] is LineKind.BINARY
    assert classify_lec_line("DIST,1\x00,AN0")[0] is LineKind.BINARY
    assert classify_lec_line("DIST,4,AN0,1151,é")[0] is LineKind.BINARY
    assert classify_lec_line(b"")[0] is LineKind.IGNORED
    assert classify_lec_line("dwm> ")[0] is LineKind.IGNORED
    assert classify_lec_line("lec\r\n")[0] is LineKind.IGNORED
    assert classify_lec_line(GOOD.encode())[0] is LineKind.READING


def test_fuzz_never_raises() -> None:
    rng = np.random.default_rng(0)
    parser = LecParser()
    for _ in range(3000):
        kind = rng.integers(3)
        if kind == 0:
            line: str | bytes = rng.integers(0, 256, rng.integers(0, 120)).astype(np.uint8).tobytes()
        elif kind == 1:
            cut = int(rng.integers(0, len(GOOD)))
            line = GOOD[:cut]
        else:
            chars = list(GOOD)
            for _ in range(3):
                chars[int(rng.integers(len(chars)))] = chr(int(rng.integers(32, 127)))
            line = "".join(chars)
        parser.feed(line)
    s = parser.stats
    assert s.lines == 3000
    assert s.readings + s.ignored + s.malformed + s.partial + s.binary == 3000
    assert s.binary > 500 and s.partial > 300 and s.malformed > 100


def test_parser_counters() -> None:
    p = LecParser()
    for line in (GOOD, GOOD[:50], "garbage", b"\x80\x81", "", "dwm> ", GOOD):
        p.feed(line)
    s = p.stats
    assert (s.readings, s.partial, s.malformed, s.binary, s.ignored) == (2, 1, 1, 1, 2)
    assert s.dropped == 3


def test_reading_feeds_the_multilateration() -> None:
    layout = load_anchor_layout()
    p = np.array([0.2, 0.1, 2.0])
    parts = ["DIST", "4"]
    for k, aid in enumerate(layout.anchor_ids[:4]):
        x, y, z = layout.position_of(aid)
        d = float(np.linalg.norm(layout.position_of(aid) - p))
        parts += [f"AN{k}", aid, f"{x:.2f}", f"{y:.2f}", f"{z:.2f}", f"{d:.4f}"]
    r = parse_lec_line(",".join(parts))
    assert r is not None
    f = Multilaterator(layout).solve_twr(r.to_twr_measurement())
    assert isinstance(f, UwbFix)
    np.testing.assert_allclose(f.position_m, p, atol=1e-3)


# --------------------------------------------------------------------------------------------
# end to end: a fake DWM1001 on a pseudo-terminal


class FakeDwm1001:
    """Plays the PANS shell on the master side of a pty: two CRs -> banner + prompt; ``lec``
    toggles a stream of lines (good ones mixed with partial, garbage and binary ones)."""

    STREAM: ClassVar[list[bytes]] = [
        GOOD.encode() + b"\r\n",
        b"DIST,4,AN0,1151,0.00,0.00,0.00,3.26,AN1,0CA8\r\n",  # partial
        b"\x00\xff\xfe garbage \x81\r\n",  # binary
        b"DIST,2,AN0,1151,0.00,0.00,0.00,3.30,AN1,0CA8,0.00,3.35,0.00,2.40\r\n",
        b"nonsense,line\r\n",  # malformed
    ]

    def __init__(self, answer: bool = True, streaming_at_start: bool = False) -> None:
        self.master, self.slave = os.openpty()
        # raw from the start: a new pty echoes what the device writes back to it until the driver
        # opens the port (pyserial sets raw then), so a stream running at start would be read back
        # as commands under load; a UART echoes nothing
        tty.setraw(self.slave)
        self.path = os.ttyname(self.slave)
        self.answer = answer
        self.commands: list[bytes] = []
        self.streaming = streaming_at_start
        self.in_shell = streaming_at_start
        self.stream_started = threading.Event()
        self.stream_stopped = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        buf = b""
        in_shell = self.in_shell
        k = 0
        next_line = time.monotonic()
        while not self._stop.is_set():
            r, _, _ = select.select([self.master], [], [], 0.005)
            if r:
                try:
                    data = os.read(self.master, 1024)
                except OSError:
                    return
                buf += data
                if not self.answer:
                    buf = b""
                    continue
                if not in_shell:
                    if b"\r\r" in buf:
                        in_shell = True
                        buf = b""
                        os.write(
                            self.master, b"\r\nDWM1001 TWR Real Time Location System\r\n\r\nHelp  : Type help\r\ndwm> "
                        )
                    continue
                while b"\r" in buf:
                    cmd, buf = buf.split(b"\r", 1)
                    if not cmd:
                        os.write(self.master, b"\r\ndwm> ")
                        continue
                    self.commands.append(cmd)
                    if cmd == b"lec":
                        if self.streaming:
                            self.streaming = False
                            self.stream_stopped.set()
                            os.write(self.master, b"\r\ndwm> ")
                        else:
                            self.streaming = True
                            self.stream_started.set()
                            os.write(self.master, b"lec\r\n")
            if self.streaming and time.monotonic() >= next_line:
                try:
                    os.write(self.master, self.STREAM[k % len(self.STREAM)])
                except OSError:
                    return
                k += 1
                next_line = time.monotonic() + 0.002

    def close(self) -> None:
        self._stop.set()
        self._thread.join(2.0)
        os.close(self.master)
        os.close(self.slave)


def test_driver_end_to_end_over_a_pty() -> None:
    fake = FakeDwm1001()
    try:
        drv = Dwm1001Driver(fake.path, prompt_timeout_s=3.0)
        drv.start()
        assert fake.stream_started.wait(2.0)
        readings = []
        deadline = time.monotonic() + 5.0
        while len(readings) < 10 and time.monotonic() < deadline:
            r = drv.read_one(timeout_s=1.0)
            if r is not None:
                readings.append(r)
        assert len(readings) == 10
        assert all(len(r.anchors) in (2, 4) for r in readings)
        assert all(math.isfinite(r.time_s) for r in readings)
        assert [r.time_s for r in readings] == sorted(r.time_s for r in readings)
        s = drv.stats
        # the fake streams on: the driver may have parsed more than the ten read by now
        assert s.readings >= 10
        assert s.partial >= 4 and s.binary >= 4 and s.malformed >= 4
        assert drv.is_open
        drv.stop()
        assert not drv.is_open
        assert fake.stream_stopped.wait(2.0)  # the second "lec" stopped the stream
        assert fake.commands == [b"lec", b"lec"]
        drv.stop()  # idempotent
    finally:
        fake.close()


def test_driver_context_manager_and_no_prompt() -> None:
    fake = FakeDwm1001()
    try:
        with Dwm1001Driver(fake.path) as drv:
            assert drv.read_one(timeout_s=2.0) is not None
            time.sleep(0.05)
            batch = drv.read()  # API v1: everything since the last call, without blocking
            assert len(batch) >= 2 and all(r.anchors for r in batch)
            assert drv.api_version == 1
        assert fake.stream_stopped.wait(2.0)
    finally:
        fake.close()
    silent = FakeDwm1001(answer=False)
    try:
        drv = Dwm1001Driver(silent.path, prompt_timeout_s=0.3)
        with pytest.raises(Dwm1001Error, match="no 'dwm>' prompt"):
            drv.start()
        drv.stop()
        assert not drv.is_open
    finally:
        silent.close()


def test_read_before_start_is_an_error_and_api_v1() -> None:
    from companion.plugin_api import API_VERSION, Driver

    assert isinstance(Dwm1001Driver("/dev/null"), Driver) and Dwm1001Driver.api_version == API_VERSION
    with pytest.raises(Dwm1001Error):
        Dwm1001Driver("/dev/null").read()
    with pytest.raises(Dwm1001Error):
        Dwm1001Driver("/dev/null").read_one(0.01)


def test_driver_keeps_a_stream_left_running() -> None:
    fake = FakeDwm1001(streaming_at_start=True)  # a previous session did not stop lec
    try:
        drv = Dwm1001Driver(fake.path)
        drv.start()
        assert fake.commands == []  # nothing sent: a "lec" would have toggled the stream off
        got = drv.read(timeout_s=1.0)
        assert got and all(r.anchors for r in got)
        drv.stop()
        assert fake.stream_stopped.wait(2.0)
        assert fake.commands == [b"lec"]
    finally:
        fake.close()


def test_a_reading_is_stamped_when_its_line_arrives_not_when_it_is_read() -> None:
    master, slave = os.openpty()
    streaming = threading.Event()
    streaming.set()

    def stream_left_running() -> None:  # start() finds lines arriving and keeps the stream
        while streaming.is_set():
            os.write(master, GOOD.encode() + b"\r\n")
            time.sleep(0.02)

    writer = threading.Thread(target=stream_left_running, daemon=True)
    writer.start()
    try:
        drv = Dwm1001Driver(os.ttyname(slave))
        drv.start(probe_s=0.3)
        streaming.clear()
        writer.join(1.0)
        time.sleep(0.1)
        drv.read()  # what arrived so far
        arrived = time.monotonic()
        os.write(master, GOOD.encode() + b"\r\n")
        time.sleep(0.3)  # the shell polls late
        polled = time.monotonic()
        (reading,) = drv.read()
        assert reading.time_s - arrived < 0.1 < polled - reading.time_s
        drv.stop()
    finally:
        streaming.clear()
        writer.join(1.0)
        os.close(master)
        os.close(slave)


def test_a_port_that_fails_while_streaming_is_an_error_on_read() -> None:
    class Unplugged:
        is_open = True
        in_waiting = 0

        def __init__(self, *args: object, **kwargs: object) -> None:
            self.reads = 0

        def reset_input_buffer(self) -> None:
            pass

        def read(self, n: int) -> bytes:
            self.reads += 1
            if self.reads <= 2:  # the probe sees a running stream
                return GOOD.encode() + b"\r\n"
            raise OSError(5, "Input/output error")

        def write(self, data: bytes) -> int:
            raise OSError(5, "Input/output error")

        def flush(self) -> None:
            pass

        def close(self) -> None:
            self.is_open = False

    drv = Dwm1001Driver("/dev/ttyGONE", serial_factory=Unplugged)
    drv.start(probe_s=0.2)
    assert drv.read()  # the readings that arrived before the fault are not lost
    with pytest.raises(Dwm1001Error, match=r"reading the port failed: .*Input/output error"):
        drv.read(timeout_s=1.0)
    drv.stop()  # the 'lec' that cannot be written is logged, the port closed
    assert not drv.is_open
