"""What a real board camera adds to the rendered frame (``[sim.camera]``, docs/vision.md): the
image's own motion during the exposure (motion blur) and the readout (rolling shutter), auto-
exposure steps under a cloud, a shadow band and a glare spot across the pad, low-light noise, JPEG
artefacts, late and dropped frames. All off by default: a frame is then the renderer's, bit for bit.

The motion effects take the image velocity of the pad's centre (pixels per second, from the
true poses of two exposures) as the whole image's: first order, right for a downward camera over
a flat pad when the yaw rate is small. Every draw comes from a generator of its own (the
camera's seed and a fixed stream), so switching a condition on changes no other random draw."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

U8Image = NDArray[np.uint8]
CONDITIONS_STREAM = 0x0CA3  # the conditions' own random stream beside the camera's seed
SHADOW_WIDTH = 0.35  # of the image diagonal: the band's width
SHADOW_SWEEP_PX_S = 40.0  # the band's drift across the image (a cloud's shadow, a moving tree)
GLARE_SIGMA = 0.12  # of the image width: the spot's size


@dataclass(frozen=True, slots=True)
class FrameFate:
    """What the driver did with one exposure: dropped, or late by ``extra_latency_s``."""

    dropped: bool
    extra_latency_s: float


class CameraConditions:
    """The conditions of one ``[sim.camera]`` table (``config``: a
    :class:`companion_sitl.params.SimCameraConditionsConfig` or anything with its fields)."""

    def __init__(self, config: Any, seed: int) -> None:
        self.config = config
        self._rng = np.random.default_rng([seed, CONDITIONS_STREAM])
        # drawn once per flight: where the shadow's edge lies and how it is turned, where the glare is
        self._shadow_angle = float(self._rng.uniform(0.0, math.pi))
        self._shadow_phase = float(self._rng.uniform(-0.5, 0.5))
        self._glare_xy = (float(self._rng.uniform(0.2, 0.8)), float(self._rng.uniform(0.2, 0.8)))
        self._steps = _StepSchedule(config, np.random.default_rng([seed, CONDITIONS_STREAM, 1]))
        self.dropped = 0
        self.late = 0

    @property
    def active(self) -> bool:
        c = self.config
        return any(
            (
                c.exposure_s > 0,
                c.rolling_shutter_s > 0,
                c.jpeg_quality > 0,
                c.exposure_steps_s > 0,
                c.shadow > 0,
                c.glare > 0,
                c.low_light_noise > 0,
                c.drop_fraction > 0,
                c.late_s > 0,
            )
        )

    def fate(self) -> FrameFate:
        """The next exposure's fate, drawn in exposure order (one draw each, used or not)."""
        c = self.config
        u_drop, u_late = self._rng.random(2)
        dropped = bool(u_drop < c.drop_fraction)
        extra = float(u_late * c.late_s) if c.late_s > 0 else 0.0
        self.dropped += dropped
        self.late += extra > 0
        return FrameFate(dropped, extra)

    def motion(self, img: U8Image, velocity_px_s: tuple[float, float]) -> U8Image:
        """Motion blur over ``exposure_s`` and the rolling shutter's skew over ``rolling_shutter_s``
        for an image moving at ``velocity_px_s`` (u, v); the image itself when both are off."""
        c = self.config
        vu, vv = velocity_px_s
        out = img
        if c.rolling_shutter_s > 0 and (vu or vv):
            out = rolling_shutter(out, vu, vv, c.rolling_shutter_s)
        if c.exposure_s > 0 and (vu or vv):
            out = motion_blur(out, vu * c.exposure_s, vv * c.exposure_s)
        return out

    def photometric(self, img: U8Image, t: float) -> U8Image:
        """Auto-exposure steps, the shadow band, the glare spot, low-light noise, then JPEG."""
        c = self.config
        if not (c.exposure_steps_s > 0 or c.shadow > 0 or c.glare > 0 or c.low_light_noise > 0 or c.jpeg_quality > 0):
            return img
        out = img.astype(np.float32)
        gain = self._steps.gain(t)
        if gain != 1.0:
            out *= np.float32(gain)
        h, w = img.shape
        if c.shadow > 0:
            out *= self._shadow_mask(h, w, t)
        if c.glare > 0:
            out += self._glare(h, w)
        if c.low_light_noise > 0:
            out += self._rng.normal(0.0, c.low_light_noise, out.shape).astype(np.float32)
        np.clip(out, 0, 255, out=out)
        frame = out.astype(np.uint8)
        if c.jpeg_quality > 0:
            frame = jpeg(frame, int(c.jpeg_quality))
        return frame

    def _shadow_mask(self, h: int, w: int, t: float) -> NDArray[np.float32]:
        """1 outside the band, 1 - shadow inside: a straight band drifting across the frame."""
        diag = math.hypot(w, h)
        nx, ny = math.cos(self._shadow_angle), math.sin(self._shadow_angle)
        # the band's centre line sweeps across the frame and comes round again: always within it
        centre = ((self._shadow_phase * diag + SHADOW_SWEEP_PX_S * t + diag / 2) % diag) - diag / 2
        x = np.arange(w, dtype=np.float32) - w / 2
        y = np.arange(h, dtype=np.float32)[:, None] - h / 2
        d = np.abs(nx * x + ny * y - np.float32(centre))
        inside = d < np.float32(SHADOW_WIDTH * diag / 2)
        return np.where(inside, np.float32(1.0 - self.config.shadow), np.float32(1.0)).astype(np.float32)

    def _glare(self, h: int, w: int) -> NDArray[np.float32]:
        gx, gy = self._glare_xy[0] * w, self._glare_xy[1] * h
        s = GLARE_SIGMA * w
        x = (np.arange(w, dtype=np.float32) - gx) ** 2
        y = (np.arange(h, dtype=np.float32)[:, None] - gy) ** 2
        return (np.float32(self.config.glare) * np.exp(-(x + y) / np.float32(2 * s * s))).astype(np.float32)


