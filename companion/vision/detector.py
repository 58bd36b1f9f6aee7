"""Pad detection and pose: ArUco detection, IPPE pose with ambiguity resolution, ROI tracking.

Pipeline per frame (``PadDetector.detect``):

1. Validate the image (uint8, HxW or HxWx3, the camera's size); a bad frame raises
   :class:`ImageError` (a ValueError) and is counted.
2. Detect markers with ``cv2.aruco.ArucoDetector`` — both dictionaries of the nested pad
   (delivery 4.2.1) in one multi-dictionary pass, sub-pixel corner refinement. After a
   detection the next frame searches only a padded crop around the last corners (region of
   interest), falling back to the full frame when the crop finds nothing, plus a periodic full
   search. Large markers in the crop are searched at reduced resolution (ArUco3 detection with a
   minimum marker length); corners are always refined on the full-resolution pixels. An
   "inner" marker whose centre is not inside the outer marker is a false match and is dropped.
3. Corners are re-measured as intersections of lines fitted to sub-pixel edge points of each
   marker border, undistorted with the camera model (OpenCV or dart eqs 2-4) before the fit
   (:func:`refine_corners_by_edges`; it removes a ~0.1 px inward bias of the corner-window
   refinement, which was 1.5-4 cm of depth at 5-8 m), then the pose is solved:
   * both markers: IPPE over all 8 corners (both planar solutions), each refined by
     Levenberg-Marquardt;
   * one marker: ``cv2.solvePnPGeneric(..., SOLVEPNP_IPPE_SQUARE)``, both solutions with their
     reprojection errors.
4. The planar two-fold ambiguity is resolved by :func:`resolve_ambiguity`: a tilt gate against the
   expected "down" direction, the error ratio err_best/err_second < threshold, and a prior (the
   previous accepted estimate when fresh, else the camera-looking-down prior). If the error ratio
   and the prior disagree, or neither decides, the observation is flagged ``ambiguous`` and
   carries both poses. Given the vehicle attitude (``detect(down_cam=...)``) the attitude decides
   instead: the candidate whose pad normal agrees with it (and with a fresh previous pose), none
   when neither agrees.

Output: :class:`MarkerObservation` with ``T_camera_pad`` (pose of the pad in the camera frame),
timestamped with the exposure time the caller passes in (docs/architecture.md: time is an input).
"""

from __future__ import annotations

import logging
import math
import numbers
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.config import DetectorConfig  # the schema of [landing.detector], declared once there
from companion.geometry import Transform
from companion.geometry.rotations import align_to_z
from companion.vision.camera import CameraModel
from companion.vision.pad import PadLayout, aruco_dictionary

log = logging.getLogger(__name__)

FloatArray = NDArray[np.float64]
MARKERS = ("outer", "inner")
EDGE_PROFILE_CELLS = 0.6  # half-length of the edge profiles, in marker cells


class ImageError(ValueError):
    """The frame handed to the detector is not a usable image."""


# ---------------------------------------------------------------------------- data types


@dataclass(frozen=True, eq=False)
class MarkerObservation:
    """The pad seen in one frame.

    ``T_camera_pad`` maps pad-frame points into the camera frame (pose of the pad in the camera).
    ``time_s`` is the exposure time given by the caller. ``markers`` names the markers used
    ("outer", "inner"). When ``ambiguous`` is True the orientation could not be told from its
    planar mirror and ``alternative`` holds the other candidate; a consumer should not fuse the
    attitude (and should treat the position with care) from an ambiguous observation.
    """

    time_s: float
    T_camera_pad: Transform
    markers: tuple[str, ...]
    reprojection_error_px: float
    ambiguous: bool
    alternative: Transform | None
    alternative_error_px: float | None
    err_ratio: float
    resolved_by: str
    corners_px: dict[str, FloatArray] = field(default_factory=dict)

    @property
    def rvec(self) -> FloatArray:
        r, _ = cv2.Rodrigues(np.asarray(self.T_camera_pad.R, dtype=float))
        return np.asarray(r, dtype=float).ravel()

    @property
    def tvec(self) -> FloatArray:
        return np.asarray(self.T_camera_pad.t, dtype=float).copy()

    @property
    def alternative_angle_rad(self) -> float:
        """Rotation between the chosen pose and the alternative (0 without one). A small angle
        means an ambiguous observation is harmless; a large one means a real mirror pair."""
        if self.alternative is None:
            return 0.0
        return rotation_angle(self.T_camera_pad.R, self.alternative.R)

    @property
    def distance_m(self) -> float:
        return float(np.linalg.norm(self.T_camera_pad.t))


@dataclass(frozen=True)
class DetectorStats:
    """Counters of a :class:`PadDetector` (a snapshot)."""

    frames: int = 0
    bad_frames: int = 0
    full_searches: int = 0
    roi_searches: int = 0
    roi_fallbacks: int = 0
    detections: int = 0
    ambiguous: int = 0
    rejected_poses: int = 0


@dataclass(frozen=True)
class PoseCandidate:
    R: FloatArray
    t: FloatArray
    error_px: float


# ---------------------------------------------------------------------------- helpers


def rotation_angle(Ra: FloatArray, Rb: FloatArray) -> float:
    """Angle (rad) of the rotation taking Ra to Rb."""
    c = (float(np.trace(np.asarray(Ra).T @ np.asarray(Rb))) - 1.0) / 2.0
    return math.acos(max(-1.0, min(1.0, c)))


