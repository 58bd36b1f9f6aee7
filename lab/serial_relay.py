"""A serial link emulator: two pseudo-terminal pairs joined by a relay that paces each direction at
a UART's baud rate, counts the bytes and can drop or corrupt a fraction of them (seeded).

A Raspberry Pi's UART wired to an autopilot's TELEM2 at 921600 baud carries at most
921600 / 10 = 92160 bytes/s each way (8N1: a start bit, 8 data bits, a stop bit). A pty pair has no
baud rate: whatever one side writes arrives at once. The relay sits between two pty pairs, one for
the autopilot (``autopilot_device``, e.g. ArduCopter SITL's ``--serial2 uart:DEVICE:921600``), one
for the companion (``companion_device``, ``serial://DEVICE:921600``), and forwards each direction
on its own thread at the line's rate: a byte is delivered one byte time (``bits_per_byte / baud``)
after the one before it, or after it was read if the line was idle.

Back-pressure as on a wire: the relay takes bytes from a sender only while fewer than
``queue_limit`` bytes wait for the line (a UART's transmit FIFO), so a sender faster than the line
fills its own pty buffer and sees its writes block or fail, as on a UART. Bytes that the receiver
does not read in time (its pty input buffer full) are lost and counted as ``overrun``, as a UART's
receive overrun loses them.

Faults are on the line: a dropped or corrupted byte took its byte time. The next faulty byte is
drawn from a geometric distribution of ``drop + corrupt`` per byte from one ``random.Random(seed)``
per direction, so the same seed and the same bytes give the same faults however the bytes were
chunked. A corrupted byte is XORed with a random non-zero value (it always changes).

With ``watch`` (MAVLink message ids) each direction also times those frames from the sender's
write to their delivery (:class:`FrameTime`; :func:`frame_summary` for latency and jitter).

``python -m companion_lab.serial_relay --baud 921600 [--drop 0.01] [--corrupt 0.01] [--seed 1]``
prints both device names, then the counters every ``--report-s`` seconds, until Ctrl-C (or for
``--duration`` seconds).
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import errno
import itertools
import math
import os
import random
import select
import statistics
import sys
import termios
import threading
import time
from dataclasses import dataclass, field

BITS_PER_BYTE_8N1 = 10  # start bit, 8 data bits, stop bit
DEFAULT_QUEUE_LIMIT = 1024  # bytes waiting for the line before the relay stops reading the sender
READ_CHUNK = 4096
MIN_WAIT_S = 0.0005  # the shortest sleep between deliveries (a burst goes out in ~0.5 ms slices)
IDLE_WAIT_S = 0.1


class SerialRelayError(RuntimeError):
    """The relay cannot start (a bad rate or fraction, no pty on this system)."""


def make_raw(fd: int) -> None:
    """cfmakeraw(3) on a terminal: no echo, no line editing, no CR/LF translation, 8 bits."""
    attrs = termios.tcgetattr(fd)
    iflag, oflag, cflag, lflag = attrs[0], attrs[1], attrs[2], attrs[3]
    iflag &= ~(
        termios.IGNBRK
        | termios.BRKINT
        | termios.PARMRK
        | termios.ISTRIP
        | termios.INLCR
        | termios.IGNCR
        | termios.ICRNL
        | termios.IXON
        | termios.IXOFF
        | termios.IXANY
        | termios.IMAXBEL
    )
    oflag &= ~termios.OPOST
    lflag &= ~(termios.ECHO | termios.ECHONL | termios.ICANON | termios.ISIG | termios.IEXTEN)
    cflag &= ~(termios.CSIZE | termios.PARENB)
    cflag |= termios.CS8
    cc = list(attrs[6])
    cc[termios.VMIN] = 1
    cc[termios.VTIME] = 0
    termios.tcsetattr(fd, termios.TCSANOW, [iflag, oflag, cflag, lflag, attrs[4], attrs[5], cc])


@dataclass
class DirectionStats:
    """One direction's counters (read from the relay thread without a lock: each is one int)."""

    name: str
    read: int = 0  # bytes taken from the sender
    line: int = 0  # bytes that crossed the line (delivered + dropped + overrun)
    delivered: int = 0  # bytes written to the receiver (corrupted ones included)
    dropped: int = 0
    corrupted: int = 0
    overrun: int = 0  # lost because the receiver did not read (its pty buffer full)
    max_backlog: int = 0  # most bytes waiting for the line at once
    first_s: float = math.nan  # monotonic time of the first byte on the line
    last_s: float = math.nan  # ... and of the last
    # bytes on the line per whole second since the relay started (index: second)
    per_second: list[int] = field(default_factory=list)

    @property
    def peak_bytes_per_s(self) -> int:
        """The most bytes on the line in one whole second since the relay started."""
        return max(self.per_second, default=0)

    def snapshot(self) -> DirectionStats:
        return DirectionStats(
            self.name,
            self.read,
            self.line,
            self.delivered,
            self.dropped,
            self.corrupted,
            self.overrun,
            self.max_backlog,
            self.first_s,
            self.last_s,
            list(self.per_second),
        )


