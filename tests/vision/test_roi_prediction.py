"""The detector's ROI follows the pad's image between frames far apart (RoiTrack.prediction):
hand-computed shifts on a pinhole camera, and rendered flights where the ROI at the last place
misses (a rocking hover, a pass over the pad) and the predicted one finds the pad."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.geometry import Transform
from companion.vision.camera import CameraModel, load_default_camera
from companion.vision.detector import DetectorConfig, PadDetector, down_in_camera, level_rotation
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera

CAM = load_default_camera()
LAYOUT = PadLayout()
PINHOLE = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0)


@pytest.fixture(scope="module")
def sim() -> SimulatedCamera:
    return SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=2.0), seed=5)


def _vehicle(north: float, east: float, alt: float, roll: float = 0.0, pitch: float = 0.0) -> Transform:
    return Transform.from_euler([north, east, -alt], roll, pitch, 0.3)


def _corners_at(centre: tuple[float, float], half_px: float) -> dict[str, np.ndarray]:
    cx, cy = centre
    return {
        "outer": np.array(
            [
                [cx - half_px, cy - half_px],
                [cx + half_px, cy - half_px],
                [cx + half_px, cy + half_px],
                [cx - half_px, cy + half_px],
            ]
        )
    }


# ---------------------------------------------------------------------------- hand-computed


def test_a_level_camera_moves_the_roi_at_the_image_velocity_and_scale_rate() -> None:
    """Centre 320 -> 330 px in 0.1 s (0.02 in the z = 1 plane per 0.1 s, f = 500) and the scale
    10% up: 0.25 s after the second frame the centre is 25 px further and the scale 1.1^2.5."""
    det = PadDetector(PINHOLE, LAYOUT)
    eye = np.eye(3)
    det.roi_track.update(_corners_at((320.0, 240.0), 20.0), 100.0, 1.0, eye)
    det.roi_track.update(_corners_at((330.0, 240.0), 22.0), 110.0, 1.1, eye)
    shift, growth = det.roi_track.prediction(1.35, eye)
    np.testing.assert_allclose(shift, [25.0, 0.0], atol=1e-9)
    assert growth == pytest.approx(1.1**2.5, rel=1e-12)


def test_a_tilt_between_frames_moves_the_roi_by_f_tan_theta() -> None:
    """The pad seen at the image centre by a level camera; the camera then tilts by 0.1 rad about
    its x axis (world down now at (0, sin, cos) in the camera): the pad is at cy + f tan(0.1)."""
    det = PadDetector(PINHOLE, LAYOUT)
    det.roi_track.update(_corners_at((320.0, 240.0), 20.0), 100.0, 1.0, level_rotation([0.0, 0.0, 1.0]))
    theta = 0.1
    shift, growth = det.roi_track.prediction(1.2, level_rotation([0.0, math.sin(theta), math.cos(theta)]))
    np.testing.assert_allclose(shift, [0.0, 500.0 * math.tan(theta)], atol=1e-9)
    assert growth == 1.0  # one frame: no motion known yet


def test_no_prediction_past_the_gap_or_when_off() -> None:
    eye = np.eye(3)
    for cfg, t in ((DetectorConfig(), 1.1 + 0.51), (DetectorConfig(roi_predict_max_gap_s=0.0), 1.2)):
        det = PadDetector(PINHOLE, LAYOUT, cfg)
        det.roi_track.update(_corners_at((320.0, 240.0), 20.0), 100.0, 1.0, eye)
        det.roi_track.update(_corners_at((330.0, 240.0), 22.0), 110.0, 1.1, eye)
        shift, growth = det.roi_track.prediction(t, eye)
        assert shift.tolist() == [0.0, 0.0] and growth == 1.0


def test_the_growth_is_bounded() -> None:
    det = PadDetector(PINHOLE, LAYOUT)
    eye = np.eye(3)
    det.roi_track.update(_corners_at((320.0, 240.0), 20.0), 100.0, 1.0, eye)
    det.roi_track.update(_corners_at((320.0, 240.0), 60.0), 300.0, 1.05, eye)  # x3 in 50 ms
    assert det.roi_track.prediction(1.45, eye)[1] == 2.0


@pytest.mark.parametrize("bad", [-0.1, math.nan, math.inf])
def test_the_gap_is_validated(bad: float) -> None:
    with pytest.raises(ValueError, match="roi_predict_max_gap_s"):
        DetectorConfig(roi_predict_max_gap_s=bad)


def test_a_bad_roi_direction_is_refused_by_name(sim: SimulatedCamera) -> None:
    f = sim.capture(_vehicle(0.0, 0.0, 5.0), 0.0)
    det = PadDetector(CAM, LAYOUT)
    with pytest.raises(ValueError, match="roi_down_cam"):
        det.detect(f.image, 0.0, roi_down_cam=[0.0, math.nan, 1.0])
    assert det.stats.bad_frames == 1


# ---------------------------------------------------------------------------- rendered flights


def _fly(sim: SimulatedCamera, poses: list[Transform], dt_s: float, cfg: DetectorConfig, attitude: bool) -> PadDetector:
    det = PadDetector(CAM, LAYOUT, cfg)
    for k, T_world_body in enumerate(poses):
        f = sim.capture(T_world_body, k * dt_s)
        down = down_in_camera(T_world_body.R, sim.T_body_camera.R) if attitude else None
        assert det.detect(f.image, f.exposure_time_s, roi_down_cam=down) is not None
    return det


def test_a_rocking_hover_keeps_the_roi_with_the_attitude(sim: SimulatedCamera) -> None:
    """A hover at 6 m rocking +-0.1 rad in pitch, frames 0.25 s apart (a paced detector): the pad's
    image jumps ~50 px a frame, twice the ROI's margin. Where it was last: the ROI misses on
    every frame; derotated by the attitude: never."""
    poses = [_vehicle(0.1, -0.1, 6.0, 0.0, 0.1 if k % 2 else -0.1) for k in range(8)]
    still = _fly(sim, poses, 0.25, DetectorConfig(roi_predict_max_gap_s=0.0), attitude=True)
    assert still.stats.roi_fallbacks == still.stats.roi_searches == 7
    followed = _fly(sim, poses, 0.25, DetectorConfig(), attitude=True)
    assert followed.stats.roi_searches == 7 and followed.stats.roi_fallbacks == 0


def test_a_pass_over_the_pad_keeps_the_roi_at_the_image_velocity(sim: SimulatedCamera) -> None:
    """Level at 5 m, 1.6 m/s over the pad, frames 0.25 s apart: ~45 px a frame. Without the
    prediction every ROI misses; with it only the second frame (no motion known yet) does."""
    poses = [_vehicle(-1.2 + 0.4 * k, 0.2, 5.0) for k in range(7)]
    still = _fly(sim, poses, 0.25, DetectorConfig(roi_predict_max_gap_s=0.0), attitude=False)
    assert still.stats.roi_fallbacks == still.stats.roi_searches == 6
    followed = _fly(sim, poses, 0.25, DetectorConfig(), attitude=False)
    assert followed.stats.roi_searches == 6 and followed.stats.roi_fallbacks == 1
