"""Things on and around the pad in the simulated camera's frames
(docs/drop-zone.md): a box on the pad, a person walking into the margin at a drawn moment, and a
shadow across the pad that is not an object.

Each is drawn from a seeded generator (:func:`draw_occluder`) and painted into the frame before
the exposure (:meth:`Occluder.paint`, on :meth:`SimulatedCamera.render_optics`' image), projected
through the camera model from its place in the pad frame (x right, y up, z up out of the pad;
metres), so it moves, scales and distorts with the vehicle's pose as the pad does. The box and the
person stand up from the pad plane: their tops are nearer the camera, as a real box's is.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Literal

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform
from companion.vision.camera import CameraModel

log = logging.getLogger(__name__)

U8Image = NDArray[np.uint8]
OccluderKind = Literal["none", "box", "person", "shadow"]
OCCLUDER_KINDS: tuple[OccluderKind, ...] = ("none", "box", "person", "shadow")
#: the occluders' own random stream beside a seed
OCCLUDER_STREAM = 0x0CC1
#: a person seen from above: shoulders (an ellipse, semi-axes m) at this height, the head above
PERSON_SHOULDER_M = (0.24, 0.13)
PERSON_SHOULDER_Z_M = 1.45
PERSON_HEAD_R_M = 0.1
PERSON_HEAD_Z_M = 1.7


@dataclass(frozen=True, slots=True)
class Occluder:
    """One occluder in the pad frame. ``box``: centre ``xy_m``, sides ``size_m`` (x, y), height
    ``height_m``, turned ``yaw_rad``, top grey ``grey``; ``person``: walks from ``xy_m`` along
    ``heading_rad`` at ``speed_m_s`` from ``start_s`` (not in the frame before), clothes ``grey``;
    ``shadow``: a band of width ``size_m[0]`` through ``xy_m`` along ``yaw_rad``, the ground under
    it darker by the factor ``darkness``."""

    kind: OccluderKind
    xy_m: tuple[float, float] = (0.0, 0.0)
    size_m: tuple[float, float] = (0.0, 0.0)
    height_m: float = 0.0
    yaw_rad: float = 0.0
    grey: int = 128
    speed_m_s: float = 0.0
    heading_rad: float = 0.0
    start_s: float = 0.0
    darkness: float = 0.0
    #: person: when it first enters the margin (the pad's edge + margin), for the time to decide
    enters_margin_s: float = math.inf

    def __post_init__(self) -> None:
        if self.kind not in OCCLUDER_KINDS:
            raise ValueError(f"occluder kind = {self.kind!r}: expected one of {OCCLUDER_KINDS}")
        for name in ("height_m", "speed_m_s", "darkness", "start_s"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0.0):
                raise ValueError(f"occluder {name} = {v!r}: must be finite and >= 0")
        if not 0 <= self.grey <= 255:
            raise ValueError(f"occluder grey = {self.grey!r}: must be 0-255")
        if self.darkness >= 1.0:
            raise ValueError(f"occluder darkness = {self.darkness!r}: must be < 1")

    def person_xy_m(self, t: float) -> tuple[float, float] | None:
        """Where the person is at ``t`` (None before ``start_s``)."""
        if self.kind != "person" or t < self.start_s:
            return None
        d = self.speed_m_s * (t - self.start_s)
        return self.xy_m[0] + d * math.cos(self.heading_rad), self.xy_m[1] + d * math.sin(self.heading_rad)

    def present(self, t: float) -> bool:
        """Is there something on the pad or in the margin at ``t`` (the shadow is not a thing)."""
        if self.kind == "box":
            return True
        return self.kind == "person" and t >= self.enters_margin_s

    def paint(self, img: U8Image, camera: CameraModel, T_camera_pad: Transform, t: float) -> U8Image:
        """The frame with this occluder in it (a new array; ``img`` itself for ``none``)."""
        if self.kind == "none":
            return img
        out = img.copy()
        R = np.asarray(T_camera_pad.R, dtype=float)
        tv = np.asarray(T_camera_pad.t, dtype=float)

        w_px, h_px = camera.size

        def px(points: NDArray[np.float64]) -> NDArray[np.int32] | None:
            cam_pts = points @ R.T + tv
            if np.any(cam_pts[:, 2] < 0.2):
                return None  # at or behind the lens: not drawn
            uv = camera.project(cam_pts)
            # far outside the frame the lens model folds over: such a shape is not drawn
            if not np.all(np.isfinite(uv)) or np.any(np.abs(uv - [w_px / 2, h_px / 2]) > [1.5 * w_px, 1.5 * h_px]):
                return None
            return np.round(uv * 16).astype(np.int32)  # 4 fractional bits for fillPoly's shift

        if self.kind == "box":
            c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
            hx, hy = self.size_m[0] / 2, self.size_m[1] / 2
            base = [(-hx, -hy), (hx, -hy), (hx, hy), (-hx, hy)]
            xy = [(self.xy_m[0] + c * a - s * b, self.xy_m[1] + s * a + c * b) for a, b in base]
            bottom = np.array([[x, y, 0.0] for x, y in xy])
            top = np.array([[x, y, self.height_m] for x, y in xy])
            pb, pt = px(bottom), px(top)
            if pb is None or pt is None:
                return out
            side = max(0, self.grey - 45)  # the sides in the box's own shade
            for i in range(4):
                j = (i + 1) % 4
                face = np.array([pb[i], pb[j], pt[j], pt[i]])
                cv2.fillConvexPoly(out, face, side, lineType=cv2.LINE_AA, shift=4)
            cv2.fillConvexPoly(out, pt, self.grey, lineType=cv2.LINE_AA, shift=4)
            # packing tape along the top: a lighter stripe
            tape = np.array([[x, y, self.height_m] for x, y in _stripe(xy)])
            ptape = px(tape)
            if ptape is not None:
                cv2.fillConvexPoly(out, ptape, min(255, self.grey + 50), lineType=cv2.LINE_AA, shift=4)
            return out
        if self.kind == "person":
            where = self.person_xy_m(t)
            if where is None:
                return out
            a = np.linspace(0.0, 2 * math.pi, 24, endpoint=False)
            h = self.heading_rad + math.pi / 2  # shoulders across the walking direction
            ex, ey = PERSON_SHOULDER_M
            sh = np.stack(
                [
                    where[0] + ex * np.cos(a) * math.cos(h) - ey * np.sin(a) * math.sin(h),
                    where[1] + ex * np.cos(a) * math.sin(h) + ey * np.sin(a) * math.cos(h),
                    np.full(a.size, PERSON_SHOULDER_Z_M),
                ],
                axis=1,
            )
            head = np.stack(
                [
                    where[0] + PERSON_HEAD_R_M * np.cos(a),
                    where[1] + PERSON_HEAD_R_M * np.sin(a),
                    np.full(a.size, PERSON_HEAD_Z_M),
                ],
                axis=1,
            )
            p1, p2 = px(sh), px(head)
            if p1 is not None:
                cv2.fillPoly(out, [p1], self.grey, lineType=cv2.LINE_AA, shift=4)
            if p2 is not None:
                cv2.fillPoly(out, [p2], max(0, min(255, 60 if self.grey > 100 else 170)), lineType=cv2.LINE_AA, shift=4)
            return out
        # shadow: a band across the pad on the ground plane: every pixel's ray meets the plane
        # (exact under any lens, where a projected polygon would fold), soft edged
        rays = _rays(camera)
        d = rays @ R  # the rays in the pad frame (R^T ray, row-wise)
        o = -R.T @ tv
        with np.errstate(divide="ignore", invalid="ignore"):
            s_hit = -o[2] / d[:, 2]
        hit = s_hit > 0
        gx = o[0] + s_hit * d[:, 0] - self.xy_m[0]
        gy = o[1] + s_hit * d[:, 1] - self.xy_m[1]
        across = np.abs(-math.sin(self.yaw_rad) * gx + math.cos(self.yaw_rad) * gy)
        mask = (hit & (across <= self.size_m[0] / 2)).reshape(h_px, w_px).astype(np.float32)
        soft = np.asarray(cv2.GaussianBlur(mask, (0, 0), 1.5), dtype=np.float32)
        f = 1.0 - np.float32(self.darkness) * soft
        return np.clip(out.astype(np.float32) * f, 0, 255).astype(np.uint8)


_RAYS: dict[str, NDArray[np.float64]] = {}


def _rays(camera: CameraModel) -> NDArray[np.float64]:
    """Each pixel's ray (z = 1) in the camera frame, row-major; computed once per camera model."""
    key = repr(camera)
    if key not in _RAYS:
        w, h = camera.size
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        _RAYS[key] = camera.unproject(np.stack([u.ravel(), v.ravel()], axis=1))
    return _RAYS[key]


