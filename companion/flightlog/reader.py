"""Reading a run folder written by the flight recorder: its CSV streams and ``run.json``, with
errors that name the file, line, column and value (:class:`LogFormatError`).

A folder that holds only ``flight.mcap`` (or lacks some CSVs) is read from the MCAP: its
``/log/<stream>`` channels give the same rows, cell for cell the same text (:func:`open_table`,
:func:`read_meta`)."""

from __future__ import annotations

import csv
import functools
import io
import json
import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.flightlog.mcap_encoding import MCAP_FILE, PROFILE, STREAM_TOPIC_PREFIX, cell_text
from companion.flightlog.streams import FORMAT, META_FILE, decode_value

log = logging.getLogger(__name__)


class LogFormatError(ValueError):
    """A run folder or log file that cannot be read: names the file, line, column and value."""


class Table:
    """One CSV stream: its header checked against the columns it must have, cells parsed on
    demand with errors naming file, line, column and value. A torn last line (a hard crash in the
    middle of a write) is dropped with a warning; any other short row is an error."""

    def __init__(self, path: Path, required: Sequence[str] = (), rows: list[list[str]] | None = None):
        """``rows``: header and body already read (from an MCAP, ``path`` then names the file
        and channel); otherwise the CSV at ``path`` is read."""
        self.path = path
        complete = True  # the last line ends in a newline (the writers end every row with one)
        if rows is None:
            try:
                with path.open(newline="", encoding="utf-8") as fh:
                    content = fh.read()
                rows = list(csv.reader(io.StringIO(content)))
                complete = content.endswith("\n")
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
        if not complete and self.rows:
            # cut in the middle of its last field, a row can still have all its fields ("1.5,2.3,4"
            # of "1.5,2.3,4.75\n"): without its newline it is torn, whatever it holds
            log.warning("%s: line %d: torn last line dropped (no newline at its end)", path, len(rows))
            self.rows.pop()
            self.torn = True
        for k, r in enumerate(self.rows):
            if len(r) != len(self.header):
                if k == len(self.rows) - 1 and not self.torn:
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


def read_columns(path: str | Path) -> dict[str, list[str]]:
    """Every column of one CSV stream as strings (figures, tests), read as :class:`Table` reads it:
    a torn last line dropped, any other fault a :class:`LogFormatError` naming the file."""
    table = Table(Path(path))
    return {h: [r[i] for r in table.rows] for i, h in enumerate(table.header)}


