"""Synthetic calibration-target images (chessboards) seen by a simulated camera.

Used to exercise ``companion.vision.camera.calibrate`` without a real camera: a planar texture is
rendered through the camera model (pinhole + OpenCV or Dart distortion) from a given pose, by
looking up, for every distorted output pixel, its ideal ray and intersecting it with the plane.
"""

from __future__ import annotations

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform, euler_to_rotmat
from companion.vision.camera import CalibrationPattern, CameraModel


def render_plane_texture(
    camera: CameraModel,
    texture: NDArray[np.uint8],
    texel_m: float,
    T_camera_plane: Transform,
    background: int = 128,
) -> NDArray[np.uint8]:
    """Render a planar texture whose top-left texel is at the plane origin (x right, y down)."""
    R, t = np.asarray(T_camera_plane.R, float), np.asarray(T_camera_plane.t, float)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError("T_camera_plane contains NaN or inf")
    A = np.array([[texel_m, 0.0, 0.5 * texel_m], [0.0, texel_m, 0.5 * texel_m], [0.0, 0.0, 1.0]])
    H = camera.K @ np.column_stack([R[:, 0], R[:, 1], t]) @ A  # texture pixel -> ideal pixel
    w, h = camera.size
    u, v = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    ideal = camera.undistort_pixels(np.stack([u.ravel(), v.ravel()], axis=1))
    q = np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(H).T
    with np.errstate(divide="ignore", invalid="ignore"):
        mx = np.where(q[:, 2] > 0, q[:, 0] / q[:, 2], -1e6).reshape(h, w).astype(np.float32)
        my = np.where(q[:, 2] > 0, q[:, 1] / q[:, 2], -1e6).reshape(h, w).astype(np.float32)
    out = cv2.remap(texture, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=background)
    return np.asarray(out, dtype=np.uint8)


def chessboard_texture(pattern: CalibrationPattern, square_px: int = 40) -> NDArray[np.uint8]:
    """A chessboard with ``pattern.cols x pattern.rows`` inner corners and a one-square margin."""
    if pattern.kind != "chessboard":
        raise ValueError(f"pattern kind {pattern.kind!r}: only 'chessboard' is rendered here")
    cols, rows = pattern.cols + 1, pattern.rows + 1
    board = np.full(((rows + 2) * square_px, (cols + 2) * square_px), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                board[(r + 1) * square_px : (r + 2) * square_px, (c + 1) * square_px : (c + 2) * square_px] = 0
    return np.asarray(cv2.GaussianBlur(board, (3, 3), 0.6), dtype=np.uint8)


def charuco_texture(pattern: CalibrationPattern, square_px: int = 40) -> NDArray[np.uint8]:
    """A ChArUco board (``cols x rows`` squares) with a one-square white margin."""
    if pattern.kind != "charuco":
        raise ValueError(f"pattern kind {pattern.kind!r}: expected 'charuco'")
    img = pattern.charuco_board().generateImage(
        (pattern.cols * square_px, pattern.rows * square_px), marginSize=0, borderBits=1
    )
    img = cv2.copyMakeBorder(img, square_px, square_px, square_px, square_px, cv2.BORDER_CONSTANT, value=255)
    return np.asarray(cv2.GaussianBlur(img, (3, 3), 0.6), dtype=np.uint8)


def chessboard_views(
    camera: CameraModel,
    pattern: CalibrationPattern,
    n: int,
    seed: int,
    distance_m: tuple[float, float] = (0.45, 0.65),
    noise_std: float = 1.5,
) -> list[NDArray[np.uint8]]:
    """``n`` seeded views of the target (chessboard or ChArUco): random tilt (+-0.5 rad), spin,
    offset and distance."""
    square_px = 40
    render = charuco_texture if pattern.kind == "charuco" else chessboard_texture
    board = render(pattern, square_px)
    texel = pattern.square_m / square_px
    width_m, height_m = board.shape[1] * texel, board.shape[0] * texel
    rng = np.random.default_rng(seed)
    views = []
    for _ in range(n):
        R = euler_to_rotmat(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.3, 0.3))
        centre = np.array([rng.uniform(-0.08, 0.08), rng.uniform(-0.06, 0.06), rng.uniform(*distance_m)])
        t = centre - R @ np.array([width_m / 2, height_m / 2, 0.0])
        img = render_plane_texture(camera, board, texel, Transform(R, t)).astype(float)
        img += rng.normal(0.0, noise_std, img.shape)
        views.append(np.clip(img, 0, 255).astype(np.uint8))
    return views
