"""The writer of one ``flight.mcap`` (:class:`McapFile`), in the flight's process or in the
logging process: foxglove-sdk's MCAP writer (``foxglove.open_mcap``, zstd chunks) into a context
of its own, so the flight's channels reach this file only (not a live server).

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
it; the last one is the final one. Each CSV stream's batches reach the file through its
:class:`McapStreamSink`, which formats a batch once for the CSV and the MCAP
(:func:`~companion.flightlog.mcap_encoding.batch_encoder`). Ending and flushing the chunk after
every hand-over (:meth:`McapFile.flush`) leaves a readable file without its summary after a hard
crash (the reader stops at the torn record).
"""

from __future__ import annotations

import base64
import json
import logging
import math
import threading
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.flightlog.losses import cause_of, note_fault
from companion.flightlog.mcap_encoding import (
    PROFILE,
    batch_encoder,
    compact_json,
    encode_row,
    row_schema,
    stream_topic,
)
from companion.foxglove_schemas import (
    EKF_SIGMA_SCHEMA,
    ENU_FROM_NED_QUAT,
    FOXGLOVE_SCHEMAS,
    foxglove_time,
    quat_from_euler_zyx,
    time_ns,
)

log = logging.getLogger(__name__)

JPEG_QUALITY = 90

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
                schema=foxglove.Schema(name=schema_name, encoding="jsonschema", data=compact_json(schema)),
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
            compact_json(
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
            cause = cause_of(err, self.path)  # the SDK's error carries no errno: the disk's state says
            note_fault(self.path, cause)
            log.error("%s: %s: cannot write the MCAP any more (the CSVs go on): %s", self.path, cause.value, err)
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
        self._add("/ekf/pose", t, compact_json(pose))
        sig: dict[str, float] = {"time_s": t}
        for a in ("north", "east", "down"):
            sig[f"sigma_{a}_m"] = math.sqrt(max(0.0, f(f"var_{a}_m2")))
        for a in ("roll", "pitch", "yaw"):
            sig[f"sigma_{a}_deg"] = math.degrees(math.sqrt(max(0.0, f(f"var_{a}_rad2"))))
        self._add("/ekf/sigma", t, compact_json(sig))

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
        self._add("/camera/image", t, compact_json(msg))
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
        self._add("/camera/markers", t, compact_json({"circles": [], "points": points, "texts": texts}))

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
        self._add("/mission/path", time_s, compact_json({"deletions": [], "entities": [entity]}))

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
