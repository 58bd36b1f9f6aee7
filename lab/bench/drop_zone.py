"""``companion bench dropzone``: the drop-zone check (companion.vision.drop_zone) over seeded
draws of a rendered approach and descent, per scenario: a clear pad, a box on it, a person
walking into the margin, a shadow across it (not an object). Figures: false holds on a clear pad
(and under the shadow), occluders caught, time to decide (docs/drop-zone.md)."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from companion.config import DropZoneConfig
from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion.vision.detector import PadDetector
from companion.vision.drop_zone import DropZoneCheck, DropZoneVerdict
from companion.vision.pad import PadLayout
from companion_sitl.camera import SimCameraConfig, SimulatedCamera
from companion_sitl.camera_occluders import OCCLUDER_STREAM, OccluderKind, draw_occluder

log = logging.getLogger(__name__)

SCENARIOS: tuple[OccluderKind, ...] = ("none", "box", "person", "shadow")
#: the approach: a hover at the approach height, then the descent
HOVER_S = 1.5
APPROACH_HEIGHT_M = 10.0
FLOOR_HEIGHT_M = 1.5
DESCENT_M_S = 1.3
#: the landing fusion's pose when the detector has none: truth off by a drawn bias and noise
PRED_POS_BIAS_M = 0.05
PRED_POS_NOISE_M = 0.01
PRED_TILT_BIAS_RAD = math.radians(0.3)
PRED_TILT_NOISE_RAD = math.radians(0.2)
PRED_YAW_BIAS_RAD = math.radians(1.0)


def _rot(rx: float, ry: float, rz: float) -> np.ndarray:
    R, _ = cv2.Rodrigues(np.array([rx, ry, rz], dtype=float))
    return np.asarray(R, dtype=float)


def _trajectory(rng: np.random.Generator, fps: float) -> list[tuple[float, Transform]]:
    """(time, T_world_body): a hover at the approach height over the pad (drifting), then the
    descent to the floor height, wobbling in roll and pitch, yaw drawn."""
    descent_s = (APPROACH_HEIGHT_M - FLOOR_HEIGHT_M) / DESCENT_M_S
    n = round((HOVER_S + descent_s) * fps) + 1
    phase = rng.uniform(0, 2 * math.pi, 4)
    off = rng.normal(0.0, 0.3, 2)
    yaw = float(rng.uniform(-math.pi, math.pi))
    out = []
    for k in range(n):
        t = k / fps
        s = min(1.0, max(0.0, (t - HOVER_S) / descent_s))
        alt = APPROACH_HEIGHT_M + (FLOOR_HEIGHT_M - APPROACH_HEIGHT_M) * s
        north = (1 - s) * (off[0] + 0.3 * math.cos(0.7 * t + phase[0]))
        east = (1 - s) * (off[1] + 0.3 * math.sin(0.5 * t + phase[1]))
        roll = 0.05 * math.sin(2.7 * t + phase[2])
        pitch = 0.05 * math.sin(3.3 * t + phase[3])
        out.append((t, Transform.from_euler([north, east, -alt], roll, pitch, yaw)))
    return out


def run_draw(
    kind: OccluderKind, draw: int, seed: int, fps: float, config: DropZoneConfig, *, keep: bool = False
) -> dict[str, Any]:
    """One draw of one scenario: the verdicts along the trajectory and when it decided."""
    rng = np.random.default_rng([seed, draw])
    cam = load_default_camera()
    layout = PadLayout()
    traj = _trajectory(rng, fps)
    duration = traj[-1][0]
    occ = draw_occluder(
        kind,
        np.random.default_rng([seed, draw, OCCLUDER_STREAM]),
        pad_size_m=layout.pad_size_m,
        margin_m=config.margin_m,
        duration_s=duration,
    )
    sim = SimulatedCamera(
        cam, layout, SimCameraConfig(noise_std=2.0, gain_jitter=0.03, offset_jitter=3.0), seed=seed * 1000 + draw
    )
    det = PadDetector(cam, layout)
    check = DropZoneCheck(cam, layout, config)
    pb = rng.normal(0.0, PRED_POS_BIAS_M, 3)
    ab = np.array([*rng.normal(0.0, PRED_TILT_BIAS_RAD, 2), rng.normal(0.0, PRED_YAW_BIAS_RAD)])
    first_judged: float | None = None
    decided: float | None = None
    decided_as = DropZoneVerdict.UNKNOWN
    hold = False
    detected_frames = predicted_frames = 0
    frames: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    check_s = 0.0
    for t, T_wb in traj:
        T_cp = sim.T_camera_pad(T_wb)
        img = sim.expose(occ.paint(sim.render_optics(T_cp), cam, T_cp, t))
        obs = det.detect(img, t)
        # the detector's pose when the outer marker gives it (a lone inner marker's tilt is off by
        # degrees, and the check extrapolates it 1.5 m), else the landing fusion's
        if obs is not None and not obs.ambiguous and "outer" in obs.markers:
            T_use = obs.T_camera_pad
            detected_frames += 1
        else:
            dR = _rot(*(ab + rng.normal(0.0, PRED_TILT_NOISE_RAD, 3)))
            T_use = Transform(dR @ T_cp.R, T_cp.t + pb + rng.normal(0.0, PRED_POS_NOISE_M, 3))
            predicted_frames += 1
        c0 = time.perf_counter()
        if obs is not None:
            st = check.update(img, t, T_use, obs.markers, obs.corners_px)
        else:
            st = check.update(img, t, T_use)
        check_s += time.perf_counter() - c0
        if first_judged is None and st.evidence.vote is not DropZoneVerdict.UNKNOWN:
            first_judged = t
        if st.verdict in (DropZoneVerdict.OCCUPIED, DropZoneVerdict.MOTION_IN_MARGIN) and decided is None:
            decided, decided_as = t, st.verdict
            hold = True
        if keep:
            frames.append({"t": t, "verdict": st.verdict.value, **_ev(st.evidence)})
    wall = time.perf_counter() - t0
    start = occ.enters_margin_s if kind == "person" else (first_judged if first_judged is not None else 0.0)
    out: dict[str, Any] = {
        "kind": kind,
        "draw": draw,
        "hold": hold,
        "decided_s": decided,
        "decided_as": decided_as.value,
        "time_to_decide_s": (decided - start) if decided is not None and decided >= start else None,
        "held_before_it_was_there": bool(decided is not None and kind == "person" and decided < start),
        "detected_frames": detected_frames,
        "predicted_frames": predicted_frames,
        "frames": len(traj),
        "check_ms_per_frame": 1000.0 * check_s / len(traj),
        "wall_s": wall,
    }
    if keep:
        out["trace"] = frames
    return out


def _ev(ev: Any) -> dict[str, Any]:
    return {
        "vote": ev.vote.value,
        "hidden": list(ev.hidden_markers),
        "differing_m2": round(ev.differing_area_m2, 4),
        "moving_m2": round(ev.moving_area_m2, 4),
        "visible": round(ev.visible_fraction, 2),
        "ppc": round(ev.px_per_cell, 2),
        "shift_m": ev.shift_m,
    }


def bench_drop_zone(
    draws: int = 100,
    seed: int = 0,
    fps: float = 10.0,
    scenarios: Sequence[OccluderKind] = SCENARIOS,
    config: DropZoneConfig | None = None,
    only: Sequence[int] | None = None,
) -> dict[str, Any]:
    """Every scenario over ``draws`` seeded draws (the same trajectories for each scenario);
    ``only``: just these draws of the ``draws`` (to look again at the ones that failed)."""
    if draws < 1:
        raise ValueError(f"draws = {draws}: must be >= 1")
    picked = list(range(draws)) if only is None else sorted(set(only))
    if not picked or any(not 0 <= d < draws for d in picked):
        raise ValueError(f"only = {only!r}: draws must be some of 0-{draws - 1}")
    if not (math.isfinite(fps) and 1.0 <= fps <= 60.0):
        raise ValueError(f"fps = {fps!r}: must be 1-60")
    bad = [s for s in scenarios if s not in SCENARIOS]
    if bad:
        raise ValueError(f"scenario(s) {bad}: expected some of {SCENARIOS}")
    cfg = config if config is not None else DropZoneConfig(enabled=True)
    out: dict[str, Any] = {"draws": len(picked), "seed": seed, "fps": fps, "scenarios": {}}
    if only is not None:
        out["only"] = picked
    for kind in scenarios:
        runs = [run_draw(kind, d, seed, fps, cfg) for d in picked]
        holds = [r for r in runs if r["hold"]]
        ttd = [r["time_to_decide_s"] for r in runs if r["time_to_decide_s"] is not None]
        out["scenarios"][kind] = {
            "holds": len(holds),
            "hold_rate": len(holds) / len(picked),
            "early_holds": sum(r["held_before_it_was_there"] for r in runs),
            "median_time_to_decide_s": float(np.median(ttd)) if ttd else None,
            "p90_time_to_decide_s": float(np.percentile(ttd, 90)) if ttd else None,
            "max_time_to_decide_s": float(np.max(ttd)) if ttd else None,
            "check_ms_per_frame": float(np.mean([r["check_ms_per_frame"] for r in runs])),
            "missed_draws": [r["draw"] for r in runs if not r["hold"]] if kind in ("box", "person") else [],
            "held_draws": [r["draw"] for r in runs if r["hold"]] if kind in ("none", "shadow") else [],
        }
        log.info("bench dropzone %s: %d of %d held", kind, len(holds), len(picked))
    return out
