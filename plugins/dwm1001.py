"""Decawave DWM1001 (PANS firmware) UART shell driver: two-way-ranging distances for the UWB
multilateration (delivery section 4.2.2).

Protocol (PANS shell over the UART, 115200 8N1): two carriage returns within a second enter the
shell, which answers with the ``dwm>`` prompt; the ``lec`` command toggles a CSV stream, one line
per ranging round::

    DIST,4,AN0,1151,0.00,0.00,0.00,3.26,AN1,0CA8,0.00,3.35,0.00,2.45,...,POS,1.87,1.49,0.46,53

``DIST,<n>`` is followed by n groups ``AN<k>,<id>,<x>,<y>,<z>,<distance>`` (metres) and, when
the tag's own location engine is on, ``POS,<x>,<y>,<z>,<quality 0-100>``. Sending ``lec`` again
stops the stream.

:func:`parse_lec_line` is a pure parser; :class:`LecParser` adds counters. Malformed, partial
(truncated), binary or unexpected lines are counted and dropped, never raised;
:func:`explain_lec_line` (and ``LecParser.last_drop_reason``) says why, naming the field.
:class:`Dwm1001Driver` owns the serial port; a reader thread stamps each reading with the injected
clock as its line completes (arrival time, not the time the shell polls; the device's own latency
is not modelled).
"""

from __future__ import annotations

import logging
import math
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum
from types import TracebackType
from typing import Any, ClassVar

import serial

from companion.uwb.anchors import AnchorLayout
from companion.uwb.measurements import TwrMeasurement

log = logging.getLogger(__name__)

MAX_LINE_BYTES = 512
MAX_QUEUED_READINGS = 256  # about 25 s at the tag's 10 Hz; older readings are dropped and counted
MAX_ANCHORS_PER_LINE = 16
PROMPT = b"dwm>"
_HEX_ID = re.compile(r"^[0-9A-Fa-f]{1,8}$")
_AN_TAG = re.compile(r"^AN(\d{1,2})$")


@dataclass(frozen=True)
class DwmAnchorRange:
    """One anchor of a ``lec`` line: its id, its configured position and the measured range."""

    anchor_id: str
    x_m: float
    y_m: float
    z_m: float
    distance_m: float


@dataclass(frozen=True)
class DwmReading:
    """One ``lec`` line. ``position_m``/``quality_factor`` only when the tag computed a position."""

    time_s: float
    anchors: tuple[DwmAnchorRange, ...]
    position_m: tuple[float, float, float] | None = None
    quality_factor: int | None = None

    def to_twr_measurement(self) -> TwrMeasurement:
        return TwrMeasurement(
            self.time_s,
            tuple(a.anchor_id for a in self.anchors),
            tuple(a.distance_m for a in self.anchors),
        )


def anchor_layout_from_reading(reading: DwmReading, tag_side: str = "above", frame: str = "pad") -> AnchorLayout:
    """The anchor layout a ``lec`` line reports (each anchor's configured position, as PANS
    stores it on the anchor). Four anchors at one height -- the usual DWM1001 set-up -- give a
    coplanar layout; ``tag_side`` says which side of their plane the tag is on. A line with three
    anchors gives a 3-anchor (always coplanar) layout, which fixes the tag exactly determined.

    Raises ``companion.uwb.AnchorLayoutError`` for fewer than 3 anchors or degenerate ones.
    """
    return AnchorLayout(
        tuple(a.anchor_id for a in reading.anchors),
        tuple((a.x_m, a.y_m, a.z_m) for a in reading.anchors),
        frame,
        "",
        tag_side=tag_side,
    )


class LineKind(Enum):
    READING = "reading"
    IGNORED = "ignored"  # empty line, the prompt, the echoed command
    MALFORMED = "malformed"
    PARTIAL = "partial"  # a valid prefix of a line that ended too early
    BINARY = "binary"  # not printable ASCII


