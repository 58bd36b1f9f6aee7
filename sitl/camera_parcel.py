"""The parcel on its line in the simulated camera's frames (docs/winch.md, "The camera judges the
parcel down"): a box hanging under the vehicle, its top level, with an ArUco tag printed on it in a
white square, painted into each frame from the parcel's true position at the exposure.

The box's top face and its tag are level and turned north (x east, y north, z up: a right-handed
frame seen from above, so the tag is not mirrored). A box whose corners come within 0.2 m of the
lens is not drawn (just below the vehicle it would fill the frame).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform
from companion.vision.camera import CameraModel
from companion.vision.pad import aruco_dictionary

U8Image = NDArray[np.uint8]
_TAG_PX = 120  # the tag's printed resolution (its image before the warp)
_QUIET = 1.3  # the white square around the tag, its side over the tag's


@dataclass(frozen=True)
class ParcelLook:
    """What the parcel looks like: its top's side and its height (m), the top's grey, and the tag
    (dictionary, id, side m; ``tag_id`` < 0: no tag printed)."""

    size_m: float = 0.3
    height_m: float = 0.25
    grey: int = 150
    tag_dict: str = "DICT_4X4_50"
    tag_id: int = -1
    tag_size_m: float = 0.2

    def __post_init__(self) -> None:
        if not (0.0 < self.size_m <= 3.0 and 0.0 <= self.height_m <= 3.0):
            raise ValueError(f"parcel size {self.size_m} m, height {self.height_m} m: expected (0, 3] and [0, 3]")
        if self.tag_id >= 0 and not (0.0 < self.tag_size_m * _QUIET <= self.size_m):
            raise ValueError(
                f"parcel tag {self.tag_size_m} m with its white square ({_QUIET}x) must fit on the {self.size_m} m top"
            )

    def tag_image(self) -> U8Image:
        """The tag as printed: the marker, its one-cell black border included."""
        return np.asarray(
            cv2.aruco.generateImageMarker(aruco_dictionary(self.tag_dict), self.tag_id, _TAG_PX), dtype=np.uint8
        )


class ParcelPainter:
    """Paints the parcel (:class:`ParcelLook`) into a frame at its true position."""

    def __init__(self, look: ParcelLook) -> None:
        self.look = look
        self._tag = look.tag_image() if look.tag_id >= 0 else None

    def paint(
        self, img: U8Image, camera: CameraModel, T_world_camera: Transform, bottom_ned_m: tuple[float, float, float]
    ) -> U8Image:
        """The frame with the parcel whose bottom's centre is at ``bottom_ned_m`` (world NED) in it
        (a new array; ``img`` itself when the parcel is not drawn)."""
        lk = self.look
        n, e, d = bottom_ned_m
        top_d = d - lk.height_m
        T_cw = T_world_camera.inverse()

        def square(side: float, down: float) -> NDArray[np.float64]:
            h = side / 2  # TL, TR, BR, BL of a marker (x east, y north): (-h, h), (h, h), (h, -h), (-h, -h)
            xy = ((-h, h), (h, h), (h, -h), (-h, -h))
            return np.array([[n + y, e + x, down] for x, y in xy])

        def px(points_ned: NDArray[np.float64]) -> NDArray[np.float64] | None:
            cam = T_cw.apply(points_ned)
            if np.any(cam[:, 2] < 0.2):
                return None
            uv = camera.project(cam)
            w, h = camera.size
            if not np.all(np.isfinite(uv)) or np.any(np.abs(uv - [w / 2, h / 2]) > [1.5 * w, 1.5 * h]):
                return None
            return np.asarray(uv, dtype=np.float64)

        bottom, top = px(square(lk.size_m, d)), px(square(lk.size_m, top_d))
        if bottom is None or top is None:
            return img
        out = img.copy()
        fixed = lambda p: np.round(p * 16).astype(np.int32)  # noqa: E731  (4 fractional bits for shift=4)
        side = max(0, lk.grey - 45)
        for i in range(4):
            j = (i + 1) % 4
            face = fixed(np.array([bottom[i], bottom[j], top[j], top[i]]))
            cv2.fillConvexPoly(out, face, side, lineType=cv2.LINE_AA, shift=4)
        cv2.fillConvexPoly(out, fixed(top), lk.grey, lineType=cv2.LINE_AA, shift=4)
        if self._tag is None:
            return out
        quiet = px(square(lk.tag_size_m * _QUIET, top_d))
        corners = px(square(lk.tag_size_m, top_d))
        if quiet is None or corners is None:
            return out
        cv2.fillConvexPoly(out, fixed(quiet), 255, lineType=cv2.LINE_AA, shift=4)
        s = float(self._tag.shape[0])
        src = np.array([[0.0, 0.0], [s, 0.0], [s, s], [0.0, s]], dtype=np.float32)
        H = cv2.getPerspectiveTransform(src, corners.astype(np.float32))
        w, h = camera.size
        warped = cv2.warpPerspective(self._tag, H, (w, h), flags=cv2.INTER_AREA)
        mask = cv2.warpPerspective(np.full_like(self._tag, 255), H, (w, h), flags=cv2.INTER_LINEAR)
        m = mask.astype(np.float32) / 255.0
        return np.asarray(out * (1.0 - m) + warped * m, dtype=np.float32).round().clip(0, 255).astype(np.uint8)
