"""Vision: camera model and calibration, nested ArUco pad layouts, marker detection and PnP.

Frames (DESIGN.md): camera = OpenCV (x right, y down, z optical axis); pad/marker = OpenCV ArUco
(x right, y up, z out of the pad); ``T_camera_pad`` is the pose of the pad in the camera frame.
"""

from companion.vision.camera import (
    CalibrationPattern,
    CameraConfigError,
    CameraModel,
    calibrate,
    camera_from_mapping,
    camera_to_toml,
    load_camera,
    load_default_camera,
    save_camera,
    shipped_camera_path,
)
from companion.vision.detector import (
    DetectorConfig,
    DetectorStats,
    ImageError,
    MarkerObservation,
    PadDetector,
    PoseCandidate,
    check_image,
    refine_corners_by_edges,
    resolve_ambiguity,
    rotation_angle,
    solve_candidates,
)
from companion.vision.pad import (
    PadConfigError,
    PadLayout,
    aruco_dictionary,
    load_pad,
    pad_from_mapping,
    pad_side_px,
    render_pad,
    render_pad_px,
    save_pad,
    save_pad_png,
)

__all__ = [
    "CalibrationPattern",
    "CameraConfigError",
    "CameraModel",
    "DetectorConfig",
    "DetectorStats",
    "ImageError",
    "MarkerObservation",
    "PadConfigError",
    "PadDetector",
    "PadLayout",
    "PoseCandidate",
    "aruco_dictionary",
    "calibrate",
    "camera_from_mapping",
    "camera_to_toml",
    "check_image",
    "load_camera",
    "load_default_camera",
    "load_pad",
    "pad_from_mapping",
    "pad_side_px",
    "refine_corners_by_edges",
    "render_pad",
    "render_pad_px",
    "resolve_ambiguity",
    "rotation_angle",
    "save_camera",
    "save_pad",
    "save_pad_png",
    "shipped_camera_path",
    "solve_candidates",
]
