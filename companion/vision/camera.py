"""Camera model: pinhole intrinsics with OpenCV or Dart barrel distortion, TOML I/O, calibration.

Two distortion models share one :class:`CameraModel`:

* ``"opencv"`` — Brown-Conrady ``(k1, k2, p1, p2, k3)`` exactly as OpenCV defines it: an ideal
  normalised point ``x_u`` is *distorted* into ``x_d = x_u (1 + k1 r^2 + k2 r^4 + k3 r^6) +
  tangential(p1, p2)`` with ``r^2 = |x_u|^2``; pixels are ``u = fx x_d + cx``.
* ``"dart"`` — the single-coefficient barrel model of the Dart paper (dart eqs 2-4), which maps
  the other way, from the *distorted* pixel to the ideal ray::

      x_m / z_m = (u - u0) (1 + k_ud r^2) / rho_x        (dart eq 2)
      y_m / z_m = (v - v0) (1 + k_ud r^2) / rho_y        (dart eq 3)
      r^2 = (u - u0)^2 / rho_x^2 + (v - v0)^2 / rho_y^2  (dart eq 4)

  with ``rho_x = fx``, ``rho_y = fy``, ``(u0, v0) = (cx, cy)``. Unprojection is therefore closed
  form; projection inverts the radial cubic ``s (1 + k_ud s^2) = r_u`` by Newton's method.

Pixel coordinates follow OpenCV: the centre of the top-left pixel is (0, 0).
"""

from __future__ import annotations

import logging
import math
import tomllib
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
DistortionKind = Literal["opencv", "dart"]
DISTORTION_KINDS: tuple[str, ...] = ("opencv", "dart")

_NEWTON_ITERS = 12


class CameraConfigError(ValueError):
    """A camera calibration file (or value) is invalid; the message names file, key, value, rule."""


def _finite(name: str, value: float) -> float:
    v = float(value)
    if not math.isfinite(v):
        raise ValueError(f"camera {name} = {value!r}: must be finite")
    return v


