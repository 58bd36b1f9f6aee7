"""OpenCV camera plugin, playback of a recorded file at its own frame times on an injected clock,
and the recorder that writes the video with its ``frame,time_s`` CSV."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from companion.flightlog.camera_file import CameraFileError, RecordingCamera
from companion.plugin_api import Frame, PluginError, create
from companion_plugins.opencv_camera import CameraFileWriter, load_frame_times, times_path_for


class FakeClock:
    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def __call__(self) -> float:
        return self.t


def _record(path: Path, times: list[float], size: tuple[int, int] = (160, 120)) -> CameraFileWriter:
    w = CameraFileWriter(path, fps=30.0)
    rng = np.random.default_rng(0)
    for i, t in enumerate(times):
        img = np.full((size[1], size[0]), 20 + 10 * i, np.uint8)
        img[10:30, 10:30] = rng.integers(0, 255, (20, 20), dtype=np.uint8)
        w.write(img, t)
    w.close()
    return w


def _player(path: Path, clock: FakeClock, **kw: object) -> object:
    cam = create("companion.cameras", "opencv", source=str(path), clock=clock, playback=True, **kw)
    cam.start()
    return cam


@pytest.mark.parametrize("ext", ["avi", "mkv"])
def test_frames_come_at_their_recorded_times_plus_latency(tmp_path: Path, ext: str) -> None:
    times = [10.0, 10.05, 10.1, 10.3, 10.31, 10.32, 11.0]  # irregular, as read in flight
    video = tmp_path / f"cam.{ext}"
    w = _record(video, times)
    assert w.frames == len(times) and times_path_for(video).is_file()
    assert load_frame_times(times_path_for(video)) == times
    clock = FakeClock(9.0)
    cam = _player(video, clock, frame_times=str(times_path_for(video)), latency_s=0.02)
    assert cam.read() is None  # type: ignore[attr-defined]
    clock.t = 10.019
    assert cam.read() is None  # type: ignore[attr-defined]  # exposed, not yet through the latency
    clock.t = 10.02
    f = cam.read()  # type: ignore[attr-defined]
    assert f is not None and f.time_s == 10.0 and f.index == 0 and f.image.shape == (120, 160, 3)
    assert cam.read() is None  # type: ignore[attr-defined]  # each frame once
    clock.t = 10.35  # frames 1..5 readable: the newest is handed out, the older ones dropped
    f = cam.read()  # type: ignore[attr-defined]
    assert f is not None and f.time_s == 10.32 and f.index == 5
    assert cam.dropped == 4  # type: ignore[attr-defined]
    # the pixels are the recorded frame's (grey level 20 + 10 i, through the codec)
    assert abs(float(np.mean(f.image[60:, 60:])) - 70.0) < 3.0
    clock.t = 20.0
    f = cam.read()  # type: ignore[attr-defined]
    assert f is not None and f.index == 6
    assert cam.read() is None and cam.eof  # type: ignore[attr-defined]
    cam.stop()  # type: ignore[attr-defined]


def test_container_timestamps_and_offset_without_a_times_file(tmp_path: Path) -> None:
    video = tmp_path / "plain.avi"
    wr = cv2.VideoWriter(str(video), cv2.VideoWriter.fourcc(*"MJPG"), 25.0, (64, 48))
    for i in range(5):
        wr.write(np.full((48, 64, 3), i * 40, np.uint8))
    wr.release()
    clock = FakeClock(100.0)
    cam = _player(video, clock, time_offset_s=100.0)
    got = []
    for k in range(10):
        clock.t = 100.0 + 0.02 * k
        f = cam.read()  # type: ignore[attr-defined]
        if f is not None:
            got.append(f.time_s)
    assert got == pytest.approx([100.0, 100.04, 100.08, 100.12, 100.16])


@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("t,x\n0,1.0\n", "line 1: header ['t', 'x']: expected the columns frame,time_s"),
        ("frame,time_s\n0,1.0\n2,1.1\n", "line 3: frame = '2': expected 1"),
        ("frame,time_s\n0,1.0\n1,abc\n", "line 3: time_s = 'abc': expected a finite number"),
        ("frame,time_s\n0,1.0\n1,nan\n", "line 3: time_s = 'nan'"),
        ("frame,time_s\n0,1.0\n1,1.0\n", "line 3: time_s = '1.0': expected increasing times"),
        ("frame,time_s\n0,1.0,3\n", "line 2: ['0', '1.0', '3']: expected 2 values"),
        ("frame,time_s\n", "no frames"),
    ],
)
def test_bad_times_files_name_file_line_column_value(tmp_path: Path, text: str, needle: str) -> None:
    p = tmp_path / "times.csv"
    p.write_text(text)
    with pytest.raises(PluginError) as err:
        load_frame_times(p)
    assert str(p) in str(err.value) and needle in str(err.value)


def test_playback_refuses_mismatched_files_and_devices(tmp_path: Path) -> None:
    video = tmp_path / "cam.avi"
    _record(video, [1.0, 1.1, 1.2])
    short = tmp_path / "short.csv"
    short.write_text("frame,time_s\n0,1.0\n1,1.1\n")
    with pytest.raises(PluginError, match=r"has 3 frames but .*short.csv lists 2 times"):
        _player(video, FakeClock(), frame_times=str(short))
    with pytest.raises(PluginError, match="frames are 160x120 px but the calibration expects 640x480"):
        _player(video, FakeClock(), width_px=640, height_px=480)
    with pytest.raises(PluginError, match="needs a video file"):
        _player(Path("0"), FakeClock())  # type: ignore[arg-type]
    with pytest.raises(PluginError, match="cannot open"):
        _player(tmp_path / "missing.avi", FakeClock())
    with pytest.raises(PluginError, match="without playback"):
        create("companion.cameras", "opencv", source=str(video), frame_times=[1.0])
    with pytest.raises(PluginError, match="before start"):
        create("companion.cameras", "opencv", source=str(video), playback=True).read()


def test_writer_refuses_bad_input(tmp_path: Path) -> None:
    with pytest.raises(CameraFileError, match=r"extension '.gif': expected one of"):
        CameraFileWriter(tmp_path / "x.gif")
    w = CameraFileWriter(tmp_path / "x.avi")
    w.write(np.zeros((48, 64), np.uint8), 1.0)
    with pytest.raises(ValueError, match=r"must be finite and after 1\.0"):
        w.write(np.zeros((48, 64), np.uint8), 1.0)
    with pytest.raises(ValueError, match="frame 1 is 32x48, the first was"):
        w.write(np.zeros((48, 32), np.uint8), 2.0)
    w.close()


class _Source:
    api_version = 1

    def __init__(self) -> None:
        self.started = self.stopped = False
        grey = [np.full((48, 64), v, np.uint8) for v in (50, 90)]
        self.queue: list[Frame | None] = [None, Frame(1.0, grey[0], 0), Frame(1.5, grey[1], 1)]

    def start(self) -> None:
        self.started = True

    def read(self) -> Frame | None:
        return self.queue.pop(0) if self.queue else None

    def stop(self) -> None:
        self.stopped = True


def test_recording_camera_writes_what_it_hands_out_and_plays_back(tmp_path: Path) -> None:
    src = _Source()
    rec = RecordingCamera(src, CameraFileWriter(tmp_path / "r.mkv", fps=2.0))
    rec.start()
    got = [rec.read() for _ in range(4)]
    rec.stop()
    assert src.started and src.stopped and rec.recorded == 2
    assert [f.time_s for f in got if f is not None] == [1.0, 1.5]
    assert load_frame_times(times_path_for(tmp_path / "r.mkv")) == [1.0, 1.5]
    cam = _player(tmp_path / "r.mkv", FakeClock(2.0), frame_times=str(times_path_for(tmp_path / "r.mkv")))
    f0 = cam.read()  # type: ignore[attr-defined]
    assert f0 is not None and f0.time_s == 1.5 and float(np.mean(f0.image)) == 90.0  # FFV1 is lossless


def test_recording_camera_passes_the_frame_listener_through(tmp_path: Path) -> None:
    from companion.plugin_api import FRAME_LISTENER_VERSION, FrameListenerSlot, frame_listener_of

    class _Notifying(_Source):
        frame_listener_version = FRAME_LISTENER_VERSION

        def __init__(self) -> None:
            super().__init__()
            self.queue = self.queue[1:]  # told only when a frame is there
            self.listener = FrameListenerSlot("test")

        def set_frame_listener(self, callback: Any) -> None:
            self.listener.set(callback)

    plain = RecordingCamera(_Source(), CameraFileWriter(tmp_path / "a.mkv", fps=2.0))
    assert plain.frame_listener_version is None and frame_listener_of(plain) is None  # polled, as its camera
    inner = _Notifying()
    rec = RecordingCamera(inner, CameraFileWriter(tmp_path / "b.mkv", fps=2.0))
    attach = frame_listener_of(rec)
    assert rec.frame_listener_version == FRAME_LISTENER_VERSION and attach is not None
    seen: list[Frame | None] = []
    attach(lambda: seen.append(rec.read()))
    inner.listener.notify()  # the inner camera's capture thread announces a frame: it is recorded
    attach(None)
    inner.listener.notify()
    rec.stop()
    plain.stop()
    assert [f.time_s for f in seen if f is not None] == [1.0] and rec.recorded == 1