class _Partial(Exception):
    """The line ended early; the message says where."""


class _Malformed(Exception):
    """The line cannot be a ``lec`` line; the message says which field is wrong."""


def _num(tok: str) -> float:
    try:
        v = float(tok)
    except ValueError as exc:
        raise _Malformed(tok) from exc
    if not math.isfinite(v):
        raise _Malformed(tok)
    return v


def explain_lec_line(line: str | bytes, time_s: float = math.nan) -> tuple[LineKind, DwmReading | None, str]:
    """:func:`classify_lec_line` with the reason a line is dropped ("" for readings and ignored
    lines), naming the field (counted from 0 in the comma-separated line) and its text."""
    if isinstance(line, bytes | bytearray):
        try:
            line = bytes(line).decode("ascii")
        except UnicodeDecodeError:
            return LineKind.BINARY, None, "not ASCII"
    text = line.strip("\r\n \t")
    if any(not (32 <= ord(ch) < 127) for ch in text):
        return LineKind.BINARY, None, "non-printable characters"
    if not text or text.startswith("dwm>") or text == "lec":
        return LineKind.IGNORED, None, ""
    tokens = text.split(",")
    try:
        if tokens[0] == "DIST":
            reading = _parse_dist(tokens, time_s)
        elif tokens[0] == "POS":
            pos, qf, used = _parse_pos(tokens, 0)
            if used != len(tokens):
                raise _Malformed(f"extra fields after POS's quality factor (from field {used})")
            reading = DwmReading(time_s, (), pos, qf)
        else:
            return LineKind.MALFORMED, None, f"starts with {tokens[0][:16]!r}, not DIST or POS"
    except _Partial as exc:
        return LineKind.PARTIAL, None, str(exc)
    except _Malformed as exc:
        return LineKind.MALFORMED, None, str(exc)
    return LineKind.READING, reading, ""


def classify_lec_line(line: str | bytes, time_s: float = math.nan) -> tuple[LineKind, DwmReading | None]:
    """Classify and parse one line (with or without its line ending)."""
    kind, reading, _ = explain_lec_line(line, time_s)
    return kind, reading


def parse_lec_line(line: str, time_s: float = math.nan) -> DwmReading | None:
    """Parse a ``lec`` CSV line; None for anything that is not a complete, valid reading."""
    kind, reading = classify_lec_line(line, time_s)
    return reading if kind is LineKind.READING else None


def _take(tokens: list[str], i: int, what: str) -> str:
    if i >= len(tokens):
        raise _Partial(f"line ends before {what} (field {i})")
    return tokens[i]


def _bad(tokens: list[str], i: int, expected_prefix_ok: bool, what: str, expected: str) -> Exception:
    """A bad token: a truncated line if it is the last token and a prefix of what was expected."""
    if i == len(tokens) - 1 and expected_prefix_ok:
        return _Partial(f"line ends inside {what} ({tokens[i]!r}, field {i})")
    return _Malformed(f"{what} (field {i}) is {tokens[i][:16]!r}: {expected} expected")


def _num_at(tokens: list[str], i: int, what: str) -> float:
    tok = _take(tokens, i, what)
    try:
        return _num(tok)
    except _Malformed:
        raise _bad(tokens, i, tok in ("", "-", "+", ".", "-."), what, "a finite number") from None


def _parse_pos(tokens: list[str], i: int) -> tuple[tuple[float, float, float], int, int]:
    """Parse ``POS,x,y,z,qf`` starting at tokens[i] == "POS"; returns (pos, qf, next index)."""
    x = _num_at(tokens, i + 1, "POS x")
    y = _num_at(tokens, i + 2, "POS y")
    z = _num_at(tokens, i + 3, "POS z")
    qf_tok = _take(tokens, i + 4, "POS quality factor")
    if not qf_tok.isdigit() or int(qf_tok) > 100:
        raise _bad(tokens, i + 4, qf_tok == "", "POS quality factor", "an integer 0-100")
    return (x, y, z), int(qf_tok), i + 5


