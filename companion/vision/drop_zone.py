"""Is the drop zone clear? The downward camera's check of the pad and a margin around it
(docs/drop-zone.md).

Per frame, given the pad's pose in the camera (the detector's, or one predicted from the landing
fusion when the pad is not detected) and the markers the detector found:

(a) **hidden markers**: a marker of the nested pad the pose puts whole in the frame and at least
    ``hidden_min_side_px`` wide, seen in an earlier frame, and not found in this one;
(b) **unlike the printed pad**: the frame is warped onto the pad plane (a grid of ``grid_m`` cells
    over the pad and its margin, through the pose and the lens model) and compared with the pad as
    printed (:func:`companion.vision.pad.render_pad_px`) by zero-mean normalised cross-correlation
    in ``window_m`` windows: a gain and an offset per window, so a shadow or an exposure change
    is not an object; a window correlating below ``zncc_min`` differs when its fit's offset (the
    print's black) is raised above ``raised_black_ratio`` of its gain: a shadow's edge across a
    window lowers the correlation too, but a shadow only scales, and the black stays black. The warp is first
    registered on the printed pad (a search of ``max_shift_m``), which absorbs a predicted pose's
    error, then refined by a homography (ECC on the print, moving the pad's corners at most
    ``max_bend_m``), which takes out the bend a misplaced marker corner gives the warp;
(c) **motion in the margin**: the margin's warps ``motion_baseline_s`` apart are differenced (the
    pose compensates the vehicle's own motion; each warp scaled to a mean grey of 128), and a
    moving region of ``motion_area_m2`` is motion.

A frame's vote is OCCUPIED (a differing area >= ``differing_area_m2``, or >= ``corroborated_area_m2``
with a marker hidden), MOTION_IN_MARGIN, CLEAR, or UNKNOWN (no pose, the pad too small or mostly
out of the frame). The verdict has hysteresis: ``enter_votes`` of the last ``votes`` judged frames
set it to OCCUPIED or MOTION_IN_MARGIN (occupied first), only ``votes`` clear frames in a row clear
it again, and ``stale_s`` without a judged frame makes it UNKNOWN.
"""

from __future__ import annotations

import enum
import logging
import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray

from companion.config import DropZoneConfig
from companion.geometry import Transform
from companion.vision.camera import CameraModel
from companion.vision.pad import PadLayout, render_pad_px

log = logging.getLogger(__name__)

F32 = NDArray[np.float32]

#: markers of the nested pad, in the detector's names
MARKERS = ("outer", "inner")
#: a pad-plane cell is kept inside the pad when this far (m) from its edge: the edge's blur
PAD_EDGE_GUARD_M = 0.01
#: the margin starts this far (m) outside the pad's edge
MARGIN_GUARD_M = 0.06
#: a margin cell moved when it is outside the other frame's range within this many cells
MOTION_TOLERANCE_CELLS = 2
#: two frames' warps whose alignment moves them more than this many cells are not compared
MOTION_MAX_SHIFT_CELLS = 4
#: the differing cells are opened by a square this many cells wide (thin bands are not objects)
DIFFERING_OPEN_CELLS = 6
#: the registration's homography refinement (ECC on the print): iterations, and its blur (cells)
REFINE_ITERATIONS = 30
REFINE_BLUR_CELLS = 5
#: the printed pad is rendered this many pixels per grid cell, then area-averaged
REFERENCE_SUPERSAMPLE = 8


class DropZoneVerdict(enum.Enum):
    """The drop zone's state, as the check judges it."""

    CLEAR = "clear"
    OCCUPIED = "occupied"
    MOTION_IN_MARGIN = "motion_in_margin"
    UNKNOWN = "unknown"


@dataclass(frozen=True, slots=True)
class DropZoneEvidence:
    """What one frame showed: its vote and why."""

    time_s: float
    vote: DropZoneVerdict
    hidden_markers: tuple[str, ...]
    differing_area_m2: float
    moving_area_m2: float
    visible_fraction: float
    px_per_cell: float
    shift_m: tuple[float, float]
    reason: str


