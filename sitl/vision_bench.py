"""``companion bench vision``: raw full-frame ArUco detection against the pad detector's ROI
pipeline, timed on the same frames rendered by the simulated camera."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion.vision.detector import MARKERS, MarkerObservation, PadDetector, raw_detectors
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera

log = logging.getLogger(__name__)


def _raw_found(dets: list[Any], layout: PadLayout, gray: NDArray[np.uint8]) -> set[str]:
    found: set[str] = set()
    names = list(dict.fromkeys([layout.outer_dict, layout.inner_dict]))
    for det, dname in zip(dets, names, strict=True):
        _, ids, _ = det.detectMarkers(gray)
        if ids is None:
            continue
        for i in np.asarray(ids).ravel():
            for which in MARKERS:
                if getattr(layout, f"{which}_dict") == dname and getattr(layout, f"{which}_id") == i:
                    found.add(which)
    return found


def bench_vision(n_frames: int = 120, seed: int = 0) -> dict[str, float]:
    """Time raw full-frame detection against the ROI pipeline on the same rendered frames.

    Renders a descent from 12 m to 1.2 m over the default pad (640x480, nominal Pi camera v2,
    clutter, noise, slight drift and attitude wobble) with the simulated camera, then times, in
    the same run: ``raw`` = one default ``ArucoDetector`` per dictionary on the full frame
    (detection only); ``ours`` = ``PadDetector.detect`` (ROI tracking, detection *and* pose).
    Returns ms/frame, detection rates (a frame counts when the pad or a marker of it is found)
    and the speed ratio ours/raw.
    """
    if n_frames < 2:
        raise ValueError(f"n_frames = {n_frames}: must be >= 2")
    rng = np.random.default_rng(seed)
    cam = load_default_camera()
    layout = PadLayout()
    sim = SimulatedCamera(cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03, offset_jitter=3.0), seed=seed)
    frames: list[NDArray[np.uint8]] = []
    truths: list[Transform] = []
    phase = rng.uniform(0, 2 * math.pi, 4)
    for k in range(n_frames):
        s = k / (n_frames - 1)
        alt = 12.0 + (1.2 - 12.0) * s
        north = 0.6 * (1 - s) * math.cos(0.7 * k / 10 + phase[0]) + 0.05
        east = 0.6 * (1 - s) * math.sin(0.5 * k / 10 + phase[1]) - 0.04
        roll = 0.05 * math.sin(0.9 * k / 10 + phase[2])
        pitch = 0.05 * math.sin(1.1 * k / 10 + phase[3])
        T_wb = Transform.from_euler([north, east, -alt], roll, pitch, 0.2)
        f = sim.capture(T_wb, k / 30.0)
        frames.append(f.image)
        truths.append(f.T_camera_pad)

    # Interleaved on the same frames so both see the same machine load.
    raw = raw_detectors(layout)
    det = PadDetector(cam, layout)
    raw_hits: list[bool] = []
    obs: list[MarkerObservation | None] = []
    raw_s = ours_s = 0.0
    for k, im in enumerate(frames):
        t0 = time.perf_counter()
        raw_hits.append(bool(_raw_found(raw, layout, im)))
        t1 = time.perf_counter()
        obs.append(det.detect(im, k / 30.0))
        t2 = time.perf_counter()
        raw_s += t1 - t0
        ours_s += t2 - t1

    errs = [
        float(np.linalg.norm(o.T_camera_pad.t - tr.t))
        for o, tr in zip(obs, truths, strict=True)
        if o is not None and not o.ambiguous
    ]
    st = det.stats
    out = {
        "n_frames": float(n_frames),
        "raw_ms_per_frame": 1000.0 * raw_s / n_frames,
        "ours_ms_per_frame": 1000.0 * ours_s / n_frames,
        "ours/raw": ours_s / raw_s,
        "raw_detection_rate": sum(raw_hits) / n_frames,
        "ours_detection_rate": sum(o is not None for o in obs) / n_frames,
        "ours_ambiguous_rate": sum(o is not None and o.ambiguous for o in obs) / n_frames,
        "ours_full_searches": float(st.full_searches),
        "ours_roi_searches": float(st.roi_searches),
        "ours_roi_fallbacks": float(st.roi_fallbacks),
        "ours_median_position_error_m": float(np.median(errs)) if errs else float("nan"),
        "ours_max_position_error_m": float(np.max(errs)) if errs else float("nan"),
    }
    log.info("bench_vision: %s", out)
    return out
