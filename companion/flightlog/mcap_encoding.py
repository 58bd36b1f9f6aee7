"""What ``flight.mcap`` holds for Foxglove, as bytes: the channels' topics and JSON schemas, and
the JSON messages of the CSV streams' rows (formatted together with the CSV text).

Every CSV stream is a channel ``/log/<stream>`` (schema ``companion.<stream>``, JSON message
encoding) with one message per CSV row, the CSV's columns as keys. Floats are JSON numbers
written with ``repr`` (shortest round-trip), non-finite ones as the strings ``"nan"``, ``"inf"``,
``"-inf"``: a cell read back (:func:`cell_text`) is the very text the CSV holds, so replay from the
MCAP is bit for bit.
"""

from __future__ import annotations

import csv
import json
import math
import operator
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

MCAP_FILE = "flight.mcap"
PROFILE = "companion"
STREAM_TOPIC_PREFIX = "/log/"

# Columns that hold text (everything else is a number; flags are 0/1).
TEXT_COLUMNS = frozenset(
    {
        "markers",
        "anchors_used",
        "frame",
        "est_source",
        "phase",
        "request",
        "kind",
        "error",
        "source",
        "detail",
        "reply",
        "mode",
        "landed_state",
        "text",
        "severity",
    }
)


def row_schema(stream: str, columns: Sequence[str]) -> dict[str, Any]:
    """The JSON schema of one CSV stream's messages: its columns as properties."""
    props: dict[str, Any] = {}
    for c in columns:
        if c in TEXT_COLUMNS:
            props[c] = {"type": "string"}
        else:
            props[c] = {
                "type": ["number", "string"],
                "description": "a number; non-finite values as the strings nan, inf, -inf",
            }
    return {
        "title": f"companion.{stream}",
        "description": f"one row of {stream}.csv (same columns, same units)",
        "type": "object",
        "properties": props,
        "required": list(columns),
    }


def stream_topic(csv_name: str) -> str:
    return STREAM_TOPIC_PREFIX + csv_name.removesuffix(".csv")


def _json_default(o: object) -> object:
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return _finite_or_text(float(o))
    if isinstance(o, np.bool_):
        return bool(o)
    raise TypeError(f"{type(o).__name__} is not a JSON value")


def _finite_or_text(v: object) -> object:
    if isinstance(v, float) and not math.isfinite(v):
        return str(v)  # "nan", "inf", "-inf": what the CSV holds
    return v


_ENCODER = json.JSONEncoder(allow_nan=False, default=_json_default, separators=(",", ":"))
_NOT_A_NUMBER = re.compile(r"[^0-9eE.+\-,]")  # anything but the reprs of finite ints and floats


_INFINITIES = (math.inf, -math.inf)


def encode_row(columns: Sequence[str], row: Sequence[object]) -> bytes:
    """One CSV row as a JSON object (floats as shortest round-trip decimals, non-finite ones as
    the strings the CSV holds)."""
    vals = [str(v) if v != v or v in _INFINITIES else v for v in row]  # v != v: NaN
    return _ENCODER.encode(dict(zip(columns, vals, strict=True))).encode()


def row_encoder(columns: Sequence[str]) -> Callable[[tuple[object, ...]], bytes]:
    """A faster :func:`encode_row` for one stream, same output: a row of finite Python ints and
    floats (most rows: samples, EKF, setpoints) is formatted once with ``%r`` (their shortest
    round-trip reprs, which are valid JSON numbers) into a template of the keys; any other row
    (text, NaN, numpy scalars, flags as bools) goes through the JSON encoder."""
    cols = tuple(columns)
    n = len(cols)
    values = ",".join(["%r"] * n)
    template = "{" + ",".join(f"{json.dumps(c)}:%s" for c in cols) + "}"

    def encode(row: tuple[object, ...]) -> bytes:
        if len(row) == n:
            text = values % row
            if _NOT_A_NUMBER.search(text) is None:
                return (template % tuple(text.split(","))).encode()
        return encode_row(cols, row)

    return encode


class _ListWriter:
    def __init__(self) -> None:
        self.parts: list[str] = []

    def write(self, text: str) -> None:
        self.parts.append(text)


# what a text cell may hold to be written as is: printable ASCII but the quote, the comma and the
# backslash (csv.writer quotes nothing of it, json.dumps escapes nothing of it)
_NOT_PLAIN_TEXT = re.compile(r"[^\x20\x21\x23-\x2b\x2d-\x5b\x5d-\x7e]")
_NOT_A_CELL = re.compile(r"[^0-9eE.+\-,nafi]")  # but the reprs of ints and floats, nan and inf included
_NON_FINITE = ("nan", "inf", "-inf")


def batch_encoder(columns: Sequence[str]) -> Callable[[list[tuple[object, ...]]], tuple[str, list[bytes]]]:
    """For a batch of rows: the CSV text ``csv.writer`` would write (``\r\n`` line ends) and
    each row's JSON message (:func:`encode_row`'s bytes), formatting every number once.

    The whole batch at once when it allows: every row ``%``-formatted into its CSV line (numbers
    with ``%r``, their shortest round-trip reprs, text columns (:data:`TEXT_COLUMNS`) with
    ``%s``), which split at the commas gives the values of its JSON template (text quoted, NaN
    and the infinities turned into the strings the CSV holds). That holds when every number
    cell is a Python int or float and every text cell a ``str`` of printable ASCII without
    ``"``, ``,`` or ``\\`` (nothing for either format to quote or escape), checked once per
    batch; any other batch goes row by row: a row of finite Python numbers formatted once, any
    other row through ``csv.writer`` and :func:`encode_row`."""
    f = _BatchFormats.of(columns)
    numeric = not f.text_idx

    def encode(batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]:
        if batch:
            done = _batch_of_numbers(f, batch) if numeric else None
            if done is None:
                done = _batch_whole(f, batch)
            if done is not None:
                return done
        return _batch_row_by_row(f, batch)

    return encode


