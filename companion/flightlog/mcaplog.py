"""The flight as one MCAP file (``flight.mcap``) beside the CSVs, for Foxglove: the flight's side
(:class:`McapFlightLog`, owned by the :class:`~companion.flightlog.recorder.FlightRecorder`).

Nothing is encoded on the control path, nor (by default) in the flight's process: the file is
written by the logging process (:mod:`companion.flightlog.logproc`) with
:class:`~companion.flightlog.mcap_file.McapFile`. Every CSV stream's batches reach it with the
stream's rows (the CSV log names its stream with a :class:`RemoteStreamSink`); the camera frames,
the planned path and ``run.json`` are queued here and handed over when the shared writer thread
wakes (the path's points computed then, the JPEG encoded by the logging process). When logging in
process the same :class:`~companion.flightlog.mcap_file.McapFile` is written by the writer
thread. A hard crash of the logging process loses at most the last two flush periods; a crash of
the flight's process leaves the logging process to close the file properly.
"""

from __future__ import annotations

import collections
import logging
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.flightlog.handover import FLUSH_PERIOD_S, SharedWriter
from companion.flightlog.hooks import FLIGHT, HAND_OVER, LogHooks
from companion.flightlog.logproc import client
from companion.flightlog.mcap_file import McapFile, McapStreamSink, Op
from companion.flightlog.registry import CloseOrder, forget, register

log = logging.getLogger(__name__)

MAX_QUEUED_IMAGES = 64  # frames waiting for JPEG encoding; beyond that a frame is dropped and counted


