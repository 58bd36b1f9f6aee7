"""Camera images into the pad detector (``PadDetector.detect``): random arrays of every dtype and
shape (truncated, wrong dtype, NaN-filled, huge, tiny, strided, not arrays at all), rendered pad
frames mutated (noise, blur, occlusion, flips, saturation, inverted), with odd exposure times and
attitude vectors.

Rule: each frame is counted (``frames``); it raises ``ImageError`` / ``ValueError`` and is
counted in ``bad_frames``, or gives None or an observation with a finite pose in front of the
camera, never another exception. The detector is not poisoned: the clean frame that follows
(later in time) is found where the pad is, within 5 cm."""

from __future__ import annotations

import math
from typing import Any

import cv2
import numpy as np
import pytest
from hypothesis import strategies as st

from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion.vision.detector import PadDetector
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera

from . import harness

pytestmark = pytest.mark.fuzz

CAM = load_default_camera()
W, H = CAM.size
SURFACE = "camera images -> pad detector"
_SIM = SimulatedCamera(CAM, PadLayout(), SimCameraConfig(noise_std=2.0), seed=5)
#: (image, truth T_camera_pad): the outer marker at 5 m, both markers at 2 m, tilted at 3 m
FRAMES = [
    (f.image, f.T_camera_pad)
    for f in (
        _SIM.capture(Transform.from_euler([0.0, 0.0, -5.0], 0.03, -0.02, 0.4), 0.0),
        _SIM.capture(Transform.from_euler([0.15, -0.1, -2.0], 0.05, 0.04, 0.7), 0.0),
        _SIM.capture(Transform.from_euler([0.5, 0.3, -3.0], 0.2, -0.15, -1.2), 0.0),
    )
]
_DTYPES = ("uint8", "int8", "uint16", "int32", "float32", "float64", "bool", "complex64", "object")
_SHAPES = [(H, W), (H, W, 3), (H, W, 1), (H, W, 4), (H, W, 3, 1), (W, H), (H - 1, W), (H, W, 2)]
_SHAPES += [(H,), (0, W), (1, 1), (2, 2, 3), (), (8 * H, 8 * W)]
_MUTATIONS = ("noise", "blur", "occlude", "fliplr", "flipud", "rot180", "saturate", "invert", "salt", "crop", "bgr")
_ODD = [None, b"\x00" * (W * H), "image", [[0] * W] * H, 3.0, np.uint8(7)]


@st.composite
def _random_image(draw: st.DrawFn) -> Any:
    dtype = draw(st.sampled_from(_DTYPES))
    shape = draw(st.sampled_from(_SHAPES))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    fill = draw(st.sampled_from(("random", "nan", "inf", "zeros", "max")))
    if dtype == "object":
        return np.empty(shape, dtype=object)
    a = rng.integers(0, 256, size=shape).astype(dtype)
    if fill == "zeros":
        a[...] = 0
    elif fill == "max":
        a[...] = {"bool": True, "int8": 127}.get(dtype, 255)
    elif fill in ("nan", "inf") and a.dtype.kind in "fc":
        a[...] = math.nan if fill == "nan" else math.inf
    if draw(st.booleans()) and a.ndim >= 2 and a.size:
        a = np.asfortranarray(a) if draw(st.booleans()) else a[::-1, ::-1]  # not C-contiguous
    return a


@st.composite
def _mutated_frame(draw: st.DrawFn) -> np.ndarray:
    img = FRAMES[draw(st.integers(0, len(FRAMES) - 1))][0].copy()
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    for op in draw(st.lists(st.sampled_from(_MUTATIONS), min_size=1, max_size=3)):
        if img.size == 0:
            break  # cropped to nothing: the detector's to refuse
        if op == "noise":
            sigma = draw(st.sampled_from((5.0, 30.0, 120.0)))
            img = np.clip(img + rng.normal(0.0, sigma, img.shape), 0, 255).astype(np.uint8)
        elif op == "blur":
            k = draw(st.sampled_from((3, 9, 31)))
            img = cv2.GaussianBlur(img, (k, k), 0)
        elif op == "occlude" and img.ndim >= 2:
            h, w = img.shape[:2]
            y, x = int(rng.integers(0, h)), int(rng.integers(0, w))
            img[y : y + int(rng.integers(1, h + 1)), x : x + int(rng.integers(1, w + 1))] = int(rng.integers(0, 256))
        elif op == "fliplr":
            img = np.ascontiguousarray(img[:, ::-1]) if draw(st.booleans()) else img[:, ::-1]
        elif op == "flipud":
            img = img[::-1]
        elif op == "rot180":
            img = np.rot90(img, 2)
        elif op == "saturate":
            img = np.clip(img.astype(np.float32) * draw(st.sampled_from((0.1, 3.0, 50.0))), 0, 255).astype(np.uint8)
        elif op == "invert":
            img = 255 - img
        elif op == "salt":
            mask = rng.random(img.shape) < 0.05
            img = np.where(mask, rng.integers(0, 2, img.shape) * 255, img).astype(np.uint8)
        elif op == "crop":
            img = img[: draw(st.integers(0, img.shape[0])), : draw(st.integers(0, img.shape[1]))]
        elif op == "bgr" and img.ndim == 2:
            img = np.dstack([img, img, img])
    return img


