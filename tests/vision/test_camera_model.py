"""Camera model: projection, dart eqs 2-4, TOML I/O, calibration on rendered chessboards."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.vision.camera import (
    CalibrationPattern,
    CameraConfigError,
    CameraModel,
    calibrate,
    camera_to_toml,
    load_camera,
    load_default_camera,
    save_camera,
)
from companion_sitl.camera_targets import chessboard_views

OPENCV_CAM = CameraModel(640, 480, 510.0, 505.0, 322.0, 238.0, dist=(0.12, -0.25, 0.001, -0.0005, 0.05))
DART_CAM = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, kind="dart", k_ud=0.18)


def _points(rng: np.random.Generator, n: int = 200) -> np.ndarray:
    p = rng.uniform(-1.0, 1.0, (n, 3))
    p[:, :2] *= 0.6
    p[:, 2] = rng.uniform(1.0, 5.0, n)
    p[:, :2] *= p[:, 2:3]
    return p


@pytest.mark.parametrize("cam", [OPENCV_CAM, DART_CAM], ids=["opencv", "dart"])
def test_project_unproject_roundtrip(cam: CameraModel) -> None:
    p = _points(np.random.default_rng(1))
    uv = cam.project(p)
    assert np.all(np.isfinite(uv))
    rays = cam.unproject(uv)
    assert np.allclose(rays[:, 2], 1.0)
    assert np.allclose(rays[:, :2], p[:, :2] / p[:, 2:3], atol=1e-9)
    # pixels -> ideal pixels -> pixels
    assert np.allclose(cam.distort_pixels(cam.undistort_pixels(uv)), uv, atol=1e-6)


def test_opencv_model_matches_cv2_project_points() -> None:
    p = _points(np.random.default_rng(2))
    ours = OPENCV_CAM.project(p)
    ref, _ = cv2.projectPoints(p, np.zeros(3), np.zeros(3), OPENCV_CAM.K, OPENCV_CAM.dist_coeffs)
    assert np.allclose(ours, ref.reshape(-1, 2), atol=1e-9)


def test_dart_unprojection_is_eqs_2_to_4() -> None:
    """dart eqs 2-4: x/z = (u-u0)(1+k r^2)/rho_x, r^2 = ((u-u0)/rho_x)^2 + ((v-v0)/rho_y)^2."""
    cam = replace(DART_CAM, fy=480.0)
    u, v = 600.0, 50.0
    r2 = ((u - cam.cx) / cam.fx) ** 2 + ((v - cam.cy) / cam.fy) ** 2  # dart eq 4
    x = (u - cam.cx) * (1 + cam.k_ud * r2) / cam.fx  # dart eq 2
    y = (v - cam.cy) * (1 + cam.k_ud * r2) / cam.fy  # dart eq 3
    ray = cam.unproject([[u, v]])[0]
    assert ray == pytest.approx([x, y, 1.0], abs=1e-12)
    # barrel: the image point lies closer to the centre than the pinhole projection
    ideal = cam.normalized_to_pixels([[x, y]])[0]
    assert np.hypot(*(ideal - [cam.cx, cam.cy])) > np.hypot(u - cam.cx, v - cam.cy)


def test_dart_projection_beyond_invertible_radius_is_nan() -> None:
    cam = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, kind="dart", k_ud=-0.5)
    # s + k s^3 peaks at s = 1/sqrt(3*0.5) -> r_u max = 0.544; beyond that there is no image point
    uv = cam.project([[0.3, 0.0, 1.0], [2.0, 0.0, 1.0]])
    assert np.all(np.isfinite(uv[0])) and np.all(np.isnan(uv[1]))


def test_points_behind_camera_project_to_nan() -> None:
    uv = OPENCV_CAM.project([[0.0, 0.0, -1.0], [0.1, 0.0, 1.0]])
    assert np.all(np.isnan(uv[0])) and np.all(np.isfinite(uv[1]))


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"fx": 0.0}, "fx"),
        ({"fy": float("nan")}, "fy"),
        ({"width_px": 0}, "width_px"),
        ({"kind": "fisheye"}, "kind"),
        ({"dist": (0.1, 0.0, 0.0, 0.0)}, "dist"),
        ({"kind": "dart", "dist": (0.1, 0.0, 0.0, 0.0, 0.0)}, "dist"),
        ({"k_ud": 0.1}, "k_ud"),
    ],
)
def test_invalid_models_rejected(kwargs: dict, word: str) -> None:
    base = {"width_px": 640, "height_px": 480, "fx": 500.0, "fy": 500.0, "cx": 320.0, "cy": 240.0}
    with pytest.raises(ValueError, match=word):
        CameraModel(**{**base, **kwargs})


@pytest.mark.parametrize("cam", [OPENCV_CAM, DART_CAM], ids=["opencv", "dart"])
def test_toml_roundtrip(tmp_path: Path, cam: CameraModel) -> None:
    path = save_camera(cam, tmp_path / "cam.toml", rms_px=0.21, n_images=9, note='a "quoted" note')
    assert load_camera(path) == cam


def test_shipped_pi_camera_is_nominal_and_loads() -> None:
    cam = load_default_camera()
    assert (cam.width_px, cam.height_px) == (640, 480)
    assert 480.0 < cam.fx < 560.0 and cam.fx == cam.fy
    assert cam.kind == "opencv"
    path = Path(__file__).resolve().parents[2] / "params" / "camera_rpi_v2.toml"
    assert "NOMINAL" in path.read_text()
    # the distortion is monotonic over the whole image (the simulator relies on it)
    corners = np.array([[0, 0], [639, 0], [0, 479], [639, 479]], float)
    assert np.all(np.isfinite(cam.undistort_pixels(corners)))


@pytest.mark.parametrize(
    "body, key, rule",
    [
        (
            "[camera]\nwidth_px = 640\nheight_px = 480\nfx = -5.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n",
            "camera.fx",
            "> 0",
        ),
        (
            "[camera]\nwidth_px = 640\nheight_px = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\nfocal = 3\n",
            "camera.focal",
            "unknown key",
        ),
        ("[camera]\nwidth_px = 640\nheight_px = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\n", "camera.cy", "missing"),
        (
            "[camera]\nwidth_px = 640\nheight_px = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n"
            "dist = [0.1, 0.2]\n",
            "camera.dist",
            "5 numbers",
        ),
        (
            "[camera]\nwidth_px = 640.5\nheight_px = 480\nfx = 500.0\nfy = 500.0\ncx = 320.0\ncy = 240.0\n",
            "camera.width_px",
            "positive integer",
        ),
        (
            "[camera]\nwidth_px = 640\nheight_px = 480\nfx = 500.0\nfy = 500.0\ncx = 900.0\ncy = 240.0\n",
            "camera.cx",
            "inside the image",
        ),
        (
            '[camera]\nkind = "fisheye"\nwidth_px = 640\nheight_px = 480\nfx = 500.0\nfy = 500.0\n'
            "cx = 320.0\ncy = 240.0\n",
            "camera.kind",
            "one of",
        ),
        ("[lens]\nfx = 1\n", "lens", "unknown"),
    ],
)
def test_toml_errors_name_file_key_value_rule(tmp_path: Path, body: str, key: str, rule: str) -> None:
    path = tmp_path / "bad_camera.toml"
    path.write_text(body)
    with pytest.raises(CameraConfigError) as info:
        load_camera(path)
    msg = str(info.value)
    assert str(path) in msg and f"'{key}'" in msg and rule in msg


def test_toml_syntax_error_names_file(tmp_path: Path) -> None:
    path = tmp_path / "broken.toml"
    path.write_text("[camera\nfx=")
    with pytest.raises(CameraConfigError, match=r"broken\.toml"):
        load_camera(path)


def test_toml_text_is_readable_by_tomllib() -> None:
    import tomllib

    doc = tomllib.loads(camera_to_toml(OPENCV_CAM, rms_px=0.3, n_images=7, note="x"))
    assert doc["camera"]["dist"] == list(OPENCV_CAM.dist)
    assert doc["calibration"] == {"rms_px": 0.3, "n_images": 7, "note": "x"}


def test_pattern_parse() -> None:
    p = CalibrationPattern.parse("chessboard:9x6:0.025")
    assert (p.kind, p.cols, p.rows, p.square_m) == ("chessboard", 9, 6, 0.025)
    c = CalibrationPattern.parse("charuco:7x5:0.04:0.03:DICT_4X4_50")
    assert (c.kind, c.marker_m, c.dictionary) == ("charuco", 0.03, "DICT_4X4_50")
    for bad in ("chessboard:9by6:0.025", "circles:9x6:0.02", "chessboard:9x6", "charuco:7x5:0.04:0.05"):
        with pytest.raises(ValueError):
            CalibrationPattern.parse(bad)


# ---------------------------------------------------------------------------- calibration


def test_calibrate_recovers_intrinsics_from_rendered_chessboards() -> None:
    truth = CameraModel(640, 480, 520.0, 515.0, 325.0, 236.0, dist=(0.1, -0.15, 0.0, 0.0, 0.0))
    pattern = CalibrationPattern.parse("chessboard:9x6:0.025")
    views = chessboard_views(truth, pattern, 10, seed=3)
    cam, rms = calibrate(views, pattern)
    assert rms < 0.5
    assert cam.fx == pytest.approx(truth.fx, rel=0.02)
    assert cam.fy == pytest.approx(truth.fy, rel=0.02)
    assert cam.cx == pytest.approx(truth.cx, abs=8.0)
    assert cam.cy == pytest.approx(truth.cy, abs=8.0)
    # the recovered lens projects like the true one where the views covered the image
    p = np.array([[x, y, 1.0] for x in (-0.3, 0.0, 0.3) for y in (-0.25, 0.0, 0.25)])
    assert np.max(np.abs(cam.project(p) - truth.project(p))) < 1.5


def test_calibrate_from_charuco_views() -> None:
    truth = CameraModel(640, 480, 505.0, 505.0, 318.0, 242.0, dist=(0.05, -0.08, 0.0, 0.0, 0.0))
    pattern = CalibrationPattern.parse("charuco:7x5:0.04:0.03:DICT_4X4_50")
    views = chessboard_views(truth, pattern, 8, seed=4, distance_m=(0.5, 0.7))
    cam, rms = calibrate(views, pattern)
    assert rms < 0.6
    assert cam.fx == pytest.approx(truth.fx, rel=0.03)
    assert cam.fy == pytest.approx(truth.fy, rel=0.03)


def test_calibrate_dart_model() -> None:
    truth = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0, kind="dart", k_ud=0.15)
    pattern = CalibrationPattern.parse("chessboard:9x6:0.025")
    views = chessboard_views(truth, pattern, 8, seed=5)
    cam, rms = calibrate(views, pattern, kind="dart")
    assert cam.kind == "dart" and rms < 0.6
    assert cam.fx == pytest.approx(500.0, rel=0.03)
    assert cam.k_ud == pytest.approx(0.15, abs=0.05)


def test_calibrate_needs_five_views() -> None:
    truth = CameraModel(640, 480, 500.0, 500.0, 320.0, 240.0)
    pattern = CalibrationPattern.parse("chessboard:9x6:0.025")
    views = chessboard_views(truth, pattern, 3, seed=1)
    blank = [np.full((480, 640), 128, np.uint8)] * 4
    with pytest.raises(ValueError, match="need >= 5"):
        calibrate(views + blank, pattern)


def test_calibrate_rejects_bad_images() -> None:
    pattern = CalibrationPattern.parse("chessboard:9x6:0.025")
    with pytest.raises(ValueError, match="dtype"):
        calibrate([np.zeros((480, 640), np.float32)] * 5, pattern)
    with pytest.raises(ValueError, match="expected 640x480"):
        calibrate([np.zeros((480, 640), np.uint8), np.zeros((240, 320), np.uint8)], pattern)


def test_scaled_camera_keeps_field_of_view() -> None:
    half = OPENCV_CAM.scaled(0.5)
    assert (half.width_px, half.height_px) == (320, 240)
    p = [[0.3, -0.2, 1.0]]
    assert np.allclose((OPENCV_CAM.project(p) + 0.5) * 0.5 - 0.5, half.project(p))
    assert math.isclose(half.fx, OPENCV_CAM.fx / 2)
