"""The open flight logs, and the one close at interpreter exit.

Every front-end registers itself here when it opens and is forgotten when it closes. Logs still
open when the interpreter exits (an uncaught exception, Ctrl-C) are closed by one ``atexit`` hook,
in an order that loses nothing: the CSV logs first (their last batches reach the MCAP), then the
MCAP files, then the ``.tlog`` files, and last the logging process is let finish its files and
exit.
"""

from __future__ import annotations

import atexit
import enum
import logging
import weakref
from typing import Protocol

from companion.flightlog.logproc import shutdown_current

log = logging.getLogger(__name__)


class Closable(Protocol):
    def close(self) -> None: ...


class CloseOrder(enum.IntEnum):
    """When an open log is closed at exit, lowest first."""

    CSV = 0
    MCAP = 1
    TLOG = 2


_OPEN: dict[CloseOrder, weakref.WeakSet[Closable]] = {order: weakref.WeakSet() for order in CloseOrder}


def register(log: Closable, order: CloseOrder) -> None:
    """``log`` is open: close it at exit unless :func:`forget` is called first."""
    _OPEN[order].add(log)


def forget(log: Closable, order: CloseOrder) -> None:
    """``log`` is closed (or closing)."""
    _OPEN[order].discard(log)


def close_open_logs() -> None:
    """Close every log still open, in :class:`CloseOrder`, then shut the logging process down
    (a log that fails to close is logged and does not keep the others open)."""
    for order in CloseOrder:
        for lg in list(_OPEN[order]):
            try:
                lg.close()
            except Exception:
                log.exception("flight logs: closing %s at exit failed", getattr(lg, "path", lg))
    shutdown_current()


atexit.register(close_open_logs)