@dataclass(frozen=True)
class CameraModel:
    """Intrinsics of a pinhole camera with lens distortion.

    ``dist`` is OpenCV's ``(k1, k2, p1, p2, k3)`` and is used when ``kind == "opencv"``;
    ``k_ud`` is the Dart coefficient (dart eqs 2-4) used when ``kind == "dart"``. The unused
    coefficients must be zero so that a model has one meaning.
    """

    width_px: int
    height_px: int
    fx: float
    fy: float
    cx: float
    cy: float
    dist: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)
    kind: DistortionKind = "opencv"
    k_ud: float = 0.0

    def __post_init__(self) -> None:
        if int(self.width_px) != self.width_px or self.width_px <= 0:
            raise ValueError(f"camera width_px = {self.width_px!r}: must be a positive integer")
        if int(self.height_px) != self.height_px or self.height_px <= 0:
            raise ValueError(f"camera height_px = {self.height_px!r}: must be a positive integer")
        for name in ("fx", "fy"):
            v = _finite(name, getattr(self, name))
            if v <= 0.0:
                raise ValueError(f"camera {name} = {v!r}: must be > 0")
        for name in ("cx", "cy", "k_ud"):
            _finite(name, getattr(self, name))
        if len(self.dist) != 5:
            raise ValueError(f"camera dist = {self.dist!r}: must be 5 numbers (k1, k2, p1, p2, k3)")
        for i, d in enumerate(self.dist):
            _finite(f"dist[{i}]", d)
        object.__setattr__(self, "dist", tuple(float(d) for d in self.dist))
        if self.kind not in DISTORTION_KINDS:
            raise ValueError(f"camera kind = {self.kind!r}: must be one of {DISTORTION_KINDS}")
        if self.kind == "opencv" and self.k_ud != 0.0:
            raise ValueError(f"camera k_ud = {self.k_ud!r}: must be 0 for kind 'opencv'")
        if self.kind == "dart" and any(d != 0.0 for d in self.dist):
            raise ValueError(f"camera dist = {self.dist!r}: must be all 0 for kind 'dart'")

    # ------------------------------------------------------------------ matrices
    @property
    def K(self) -> FloatArray:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist_coeffs(self) -> FloatArray:
        """OpenCV distortion vector (zeros for the Dart model: undistort points first)."""
        return np.asarray(self.dist, dtype=float)

    @property
    def size(self) -> tuple[int, int]:
        """(width, height), OpenCV's ``Size`` order."""
        return (int(self.width_px), int(self.height_px))

    @property
    def is_distorted(self) -> bool:
        return any(d != 0.0 for d in self.dist) or self.k_ud != 0.0

    def scaled(self, factor: float) -> CameraModel:
        """The same lens at another resolution (focal lengths and principal point scale)."""
        f = float(factor)
        return replace(
            self,
            width_px=round(self.width_px * f),
            height_px=round(self.height_px * f),
            fx=self.fx * f,
            fy=self.fy * f,
            cx=(self.cx + 0.5) * f - 0.5,
            cy=(self.cy + 0.5) * f - 0.5,
        )

    # ------------------------------------------------------------------ distortion in normalised coordinates
    def distort_normalized(self, xy_u: ArrayLike) -> FloatArray:
        """Ideal normalised coordinates (x/z, y/z) -> distorted normalised coordinates.

        For the Dart model, points beyond the radius where the model stops being invertible
        come back as NaN.
        """
        xy = np.asarray(xy_u, dtype=float).reshape(-1, 2)
        x, y = xy[:, 0], xy[:, 1]
        r2 = x * x + y * y
        if self.kind == "opencv":
            k1, k2, p1, p2, k3 = self.dist
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            return np.stack([xd, yd], axis=1)
        # dart eqs 2-3 say x_u = x_d (1 + k r_d^2); invert the radial cubic s + k s^3 = r_u.
        k = self.k_ud
        r_u = np.sqrt(r2)
        if k == 0.0:
            return xy.copy()
        s = r_u.copy()
        for _ in range(_NEWTON_ITERS):
            f = s + k * s**3 - r_u
            s = s - f / (1.0 + 3.0 * k * s * s)
        bad = np.abs(s + k * s**3 - r_u) > 1e-9 * np.maximum(1.0, r_u)
        if k < 0.0:  # the map is monotonic only while 1 + 3 k s^2 > 0
            bad |= (1.0 + 3.0 * k * s * s) <= 0.0
        scale = np.where(r_u > 0.0, s / np.where(r_u > 0.0, r_u, 1.0), 1.0)
        out = xy * scale[:, None]
        out[bad] = np.nan
        return out

    def undistort_normalized(self, xy_d: ArrayLike) -> FloatArray:
        """Distorted normalised coordinates -> ideal normalised coordinates (x/z, y/z)."""
        xy = np.asarray(xy_d, dtype=float).reshape(-1, 2)
        if self.kind == "dart":
            r2 = xy[:, 0] ** 2 + xy[:, 1] ** 2  # dart eq 4 (in normalised units)
            return xy * (1.0 + self.k_ud * r2)[:, None]  # dart eqs 2-3
        if not self.is_distorted:
            return xy.copy()
        pts = (xy * [self.fx, self.fy] + [self.cx, self.cy]).reshape(-1, 1, 2)
        crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-10)
        und = cv2.undistortPoints(pts, self.K, self.dist_coeffs, criteria=crit)
        return np.asarray(und, dtype=float).reshape(-1, 2)

    # ------------------------------------------------------------------ pixels
    def project(self, points_cam: ArrayLike) -> FloatArray:
        """Points in the camera frame (N, 3) -> distorted pixels (N, 2); NaN behind the camera."""
        p = np.asarray(points_cam, dtype=float).reshape(-1, 3)
        z = p[:, 2]
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = p[:, :2] / z[:, None]
        xy[z <= 0.0] = np.nan
        return self.normalized_to_pixels(self.distort_normalized(xy))

    def unproject(self, pixels: ArrayLike) -> FloatArray:
        """Distorted pixels (N, 2) -> rays (N, 3) in the camera frame with z = 1."""
        xy = self.undistort_normalized(self.pixels_to_normalized(pixels))
        return np.concatenate([xy, np.ones((xy.shape[0], 1))], axis=1)

    def undistort_pixels(self, pixels: ArrayLike) -> FloatArray:
        """Distorted pixels -> ideal (pinhole, same K) pixels."""
        return self.normalized_to_pixels(self.undistort_normalized(self.pixels_to_normalized(pixels)))

    def distort_pixels(self, pixels: ArrayLike) -> FloatArray:
        """Ideal (pinhole) pixels -> distorted pixels."""
        return self.normalized_to_pixels(self.distort_normalized(self.pixels_to_normalized(pixels)))

    def pixels_to_normalized(self, pixels: ArrayLike) -> FloatArray:
        uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
        return np.stack([(uv[:, 0] - self.cx) / self.fx, (uv[:, 1] - self.cy) / self.fy], axis=1)

    def normalized_to_pixels(self, xy: ArrayLike) -> FloatArray:
        n = np.asarray(xy, dtype=float).reshape(-1, 2)
        return np.stack([n[:, 0] * self.fx + self.cx, n[:, 1] * self.fy + self.cy], axis=1)

    def in_image(self, pixels: ArrayLike, margin_px: float = 0.0) -> NDArray[np.bool_]:
        uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
        m = margin_px
        with np.errstate(invalid="ignore"):
            return (
                (uv[:, 0] >= -0.5 + m)
                & (uv[:, 0] <= self.width_px - 0.5 - m)
                & (uv[:, 1] >= -0.5 + m)
                & (uv[:, 1] <= self.height_px - 0.5 - m)
            )


