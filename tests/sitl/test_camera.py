"""Simulated downward camera: frames, geometry of the rendering, determinism, speed, bad poses."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from companion.geometry import Transform
from companion.vision.camera import CameraModel, load_default_camera
from companion.vision.pad import PadLayout, aruco_dictionary
from companion_sitl.camera import (
    R_BODY_CAMERA_DOWN,
    SimCameraConfig,
    SimulatedCamera,
    downward_mount,
    pad_pose_ned,
)

CAM = load_default_camera()
LAYOUT = PadLayout()


def _vehicle(
    north: float, east: float, alt: float, roll: float = 0.0, pitch: float = 0.0, yaw: float = 0.0
) -> Transform:
    return Transform.from_euler([north, east, -alt], roll, pitch, yaw)


def _outer_corners(img: np.ndarray) -> np.ndarray | None:
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary(LAYOUT.outer_dict), p)
    corners, ids, _ = det.detectMarkers(img)
    if ids is None:
        return None
    for c, i in zip(corners, np.asarray(ids).ravel(), strict=True):
        if int(i) == LAYOUT.outer_id:
            return np.asarray(c, float).reshape(4, 2)
    return None


def test_mount_maps_camera_axes_to_body_axes() -> None:
    R = R_BODY_CAMERA_DOWN
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0])  # camera x -> body y (right)
    assert np.allclose(R @ [0, 1, 0], [-1, 0, 0])  # camera y -> body -x (back)
    assert np.allclose(R @ [0, 0, 1], [0, 0, 1])  # camera z -> body z (down)
    T = downward_mount((0.1, 0.0, 0.05))
    assert np.allclose(T.t, [0.1, 0.0, 0.05])


def test_pad_pose_axes() -> None:
    T = pad_pose_ned(3.0, -2.0, 0.0)
    assert np.allclose(T.R @ [1, 0, 0], [0, 1, 0])  # pad x = east
    assert np.allclose(T.R @ [0, 1, 0], [1, 0, 0])  # pad y = north
    assert np.allclose(T.R @ [0, 0, 1], [0, 0, -1])  # pad z = up
    assert np.allclose(T.t, [3.0, -2.0, 0.0])


def test_truth_pose_for_a_level_vehicle_above_the_pad() -> None:
    sim = SimulatedCamera(CAM, LAYOUT, seed=0)
    T = sim.T_camera_pad(_vehicle(0.0, 0.0, 4.0))
    assert np.allclose(T.t, [0.0, 0.0, 4.0])
    # heading north: pad y (north) appears as image up (-y), pad x (east) as image right (+x)
    assert np.allclose(T.R @ [0, 1, 0], [0, -1, 0]) and np.allclose(T.R @ [1, 0, 0], [1, 0, 0])
    # north of the pad, the pad is behind the vehicle: low in the image (+y)
    T2 = sim.T_camera_pad(_vehicle(1.0, 0.0, 4.0))
    assert T2.t[1] > 0.9


def test_rendered_marker_lands_where_the_camera_model_projects_it() -> None:
    """Pad corners in the image agree with CameraModel.project of the truth (distortion on)."""
    sim = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0), seed=1)
    for pose in (_vehicle(0.0, 0.0, 3.0, 0.0, 0.0, 0.3), _vehicle(1.0, -0.9, 4.0, 0.05, 0.1, 1.1)):
        f = sim.capture(pose, 0.0)
        found = _outer_corners(f.image)
        assert found is not None
        expect = CAM.project(f.T_camera_pad.apply(LAYOUT.outer_corners))
        assert np.max(np.linalg.norm(found - expect, axis=1)) < 0.5


def test_dart_distortion_is_rendered() -> None:
    cam = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, kind="dart", k_ud=0.25)
    sim = SimulatedCamera(cam, LAYOUT, SimCameraConfig(noise_std=0.0), seed=1)
    f = sim.capture(_vehicle(-0.8, 0.9, 3.0), 0.0)
    found = _outer_corners(f.image)
    assert found is not None
    expect = cam.project(f.T_camera_pad.apply(LAYOUT.outer_corners))
    assert np.max(np.linalg.norm(found - expect, axis=1)) < 0.5
    pinhole = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0).project(f.T_camera_pad.apply(LAYOUT.outer_corners))
    assert np.max(np.linalg.norm(found - pinhole, axis=1)) > 5.0  # barrel pulls corners in


def test_deterministic_for_a_seed() -> None:
    pose = _vehicle(0.3, 0.2, 5.0, 0.02, -0.01, 0.4)
    cfg = SimCameraConfig(gain_jitter=0.05, offset_jitter=4.0)
    a = SimulatedCamera(CAM, LAYOUT, cfg, seed=5)
    b = SimulatedCamera(CAM, LAYOUT, cfg, seed=5)
    c = SimulatedCamera(CAM, LAYOUT, cfg, seed=6)
    fa = [a.capture(pose, k * 0.1).image for k in range(3)]
    fb = [b.capture(pose, k * 0.1).image for k in range(3)]
    assert all(np.array_equal(x, y) for x, y in zip(fa, fb, strict=True))
    assert not np.array_equal(fa[0], fa[1])  # noise differs frame to frame
    assert not np.array_equal(fa[0], c.capture(pose, 0.0).image)


def test_capture_from_world_camera_pose_matches_vehicle_pose() -> None:
    sim_a = SimulatedCamera(CAM, LAYOUT, seed=4)
    sim_b = SimulatedCamera(CAM, LAYOUT, seed=4)
    T_wb = _vehicle(0.4, -0.3, 3.0, 0.05, -0.04, 0.7)
    fa = sim_a.capture(T_wb, 1.0)
    fb = sim_b.capture_camera(T_wb @ sim_b.T_body_camera, 1.0)
    assert np.array_equal(fa.image, fb.image)
    assert np.allclose(fa.T_camera_pad.matrix(), fb.T_camera_pad.matrix())
    with pytest.raises(ValueError, match="T_world_camera"):
        sim_b.capture_camera(Transform(np.eye(3), np.array([0.0, np.inf, -3.0])), 0.0)


def test_frame_times_and_latency() -> None:
    sim = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(latency_s=0.045), seed=0)
    f = sim.capture(_vehicle(0, 0, 3.0), 12.5)
    assert f.exposure_time_s == 12.5 and f.available_time_s == pytest.approx(12.545)
    assert f.image.shape == (480, 640) and f.image.dtype == np.uint8
    with pytest.raises(ValueError, match="exposure_time_s"):
        sim.capture(_vehicle(0, 0, 3.0), float("nan"))


def test_lighting_and_blur_change_the_image() -> None:
    pose = _vehicle(0.0, 0.0, 3.0)
    base = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0), seed=3).capture(pose, 0).image
    dim = (
        SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0, gain=0.5, offset=10.0), seed=3)
        .capture(pose, 0)
        .image
    )
    assert np.allclose(dim.astype(float), np.clip(base * 0.5 + 10.0, 0, 255), atol=1.0)
    blur = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0, blur_px=9.0), seed=3)
    b = blur.capture(pose, 0).image
    # motion blur along x smooths horizontal gradients more than vertical ones
    gx = np.abs(np.diff(b.astype(float), axis=1)).mean() / np.abs(np.diff(base.astype(float), axis=1)).mean()
    gy = np.abs(np.diff(b.astype(float), axis=0)).mean() / np.abs(np.diff(base.astype(float), axis=0)).mean()
    assert gx < 0.7 and gx < 0.8 * gy


def test_noise_level() -> None:
    pose = _vehicle(0.0, 0.0, 3.0)
    a = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0), seed=3).capture(pose, 0).image
    b = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=4.0), seed=3).capture(pose, 0).image
    d = b.astype(float) - a.astype(float)
    mid = (a > 20) & (a < 235)  # away from clipping
    assert 3.0 < d[mid].std() < 5.0


def test_tilted_view_shows_sky_above_the_horizon() -> None:
    sim = SimulatedCamera(CAM, LAYOUT, SimCameraConfig(noise_std=0.0, sky_level=240), seed=0)
    img = sim.capture(_vehicle(0.0, 0.0, 5.0, 0.0, math.radians(70.0), 0.0), 0.0).image
    # pitch up 70 deg: the camera looks 20 deg below the horizon, which crosses the image top
    assert np.all(img[0] == 240) and not np.all(img[-1] == 240)


@pytest.mark.parametrize(
    "pose, word",
    [
        (Transform(np.eye(3), np.array([0.0, float("nan"), -3.0])), "NaN"),
        (Transform(np.full((3, 3), np.nan), np.zeros(3)), "NaN"),
        (Transform(2 * np.eye(3), np.array([0.0, 0.0, -3.0])), "rotation"),
        (_vehicle(0.0, 0.0, -1.0), "above"),  # below the ground
    ],
)
def test_bad_poses_rejected(pose: Transform, word: str) -> None:
    sim = SimulatedCamera(CAM, LAYOUT, seed=0)
    with pytest.raises(ValueError, match=word):
        sim.capture(pose, 0.0)


def test_bad_config_rejected() -> None:
    with pytest.raises(ValueError, match="noise_std"):
        SimCameraConfig(noise_std=-1.0)
    with pytest.raises(ValueError, match="gain"):
        SimCameraConfig(gain=float("nan"))


def _poses_around_the_pad(n: int, seed: int) -> list[Transform]:
    """Vehicle poses from 0.3 m to 40 m over and beside the pad, level to steeply tilted: the pad
    fills the frame, sits at an edge or a corner, lies partly or wholly outside the frame."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        alt = float(np.exp(rng.uniform(np.log(0.3), np.log(40.0))))
        off = alt * rng.uniform(-0.9, 0.9, 2)  # up to ~ the edge of the view and beyond it
        tilt = rng.uniform(-0.6, 0.6, 2) if rng.uniform() < 0.3 else rng.uniform(-0.08, 0.08, 2)
        out.append(_vehicle(float(off[0]), float(off[1]), alt, float(tilt[0]), float(tilt[1]), rng.uniform(-3.1, 3.1)))
    return out