@dataclass(frozen=True, slots=True)
class DropZoneStatus:
    """The verdict after a frame: since when it holds, and that frame's evidence."""

    verdict: DropZoneVerdict
    since_s: float
    evidence: DropZoneEvidence


def _check_finite_time(time_s: float) -> float:
    if isinstance(time_s, bool) or not isinstance(time_s, int | float) or not math.isfinite(float(time_s)):
        raise ValueError(f"time_s = {time_s!r}: must be a finite number")
    return float(time_s)


class DropZoneCheck:
    """The check of one camera stream; not thread-safe. ``update`` per frame, ``reset`` between
    landings (a new pad)."""

    def __init__(self, camera: CameraModel, layout: PadLayout | None = None, config: DropZoneConfig | None = None):
        self.camera = camera
        self.layout = layout if layout is not None else PadLayout()
        self.config = config if config is not None else DropZoneConfig()
        cfg = self.config
        lay = self.layout
        cell = cfg.grid_m
        self._cell_m = cell
        extent = lay.pad_size_m + 2.0 * cfg.margin_m
        n = math.ceil(extent / cell)
        self._n = n
        half = n * cell / 2.0
        c = (np.arange(n) + 0.5) * cell
        X, Y = np.meshgrid(c - half, half - c)  # row down = pad y down, as the printed image
        self._plane = np.stack([X.ravel(), Y.ravel(), np.zeros(X.size)], axis=1)
        gc, gr = np.meshgrid(np.arange(n, dtype=np.float64), np.arange(n, dtype=np.float64))
        self._grid_h = np.stack([gc.ravel(), gr.ravel(), np.ones(n * n)], axis=1)  # (column, row, 1) per cell
        a = np.maximum(np.abs(X), np.abs(Y))
        hp = lay.pad_size_m / 2.0
        self._pad_mask = a <= hp - PAD_EDGE_GUARD_M
        self._margin_mask = (a >= hp + MARGIN_GUARD_M) & (a <= hp + cfg.margin_m)
        # the printed pad on the grid: rendered finer, then area-averaged; the margin is not known
        n_pad = round(lay.pad_size_m / cell)
        fine = render_pad_px(lay, n_pad * REFERENCE_SUPERSAMPLE).astype(np.float32) / 255.0
        pad_ref = np.asarray(cv2.resize(fine, (n_pad, n_pad), interpolation=cv2.INTER_AREA), dtype=np.float32)
        ref = np.zeros((n, n), np.float32)
        o = (n - n_pad) // 2
        ref[o : o + n_pad, o : o + n_pad] = pad_ref
        self._ref = ref
        self._pad_slice = (slice(o, o + n_pad), slice(o, o + n_pad))
        self._pad_ref = pad_ref
        w = max(3, round(cfg.window_m / cell) | 1)
        self._win = (w, w)
        m = self._pad_mask.astype(np.float32)
        mean_r = cv2.boxFilter(ref * m, -1, self._win, normalize=False)
        cnt = cv2.boxFilter(m, -1, self._win, normalize=False)
        with np.errstate(invalid="ignore", divide="ignore"):
            mu = mean_r / cnt
            var = cv2.boxFilter(ref * ref * m, -1, self._win, normalize=False) / cnt - mu * mu
        # a window is compared where the printed pad has contrast and lies (mostly) on the pad
        self._textured = self._pad_mask & (cnt >= 0.8 * w * w) & (np.sqrt(np.maximum(var, 0.0)) >= cfg.min_texture)
        self._max_shift = round(cfg.max_shift_m / cell)
        self._max_bend = cfg.max_bend_m / cell
        w_px, h_px = camera.size
        frame = np.array([[0, 0], [w_px - 1, 0], [0, h_px - 1], [w_px - 1, h_px - 1], [w_px / 2, 0], [0, h_px / 2]])
        corners_n = camera.undistort_normalized(camera.pixels_to_normalized(frame))
        self._fov_radius = 1.02 * float(np.max(np.hypot(corners_n[:, 0], corners_n[:, 1])))
        self.reset()

    # ------------------------------------------------------------------ state
    def reset(self) -> None:
        """Forget the markers seen, the margin history and the votes (a new pad)."""
        self._seen: set[str] = set()
        self._margins: deque[tuple[float, F32, NDArray[np.bool_]]] = deque()
        self._votes: deque[DropZoneVerdict] = deque(maxlen=self.config.votes)
        self._verdict = DropZoneVerdict.UNKNOWN
        self._since_s = -math.inf
        self._last_judged_s = -math.inf

    @property
    def verdict(self) -> DropZoneVerdict:
        return self._verdict

    # ------------------------------------------------------------------ per frame
    def update(
        self,
        image: NDArray[np.uint8],
        time_s: float,
        T_camera_pad: Transform | None,
        detected: Iterable[str] = (),
        corners_px: Mapping[str, NDArray[np.float64]] | None = None,
    ) -> DropZoneStatus:
        """Judge one frame (greyscale, the camera's size) exposed at ``time_s``; ``T_camera_pad``:
        the pad's pose in the camera (None: none known, the frame abstains); ``detected``: the
        markers the detector found in it ("outer", "inner"); ``corners_px``: their corners
        (distorted pixels, ArUco order, the detector's ``MarkerObservation.corners_px``): the pad
        plane is then warped through the homography they give, which a lone marker's pose error
        (its tilt, the IPPE mirror) does not bend, and the pose serves the rest."""
        t = _check_finite_time(time_s)
        img = np.asarray(image)
        w, h = self.camera.size
        if img.dtype != np.uint8 or img.shape != (h, w):
            raise ValueError(f"image: expected a uint8 {h}x{w} greyscale frame, got {img.dtype} {img.shape}")
        found = tuple(detected)
        bad = [m for m in found if m not in MARKERS]
        if bad:
            raise ValueError(f"detected = {found!r}: markers are {MARKERS}")
        # the inner marker alone (25 px at 2 m) pins no perspective across a 3 m grid: its
        # homography, extrapolated, folds the warp; then the pose serves
        H = self._homography(corners_px) if corners_px else None
        if corners_px is not None and "outer" not in corners_px:
            H = None
        ev = self._evidence(img, t, T_camera_pad, found, H)
        self._seen.update(found)
        return self._vote(ev)

    def _homography(self, corners_px: Mapping[str, NDArray[np.float64]]) -> NDArray[np.float64] | None:
        """Pad plane (x, y, 1) -> ideal (undistorted) pixels from the markers' corners; None when
        they do not give one."""
        obj, img = [], []
        for m, c in corners_px.items():
            if m not in MARKERS:
                raise ValueError(f"corners_px: marker {m!r}: markers are {MARKERS}")
            a = np.asarray(c, dtype=float)
            if a.shape != (4, 2) or not np.all(np.isfinite(a)):
                raise ValueError(f"corners_px[{m!r}]: expected 4 finite (u, v) corners, got shape {a.shape}")
            obj.append(self.layout.marker_corners(m)[:, :2])
            img.append(self.camera.undistort_pixels(a))
        H, _ = cv2.findHomography(np.vstack(obj), np.vstack(img), 0)
        if H is None or not np.all(np.isfinite(H)):
            return None
        return np.asarray(H, dtype=float)

    def _unknown(self, t: float, reason: str, visible: float = 0.0, ppc: float = 0.0) -> DropZoneEvidence:
        return DropZoneEvidence(t, DropZoneVerdict.UNKNOWN, (), 0.0, 0.0, visible, ppc, (0.0, 0.0), reason)

    def _evidence(
        self,
        img: NDArray[np.uint8],
        t: float,
        T: Transform | None,
        found: tuple[str, ...],
        H: NDArray[np.float64] | None,
    ) -> DropZoneEvidence:
        cfg = self.config
        if T is None:
            return self._unknown(t, "no pose of the pad")
        R = np.asarray(T.R, dtype=float)
        tv = np.asarray(T.t, dtype=float)
        if not (np.all(np.isfinite(R)) and np.all(np.isfinite(tv))):
            raise ValueError("T_camera_pad: contains NaN or inf")
        if tv[2] <= 0.05:
            return self._unknown(t, "pad not in front of the camera")
        f = 0.5 * (self.camera.fx + self.camera.fy)
        ppc = f * self._cell_m / float(tv[2])
        if ppc < cfg.min_px_per_cell:
            return self._unknown(t, f"pad too far: {ppc:.2f} px per cell", ppc=ppc)
        # warp the frame onto the pad plane, from an image pyramid level near one pixel per cell
        level = max(0, math.floor(math.log2(ppc))) if ppc >= 2.0 else 0
        src = img
        for _ in range(level):
            src = np.asarray(cv2.pyrDown(src))
        if H is not None:
            q = np.column_stack([self._plane[:, :2], np.ones(len(self._plane))]) @ H.T
            with np.errstate(divide="ignore", invalid="ignore"):
                ideal = q[:, :2] / q[:, 2:3]
            ideal[q[:, 2] <= 0] = np.nan
            xy = self.camera.pixels_to_normalized(ideal)
        else:
            p = self._plane @ R.T + tv
            with np.errstate(divide="ignore", invalid="ignore"):
                xy = p[:, :2] / p[:, 2:3]
            xy[p[:, 2] <= 0] = np.nan
        # beyond the frame's field of view the lens model folds back into the image: such points
        # are out of the frame, whatever pixel the model gives them
        with np.errstate(invalid="ignore"):
            xy[np.hypot(xy[:, 0], xy[:, 1]) > self._fov_radius] = np.nan
        uv = self.camera.normalized_to_pixels(self.camera.distort_normalized(xy))
        scale = 2.0**-level
        n = self._n
        mx = ((uv[:, 0] + 0.5) * scale - 0.5).reshape(n, n).astype(np.float32)
        my = ((uv[:, 1] + 0.5) * scale - 0.5).reshape(n, n).astype(np.float32)
        inside = self.camera.in_image(uv, margin_px=1.0).reshape(n, n)
        inside &= np.isfinite(mx) & np.isfinite(my)
        mx[~inside] = -10.0
        my[~inside] = -10.0
        warp = np.asarray(
            cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0), dtype=np.float32
        )
        visible = float(np.count_nonzero(inside & self._pad_mask)) / float(np.count_nonzero(self._pad_mask))
        if visible < cfg.min_visible_fraction:
            return self._unknown(t, f"{100 * visible:.0f} % of the pad in the frame", visible, ppc)
        dy, dx = self._register(warp, inside)
        A = self._refine(warp, inside, dy, dx)
        in_frame = inside
        warp = np.roll(warp, (-dy, -dx), axis=(0, 1))
        inside = np.roll(inside, (-dy, -dx), axis=(0, 1))
        shift_m = (dx * self._cell_m, -dy * self._cell_m)
        differs = self._differing(warp, inside)
        if A is not None:
            # the print is unlike the warp only where it is unlike under both registrations: the
            # homography takes out a misplaced corner's bend, but a shadow's edge across the pad
            # can pull ECC off where the shift alone was right; an object differs under both
            bent = self._resample(src, mx, my, in_frame, A)
            d_bent = self._differing(bent[0], bent[1])
            if np.count_nonzero(d_bent) <= np.count_nonzero(differs):
                warp, inside, shift_m = bent
                differs = d_bent
        self.last_differing = differs  # the cells judged unlike the print (for inspection)
        differing = float(np.count_nonzero(differs)) * self._cell_m**2
        hidden = self._hidden(R, tv, found)
        moving = self._moving_area_m2(t, warp, inside)
        if differing >= cfg.differing_area_m2 or (hidden and differing >= cfg.corroborated_area_m2):
            vote = DropZoneVerdict.OCCUPIED
            reason = f"{differing:.3f} m^2 of the pad unlike the printed pad" + (
                f", {' and '.join(hidden)} marker hidden" if hidden else ""
            )
        elif moving >= cfg.motion_area_m2:
            vote = DropZoneVerdict.MOTION_IN_MARGIN
            reason = f"{moving:.3f} m^2 moving in the margin"
        else:
            vote = DropZoneVerdict.CLEAR
            reason = "pad as printed, margin still"
        return DropZoneEvidence(t, vote, hidden, differing, moving, visible, ppc, shift_m, reason)

    def _register(self, warp: F32, inside: NDArray[np.bool_]) -> tuple[int, int]:
        """The (rows, columns) by which the printed pad lies off the grid's pad in the warp."""
        s = self._max_shift
        if s == 0:
            return 0, 0
        rs, cs = self._pad_slice
        r0, r1, c0, c1 = rs.start - s, rs.stop + s, cs.start - s, cs.stop + s
        if r0 < 0 or c0 < 0 or r1 > self._n or c1 > self._n:
            return 0, 0
        area = warp[r0:r1, c0:c1]
        if not np.all(inside[r0:r1, c0:c1]):
            # out-of-frame cells would pull the match: fill them with the area's mean
            ins = inside[r0:r1, c0:c1]
            area = np.where(ins, area, np.float32(area[ins].mean() if np.any(ins) else 0.0)).astype(np.float32)
        res = cv2.matchTemplate(area, self._pad_ref, cv2.TM_CCOEFF_NORMED)
        _, _, _, loc = cv2.minMaxLoc(res)
        return int(loc[1]) - s, int(loc[0]) - s

    def _resample(
        self, src: NDArray[np.uint8], mx: F32, my: F32, inside: NDArray[np.bool_], A: NDArray[np.float64]
    ) -> tuple[F32, NDArray[np.bool_], tuple[float, float]]:
        """The warp with the grid's cell (x, y) at the warp's A (x, y): the maps resampled, then the
        frame remapped once; with its cells in the frame and the pad's shift (m)."""
        n = self._n
        q = self._grid_h @ A.T
        qx = (q[:, 0] / q[:, 2]).reshape(n, n).astype(np.float32)
        qy = (q[:, 1] / q[:, 2]).reshape(n, n).astype(np.float32)
        ins = cv2.remap(inside.astype(np.float32), qx, qy, cv2.INTER_LINEAR, borderValue=0.0)
        mx = np.asarray(cv2.remap(mx, qx, qy, cv2.INTER_LINEAR), dtype=np.float32)
        my = np.asarray(cv2.remap(my, qx, qy, cv2.INTER_LINEAR), dtype=np.float32)
        ok = np.asarray(ins, dtype=np.float32) >= 0.999  # every neighbour interpolated was in the frame
        mx[~ok] = -10.0
        my[~ok] = -10.0
        warp = np.asarray(
            cv2.remap(src, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0), dtype=np.float32
        )
        c = (n - 1) / 2.0
        qc = A @ np.array([c, c, 1.0])
        return warp, ok, ((qc[0] / qc[2] - c) * self._cell_m, -(qc[1] / qc[2] - c) * self._cell_m)

    def _refine(self, warp: F32, inside: NDArray[np.bool_], dy: int, dx: int) -> NDArray[np.float64] | None:
        """The homography (grid cell -> warp cell) that lays the printed pad onto the warp, from the
        shift ``_register`` found (ECC on the print); None when it does not converge or moves a pad
        corner more than ``max_bend_m`` from the shift. A marker corner the detector misplaced
        (a shadow's edge through it pulls it, docs/drop-zone.md) bends the warp through the
        homography by a few cells near it, and the print there reads as an object; that error is
        itself a plane-to-plane homography, which this takes out."""
        if self._max_bend == 0:
            return None
        rs, cs = self._pad_slice
        A0 = np.array([[1.0, 0.0, cs.start + dx], [0.0, 1.0, rs.start + dy], [0.0, 0.0, 1.0]], np.float32)
        A: Any = A0.copy()
        try:
            _, A = cv2.findTransformECC(
                self._pad_ref,
                warp,
                A,
                cv2.MOTION_HOMOGRAPHY,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, REFINE_ITERATIONS, 1e-4),
                inside.astype(np.uint8),
                REFINE_BLUR_CELLS,
            )
        except cv2.error:
            return None
        A = np.asarray(A, dtype=np.float64)
        if not np.all(np.isfinite(A)):
            return None
        m = self._pad_ref.shape[0] - 1
        corners = np.array([[0.0, 0.0, 1.0], [m, 0.0, 1.0], [0.0, m, 1.0], [m, m, 1.0]]).T
        p, p0 = A @ corners, A0.astype(np.float64) @ corners
        if np.any(p[2] <= 0) or np.max(np.hypot(*(p[:2] / p[2] - p0[:2]))) > self._max_bend:
            return None
        to_pad = np.array([[1.0, 0.0, -cs.start], [0.0, 1.0, -rs.start], [0.0, 0.0, 1.0]])
        return A @ to_pad

    def _hidden(self, R: NDArray[np.float64], t: NDArray[np.float64], found: tuple[str, ...]) -> tuple[str, ...]:
        out = []
        for m in MARKERS:
            if m in found or m not in self._seen:
                continue
            corners = self.layout.marker_corners(m)
            uv = self.camera.project(corners @ R.T + t)
            if not np.all(self.camera.in_image(uv, margin_px=2.0)):
                continue
            side = float(np.mean(np.linalg.norm(uv - np.roll(uv, 1, axis=0), axis=1)))
            if side >= self.config.hidden_min_side_px:
                out.append(m)
        return tuple(out)

    def _differing(self, warp: F32, inside: NDArray[np.bool_]) -> NDArray[np.bool_]:
        """The pad's cells unlike the print (the differing windows' centres, opened)."""
        m = (inside & self._pad_mask).astype(np.float32)
        I = warp * m  # noqa: E741 - the image in the usual ZNCC notation
        Rf = self._ref * m
        box = self._win

        def bf(x: F32) -> F32:
            return np.asarray(cv2.boxFilter(x, -1, box, normalize=False), dtype=np.float32)

        cnt = bf(m)
        with np.errstate(invalid="ignore", divide="ignore"):
            mi, mr = bf(I) / cnt, bf(Rf) / cnt
            vi = bf(I * I) / cnt - mi * mi
            vr = bf(Rf * Rf) / cnt - mr * mr
            cov = bf(I * Rf) / cnt - mi * mr
            zncc = cov / np.sqrt(np.maximum(vi, 1e-6) * np.maximum(vr, 1e-9))
            # the window as gain x print + offset: a shadow scales the whole print (the offset,
            # the print's black, stays near 0); an object lays its own grey over the black cells
            gain = cov / np.maximum(vr, 1e-9)
            black = mi - gain * mr
        full = cnt >= 0.8 * box[0] * box[1]
        judged = self._textured & full & inside
        raised = (gain <= 0) | (black > self.config.raised_black_ratio * gain)
        differs = judged & (zncc < self.config.zncc_min) & raised
        # an object is a blob; a shadow's edge leaves thin bands along it: opened away
        k = DIFFERING_OPEN_CELLS
        return np.asarray(cv2.morphologyEx(differs.astype(np.uint8), cv2.MORPH_OPEN, np.ones((k, k), np.uint8)) > 0)

    def _moving_area_m2(self, t: float, warp: F32, inside: NDArray[np.bool_]) -> float:
        cfg = self.config
        now = np.asarray(cv2.GaussianBlur(warp, (0, 0), 1.0), dtype=np.float32)
        # the blur reaches a few cells past the frame's edge: those cells are not the ground's
        inside = cv2.erode(inside.astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        ok_m = inside & self._margin_mask
        self._margins.append((t, now, inside))
        while len(self._margins) > 1 and t - self._margins[1][0] >= cfg.motion_baseline_s:
            self._margins.popleft()
        t0, then, in0 = self._margins[0]
        if not (cfg.motion_baseline_s <= t - t0 <= 3.0 * cfg.motion_baseline_s):
            return 0.0
        # the two poses' errors (a lone marker's tilt at 10 m is off by degrees) leave the two warps
        # off by more than a shift across the margin: align them on their content (ECC, a homography;
        # the pad's own print anchors it), then compare
        both = (inside & in0).astype(np.uint8)
        if np.count_nonzero(both & self._margin_mask) < 50:
            return 0.0
        A: Any = np.eye(3, dtype=np.float32)
        try:
            _, A = cv2.findTransformECC(
                now,
                then,
                A,
                cv2.MOTION_HOMOGRAPHY,
                (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 40, 1e-4),
                both,
                1,
            )
        except cv2.error:
            return 0.0  # no alignment: no judgement of motion in this frame
        n = self._n
        if abs(float(A[0, 2])) > MOTION_MAX_SHIFT_CELLS or abs(float(A[1, 2])) > MOTION_MAX_SHIFT_CELLS:
            return 0.0
        flags = cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP
        then_a = np.asarray(cv2.warpPerspective(then, A, (n, n), flags=flags), dtype=np.float32)
        in_a = cv2.warpPerspective(in0.astype(np.uint8), A, (n, n), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP) > 0
        ok = ok_m & in_a
        if np.count_nonzero(ok) < 50:
            return 0.0
        # the exposure on the cells both frames see (not the whole margin's: the part in view
        # changes, and with it how much of a shadow is in it): each scaled to a median of 128
        now = now * np.float32(128.0 / max(float(np.median(now[ok])), 1.0))
        then_a = then_a * np.float32(128.0 / max(float(np.median(then_a[ok])), 1.0))
        # a cell moved when it lies outside the range of the other frame's cells around it (both
        # ways): what is left of the misalignment is not motion
        k = np.ones((2 * MOTION_TOLERANCE_CELLS + 1,) * 2, np.uint8)
        lo_then, hi_then = cv2.erode(then_a, k), cv2.dilate(then_a, k)
        lo_now, hi_now = cv2.erode(now, k), cv2.dilate(now, k)
        diff = np.maximum.reduce([now - hi_then, lo_then - now, then_a - hi_now, lo_now - then_a])
        moving = (ok & (diff > cfg.motion_threshold)).astype(np.uint8)
        moving = cv2.morphologyEx(moving, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8))
        count, _, stats, _ = cv2.connectedComponentsWithStats(moving, connectivity=8)
        if count <= 1:
            return 0.0
        return float(stats[1:, cv2.CC_STAT_AREA].max()) * self._cell_m**2

    # ------------------------------------------------------------------ verdict
    def _vote(self, ev: DropZoneEvidence) -> DropZoneStatus:
        cfg = self.config
        t = ev.time_s
        before = self._verdict
        if ev.vote is not DropZoneVerdict.UNKNOWN:
            self._votes.append(ev.vote)
            self._last_judged_s = t
            occ = sum(v is DropZoneVerdict.OCCUPIED for v in self._votes)
            mov = sum(v is DropZoneVerdict.MOTION_IN_MARGIN for v in self._votes)
            clear = sum(v is DropZoneVerdict.CLEAR for v in self._votes)
            if occ >= cfg.enter_votes or mov >= cfg.enter_votes or occ + mov >= cfg.enter_votes:
                self._verdict = DropZoneVerdict.OCCUPIED if occ >= mov else DropZoneVerdict.MOTION_IN_MARGIN
            elif self._verdict in (DropZoneVerdict.OCCUPIED, DropZoneVerdict.MOTION_IN_MARGIN):
                if clear == cfg.votes:
                    self._verdict = DropZoneVerdict.CLEAR
            elif clear >= cfg.enter_votes:
                self._verdict = DropZoneVerdict.CLEAR
        elif t - self._last_judged_s > cfg.stale_s:
            self._verdict = DropZoneVerdict.UNKNOWN
            self._votes.clear()
        if self._verdict is not before:
            self._since_s = t
            log.info("drop zone %s at %.2f s: %s", self._verdict.value, t, ev.reason)
        return DropZoneStatus(self._verdict, self._since_s, ev)
