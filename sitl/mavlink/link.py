"""The MAVLink 2 UDP endpoint of the sim vehicle: socket, real-time thread, parsing, sending, signing.

The vehicle sends to a configured remote address (as PX4 SITL sends to 14540) and to every
peer it has heard from. Malformed bytes on the socket are counted and ignored.

MAVLink 2 signing (ArduPilot dialect), as ArduPilot's GCS_Signing.cpp: SETUP_SIGNING stores the
key (refused while armed, with "ERROR: Won't setup signing when armed"), the vehicle's timestamp
starts 60 s past the pushed one (raised to the clock, as ArduPilot does on a GPS fix), and from then
on every packet it sends is signed and unsigned or wrongly signed packets are dropped, except
RADIO_STATUS and RADIO, or everything on a ``trusted_link`` (ArduPilot's channel 0: USB, SITL TCP
5760). The all-zero key with timestamp 0 turns signing off. ``signing_key`` starts with a key.
"""

from __future__ import annotations

import abc
import logging
import os
import select
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Self

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.signing import (
    AP_KEY_LOAD_OFFSET,
    KEY_LEN,
    accept_everything,
    accept_unsigned_ardupilot,
    clock_timestamp,
)
from companion_sitl.params import SimConfig
from companion_sitl.vehicle import SimVehicle

log = logging.getLogger(__name__)


@dataclass
class LinkStats:
    """What the vehicle's MAVLink endpoint saw (read from any thread; counters only grow)."""

    datagrams_in: int = 0
    messages_in: int = 0
    bad_data: int = 0  # malformed packets (bad prefix, CRC, length)
    garbage_bytes: int = 0
    messages_out: int = 0
    send_errors: int = 0
    setpoints: int = 0
    setpoints_rejected: int = 0
    landing_targets: int = 0
    signature_rejects: int = 0  # dropped by the signing check (unsigned, or another key)
    signed_in: int = 0  # accepted with a verified signature
    handle_errors: int = 0  # accepted messages whose handling raised (logged, dropped)
    commands: Counter[int] = field(default_factory=Counter)
    unsupported_commands: Counter[int] = field(default_factory=Counter)
    by_type_in: Counter[str] = field(default_factory=Counter)


class PacketWriter:
    """File-like sink for pymavlink's encoder: collects the bytes of one message."""

    def __init__(self) -> None:
        self.data = b""

    def write(self, b: bytes) -> None:
        self.data += b