@pytest.mark.parametrize(
    "camera, config",
    [
        (CAM, SimCameraConfig()),
        (CAM, SimCameraConfig(noise_std=0.0, blur_px=3.0, gain=1.2, offset=-5.0, gain_jitter=0.05, offset_jitter=2.0)),
        (CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0), SimCameraConfig()),  # no distortion: no remap
        (CameraModel(352, 288, 300.0, 300.0, 170.0, 150.0, kind="dart", k_ud=0.25), SimCameraConfig()),
    ],
    ids=["default", "blur-lighting-jitter", "pinhole", "dart-odd-size"],
)
def test_pad_warp_into_the_reachable_canvas_gives_the_pixels_of_the_whole_canvas_warp(camera, config) -> None:
    """The renderer warps the pad only into the top-left part of the canvas it can reach; the
    frames are bit for bit those of the warp over the whole canvas (the reference path), for
    every pose, noise and lighting draw included."""
    cropped = SimulatedCamera(camera, LAYOUT, config, seed=11)
    whole = SimulatedCamera(camera, LAYOUT, config, seed=11)
    whole.crop_pad_warp = False
    for k, pose in enumerate(_poses_around_the_pad(150, seed=3)):
        a = cropped.capture(pose, k / 30).image
        b = whole.capture(pose, k / 30).image
        assert np.array_equal(a, b), f"pose {k}: {np.count_nonzero(a != b)} pixels differ"


