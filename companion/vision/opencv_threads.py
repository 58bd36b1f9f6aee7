"""How many threads OpenCV's parallel loops may use, process-wide (``cv2.setNumThreads``).

OpenCV runs ``detectMarkers``, ``warpPerspective`` and ``remap`` on a worker pool of one thread per
CPU by default. On a companion computer's 640x480 frames that pool costs more than it saves: the
detector already runs off the event loop (an executor thread), and the pool's workers, woken for
every call, keep spinning between the small jobs. One thread saves the pool's share of a core
(``companion bench app`` shows it) and keeps detection well inside a 33 ms frame period.
"""

from __future__ import annotations

import logging

import cv2

log = logging.getLogger(__name__)


def check_opencv_threads(threads: object) -> int:
    """``threads`` if it is a valid ``opencv_threads`` setting (an integer >= -1), else ValueError
    naming the key."""
    if isinstance(threads, bool) or not isinstance(threads, int) or threads < -1:
        raise ValueError(f"opencv_threads = {threads!r}: must be an integer >= -1 (-1: OpenCV's default)")
    return threads


def apply_opencv_threads(threads: int) -> int:
    """Set OpenCV's thread count for this process: ``threads`` >= 1 threads (1: every call runs on
    the calling thread), 0 the same as 1 (OpenCV: threading off), -1 OpenCV's default (one per
    CPU). Returns what OpenCV now uses. Raises ValueError for anything below -1."""
    check_opencv_threads(threads)
    before = cv2.getNumThreads()
    cv2.setNumThreads(threads)
    now = cv2.getNumThreads()
    if now != before:
        log.debug("OpenCV threads %d -> %d (opencv_threads = %d)", before, now, threads)
    return now
