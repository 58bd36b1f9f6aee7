"""A recorded camera: a video file plus the exposure time of each of its frames.

The format the OpenCV camera plugin plays back (``companion demo --camera-file``) and that
``companion demo --record-camera`` / ``companion fly --record-camera`` write: the video (codec
from the extension, :data:`CODECS`) and beside it ``<video>.csv`` with the columns
``frame,time_s`` -- frame index from 0 and its exposure time in seconds on the clock of the
flight that recorded it (the shell's monotonic clock; virtual in simulation), as every other
log in the run folder is stamped.
"""

from __future__ import annotations

import csv
import logging
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any, ClassVar

import cv2
import numpy as np

log = logging.getLogger(__name__)


class CameraFileError(ValueError):
    """A camera recording or its frame-times file is unusable; the message names the file, the
    line, the column, the value and what is expected."""


TIMES_COLUMNS = ("frame", "time_s")
#: video codecs by file extension: FFV1 is lossless (.mkv), MJPG (.avi) and mp4v (.mp4) are what
#: most cameras and recorders write
CODECS = {".mkv": "FFV1", ".avi": "MJPG", ".mp4": "mp4v"}


def times_path_for(video: str | Path) -> Path:
    """The frame-times CSV written beside a recording: ``<video>.csv`` (e.g. ``cam.avi.csv``)."""
    return Path(f"{video}.csv")


def load_frame_times(path: str | Path) -> list[float]:
    """Frame exposure times (seconds) from a CSV with the columns ``frame,time_s``, one row per
    video frame in order (``frame`` = 0, 1, 2, ...). Every problem is a :class:`CameraFileError`
    naming the file, the line, the column, the value and what is expected."""
    p = Path(path)
    try:
        with p.open(newline="") as fh:
            rows = list(csv.reader(fh))
    except OSError as exc:
        raise CameraFileError(f"{p}: cannot read frame times: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise CameraFileError(f"{p}: not UTF-8 text: {exc}") from None
    except csv.Error as exc:  # e.g. a field longer than csv.field_size_limit()
        raise CameraFileError(f"{p}: not a frame-times CSV: {exc}") from None
    if not rows or tuple(c.strip() for c in rows[0]) != TIMES_COLUMNS:
        head = rows[0] if rows else []
        raise CameraFileError(f"{p}: line 1: header {head!r}: expected the columns {','.join(TIMES_COLUMNS)}")
    times: list[float] = []
    for i, row in enumerate(rows[1:]):
        line = i + 2
        if not row:
            continue
        if len(row) != 2:
            raise CameraFileError(f"{p}: line {line}: {row!r}: expected 2 values (frame, time_s)")
        if row[0].strip() != str(len(times)):
            raise CameraFileError(
                f"{p}: line {line}: frame = {row[0]!r}: expected {len(times)} (frames in order from 0)"
            )
        try:
            t = float(row[1])
        except ValueError:
            t = math.nan
        if not math.isfinite(t):
            raise CameraFileError(f"{p}: line {line}: time_s = {row[1]!r}: expected a finite number of seconds")
        if times and t <= times[-1]:
            raise CameraFileError(
                f"{p}: line {line}: time_s = {row[1]!r}: expected increasing times (previous {times[-1]!r})"
            )
        times.append(t)
    if not times:
        raise CameraFileError(f"{p}: no frames: expected one row per video frame")
    return times


class CameraFileWriter:
    """Record frames with their exposure times: the video (codec from the extension, see
    :data:`CODECS`) and the ``frame,time_s`` CSV beside it (:func:`times_path_for`), the format
    :class:`OpenCvCamera` plays back. Grey or BGR frames; the size is fixed by the first frame."""

    def __init__(self, video: str | Path, fps: float = 30.0, times: str | Path | None = None, quality: int = 95):
        self.video = Path(video)
        codec = CODECS.get(self.video.suffix.lower())
        if codec is None:
            raise CameraFileError(
                f"recording {self.video}: extension {self.video.suffix!r}: expected one of {sorted(CODECS)}"
            )
        if not (math.isfinite(fps) and fps > 0):
            raise CameraFileError(f"recording {self.video}: fps = {fps!r}: expected a positive number")
        self.codec = codec
        self.fps = fps
        self.quality = quality
        self.times_path = Path(times) if times is not None else times_path_for(self.video)
        self._writer: cv2.VideoWriter | None = None
        self._size: tuple[int, int] | None = None
        self._times = self.times_path.open("w", newline="")
        self._csv = csv.writer(self._times)
        self._csv.writerow(TIMES_COLUMNS)
        self._last_t = -math.inf
        self.frames = 0

    def write(self, image: np.ndarray, time_s: float) -> None:
        if not (math.isfinite(time_s) and time_s > self._last_t):
            raise ValueError(f"recording {self.video}: frame time {time_s!r} must be finite and after {self._last_t!r}")
        img = image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2BGR)
        h, w = img.shape[:2]
        if self._writer is None:
            self._writer = cv2.VideoWriter(str(self.video), cv2.VideoWriter.fourcc(*self.codec), self.fps, (w, h))
            if not self._writer.isOpened():
                raise CameraFileError(f"recording {self.video}: OpenCV cannot write codec {self.codec}")
            self._writer.set(cv2.VIDEOWRITER_PROP_QUALITY, float(self.quality))
            self._size = (w, h)
        elif (w, h) != self._size:
            raise ValueError(f"recording {self.video}: frame {self.frames} is {w}x{h}, the first was {self._size}")
        self._writer.write(img)
        self._csv.writerow((self.frames, repr(float(time_s))))
        self._last_t = float(time_s)
        self.frames += 1

    def close(self) -> None:
        if self._writer is not None:
            self._writer.release()
            self._writer = None
        if not self._times.closed:
            self._times.close()
            log.info("recorded %d frames to %s (times in %s)", self.frames, self.video, self.times_path)


class RecordingCamera:
    """A camera plugin (api_version 1) that records what it hands out: every frame ``read()``
    returns is written with its exposure time by ``writer``, then passed on. ``stop()`` stops the
    camera and closes the recording."""

    api_version: ClassVar[int] = 1

    def __init__(self, inner: Any, writer: CameraFileWriter):
        self.inner = inner
        self.writer = writer
        self.recorded = 0

    @property
    def frame_listener_version(self) -> Any:
        """The wrapped camera's frame-listener capability (plugin_api), passed through: the frame
        it notifies is the one the next ``read()`` records."""
        return getattr(self.inner, "frame_listener_version", None)

    def set_frame_listener(self, callback: Callable[[], None] | None) -> None:
        self.inner.set_frame_listener(callback)

    def start(self) -> None:
        self.inner.start()

    def read(self) -> Any:
        frame = self.inner.read()
        if frame is not None:
            self.writer.write(frame.image, frame.time_s)
            self.recorded += 1
        return frame

    def stop(self) -> None:
        try:
            self.inner.stop()
        finally:
            self.writer.close()