# ---------------------------------------------------------------------------- TOML I/O

_CAMERA_KEYS = {"kind", "width_px", "height_px", "fx", "fy", "cx", "cy", "dist", "k_ud"}
_META_KEYS = {"rms_px", "n_images", "source", "note"}


def _cfg_error(path: Path | str, key: str, value: Any, rule: str) -> CameraConfigError:
    return CameraConfigError(f"{path}: key '{key}' = {value!r}: {rule}")


def _num(path: Path | str, key: str, value: Any, *, positive: bool = False) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise _cfg_error(path, key, value, "must be a number")
    v = float(value)
    if not math.isfinite(v):
        raise _cfg_error(path, key, value, "must be finite")
    if positive and v <= 0.0:
        raise _cfg_error(path, key, value, "must be > 0")
    return v


def camera_from_mapping(data: dict[str, Any], source: Path | str = "<camera>") -> CameraModel:
    """Validate a ``[camera]`` table and build the model; errors name source, key, value, rule."""
    unknown = sorted(set(data) - _CAMERA_KEYS)
    if unknown:
        k = unknown[0]
        raise _cfg_error(source, f"camera.{k}", data[k], f"unknown key (allowed: {sorted(_CAMERA_KEYS)})")
    for k in ("width_px", "height_px", "fx", "fy", "cx", "cy"):
        if k not in data:
            raise _cfg_error(source, f"camera.{k}", None, "missing required key")
    kind = data.get("kind", "opencv")
    if kind not in DISTORTION_KINDS:
        raise _cfg_error(source, "camera.kind", kind, f"must be one of {list(DISTORTION_KINDS)}")
    dims: dict[str, int] = {}
    for k in ("width_px", "height_px"):
        v = data[k]
        if isinstance(v, bool) or not isinstance(v, int) or v <= 0:
            raise _cfg_error(source, f"camera.{k}", v, "must be a positive integer")
        dims[k] = v
    vals = {k: _num(source, f"camera.{k}", data[k], positive=k in ("fx", "fy")) for k in ("fx", "fy", "cx", "cy")}
    dist_raw = data.get("dist", [0.0, 0.0, 0.0, 0.0, 0.0])
    if not isinstance(dist_raw, list) or len(dist_raw) != 5:
        raise _cfg_error(source, "camera.dist", dist_raw, "must be a list of 5 numbers [k1, k2, p1, p2, k3]")
    dist = tuple(_num(source, f"camera.dist[{i}]", d) for i, d in enumerate(dist_raw))
    k_ud = _num(source, "camera.k_ud", data.get("k_ud", 0.0))
    if kind == "opencv" and k_ud != 0.0:
        raise _cfg_error(source, "camera.k_ud", k_ud, "must be 0 (or absent) when kind = 'opencv'")
    if kind == "dart" and any(d != 0.0 for d in dist):
        raise _cfg_error(source, "camera.dist", dist_raw, "must be all 0 (or absent) when kind = 'dart'")
    for k in ("cx", "cy"):
        limit = dims["width_px"] if k == "cx" else dims["height_px"]
        if not 0.0 <= vals[k] <= limit:
            raise _cfg_error(source, f"camera.{k}", data[k], f"must lie inside the image [0, {limit}]")
    return CameraModel(
        width_px=dims["width_px"],
        height_px=dims["height_px"],
        fx=vals["fx"],
        fy=vals["fy"],
        cx=vals["cx"],
        cy=vals["cy"],
        dist=dist,  # type: ignore[arg-type]
        kind=kind,
        k_ud=k_ud,
    )