_TIMES = st.one_of(
    st.floats(0.0, 1e4),
    st.sampled_from([math.nan, math.inf, -math.inf, -1.0, 1e300, -1e300, 0.0, True, "1.0", None]),
)
_VEC = st.one_of(
    st.none(),
    st.sampled_from([(0.0, 0.0, 1.0), (0.0, 0.0, 0.0), (math.nan, 0.0, 1.0), (0.0, 1.0), (0.1, 0.0, 0.99, 0.0)]),
    st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-2, 2)),
)
CASES = st.tuples(
    st.one_of(_mutated_frame(), _random_image(), st.sampled_from(_ODD)),
    _TIMES,
    st.sampled_from(("down_cam", "normal_cam", "roi_down_cam", "both")),
    _VEC,
)


def _check_observation(obs: Any, time_s: float) -> None:
    T = obs.T_camera_pad
    assert np.all(np.isfinite(T.R)) and np.all(np.isfinite(T.t)), f"a non-finite pose: {T}"
    assert T.t[2] > 0.0, f"the pad behind the camera: {T.t}"
    assert obs.time_s == float(time_s) and math.isfinite(obs.reprojection_error_px)


class _Detector:
    """One detector for the whole run, as one camera stream has; its clock moves on each frame."""

    def __init__(self) -> None:
        self.det = PadDetector(CAM, PadLayout())
        self.clock = 0.0
        self.k = 0

    def feed(self, case: tuple[Any, Any, str, Any]) -> str:
        image, time_s, which, vec = case
        before = self.det.stats
        kw = {"down_cam": vec, "normal_cam": vec} if which == "both" else {which: vec}
        if isinstance(time_s, float) and math.isfinite(time_s) and 0.0 <= time_s <= 1e4:
            time_s = self.clock + time_s * 1e-4  # a time that goes on, by a little or by a second
        try:
            obs = self.det.detect(image, time_s, **kw)
        except ValueError:
            s = self.det.stats
            assert (s.frames, s.bad_frames) == (before.frames + 1, before.bad_frames + 1), "a refusal not counted"
            outcome = "refused (bad_frames)"
        else:
            s = self.det.stats
            assert (s.frames, s.bad_frames) == (before.frames + 1, before.bad_frames), "a frame not counted"
            if obs is not None:
                _check_observation(obs, time_s)
            outcome = "no pad" if obs is None else "pad seen"
        self.clock = max(self.clock, float(time_s) if isinstance(time_s, float) and math.isfinite(time_s) else 0.0)
        # the clean frame next: found where it is, whatever the fuzzed frame did to the tracker
        self.clock += 0.05
        self.k = (self.k + 1) % len(FRAMES)
        clean, truth = FRAMES[self.k]
        obs = self.det.detect(clean, self.clock, down_cam=None)
        assert obs is not None, f"the clean frame {self.k} not found after {outcome}"
        err = float(np.linalg.norm(obs.T_camera_pad.t - truth.t))
        assert err < 0.05, f"the clean frame {self.k} found {err:.3f} m off after {outcome}"
        return outcome


def test_images_into_the_detector(fuzz_budget: int) -> None:
    d = _Detector()
    seeds: list[tuple[Any, Any, str, Any]] = [(img, 1.0, "down_cam", None) for img, _ in FRAMES]
    seeds += [(img, 1.0, "down_cam", None) for img in _ODD]
    seeds += [
        (FRAMES[0][0][: H // 2], 1.0, "down_cam", None),  # truncated
        (FRAMES[0][0].astype(np.float32), 1.0, "down_cam", None),  # wrong dtype
        (np.full((H, W), np.nan), 1.0, "down_cam", None),  # NaN-filled
        (np.zeros((4 * H, 4 * W, 3), np.uint8), 1.0, "down_cam", None),  # huge
        (np.zeros((1, 1), np.uint8), 1.0, "down_cam", None),  # tiny
        (FRAMES[1][0][:, ::-1], 1.0, "down_cam", None),  # mirrored, not contiguous
        (FRAMES[1][0], math.nan, "down_cam", None),
        (FRAMES[1][0], 1e300, "down_cam", None),  # far in the future: the clean frame comes "before" it
        (FRAMES[1][0], -1e300, "down_cam", None),
        (FRAMES[2][0], 1.0, "down_cam", (0.0, 0.0, 0.0)),
        (FRAMES[2][0], 1.0, "both", (0.0, 0.0, 1.0)),
        (FRAMES[2][0], 1.0, "normal_cam", (0.0, 0.0, -1.0)),
    ]
    for case in seeds:
        harness.check(SURFACE, d.feed, case, ())
    harness.run(CASES, lambda case: harness.check(SURFACE, d.feed, case, ()), fuzz_budget)
    c = harness.COUNTS[SURFACE]
    assert c.outcomes["refused (bad_frames)"] and c.outcomes["pad seen"], c.outcomes