MAVLINK2_STX, MAVLINK1_STX = 0xFD, 0xFE
MAVLINK2_IFLAG_SIGNED = 0x01


@dataclass(frozen=True, slots=True)
class FrameTime:
    """One watched MAVLink frame on the line: when its last byte was read from the sender, when
    that byte left the emulated wire (its line time: the wait for the line plus the byte times)
    and when the relay wrote it to the receiver (later by the relay thread's own scheduling)."""

    msgid: int
    read_s: float
    line_s: float
    delivered_s: float

    @property
    def latency_s(self) -> float:
        """The UART's latency for this frame: from the sender's write to the frame's last bit."""
        return self.line_s - self.read_s

    @property
    def relay_lag_s(self) -> float:
        """What the emulator added (its thread not scheduled at the byte's time): not the UART's."""
        return self.delivered_s - self.line_s


class FrameClock:
    """Finds the MAVLink frames of ``msgids`` in a direction's sender stream (clean: faults come
    after) and times each from its read to its delivery. The framing is the header's length (and
    the signature flag); a byte that starts no frame is skipped."""

    def __init__(self, msgids: frozenset[int]) -> None:
        self.msgids = msgids
        self._buf = bytearray()
        self._buf_offset = 0  # the sender stream's offset of _buf[0]
        self._pending: collections.deque[tuple[int, float, int]] = collections.deque()  # end, read_s, msgid
        self.frames: list[FrameTime] = []

    def on_read(self, data: bytes, now: float) -> None:
        buf = self._buf
        buf += data
        i, n = 0, len(buf)
        while i < n:
            stx = buf[i]
            if stx == MAVLINK2_STX:
                if n - i < 10:
                    break
                total = 12 + buf[i + 1] + (13 if buf[i + 2] & MAVLINK2_IFLAG_SIGNED else 0)
                msgid = buf[i + 7] | buf[i + 8] << 8 | buf[i + 9] << 16
            elif stx == MAVLINK1_STX:
                if n - i < 6:
                    break
                total, msgid = 8 + buf[i + 1], buf[i + 5]
            else:
                i += 1
                continue
            if n - i < total:
                break
            if msgid in self.msgids:
                self._pending.append((self._buf_offset + i + total, now, msgid))
            i += total
        del buf[:i]
        self._buf_offset += i

    def on_delivered(self, offset: int, now: float, base_offset: int, base_s: float, byte_s: float) -> None:
        """The line has carried the sender's stream up to ``offset``, the bytes from ``base_offset``
        on one after another from ``base_s`` (each ``byte_s`` long); written out at ``now``."""
        pending = self._pending
        while pending and pending[0][0] <= offset:
            end, read_s, msgid = pending.popleft()
            line_s = base_s + (end - base_offset) * byte_s
            self.frames.append(FrameTime(msgid, read_s, line_s, now))


def _pct(sorted_ms: list[float], q: float) -> float:
    return sorted_ms[min(len(sorted_ms) - 1, max(0, math.ceil(q * len(sorted_ms)) - 1))]


