"""``companion bench vision``: raw full-frame ArUco detection against the pad detector's ROI
pipeline, timed on the same frames rendered by the simulated camera."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np
from numpy.typing import NDArray

from companion.geometry import Transform
from companion.vision.camera import CameraModel, load_default_camera
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


def _hover_sequence(n_frames: int, seed: int) -> list[tuple[float, float, float, float, float, float]]:
    """A seeded slow approach over the pad, (north_m, east_m, alt_m, roll_rad, pitch_rad, yaw_rad)
    per frame at 30 Hz: from 15 m down to 3 m, drifting up to ~1 m off the pad, rolling and
    pitching up to ~8 deg. Above the inner marker's range only the outer marker gives the pose (4
    corners, IPPE_SQUARE), and near-fronto-parallel views like these are where its mirror pair is
    hardest to tell apart."""
    rng = np.random.default_rng(seed)
    ph = rng.uniform(0.0, 2.0 * math.pi, 6)
    out = []
    for k in range(n_frames):
        s = k / max(1, n_frames - 1)
        t = k / 30.0
        alt = 15.0 + (3.0 - 15.0) * s
        north = 0.9 * math.sin(0.31 * t + ph[0]) * (1.0 - 0.5 * s)
        east = 0.9 * math.sin(0.23 * t + ph[1]) * (1.0 - 0.5 * s)
        roll = math.radians(8.0) * math.sin(0.9 * t + ph[2])
        pitch = math.radians(8.0) * math.sin(0.7 * t + ph[3])
        yaw = 0.4 * math.sin(0.1 * t + ph[4])
        out.append((north, east, alt, roll, pitch, yaw))
    return out


def bench_ambiguity(
    n_frames: int = 300, seed: int = 0, attitude_noise_deg: float = 1.0, attitude_bias_deg: float = 0.5
) -> dict[str, Any]:
    """How many more detections are fused when the attitude resolves the IPPE mirror pair, and
    whether any fused one is wrong, on one seeded rendered sequence (:func:`_hover_sequence`).

    The same frames go through two detectors: ``before`` as the shells call it today (no
    attitude: the looking-down prior, the previous pose and the error ratio decide), ``after``
    with ``down_cam`` from the attitude an autopilot / Madgwick filter would report: truth roll
    and pitch plus a constant bias (``attitude_bias_deg``) and seeded white noise
    (``attitude_noise_deg``, 1 sigma). A detection is *fused* when it is not flagged ambiguous.
    Its error is against the renderer's truth: position of the pad in the camera frame (m), the
    camera's position in the pad frame it implies (-R^T t, m: the rotation error times the range
    shows here, this is what a wrong mirror choice costs a landing) and the rotation (deg); a
    *wrong choice* is a fused pose nearer the mirror solution than
    the truth (its rotation farther from the true one than the alternative's).
    """
    from companion.geometry.rotations import euler_to_rotmat
    from companion.vision.detector import DetectorConfig, down_in_camera, rotation_angle

    if n_frames < 2:
        raise ValueError(f"n_frames = {n_frames}: must be >= 2")
    for name, v in (("attitude_noise_deg", attitude_noise_deg), ("attitude_bias_deg", attitude_bias_deg)):
        if not (math.isfinite(v) and v >= 0.0):
            raise ValueError(f"{name} = {v!r}: must be finite and >= 0")
    rng = np.random.default_rng(seed + 1000)
    cam = load_default_camera()
    layout = PadLayout()
    sim = SimulatedCamera(cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03, offset_jitter=3.0), seed=seed)
    R_bc = sim.T_body_camera.R
    det_before = PadDetector(cam, layout)
    det_after = PadDetector(cam, layout, DetectorConfig())
    bias = math.radians(attitude_bias_deg)
    sigma = math.radians(attitude_noise_deg)
    rows: dict[str, list[tuple[bool, float, float, bool, float]]] = {"before": [], "after": []}
    nan = float("nan")
    reasons: dict[str, dict[str, int]] = {"before": {}, "after": {}}
    for k, (north, east, alt, roll, pitch, yaw) in enumerate(_hover_sequence(n_frames, seed)):
        T_wb = Transform.from_euler([north, east, -alt], roll, pitch, yaw)
        frame = sim.capture(T_wb, k / 30.0)
        truth = frame.T_camera_pad
        r_est = roll + bias + sigma * float(rng.standard_normal())
        p_est = pitch - bias + sigma * float(rng.standard_normal())
        down_cam = down_in_camera(euler_to_rotmat(r_est, p_est, yaw), R_bc)
        for name, det, kw in (("before", det_before, {}), ("after", det_after, {"down_cam": down_cam})):
            o = det.detect(frame.image, k / 30.0, **kw)
            if o is None:
                continue
            reasons[name][o.resolved_by] = reasons[name].get(o.resolved_by, 0) + 1
            pos_err = float(np.linalg.norm(o.T_camera_pad.t - truth.t))
            cam_err = float(np.linalg.norm(o.T_camera_pad.R.T @ o.T_camera_pad.t - truth.R.T @ truth.t))
            normal_err = math.degrees(rotation_angle(o.T_camera_pad.R, truth.R))
            wrong = o.alternative is not None and rotation_angle(o.T_camera_pad.R, truth.R) > rotation_angle(
                o.alternative.R, truth.R
            ) + math.radians(2.0)
            rows[name].append((not o.ambiguous, pos_err, normal_err, wrong, cam_err))
    out: dict[str, Any] = {"n_frames": n_frames, "seed": seed, "attitude_noise_deg": attitude_noise_deg,
                           "attitude_bias_deg": attitude_bias_deg}  # fmt: skip
    for name, rs in rows.items():
        fused = [r for r in rs if r[0]]
        pos = sorted(r[1] for r in fused)
        out[name] = {
            "detections": len(rs),
            "ambiguous": len(rs) - len(fused),
            "fused": len(fused),
            "fused_share": len(fused) / len(rs) if rs else float("nan"),
            "fused_wrong_choice": sum(1 for r in fused if r[3]),
            "fused_position_error_median_m": float(np.median(pos)) if pos else float("nan"),
            "fused_position_error_p95_m": float(np.percentile(pos, 95)) if pos else float("nan"),
            "fused_position_error_max_m": pos[-1] if pos else float("nan"),
            "fused_rotation_error_max_deg": max((r[2] for r in fused), default=float("nan")),
            "fused_camera_position_error_p95_m": float(np.percentile([r[4] for r in fused], 95)) if fused else nan,
            "fused_camera_position_error_max_m": max((r[4] for r in fused), default=float("nan")),
            "resolved_by": dict(sorted(reasons[name].items())),
        }
    out["extra_fused"] = out["after"]["fused"] - out["before"]["fused"]
    log.info("bench_ambiguity: %s", out)
    return out


def _summarise_records(records: Sequence[Any]) -> dict[str, Any]:
    fused = [r for r in records if r.fused]
    cam = [r.camera_position_error_m for r in fused]
    reasons: dict[str, int] = {}
    for r in records:
        reasons[r.resolved_by] = reasons.get(r.resolved_by, 0) + 1
    return {
        "detections": len(records),
        "ambiguous": len(records) - len(fused),
        "fused": len(fused),
        "fused_share": len(fused) / len(records) if records else float("nan"),
        "fused_wrong_choice": sum(1 for r in fused if r.wrong_choice),
        "fused_position_error_max_m": max((r.position_error_m for r in fused), default=float("nan")),
        "fused_camera_position_error_p95_m": float(np.percentile(cam, 95)) if cam else float("nan"),
        "fused_camera_position_error_max_m": max(cam, default=float("nan")),
        "fused_rotation_error_max_deg": max((r.rotation_error_deg for r in fused), default=float("nan")),
        "resolved_by": dict(sorted(reasons.items())),
    }


def bench_dart_ambiguity(estimator: str = "FCF-CF", seed: int = 0, duration_s: float = 10.0) -> dict[str, Any]:
    """The Dart hover (companion_sitl.dart_sim, wall marker 1.5 m ahead, seeded) flown twice:
    ``before`` the detector as the Dart calls it (no attitude), ``after`` with the attitude aid
    (:class:`~companion_sitl.dart_sim.AttitudeAid` defaults: 0.5 deg roll/pitch bias, 2 deg yaw
    bias, 1 deg noise). Same seed, so the same disturbances and noise; the flights differ only
    through what is fused. Every detection is scored against the rendered truth."""
    from companion_sitl.dart_sim import AttitudeAid, DartSim

    if not (math.isfinite(duration_s) and 0.5 <= duration_s <= 600.0):
        raise ValueError(f"duration_s = {duration_s!r}: must be in [0.5, 600]")
    out: dict[str, Any] = {"estimator": estimator, "seed": seed, "duration_s": duration_s}
    for name, aid in (("before", None), ("after", AttitudeAid())):
        sim = DartSim(estimator, seed=seed, attitude_aid=aid)
        sim.run_until(duration_s)
        out[name] = _summarise_records(sim.detection_log)
    out["extra_fused"] = out["after"]["fused"] - out["before"]["fused"]
    log.info("bench_dart_ambiguity: %s", out)
    return out


def camera_720p(cam: CameraModel) -> CameraModel:
    """The 640x480 camera's lens at 1280x720: intrinsics scaled x2 (1280x960), then the centre
    720 rows kept (a 16:9 crop of the 4:3 sensor mode, as the Pi camera v2's 720p mode)."""
    big = cam.scaled(2.0)
    crop = (big.height_px - 720) / 2.0
    return replace(big, height_px=720, cy=big.cy - crop)


def bench_vision_range(
    frames_per_height: int = 20,
    seed: int = 0,
    *,
    heights_m: Sequence[float] | None = None,
    tilts_deg: Sequence[float] = (0.0, 10.0),
    min_rate: float = 0.9,
) -> dict[str, Any]:
    """Largest height at which each marker of the nested pad is still found.

    For each resolution (the nominal Pi camera v2 at 640x480, and :func:`camera_720p`), each
    camera tilt (about the image x axis, the camera still above the pad centre) and each height,
    ``frames_per_height`` seeded frames are rendered (exposure noise, lighting jitter, clutter,
    the pad shifted up to 10 % of the footprint and yawed at random) and the markers are searched
    on the full frame (a fresh search per frame: no region of interest). A marker's range is the
    top of the first band of grid heights at which it is found in >= ``min_rate`` of the frames
    (``*_from_m`` its bottom: lower down the outer marker leaves the frame); the search of a
    configuration stops when both bands have ended. Heights: 1 m steps to 20 m, then 2 m to 60 m,
    unless given.
    """
    from companion.geometry.rotations import rot_x, rot_z

    if frames_per_height < 5:
        raise ValueError(f"frames_per_height = {frames_per_height}: must be >= 5")
    if not 0.0 < min_rate <= 1.0:
        raise ValueError(f"min_rate = {min_rate}: must be in (0, 1]")
    grid = (
        list(heights_m)
        if heights_m is not None
        else [float(h) for h in range(1, 21)] + [float(h) for h in range(22, 61, 2)]
    )
    if not grid or any(not (math.isfinite(h) and h > 0) for h in grid) or sorted(grid) != grid:
        raise ValueError(f"heights_m = {grid!r}: must be increasing positive heights")
    base = load_default_camera()
    layout = PadLayout()
    results: list[dict[str, Any]] = []
    for cam_name, cam in (("640x480", base), ("1280x720", camera_720p(base))):
        sim = SimulatedCamera(
            cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03, offset_jitter=3.0), seed=seed
        )
        fov_half = math.atan2(0.5 * cam.height_px, cam.fy)
        for tilt_deg in tilts_deg:
            rng = np.random.default_rng([seed, round(tilt_deg * 10), cam.width_px])
            det = PadDetector(cam, layout)
            passed: dict[str, float | None] = dict.fromkeys(MARKERS)
            lowest: dict[str, float | None] = dict.fromkeys(MARKERS)
            broken = dict.fromkeys(MARKERS, False)
            rates: list[dict[str, float]] = []
            misses = 0
            for h in grid:
                hits = dict.fromkeys(MARKERS, 0)
                for _ in range(frames_per_height):
                    foot = h * math.tan(fov_half)
                    dx, dy = rng.uniform(-0.1, 0.1, 2) * foot
                    yaw = rng.uniform(-math.pi, math.pi)
                    # camera at (dx, dy, h) above the pad looking down, tilted about its x axis
                    R_pc = rot_z(yaw) @ np.diag([1.0, -1.0, -1.0]) @ rot_x(math.radians(tilt_deg))
                    T_cp = Transform(R_pc, np.array([dx, dy, h])).inverse()
                    det.reset()
                    found, _ = det.detect_markers(sim.render(T_cp))
                    for m in MARKERS:
                        hits[m] += m in found
                row = {"height_m": h} | {m: hits[m] / frames_per_height for m in MARKERS}
                rates.append(row)
                ok = {m: row[m] >= min_rate for m in MARKERS}
                for m in MARKERS:
                    if ok[m] and not broken[m]:
                        passed[m] = h
                        lowest[m] = h if lowest[m] is None else lowest[m]
                    elif not ok[m] and passed[m] is not None:
                        broken[m] = True  # the band of heights where it is found has ended
                misses = misses + 1 if all(broken.values()) or not any(ok.values()) else 0
                if all(broken.values()) or (misses >= 2 and any(p is not None for p in passed.values())):
                    break
            results.append(
                {
                    "resolution": cam_name,
                    "tilt_deg": tilt_deg,
                    "outer_range_m": passed["outer"],
                    "inner_range_m": passed["inner"],
                    "outer_from_m": lowest["outer"],
                    "inner_from_m": lowest["inner"],
                    "detection_rates": rates,
                }
            )
    out = {
        "frames_per_height": frames_per_height,
        "seed": seed,
        "min_rate": min_rate,
        "outer_size_m": layout.outer_size_m,
        "inner_size_m": layout.inner_size_m,
        "runs": results,
    }
    log.info(
        "bench_vision_range: %s",
        [(r["resolution"], r["tilt_deg"], r["outer_range_m"], r["inner_range_m"]) for r in results],
    )
    return out


# the descent takes n_frames / 30 s (4 s by default): clouds every second, to see steps in it
BENCH_EXPOSURE_STEPS_S = 1.0


def bench_vision_conditions(n_frames: int = 120, seed: int = 0, names: Sequence[str] | None = None) -> dict[str, Any]:
    """Detection rate and pose error of the pad detector per real-camera condition
    (companion_sitl.camera_conditions at params/camera_real.toml's levels, clouds every
    BENCH_EXPOSURE_STEPS_S), on the rendered descent of :func:`bench_vision` (12 m to 1.2 m in
    ``n_frames`` frames at 30 fps, drifting and wobbling): the same poses for every condition, a
    fresh detector each, the error against the renderer's truth. ``all`` is every condition
    together. The motion effects take the pad centre's image velocity between frames."""
    from companion_sitl.camera_conditions import CameraConditions, condition_tables, pad_velocity_px_s
    from companion_sitl.params import SimCameraConditionsConfig

    if n_frames < 2:
        raise ValueError(f"n_frames = {n_frames}: must be >= 2")
    table: dict[str, dict[str, Any]] = {"none": {}, **condition_tables()}
    table.pop("late_dropped")  # the driver's timing: a flight's, not a frame's
    for t in table.values():
        if "exposure_steps_s" in t:
            t["exposure_steps_s"] = BENCH_EXPOSURE_STEPS_S
    chosen = list(table) if names is None else list(names)
    unknown = [n for n in chosen if n not in table]
    if unknown:
        raise ValueError(f"condition(s) {unknown}: expected some of {', '.join(table)}")
    cam = load_default_camera()
    layout = PadLayout()
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 2 * math.pi, 4)
    poses = []
    for k in range(n_frames):  # the descent of bench_vision
        s = k / (n_frames - 1)
        alt = 12.0 + (1.2 - 12.0) * s
        north = 0.6 * (1 - s) * math.cos(0.7 * k / 10 + phase[0]) + 0.05
        east = 0.6 * (1 - s) * math.sin(0.5 * k / 10 + phase[1]) - 0.04
        roll = 0.05 * math.sin(0.9 * k / 10 + phase[2])
        pitch = 0.05 * math.sin(1.1 * k / 10 + phase[3])
        poses.append(Transform.from_euler([north, east, -alt], roll, pitch, 0.2))
    out: dict[str, Any] = {"n_frames": n_frames, "seed": seed, "conditions": {}}
    for name in chosen:
        sim = SimulatedCamera(
            cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03, offset_jitter=3.0), seed=seed
        )
        cond = CameraConditions(SimCameraConditionsConfig(**table[name]), seed)
        det = PadDetector(cam, layout)
        prev_t: NDArray[np.float64] | None = None
        found = fused = 0
        errs: list[float] = []
        t0 = time.perf_counter()
        for k, T_wb in enumerate(poses):
            T_cp = sim.T_camera_pad(T_wb)
            v = pad_velocity_px_s(cam.fx, cam.fy, cam.cx, cam.cy, prev_t, T_cp.t, 1.0 / 30.0)
            prev_t = T_cp.t.copy()
            image = cond.photometric(sim.expose(cond.motion(sim.render_optics(T_cp), v)), k / 30.0)
            o = det.detect(image, k / 30.0)
            if o is None:
                continue
            found += 1
            if not o.ambiguous:
                fused += 1
                errs.append(float(np.linalg.norm(o.T_camera_pad.t - T_cp.t)))
        out["conditions"][name] = {
            "detection_rate": found / n_frames,
            "fused_rate": fused / n_frames,
            "median_position_error_m": float(np.median(errs)) if errs else float("nan"),
            "p90_position_error_m": float(np.percentile(errs, 90)) if errs else float("nan"),
            "max_position_error_m": float(np.max(errs)) if errs else float("nan"),
            "ms_per_frame": 1000.0 * (time.perf_counter() - t0) / n_frames,
        }
    return out