def _angle(a: FloatArray, b: FloatArray) -> float:
    c = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.acos(max(-1.0, min(1.0, c)))


def _rms(obj: FloatArray, img: FloatArray, R: FloatArray, t: FloatArray, K: FloatArray) -> float:
    pc = obj @ R.T + t
    uv = pc[:, :2] / pc[:, 2:3]
    uv = uv * [K[0, 0], K[1, 1]] + [K[0, 2], K[1, 2]]
    return float(np.sqrt(np.mean(np.sum((uv - img) ** 2, axis=1))))


def solve_candidates(obj: FloatArray, img_ideal: FloatArray, K: FloatArray) -> list[PoseCandidate]:
    """Both planar pose solutions (sorted by reprojection RMS) for undistorted image points.

    Four points of a square centred at the origin (ArUco order) use IPPE_SQUARE; more points use
    IPPE followed by Levenberg-Marquardt refinement of each solution.
    """
    obj = np.ascontiguousarray(obj, dtype=np.float64).reshape(-1, 3)
    img = np.ascontiguousarray(img_ideal, dtype=np.float64).reshape(-1, 2)
    zero = np.zeros(5)
    flags = cv2.SOLVEPNP_IPPE_SQUARE if obj.shape[0] == 4 else cv2.SOLVEPNP_IPPE
    n, rvecs, tvecs, _ = cv2.solvePnPGeneric(obj, img, K, zero, flags=flags)
    out: list[PoseCandidate] = []
    for i in range(int(n)):
        rv: Any = np.asarray(rvecs[i], dtype=np.float64).reshape(3, 1)
        tv: Any = np.asarray(tvecs[i], dtype=np.float64).reshape(3, 1)
        if obj.shape[0] > 4:
            rv, tv = cv2.solvePnPRefineLM(obj, img, K, zero, rv, tv)
        R = np.asarray(cv2.Rodrigues(rv)[0], dtype=np.float64)
        t = np.asarray(tv, dtype=float).ravel()
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))) or t[2] <= 0:
            continue
        out.append(PoseCandidate(np.asarray(R, float), t, _rms(obj, img, R, t, K)))
    out.sort(key=lambda c: c.error_px)
    return out


@dataclass(frozen=True)
class Resolution:
    chosen: int
    ambiguous: bool
    resolved_by: str
    err_ratio: float


def resolve_ambiguity(
    cands: Sequence[PoseCandidate],
    cfg: DetectorConfig,
    *,
    up_cam: FloatArray,
    prior_R: FloatArray | None = None,
    attitude: bool = False,
) -> Resolution:
    """Choose between the (<= 2) planar pose candidates, sorted by error.

    ``up_cam`` is the expected pad normal (world up) in the camera frame; ``prior_R`` the rotation
    of the previous accepted ``T_camera_pad`` if it is fresh.

    ``attitude=True`` says ``up_cam`` comes from a measured attitude (autopilot or Madgwick, the
    camera mount applied), not from the looking-down assumption; it then replaces the
    looking-down prior (:func:`_resolve_by_attitude`). A candidate *agrees* with the attitude
    when its pad normal is within ``cfg.attitude_agree_rad`` of ``up_cam``, i.e. the camera roll
    and pitch it implies (the marker where it is known to be) match the attitude's; the rotation
    about the normal is not compared, the mirror pair differs in tilt. The attitude prefers the
    only agreeing candidate, or of two the one closer by ``cfg.attitude_margin_rad``; the fresh
    previous pose prefers the candidate closer to it by ``cfg.prior_margin_rad``. Neither
    candidate agreeing: ambiguous (never fused), whatever the error ratio says, also when the
    two candidates are the same pose or there is only one (a bad fit the attitude exposes). A decisive error
    ratio is kept unless the attitude or the previous pose prefers the other (then ambiguous);
    otherwise the attitude's preference, else the previous pose's, decides, and a disagreement
    between the two, or no preference at all, leaves the observation ambiguous.
    """
    if not cands:
        raise ValueError("resolve_ambiguity: no candidates")
    e0 = cands[0].error_px
    e1 = cands[1].error_px if len(cands) > 1 else float("inf")
    ratio = e0 / e1 if len(cands) > 1 and e1 > 0 else (0.0 if len(cands) == 1 else 1.0)
    if attitude and all(_angle(c.R[:, 2], up_cam) > cfg.attitude_agree_rad for c in cands[:2]):
        # no solution matches the attitude (both alike but wrong: a bad fit of the corners)
        return Resolution(0, True, "attitude_disagrees", ratio)
    if len(cands) == 1:
        return Resolution(0, False, "single", 0.0)
    # tilt gate: the pad normal (pad z) must point roughly towards the expected up direction
    tilts = [_angle(c.R[:, 2], up_cam) for c in cands[:2]]
    ok = [tl <= cfg.max_tilt_rad for tl in tilts]
    if ok[0] != ok[1]:
        return Resolution(0 if ok[0] else 1, False, "tilt_gate", ratio)
    if not ok[0]:
        return Resolution(0, True, "tilt_gate_failed", ratio)
    if rotation_angle(cands[0].R, cands[1].R) < cfg.agree_angle_rad:
        return Resolution(0, False, "agree", ratio)
    if attitude:
        return _resolve_by_attitude(cands, cfg, tilts, prior_R, ratio)
    # prior preference: the previous estimate when fresh, else the camera-looking-down prior
    pref: int | None = None
    pref_name = ""
    if prior_R is not None:
        d = [rotation_angle(c.R, prior_R) for c in cands[:2]]
        if abs(d[0] - d[1]) > cfg.prior_margin_rad:
            pref, pref_name = int(np.argmin(d)), "previous"
    if pref is None and abs(tilts[0] - tilts[1]) > cfg.prior_margin_rad:
        pref, pref_name = int(np.argmin(tilts)), "gravity"
    if ratio < cfg.err_ratio_threshold:
        if pref is None or pref == 0:
            return Resolution(0, False, "error_ratio", ratio)
        return Resolution(0, True, f"conflict_{pref_name}", ratio)
    if pref is not None:
        return Resolution(pref, False, pref_name, ratio)
    return Resolution(0, True, "unresolved", ratio)