def free_udp_port() -> int:
    """A currently free UDP port on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class MavlinkLink(abc.ABC):
    """The endpoint's state and its real-time loop; the layers above decide what is sent and how
    a received message is handled (:meth:`_handle`). The state is set by the vehicle's ``__init__``."""

    dialect: str
    SIGNING: ClassVar[bool] = False  # handles SETUP_SIGNING and signs (the ArduPilot dialect)
    cfg: SimConfig
    vehicle: SimVehicle
    system_id: int
    component_id: int
    stats: LinkStats
    remote: tuple[str, int] | None
    peers: list[tuple[str, int]]
    lock: threading.RLock  # held while the vehicle is stepped or commanded
    trusted_link: bool
    route_peers: bool
    _rx_addr: tuple[str, int] | None
    on_message: Callable[[Any], None] | None  # test hook: every decoded message
    _bind: tuple[str, int]
    _sock: socket.socket | None
    _thread: threading.Thread | None
    _running: bool
    _link_up: bool
    _t0: float
    _enc: mavlink.MAVLink
    _rx: mavlink.MAVLink

    @abc.abstractmethod
    def _handle(self, m: Any) -> None:
        """Act on one decoded message (the vehicle stepped to now, the lock held)."""

    @abc.abstractmethod
    def _rc_switch(self, now: float) -> None:
        """The autopilot reads the pilot's RC (mode switch, sticks), every tick."""

    @abc.abstractmethod
    def _send_due(self, now: float) -> None:
        """Send what is due at ``now`` (heartbeat, streams, texts), every tick."""

    def _failsafes(self, now: float) -> None:
        """The autopilot's own failsafes that watch its peers (ArduCopter's GCS failsafe), every tick."""
        return None  # optional hook: this dialect has none beyond the vehicle's offboard loss

    # ------------------------------------------------------------------ signing
    @property
    def signing_key(self) -> bytes | None:
        """The key the vehicle signs with (None: not signing)."""
        key = self._rx.signing.secret_key
        return bytes(key) if key is not None else None

    def _set_signing(self, key: bytes, initial_timestamp: int) -> None:
        """ArduPilot's load_signing_key: the all-zero key with timestamp 0 turns signing off."""
        if len(key) != KEY_LEN:
            raise ValueError(f"signing key: {KEY_LEN} bytes expected, got {len(key)}")
        sig = self._rx.signing
        if initial_timestamp == 0 and not any(key):
            sig.secret_key = None
            sig.sign_outgoing = False
            sig.allow_unsigned_callback = None
            log.info("sim vehicle: signing off")
            return
        sig.secret_key = bytes(key)
        sig.link_id = 0  # ArduPilot: its channel number
        sig.sign_outgoing = True
        sig.allow_unsigned_callback = accept_everything if self.trusted_link else accept_unsigned_ardupilot
        # 60 s past the stored timestamp, then up to the GPS clock (update_signing_timestamp)
        # (a second SETUP_SIGNING with the same timestamp turns it back, as on ArduPilot)
        sig.timestamp = max(initial_timestamp + AP_KEY_LOAD_OFFSET, clock_timestamp())
        log.info("sim vehicle: signing on")

    def _setup_signing(self, m: Any) -> None:
        if not self.SIGNING or m.target_system not in (0, self.system_id):
            return
        if self.vehicle.armed:
            self._statustext("ERROR: Won't setup signing when armed", mavlink.MAV_SEVERITY_WARNING)
            return
        self._set_signing(bytes(m.secret_key), int(m.initial_timestamp))

    # ------------------------------------------------------------------ lifecycle
    @property
    def address(self) -> tuple[str, int]:
        if self._sock is None:
            raise RuntimeError("vehicle not started")
        host, port = self._sock.getsockname()[:2]
        return host, port

    @property
    def running(self) -> bool:
        """Started and not stopped: the vehicle's clock runs."""
        return self._thread is not None

    @property
    def now(self) -> float:
        """Vehicle time: seconds since :meth:`start` (the vehicle's boot)."""
        return time.monotonic() - self._t0

    def start(self) -> Self:
        if self._thread is not None:
            return self
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(self._bind)
        sock.setblocking(False)
        self._sock = sock
        self._t0 = time.monotonic() - self.vehicle.time_s
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"mavlink-sim-{self.dialect}", daemon=True)
        self._thread.start()
        log.info("MAVLink %s sim vehicle on udp %s:%d -> %s", self.dialect, *self.address, self.remote)
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_link(self, up: bool) -> None:
        """Test hook: cut (both directions) or restore the radio link."""
        self._link_up = up

    # ------------------------------------------------------------------ main loop
    def _run(self) -> None:
        v = self.vehicle
        dt = 1.0 / self.cfg.vehicle.physics_rate_hz
        assert self._sock is not None
        sock = self._sock
        next_tick = self.now
        while self._running:
            timeout = next_tick - self.now
            if timeout > 0:
                try:
                    ready, _, _ = select.select([sock], [], [], timeout)
                except (OSError, ValueError):
                    break
                if ready:
                    self._drain(sock)
                    continue
            now = self.now
            with self.lock:
                v.step_to(now)
                self._rc_switch(now)
                self._failsafes(now)
                self._send_due(now)
            next_tick = max(next_tick + dt, now - dt)

    def _drain(self, sock: socket.socket) -> None:
        for _ in range(64):
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as err:  # e.g. ICMP port unreachable from a peer that went away
                log.debug("recv error: %s", err)
                return
            if not self._link_up:
                continue
            self.stats.datagrams_in += 1
            if addr not in self.peers:
                self.peers.append(addr)
                if len(self.peers) > 8:
                    del self.peers[0]
            self._rx_addr = addr
            self._parse(data)

    def _parse(self, data: bytes) -> None:
        rx = self._rx
        try:
            msgs = rx.parse_buffer(data) or []
        except Exception as err:
            self.stats.bad_data += 1
            self.stats.garbage_bytes += len(data)
            log.debug("unparseable datagram (%d bytes): %s", len(data), err)
            msgs = []
        if rx.buf_len() > 0:  # a datagram holds whole packets: leftovers are garbage
            self.stats.garbage_bytes += rx.buf_len()
            self.stats.bad_data += 1
            rx.buf = bytearray()
            rx.buf_index = 0
            rx.expected_length = mavlink.HEADER_LEN_V1 + 2
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                if getattr(m, "reason", "") == "Invalid signature":
                    self.stats.signature_rejects += 1
                    continue
                self.stats.bad_data += 1
                self.stats.garbage_bytes += len(m.data)
                continue
            if m.get_srcSystem() == self.system_id and m.get_srcComponent() == self.component_id:
                continue
            self.stats.messages_in += 1
            self.stats.signed_in += m.get_signed()
            if self.route_peers:
                self._route(m)
            if self.on_message is not None:
                self.on_message(m)
            try:
                with self.lock:
                    self.vehicle.step_to(self.now)
                    self._handle(m)
            except Exception:
                self.stats.handle_errors += 1
                log.exception("error handling %s", m.get_type())
            # counted once handled: a reader that sees the count sees the message's effect
            self.stats.by_type_in[m.get_type()] += 1

    def _route(self, m: Any) -> None:
        """Forward ``m`` to the peers other than its sender, unless it is addressed to the vehicle
        (PX4's Mavlink::forward_message, ArduPilot's MAVLink_routing)."""
        if getattr(m, "target_system", None) == self.system_id and getattr(m, "target_component", None) in (
            self.component_id,
        ):
            return
        buf = m.get_msgbuf()
        for addr in list(self.peers):
            if addr != self._rx_addr and self._sock is not None:
                try:
                    self._sock.sendto(buf, addr)
                except OSError:
                    self.stats.send_errors += 1

    # ------------------------------------------------------------------ sending
    def _send(self, msg: Any) -> None:
        if not self._link_up or self._sock is None:
            return
        w = self._enc.file
        w.data = b""
        self._enc.send(msg)
        buf = w.data
        targets = list(self.peers)
        if self.remote is not None and self.remote not in targets:
            targets.append(self.remote)
        for addr in targets:
            try:
                self._sock.sendto(buf, addr)
            except OSError:
                self.stats.send_errors += 1
        self.stats.messages_out += 1

    def _statustext(self, text: str, severity: int) -> None:
        self._send(self._enc.statustext_encode(severity, text[:50].encode()))

    def _ack(self, command: int, result: int, m: Any) -> None:
        self._send(self._enc.command_ack_encode(command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))
