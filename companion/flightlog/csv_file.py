"""CSV flight log files: time in seconds first, units in the headers (PlotJuggler-friendly).

:class:`CsvFile` writes one file a batch at a time (``csv.writer``, or the text a
:class:`BatchSink` formats together with messages of its own), flushing each batch to the OS; it
knows nothing of threads or processes, so the flight's process and the logging process write the
same bytes. Floats are written as their shortest round-trip decimal (``repr``): reading a value
back with ``float()`` gives the very same double, which replay needs.
"""

from __future__ import annotations

import csv
import logging
import os
from pathlib import Path
from typing import Protocol, TextIO

from companion.flightlog.losses import cause_of, note_fault

log = logging.getLogger(__name__)


class BatchSink(Protocol):
    """A second consumer of a log's batches (on the writer thread): ``encode`` gives the CSV
    text ``csv.writer`` would write and one message per row; ``publish`` must not raise."""

    def encode(self, batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]: ...

    def publish(self, batch: list[tuple[object, ...]], payloads: list[bytes] | None) -> None: ...


class CsvFile:
    """One CSV file being written, a batch at a time: in this process (the in-process path of
    :class:`~companion.flightlog.csvlog.CsvLog`) or in the logging process. ``append``: the header is already there (the
    file is continued). An ``OSError`` (a full disk, an I/O error) stops the file: said once with
    the path and its cause (:mod:`companion.flightlog.losses`); that batch and every later one are
    counted in ``dropped``. ``fh``: the open text file to write instead of opening ``path`` (a
    test's file that fails). Not thread-safe (its owner serialises)."""

    def __init__(
        self,
        path: Path,
        columns: tuple[str, ...],
        sink: BatchSink | None = None,
        append: bool = False,
        fh: TextIO | None = None,
    ):
        self.path = path
        self.written = 0
        self.dropped = 0
        self.failed: OSError | None = None
        self._sink = sink
        self._fh = fh if fh is not None else path.open("a" if append else "w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh)
        if not append:
            self._writer.writerow(columns)
            self._fh.flush()

    def write_batch(self, batch: list[tuple[object, ...]]) -> None:
        """Write one batch and flush it to the OS."""
        n = len(batch)
        if not n or self._fh.closed:
            return
        if self.failed is not None:  # keep emptying the queue so memory stays bounded
            self.dropped += n
            return
        payloads: list[bytes] | None = None
        try:
            if self._sink is not None:
                try:
                    text, payloads = self._sink.encode(batch)
                except Exception:
                    log.exception("%s: the batch encoder failed; written by csv.writer", self.path)
                    text = ""
                if payloads is not None:
                    self._fh.write(text)
                else:
                    self._writer.writerows(batch)
            else:
                # csv writes str(v): for floats (and numpy float64) the shortest round-trip decimal
                self._writer.writerows(batch)
            self._fh.flush()
        except OSError as err:
            self.failed = err
            self.dropped += n
            stopped(self.path, err)
            return
        self.written += n
        if self._sink is not None:
            self._sink.publish(batch, payloads)

    def close(self) -> None:
        try:
            self._fh.close()
        except OSError as err:
            if self.failed is None:  # else the failed batch's text, already counted and said
                self.failed = err
                stopped(self.path, err)


def stopped(path: Path, err: OSError) -> None:
    """The one line for a log file that cannot be written any more, with its cause."""
    cause = cause_of(err, path)
    note_fault(path, cause)
    log.error("%s: %s: cannot write the log any more (%s); the flight goes on", path, cause.value, err)


def cut_torn_line(path: Path) -> None:
    """Drop a last line without its end (a writer killed mid-write) before the file is continued."""
    try:
        with path.open("r+b") as fh:
            size = fh.seek(0, os.SEEK_END)
            if size == 0:
                return
            start = max(0, size - 65536)
            fh.seek(start)
            tail = fh.read()
            if tail.endswith(b"\n"):
                return
            cut = tail.rfind(b"\n")
            fh.truncate(start + cut + 1 if cut >= 0 else start)
    except OSError:
        pass  # CsvFile's own open reports the path's trouble


class _FailedFile(CsvFile):
    """A file that could not be reopened: every batch is counted as dropped."""

    def __init__(self, path: Path, err: OSError) -> None:  # no super().__init__: nothing to open
        self.path = path
        self.written = 0
        self.dropped = 0
        self.failed = err

    def write_batch(self, batch: list[tuple[object, ...]]) -> None:
        self.dropped += len(batch)

    def close(self) -> None:
        pass


def open_csv_file(path: Path, columns: tuple[str, ...], sink: BatchSink | None, append: bool) -> CsvFile:
    """A :class:`CsvFile` to continue (or start); one that cannot be opened is reported once by
    path and stands in as a file that counts every batch it is given as dropped (in this process,
    or in the logging process)."""
    try:
        return CsvFile(path, columns, sink, append=append)
    except OSError as err:
        stopped(path, err)
        return _FailedFile(path, err)


def format_cell(v: object) -> str:
    """A value as the writer puts it in the file: ``str(v)``, which for a float is its shortest
    decimal that reads back as the same double."""
    return "" if v is None else str(v)


def read_csv(path: str | Path) -> dict[str, list[str]]:
    """Columns of any CSV file written by :class:`CsvFile`, as strings (tests, tools); a row of the
    wrong length is a ValueError naming the file and line. Run-folder streams are read with
    ``flightlog.reader`` instead (a torn last line dropped, the MCAP as fallback)."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty CSV file")
    header, body = rows[0], rows[1:]
    for k, r in enumerate(body):
        if len(r) != len(header):
            raise ValueError(f"{path}: line {k + 2}: {len(r)} fields, the header has {len(header)}")
    return {h: [r[i] for r in body] for i, h in enumerate(header)}
