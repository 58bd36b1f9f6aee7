"""CSV flight logs: time in seconds first, units in the headers (PlotJuggler-friendly).

Rows are handed to a writer thread through a bounded queue so disk I/O never runs on the
control path; every row is flushed as it is written, so a crash loses nothing written before
it. ``close()`` drains the queue and closes the file (also on exceptions, via ``with``).
"""

from __future__ import annotations

import csv
import logging
import queue
import threading
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

log = logging.getLogger(__name__)

_STOP = object()


class CsvLog:
    def __init__(self, path: str | Path, columns: Sequence[str], max_queue: int = 10000):
        if not columns or columns[0] != "time_s":
            raise ValueError(f"the first CSV column must be time_s, got {list(columns)[:1]}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self.dropped = 0
        self.written = 0
        self._q: queue.Queue[object] = queue.Queue(max_queue)
        self._fh = self.path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh)
        self._writer.writerow(self.columns)
        self._fh.flush()
        self._thread = threading.Thread(target=self._drain, name=f"csvlog-{self.path.name}", daemon=True)
        self._thread.start()
        self._closed = False

    def write(self, row: Sequence[object]) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        if len(row) != len(self.columns):
            raise ValueError(f"{self.path}: row has {len(row)} fields, header has {len(self.columns)}")
        try:
            self._q.put_nowait(tuple(row))
        except queue.Full:
            self.dropped += 1

    def _drain(self) -> None:
        while True:
            item = self._q.get()
            if item is _STOP:
                break
            self._writer.writerow(_fmt(v) for v in item)  # type: ignore[attr-defined]
            self.written += 1
            if self._q.empty():
                self._fh.flush()
        self._fh.flush()

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        self._q.put(_STOP)
        self._thread.join()
        self._fh.close()
        if self.dropped:
            log.warning("%s: %d rows dropped (writer could not keep up)", self.path, self.dropped)

    def __enter__(self) -> CsvLog:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


def _fmt(v: object) -> object:
    if isinstance(v, float):
        return f"{v:.6f}"
    return v


def read_csv(path: str | Path) -> dict[str, list[str]]:
    """Columns of a CSV log, as strings (for reports and tests)."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty CSV log")
    header, body = rows[0], rows[1:]
    return {h: [r[i] for r in body] for i, h in enumerate(header)}
