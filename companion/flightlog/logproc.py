"""The logging process's client: each process that opens a flight log starts, lazily at the first
log, one child process that formats and writes the logs on another core
(:mod:`companion.flightlog.logproc_child`, a fresh interpreter: no fork of a threaded parent).

Formatting rows in the flight's own process, even on a writer thread, competes for the GIL with
the control loop (``companion bench log``). The flight's logs still queue their rows; the shared
writer thread (:class:`~companion.flightlog.handover.SharedWriter`) posts each log's batch here
(:meth:`LogProcess.post`) and, once a round, sends everything posted as one message
(:func:`flush_current`). Closing a log is a request: it returns once the child has closed the file
and answered with its counts.

Batches are sent as soon as they are posted, also while the child is still starting: the socket
holds them until it reads them. A parent killed with ``kill -9`` (even before the child is ready)
loses only the rows it had not handed over yet (at most one flush period): the child sees its
socket close, writes everything it was sent and closes its files. If the child cannot be started,
or dies (a failed send, an answer that does not come, no ready message within
:data:`START_TIMEOUT_S`), every log continues in the parent (the in-process path), said once at
ERROR level with the reason; the batches not yet sent are written there, and so are those sent
before the child said it was ready (it never read them). Set :data:`IN_PROCESS` (or
``COMPANION_LOG_IN_PROCESS=1``) to write in process from the start.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import select
import socket
import subprocess
import sys
import threading
import time
from collections import defaultdict
from pathlib import Path
from typing import Any, ClassVar

from companion.flightlog.logproc_wire import HEADER, Op, recv
from companion.flightlog.losses import LossCause, note_fault

log = logging.getLogger(__name__)

ENV_IN_PROCESS = "COMPANION_LOG_IN_PROCESS"
IN_PROCESS: bool = os.environ.get(ENV_IN_PROCESS, "") not in ("", "0")
"""Write the logs in this process (no logging process). Read when a log is opened."""

CHILD_COMMAND = [sys.executable, "-m", "companion.flightlog.logproc_child"]  # + the socket's fd
START_TIMEOUT_S = 30.0  # for the child to import and say it is ready (a loaded CI machine)
REPLY_TIMEOUT_S = 60.0  # for any send or answer (closing a log whose last batch holds images)


def _plain(op: Op) -> Op:
    """A rows op whose cells pickle: anything that does not becomes its ``str`` (what the CSV
    writer writes for it)."""
    if op[0] != "rows":
        return op

    def cell(v: object) -> object:
        try:
            pickle.dumps(v, protocol=5)
        except Exception:
            return str(v)
        return v

    return (op[0], op[1], [tuple(cell(v) for v in row) for row in op[2]])


class _Unpicklable(Exception):
    """A batch that cannot be handed over: written in process instead."""


class LogProcess:
    """The parent's end of its logging process (one per process; see the module doc).
    Thread-safe: the writer thread and ``close()`` on other threads take turns on the socket."""

    _current: ClassVar[LogProcess | None] = None
    _failed_pid: ClassVar[int | None] = None  # this process could not start one: do not retry
    _class_lock = threading.Lock()

    def __init__(self) -> None:
        parent, child = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            env = dict(os.environ)
            root = str(Path(__file__).resolve().parents[2])  # where the companion package is
            env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH", "")) if p)
            self.child = subprocess.Popen(
                [*CHILD_COMMAND, str(child.fileno())],
                pass_fds=(child.fileno(),),
                stdin=subprocess.DEVNULL,
                env=env,
            )
        except BaseException:
            parent.close()
            raise
        finally:
            child.close()
        parent.settimeout(REPLY_TIMEOUT_S)
        self._sock: socket.socket | None = parent
        self._lock = threading.Lock()
        self._outbox: list[Op] = []
        self._next_id = 0
        self.ready = False  # the child said it is ready (it reads what it is sent from then on)
        self._started_s = time.monotonic()
        self._unconfirmed: list[Op] = []  # sent before the child said it is ready
        self.dead = False
        self.reason = ""
        self._returned: dict[int, list[Op]] = defaultdict(list)
        self.pid = os.getpid()

    # ---- the registry ----------------------------------------------------------------------
    @classmethod
    def get(cls) -> LogProcess | None:
        """This process's logging process, started at the first call; None when logging in
        process (:data:`IN_PROCESS`, or it could not be started: said once)."""
        if IN_PROCESS:
            return None
        cur = cls._current
        if cur is not None and cur.pid == os.getpid() and not cur.dead:
            return cur
        if cls._failed_pid == os.getpid():
            return None
        with cls._class_lock:
            cur = cls._current
            if cur is not None and cur.pid == os.getpid() and not cur.dead:
                return cur
            if cur is not None and cur.dead:
                return None  # it died: the logs opened from now on write in process too
            try:
                cls._current = cur = LogProcess()
            except Exception as err:
                cls._failed_pid = os.getpid()
                log.error("flight logs: cannot start the logging process (%s); writing in this process", err)
                return None
            return cur

    @classmethod
    def _forget_after_fork(cls) -> None:
        """A forked child must not touch its parent's socket (closing its copy lets the parent's
        logging process see the end); its logs start a logging process of their own."""
        cur = cls._current
        if cur is not None:
            cur.dead = True  # logs inherited from the parent: in-process from here (if ever used)
            cur.reason = "inherited from the parent process"
            if cur._sock is not None:
                cur._sock.close()
                cur._sock = None
        cls._current = None
        cls._failed_pid = None
        cls._class_lock = threading.Lock()

    # ---- the logs' side ---------------------------------------------------------------------
    def new_id(self) -> int:
        with self._lock:
            self._next_id += 1
            return self._next_id

    def open_csv(self, path: Path, columns: tuple[str, ...], sink_key: tuple[int, str] | None) -> int:
        i = self.new_id()
        self.post(("csv", i, str(path), columns, sink_key))
        return i

    def open_mcap(self, path: Path, streams: dict[str, tuple[str, ...]]) -> int:
        i = self.new_id()
        self.post(("mcap", i, str(path), streams))
        return i

    def post(self, op: Op) -> bool:
        """Queue an op for the next send; False when the process is gone (write in process)."""
        with self._lock:
            if self.dead:
                return False
            self._outbox.append(op)
            return True

    def take_returned(self, log_id: int) -> list[Op]:
        """The ops of a log that were never sent (the process died first), oldest first."""
        with self._lock:
            return self._returned.pop(log_id, [])

    def flush(self) -> None:
        """Send what was posted (one message), and log what the child said."""
        with self._lock:
            if self.dead:
                return
            if self._outbox:
                ops, self._outbox = self._outbox, []
                self._send_ops(ops)
            if not self.dead:
                try:
                    self._read_available()
                except (OSError, EOFError, pickle.UnpicklingError) as err:
                    self._die(f"closed its end ({err})", [])

    def request(self, op: Op) -> Any:
        """Send what was posted and ``op``, and wait for the child's answer (None: the process
        is gone; the caller continues in process)."""
        return self.request_all([op])[0]

    def request_all(self, ops: list[Op]) -> list[Any]:
        """Send what was posted and ``ops`` (each answered by the child) in one message, and wait
        for every answer: one per op, in order, None for the ops the process did not answer
        (it is gone; their callers continue in process)."""
        replies: list[Any] = []
        with self._lock:
            out, self._outbox = [*self._outbox, *ops], []
            if not self.dead and self._send_ops(out):
                try:
                    while len(replies) < len(ops):
                        msg = recv(self._sock)  # type: ignore[arg-type]
                        if msg[0] == "reply":
                            replies.append(msg[1])
                        else:
                            self._handle(msg)
                except (OSError, EOFError, pickle.UnpicklingError) as err:
                    self._die(f"did not answer ({err or type(err).__name__})", ops[len(replies) :])
        return replies + [None] * (len(ops) - len(replies))

    def cpu_s(self) -> float | None:
        """The logging process's CPU time so far (user + system), for ``companion bench log``."""
        return self.request(("cpu",))  # type: ignore[no-any-return]

    # ---- the socket (caller holds _lock) -------------------------------------------------------
    def _send_ops(self, ops: list[Op]) -> bool:
        sock = self._sock
        assert sock is not None
        try:
            if not self.ready:
                self._read_available()  # its ready message, if it has come
                if not self.ready and self.child.poll() is not None:
                    raise EOFError("exited before it was ready")
                left_s = START_TIMEOUT_S - (time.monotonic() - self._started_s)
                if not self.ready and left_s <= 0.0:
                    raise EOFError(f"no ready message in {START_TIMEOUT_S:g} s")
                # a child that never reads must not hold a send longer than its start may take
                sock.settimeout(REPLY_TIMEOUT_S if self.ready else max(0.1, left_s))
            try:
                data = pickle.dumps(ops, protocol=5)
            except Exception:
                try:
                    data = pickle.dumps([_plain(op) for op in ops], protocol=5)
                except Exception as err:  # not rows (a .tlog record of a class defined in a function...)
                    raise _Unpicklable(f"a batch does not pickle: {err}") from err
            sock.sendall(HEADER.pack(len(data)))
            sock.sendall(data)
            if not self.ready:
                self._unconfirmed.extend(ops)
        except _Unpicklable as err:
            self._die(str(err), ops)
            return False
        except (OSError, EOFError, pickle.UnpicklingError) as err:
            self._die(f"could not be sent a batch ({err or type(err).__name__})", ops)
            return False
        return True

    def _read_available(self) -> None:
        sock = self._sock
        while sock is not None and select.select([sock], [], [], 0)[0]:
            self._handle(recv(sock))

    def _handle(self, msg: Any) -> None:
        if msg[0] == "ready":
            self.ready = True
            self._unconfirmed = []
            if self._sock is not None:
                self._sock.settimeout(REPLY_TIMEOUT_S)
        elif msg[0] == "log":
            _, level, name, text = msg
            logging.getLogger(name).log(level, "%s", text)
        elif msg[0] == "fault":  # a file the child stopped writing (a full disk): said by its log
            note_fault(Path(msg[1]), LossCause[msg[2]])

    def _die(self, reason: str, unsent: list[Op]) -> None:
        """Give up on the child: every log continues in process (see the module doc)."""
        if not self.ready and self._sock is not None:
            with contextlib.suppress(OSError, EOFError, pickle.UnpicklingError):
                self._read_available()  # did it start (and so read what it was sent) after all?
        self.dead = True
        code = self.child.poll()
        if code is None:
            self.child.kill()  # a hung child must not write beside the in-process fallback
            try:
                code = self.child.wait(5.0)
            except subprocess.TimeoutExpired:
                code = None
        self.reason = f"{reason}; exit code {code}" if code is not None else reason
        never_read = [] if self.ready else self._unconfirmed
        self._unconfirmed = []
        for op in [*never_read, *unsent, *self._outbox]:
            if op[0] in ("rows", "mops", "trecs"):
                self._returned[op[1]].append(op)
        self._outbox = []
        if self._sock is not None:
            self._sock.close()
            self._sock = None
        log.error(
            "flight logs: the logging process (pid %d) %s; the logs are written in this process from now on",
            self.child.pid,
            self.reason,
        )

    def shutdown(self) -> None:
        """Close the socket (the child finishes its files and exits) and wait for the child."""
        with self._lock:
            self.dead = True
            self.reason = "shut down"
            if self._sock is not None:
                self._sock.close()
                self._sock = None
        try:
            self.child.wait(REPLY_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            log.error("flight logs: the logging process (pid %d) did not exit; killed", self.child.pid)
            self.child.kill()


def client() -> LogProcess | None:
    """The logging process a new log should use (None: write in this process)."""
    return LogProcess.get()


def flush_current() -> None:
    """Send what the logs posted (the shared writer thread, after each round)."""
    cur = LogProcess._current
    if cur is not None and cur.pid == os.getpid():
        cur.flush()


def shutdown_current() -> None:
    """Let this process's logging process finish its files and exit (at interpreter exit, once
    every log is closed: :mod:`companion.flightlog.registry`)."""
    cur = LogProcess._current
    if cur is not None and cur.pid == os.getpid():
        cur.shutdown()


os.register_at_fork(after_in_child=LogProcess._forget_after_fork)
