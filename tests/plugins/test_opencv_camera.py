import itertools
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
