"""MAVSDK itself, outside any one vehicle: its log lines routed to Python logging, the JSON
message interceptor the MAVLink log is written from, and the check of a MAVSDK connection URL."""

from __future__ import annotations

import contextlib
import ctypes
import logging
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

from companion.autopilot.interface import (
    ConnectionUrlError,
    LinkDeviceMissing,
    PacketSink,
    check_port,
)
from companion.autopilot.mavlink_messages import MavlinkPacker

log = logging.getLogger(__name__)


@dataclass
class InterceptCounters:
    """Messages MAVSDK handed to an interceptor: passed on, or dropped because the handler raised."""

    delivered: int = 0
    errors: int = 0


def deliver_intercepted(fn: Callable[[Any], bool | None], msg: Any, counters: InterceptCounters) -> int:
    """Hand one intercepted message to ``fn`` on MAVSDK's thread, where nothing may raise: a
    handler that raises drops the message from ``fn``, counted in ``counters.errors`` and logged
    (the first and every 1000th). Returns 1 (MAVSDK passes the message on) unless ``fn`` returned
    False: 0, and MAVSDK drops the message (an outgoing one is not sent)."""
    try:
        keep = fn(msg)
    except Exception as err:
        counters.errors += 1
        if counters.errors == 1 or counters.errors % 1000 == 0:
            why = f"{type(err).__name__}: {err}"
            log.warning("%d intercepted MAVLink message(s) dropped, the last: %s", counters.errors, why)
        return 1
    counters.delivered += 1
    return 0 if keep is False else 1


def message_logger(tlog: PacketSink) -> Callable[[Any], None]:
    """An interceptor writing each message MAVSDK decoded into ``tlog``, packed again from its
    name and fields JSON on the sink's writer thread (a packing failure is the sink's count)."""
    packer = MavlinkPacker()  # used on the writer thread only

    def log_message(msg: Any) -> None:
        name, fields = msg.message_name.decode(), msg.fields_json.decode()
        sysid, compid = msg.system_id, msg.component_id
        tlog.write(lambda: packer.pack_json(name, fields, sysid, compid))

    return log_message


def intercept_messages_json(
    mavsdk: Any, direction: str, fn: Callable[[Any], bool | None], counters: InterceptCounters | None = None
) -> Any:
    """Call ``fn`` with every MAVLink message MAVSDK receives (``direction="incoming"``) or sends
    (``"outgoing"``), decoded: a ``mavsdk.types.MavsdkMessage`` with ``message_name``,
    ``system_id``, ``component_id`` and ``fields_json``. Runs on MAVSDK's thread (or the sender's).

    The C library exports ``mavsdk_subscribe_{incoming,outgoing}_messages_json`` but the mavsdk 4
    Python binding does not wrap them, so they are called through ctypes. The message is passed on
    unless ``fn`` returns False (MAVSDK drops a message whose interceptor returns 0); one ``fn``
    raises on is counted in ``counters`` (:func:`deliver_intercepted`). Returns an unsubscribe
    function, or None if this MAVSDK build lacks the interface.
    """
    counts = counters if counters is not None else InterceptCounters()
    try:
        from mavsdk.cmavsdk_loader import _cmavsdk_lib as lib
        from mavsdk.types import InterceptJsonCallback
    except ImportError:
        return None
    sub = getattr(lib, f"mavsdk_subscribe_{direction}_messages_json", None)
    unsub = getattr(lib, f"mavsdk_unsubscribe_{direction}_messages_json", None)
    core = getattr(getattr(mavsdk, "_mavsdk", None), "_handle", None)
    if sub is None or unsub is None or not core:
        return None
    sub.argtypes = [ctypes.c_void_p, InterceptJsonCallback, ctypes.c_void_p]
    sub.restype = ctypes.c_void_p
    unsub.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    unsub.restype = None

    def trampoline(msg: Any, _user_data: Any) -> int:
        return deliver_intercepted(fn, msg, counts)

    cb = InterceptJsonCallback(trampoline)
    handle = sub(core, cb, None)
    if not handle:
        return None

    def unsubscribe(keep_alive: Any = cb) -> None:  # the C callback must outlive the subscription
        unsub(core, handle)

    return unsubscribe


_mavsdk_log = logging.getLogger("companion.autopilot.px4.mavsdk")  # what `companion -vv` shows
_MAVSDK_LOG_LEVELS = (logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR)  # mavsdk LogLevel 0..3
_mavsdk_log_routed = False
#: while a connect is waiting for the autopilot: MAVSDK's warnings and errors, kept for the error
#: message (and logged at debug) instead of printed one per retry
_connect_problems: list[str] | None = None


@contextlib.contextmanager
def collect_connect_problems() -> Iterator[list[str]]:
    """While a connect waits for the autopilot: MAVSDK's warnings and errors go into the list
    yielded (for the error message) instead of being printed once per retry."""
    global _connect_problems
    problems: list[str] = []
    _connect_problems = problems
    try:
        yield problems
    finally:
        _connect_problems = None


def route_mavsdk_log() -> None:
    """Send MAVSDK's own log lines (its C++ core prints them to stderr) to Python logging, logger
    ``companion.autopilot.px4.mavsdk``, so ``-v`` shows them and a failed start-up prints only
    its one error line. Once per process."""
    global _mavsdk_log_routed
    if _mavsdk_log_routed:
        return
    from mavsdk.logging import log_subscribe

    def on_log(level: Any, message: str, file: str | None, line: int) -> bool:
        lvl = _MAVSDK_LOG_LEVELS[min(max(int(level), 0), 3)]
        problems = _connect_problems
        if problems is not None and lvl >= logging.WARNING:
            problems.append(message)
            lvl = logging.DEBUG
        _mavsdk_log.log(lvl, "%s (%s:%d)", message, file or "?", line)
        return True  # handled: MAVSDK does not print it

    log_subscribe(on_log)
    _mavsdk_log_routed = True


def check_connection_url(url: str) -> str:
    """Validate a MAVSDK connection URL; a serial device must exist. Returns the URL."""
    u = url.strip()
    scheme, sep, rest = u.partition("://")
    if not sep:
        raise ConnectionUrlError(
            f"connection {url!r}: expected a MAVSDK URL (udpin://HOST:PORT, udpout://, tcpout://, serial:///dev/X:BAUD)"
        )
    if scheme == "serial":
        dev = rest.rsplit(":", 1)[0] if rest.rsplit(":", 1)[-1].isdigit() else rest
        if not os.path.exists(dev):
            raise LinkDeviceMissing(f"serial device {dev} does not exist (connection {url!r})")
    elif scheme not in ("udp", "udpin", "udpout", "tcp", "tcpin", "tcpout", "raw"):
        raise ConnectionUrlError(f"connection {url!r}: unknown scheme {scheme!r}")
    elif scheme != "raw":
        _host, colon, port = rest.rpartition(":")
        if not colon:
            raise ConnectionUrlError(f"connection {url!r}: expected {scheme}://HOST:PORT")
        check_port(url, port)
    return u