class McapFlightLog:
    """``flight.mcap`` of one run (see the module doc). Frames, path updates and ``run.json``
    are queued here and handed, when the shared writer thread wakes, to the file: in the logging
    process (:mod:`companion.flightlog.logproc`), or in this process
    (:class:`~companion.flightlog.mcap_file.McapFile`). If the logging process dies after it started
    the file, the MCAP ends there (counted in ``errors``, logged); the CSVs go on."""

    def __init__(self, path: str | Path, streams: Mapping[str, Sequence[str]], hooks: LogHooks = FLIGHT):
        """``hooks``: a bench's instruments (:class:`~companion.flightlog.hooks.LogHooks`: the
        close's wait for the logging process timed as the hand-over)."""
        self.path = Path(path)
        self._columns = {name: tuple(cols) for name, cols in streams.items()}
        self.dropped_images = 0
        self._errors = 0  # here: a path that could not be computed, a logging process that died
        self._remote_counts = (0, 0)  # the logging process's (errors, messages), once closed
        self._closed = False
        self._lost = False  # the logging process died with the file
        self._mode_lock = threading.Lock()
        self._io = threading.Lock()  # the writer thread and close() take turns handing over
        self._images: collections.deque[tuple[float, np.ndarray, dict[str, np.ndarray]]] = collections.deque()
        self._pending: collections.deque[tuple[Any, ...]] = collections.deque()
        self._proc = client()
        self._file: McapFile | None = None
        if self._proc is None:
            self._file = McapFile(self.path, self._columns)
        else:
            self.path.open("wb").close()  # errors raise here; the logging process writes it
            self._id = self._proc.open_mcap(self.path, self._columns)
        self._request = hooks.timed(HAND_OVER, self._proc.request) if self._proc is not None else None
        self._shared = SharedWriter.attach(self, FLUSH_PERIOD_S, hooks)
        register(self, CloseOrder.MCAP)

    @property
    def errors(self) -> int:
        return self._errors + self._remote_counts[0] + (self._file.errors if self._file is not None else 0)

    @property
    def in_process(self) -> bool:
        """Written by this process (not, or no longer, by the logging process)."""
        return self._file is not None

    @property
    def messages(self) -> int:
        """Messages written (in the logging process: counted once the file is closed)."""
        return self._remote_counts[1] + (self._file.messages if self._file is not None else 0)

    def stream_sink(self, name: str) -> McapStreamSink | RemoteStreamSink:
        """What a CSV stream hands its batches to: the in-process file's
        :class:`~companion.flightlog.mcap_file.McapStreamSink`, or a :class:`RemoteStreamSink`
        naming the stream in the logging process."""
        if self._file is not None:
            return self._file.stream_sink(name)
        return RemoteStreamSink(self, name)

    def _local_file(self) -> McapFile | None:
        """The in-process file once the logging process is gone: a new one if that process
        died before it was handed anything, else none (the file stays as the process left it)."""
        with self._mode_lock:
            if self._file is None and not self._lost and self._proc is not None and self._proc.dead:
                returned = self._proc.take_returned(self._id)
                if self._proc.ready:
                    self._lost = True
                    self._errors += 1
                    log.error(
                        "%s: the logging process died (%s); the MCAP ends where it stopped (the CSVs go on)",
                        self.path,
                        self._proc.reason,
                    )
                else:
                    self._file = McapFile(self.path, self._columns)
                    for op in returned:
                        self._file.apply(op[2])
            return self._file

    # ---- the shared writer thread, or close() -----------------------------------------------
    def _take(self) -> list[Op]:
        ops: list[Op] = []
        while self._pending:
            op = self._pending.popleft()
            if op[0] == "path":
                try:
                    op = ("path", op[1], np.asarray(op[2](), dtype=float).reshape(-1, 3))
                except Exception as err:
                    self._errors += 1
                    log.error("%s: the planned path could not be computed: %s", self.path, err)
                    continue
            ops.append(op)
        while self._images:
            ops.append(("img", *self._images.popleft()))
        return ops

    def drain(self) -> None:
        """Hand the queued frames and path updates to the file, then (in process) end the chunk
        and flush it to the OS (the shared writer thread, every 0.1 s)."""
        with self._io:
            self._hand_over()

    def _hand_over(self) -> None:
        """:meth:`drain` (caller holds ``_io``: what the writer took is posted before a close)."""
        if self._closed or self._lost:
            return
        if not self._images and not self._pending:
            if self._file is not None:
                self._file.flush()
            elif self._proc is not None and self._proc.dead:
                self._local_file()
            return
        ops = self._take()
        if self._file is None and self._proc is not None:
            if self._proc.post(("mops", self._id, ops)):
                return
            if self._local_file() is None:
                return
        assert self._file is not None
        self._file.apply(ops)
        self._file.flush()

    # ---- queueing (the loop thread) -------------------------------------------------------
    def add_image(self, time_s: float, image: Any, corners_px: dict[str, Any]) -> None:
        """A frame the pad was detected in (JPEG-encoded later, by the logging process or the
        writer thread)."""
        if self._closed or self._lost or (self._file is not None and self._file._failed):
            return
        if len(self._images) >= MAX_QUEUED_IMAGES:
            self.dropped_images += 1
            return
        self._images.append(
            (float(time_s), np.array(image, copy=True), {k: np.array(v, dtype=float) for k, v in corners_px.items()})
        )

    def add_path(self, time_s: float, points_ned: Callable[[], Any]) -> None:
        """The planned path as a SceneUpdate line; a replan replaces it. ``points_ned`` gives the
        N x 3 NED points (called on the writer thread)."""
        self._pending.append(("path", float(time_s), points_ned))

    def add_meta(self, meta_json: str) -> None:
        """``run.json`` as metadata (the reader keeps the last)."""
        self._pending.append(("meta", meta_json))

    # ---- closing ----------------------------------------------------------------------------
    def close(self) -> None:
        """Encode what is queued, write the summary and close the file (idempotent); returns
        once the file is complete on disk."""
        if self._closed:
            return
        forget(self, CloseOrder.MCAP)
        self._shared.detach(self)
        with self._io:  # after any hand-over the writer thread is in the middle of
            self._hand_over()
            self._closed = True
        if self._file is None and self._request is not None and not self._lost:
            reply = self._request(("mclose", self._id))
            if reply is not None:
                self._remote_counts = reply
            else:
                self._local_file()
        if self._file is not None:
            self._file.close()
        if self.dropped_images:
            log.warning(
                "%s: %d camera frames dropped (JPEG encoding could not keep up)", self.path, self.dropped_images
            )


class RemoteStreamSink:
    """A CSV stream of a ``flight.mcap`` the logging process writes (a
    :class:`~companion.flightlog.csvlog.RemoteSink`): the CSV log names it to that process."""

    def __init__(self, owner: McapFlightLog, name: str):
        self._owner = owner
        self.name = name
        self.remote_key = (owner._id, name)

    def local(self) -> McapStreamSink | None:
        f = self._owner._local_file()
        return f.stream_sink(self.name) if f is not None else None