def read_meta(run_dir: Path) -> dict[str, Any]:
    """``run.json`` of a run folder, or the last one stored in its ``flight.mcap``."""
    p = run_dir / META_FILE
    mcap_path = run_dir / MCAP_FILE
    try:
        meta = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        if not mcap_path.exists():
            raise LogFormatError(
                f"{p}: file not found (nor {MCAP_FILE}): {run_dir} is not a run folder written by the flight recorder"
            ) from None
        meta = read_mcap(mcap_path).meta
        if meta is None:
            raise LogFormatError(f"{mcap_path}: no {META_FILE!r} metadata (and no {p})") from None
        p = Path(f"{mcap_path}:{META_FILE}")
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise LogFormatError(f"{p}: cannot read: {err}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        got = meta.get("format") if isinstance(meta, dict) else type(meta).__name__
        raise LogFormatError(f"{p}: format {got!r}, expected {FORMAT!r}")
    return meta


# ---------------------------------------------------------------------------------------------
# flight.mcap


@dataclass(frozen=True)
class McapRun:
    """What a ``flight.mcap`` holds for replay and reports: each CSV stream's header and rows (as
    the CSV's text), the last ``run.json`` stored, the message count per topic, and whether the
    file ends in a torn record (a hard crash: no summary)."""

    path: Path
    streams: dict[str, list[list[str]]]  # CSV name -> [header, *rows]
    meta: dict[str, Any] | None
    message_counts: dict[str, int]
    torn: bool


def read_mcap(path: str | Path) -> McapRun:
    """Read ``flight.mcap`` (cached while the file is unchanged)."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise LogFormatError(f"{p}: file not found") from None
    return _read_mcap(p, st.st_mtime_ns, st.st_size)


@functools.lru_cache(maxsize=4)
def _read_mcap(p: Path, _mtime_ns: int, _size: int) -> McapRun:
    from mcap.records import Channel, Header, Message, Metadata, Schema
    from mcap.stream_reader import StreamReader

    channels: dict[int, Channel] = {}
    streams: dict[int, tuple[str, list[str], list[list[str]]]] = {}
    counts: dict[str, int] = {}
    meta_text: str | None = None
    torn = False
    profile: str | None = None
    try:
        fh = p.open("rb")
    except OSError as err:
        raise LogFormatError(f"{p}: cannot read: {err}") from None
    with fh:
        records = StreamReader(fh, validate_crcs=True).records
        while True:
            try:
                rec = next(records)
            except StopIteration:
                break
            except Exception as err:
                if profile is None:
                    raise LogFormatError(f"{p}: not an MCAP file ({type(err).__name__}: {err})") from None
                log.warning("%s: torn record at the end dropped (%s: %s): a crashed run", p, type(err).__name__, err)
                torn = True
                break
            if isinstance(rec, Header):
                profile = rec.profile
                if profile != PROFILE:
                    raise LogFormatError(f"{p}: MCAP profile {profile!r}, expected {PROFILE!r} (a companion flight)")
            elif isinstance(rec, Schema):
                pass
            elif isinstance(rec, Channel):
                if rec.id in channels:  # the summary section repeats the channels
                    continue
                channels[rec.id] = rec
                if rec.topic.startswith(STREAM_TOPIC_PREFIX):
                    streams[rec.id] = _stream_channel(p, rec.topic, rec.metadata)
            elif isinstance(rec, Message):
                ch = channels.get(rec.channel_id)
                if ch is None:
                    raise LogFormatError(f"{p}: a message on channel id {rec.channel_id}, which was never declared")
                counts[ch.topic] = counts.get(ch.topic, 0) + 1
                stream = streams.get(rec.channel_id)
                if stream is None:
                    continue
                _name, header, rows = stream
                rows.append(_stream_row(p, ch.topic, counts[ch.topic], rec.data, header))
            elif isinstance(rec, Metadata) and rec.name == META_FILE:
                meta_text = rec.metadata.get("json")
    if profile is None:
        raise LogFormatError(f"{p}: empty or not an MCAP file")
    meta: dict[str, Any] | None = None
    if meta_text is not None:
        try:
            meta = json.loads(meta_text)
        except json.JSONDecodeError as err:
            raise LogFormatError(f"{p}: metadata {META_FILE!r}: not JSON ({err})") from None
    return McapRun(
        path=p,
        streams={name: [header, *rows] for name, header, rows in streams.values()},
        meta=meta,
        message_counts=counts,
        torn=torn,
    )


def _stream_channel(p: Path, topic: str, metadata: dict[str, str]) -> tuple[str, list[str], list[list[str]]]:
    """A stream channel's (CSV name, columns, no rows yet) from its metadata."""
    name = metadata.get("csv", "")
    try:
        header = json.loads(metadata["columns"])
    except (KeyError, json.JSONDecodeError) as err:
        raise LogFormatError(f"{p}: channel {topic!r}: metadata 'columns' missing or not a JSON list ({err})") from None
    if not name.endswith(".csv") or not isinstance(header, list):
        raise LogFormatError(
            f"{p}: channel {topic!r}: metadata csv={name!r}, columns={header!r}: "
            "expected a CSV file name and a list of column names"
        )
    return (name, [str(c) for c in header], [])


def _stream_row(p: Path, topic: str, n: int, data: bytes, header: list[str]) -> list[str]:
    """Message ``n`` of a stream channel (a JSON object) as the CSV row's cells, in ``header``'s order."""
    try:
        obj = json.loads(data)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise LogFormatError(f"{p}: channel {topic!r}, message {n}: not JSON ({err})") from None
    if not isinstance(obj, dict):
        raise LogFormatError(f"{p}: channel {topic!r}, message {n}: expected a JSON object, got {type(obj).__name__}")
    try:
        return [cell_text(obj[c]) for c in header]
    except KeyError as err:
        raise LogFormatError(f"{p}: channel {topic!r}, message {n}: key {err.args[0]!r} missing") from None


def open_table(run_dir: str | Path, name: str, required: Sequence[str] = ()) -> Table:
    """Stream ``name`` (e.g. ``"ekf.csv"``) of a run folder: the CSV if it is there, else the
    same rows from ``flight.mcap``."""
    run = Path(run_dir)
    path = run / name
    mcap_path = run / MCAP_FILE
    if path.exists() or not mcap_path.exists():
        return Table(path, required)
    m = read_mcap(mcap_path)
    rows = m.streams.get(name)
    if rows is None:
        # a stream without messages has no channel in the file: its columns are in run.json
        streams = m.meta.get("streams") if isinstance(m.meta, dict) else None
        columns = streams.get(name) if isinstance(streams, dict) else None
        if not isinstance(columns, list):
            raise LogFormatError(
                f"{path}: file not found, and {mcap_path} has neither a channel for it nor its columns "
                f"(metadata {META_FILE!r}, key 'streams')"
            )
        rows = [[str(c) for c in columns]]
    return Table(Path(f"{mcap_path}:{name}"), required, rows=[list(r) for r in rows])