def down_in_camera(R_world_body: FloatArray, R_body_camera: FloatArray) -> FloatArray:
    """World "down" (NED z) in the camera frame, for ``PadDetector.detect(down_cam=...)``, from
    the vehicle attitude ``R_world_body`` (body FRD to NED) and the camera mount."""
    R_wc = np.asarray(R_world_body, dtype=float) @ np.asarray(R_body_camera, dtype=float)
    if R_wc.shape != (3, 3) or not np.all(np.isfinite(R_wc)):
        raise ValueError(f"down_in_camera: expected finite 3x3 rotations, got shape {R_wc.shape}")
    return np.asarray(R_wc.T @ np.array([0.0, 0.0, 1.0]), dtype=float)


def marker_normal_in_camera(R_world_camera: FloatArray, normal_world: FloatArray) -> FloatArray:
    """A marker's normal (out of its printed face, world frame) in the camera frame, for
    ``PadDetector.detect(normal_cam=...)``, from the camera attitude ``R_world_camera``."""
    R = np.asarray(R_world_camera, dtype=float)
    n = np.asarray(normal_world, dtype=float).reshape(-1)
    if R.shape != (3, 3) or n.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(n))):
        raise ValueError(
            f"marker_normal_in_camera: expected a finite 3x3 rotation and 3-vector, got {R.shape}, {n.shape}"
        )
    return np.asarray(R.T @ (n / np.linalg.norm(n)), dtype=float)


def _resolve_by_attitude(
    cands: Sequence[PoseCandidate],
    cfg: DetectorConfig,
    tilts: Sequence[float],
    prior_R: FloatArray | None,
    ratio: float,
) -> Resolution:
    """The attitude rule of :func:`resolve_ambiguity` (two candidates that differ).

    ``tilts``: each candidate's pad normal against the attitude's expected normal (rad).
    """
    agree = [tl <= cfg.attitude_agree_rad for tl in tilts[:2]]
    if not (agree[0] or agree[1]):
        return Resolution(0, True, "attitude_disagrees", ratio)
    att: int | None = None  # the attitude's preference
    if agree[0] != agree[1]:
        att = 0 if agree[0] else 1
    elif abs(tilts[0] - tilts[1]) > cfg.attitude_margin_rad:
        att = int(np.argmin(tilts[:2]))
    prev: int | None = None  # the fresh previous pose's preference
    if prior_R is not None:
        d = [rotation_angle(c.R, prior_R) for c in cands[:2]]
        if abs(d[0] - d[1]) > cfg.prior_margin_rad:
            prev = int(np.argmin(d))
    if ratio < cfg.err_ratio_threshold:  # the reprojection error prefers candidate 0
        if att in (None, 0) and prev in (None, 0):
            return Resolution(0, False, "error_ratio", ratio)
        return Resolution(0, True, "conflict_attitude" if att == 1 else "conflict_previous", ratio)
    if att is not None:
        if prev is not None and prev != att:
            return Resolution(att, True, "conflict_attitude_previous", ratio)
        return Resolution(att, False, "attitude", ratio)
    if prev is not None:  # both agree with the attitude: the previous pose decides
        return Resolution(prev, False, "previous", ratio)
    return Resolution(0, True, "attitude_both", ratio)


def check_image(image: Any, size: tuple[int, int] | None = None) -> NDArray[np.uint8]:
    """Return a greyscale uint8 view of ``image`` or raise :class:`ImageError`."""
    if image is None:
        raise ImageError("image is None")
    if not isinstance(image, np.ndarray):
        raise ImageError(f"image must be a numpy array, got {type(image).__name__}")
    if image.size == 0:
        raise ImageError(f"image is empty (shape {image.shape})")
    if image.dtype != np.uint8:
        raise ImageError(f"image dtype is {image.dtype}, expected uint8")
    if image.ndim == 3 and image.shape[2] == 1:
        image = image[:, :, 0]
    if image.ndim == 3 and image.shape[2] == 3:
        gray = cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    elif image.ndim == 2:
        gray = image
    else:
        raise ImageError(f"image shape {image.shape}: expected HxW or HxWx3")
    if size is not None and (gray.shape[1], gray.shape[0]) != size:
        raise ImageError(f"image is {gray.shape[1]}x{gray.shape[0]}, the camera model is {size[0]}x{size[1]}")
    return gray