def _parse_dist(tokens: list[str], time_s: float) -> DwmReading:
    n_tok = _take(tokens, 1, "the anchor count")
    if not n_tok.isdigit() or int(n_tok) > MAX_ANCHORS_PER_LINE:
        raise _Malformed(f"anchor count {n_tok[:16]!r} (field 1): 0-{MAX_ANCHORS_PER_LINE} expected")
    n = int(n_tok)
    anchors: list[DwmAnchorRange] = []
    i = 2
    for k in range(n):
        tag = _take(tokens, i, f"AN{k}")
        m = _AN_TAG.match(tag)
        if not m or int(m.group(1)) != k:
            raise _bad(tokens, i, f"AN{k}".startswith(tag), f"the AN{k} tag", f"'AN{k}'")
        aid = _take(tokens, i + 1, f"AN{k} id")
        if not _HEX_ID.match(aid):
            raise _bad(tokens, i + 1, aid == "", f"AN{k} id", "1-8 hex digits")
        x = _num_at(tokens, i + 2, f"AN{k} x")
        y = _num_at(tokens, i + 3, f"AN{k} y")
        z = _num_at(tokens, i + 4, f"AN{k} z")
        d = _num_at(tokens, i + 5, f"AN{k} distance")
        if d < 0.0:
            raise _Malformed(f"AN{k} distance {d} (field {i + 5}) is negative")
        anchors.append(DwmAnchorRange(aid.upper(), x, y, z, d))
        i += 6
    pos = None
    qf = None
    if i < len(tokens):
        if tokens[i] != "POS":
            raise _bad(
                tokens,
                i,
                "POS".startswith(tokens[i]) and tokens[i] != "",
                f"the field after AN{n - 1}",
                "'POS' or the end",
            )
        pos, qf, i = _parse_pos(tokens, i)
        if i != len(tokens):
            raise _Malformed(f"extra fields after POS's quality factor (from field {i})")
    return DwmReading(time_s, tuple(anchors), pos, qf)


@dataclass
class LecStats:
    lines: int = 0
    readings: int = 0
    ignored: int = 0
    malformed: int = 0
    partial: int = 0
    binary: int = 0
    overflow: int = 0  # bytes without a line ending beyond MAX_LINE_BYTES (dropped)
    unread: int = 0  # readings dropped because nobody read them (more than MAX_QUEUED_READINGS waiting)

    @property
    def dropped(self) -> int:
        return self.malformed + self.partial + self.binary + self.overflow + self.unread


class LecParser:
    """:func:`classify_lec_line` with counters."""

    def __init__(self) -> None:
        self.stats = LecStats()
        #: why the last dropped line was dropped (:func:`explain_lec_line`); "" before any
        self.last_drop_reason = ""

    def feed(self, line: str | bytes, time_s: float = math.nan) -> DwmReading | None:
        self.stats.lines += 1
        kind, reading, reason = explain_lec_line(line, time_s)
        if kind is LineKind.READING:
            self.stats.readings += 1
        elif kind is LineKind.IGNORED:
            self.stats.ignored += 1
        elif kind is LineKind.MALFORMED:
            self.stats.malformed += 1
        elif kind is LineKind.PARTIAL:
            self.stats.partial += 1
        else:
            self.stats.binary += 1
        if kind in (LineKind.MALFORMED, LineKind.PARTIAL, LineKind.BINARY):
            self.last_drop_reason = f"{kind.value}: {reason}"
            log.debug("dwm1001: dropped %s line %r: %s", kind.value, line[:80], reason)
        return reading


class Dwm1001Error(RuntimeError):
    """The device did not answer as a DWM1001 PANS shell."""