def load_camera(path: str | Path) -> CameraModel:
    """Read a camera calibration TOML file (``[camera]`` table, optional ``[calibration]``)."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            doc = tomllib.load(fh)
    except OSError as exc:
        raise CameraConfigError(f"{p}: cannot read camera file: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise CameraConfigError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise CameraConfigError(f"{p}: not UTF-8 text, as TOML must be: {exc}") from None
    unknown = sorted(set(doc) - {"camera", "calibration"})
    if unknown:
        raise _cfg_error(p, unknown[0], doc[unknown[0]], "unknown table/key (allowed: camera, calibration)")
    if "camera" not in doc or not isinstance(doc["camera"], dict):
        raise _cfg_error(p, "camera", doc.get("camera"), "a [camera] table is required")
    meta = doc.get("calibration", {})
    if not isinstance(meta, dict):
        raise _cfg_error(p, "calibration", meta, "must be a table")
    bad_meta = sorted(set(meta) - _META_KEYS)
    if bad_meta:
        k = bad_meta[0]
        raise _cfg_error(p, f"calibration.{k}", meta[k], f"unknown key (allowed: {sorted(_META_KEYS)})")
    return camera_from_mapping(doc["camera"], p)


def _toml_float(v: float) -> str:
    r = repr(float(v))
    return r if ("." in r or "e" in r or "inf" in r or "nan" in r) else r + ".0"


def _toml_str(s: str) -> str:
    return '"' + s.replace("\\", "\\\\").replace('"', '\\"').replace("\n", "\\n") + '"'


def camera_to_toml(
    camera: CameraModel,
    *,
    rms_px: float | None = None,
    n_images: int | None = None,
    note: str | None = None,
) -> str:
    """The TOML text :func:`load_camera` reads back (written by hand: tomllib only reads)."""
    lines = [
        "# Camera intrinsics (companion.vision.camera). Pixels: OpenCV convention, the centre of",
        '# the top-left pixel is (0, 0). kind = "opencv": dist = [k1, k2, p1, p2, k3];',
        '# kind = "dart": single barrel coefficient k_ud (dart eqs 2-4).',
        "[camera]",
        f"kind = {_toml_str(camera.kind)}",
        f"width_px = {int(camera.width_px)}",
        f"height_px = {int(camera.height_px)}",
        f"fx = {_toml_float(camera.fx)}",
        f"fy = {_toml_float(camera.fy)}",
        f"cx = {_toml_float(camera.cx)}",
        f"cy = {_toml_float(camera.cy)}",
        "dist = [" + ", ".join(_toml_float(d) for d in camera.dist) + "]",
        f"k_ud = {_toml_float(camera.k_ud)}",
    ]
    meta = []
    if rms_px is not None:
        meta.append(f"rms_px = {_toml_float(rms_px)}")
    if n_images is not None:
        meta.append(f"n_images = {int(n_images)}")
    if note is not None:
        meta.append(f"note = {_toml_str(note)}")
    if meta:
        lines += ["", "[calibration]", *meta]
    return "\n".join(lines) + "\n"


def save_camera(
    camera: CameraModel,
    path: str | Path,
    *,
    rms_px: float | None = None,
    n_images: int | None = None,
    note: str | None = None,
) -> Path:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(camera_to_toml(camera, rms_px=rms_px, n_images=n_images, note=note))
    return p


# ---------------------------------------------------------------------------- calibration

_DICT_NAMES = {n for n in dir(cv2.aruco) if n.startswith("DICT_")}


@dataclass(frozen=True)
class CalibrationPattern:
    """A planar calibration target.

    ``chessboard``: ``cols x rows`` *inner* corners, squares of ``square_m``.
    ``charuco``: ``cols x rows`` *squares*, squares of ``square_m``, markers of ``marker_m`` from
    ``dictionary``.
    """

    kind: Literal["chessboard", "charuco"]
    cols: int
    rows: int
    square_m: float
    marker_m: float = 0.0
    dictionary: str = "DICT_5X5_100"

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise ValueError(f"pattern kind {self.kind!r}: must be 'chessboard' or 'charuco'")
        if self.cols < 2 or self.rows < 2:
            raise ValueError(f"pattern {self.cols}x{self.rows}: needs at least 2x2")
        if not (math.isfinite(self.square_m) and self.square_m > 0):
            raise ValueError(f"pattern square_m = {self.square_m!r}: must be > 0")
        if self.kind == "charuco":
            if not (0.0 < self.marker_m < self.square_m):
                raise ValueError(f"pattern marker_m = {self.marker_m!r}: must be in (0, square_m={self.square_m})")
            if self.dictionary not in _DICT_NAMES:
                raise ValueError(f"pattern dictionary {self.dictionary!r}: unknown ArUco dictionary")

    @staticmethod
    def parse(text: str) -> CalibrationPattern:
        """``chessboard:9x6:0.025`` or ``charuco:7x5:0.04:0.03[:DICT_5X5_100]``."""
        parts = text.strip().split(":")
        try:
            kind = parts[0].lower()
            cols_s, rows_s = parts[1].lower().split("x")
            cols, rows, square = int(cols_s), int(rows_s), float(parts[2])
            if kind == "chessboard" and len(parts) == 3:
                return CalibrationPattern("chessboard", cols, rows, square)
            if kind == "charuco" and len(parts) in (4, 5):
                dictionary = parts[4].upper() if len(parts) == 5 else "DICT_5X5_100"
                return CalibrationPattern("charuco", cols, rows, square, float(parts[3]), dictionary)
        except (IndexError, ValueError) as exc:
            raise ValueError(
                f"pattern {text!r}: expected 'chessboard:COLSxROWS:SQUARE_M' or "
                f"'charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]' ({exc})"
            ) from exc
        raise ValueError(
            f"pattern {text!r}: expected 'chessboard:COLSxROWS:SQUARE_M' or "
            "'charuco:COLSxROWS:SQUARE_M:MARKER_M[:DICT]'"
        )

    def charuco_board(self) -> Any:
        d = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, self.dictionary))
        return cv2.aruco.CharucoBoard((self.cols, self.rows), self.square_m, self.marker_m, d)

    def object_points(self) -> FloatArray:
        """Chessboard inner corners in the target plane (z = 0), row-major like OpenCV."""
        gx, gy = np.meshgrid(np.arange(self.cols), np.arange(self.rows))
        pts = np.stack([gx.ravel(), gy.ravel(), np.zeros(gx.size)], axis=1).astype(np.float64)
        return np.asarray(pts * self.square_m, dtype=np.float64)


@dataclass
class _Views:
    obj: list[NDArray[np.float32]] = field(default_factory=list)
    img: list[NDArray[np.float32]] = field(default_factory=list)


def _to_gray(image: Any) -> NDArray[np.uint8]:
    if not isinstance(image, np.ndarray) or image.size == 0:
        raise ValueError(f"calibration image must be a non-empty numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise ValueError(f"calibration image dtype {image.dtype}: must be uint8")
    if image.ndim == 3 and image.shape[2] == 3:
        return np.asarray(cv2.cvtColor(image, cv2.COLOR_BGR2GRAY), dtype=np.uint8)
    if image.ndim == 2:
        return image
    raise ValueError(f"calibration image shape {image.shape}: must be HxW or HxWx3")


def _find_views(
    images: Iterable[Any], pattern: CalibrationPattern, on_skip: Callable[[int, str], None] | None = None
) -> tuple[_Views, tuple[int, int]]:
    views = _Views()
    size: tuple[int, int] | None = None
    charuco = None
    if pattern.kind == "charuco":
        charuco = cv2.aruco.CharucoDetector(pattern.charuco_board())
    obj_cb = pattern.object_points().astype(np.float32)
    for i, image in enumerate(images):
        gray = _to_gray(image)
        hw = (gray.shape[1], gray.shape[0])
        if size is None:
            size = hw
        elif hw != size:
            raise ValueError(f"calibration image {i} is {hw[0]}x{hw[1]}, expected {size[0]}x{size[1]}")
        if charuco is None:
            flags = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
            ok, corners = cv2.findChessboardCorners(gray, (pattern.cols, pattern.rows), flags=flags)
            if not ok:
                log.info("calibration image %d: chessboard not found", i)
                if on_skip is not None:
                    on_skip(i, f"no {pattern.cols}x{pattern.rows} chessboard found")
                continue
            crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 50, 1e-3)
            corners = cv2.cornerSubPix(gray, corners, (5, 5), (-1, -1), crit)
            views.obj.append(obj_cb)
            views.img.append(corners.reshape(-1, 2).astype(np.float32))
        else:
            ch_corners, ch_ids, _, _ = charuco.detectBoard(gray)
            if ch_ids is None or len(ch_ids) < 6:
                log.info("calibration image %d: too few ChArUco corners", i)
                if on_skip is not None:
                    on_skip(i, f"{0 if ch_ids is None else len(ch_ids)} ChArUco corners found, at least 6 needed")
                continue
            obj, img = pattern.charuco_board().matchImagePoints(ch_corners, ch_ids)
            views.obj.append(np.asarray(obj, np.float32).reshape(-1, 3))
            views.img.append(np.asarray(img, np.float32).reshape(-1, 2))
    if size is None:
        raise ValueError("calibration: no images given")
    return views, size


def _fit_dart_k(k1: float, k2: float, k3: float, r_max: float) -> float:
    """Least-squares Dart k_ud (dart eqs 2-4) matching OpenCV radial (k1, k2, k3) up to r_max."""
    r_u = np.linspace(1e-3, r_max, 200)
    r_d = r_u * (1.0 + k1 * r_u**2 + k2 * r_u**4 + k3 * r_u**6)
    # r_u = r_d (1 + k r_d^2)  =>  (r_u - r_d) = k r_d^3
    a = r_d**3
    return float(np.dot(a, r_u - r_d) / np.dot(a, a))


def calibrate(
    images: Sequence[Any],
    pattern: CalibrationPattern | str,
    *,
    kind: DistortionKind = "opencv",
    min_views: int = 5,
    on_skip: Callable[[int, str], None] | None = None,
) -> tuple[CameraModel, float]:
    """Calibrate from >= ``min_views`` views of a chessboard or ChArUco target; ``on_skip(index,
    why)`` hears of each image the target was not found in.

    Returns ``(camera, rms_px)``: the model and the RMS reprojection error in pixels reported by
    ``cv2.calibrateCamera``. ``kind="dart"`` fits radial k1 only and converts it to the Dart
    single coefficient (dart eqs 2-4) by least squares over the image radius.
    """
    pat = CalibrationPattern.parse(pattern) if isinstance(pattern, str) else pattern
    if kind not in DISTORTION_KINDS:
        raise ValueError(f"calibrate kind {kind!r}: must be one of {DISTORTION_KINDS}")
    views, size = _find_views(images, pat, on_skip)
    if len(views.obj) < min_views:
        raise ValueError(f"calibration: the pattern was found in {len(views.obj)} image(s), need >= {min_views}")
    flags = 0
    if kind == "dart":
        flags = cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST
    rms, K, dist, _, _ = cv2.calibrateCamera(views.obj, views.img, size, None, None, flags=flags)
    d = np.asarray(dist, dtype=float).ravel()
    d5 = np.zeros(5)
    d5[: min(5, d.size)] = d[:5]
    w, h = size
    common: dict[str, Any] = dict(
        width_px=w, height_px=h, fx=float(K[0, 0]), fy=float(K[1, 1]), cx=float(K[0, 2]), cy=float(K[1, 2])
    )
    if kind == "dart":
        r_max = math.hypot(max(K[0, 2], w - K[0, 2]) / K[0, 0], max(K[1, 2], h - K[1, 2]) / K[1, 1])
        cam = CameraModel(**common, kind="dart", k_ud=_fit_dart_k(d5[0], d5[1], d5[4], r_max))
    else:
        cam = CameraModel(**common, dist=(d5[0], d5[1], d5[2], d5[3], d5[4]))
    log.info("calibrated from %d views: rms %.3f px, fx %.1f fy %.1f", len(views.obj), rms, cam.fx, cam.fy)
    return cam, float(rms)


def shipped_camera_path(name: str = "camera_rpi_v2.toml") -> Path:
    """A camera file shipped in ``params/`` (installed as ``companion_params``)."""
    return Path(str(resources.files("companion_params").joinpath(name)))


def load_default_camera() -> CameraModel:
    """The shipped *nominal* Raspberry Pi camera v2 model at 640x480 (params/camera_rpi_v2.toml)."""
    return load_camera(shipped_camera_path())