def frame_summary(frames: list[FrameTime], msgid: int, pause_s: float = 0.5) -> dict[str, float]:
    """The frames of ``msgid``: the UART's latency (ms: p50, p99, max), the intervals between
    their line times while they stream (ms: mean, std, max; a gap over ``pause_s`` is a pause of
    the stream, counted in ``pauses``, not jitter) and the relay's own lag (ms: p99, max). Empty
    without two frames."""
    times = [f for f in frames if f.msgid == msgid]
    if len(times) < 2:
        return {}
    lat = sorted(1e3 * f.latency_s for f in times)
    lag = sorted(1e3 * f.relay_lag_s for f in times)
    gaps = [1e3 * (b.line_s - a.line_s) for a, b in itertools.pairwise(times)]
    streaming = [g for g in gaps if g <= 1e3 * pause_s] or [math.nan]
    return {
        "n": float(len(times)),
        "latency_p50_ms": _pct(lat, 0.5),
        "latency_p99_ms": _pct(lat, 0.99),
        "latency_max_ms": lat[-1],
        "interval_mean_ms": statistics.fmean(streaming),
        "interval_std_ms": statistics.pstdev(streaming),
        "interval_max_ms": max(streaming),
        "pauses": float(len(gaps) - len([g for g in gaps if g <= 1e3 * pause_s])),
        "relay_lag_p99_ms": _pct(lag, 0.99),
        "relay_lag_max_ms": lag[-1],
    }


class _Direction:
    """One direction of the line: a thread from ``src`` (a pty master) to ``dst`` (another)."""

    def __init__(self, relay: SerialRelay, name: str, src: int, dst: int, seed: int) -> None:
        self.relay = relay
        self.src, self.dst = src, dst
        self.stats = DirectionStats(name)
        self.rng = random.Random(seed)
        self.queue = bytearray()
        self.line_until = 0.0  # monotonic time through which the line has been used
        self.until_fault = self._draw_gap()
        self.on_line = 0  # bytes of the sender's stream the line has carried
        self.clock = FrameClock(relay.watch) if relay.watch else None
        self.thread = threading.Thread(target=self._run, name=f"serial-relay-{name}", daemon=True)

    def _draw_gap(self) -> int:
        """Bytes before the next faulty one (geometric, mean 1/p - 1); a huge gap when p = 0."""
        p = self.relay.drop + self.relay.corrupt
        if p <= 0.0:
            return sys.maxsize
        if p >= 1.0:
            return 0
        return int(math.log(1.0 - self.rng.random()) / math.log(1.0 - p))

    def apply_faults(self, data: bytes) -> bytes:
        """``data`` as the receiver gets it: dropped bytes removed, corrupted ones changed."""
        if self.until_fault >= len(data):
            self.until_fault -= len(data)
            return data
        out = bytearray()
        i = 0
        p = self.relay.drop + self.relay.corrupt
        while self.until_fault < len(data) - i:
            j = i + self.until_fault
            out += data[i:j]
            if self.rng.random() * p < self.relay.drop:
                self.stats.dropped += 1
            else:
                out.append(data[j] ^ self.rng.randrange(1, 256))
                self.stats.corrupted += 1
            i = j + 1
            self.until_fault = self._draw_gap()
        self.until_fault -= len(data) - i
        out += data[i:]
        return bytes(out)

    def _count_line(self, n: int, now: float) -> None:
        st = self.stats
        st.line += n
        if math.isnan(st.first_s):
            st.first_s = now
        st.last_s = now
        sec = int(now - self.relay.started_s)
        while len(st.per_second) <= sec:
            st.per_second.append(0)
        st.per_second[sec] += n

    def _deliver(self, now: float) -> None:
        byte_s = self.relay.byte_time_s
        n = min(len(self.queue), int((now - self.line_until) / byte_s + 1e-9))
        if n <= 0:
            return
        chunk = bytes(self.queue[:n])
        del self.queue[:n]
        base_s, base_offset = self.line_until, self.on_line
        self.line_until += n * byte_s
        self._count_line(n, now)
        self.on_line += n
        if self.clock is not None:
            self.clock.on_delivered(self.on_line, now, base_offset, base_s, byte_s)
        data = self.apply_faults(chunk)
        while data:
            try:
                k = os.write(self.dst, data)
            except BlockingIOError:
                self.stats.overrun += len(data)  # the receiver is not reading: lost, as a UART overruns
                return
            except OSError as err:
                if err.errno == errno.EIO:  # nobody holds the other side (closing)
                    return
                raise
            self.stats.delivered += k
            data = data[k:]

    def _run(self) -> None:
        relay = self.relay
        while not relay.stopping.is_set():
            now = time.monotonic()
            self._deliver(now)
            wait = max(MIN_WAIT_S, self.line_until + relay.byte_time_s - now) if self.queue else IDLE_WAIT_S
            readers = [self.src] if len(self.queue) < relay.queue_limit else []
            try:
                ready, _, _ = select.select(readers, [], [], wait)
            except (OSError, ValueError):  # closed under us at stop
                return
            if not ready:
                continue
            try:
                data = os.read(self.src, min(READ_CHUNK, relay.queue_limit - len(self.queue)))
            except BlockingIOError:
                continue
            except OSError as err:
                if err.errno == errno.EIO or relay.stopping.is_set():
                    time.sleep(IDLE_WAIT_S)  # no sender holds its side (yet): nothing to relay
                    continue
                raise
            if not data:
                continue
            now = time.monotonic()
            if not self.queue:
                self.line_until = max(self.line_until, now)  # an idle line starts now
            self.queue += data
            self.stats.read += len(data)
            if self.clock is not None:
                self.clock.on_read(data, now)
            self.stats.max_backlog = max(self.stats.max_backlog, len(self.queue))