class Dwm1001Driver:
    """The DWM1001 shell over a serial port (``companion.uwb`` plugin, API version 1):
    ``start()`` enters the shell and starts ``lec``, ``read()`` returns the readings received
    since the last call (``read_one()`` blocks for the next one), ``stop()`` stops the stream
    and closes the port.
    """

    api_version: ClassVar[int] = 1

    def __init__(
        self,
        port: str,
        baudrate: int = 115200,
        *,
        clock: Callable[[], float] = time.monotonic,
        prompt_timeout_s: float = 3.0,
        serial_factory: Callable[..., Any] = serial.Serial,
    ) -> None:
        self.port = port
        self.baudrate = baudrate
        self.clock = clock
        self.prompt_timeout_s = prompt_timeout_s
        self._serial_factory = serial_factory
        self._ser: Any = None
        self._buf = bytearray()
        self._streaming = False
        self.parser = LecParser()
        # readings stamped by the reader thread, handed to read() / read_one()
        self._ready: deque[DwmReading] = deque()
        self._cond = threading.Condition()
        self._reader: threading.Thread | None = None
        self._stop_reader = threading.Event()
        self.reader_error: BaseException | None = None

    @property
    def stats(self) -> LecStats:
        return self.parser.stats

    @property
    def is_open(self) -> bool:
        return self._ser is not None and bool(self._ser.is_open)

    def start(self, probe_s: float = 0.3) -> None:
        """Open the port, enter the shell ("\\r\\r" until ``dwm>``), start the ``lec`` stream.

        ``lec`` toggles, so first listen for ``probe_s``: if a previous session left the stream
        running (valid lines arriving), keep it and send nothing.
        """
        if self._ser is None:
            self._ser = self._serial_factory(self.port, self.baudrate, timeout=0.05, write_timeout=1.0)
        self._ser.reset_input_buffer()
        self._buf.clear()
        if probe_s > 0 and self._stream_running(probe_s):
            self._streaming = True
            log.info("dwm1001 on %s: lec stream already running", self.port)
            self._start_reader()
            return
        deadline = self.clock() + self.prompt_timeout_s
        seen = bytearray()
        next_send = 0.0
        while True:
            now = self.clock()
            if now >= deadline:
                raise Dwm1001Error(f"{self.port}: no '{PROMPT.decode()}' prompt within {self.prompt_timeout_s} s")
            if now >= next_send:
                self._ser.write(b"\r\r")  # PANS: two Enters within 1 s open the shell
                self._ser.flush()
                next_send = now + 1.0
            chunk = self._ser.read(max(1, self._ser.in_waiting))
            if chunk:
                seen += chunk
                if PROMPT in seen:
                    break
                del seen[:-64]  # only the tail matters
        self._ser.write(b"lec\r")
        self._ser.flush()
        self._streaming = True
        self._buf.clear()
        log.info("dwm1001 on %s: shell open, lec stream started", self.port)
        self._start_reader()

    def _start_reader(self) -> None:
        self._stop_reader.clear()
        self._reader = threading.Thread(target=self._read_port, name=f"dwm1001 {self.port}", daemon=True)
        self._reader.start()

    def _read_port(self) -> None:
        """Reader thread: bytes as they arrive (the port's 0.05 s read timeout bounds each wait),
        each completed line parsed and stamped at once."""
        ser = self._ser
        try:
            self._parse_buffer()  # lines the start-up probe left buffered
            while not self._stop_reader.is_set():
                chunk = ser.read(max(1, ser.in_waiting))
                if chunk:
                    self._buf += chunk
                    self._parse_buffer()
        except (serial.SerialException, OSError, TypeError) as exc:  # unplugged: pyserial may raise either
            if not self._stop_reader.is_set():
                log.error("dwm1001 on %s: reading the port failed: %s", self.port, exc)
                self.reader_error = exc
        finally:
            with self._cond:
                self._cond.notify_all()

    def _parse_buffer(self) -> None:
        """Readings of every complete line in the buffer, stamped now, queued for read()."""
        while (reading := self._next_from_buffer()) is not None:
            with self._cond:
                if len(self._ready) >= MAX_QUEUED_READINGS:
                    self._ready.popleft()
                    self.parser.stats.unread += 1
                self._ready.append(reading)
                self._cond.notify_all()

    def _stream_running(self, window_s: float) -> bool:
        """Are complete, valid lec lines arriving? (They stay buffered for :meth:`read`.)"""
        deadline = self.clock() + window_s
        while self.clock() < deadline:
            chunk = self._ser.read(max(1, self._ser.in_waiting))
            if chunk:
                self._buf += chunk
            lines = bytes(self._buf).split(b"\n")[:-1]
            if any(classify_lec_line(line)[0] is LineKind.READING for line in lines):
                return True
        self._buf.clear()
        return False

    def read(self, timeout_s: float = 0.0) -> list[DwmReading]:
        """Plugin API v1: every valid reading received since the last call (non-blocking by
        default; with ``timeout_s`` > 0 wait that long for at least one). Bad lines are counted."""
        if self._ser is None:
            raise Dwm1001Error("read() before start()")
        self._raise_if_reader_failed()
        with self._cond:
            if not self._ready and timeout_s > 0.0:
                self._wait_for_reading(timeout_s)
                self._raise_if_reader_failed()
            out = list(self._ready)
            self._ready.clear()
        return out

    def read_one(self, timeout_s: float = 1.0) -> DwmReading | None:
        """The next valid reading within ``timeout_s`` (None on timeout). Bad lines are counted."""
        if self._ser is None:
            raise Dwm1001Error("read_one() before start()")
        self._raise_if_reader_failed()
        with self._cond:
            if not self._ready:
                self._wait_for_reading(timeout_s)
                self._raise_if_reader_failed()
            return self._ready.popleft() if self._ready else None

    def _raise_if_reader_failed(self) -> None:
        if self.reader_error is not None and not self._ready:
            raise Dwm1001Error(f"{self.port}: reading the port failed: {self.reader_error}")

    def _wait_for_reading(self, timeout_s: float) -> None:
        """Under ``self._cond``: until a reading is queued, the reader stops, or ``timeout_s``."""
        deadline = time.monotonic() + timeout_s
        while not self._ready and self._reader is not None and self._reader.is_alive():
            left = deadline - time.monotonic()
            if left <= 0.0:
                return
            self._cond.wait(left)

    def _next_from_buffer(self) -> DwmReading | None:
        while True:
            nl = self._buf.find(b"\n")
            if nl < 0:
                if len(self._buf) > MAX_LINE_BYTES:
                    self.parser.stats.overflow += 1
                    self._buf.clear()
                return None
            raw = bytes(self._buf[:nl])
            del self._buf[: nl + 1]
            if len(raw) > MAX_LINE_BYTES:
                self.parser.stats.overflow += 1
                continue
            reading = self.parser.feed(raw, self.clock())
            if reading is not None:
                return reading

    def stop(self) -> None:
        """Send ``lec`` again (stops the stream) and close the port. Safe to call twice."""
        if self._ser is None:
            return
        self._stop_reader.set()
        if self._reader is not None:
            self._reader.join(1.0)  # the port's read timeout is 0.05 s
            self._reader = None
        try:
            if self._streaming and self._ser.is_open:
                self._ser.write(b"lec\r")
                self._ser.flush()
        except (serial.SerialException, OSError) as exc:
            log.warning("dwm1001 on %s: could not stop lec: %s", self.port, exc)
        finally:
            self._streaming = False
            self._ser.close()
            self._ser = None
            log.info("dwm1001 on %s: stopped", self.port)

    def __enter__(self) -> Dwm1001Driver:
        self.start()
        return self

    def __exit__(
        self, exc_type: type[BaseException] | None, exc: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()
