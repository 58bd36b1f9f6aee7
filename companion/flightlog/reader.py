"""Reading a run folder written by the flight recorder: its CSV streams and ``meta.json``, with
errors that name the file, line, column and value (:class:`LogFormatError`)."""

from __future__ import annotations

import csv
import json
import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.flightlog.recorder import FORMAT, META_FILE, decode_value

log = logging.getLogger(__name__)


class LogFormatError(ValueError):
    """A run folder or log file that cannot be read: names the file, line, column and value."""


class Table:
    """One CSV stream: its header checked against the columns it must have, cells parsed on
    demand with errors naming file, line, column and value. A torn last line (a hard crash in the
    middle of a write) is dropped with a warning; any other short row is an error."""

    def __init__(self, path: Path, required: Sequence[str] = ()):
        self.path = path
        try:
            with path.open(newline="", encoding="utf-8") as fh:
                rows = list(csv.reader(fh))
        except FileNotFoundError:
            raise LogFormatError(f"{path}: file not found") from None
        except (OSError, UnicodeDecodeError, csv.Error) as err:
            raise LogFormatError(f"{path}: cannot read: {err}") from None
        if not rows:
            raise LogFormatError(f"{path}: empty file (expected a header line starting with time_s)")
        self.header = rows[0]
        if not self.header or self.header[0] != "time_s":
            raise LogFormatError(f"{path}: line 1: the first column must be time_s, got {self.header[:1]}")
        missing = [c for c in required if c not in self.header]
        if missing:
            raise LogFormatError(f"{path}: line 1: missing column(s) {missing}")
        self.index = {c: i for i, c in enumerate(self.header)}
        self.rows = rows[1:]
        self.torn = False
        for k, r in enumerate(self.rows):
            if len(r) != len(self.header):
                if k == len(self.rows) - 1:
                    log.warning(
                        "%s: line %d: torn last line dropped (%d of %d fields)", path, k + 2, len(r), len(self.header)
                    )
                    self.rows.pop()
                    self.torn = True
                    break
                raise LogFormatError(f"{path}: line {k + 2}: {len(r)} fields, the header has {len(self.header)}")

    def __len__(self) -> int:
        return len(self.rows)

    def text(self, k: int, column: str) -> str:
        return self.rows[k][self.index[column]]

    def value(self, k: int, column: str, typ: Any = float) -> Any:
        text = self.rows[k][self.index[column]]
        try:
            return decode_value(text, typ)
        except (ValueError, TypeError) as err:
            what = getattr(typ, "__name__", str(typ))
            raise LogFormatError(
                f"{self.path}: line {k + 2}, column {column!r}: {text!r} is not a valid {what} ({err})"
            ) from None

    def floats(self, column: str) -> np.ndarray:
        return np.array([self.value(k, column, float) for k in range(len(self.rows))], dtype=float)


def read_meta(run_dir: Path) -> dict[str, Any]:
    p = run_dir / META_FILE
    try:
        meta = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise LogFormatError(
            f"{p}: file not found: {run_dir} is not a run folder written by the flight recorder"
        ) from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise LogFormatError(f"{p}: cannot read: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise LogFormatError(f"{p}: format {got!r}, expected {FORMAT!r}")
    return meta