@dataclass(frozen=True)
class _BatchFormats:
    """One stream's formats for :func:`batch_encoder`: the CSV line's and the JSON message's
    (text columns apart), and those of a row of numbers only."""

    cols: tuple[str, ...]
    text_idx: list[int]
    number_idx: list[int]
    line_fmt: str
    json_fmt: str
    numbers_of: Callable[[list[str]], tuple[str, ...]] | None
    texts_of: Callable[[tuple[object, ...]], tuple[object, ...]] | None
    values: str
    template: str

    @property
    def n_cols(self) -> int:
        return len(self.cols)

    @staticmethod
    def of(columns: Sequence[str]) -> _BatchFormats:
        cols = tuple(columns)
        text_idx = [i for i, c in enumerate(cols) if c in TEXT_COLUMNS]
        number_idx = [i for i, c in enumerate(cols) if c not in TEXT_COLUMNS]
        keys = [json.dumps(c).replace("%", "%%") + ":" for c in cols]
        return _BatchFormats(
            cols=cols,
            text_idx=text_idx,
            number_idx=number_idx,
            line_fmt=",".join("%s" if c in TEXT_COLUMNS else "%r" for c in cols),
            json_fmt="{"
            + ",".join(k + ('"%s"' if c in TEXT_COLUMNS else "%s") for k, c in zip(keys, cols, strict=True))
            + "}",
            numbers_of=operator.itemgetter(*number_idx) if len(number_idx) > 1 else None,
            texts_of=operator.itemgetter(*text_idx) if len(text_idx) > 1 else None,
            values=",".join(["%r"] * len(cols)),
            template="{" + ",".join(f"{json.dumps(c)}:%s" for c in cols) + "}",
        )


def _batch_of_numbers(f: _BatchFormats, batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]] | None:
    """A batch of finite Python ints and floats only (a stream without text columns); None
    for any other batch."""
    values, template = f.values, f.template
    try:
        lines = [values % row for row in batch]
    except TypeError:  # a row of another length
        return None
    if _NOT_A_NUMBER.search(",".join(lines)) is not None:  # not only finite ints and floats
        return None
    payloads = [(template % tuple(t.split(","))).encode() for t in lines]
    lines.append("")  # the last line's end
    return "\r\n".join(lines), payloads


def _batch_whole(f: _BatchFormats, batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]] | None:
    """The whole batch formatted at once (see :func:`batch_encoder`); None when a cell would need
    quoting or escaping."""
    n, number_idx, text_idx, numbers_of, texts_of = f.n_cols, f.number_idx, f.text_idx, f.numbers_of, f.texts_of
    line_fmt, json_fmt = f.line_fmt, f.json_fmt
    try:
        lines = [line_fmt % row for row in batch]
    except TypeError:  # a row of another length
        return None
    cells = [line.split(",") for line in lines]
    if any(len(c) != n for c in cells):  # a comma in a cell
        return None
    if number_idx:
        if numbers_of is not None:
            nums = ",".join([",".join(numbers_of(c)) for c in cells])
        else:
            nums = ",".join([c[number_idx[0]] for c in cells])
        if _NOT_A_CELL.search(nums) is not None:
            return None
    if text_idx:
        if texts_of is not None:
            texts = [t for row in batch for t in texts_of(row)]
        else:
            texts = [row[text_idx[0]] for row in batch]
        if set(map(type, texts)) - {str} or _NOT_PLAIN_TEXT.search("".join(texts)) is not None:  # type: ignore[arg-type]
            return None
    messages = "\n".join([json_fmt % tuple(c) for c in cells])
    if number_idx:
        for v in _NON_FINITE:
            if v in messages:
                for end in (",", "}"):
                    # after a key's closing quote (a text value holds no quote): a number's cell
                    messages = messages.replace(f'":{v}{end}', f'":"{v}"{end}')
    lines.append("")  # the last line's end
    return "\r\n".join(lines), messages.encode().split(b"\n")


def _batch_row_by_row(f: _BatchFormats, batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]:
    """Any batch, row by row: a row of finite Python numbers formatted once (a stream without
    text columns), any other row through ``csv.writer`` and :func:`encode_row`."""
    cols, n, values, template = f.cols, f.n_cols, f.values, f.template
    numeric = not f.text_idx
    search = _NOT_A_NUMBER.search
    out = _ListWriter()
    slow = csv.writer(out)
    payloads: list[bytes] = []
    for row in batch:
        if numeric and len(row) == n:
            text = values % row
            if search(text) is None:
                out.parts.append(text + "\r\n")
                payloads.append((template % tuple(text.split(","))).encode())
                continue
        slow.writerow(row)
        payloads.append(encode_row(cols, row))
    return "".join(out.parts), payloads


def cell_text(v: object) -> str:
    """A decoded JSON value as the CSV writer wrote it (``str(v)``; None as empty)."""
    if v is None:
        return ""
    if isinstance(v, str):
        return v
    return str(v)


def compact_json(obj: object) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()
