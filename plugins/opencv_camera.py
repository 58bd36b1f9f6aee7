"""OpenCV camera driver: a V4L2 device index, a video/image file, or a GStreamer pipeline string.

A capture thread keeps only the newest frame (bounded, keep-newest), stamped at capture on the
monotonic clock minus the configured exposure latency; ``read()`` never blocks the event loop.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import ClassVar

import cv2

from companion.plugin_api import Frame, PluginError

log = logging.getLogger(__name__)


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
    ):
        self.source = source
        self.width_px, self.height_px, self.fps = width_px, height_px, fps
        self.latency_s = latency_s
        self.loop_file = loop_file
        self._clock = clock
        self._cap: cv2.VideoCapture | None = None
        self._lock = threading.Lock()
        self._latest: Frame | None = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.frames = 0
        self.read_failures = 0
        self.eof = False

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
            t = self._clock() - self.latency_s
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
            with self._lock:
                self._latest = Frame(t, img, self.frames)
            self.frames += 1

    def read(self) -> Frame | None:
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