class SerialRelay:
    """Two pty pairs and the paced relay between them. Use as a context manager.

    ``autopilot_device`` and ``companion_device`` are the slave paths to give each side;
    ``to_companion`` and ``to_autopilot`` the counters of each direction. ``baud`` 921600 with
    ``bits_per_byte`` 10 (8N1) is 92160 bytes/s each way.
    """

    def __init__(
        self,
        baud: int = 921600,
        drop: float = 0.0,
        corrupt: float = 0.0,
        seed: int = 0,
        bits_per_byte: int = BITS_PER_BYTE_8N1,
        queue_limit: int = DEFAULT_QUEUE_LIMIT,
        watch: tuple[int, ...] = (),
    ) -> None:
        if baud <= 0:
            raise SerialRelayError(f"baud {baud}: expected a positive rate")
        if bits_per_byte < 1:
            raise SerialRelayError(f"bits_per_byte {bits_per_byte}: expected at least 1")
        for what, v in (("drop", drop), ("corrupt", corrupt)):
            if not 0.0 <= v <= 1.0:
                raise SerialRelayError(f"{what} {v}: expected a fraction of the bytes, 0..1")
        if drop + corrupt > 1.0:
            raise SerialRelayError(f"drop + corrupt = {drop + corrupt}: more than every byte")
        if queue_limit < 1:
            raise SerialRelayError(f"queue_limit {queue_limit}: expected at least 1 byte")
        self.baud = baud
        self.bits_per_byte = bits_per_byte
        self.drop, self.corrupt, self.seed = drop, corrupt, seed
        self.queue_limit = queue_limit
        self.watch = frozenset(watch)  # MAVLink message ids timed on the line, each way (frame_times)
        self.stopping = threading.Event()
        self.started_s = math.nan
        self._fds: list[int] = []
        self._dirs: list[_Direction] = []
        self.autopilot_device = ""
        self.companion_device = ""

    @property
    def byte_time_s(self) -> float:
        return self.bits_per_byte / self.baud

    @property
    def bytes_per_s(self) -> float:
        """The line's capacity each way."""
        return self.baud / self.bits_per_byte

    @property
    def to_companion(self) -> DirectionStats:
        return self._dirs[0].stats

    @property
    def to_autopilot(self) -> DirectionStats:
        return self._dirs[1].stats

    def frame_times(self, direction: str) -> list[FrameTime]:
        """The watched frames delivered so far in ``direction`` ("to_companion", "to_autopilot")."""
        for d in self._dirs:
            if d.stats.name == direction:
                return list(d.clock.frames) if d.clock is not None else []
        raise ValueError(f"direction {direction!r}: expected 'to_companion' or 'to_autopilot'")

    def start(self) -> SerialRelay:
        try:
            ap_master, ap_slave = os.openpty()
            co_master, co_slave = os.openpty()
        except OSError as err:
            raise SerialRelayError(f"no pseudo-terminal: {err}") from None
        # the slaves stay open here: a pty master reads EIO while no one holds its slave, and the
        # raw settings stay with the pty until the last holder closes it
        self._fds = [ap_master, ap_slave, co_master, co_slave]
        for fd in (ap_slave, co_slave):
            make_raw(fd)
        for fd in (ap_master, co_master):
            os.set_blocking(fd, False)
        self.autopilot_device = os.ttyname(ap_slave)
        self.companion_device = os.ttyname(co_slave)
        self.started_s = time.monotonic()
        self._dirs = [
            _Direction(self, "to_companion", ap_master, co_master, self.seed),
            _Direction(self, "to_autopilot", co_master, ap_master, self.seed + 1),
        ]
        for d in self._dirs:
            d.thread.start()
        return self

    def stop(self) -> None:
        self.stopping.set()
        for d in self._dirs:
            d.thread.join(timeout=2.0)
        for fd in self._fds:
            with contextlib.suppress(OSError):
                os.close(fd)
        self._fds = []

    def __enter__(self) -> SerialRelay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def report(self) -> str:
        """One line per direction: bytes, rate over the active time, peak second, faults."""
        lines = []
        for st in (self.to_companion, self.to_autopilot):
            span = st.last_s - st.first_s if st.line else 0.0
            mean = st.line / span if span > 0 else 0.0
            lines.append(
                f"{st.name:>12}: {st.line} bytes, {mean:.0f} B/s mean, {st.peak_bytes_per_s} B/s peak "
                f"({100 * st.peak_bytes_per_s / self.bytes_per_s:.1f} % of {self.bytes_per_s:.0f}); "
                f"dropped {st.dropped}, corrupted {st.corrupted}, overrun {st.overrun}, "
                f"backlog max {st.max_backlog}"
            )
        return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m companion_lab.serial_relay", description=__doc__.split("\n")[0])
    ap.add_argument("--baud", type=int, default=921600, help="the line's baud rate (default 921600)")
    ap.add_argument("--drop", type=float, default=0.0, help="fraction of the bytes dropped (default 0)")
    ap.add_argument("--corrupt", type=float, default=0.0, help="fraction of the bytes corrupted (default 0)")
    ap.add_argument("--seed", type=int, default=0, help="the faults' random seed (default 0)")
    ap.add_argument("--report-s", type=float, default=5.0, help="seconds between counter lines (default 5)")
    ap.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (default 0: Ctrl-C)")
    args = ap.parse_args(argv)
    try:
        relay = SerialRelay(args.baud, args.drop, args.corrupt, args.seed).start()
    except SerialRelayError as e:
        print(f"serial_relay: {e}", file=sys.stderr)
        return 2
    ap_dev, co_dev = relay.autopilot_device, relay.companion_device
    print(f"autopilot side: {ap_dev}  (ArduCopter SITL: --serial2 uart:{ap_dev}:{args.baud})")
    print(f'companion side: {co_dev}  (connection = "serial://{co_dev}:{args.baud}")')
    print(f"line: {args.baud} baud, {relay.bytes_per_s:.0f} bytes/s each way", flush=True)
    end = time.monotonic() + args.duration if args.duration > 0 else math.inf
    try:
        while time.monotonic() < end:
            relay.stopping.wait(max(0.0, min(args.report_s, end - time.monotonic())))
            print(relay.report(), flush=True)
    except KeyboardInterrupt:
        pass
    finally:
        relay.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