def test_pad_warp_extent() -> None:
    from companion_sitl.camera import _WARP_COLUMN_BLOCK, _transparent_warp_extent

    cw, ch = 650, 490

    def scaled_to(x0: float, y0: float) -> np.ndarray:
        """The pad's 1024 texels shown 100 px across with its top-left texel at canvas (x0, y0)."""
        return np.array([[100 / 1024, 0.0, x0], [0.0, 100 / 1024, y0], [0.0, 0.0, 1.0]])

    w, h = _transparent_warp_extent(scaled_to(200.0, 150.0), 1024, (cw, ch))
    assert w % _WARP_COLUMN_BLOCK == 0 and 300 < w <= 300 + _WARP_COLUMN_BLOCK + 4 and 250 < h < 256
    # reaching into the last, partial column block: the whole width
    assert _transparent_warp_extent(scaled_to(600.0, 150.0), 1024, (cw, ch)) == (cw, h)
    assert _transparent_warp_extent(scaled_to(-200.0, 150.0), 1024, (cw, ch)) == (0, 0)  # left of the canvas
    assert _transparent_warp_extent(scaled_to(200.0, 600.0), 1024, (cw, ch)) == (0, 0)  # below it
    behind = scaled_to(200.0, 150.0)
    behind[2] = [0.0, -0.002, 1.0]  # the far side of the texture behind the camera
    assert _transparent_warp_extent(behind, 1024, (cw, ch)) is None