def _params(min_perimeter_rate: float = 0.03) -> Any:
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    p.minMarkerPerimeterRate = min_perimeter_rate
    # The pad's white margin is only 0.1 m around the 0.8 m outer marker: with the default
    # minMarkerDistanceRate (0.125) the pad outline (a quad candidate on darker ground) is grouped
    # with the outer marker and the group can lose the marker. 0.025 keeps them apart but still
    # merges the two contours of one marker border (on rendered frames).
    p.minMarkerDistanceRate = 0.025
    return p


def _marker_side_px(c: FloatArray) -> float:
    return float(np.mean(np.linalg.norm(c - np.roll(c, 1, axis=0), axis=1)))


# Small-array reductions of the edge refinement (a few hundred numbers each, ~20 calls a marker):
# the operations numpy's wrappers end in, without their argument handling (the same floats).
_add_reduce: Any = np.add.reduce


def _mean(x: NDArray[Any], axis: int) -> FloatArray:
    """``x.mean(axis)`` of a float64 array: the sum (``np.add.reduce``) divided by the count."""
    m: FloatArray = _add_reduce(x, axis=axis) / x.shape[axis]
    return m


def _row_norms(x: FloatArray, keepdims: bool = False) -> FloatArray:
    """``np.linalg.norm(x, axis=1)`` of a real array: the root of the rows' sums of squares."""
    r: FloatArray = np.sqrt(_add_reduce(x * x, axis=1, keepdims=keepdims))
    return r


_EDGE_FRACTIONS: dict[int, FloatArray] = {}


def _edge_fractions(samples_per_side: int) -> FloatArray:
    """Where along a side its edge profiles are sampled (computed once per count; never written)."""
    f = _EDGE_FRACTIONS.get(samples_per_side)
    if f is None:
        f = _EDGE_FRACTIONS[samples_per_side] = np.linspace(0.12, 0.88, samples_per_side)
        f.flags.writeable = False
    return f


def _cov_rows(x: FloatArray) -> FloatArray:
    """``np.cov(x)`` for a (2, n) float64 ``x``, n >= 2, by the same operations without the
    argument handling (bit for bit the same matrix)."""
    X = np.array(x, ndmin=2, dtype=np.float64)
    X -= _mean(X, 1)[:, None]
    c = np.dot(X, X.T.conj())
    c *= np.true_divide(1, X.shape[1] - 1)
    return c


def refine_corners_by_edges(
    gray: NDArray[np.uint8],
    corners: FloatArray,
    camera: CameraModel,
    cells: int,
    samples_per_side: int = 16,
) -> FloatArray | None:
    """Corners of a marker as intersections of its four fitted border lines, in IDEAL pixels.

    For every side, intensity profiles across the border edge are sampled (bilinear) at points
    along it, away from the corners; the sub-pixel position of each profile's 50 % crossing
    between the dark border and the light surround is an edge point. Edge points are undistorted
    with the camera model (OpenCV or dart eqs 2-4) — straight lines only exist in the ideal image
    — a line is fitted to each side by total least squares, and adjacent lines are intersected.
    This removes the ~0.1 px inward bias that corner-window refinement shows on sharp marker
    corners (0.3-0.5 % scale, i.e. 1.5-4 cm of depth at 5-8 m). ``cells`` is the
    marker's width in cells including the border; the profile reaches 0.6 of a cell either side
    (the border is one cell wide and the pad keeps a one-cell quiet zone around each marker).
    Returns None when an edge cannot be measured (the caller falls back to the detected corners).
    """
    c = np.asarray(corners, dtype=np.float64).reshape(4, 2)
    p1s = c[[1, 2, 3, 0]]  # np.roll(c, -1, axis=0)
    side_len = float(_mean(_row_norms(c - p1s), 0))
    half = min(6.0, EDGE_PROFILE_CELLS * side_len / cells)
    if half < 1.0:
        return None
    S = samples_per_side
    edge, good = _border_edge_points(gray, c, p1s, half, S)
    for i in range(4):
        if good[i * S : (i + 1) * S].sum() < 4:
            return None
    # the edge points and the detected corners undistorted in one call (point by point)
    ideal_good_and_ref = camera.undistort_pixels(np.concatenate([edge[good], c]))
    ideal_all = np.full((4 * S, 2), np.nan)
    ideal_all[good] = ideal_good_and_ref[:-4]
    ref = ideal_good_and_ref[-4:]
    lines = _side_lines(ideal_all, good, S)
    if lines is None:
        return None
    out = _corner_intersections(lines)
    if out is None:
        return None
    if _row_norms(out - ref).max() > max(1.5, 0.05 * side_len):
        return None  # refinement disagrees with the detector: do not trust it
    return out


