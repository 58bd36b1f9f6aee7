"""The operator's signals in flight: SIGINT (Ctrl-C) and SIGTERM abort the mission (hold, then
land, then disarm: docs/flying.md) instead of killing the process mid-air. One place for `fly`,
`fly --orders`' flights and the demo."""

from __future__ import annotations

import asyncio
import contextlib
import signal
from collections.abc import Iterator
from typing import Protocol

from companion.delivery.mission.types import FailureKind

OPERATOR_ABORT = "operator abort"  # the abort reason a signal gives (exit 130 when it ended the flight)
SIGNALS = (signal.SIGINT, signal.SIGTERM)


class Abortable(Protocol):
    def abort(self, reason: str, kind: FailureKind = ...) -> None: ...


@contextlib.contextmanager
def abort_on_signals(shell: Abortable, loop: asyncio.AbstractEventLoop | None = None) -> Iterator[None]:
    """While inside: SIGINT and SIGTERM call ``shell.abort("operator abort (SIGINT)",
    FailureKind.OPERATOR_ABORT)`` on ``loop`` (the running one); the handlers are removed on the
    way out. Where the loop cannot take signal handlers (not the main thread), nothing changes."""
    loop = loop or asyncio.get_running_loop()
    for sig in SIGNALS:
        with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
            loop.add_signal_handler(
                sig, shell.abort, f"{OPERATOR_ABORT} ({signal.Signals(sig).name})", FailureKind.OPERATOR_ABORT
            )
    try:
        yield
    finally:
        for sig in SIGNALS:
            with contextlib.suppress(NotImplementedError, RuntimeError, ValueError):
                loop.remove_signal_handler(sig)
