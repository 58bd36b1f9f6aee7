"""The logging process itself (``python -m companion.flightlog.logproc_child <socket fd>``),
started by :class:`~companion.flightlog.logproc.LogProcess`.

It writes each message's batches with the file formats the flight's process uses when logging in
process (:class:`~companion.flightlog.csv_file.CsvFile`,
:class:`~companion.flightlog.mcap_file.McapFile`,
:class:`~companion.flightlog.tlog_replay.TlogReplayer`), so the bytes are the same, and flushes
every MCAP after each message. numpy and foxglove are imported at the first MCAP, pymavlink at
the first ``.tlog``. Its own log records (a write error, named by path) are sent back and logged
by the parent under the same logger names, and a file that stops (its cause) is told to the
parent as a ``fault`` message (:mod:`companion.flightlog.losses`). It ignores SIGINT/SIGTERM and exits when its socket
closes, after writing everything it was sent and closing its files (the MCAP with its summary).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import sys
from pathlib import Path
from typing import Any

from companion.flightlog.csv_file import open_csv_file
from companion.flightlog.logproc_wire import Op, recv, send
from companion.flightlog.losses import set_forward

log = logging.getLogger(__name__)

FOXGLOVE_SINK_LOGGER = "foxglove.log_sink_set"  # the SDK's warnings about messages it could not write


class _Forward(logging.Handler):
    """The child's log records, sent to the parent (which logs them under the same names)."""

    def __init__(self, sock: socket.socket) -> None:
        super().__init__(logging.WARNING)
        self._sock = sock

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):  # the parent is gone: nobody to tell
            send(self._sock, ("log", record.levelno, record.name, self.format(record)))


class _First(logging.Filter):
    """Lets the first ``n`` records through: the MCAP SDK warns once per message it cannot log
    (a full disk: thousands); the file's own error line says the rest."""

    def __init__(self, n: int) -> None:
        super().__init__()
        self.left = n

    def filter(self, record: logging.LogRecord) -> bool:
        self.left -= 1
        return self.left >= 0


# the answer to a request the child failed to carry out: (written, dropped), (errors, messages)
# (written, dropped, encode errors)
_ANSWERED: dict[str, tuple[int, ...] | None] = {"close": (0, 0), "mclose": (1, 0), "tclose": (0, 0, 0), "cpu": None}


class _Child:
    """The logging process's files, by the parent's ids."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock = sock
        self.csvs: dict[int, Any] = {}
        self.mcaps: dict[int, Any] = {}
        self.tlogs: dict[int, Any] = {}

    def tell(self, msg: Any) -> None:
        """Send the parent ``msg``; a parent that is gone (killed) is not an error: the rows it
        sent are still to be written."""
        with contextlib.suppress(OSError):
            send(self.sock, msg)

    def run(self) -> None:
        self.tell(("ready", os.getpid()))
        try:
            while True:
                try:
                    ops = recv(self.sock)
                except EOFError:
                    break
                for op in ops:
                    try:
                        self.apply(op)
                    except Exception:
                        log.exception("logging process: %s op failed", op[0])
                        if op[0] in _ANSWERED:  # the parent waits for an answer: one saying it failed
                            self.tell(("reply", _ANSWERED[op[0]]))
                for m in self.mcaps.values():
                    m.flush()
        finally:
            self.finish()

    def apply(self, op: Op) -> None:
        kind = op[0]
        if kind == "rows":
            self.csvs[op[1]].write_batch(op[2])
        elif kind == "csv":
            _, i, path, columns, key = op
            sink = self.mcaps[key[0]].stream_sink(key[1]) if key is not None and key[0] in self.mcaps else None
            self.csvs[i] = open_csv_file(Path(path), tuple(columns), sink, append=True)
        elif kind == "close":
            f = self.csvs.pop(op[1])
            f.close()
            self.tell(("reply", (f.written, f.dropped)))
        elif kind == "mcap":
            from companion.flightlog.mcap_file import McapFile

            _, i, path, streams = op
            self.mcaps[i] = McapFile(Path(path), streams)
        elif kind == "mops":
            if op[1] in self.mcaps:  # else it could not be created (said then)
                self.mcaps[op[1]].apply(op[2])
        elif kind == "mclose":
            m = self.mcaps.pop(op[1])
            m.close()
            self.tell(("reply", (m.errors, m.messages)))
        elif kind == "trecs":
            if op[1] in self.tlogs:  # else it could not be opened (said then)
                self.tlogs[op[1]].apply(op[2])
        elif kind == "tlog":
            from companion.flightlog.tlog_replay import open_replayer

            _, i, path, params = op
            self.tlogs[i] = open_replayer(Path(path), params)
        elif kind == "tclose":
            t = self.tlogs.pop(op[1], None)
            if t is None:
                self.tell(("reply", _ANSWERED["tclose"]))
            else:
                t.close()
                self.tell(("reply", (t.written, t.dropped, t.encode_errors)))
        elif kind == "cpu":
            t = os.times()
            self.tell(("reply", t.user + t.system))
        else:
            raise ValueError(f"unknown op {kind!r}")

    def finish(self) -> None:
        """The parent is gone (or done): close every file it left open."""
        for f in self.csvs.values():
            f.close()
        for m in self.mcaps.values():
            m.close()
        for t in self.tlogs.values():
            t.close()
        self.csvs.clear()
        self.mcaps.clear()
        self.tlogs.clear()


def main(argv: list[str] | None = None) -> None:
    args = sys.argv[1:] if argv is None else argv
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is for the parent, which closes the logs
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the end is the socket closing
    # started from a real-time thread (runtime.realtime_priority), the policy is inherited: the
    # logs' formatting and I/O are not real-time work
    with contextlib.suppress(AttributeError, OSError):
        if os.sched_getscheduler(0) != os.SCHED_OTHER:
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    sock = socket.socket(fileno=int(args[0]))
    sock.setblocking(True)
    root = logging.getLogger()
    root.addHandler(_Forward(sock))
    root.setLevel(logging.WARNING)
    logging.getLogger(FOXGLOVE_SINK_LOGGER).addFilter(_First(3))
    child = _Child(sock)
    # a file that stops (a full disk) is the parent's to know at once: the flight reads it there
    set_forward(lambda path, cause: child.tell(("fault", str(path), cause.name)))
    child.run()


if __name__ == "__main__":
    main()
