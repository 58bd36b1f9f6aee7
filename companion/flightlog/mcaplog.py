"""The flight as one MCAP file (``flight.mcap``) beside the CSVs, for Foxglove.

Written by :class:`McapFlightLog`, which the :class:`~companion.flightlog.recorder.FlightRecorder`
owns. Nothing is encoded on the control path, nor (by default) in the flight's process: the file
is written by the logging process (:mod:`companion.flightlog.logproc`) with :class:`McapFile`.
Every CSV stream's batch reaches it with the stream's rows (the CSV log names its stream with a
:class:`RemoteStreamSink`; there :class:`McapStreamSink` formats each batch once for the CSV and
the MCAP), and the camera frames, the planned path and ``run.json`` are queued here and handed
over when the shared writer thread wakes (the path's points computed then, the JPEG encoded by
the logging process). When logging in process the same :class:`McapFile` is written by the
writer thread. The file is written by foxglove-sdk's MCAP writer (``foxglove.open_mcap``, zstd
chunks) into a context of its own; the chunk is ended and flushed after every hand-over (every
wake-up in process), so a hard crash of the logging process loses at most the last 0.2 s (two
periods of 0.1 s) and leaves a readable file without its summary (the reader stops at the torn record); a
crash of the flight's process leaves the logging process to close the file properly.

Channels (JSON message encoding, JSON schemas):

==========================  ===============================  =====================================
``/log/<stream>``           ``companion.<stream>``            one message per CSV row, the CSV's
                                                              columns as keys (``/log/ekf``:
                                                              pose, velocity, covariance diagonal)
``/camera/image``           ``foxglove.CompressedImage``      the frames the pad was detected in
``/camera/markers``         ``foxglove.ImageAnnotations``     the detected marker corners
``/ekf/pose``               ``foxglove.PoseInFrame``          the fused pose, frame ``ned``
``/ekf/sigma``              ``companion.ekf_sigma``           1-sigma of position (m) and attitude
                                                              (deg) from the covariance diagonal
``/mission/path``           ``foxglove.SceneUpdate``          the planned path (line), frame ``ned``
``/tf``                     ``foxglove.FrameTransform``       ``world`` (ENU, z up) -> ``ned``
==========================  ===============================  =====================================

``run.json`` is stored as metadata ``run.json`` (key ``json``) every time the recorder rewrites
it; the last one is the final one. Floats are JSON numbers written with ``repr`` (shortest
round-trip), non-finite ones as the strings ``"nan"``, ``"inf"``, ``"-inf"``: a cell read back
(:func:`cell_text`) is the very text the CSV holds, so replay from the MCAP is bit for bit.
"""

from __future__ import annotations

import atexit
import base64
import collections
import csv
import json
import logging
import math
import operator
import re
import threading
import weakref
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.foxglove_schemas import (
    EKF_SIGMA_SCHEMA,
    ENU_FROM_NED_QUAT,
    FOXGLOVE_SCHEMAS,
    foxglove_time,
    quat_from_euler_zyx,
    time_ns,
)

log = logging.getLogger(__name__)

_OPEN: weakref.WeakSet[McapFlightLog] = weakref.WeakSet()


@atexit.register
def _close_open_mcaps() -> None:
    """At interpreter exit: the CSV logs first (their last batches reach the MCAP), then the MCAPs."""
    from companion.flightlog import csvlog

    csvlog._close_open_logs()
    for m in list(_OPEN):
        m.close()


MCAP_FILE = "flight.mcap"
PROFILE = "companion"
STREAM_TOPIC_PREFIX = "/log/"
MAX_QUEUED_IMAGES = 64  # frames waiting for JPEG encoding; beyond that a frame is dropped and counted
JPEG_QUALITY = 90

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
    cols = tuple(columns)
    n = len(cols)
    text_idx = [i for i, c in enumerate(cols) if c in TEXT_COLUMNS]
    number_idx = [i for i, c in enumerate(cols) if c not in TEXT_COLUMNS]
    line_fmt = ",".join("%s" if c in TEXT_COLUMNS else "%r" for c in cols)
    keys = [json.dumps(c).replace("%", "%%") + ":" for c in cols]
    json_fmt = (
        "{" + ",".join(k + ('"%s"' if c in TEXT_COLUMNS else "%s") for k, c in zip(keys, cols, strict=True)) + "}"
    )
    numbers_of = operator.itemgetter(*number_idx) if len(number_idx) > 1 else None
    texts_of = operator.itemgetter(*text_idx) if len(text_idx) > 1 else None
    values = ",".join(["%r"] * n)
    template = "{" + ",".join(f"{json.dumps(c)}:%s" for c in cols) + "}"
    search = _NOT_A_NUMBER.search
    numeric = not text_idx

    def numbers(batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]] | None:
        try:
            lines = [values % row for row in batch]
        except TypeError:  # a row of another length
            return None
        if search(",".join(lines)) is not None:  # not only finite ints and floats
            return None
        payloads = [(template % tuple(t.split(","))).encode() for t in lines]
        lines.append("")  # the last line's end
        return "\r\n".join(lines), payloads

    def whole(batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]] | None:
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

    def encode(batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]:
        if batch:
            done = numbers(batch) if numeric else None
            if done is None:
                done = whole(batch)
            if done is not None:
                return done
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

    return encode