def _stripe(xy: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """A tape stripe a sixth of the box wide along the middle of its top (corners in order)."""
    (x0, y0), (x1, y1), (x2, y2), (x3, y3) = xy
    f0, f1 = 5 / 12, 7 / 12

    def lerp(a: tuple[float, float], b: tuple[float, float], u: float) -> tuple[float, float]:
        return a[0] + (b[0] - a[0]) * u, a[1] + (b[1] - a[1]) * u

    return [
        lerp((x0, y0), (x1, y1), f0),
        lerp((x0, y0), (x1, y1), f1),
        lerp((x3, y3), (x2, y2), f1),
        lerp((x3, y3), (x2, y2), f0),
    ]


def draw_occluder(
    kind: OccluderKind,
    rng: np.random.Generator,
    *,
    pad_size_m: float = 1.0,
    margin_m: float = 1.0,
    duration_s: float = 8.0,
) -> Occluder:
    """A seeded occluder of ``kind``: a box lying wholly on the pad (0.25-0.5 m sides, 0.15-0.4 m
    tall, any yaw, a cardboard grey); a person walking past the pad at 0.8-1.5 m/s whose path
    comes within 0.1-0.8 m of the pad's edge, entering the margin at a moment drawn in the first
    60 % of ``duration_s``; a shadow band 0.2-0.6 m wide across the pad, 30-70 % darker."""
    if kind not in OCCLUDER_KINDS:
        raise ValueError(f"occluder kind = {kind!r}: expected one of {OCCLUDER_KINDS}")
    if not (math.isfinite(duration_s) and duration_s > 0):
        raise ValueError(f"duration_s = {duration_s!r}: must be > 0")
    hp = pad_size_m / 2
    if kind == "none":
        return Occluder("none")
    if kind == "box":
        sx, sy = (float(v) for v in rng.uniform(0.25, 0.5, 2))
        yaw = float(rng.uniform(0.0, math.pi))
        # the box's footprint radius bounds where its centre may lie and stay on the pad
        r = 0.5 * math.hypot(sx, sy)
        lim = max(0.0, hp - r)
        xy = (float(rng.uniform(-lim, lim)), float(rng.uniform(-lim, lim)))
        return Occluder(
            "box",
            xy,
            (sx, sy),
            float(rng.uniform(0.15, 0.4)),
            yaw,
            int(rng.integers(110, 200)),
        )
    if kind == "person":
        speed = float(rng.uniform(0.8, 1.5))
        closest = hp + float(rng.uniform(0.1, 0.8))  # from the pad centre, along a side's normal
        side = float(rng.uniform(0.0, 2 * math.pi))
        # the path: a line whose nearest point to the pad centre is `closest` away, along `heading`
        heading = side + math.pi / 2
        nx, ny = math.cos(side), math.sin(side)
        t_enter = float(rng.uniform(0.1, 0.6)) * duration_s
        # walk from well outside; enter the margin (distance hp + margin from the centre) at t_enter
        reach = hp + margin_m
        along_enter = -math.sqrt(max(reach**2 - closest**2, 0.0))  # where the line crosses the margin's circle
        lead_m = 1.5  # it walks this far before it reaches the margin
        start_along = along_enter - lead_m
        start = (closest * nx + start_along * math.cos(heading), closest * ny + start_along * math.sin(heading))
        start_s = max(0.0, t_enter - lead_m / speed)
        grey = int(rng.choice([int(rng.integers(20, 65)), int(rng.integers(165, 230))]))
        return Occluder(
            "person",
            start,
            speed_m_s=speed,
            heading_rad=heading,
            start_s=start_s,
            grey=grey,
            enters_margin_s=start_s + lead_m / speed,
        )
    width = float(rng.uniform(0.2, 0.6))
    xy = (float(rng.uniform(-0.25, 0.25)), float(rng.uniform(-0.25, 0.25)))
    return Occluder(
        "shadow", xy, (width, 0.0), yaw_rad=float(rng.uniform(0.0, math.pi)), darkness=float(rng.uniform(0.3, 0.7))
    )
