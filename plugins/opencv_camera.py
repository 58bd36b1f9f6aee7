"""OpenCV camera driver: a V4L2 device index, a video/image file, or a GStreamer pipeline string.

A capture thread keeps only the newest frame (bounded, keep-newest), stamped at capture on the
monotonic clock minus the configured exposure latency; ``read()`` never blocks the event loop.
``driver_stamp=True`` (a V4L2 device; ``landing.camera_time`` = driver / measured, docs/clock.md):
each frame also carries the V4L2 buffer's timestamp (``CAP_PROP_POS_MSEC``, ``CLOCK_MONOTONIC``,
the clock ``time.monotonic`` reads) as its capture stamp, and its arrival.
It offers the frame-listener capability (version 1, see :mod:`companion.plugin_api`): the capture
thread calls the listener after each new frame, so the app reads it at once instead of on its
next poll.

Playback of a recorded flight (``playback=True``, hardware-in-the-loop with a camera file): no
thread; the file's frames are played at their *own* times on the injected clock (the shell's,
virtual in simulation). Frame i was exposed at ``frame_times[i] + time_offset_s`` -- the times
from a CSV written beside the video (:class:`CameraFileWriter`, columns ``frame,time_s``) or,
without one, from the container's timestamps -- and becomes readable ``latency_s`` later.
``read()`` returns the newest frame that is readable and not yet returned; frames it passed are
dropped, as a live camera's keep-newest buffer drops them. Playback has no capture thread and
offers no frame listener (``frame_listener_version`` is None): it is polled. :class:`CameraFileWriter` records
frames with their exposure times in that format.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import ClassVar

import cv2

from companion.flightlog.camera_file import (
    CODECS,
    TIMES_COLUMNS,
    CameraFileError,
    CameraFileWriter,
    RecordingCamera,
    times_path_for,
)
from companion.flightlog.camera_file import load_frame_times as _load_frame_times
from companion.plugin_api import FRAME_LISTENER_VERSION, Frame, FrameListenerSlot, PluginError

__all__ = [
    "CODECS",
    "TIMES_COLUMNS",
    "CameraFileWriter",
    "OpenCvCamera",
    "RecordingCamera",
    "load_frame_times",
    "times_path_for",
]

log = logging.getLogger(__name__)


def _is_v4l2_device(source: str | int) -> bool:
    """A V4L2 device: an index, or a /dev/video* path."""
    return isinstance(source, int) or source.isdigit() or source.startswith("/dev/video")


def load_frame_times(path: str | Path) -> list[float]:
    """:func:`companion.flightlog.camera_file.load_frame_times`, its errors as :class:`PluginError`."""
    try:
        return _load_frame_times(path)
    except CameraFileError as err:
        raise PluginError(str(err)) from None


class OpenCvCamera:
    api_version: ClassVar[int] = 1

    def __init__(
        self,
        source: str | int = 0,
        width_px: int | None = None,
        height_px: int | None = None,
        fps: float | None = None,
        latency_s: float = 0.0,
        loop_file: bool = False,
        clock: Callable[[], float] = time.monotonic,
        playback: bool = False,
        frame_times: str | Path | Sequence[float] | None = None,
        time_offset_s: float = 0.0,
        driver_stamp: bool = False,
    ):
        if driver_stamp and (playback or clock is not time.monotonic or not _is_v4l2_device(source)):
            raise PluginError(
                f"camera {source!r}: driver_stamp needs a live V4L2 device (an index or /dev/video*) on the "
                "monotonic clock: its buffer timestamps are CLOCK_MONOTONIC; a file or pipeline has none"
            )
        self.driver_stamp = driver_stamp
        self.stamps_missing = 0  # driver_stamp: frames whose buffer had no timestamp (0 ms)
        self.source = source
        self.width_px, self.height_px, self.fps = width_px, height_px, fps
        self.latency_s = latency_s
        self.loop_file = loop_file
        self._clock = clock
        self.playback = playback
        if frame_times is not None and not playback:
            raise PluginError(f"camera {source!r}: frame_times given without playback=True")
        if not math.isfinite(time_offset_s):
            raise PluginError(f"camera {source!r}: time_offset_s = {time_offset_s!r}: expected a finite number")
        self.time_offset_s = float(time_offset_s)
        self._frame_times_arg = frame_times
        self._times: list[float] | None = None
        self._pending: Frame | None = None  # playback: the next decoded frame, not yet due
        self.dropped = 0  # playback: frames passed over by a newer readable one
        self._cap: cv2.VideoCapture | None = None
        self._lock = threading.Lock()
        self._latest: Frame | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._listener = FrameListenerSlot(repr(source))
        self.frames = 0
        self.read_failures = 0
        self.eof = False

    @property
    def frame_listener_version(self) -> int | None:
        """The frame-listener capability: the live capture thread notifies, playback does not."""
        return None if self.playback else FRAME_LISTENER_VERSION

    def set_frame_listener(self, callback: Callable[[], None] | None) -> None:
        """``callback()`` on the capture thread after each new frame (None detaches); see
        :class:`companion.plugin_api.FrameListenerSlot`."""
        if self.playback and callback is not None:
            raise PluginError(f"camera {self.source!r}: playback has no capture thread to notify from; poll read()")
        self._listener.set(callback)

    @property
    def listener_errors(self) -> int:
        """Frame-listener calls that raised (each counted, the capture goes on)."""
        return self._listener.errors

    def _open(self) -> cv2.VideoCapture:
        src = self.source
        if isinstance(src, str) and src.isdigit():
            src = int(src)
        # OpenCV prints each backend's failed attempt as a WARN line on stderr; the error below says it once
        level = cv2.utils.logging.getLogLevel()
        cv2.utils.logging.setLogLevel(min(level, cv2.utils.logging.LOG_LEVEL_ERROR))
        try:
            gst = isinstance(src, str) and "!" in src
            cap = cv2.VideoCapture(src, cv2.CAP_GSTREAMER) if gst else cv2.VideoCapture(src)
        finally:
            cv2.utils.logging.setLogLevel(level)
        if not cap.isOpened():
            raise PluginError(f"camera {self.source!r}: cannot open (no such device/file, or no backend for it)")
        if self.width_px:
            cap.set(cv2.CAP_PROP_FRAME_WIDTH, self.width_px)
        if self.height_px:
            cap.set(cv2.CAP_PROP_FRAME_HEIGHT, self.height_px)
        if self.fps:
            cap.set(cv2.CAP_PROP_FPS, self.fps)
        return cap

    def start(self) -> None:
        if self.playback:
            self._start_playback()
            return
        if self._thread is not None:
            return
        self._cap = self._open()
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name=f"camera-{self.source}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        assert self._cap is not None
        while not self._stop.is_set():
            ok, img = self._cap.read()
            arrival_s = self._clock()
            t = arrival_s - self.latency_s
            if not ok or img is None:
                if self.loop_file and self.frames > 0:
                    self._cap.set(cv2.CAP_PROP_POS_FRAMES, 0)
                    continue
                self.read_failures += 1
                self.eof = True
                if self.read_failures in (1, 10, 100):
                    log.warning("camera %r: read failed (%d so far)", self.source, self.read_failures)
                if isinstance(self.source, str) and not self.source.isdigit() and "!" not in self.source:
                    break  # end of file
                time.sleep(0.01)
                continue
            frame = Frame(t, img, self.frames)
            if self.driver_stamp:
                stamp_ms = float(self._cap.get(cv2.CAP_PROP_POS_MSEC))  # V4L2 buffer timestamp
                if stamp_ms > 0.0:
                    frame = Frame(t, img, self.frames, capture_time_s=stamp_ms / 1e3, arrival_time_s=arrival_s)
                else:
                    self.stamps_missing += 1
            with self._lock:
                self._latest = frame
            self.frames += 1
            self._listener.notify()  # never raises

    # ---- playback of a recorded file ----------------------------------------------------------
    def _start_playback(self) -> None:
        if self._cap is not None:
            return
        if not isinstance(self.source, str) or self.source.isdigit() or "!" in self.source:
            raise PluginError(f"camera {self.source!r}: playback needs a video file, not a device or pipeline")
        arg = self._frame_times_arg
        if isinstance(arg, str | Path):
            self._times = load_frame_times(arg)
        elif arg is not None:
            self._times = [float(t) for t in arg]
            if not all(math.isfinite(t) for t in self._times) or any(
                b <= a for a, b in zip(self._times, self._times[1:], strict=False)
            ):
                raise PluginError(f"camera {self.source!r}: frame_times must be finite and increasing")
        self._cap = self._open_file()
        n = int(self._cap.get(cv2.CAP_PROP_FRAME_COUNT))
        if self._times is not None and n > 0 and n != len(self._times):
            where = str(arg) if isinstance(arg, str | Path) else "frame_times"
            raise PluginError(
                f"camera {self.source!r}: the video has {n} frames but {where} lists {len(self._times)} times: "
                "expected one time per frame"
            )
        self._pending = self._decode_next()
        if self._pending is None:
            raise PluginError(f"camera {self.source!r}: no frame could be read from the file")
        h, w = self._pending.image.shape[:2]
        if (self.width_px and w != self.width_px) or (self.height_px and h != self.height_px):
            raise PluginError(
                f"camera {self.source!r}: frames are {w}x{h} px but the calibration expects "
                f"{self.width_px}x{self.height_px}: expected the recording's own calibration"
            )
        log.info(
            "camera %r: playing back %s frames from t = %.3f s (times from %s)",
            self.source,
            n if n > 0 else "?",
            self._pending.time_s,
            "the frame-times file" if self._times is not None else "the container",
        )

    def _open_file(self) -> cv2.VideoCapture:
        cap = cv2.VideoCapture(str(self.source))
        if not cap.isOpened():
            raise PluginError(f"camera {self.source!r}: cannot open the video file")
        return cap

    def _decode_next(self) -> Frame | None:
        assert self._cap is not None
        i = self.frames
        if self._times is None:
            # the container's timestamp of the frame about to be decoded
            ok = self._cap.grab()
            t_file = self._cap.get(cv2.CAP_PROP_POS_MSEC) / 1000.0
            ok, img = self._cap.retrieve() if ok else (False, None)
        else:
            if i >= len(self._times):
                self.eof = True
                return None
            ok, img = self._cap.read()
            t_file = self._times[i]
        if not ok or img is None:
            self.eof = True
            if self._times is not None and i < len(self._times):
                log.warning("camera %r: the video ended after %d of %d timed frames", self.source, i, len(self._times))
            return None
        self.frames += 1
        return Frame(t_file + self.time_offset_s, img, i)

    def _read_playback(self) -> Frame | None:
        if self._cap is None:
            raise PluginError(f"camera {self.source!r}: read() before start()")
        now = self._clock()
        out: Frame | None = None
        while self._pending is not None and self._pending.time_s + self.latency_s <= now:
            if out is not None:
                self.dropped += 1
            out = self._pending
            self._pending = self._decode_next()
        return out

    def read(self) -> Frame | None:
        if self.playback:
            return self._read_playback()
        with self._lock:
            f, self._latest = self._latest, None
        return f

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._cap is not None:
            self._cap.release()
            self._cap = None