def cell_text(v: object) -> str:
    """A decoded JSON value as the CSV writer wrote it (``str(v)``; None as empty)."""
    if v is None:
        return ""
    if isinstance(v, str):
        return v
    return str(v)


def _dumps(obj: object) -> bytes:
    return json.dumps(obj, separators=(",", ":"), allow_nan=False).encode()


Op = tuple[Any, ...]  # ("img", t, image, corners), ("path", t, points N x 3), ("meta", run.json text)


class McapFile:
    """The foxglove MCAP writer of one ``flight.mcap`` (in this process, or in the logging
    process): channels, the messages of each op, the stream sinks. Thread-safe (the writer
    thread and ``close()`` take turns). A write error disables it (logged once, counted in
    ``errors``); the CSVs go on."""

    def __init__(self, path: Path, streams: Mapping[str, Sequence[str]]):
        import foxglove
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        self.path = path
        self._lock = threading.Lock()
        # a context of its own: the flight's channels reach this file only (not a live server)
        self._context: Any = foxglove.Context()
        self._writer: Any = foxglove.open_mcap(
            self.path,
            allow_overwrite=True,
            context=self._context,
            writer_options=MCAPWriteOptions(profile=PROFILE, compression=MCAPCompression.Zstd, compression_threads=0),
        )
        self._columns = {name: tuple(cols) for name, cols in streams.items()}
        self._channels: dict[str, Any] = {}
        self.errors = 0
        self.messages = 0
        self._failed = False
        self._closed = False
        self._dirty = False

        def channel(topic: str, schema_name: str, schema: dict[str, Any], metadata: dict[str, str] | None) -> None:
            self._channels[topic] = foxglove.Channel(
                topic,
                schema=foxglove.Schema(name=schema_name, encoding="jsonschema", data=_dumps(schema)),
                message_encoding="json",
                context=self._context,
                metadata=metadata,
            )

        for name, cols in self._columns.items():
            stem = name.removesuffix(".csv")
            channel(
                stream_topic(name),
                f"companion.{stem}",
                row_schema(stem, cols),
                {"csv": name, "columns": json.dumps(list(cols))},
            )
        for topic, schema_name in (
            ("/camera/image", "foxglove.CompressedImage"),
            ("/camera/markers", "foxglove.ImageAnnotations"),
            ("/ekf/pose", "foxglove.PoseInFrame"),
            ("/mission/path", "foxglove.SceneUpdate"),
            ("/tf", "foxglove.FrameTransform"),
        ):
            channel(topic, schema_name, FOXGLOVE_SCHEMAS[schema_name], None)
        channel("/ekf/sigma", "companion.ekf_sigma", EKF_SIGMA_SCHEMA, None)
        self._add(
            "/tf",
            0.0,
            _dumps(
                {
                    "timestamp": foxglove_time(0.0),
                    "parent_frame_id": "world",
                    "child_frame_id": "ned",
                    "translation": {"x": 0.0, "y": 0.0, "z": 0.0},
                    "rotation": ENU_FROM_NED_QUAT,
                }
            ),
        )
        self._writer.flush()

    def _add(self, topic: str, t_s: float, data: bytes) -> None:
        self._channels[topic].log(data, log_time=time_ns(t_s))
        self.messages += 1
        self._dirty = True

    def _fail(self, err: BaseException) -> None:
        self.errors += 1
        if not self._failed:
            log.error("%s: cannot write the MCAP any more (the CSVs go on): %s", self.path, err)
        self._failed = True

    def stream_sink(self, name: str) -> McapStreamSink:
        """What a CSV stream hands its batches to (see :class:`McapStreamSink`)."""
        return McapStreamSink(self, name)

    def _ekf_messages(self, idx: dict[str, int], row: tuple[object, ...], t: float) -> None:
        def f(c: str) -> float:
            return float(row[idx[c]])  # type: ignore[arg-type]

        stamp = foxglove_time(t)
        pose = {
            "timestamp": stamp,
            "frame_id": "ned",
            "pose": {
                "position": {"x": f("north_m"), "y": f("east_m"), "z": f("down_m")},
                "orientation": quat_from_euler_zyx(f("roll_rad"), f("pitch_rad"), f("yaw_rad")),
            },
        }
        self._add("/ekf/pose", t, _dumps(pose))
        sig: dict[str, float] = {"time_s": t}
        for a in ("north", "east", "down"):
            sig[f"sigma_{a}_m"] = math.sqrt(max(0.0, f(f"var_{a}_m2")))
        for a in ("roll", "pitch", "yaw"):
            sig[f"sigma_{a}_deg"] = math.degrees(math.sqrt(max(0.0, f(f"var_{a}_rad2"))))
        self._add("/ekf/sigma", t, _dumps(sig))

    def apply(self, ops: list[Op]) -> None:
        """Write the messages of queued frames, path updates and metadata, in order."""
        with self._lock:
            if self._closed or self._failed:
                return
            try:
                for op in ops:
                    kind = op[0]
                    if kind == "img":
                        self._write_image(op[1], op[2], op[3])
                    elif kind == "path":
                        self._write_path(op[1], op[2])
                    elif kind == "meta":
                        self._writer.write_metadata("run.json", {"json": op[1]})
                    else:
                        raise ValueError(f"unknown MCAP op {kind!r}")
            except Exception as err:
                self._fail(err)

    def flush(self) -> None:
        """End the chunk and flush it to the OS (when something was written since)."""
        if not self._dirty:
            return
        with self._lock:
            if self._closed or self._failed or not self._dirty:
                return
            self._dirty = False
            try:
                self._writer.flush()
            except Exception as err:
                self._fail(err)

    def _write_image(self, t: float, image: np.ndarray, corners: dict[str, np.ndarray]) -> None:
        import cv2

        ok, buf = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
        if not ok:
            raise ValueError(f"JPEG encoding of a {image.shape} {image.dtype} frame failed")
        stamp = foxglove_time(t)
        msg = {
            "timestamp": stamp,
            "frame_id": "camera",
            "data": base64.b64encode(buf.tobytes()).decode("ascii"),
            "format": "jpeg",
        }
        self._add("/camera/image", t, _dumps(msg))
        colors = {"outer": {"r": 0.1, "g": 0.9, "b": 0.2, "a": 1.0}, "inner": {"r": 1.0, "g": 0.5, "b": 0.0, "a": 1.0}}
        points = []
        texts = []
        for name, pts in sorted(corners.items()):
            xy = np.asarray(pts, dtype=float).reshape(-1, 2)
            color = colors.get(name, {"r": 0.2, "g": 0.6, "b": 1.0, "a": 1.0})
            points.append(
                {
                    "timestamp": stamp,
                    "type": 2,  # LINE_LOOP
                    "points": [{"x": float(x), "y": float(y)} for x, y in xy],
                    "outline_color": color,
                    "outline_colors": [],
                    "fill_color": {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.0},
                    "thickness": 2.0,
                }
            )
            texts.append(
                {
                    "timestamp": stamp,
                    "position": {"x": float(xy[0, 0]), "y": float(xy[0, 1])},
                    "text": name,
                    "font_size": 14.0,
                    "text_color": color,
                    "background_color": {"r": 0.0, "g": 0.0, "b": 0.0, "a": 0.5},
                }
            )
        self._add("/camera/markers", t, _dumps({"circles": [], "points": points, "texts": texts}))

    def _write_path(self, time_s: float, points: Any) -> None:
        pts = np.asarray(points, dtype=float).reshape(-1, 3)
        stamp = foxglove_time(time_s)
        entity = {
            "timestamp": stamp,
            "frame_id": "ned",
            "id": "planned_path",
            "lifetime": {"sec": 0, "nsec": 0},
            "frame_locked": False,
            "metadata": [],
            "lines": [
                {
                    "type": 0,  # LINE_STRIP
                    "pose": {
                        "position": {"x": 0.0, "y": 0.0, "z": 0.0},
                        "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},
                    },
                    "thickness": 3.0,
                    "scale_invariant": True,
                    "points": [{"x": float(n), "y": float(e), "z": float(d)} for n, e, d in pts],
                    "color": {"r": 0.2, "g": 0.8, "b": 1.0, "a": 1.0},
                    "colors": [],
                    "indices": [],
                }
            ],
            "spheres": [],
        }
        self._add("/mission/path", time_s, _dumps({"deletions": [], "entities": [entity]}))

    def close(self) -> None:
        """Write the summary and close the file (idempotent)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                for ch in self._channels.values():
                    ch.close()
                self._writer.close()
            except Exception as err:
                self._fail(err)
            # drop the SDK's objects here, not in some later garbage collection
            self._channels.clear()
            self._writer = self._context = None


class McapFlightLog:
    """``flight.mcap`` of one run (see the module doc). Frames, path updates and ``run.json``
    are queued here and handed, when the shared writer thread wakes, to the file: in the logging
    process (:mod:`companion.flightlog.logproc`), or in this process (:class:`McapFile`). If the
    logging process dies after it started the file, the MCAP ends there (counted in ``errors``,
    logged); the CSVs go on."""

    def __init__(self, path: str | Path, streams: Mapping[str, Sequence[str]]):
        from companion.flightlog import csvlog, logproc

        self.path = Path(path)
        self._columns = {name: tuple(cols) for name, cols in streams.items()}
        self.dropped_images = 0
        self._errors = 0  # here: a path that could not be computed, a logging process that died
        self._remote_counts = (0, 0)  # the logging process's (errors, messages), once closed
        self._closed = False
        self._lost = False  # the logging process died with the file
        self._mode_lock = threading.Lock()
        self._images: collections.deque[tuple[float, np.ndarray, dict[str, np.ndarray]]] = collections.deque()
        self._pending: collections.deque[tuple[Any, ...]] = collections.deque()
        self._proc = logproc.client()
        self._file: McapFile | None = None
        if self._proc is None:
            self._file = McapFile(self.path, self._columns)
        else:
            self.path.open("wb").close()  # errors raise here; the logging process writes it
            self._id = self._proc.open_mcap(self.path, self._columns)
        self._shared = csvlog._SharedWriter.attach(self, csvlog.FLUSH_PERIOD_S)
        _OPEN.add(self)

    @property
    def errors(self) -> int:
        return self._errors + self._remote_counts[0] + (self._file.errors if self._file is not None else 0)

    @property
    def messages(self) -> int:
        """Messages written (in the logging process: counted once the file is closed)."""
        return self._remote_counts[1] + (self._file.messages if self._file is not None else 0)

    def stream_sink(self, name: str) -> McapStreamSink | RemoteStreamSink:
        """What a CSV stream hands its batches to: the in-process file's
        :class:`McapStreamSink`, or a :class:`RemoteStreamSink` naming the stream in the logging
        process."""
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

    def _drain(self) -> None:
        """Hand the queued frames and path updates to the file, then (in process) end the chunk
        and flush it to the OS (the shared writer thread, every 0.1 s)."""
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
        _OPEN.discard(self)
        self._shared.detach(self)
        self._drain()
        self._closed = True
        if self._file is None and self._proc is not None and not self._lost:
            reply = self._proc.request(("mclose", self._id))
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


class McapStreamSink:
    """One CSV stream's link to the MCAP: :meth:`encode` formats a batch once into the CSV text
    and the JSON messages (the CSV writer writes the text), :meth:`publish` logs the messages
    (and, for ``ekf.csv``, the pose and sigma messages) once the CSV has them."""

    def __init__(self, owner: McapFile, name: str):
        self._owner = owner
        self.name = name
        self.columns = owner._columns[name]
        self.encode = batch_encoder(self.columns)
        self._ekf = name == "ekf.csv"
        self._idx = {c: i for i, c in enumerate(self.columns)}
        self._channel = owner._channels[stream_topic(name)]
        base = getattr(self._channel, "base", None)  # foxglove.Channel's native channel
        self._log: Callable[[bytes, int, None], None] = (
            base.log if base is not None else lambda data, t, _: self._channel.log(data, log_time=t)
        )

    def publish(self, batch: list[tuple[object, ...]], payloads: list[bytes] | None) -> None:
        m = self._owner
        with m._lock:
            if m._failed or m._closed:
                return
            try:
                if payloads is None:  # the batch encoder failed: the CSV was written without it
                    payloads = [encode_row(self.columns, row) for row in batch]
                if self._ekf:
                    for row, data in zip(batch, payloads, strict=True):
                        t = float(row[0])  # type: ignore[arg-type]
                        self._channel.log(data, log_time=time_ns(t))
                        m._ekf_messages(self._idx, row, t)
                else:
                    # the SDK's Channel.log for bytes, without its checks; log_time as time_ns()
                    log_ = self._log
                    for row, data in zip(batch, payloads, strict=True):
                        t = float(row[0])  # type: ignore[arg-type]
                        log_(data, round(t * 1e9) if 0.0 < t < math.inf else 0, None)
                m.messages += len(batch)
                m._dirty = True
            except Exception as err:
                m._fail(err)


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
