"""Simulated downward camera that renders real greyscale images of the landing pad.

Import as ``from companion_sitl.camera import SimulatedCamera``.

Rendering, per frame:

1. The ground (a seeded procedural texture with clutter) and the pad texture lie on the plane
   z = 0 of the pad frame. Each is mapped into an *undistorted* canvas by the plane homography
   ``H = K [r1 r2 t] A`` (``cv2.warpPerspective``), where ``[r1 r2 t]`` comes from
   ``T_camera_pad`` and ``A`` maps texture pixels to pad-plane metres. Textures are kept at
   several resolutions (INTER_AREA pyramids) and the level is chosen so a texel covers about
   one image pixel, which avoids aliasing at altitude.
2. Lens distortion is applied with ``cv2.remap`` through maps computed once per camera: every
   distorted output pixel looks up its ideal (pinhole) position, ``CameraModel.undistort_pixels``
   on the pixel grid (OpenCV model or dart eqs 2-4). The canvas is larger than the image when
   barrel distortion pulls the view outwards.
3. Optional motion blur (a line kernel), lighting (gain / offset, with optional per-frame
   jitter) and exposure noise (Gaussian, from a seeded noise bank).

Frames: world NED; body FRD; camera OpenCV (x right, y down, z optical axis); pad = ArUco marker
frame (x right, y up, z up out of the pad). The default mount looks straight down with the
image top towards the vehicle's front: camera x -> body y, camera y -> body -x, camera z -> body
z, i.e. ``R_body_camera = rot_z(pi/2)``. The default pad pose has pad x = east, pad y = north,
so a vehicle heading north sees the printed pad upright.

Time: the caller passes the exposure time; the frame carries it and the time it becomes
available (exposure + ``latency_s``). Nothing here reads a clock.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform
from companion.geometry.mounts import R_BODY_CAMERA_DOWN, downward_mount, pad_pose_ned
from companion.vision.camera import CameraModel
from companion.vision.pad import PadLayout, render_pad_px

log = logging.getLogger(__name__)

U8Image = NDArray[np.uint8]

#: Downward camera, image top towards the vehicle front (camera x -> body y, y -> -x, z -> z).
# the mount and pad-frame conventions live in companion.geometry.mounts (re-exported here)
__all__ = ["R_BODY_CAMERA_DOWN", "SimCameraConfig", "SimFrame", "SimulatedCamera", "downward_mount", "pad_pose_ned"]


def check_pose(T: Transform, name: str = "pose") -> None:
    """Reject non-finite or non-rotation poses with a ValueError naming the pose."""
    R = np.asarray(T.R, dtype=float)
    t = np.asarray(T.t, dtype=float)
    if R.shape != (3, 3) or t.shape != (3,):
        raise ValueError(f"{name}: R must be 3x3 and t 3-vector, got {R.shape} and {t.shape}")
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        raise ValueError(f"{name}: contains NaN or inf (R={R.tolist()}, t={t.tolist()})")
    if np.max(np.abs(R.T @ R - np.eye(3))) > 1e-6 or abs(np.linalg.det(R) - 1.0) > 1e-6:
        raise ValueError(f"{name}: R is not a rotation matrix")


@dataclass(frozen=True)
class SimCameraConfig:
    """Image formation settings of the simulated camera (all deterministic given the seed)."""

    latency_s: float = 0.03  # exposure -> frame available to the application
    noise_std: float = 2.0  # grey levels, Gaussian exposure noise
    blur_px: float = 0.0  # motion blur length (0 = off)
    blur_angle_rad: float = 0.0  # direction of the blur in the image (0 = along +x)
    gain: float = 1.0
    offset: float = 0.0
    gain_jitter: float = 0.0  # per-frame std of the gain
    offset_jitter: float = 0.0  # per-frame std of the offset (grey levels)
    ground_size_m: float = 45.0
    ground_texel_m: float = 0.02
    pad_texel_m: float = 0.001
    clutter: int = 120  # shapes on the ground around the pad
    clutter_radius_m: float = 12.0
    sky_level: int = 230

    def __post_init__(self) -> None:
        for name in ("latency_s", "noise_std", "blur_px", "gain_jitter", "offset_jitter"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ValueError(f"SimCameraConfig.{name} = {v!r}: must be finite and >= 0")
        for name in ("gain", "ground_size_m", "ground_texel_m", "pad_texel_m", "clutter_radius_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"SimCameraConfig.{name} = {v!r}: must be finite and > 0")
        if not math.isfinite(self.offset) or not math.isfinite(self.blur_angle_rad):
            raise ValueError("SimCameraConfig.offset / blur_angle_rad must be finite")
        if self.clutter < 0:
            raise ValueError(f"SimCameraConfig.clutter = {self.clutter!r}: must be >= 0")


@dataclass(frozen=True, eq=False)
class SimFrame:
    """One rendered frame with its ground truth."""

    image: U8Image
    exposure_time_s: float
    available_time_s: float  # exposure + latency: when the application may see it
    T_camera_pad: Transform  # truth
    T_world_camera: Transform | None = None


@dataclass
class _Texture:
    """A texture on the pad plane, centred on the pad origin, with a resolution pyramid."""

    base: U8Image
    extent_m: float  # side length in metres (square textures)
    levels: dict[int, U8Image] = field(default_factory=dict)

    def level(self, n: int) -> U8Image:
        """Level n: 2^-n of the base resolution (exact 2x box filters while the side is even)."""
        if n <= 0:
            return self.base
        if n not in self.levels:
            prev = self.level(n - 1)
            if prev.shape[0] <= 8 or prev.shape[0] % 2:
                return prev  # no exact 2x level below this one
            side = prev.shape[0] // 2
            self.levels[n] = np.asarray(cv2.resize(prev, (side, side), interpolation=cv2.INTER_AREA), dtype=np.uint8)
        return self.levels[n]

    def texel_to_plane(self, img: U8Image) -> NDArray[np.float64]:
        """A: texture pixel (c, r, 1) -> pad-plane (X, Y, 1) in metres; pixel centres at integers."""
        s = self.extent_m / img.shape[0]
        h = self.extent_m / 2.0
        return np.array([[s, 0.0, 0.5 * s - h], [0.0, -s, h - 0.5 * s], [0.0, 0.0, 1.0]])


def _ground_texture(cfg: SimCameraConfig, rng: np.random.Generator) -> U8Image:
    n = -(-round(cfg.ground_size_m / cfg.ground_texel_m) // 64) * 64  # exact 2x pyramid levels
    coarse = rng.normal(0.0, 1.0, (24, 24)).astype(np.float32)
    low = cv2.resize(coarse, (n, n), interpolation=cv2.INTER_CUBIC)
    mid = np.asarray(
        cv2.resize(rng.normal(0.0, 1.0, (n // 16, n // 16)).astype(np.float32), (n, n), interpolation=cv2.INTER_LINEAR),
        dtype=np.float32,
    )
    # 105 + 22 low + 10 mid + 6 N(0, 1), evaluated left to right in float32 as that expression
    # is, in place (each step the same single rounding; + commutes exactly): no 21 MB temporaries
    img = np.asarray(low, dtype=np.float32)
    img *= 22.0
    img += 105.0
    mid *= 10.0
    img += mid
    noise = rng.standard_normal((n, n), dtype=np.float32)
    noise *= 6.0
    img += noise
    ground = np.clip(img, 0, 255, out=img).astype(np.uint8)
    px_per_m = 1.0 / cfg.ground_texel_m
    c0 = n / 2.0

    def to_px(x: float, y: float) -> tuple[int, int]:
        return round(c0 + x * px_per_m), round(c0 - y * px_per_m)

    keep_out = 1.2  # metres around the pad centre left free (the pad is 1 m)
    for _ in range(cfg.clutter):
        r = cfg.clutter_radius_m * math.sqrt(rng.uniform(0.0, 1.0))
        a = rng.uniform(0.0, 2.0 * math.pi)
        x, y = r * math.cos(a), r * math.sin(a)
        if math.hypot(x, y) < keep_out + 0.6:
            continue
        kind = int(rng.integers(0, 5))
        grey = int(rng.integers(0, 256))
        size = rng.uniform(0.15, 1.2)
        if kind in (0, 1):  # rotated rectangle or square tile (quad candidates for the detector)
            w = size
            h = size if kind == 1 else size * rng.uniform(0.3, 1.0)
            ang = rng.uniform(0.0, 180.0)
            box = cv2.boxPoints(((c0 + x * px_per_m, c0 - y * px_per_m), (w * px_per_m, h * px_per_m), ang))
            if kind == 1:  # dark tile on a light border, like a marker without a valid code
                border = cv2.boxPoints(
                    ((c0 + x * px_per_m, c0 - y * px_per_m), (1.4 * w * px_per_m, 1.4 * h * px_per_m), ang)
                )
                cv2.fillPoly(ground, [np.round(border).astype(np.int32)], 235)
                grey = int(rng.integers(0, 60))
            cv2.fillPoly(ground, [np.round(box).astype(np.int32)], grey)
        elif kind == 2:
            cv2.circle(ground, to_px(x, y), max(1, round(size / 2 * px_per_m)), grey, -1)
        elif kind == 3:
            a2 = rng.uniform(0.0, 2.0 * math.pi)
            p2 = (x + 2.0 * size * math.cos(a2), y + 2.0 * size * math.sin(a2))
            cv2.line(ground, to_px(x, y), to_px(*p2), grey, max(1, round(0.05 * px_per_m)))
        else:  # grid of small squares (a paving / checker patch)
            k = int(rng.integers(2, 5))
            cell = size / k
            for i in range(k):
                for j in range(k):
                    if (i + j) % 2:
                        p0 = to_px(x + i * cell, y + j * cell)
                        p1 = to_px(x + (i + 1) * cell, y + (j + 1) * cell)
                        cv2.rectangle(ground, p0, p1, 30, -1)
    return ground


_Distortion = tuple[tuple[float, float], tuple[int, int], tuple[NDArray, NDArray] | None]
_DISTORTION_CACHE: dict[str, _Distortion] = {}
_DISTORTION_CACHE_SIZE = 8


def _distortion_setup(cam: CameraModel) -> _Distortion:
    """The undistorted canvas (offset of the image in it, its size) and the ``cv2.remap`` maps
    (distorted pixel -> canvas) of a camera model; None for the maps of an undistorted camera.

    The maps depend on the model alone, and every landing of a campaign builds a camera of the same
    model: they are computed once per model (keyed by its repr, which tells every float apart)
    and shared read-only.
    """
    key = repr(cam)
    hit = _DISTORTION_CACHE.get(key)
    if hit is not None:
        return hit
    w, h = cam.size
    out: _Distortion
    if not cam.is_distorted:
        out = ((0.0, 0.0), (w, h), None)
    else:
        u, v = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
        ideal = cam.undistort_pixels(np.stack([u.ravel(), v.ravel()], axis=1))
        if not np.all(np.isfinite(ideal)):
            raise ValueError("camera distortion is not invertible over the whole image")
        mx = ideal[:, 0].reshape(h, w)
        my = ideal[:, 1].reshape(h, w)
        ox = max(0.0, math.ceil(-mx.min()) + 2.0)
        oy = max(0.0, math.ceil(-my.min()) + 2.0)
        cw = math.ceil(mx.max() + ox) + 3
        ch = math.ceil(my.max() + oy) + 3
        m1, m2 = cv2.convertMaps((mx + ox).astype(np.float32), (my + oy).astype(np.float32), cv2.CV_16SC2)
        m1.flags.writeable = False
        m2.flags.writeable = False
        out = ((ox, oy), (cw, ch), (m1, m2))
    if len(_DISTORTION_CACHE) >= _DISTORTION_CACHE_SIZE:
        del _DISTORTION_CACHE[next(iter(_DISTORTION_CACHE))]  # the oldest
    _DISTORTION_CACHE[key] = out
    return out


# Columns of a warp's destination are processed in SIMD blocks from x = 0 (OpenCV: 2x the float32
# lanes, 8 to 32 pixels), the last partial block by scalar code that rounds differently; a
# destination narrowed to a multiple of 64 columns keeps every pixel in the same kind of block.
_WARP_COLUMN_BLOCK = 64


def _transparent_warp_extent(H: NDArray, tex_side: int, canvas_size: tuple[int, int]) -> tuple[int, int] | None:
    """(width, height) of the top-left part of the canvas outside of which a BORDER_TRANSPARENT
    ``cv2.warpPerspective`` of a square ``tex_side``-texel texture through ``H`` (texel -> canvas
    pixel) writes nothing; (0, 0) when it misses the canvas; None when a texture corner is not in
    front of the camera (then warp the whole canvas).

    Each destination pixel's source position depends only on its own (x, y) and ``H``, so warping
    into ``canvas[:height, :width]`` gives the same pixels there as warping the whole canvas (the
    width is a multiple of :data:`_WARP_COLUMN_BLOCK` or the canvas width, see there); pixels
    outside are left as they are, as the whole-canvas warp leaves them.
    """
    cw, ch = canvas_size
    lo, hi = -2.0, tex_side + 1.0  # bilinear taps reach a texel past the outer texel centres; one more spare
    xs, ys = [], []
    for c, r in ((lo, lo), (hi, lo), (hi, hi), (lo, hi)):
        w = H[2, 0] * c + H[2, 1] * r + H[2, 2]
        if not w > 1e-9:  # also NaN
            return None
        xs.append((H[0, 0] * c + H[0, 1] * r + H[0, 2]) / w)
        ys.append((H[1, 0] * c + H[1, 1] * r + H[1, 2]) / w)
    # w > 0 at every corner, so over the whole square: its image is the convex hull of the corners
    margin = 2.0
    x_max, y_max = max(xs) + margin, max(ys) + margin
    if x_max < 0.0 or y_max < 0.0 or min(xs) - margin > cw or min(ys) - margin > ch:
        return (0, 0)
    width = min(cw, -(-(math.ceil(x_max) + 1) // _WARP_COLUMN_BLOCK) * _WARP_COLUMN_BLOCK)
    height = min(ch, math.ceil(y_max) + 1)
    return width, height


class SimulatedCamera:
    """A downward camera over the pad; deterministic for a given ``seed``.

    ``capture(T_world_body, exposure_time_s)`` renders what the camera mounted at
    ``T_body_camera`` sees; ``render(T_camera_pad)`` renders from a relative pose directly.
    """

    #: warp the pad only into the part of the canvas it can reach (same pixels; False: the whole
    #: canvas, the reference the tests compare against)
    crop_pad_warp: bool = True

    def __init__(
        self,
        camera: CameraModel,
        layout: PadLayout | None = None,
        config: SimCameraConfig | None = None,
        *,
        T_body_camera: Transform | None = None,
        T_world_pad: Transform | None = None,
        seed: int = 0,
    ) -> None:
        self.camera = camera
        self.layout = layout if layout is not None else PadLayout()
        self.config = config if config is not None else SimCameraConfig()
        self.T_body_camera = T_body_camera if T_body_camera is not None else downward_mount()
        self.T_world_pad = T_world_pad if T_world_pad is not None else pad_pose_ned()
        check_pose(self.T_body_camera, "T_body_camera")
        check_pose(self.T_world_pad, "T_world_pad")
        self._rng = np.random.default_rng(seed)
        cfg = self.config
        gtex = _ground_texture(cfg, self._rng)
        self._ground = _Texture(gtex, gtex.shape[0] * cfg.ground_texel_m)
        self._ground_mean = int(np.mean(self._ground.base[::8, ::8]))
        # The pad texture is padded (with the ground's mean grey) to a multiple of 2^6 texels so
        # that every pyramid level is an exact 2x box filter and keeps marker edges in place.
        pad_px = round(self.layout.pad_size_m / cfg.pad_texel_m)
        side = -(-pad_px // 64) * 64
        tex = np.full((side, side), self._ground_mean, np.uint8)
        o = (side - pad_px) // 2
        tex[o : o + pad_px, o : o + pad_px] = render_pad_px(self.layout, pad_px)
        self._pad = _Texture(tex, side * self.layout.pad_size_m / pad_px)
        self._setup_distortion()
        w, h = camera.size
        self._noise_margin = 64
        self._noise = self._rng.standard_normal((h + self._noise_margin, w + self._noise_margin)).astype(
            np.float32
        ) * np.float32(cfg.noise_std)
        self._blur_kernel = self._make_blur_kernel()
        # per-frame constants, computed once: the canvas intrinsics and their inverse (sky test),
        # the mean focal length (texture levels), and the buffers a frame is built in (canvas and
        # undistorted image are overwritten whole every frame, exposure works in float32; the
        # frame handed out is a new array): one camera renders one frame at a time
        ox, oy = self._offset
        self._Kc = camera.K.copy()
        self._Kc[0, 2] += ox
        self._Kc[1, 2] += oy
        self._Kc_inv = np.linalg.inv(self._Kc)
        self._f = 0.5 * (camera.fx + camera.fy)
        cw, ch = self._canvas_size
        self._canvas: U8Image = np.empty((ch, cw), np.uint8)
        self._undistorted: U8Image = np.empty((h, w), np.uint8)
        self._exposure = np.empty((h, w), np.float32)
        self.frames_rendered = 0

    @property
    def distortion_maps(self) -> tuple[NDArray, NDArray] | None:
        """The remap tables from the undistorted canvas to the camera's pixels (read-only arrays,
        shared by every camera of the same model; None without distortion)."""
        return self._maps

    # ------------------------------------------------------------------ setup
    def _setup_distortion(self) -> None:
        self._offset, self._canvas_size, self._maps = _distortion_setup(self.camera)

    def _make_blur_kernel(self) -> NDArray[np.float32] | None:
        L = self.config.blur_px
        if L < 1.0:
            return None
        n = math.ceil(L) | 1
        k = np.zeros((n, n), np.float32)
        c = n // 2
        dx, dy = math.cos(self.config.blur_angle_rad), math.sin(self.config.blur_angle_rad)
        for s in np.linspace(-L / 2.0, L / 2.0, 4 * n):
            k[round(c + s * dy), round(c + s * dx)] = 1.0
        return k / k.sum()

    # ------------------------------------------------------------------ poses
    def T_world_camera(self, T_world_body: Transform) -> Transform:
        check_pose(T_world_body, "T_world_body")
        return T_world_body @ self.T_body_camera

    def T_camera_pad(self, T_world_body: Transform) -> Transform:
        """Truth: pose of the pad in the camera frame for a vehicle pose."""
        return self.T_world_camera(T_world_body).inverse() @ self.T_world_pad

    def capture(self, T_world_body: Transform, exposure_time_s: float) -> SimFrame:
        """Render the frame exposed at ``exposure_time_s`` with the vehicle at ``T_world_body``."""
        if not math.isfinite(exposure_time_s):
            raise ValueError(f"exposure_time_s = {exposure_time_s!r}: must be finite")
        T_wc = self.T_world_camera(T_world_body)
        T_cp = T_wc.inverse() @ self.T_world_pad
        image = self.render(T_cp)
        return SimFrame(image, float(exposure_time_s), float(exposure_time_s) + self.config.latency_s, T_cp, T_wc)

    def capture_camera(self, T_world_camera: Transform, exposure_time_s: float) -> SimFrame:
        """Render the frame for a camera pose given directly in the world (NED) frame."""
        if not math.isfinite(exposure_time_s):
            raise ValueError(f"exposure_time_s = {exposure_time_s!r}: must be finite")
        check_pose(T_world_camera, "T_world_camera")
        T_cp = T_world_camera.inverse() @ self.T_world_pad
        image = self.render(T_cp)
        return SimFrame(
            image, float(exposure_time_s), float(exposure_time_s) + self.config.latency_s, T_cp, T_world_camera
        )

    # ------------------------------------------------------------------ rendering
    def _level_for(self, tex: _Texture, px_per_texel: float) -> int:
        if px_per_texel >= 1.0:
            return 0
        return max(0, round(math.log2(1.0 / px_per_texel)))

    def render(self, T_camera_pad: Transform) -> U8Image:
        """Greyscale uint8 image (height_px, width_px) of the scene seen from ``T_camera_pad``."""
        return self.expose(self.render_optics(T_camera_pad))

    def render_optics(self, T_camera_pad: Transform, *, fresh: bool = False) -> U8Image:
        """The image before exposure: the scene through the lens (and motion blur), a function of
        the pose alone (it draws nothing from the random generator). :meth:`expose` finishes it.

        It is built in the camera's buffers, so one call at a time; ``fresh``: the result is a new
        array (else it may be a buffer of the camera, valid until the next call)."""
        check_pose(T_camera_pad, "T_camera_pad")
        R = np.asarray(T_camera_pad.R, dtype=float)
        t = np.asarray(T_camera_pad.t, dtype=float)
        cam_in_pad = -R.T @ t
        if cam_in_pad[2] <= 1e-3:
            raise ValueError(f"T_camera_pad: camera is {cam_in_pad[2]:.3f} m above the pad plane; must be above it")
        cfg = self.config
        cw, ch = self._canvas_size
        Kc = self._Kc
        P = Kc @ np.column_stack([R[:, 0], R[:, 1], t])  # pad plane (X, Y, 1) -> canvas pixels

        # depth of the ground under the optical axis, for the ground's texture level
        ray_pad = R.T @ np.array([0.0, 0.0, 1.0])
        depth = cam_in_pad[2] / max(-ray_pad[2], 0.1)
        f = self._f
        lg = self._level_for(self._ground, f * cfg.ground_texel_m / depth)
        gimg = self._ground.level(lg)
        canvas = self._canvas
        cv2.warpPerspective(
            gimg,
            P @ self._ground.texel_to_plane(gimg),
            (cw, ch),
            dst=canvas,
            flags=cv2.INTER_LINEAR,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=self._ground_mean,
        )
        z_pad = max(float(t[2]), 1e-3)  # depth of the pad centre
        lp = self._level_for(self._pad, f * cfg.pad_texel_m / z_pad)
        pimg = self._pad.level(lp)
        H_pad = P @ self._pad.texel_to_plane(pimg)
        # the pad covers a small part of the canvas: warp only the top-left-anchored part it can
        # reach (same pixels, see _transparent_warp_extent), or nothing when it misses the canvas
        ext = _transparent_warp_extent(H_pad, pimg.shape[0], (cw, ch)) if self.crop_pad_warp else None
        pw, ph = ext if ext is not None else (cw, ch)
        if pw > 0 and ph > 0:
            cv2.warpPerspective(
                pimg,
                H_pad,
                (pw, ph),
                dst=canvas[:ph, :pw],
                flags=cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_TRANSPARENT,
            )
        self._paint_sky(canvas, R, Kc)
        if self._maps is not None:
            img: Any = cv2.remap(canvas, *self._maps, cv2.INTER_LINEAR, dst=None if fresh else self._undistorted)
        else:
            img = canvas.copy() if fresh else canvas
        if self._blur_kernel is not None:
            img = cv2.filter2D(img, -1, self._blur_kernel, borderType=cv2.BORDER_REPLICATE)
        return np.asarray(img, dtype=np.uint8)

    def _paint_sky(self, canvas: U8Image, R: NDArray, Kc: NDArray) -> None:
        """Pixels whose ray does not reach the ground (above the horizon) get the sky level."""
        ch, cw = canvas.shape
        # ray direction z in the pad frame is linear in the pixel: n . [u, v, 1]
        Kc_inv = self._Kc_inv if Kc is self._Kc else np.linalg.inv(Kc)
        n = (R.T @ Kc_inv)[2]
        corners = np.array([[0, 0, 1], [cw - 1, 0, 1], [0, ch - 1, 1], [cw - 1, ch - 1, 1]], float)
        if np.all(corners @ n < -1e-3):
            return
        u, v = np.meshgrid(np.arange(cw, dtype=np.float32), np.arange(ch, dtype=np.float32))
        sky = (n[0] * u + n[1] * v + n[2]) >= -1e-3
        canvas[sky] = self.config.sky_level

    def expose(self, img: U8Image) -> U8Image:
        """The frame from :meth:`render_optics`' image: gain, offset and exposure noise (drawn from
        the camera's random generator, one frame after the other); a new array."""
        out = self._expose(img)
        self.frames_rendered += 1
        return out

    def _expose(self, img: U8Image) -> U8Image:
        cfg = self.config
        gain = cfg.gain
        offset = cfg.offset
        if cfg.gain_jitter > 0:
            gain = max(0.05, gain + float(self._rng.normal(0.0, cfg.gain_jitter)))
        if cfg.offset_jitter > 0:
            offset = offset + float(self._rng.normal(0.0, cfg.offset_jitter))
        h, w = img.shape
        # in the float32 buffer, in place: the same operations as img.astype(float32), *, +, clip
        out = self._exposure if self._exposure.shape == img.shape else np.empty(img.shape, np.float32)
        out[...] = img  # uint8 -> float32, exact
        if gain != 1.0 or offset != 0.0:
            out *= np.float32(gain)
            out += np.float32(offset)
        if cfg.noise_std > 0:
            dy, dx = (int(x) for x in self._rng.integers(0, self._noise_margin, 2))
            out += self._noise[dy : dy + h, dx : dx + w]
        np.clip(out, 0, 255, out=out)
        return out.astype(np.uint8)
