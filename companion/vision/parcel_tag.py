"""The parcel seen from above (docs/winch.md, "The camera judges the parcel down"): an ArUco tag
printed on the parcel's top, found in the downward camera's frame while the winch lowers it, and
the height of the parcel's bottom above the pad worked out from the tag's position in the camera
and the vehicle's fused pose.

The tag's translation is what is used: the two IPPE solutions of a small square differ in its
tilt, hardly in where it is, so no ambiguity has to be resolved.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform, euler_to_rotmat
from companion.vision.camera import CameraModel
from companion.vision.detector import check_image, solve_candidates
from companion.vision.pad import PadLayout, aruco_dictionary, square_corners


@dataclass(frozen=True, slots=True)
class ParcelSighting:
    """The parcel as one frame showed it: the exposure's time (s, the loop's clock), the tag's
    position in the camera frame (m) and the parcel's bottom above the pad (m; negative: below it,
    the estimate's error)."""

    time_s: float
    tag_in_camera_m: tuple[float, float, float]
    bottom_above_pad_m: float


def tag_clashes_with_pad(layout: PadLayout, tag_dict: str, tag_id: int) -> str:
    """Why a parcel tag cannot be told from the pad's own markers ("" when it can)."""
    for which in ("outer", "inner"):
        if getattr(layout, f"{which}_dict") == tag_dict and getattr(layout, f"{which}_id") == tag_id:
            return f"the parcel tag {tag_dict} id {tag_id} is the pad's {which} marker"
    return ""


class ParcelTagFinder:
    """Finds the tag (``tag_dict``, ``tag_id``, ``tag_size_m`` a side) in a whole frame."""

    def __init__(self, camera: CameraModel, tag_dict: str, tag_id: int, tag_size_m: float) -> None:
        dictionary = aruco_dictionary(tag_dict)
        n = dictionary.bytesList.shape[0]
        if isinstance(tag_id, bool) or not 0 <= int(tag_id) < n:
            raise ValueError(f"parcel tag id {tag_id!r}: must be an integer in [0, {n}) for {tag_dict}")
        if not (math.isfinite(tag_size_m) and tag_size_m > 0.0):
            raise ValueError(f"parcel tag size {tag_size_m!r} m: must be > 0")
        self.camera = camera
        self.tag_id = int(tag_id)
        params = cv2.aruco.DetectorParameters()
        # sub-pixel corners: the tag is ~20 px across at a 5 m hover, where a pixel is 5 % of its range
        params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
        self._detector = cv2.aruco.ArucoDetector(dictionary, params)
        self._object = square_corners(tag_size_m)
        self.frames = 0
        self.found = 0

    def find(self, image: Any) -> tuple[float, float, float] | None:
        """The tag's centre in the camera frame (m), or None when it is not in the frame."""
        gray = check_image(image)
        self.frames += 1
        corners, ids, _ = self._detector.detectMarkers(gray)
        if ids is None:
            return None
        for c, i in zip(corners, np.asarray(ids).ravel(), strict=False):
            if int(i) != self.tag_id:
                continue
            ideal = self.camera.undistort_pixels(np.asarray(c, dtype=np.float64).reshape(4, 2))
            candidates = solve_candidates(self._object, ideal, self.camera.K)
            if not candidates:
                return None
            t = candidates[0].t
            self.found += 1
            return float(t[0]), float(t[1]), float(t[2])
        return None


def parcel_bottom_above_pad_m(
    tag_in_camera_m: tuple[float, float, float] | NDArray[np.float64],
    position_ned_m: tuple[float, float, float] | NDArray[np.float64],
    euler_rad: tuple[float, float, float],
    T_body_camera: Transform,
    pad_down_m: float,
    parcel_height_m: float,
) -> float:
    """The parcel's bottom above the pad: the tag (on the parcel's top, ``parcel_height_m`` above
    its bottom) carried into world NED through the camera's mount and the vehicle's pose,
    t_w = p + R_wb (t_bc + R_bc t_c), and its down coordinate set against the pad's."""
    R_wb = euler_to_rotmat(*euler_rad)
    t_c = np.asarray(tag_in_camera_m, dtype=float).reshape(3)
    t_b = T_body_camera.t + T_body_camera.R @ t_c
    tag_down = float(position_ned_m[2] + (R_wb @ t_b)[2])
    return pad_down_m - tag_down - parcel_height_m