def _border_edge_points(
    gray: NDArray[np.uint8], c: FloatArray, p1s: FloatArray, half: float, samples_per_side: int
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """:func:`refine_corners_by_edges`'s edge points, ``samples_per_side`` per side (4 S, 2), in
    the image's pixels, and which of them were measured: a profile from -half to +half px across
    each side c[i] -> p1s[i], its 50 % crossing between the dark border and the light surround."""
    offs = np.linspace(-half, half, max(9, int(4 * half) | 1))
    frac = _edge_fractions(samples_per_side)
    centroid = _mean(c, 0)
    p0s = c
    d = p1s - p0s
    d /= _row_norms(d, keepdims=True)
    n = np.stack([-d[:, 1], d[:, 0]], axis=1)
    flip = _add_reduce(n * (0.5 * (p0s + p1s) - centroid), axis=1) < 0
    n[flip] *= -1.0  # n points out of the marker: dark (border) -> light (surround)
    # base points (4, S, 2) along each side, profiles (4, S, O) across it
    base = p0s[:, None, :] + frac[None, :, None] * (p1s - p0s)[:, None, :]
    pts = base[:, :, None, :] + offs[None, None, :, None] * n[:, None, None, :]
    S, n_off = samples_per_side, len(offs)
    mx = pts[..., 0].reshape(4 * S, n_off).astype(np.float32)
    my = pts[..., 1].reshape(4 * S, n_off).astype(np.float32)
    prof = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    prof = prof.astype(np.float64)
    k = max(1, n_off // 4)
    dark = _mean(prof[:, :k], 1)
    light = _mean(prof[:, -k:], 1)
    level = 0.5 * (dark + light)
    above = prof > level[:, None]
    change = above[:, 1:] != above[:, :-1]
    good = ((light - dark) > 20.0) & (_add_reduce(change, axis=1) == 1)
    a = np.argmax(change, axis=1)
    rows = np.arange(4 * S)
    v0, v1 = prof[rows, a], prof[rows, a + 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        s_off = offs[a] + (level - v0) / (v1 - v0) * (offs[1] - offs[0])
    edge = base.reshape(4 * S, 2) + s_off[:, None] * np.repeat(n, S, axis=0)
    return edge, good


def _side_lines(ideal_all: FloatArray, good: NDArray[np.bool_], S: int) -> list[tuple[FloatArray, float]] | None:
    """Each side's line (normal, c: normal . x = c) fitted to its measured ideal edge points by
    total least squares; None when a point did not undistort."""
    means, covs = [], np.empty((4, 2, 2))
    for i in range(4):
        ideal = ideal_all[i * S : (i + 1) * S][good[i * S : (i + 1) * S]]
        if not np.isfinite(ideal).all():
            return None
        m = _mean(ideal, 0)
        means.append(m)
        covs[i] = _cov_rows((ideal - m).T)
    # the four sides' eigen-decompositions in one call (LAPACK's per matrix, as four calls)
    normals = np.linalg.eigh(covs)[1][:, :, 0]  # smallest eigenvalue: the line's normal (total least squares)
    return [(normals[i], float(normals[i] @ means[i])) for i in range(4)]  # normal . x = c


def _corner_intersections(lines: list[tuple[FloatArray, float]]) -> FloatArray | None:
    """Corner i where sides i-1 and i meet (4, 2); None when two adjacent sides are parallel."""
    A = np.empty((4, 2, 2))
    b = np.empty((4, 2, 1))
    for i in range(4):
        (n0, c0), (n1, c1) = lines[(i - 1) % 4], lines[i]  # corner i joins sides i-1 and i
        A[i] = (n0, n1)
        b[i, :, 0] = (c0, c1)
    if (np.abs(np.linalg.det(A)) < 1e-9).any():
        return None
    return np.asarray(np.linalg.solve(A, b)[:, :, 0], dtype=np.float64)


# ---------------------------------------------------------------------------- the detector


def level_rotation(ref_cam: Any) -> FloatArray:
    """The smallest rotation taking ``ref_cam`` (a world-fixed direction near the optical axis,
    in the camera frame) onto the camera's z axis: image points rotated by it no longer move
    when the camera tilts (the gyro-derotation of optical flow). Identity without one."""
    if ref_cam is None:
        return np.eye(3)
    return align_to_z(ref_cam)


class RoiTrack:
    """The pad's derotated image motion between the frames that found it (:class:`PadDetector`'s
    ROI follows it): :meth:`update` with each frame that finds the pad, :meth:`prediction` for
    the next frame's ROI. ``camera`` and ``config`` are the detector's."""

    def __init__(self, camera: CameraModel, config: DetectorConfig) -> None:
        self.camera = camera
        self.config = config
        # the last frame that found the pad: its time, derotated centre (_to_level), centre (px)
        # and scale (px per metre); the motion between it and the one before (derotated centre
        # per second, d ln(scale)/dt in 1/s)
        self._track: tuple[float, FloatArray, FloatArray, float] | None = None
        self._motion: tuple[FloatArray, float] | None = None

    def clear(self) -> None:
        """Forget the track (a frame that did not find the pad)."""
        self._track = self._motion = None

    def _to_level(self, pixel: FloatArray, R_level_cam: FloatArray) -> FloatArray | None:
        """A pixel's ray in the derotated camera, on its z = 1 plane (None beyond 90 deg of z)."""
        b = R_level_cam @ self.camera.unproject(pixel)[0]
        return b[:2] / b[2] if b[2] > 1e-6 else None

    def prediction(self, time_s: float | None, R_level_cam: FloatArray) -> tuple[FloatArray, float]:
        """How far (px) the pad's image has moved, and by what factor it has grown, since the last
        frame that found it: its centre derotated by the attitude then, moved at the derotated
        image velocity and scale rate of the last two frames that found it, and rotated back by
        the attitude now (``R_level_cam``: :func:`level_rotation`). With frames far apart (a CPU
        budget, runtime.vision_cpu_budget) a rocking or turning vehicle moves the pad's image by
        more than the ROI's margin, and a missed ROI costs a full-frame search on top. No track,
        or a gap over ``roi_predict_max_gap_s``: no prediction."""
        none = (np.zeros(2), 1.0)
        if time_s is None or self._track is None:
            return none
        t0, level0, centre0, _ = self._track
        dt = time_s - t0
        if not 0.0 < dt <= self.config.roi_predict_max_gap_s:
            return none
        level, growth = level0, 1.0
        if self._motion is not None:
            velocity, log_scale_rate = self._motion
            level = level0 + velocity * dt
            # bounded to [1/2, 2]: a wrong rate must not make the ROI vanish or swallow the frame
            growth = float(np.clip(math.exp(log_scale_rate * dt), 0.5, 2.0))
        centre = self.camera.project(R_level_cam.T @ np.array([level[0], level[1], 1.0]))[0]
        if not np.all(np.isfinite(centre)):
            return none
        return centre - centre0, growth

    def update(
        self, found: dict[str, FloatArray], px_per_m: float, time_s: float | None, R_level_cam: FloatArray
    ) -> None:
        """Keep the pad's derotated image motion from this frame (its markers' corners by name,
        its scale in px per metre, its time in s) and the last one that found it."""
        # the pad's markers are concentric (see detect_markers): the centre does not jump when one
        # of them comes into or out of view
        centre = np.vstack(list(found.values())).mean(axis=0)
        level = self._to_level(centre, R_level_cam)
        prev, self._track, self._motion = self._track, None, None
        if time_s is None or level is None:
            return
        if prev is not None:
            dt = time_s - prev[0]
            if 0.0 < dt <= self.config.roi_predict_max_gap_s:
                self._motion = ((level - prev[1]) / dt, math.log(px_per_m / prev[3]) / dt)
        self._track = (time_s, level, centre, px_per_m)


class PadDetector:
    """Detects the nested pad and estimates ``T_camera_pad``; keeps ROI-tracking state.

    Not thread-safe: one instance per camera stream.
    """

    def __init__(
        self,
        camera: CameraModel,
        layout: PadLayout | None = None,
        config: DetectorConfig | None = None,
        markers: tuple[str, ...] = MARKERS,
    ) -> None:
        """``markers``: which of the pad's markers to use ("outer", "inner"); a marker left out is
        ignored even when seen (a damaged or covered marker, and the campaign's failure variants)."""
        if not markers or any(m not in MARKERS for m in markers):
            raise ValueError(f"markers = {markers!r}: choose from {MARKERS}")
        self.camera = camera
        self.layout = layout if layout is not None else PadLayout()
        self.config = config if config is not None else DetectorConfig()
        lay = self.layout
        self._targets: dict[tuple[int, int], str] = {}
        self._dicts: list[Any] = []
        dict_names: list[str] = []
        for which in MARKERS:
            dname = getattr(lay, f"{which}_dict")
            if dname not in dict_names:
                dict_names.append(dname)
                self._dicts.append(aruco_dictionary(dname))
            if which in markers:
                self._targets[(dict_names.index(dname), getattr(lay, f"{which}_id"))] = which
        w, h = camera.size
        min_rate = 4.0 * self.config.min_marker_px / max(w, h)
        self._full = cv2.aruco.ArucoDetector(self._dicts[0], _params(min_rate))
        self._full.setDictionaries(self._dicts)
        self._roi_det = cv2.aruco.ArucoDetector(self._dicts[0], _params(min_rate))
        self._roi_det.setDictionaries(self._dicts)
        self._obj = {m: lay.marker_corners(m) for m in MARKERS}
        self._cells = {m: aruco_dictionary(getattr(lay, f"{m}_dict")).markerSize + 2 for m in MARKERS}
        self.reset()

    @property
    def marker_cells(self) -> dict[str, int]:
        """Cells along each marker's side, its black border included ("outer", "inner"; a copy)."""
        return dict(self._cells)

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget tracking state and the pose prior (counters are kept)."""
        self._roi_corners: FloatArray | None = None
        self._min_side_px = 0.0
        self.roi_track = RoiTrack(self.camera, self.config)  # the pad's image motion (the ROI follows it)
        self._frames_since_full = 0
        self._prior: tuple[float, FloatArray] | None = None
        if not hasattr(self, "_counts"):
            self._counts = dict.fromkeys(DetectorStats.__dataclass_fields__, 0)

    @property
    def stats(self) -> DetectorStats:
        return DetectorStats(**self._counts)

    def seed_prior(self, time_s: float, T_camera_pad: Transform) -> None:
        """Give the detector an external pose prior (e.g. predicted from the state estimate)."""
        R = np.asarray(T_camera_pad.R, dtype=float)
        if not np.all(np.isfinite(R)) or not np.all(np.isfinite(T_camera_pad.t)):
            raise ValueError("seed_prior: pose contains NaN or inf")
        if not math.isfinite(time_s):
            raise ValueError(f"seed_prior: time_s = {time_s!r} must be finite")
        self._prior = (float(time_s), R.copy())

    # ------------------------------------------------------------------ detection
    def _run(self, det: Any, gray: NDArray[np.uint8], x0: int = 0, y0: int = 0) -> dict[str, FloatArray]:
        corners, ids, _, dict_idx = det.detectMarkersMultiDict(gray)
        found: dict[str, FloatArray] = {}
        if ids is None or len(ids) == 0:
            return found
        ids_a = np.asarray(ids).ravel()
        didx = np.asarray(dict_idx).ravel() if dict_idx is not None else np.zeros_like(ids_a)
        for c, i, d in zip(corners, ids_a, didx, strict=False):
            which = self._targets.get((int(d), int(i)))
            if which is None:
                continue
            pts = np.asarray(c, dtype=np.float64).reshape(4, 2) + np.array([x0, y0], dtype=np.float64)
            # keep the largest if a marker id shows up twice (it should not)
            if which not in found or _marker_side_px(pts) > _marker_side_px(found[which]):
                found[which] = pts
        return found

    def _search_roi(
        self, gray: NDArray[np.uint8], time_s: float | None, R_level_cam: FloatArray
    ) -> dict[str, FloatArray]:
        assert self._roi_corners is not None
        cfg = self.config
        h, w = gray.shape
        lo = self._roi_corners.min(axis=0)
        hi = self._roi_corners.max(axis=0)
        shift, growth = self.roi_track.prediction(time_s, R_level_cam)
        centre, half = (lo + hi) / 2.0 + shift, growth * (hi - lo) / 2.0
        lo, hi = centre - half, centre + half
        size = float(max(hi - lo))
        m = max(cfg.roi_min_margin_px, cfg.roi_margin_frac * size)
        x0, y0 = max(0, int(lo[0] - m)), max(0, int(lo[1] - m))
        x1, y1 = min(w, math.ceil(hi[0] + m) + 1), min(h, math.ceil(hi[1] + m) + 1)
        if x1 - x0 < 2 * cfg.min_marker_px or y1 - y0 < 2 * cfg.min_marker_px:
            return {}  # predicted out of the frame: nothing to decode there
        crop = gray[y0:y1, x0:x1]
        p = self._roi_det.getDetectorParameters()
        longest = max(crop.shape)
        # only markers at least ~half as large as the smallest pad marker expected at the scale
        # seen last frame (a marker not yet seen, e.g. the inner one while descending, counts as
        # soon as it would be large enough to decode)
        min_side_px = growth * self._min_side_px
        min_side = max(self.config.min_marker_px * 0.75, 0.5 * min_side_px)
        p.minMarkerPerimeterRate = min(0.9, 4.0 * min_side / longest)
        ratio = cfg.roi_target_marker_px / max(min_side_px, 1.0)
        if ratio < 0.5:  # large markers: find candidates at reduced resolution (ArUco3)
            p.useAruco3Detection = True
            p.minMarkerLengthRatioOriginalImg = float(min(0.9, 0.5 * min_side / longest))
            p.minSideLengthCanonicalImg = 24
        else:
            p.useAruco3Detection = False
        self._roi_det.setDetectorParameters(p)
        return self._run(self._roi_det, crop, x0, y0)

    def detect_markers(
        self, gray: NDArray[np.uint8], time_s: float | None = None, ref_cam: Any = None
    ) -> tuple[dict[str, FloatArray], str]:
        """Marker corners (distorted pixels, ArUco order) by name, and the search used.
        ``time_s``: the frame's exposure time, and ``ref_cam`` a world-fixed unit direction near
        the optical axis in the camera frame (world down for a level pad), for the ROI to follow
        the pad's image (:meth:`RoiTrack.prediction`); without a time the ROI is searched where the
        pad was last seen, without a direction the camera's tilt is not taken out."""
        cfg = self.config
        use_roi = cfg.roi_enabled and self._roi_corners is not None and self._frames_since_full < cfg.full_search_every
        R_level_cam = level_rotation(ref_cam)
        found: dict[str, FloatArray] = {}
        how = "full"
        if use_roi:
            self._counts["roi_searches"] += 1
            found = self._search_roi(gray, time_s, R_level_cam)
            how = "roi"
            if not found:
                self._counts["roi_fallbacks"] += 1
                use_roi = False
        if not use_roi:
            self._counts["full_searches"] += 1
            self._frames_since_full = 0
            found = self._run(self._full, gray)
            how = "full" if how == "full" else "roi_fallback"
        else:
            self._frames_since_full += 1
        if "outer" in found and "inner" in found:
            centre = found["inner"].mean(axis=0)
            poly = found["outer"].astype(np.float32).reshape(-1, 1, 2)
            if cv2.pointPolygonTest(poly, (float(centre[0]), float(centre[1])), False) < 0:
                # the pad's markers are concentric: an "inner" outside the outer is a false match
                log.debug("inner marker outside the outer one: dropped")
                del found["inner"]
        if found:
            self._roi_corners = np.vstack(list(found.values()))
            px_per_m = max(_marker_side_px(c) / self.layout.marker_size_m(m) for m, c in found.items())
            expected = [px_per_m * self.layout.marker_size_m(m) for m in MARKERS]
            decodable = [s for s in expected if s >= self.config.min_marker_px]
            self._min_side_px = min(decodable) if decodable else max(expected)
            self.roi_track.update(found, px_per_m, time_s, R_level_cam)
        else:
            self._roi_corners = None
            self.roi_track.clear()
        return found, how

    def detect(
        self, image: Any, time_s: float, *, down_cam: Any = None, normal_cam: Any = None, roi_down_cam: Any = None
    ) -> MarkerObservation | None:
        """Detect the pad in ``image`` exposed at ``time_s``; None when it is not seen.

        ``down_cam``: world "down" in the camera frame from the attitude estimate (unit vector);
        default (0, 0, 1), a level vehicle with the camera looking straight down. Given (and
        ``config.attitude_resolution``), the IPPE mirror pair is resolved by the attitude
        (:func:`resolve_ambiguity` with ``attitude=True``; see :func:`down_in_camera`).
        ``normal_cam``: instead of ``down_cam`` for a marker that does not lie level (the Dart's
        wall marker), its normal (pointing out of the printed face) in the camera frame from the
        attitude (:func:`marker_normal_in_camera`); same use.
        ``roi_down_cam``: world "down" in the camera frame for the ROI to follow the pad's image
        through the vehicle's tilt (:meth:`detect_markers`) and for nothing else, for a caller
        that does not resolve the pair by the attitude; ``down_cam`` or ``normal_cam`` serve the
        ROI too when given.
        Raises :class:`ImageError` (ValueError) for an unusable frame, ValueError for a
        non-finite time or prior.
        """
        self._counts["frames"] += 1
        try:
            gray = check_image(image, self.camera.size)
            if isinstance(time_s, bool) or not isinstance(time_s, numbers.Real) or not math.isfinite(float(time_s)):
                raise ValueError(f"time_s = {time_s!r}: must be a finite number")
            up = np.array([0.0, 0.0, -1.0])
            if down_cam is not None and normal_cam is not None:
                raise ValueError("detect: give down_cam (a level pad) or normal_cam (any marker), not both")
            # a world-fixed direction near the optical axis for the ROI: down for a level pad, into
            # a wall marker
            ref_cam = None
            for name, vec, sign in (
                ("roi_down_cam", roi_down_cam, -1.0),
                ("down_cam", down_cam, -1.0),
                ("normal_cam", normal_cam, 1.0),
            ):
                if vec is None:
                    continue
                d = np.asarray(vec, dtype=float).reshape(-1)
                n = float(np.linalg.norm(d)) if d.shape == (3,) else float("nan")
                if not (math.isfinite(n) and n > 0.5):
                    raise ValueError(f"{name} = {vec!r}: must be a finite unit 3-vector")
                ref_cam = -sign * d / n
                if name != "roi_down_cam":
                    up = sign * d / n
        except ValueError:
            self._counts["bad_frames"] += 1
            raise
        found, _ = self.detect_markers(gray, float(time_s), ref_cam)
        if not found:
            return None
        attitude = (down_cam is not None or normal_cam is not None) and self.config.attitude_resolution
        return self._estimate(found, gray, float(time_s), up, attitude)

    # ------------------------------------------------------------------ pose
    def _ideal_corners(
        self, found: dict[str, FloatArray], names: tuple[str, ...], gray: NDArray[np.uint8]
    ) -> FloatArray:
        out = []
        for m in names:
            ref = None
            if self.config.edge_refinement:
                ref = refine_corners_by_edges(gray, found[m], self.camera, self._cells[m])
            out.append(ref if ref is not None else self.camera.undistort_pixels(found[m]))
        return np.vstack(out)

    def _estimate(
        self,
        found: dict[str, FloatArray],
        gray: NDArray[np.uint8],
        time_s: float,
        up_cam: FloatArray,
        attitude: bool = False,
    ) -> MarkerObservation | None:
        cfg = self.config
        names = tuple(m for m in MARKERS if m in found)
        if len(names) == 1 and _marker_side_px(found[names[0]]) < cfg.min_pose_marker_px:
            self._counts["rejected_poses"] += 1
            log.debug("pose rejected: lone %s marker is only %.1f px", names[0], _marker_side_px(found[names[0]]))
            return None
        obj = np.vstack([self._obj[m] for m in names])
        ideal = self._ideal_corners(found, names, gray)
        if not np.all(np.isfinite(ideal)):
            self._counts["rejected_poses"] += 1
            return None
        cands = solve_candidates(obj, ideal, self.camera.K)
        if not cands:
            self._counts["rejected_poses"] += 1
            return None
        prior_R = None
        if self._prior is not None and 0.0 <= time_s - self._prior[0] <= cfg.prior_max_age_s:
            prior_R = self._prior[1]
        res = resolve_ambiguity(cands, cfg, up_cam=up_cam, prior_R=prior_R, attitude=attitude)
        best = cands[res.chosen]
        if best.error_px > cfg.max_reprojection_error_px:
            self._counts["rejected_poses"] += 1
            log.debug("pose rejected: reprojection error %.2f px", best.error_px)
            return None
        alt = cands[1 - res.chosen] if len(cands) > 1 else None
        obs = MarkerObservation(
            time_s=time_s,
            T_camera_pad=Transform(best.R, best.t),
            markers=names,
            reprojection_error_px=best.error_px,
            ambiguous=res.ambiguous,
            alternative=Transform(alt.R, alt.t) if alt is not None else None,
            alternative_error_px=alt.error_px if alt is not None else None,
            err_ratio=res.err_ratio,
            resolved_by=res.resolved_by,
            corners_px={m: found[m].copy() for m in names},
        )
        self._counts["detections"] += 1
        if res.ambiguous:
            self._counts["ambiguous"] += 1
        else:
            self._prior = (time_s, best.R.copy())
        return obs


def raw_detectors(layout: PadLayout) -> list[Any]:
    """The straightforward baseline: one default ArucoDetector (sub-pixel) per dictionary."""
    names = dict.fromkeys([layout.outer_dict, layout.inner_dict])
    return [cv2.aruco.ArucoDetector(aruco_dictionary(n), _params()) for n in names]