class _StepSchedule:
    """Auto-exposure under passing clouds: steps at exponential intervals (mean ``exposure_steps_s``)
    to ``exposure_step_gain``, recovering linearly to 1 over ``exposure_recover_s``."""

    def __init__(self, config: Any, rng: np.random.Generator) -> None:
        self.config = config
        self._rng = rng
        self._starts: list[float] = []
        self._next = float(rng.exponential(config.exposure_steps_s)) if config.exposure_steps_s > 0 else math.inf

    def gain(self, t: float) -> float:
        c = self.config
        while self._next <= t:
            self._starts.append(self._next)
            self._next += float(self._rng.exponential(c.exposure_steps_s))
        if not self._starts:
            return 1.0
        since = t - self._starts[-1]
        if since < 0 or since >= c.exposure_recover_s:
            return 1.0
        return float(c.exposure_step_gain + (1.0 - c.exposure_step_gain) * since / c.exposure_recover_s)


def motion_blur(img: U8Image, du_px: float, dv_px: float) -> U8Image:
    """The image smeared along (du, dv) pixels (its motion during the exposure): a line kernel."""
    length = math.hypot(du_px, dv_px)
    if length < 1.0:
        return img
    n = math.ceil(length) | 1
    k = np.zeros((n, n), np.float32)
    c = n // 2
    for s in np.linspace(-0.5, 0.5, 4 * n):
        k[round(c + s * dv_px), round(c + s * du_px)] = 1.0
    k /= k.sum()
    out: Any = cv2.filter2D(img, -1, k, borderType=cv2.BORDER_REPLICATE)
    return out


def rolling_shutter(img: U8Image, vu_px_s: float, vv_px_s: float, readout_s: float) -> U8Image:
    """Row r read ``readout_s * r / h`` after the first: it shows the scene moved by the image's
    velocity times that delay (first order), so the frame is sheared along the motion."""
    h, w = img.shape
    tau = (np.arange(h, dtype=np.float32) / np.float32(h) * np.float32(readout_s))[:, None]
    map_x = np.arange(w, dtype=np.float32)[None, :] - np.float32(vu_px_s) * tau
    map_y = np.arange(h, dtype=np.float32)[:, None] - np.float32(vv_px_s) * tau
    map_x = np.broadcast_to(map_x, (h, w)).astype(np.float32)
    map_y = np.broadcast_to(map_y, (h, w)).astype(np.float32)
    out: Any = cv2.remap(img, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out


def jpeg(img: U8Image, quality: int) -> U8Image:
    """The frame after a JPEG round trip at ``quality`` (1-100), as an MJPG camera delivers it."""
    ok, buf = cv2.imencode(".jpg", img, [int(cv2.IMWRITE_JPEG_QUALITY), int(quality)])
    if not ok:  # OpenCV refused to encode: the frame as it was
        return img
    out: Any = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
    return out if out is not None else img


def pad_velocity_px_s(
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    t_prev: NDArray[np.float64] | None,
    t_now: NDArray[np.float64],
    dt: float,
) -> tuple[float, float]:
    """The image velocity of the pad's centre from its camera-frame positions at two exposures
    ``dt`` apart (0, 0 without a previous one, the pad behind the camera or dt <= 0)."""
    if t_prev is None or dt <= 0 or t_prev[2] <= 0.05 or t_now[2] <= 0.05:
        return 0.0, 0.0
    u0, v0 = fx * t_prev[0] / t_prev[2] + cx, fy * t_prev[1] / t_prev[2] + cy
    u1, v1 = fx * t_now[0] / t_now[2] + cx, fy * t_now[1] / t_now[2] + cy
    return float((u1 - u0) / dt), float((v1 - v0) / dt)


#: the conditions one at a time: the [sim.camera] keys each one sets
CONDITION_KEYS: dict[str, tuple[str, ...]] = {
    "motion_blur": ("exposure_s",),
    "rolling_shutter": ("rolling_shutter_s",),
    "exposure_steps": ("exposure_steps_s", "exposure_step_gain", "exposure_recover_s"),
    "shadow": ("shadow",),
    "glare": ("glare",),
    "low_light": ("low_light_noise",),
    "jpeg": ("jpeg_quality",),
    "late_dropped": ("drop_fraction", "late_s"),
}
REAL_CAMERA_PARAMS = "camera_real.toml"  # the levels of a Pi camera v2 class board camera


def condition_tables() -> dict[str, dict[str, Any]]:
    """Each condition's [sim.camera] table at the level params/camera_real.toml gives it, and
    ``all`` (the whole table): the campaign's camera_* variants and ``bench vision --conditions``."""
    import tomllib

    from companion.config import shipped_params_path

    real = tomllib.loads(shipped_params_path(REAL_CAMERA_PARAMS).read_text())["sim"]["camera"]
    out = {name: {k: real[k] for k in keys if k in real} for name, keys in CONDITION_KEYS.items()}
    out["all"] = dict(real)
    return out
