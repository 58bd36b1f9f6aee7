"""A UDP relay between an autopilot and the companion that can cut the link (a radio or cable
dropping out), for link-loss tests on the real firmware.

PX4 SITL sends its onboard MAVLink link to a fixed port (14540); the relay listens there and
forwards everything to the port the companion listens on, and the companion's replies back to
wherever the autopilot sent from. While cut, datagrams in both directions are dropped (counted),
as a dead radio would. With ``watch_commands`` the relay also decodes what the companion sends and
keeps the COMMAND_LONG / COMMAND_INT command ids that reached the autopilot (a test's proof that a
release command was, or was not, sent).
"""

from __future__ import annotations

import logging
import select
import socket
import threading
import time
from typing import Any

from pymavlink import mavutil

log = logging.getLogger(__name__)


class UdpRelay:
    def __init__(self, listen_port: int, forward_port: int, host: str = "127.0.0.1", watch_commands: bool = False):
        self.host = host
        self.listen_port = listen_port
        self.forward = (host, forward_port)
        self._a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # autopilot side (bound at start)
        self._b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # companion side
        self._autopilot: tuple[str, int] | None = None
        self._cut_until = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="udp-relay", daemon=True)
        self.forwarded = 0
        self.dropped = 0
        # (monotonic s, command id) of every COMMAND_LONG / COMMAND_INT forwarded to the autopilot
        self.commands_to_autopilot: list[tuple[float, int]] = []
        self._parser: Any = mavutil.mavlink.MAVLink(None) if watch_commands else None
        if self._parser is not None:
            self._parser.robust_parsing = True

    def start(self) -> UdpRelay:
        self._a.bind((self.host, self.listen_port))
        self._b.bind((self.host, 0))
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._a.close()
        self._b.close()

    def __enter__(self) -> UdpRelay:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def cut(self, seconds: float) -> None:
        """Drop everything, both ways, for ``seconds`` from now."""
        self._cut_until = time.monotonic() + seconds
        log.info("link cut for %.1f s", seconds)

    @property
    def is_cut(self) -> bool:
        return time.monotonic() < self._cut_until

    def _run(self) -> None:
        while not self._stop.is_set():
            ready, _, _ = select.select([self._a, self._b], [], [], 0.1)
            for s in ready:
                try:
                    data, addr = s.recvfrom(65535)
                except OSError:
                    continue
                if s is self._a:
                    self._autopilot = addr
                    dest: tuple[str, int] | None = self.forward
                    out = self._b
                else:
                    dest = self._autopilot
                    out = self._a
                if self.is_cut or dest is None:
                    self.dropped += 1
                    continue
                try:
                    out.sendto(data, dest)
                    self.forwarded += 1
                except OSError as err:
                    log.debug("relay: %s", err)
                    continue
                if s is self._b and self._parser is not None:
                    self._watch(data)

    def _watch(self, data: bytes) -> None:
        try:
            msgs = self._parser.parse_buffer(data) or []
        except Exception as err:  # a packet pymavlink cannot decode (unknown or signed): not a command we know
            log.debug("relay: undecoded packet: %s", err)
            return
        for m in msgs:
            if m.get_type() in ("COMMAND_LONG", "COMMAND_INT"):
                self.commands_to_autopilot.append((time.monotonic(), int(m.command)))
