"""The landing kit of a real vehicle, built from config through the plugin entry points."""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from companion.cli import exits
from companion.cli.main import main
from companion.delivery.landing_setup import LandingSetupError, build_landing_kit, start_sensors

FIXTURES = Path(__file__).parents[1] / "vision" / "fixtures"


def _cfg(mav, **landing):  # type: ignore[no-untyped-def]
    """The PX4 quad's params (the companion's config alone) with fusion on and [landing] keys set."""
    return mav.shipped_config("px4_sih_quad.toml", simulated=False, landing={"fusion": True, **landing})


def test_kit_from_config_sees_the_pad_in_a_real_image_through_the_camera_plugin(mav, tmp_path):
    cfg = _cfg(mav, camera_source=str(FIXTURES / "pad_2m5.png"), use_uwb=False)
    kit = build_landing_kit(cfg)
    assert kit is not None and kit.uwb is None and kit.multilaterator is None
    start_sensors(kit)
    try:
        frame = None
        t_end = time.monotonic() + 5.0
        while frame is None and time.monotonic() < t_end:
            frame = kit.camera.read()
            time.sleep(0.01)
        assert frame is not None, "the opencv plugin delivered no frame of the image file"
        obs = kit.detector.detect(frame.image, frame.time_s)
    finally:
        kit.camera.stop()
    assert obs is not None and "outer" in obs.markers
    # ground truth of the fixture: the pad 2.49 m in front of the camera
    truth = np.array([0.3265974280354187, 0.10833722894894722, 2.493310483037424])
    assert np.linalg.norm(obs.T_camera_pad.t - truth) < 0.05


def test_missing_camera_fails_on_the_ground_and_says_how_to_fly_without(mav, tmp_path):
    kit = build_landing_kit(_cfg(mav, camera_source=str(tmp_path / "no_such_video.mp4"), use_uwb=False))
    with pytest.raises(LandingSetupError, match=r"landing\.camera_source, or set landing\.use_camera = false") as info:
        start_sensors(kit)
    assert info.value.device_missing


def test_missing_uwb_port_fails_on_the_ground(mav, tmp_path):
    kit = build_landing_kit(_cfg(mav, use_camera=False, uwb_port=str(tmp_path / "ttyNOPE")))
    with pytest.raises(LandingSetupError, match=r"landing\.uwb_port, or set landing\.use_uwb = false") as info:
        start_sensors(kit)
    assert info.value.device_missing


def test_bad_files_and_plugins_are_named(mav, tmp_path):
    with pytest.raises(LandingSetupError, match="camera_calibration") as info:
        build_landing_kit(_cfg(mav, camera_calibration="nope.toml"))
    assert not info.value.device_missing  # a setting to change, not a device to plug in
    bad_pad = tmp_path / "pad_bad.toml"
    bad_pad.write_text("[pad]\nouter_size_m = -1.0\n")
    with pytest.raises(LandingSetupError, match=r"landing.pad_file = '.*pad_bad.toml': .*'pad.outer_size_m' = -1.0"):
        build_landing_kit(_cfg(mav, pad_file=str(bad_pad), use_uwb=False))
    bad_anchors = tmp_path / "anchors_bad.toml"
    bad_anchors.write_text('frame = "pad"\n')
    with pytest.raises(LandingSetupError, match=r"landing.uwb_anchors = '.*anchors_bad.toml'"):
        build_landing_kit(_cfg(mav, uwb_anchors=str(bad_anchors), use_camera=False))
    with pytest.raises(LandingSetupError, match=r"no plugin companion\.cameras/nosuch"):
        build_landing_kit(_cfg(mav, camera_plugin="nosuch", use_uwb=False))
    with pytest.raises(LandingSetupError, match="nothing to fuse"):
        build_landing_kit(_cfg(mav, use_camera=False, use_uwb=False))
    assert build_landing_kit(mav.shipped_config("px4_sih_quad.toml", simulated=False)) is None  # fusion off


def test_fly_refuses_to_start_without_its_camera(tmp_path, capsys):
    p = tmp_path / "vehicle.toml"
    p.write_text(
        'autopilot = "px4"\nconnection = "udpin://127.0.0.1:9"\n'
        f'[landing]\nfusion = true\nuse_uwb = false\ncamera_source = "{tmp_path / "missing.mp4"}"\n'
    )
    assert main(["fly", "--params", str(p), "--out", str(tmp_path / "run")]) == exits.DEVICE_MISSING
    assert "use_camera = false" in capsys.readouterr().err
    assert not (tmp_path / "run").exists()  # nothing flew, nothing logged


def test_record_camera_wraps_the_kit_camera_and_writes_the_frames_it_reads(mav, tmp_path):
    from companion.delivery.landing_setup import record_camera
    from companion.flightlog.camera_file import load_frame_times, times_path_for

    cfg = _cfg(mav, camera_source=str(FIXTURES / "pad_2m5.png"), use_uwb=False)
    kit = build_landing_kit(cfg)
    assert kit is not None
    with pytest.raises(LandingSetupError, match=r"--record-camera .*x\.gif: .*extension '\.gif'"):
        record_camera(kit, tmp_path / "x.gif", 30.0)
    video = tmp_path / "cam.mkv"
    rec = record_camera(kit, video, 30.0)
    start_sensors(rec)
    try:
        frame = None
        t_end = time.monotonic() + 5.0
        while frame is None and time.monotonic() < t_end:
            frame = rec.camera.read()
            time.sleep(0.01)
        assert frame is not None
    finally:
        rec.camera.stop()
    assert load_frame_times(times_path_for(video)) == [frame.time_s]
    no_cam = build_landing_kit(_cfg(mav, use_camera=False))
    with pytest.raises(LandingSetupError, match="no camera to record"):
        record_camera(no_cam, video, 30.0)


def test_vision_attitude_reaches_the_kit(mav, tmp_path):
    assert build_landing_kit(_cfg(mav, use_camera=False)).vision_attitude is False  # off by default
    assert build_landing_kit(_cfg(mav, use_camera=False, vision_attitude=True)).vision_attitude is True
