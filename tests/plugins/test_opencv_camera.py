import itertools
import logging
import threading
import time

import cv2
import numpy as np
import pytest

from companion.plugin_api import PluginError, create


def test_reads_a_video_file_with_capture_stamps(tmp_path):
    path = tmp_path / "clip.avi"
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (160, 120))
    assert w.isOpened()
    for i in range(20):
        img = np.full((120, 160, 3), i * 10, np.uint8)
        w.write(img)
    w.release()
    t = [100.0]

    def clock():
        t[0] += 0.01
        return t[0]

    cam = create("companion.cameras", "opencv", source=str(path), latency_s=0.005, clock=clock)
    cam.start()
    frames = []
    deadline = time.monotonic() + 5
    while not cam.eof and time.monotonic() < deadline:
        f = cam.read()
        if f is not None:
            frames.append(f)
        time.sleep(0.001)
    last = cam.read()
    if last is not None:
        frames.append(last)
    cam.stop()
    assert cam.frames == 20 and frames
    assert frames[-1].image.shape == (120, 160, 3)
    assert all(b.time_s > a.time_s for a, b in itertools.pairwise(frames))
    assert frames[0].time_s < 100.2  # stamped from the injected clock, minus latency


def test_missing_device_is_a_clear_error(tmp_path):
    cam = create("companion.cameras", "opencv", source=str(tmp_path / "nope.avi"))
    with pytest.raises(PluginError, match="cannot open"):
        cam.start()


def _clip(path, n: int) -> None:
    w = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    assert w.isOpened()
    for i in range(n):
        w.write(np.full((48, 64, 3), i * 10, np.uint8))
    w.release()


def _run_to_eof(cam, timeout_s: float = 5.0) -> None:
    cam.start()
    deadline = time.monotonic() + timeout_s
    while not cam.eof and time.monotonic() < deadline:
        time.sleep(0.002)
    cam.stop()


def test_the_capture_thread_notifies_each_frame_once_it_is_readable(tmp_path):
    from companion.plugin_api import FRAME_LISTENER_VERSION, frame_listener_of

    path = tmp_path / "clip.avi"
    _clip(path, 12)
    cam = create("companion.cameras", "opencv", source=str(path))
    assert cam.frame_listener_version == FRAME_LISTENER_VERSION and frame_listener_of(cam) is not None
    seen = []

    def listener() -> None:  # on the capture thread: the frame it announces is readable now
        f = cam.read()
        seen.append((f.index if f is not None else None, threading.current_thread().name))

    cam.set_frame_listener(listener)
    _run_to_eof(cam)
    assert [i for i, _ in seen] == list(range(12))
    assert {name for _, name in seen} == {f"camera-{path}"}


def test_a_failing_listener_is_logged_and_capture_goes_on(tmp_path, caplog):
    path = tmp_path / "clip.avi"
    _clip(path, 10)
    cam = create("companion.cameras", "opencv", source=str(path))
    calls = []

    def listener() -> None:
        calls.append(1)
        raise RuntimeError("listener bug")

    cam.set_frame_listener(listener)
    with caplog.at_level(logging.ERROR, logger="companion.plugin_api"):
        _run_to_eof(cam)
    assert cam.frames == 10 and len(calls) == 10 and cam.listener_errors == 10
    errors = [r for r in caplog.records if "listener bug" in r.getMessage()]
    assert len(errors) == 1 and "capture goes on" in errors[0].getMessage()  # the first, not every frame


def test_a_detached_listener_is_not_called(tmp_path):
    path = tmp_path / "clip.avi"
    _clip(path, 10)
    cam = create("companion.cameras", "opencv", source=str(path))
    calls = []
    cam.set_frame_listener(lambda: calls.append(1))
    cam.set_frame_listener(None)
    _run_to_eof(cam)
    assert cam.frames == 10 and not calls


def test_playback_offers_no_frame_listener(tmp_path):
    from companion.plugin_api import frame_listener_of

    path = tmp_path / "clip.avi"
    _clip(path, 3)
    cam = create("companion.cameras", "opencv", source=str(path), playback=True)
    assert cam.frame_listener_version is None and frame_listener_of(cam) is None
    with pytest.raises(PluginError, match="poll read"):
        cam.set_frame_listener(lambda: None)