@pytest.mark.parametrize(
    "config",
    [
        SimCameraConfig(),
        SimCameraConfig(noise_std=0.0),
        SimCameraConfig(gain=1.3, offset=-7.5),
        SimCameraConfig(noise_std=0.0, gain=0.8),
        SimCameraConfig(noise_std=5.0, gain_jitter=0.1, offset_jitter=6.0),
    ],
    ids=["noise", "none", "lighting-noise", "lighting", "jitter-noise"],
)
def test_exposure_in_place_equals_the_float32_formula(config: SimCameraConfig) -> None:
    """The exposure works in a float32 buffer it keeps; the frames are those of
    clip(float32(img) * gain + offset + noise, 0, 255) -> uint8, the same draws consumed."""
    import copy

    sim = SimulatedCamera(CAM, LAYOUT, config, seed=9)
    rng = np.random.default_rng(1)
    for _ in range(4):
        img = rng.integers(0, 256, (480, 640), dtype=np.uint8)
        draws = copy.deepcopy(sim._rng)
        got = sim._expose(img)
        gain, offset = config.gain, config.offset
        if config.gain_jitter > 0:
            gain = max(0.05, gain + float(draws.normal(0.0, config.gain_jitter)))
        if config.offset_jitter > 0:
            offset = offset + float(draws.normal(0.0, config.offset_jitter))
        want = img.astype(np.float32)
        if gain != 1.0 or offset != 0.0:
            want = want * np.float32(gain) + np.float32(offset)
        if config.noise_std > 0:
            dy, dx = (int(x) for x in draws.integers(0, 64, 2))
            want = want + sim._noise[dy : dy + 480, dx : dx + 640]
        assert np.array_equal(got, np.clip(want, 0, 255).astype(np.uint8))
        assert got is not sim._expose(img)  # a new array every frame
        sim._rng = draws  # the same draws consumed as the formula's


def test_distortion_maps_are_computed_once_per_camera_model_and_equal_a_fresh_computation() -> None:
    from companion_sitl import camera as sim_camera

    dart = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, kind="dart", k_ud=0.25)
    a = SimulatedCamera(CAM, LAYOUT, seed=1)
    b = SimulatedCamera(CAM, LAYOUT, seed=2)
    maps = a.distortion_maps
    assert maps is b.distortion_maps and maps is not None and not maps[0].flags.writeable
    assert SimulatedCamera(dart, LAYOUT, seed=1).distortion_maps is not maps  # another model, its own maps
    cached = sim_camera._distortion_setup(CAM)
    sim_camera._DISTORTION_CACHE.clear()
    fresh = sim_camera._distortion_setup(CAM)
    assert fresh is not cached and fresh[:2] == cached[:2]
    assert fresh[2] is not None and cached[2] is not None
    assert all(np.array_equal(x, y) for x, y in zip(fresh[2], cached[2], strict=True))
    for k in range(12):  # the cache stays small
        sim_camera._distortion_setup(CameraModel(64, 48, 50.0 + k, 50.0, 32.0, 24.0, dist=(0.05, 0.0, 0.0, 0.0, 0.0)))
    assert len(sim_camera._DISTORTION_CACHE) <= sim_camera._DISTORTION_CACHE_SIZE
