"""The OpenCV camera's driver stamps (docs/clock.md): only a live V4L2 device on the monotonic
clock has them; anything else is refused at construction, naming why."""

from __future__ import annotations

import time

import pytest

from companion.plugin_api import PluginError
from companion_plugins.opencv_camera import OpenCvCamera


@pytest.mark.parametrize(
    "kwargs",
    [
        {"source": "flight.mp4"},  # a file: its positions are not capture times
        {"source": "videotestsrc ! appsink"},  # a pipeline
        {"source": 0, "clock": lambda: 0.0},  # a clock that is not CLOCK_MONOTONIC
        {"source": "clip.mkv", "playback": True},
    ],
)
def test_driver_stamp_needs_a_live_v4l2_device(kwargs):
    with pytest.raises(PluginError, match="driver_stamp needs a live V4L2 device"):
        OpenCvCamera(driver_stamp=True, **kwargs)


def test_a_device_may_have_driver_stamps():
    for source in (0, "2", "/dev/video1"):
        cam = OpenCvCamera(source=source, driver_stamp=True, clock=time.monotonic)
        assert cam.driver_stamp and cam.stamps_missing == 0
