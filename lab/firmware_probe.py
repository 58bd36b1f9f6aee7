"""Measure a real autopilot SITL the way the autopilot profiles describe it.

One short flight through the normal backend (MAVSDK for PX4, pymavlink for ArduPilot) with the
firmware's ground truth on a second link: hover, a velocity step, a descent onto the ground. It
records, at 50 Hz, truth next to what the autopilot reports (LOCAL_POSITION_NED position and
velocity, its landed state) and derives the figures a profile needs:

- the autopilot's position-estimate error (about the error at take-off: the local origin is
  arbitrary), per axis, standard deviation and maximum;
- its velocity-estimate error, RMS overall and below 1 m, and the error's correlation time;
- its velocity response to a step in the offboard / GUIDED setpoint (63 % rise time);
- the land detector: seconds from the true touchdown to ON_GROUND.

``companion campaign probe --autopilot px4|ardupilot`` runs it and writes ``probe.csv`` and
``probe.json``; the autopilot profiles' figures come from it (docs/simulation.md).
"""

from __future__ import annotations

import asyncio
import csv
import json
import logging
import math
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.autopilot.interface import Autopilot
from companion.autopilot.types import LandedState
from companion.guidance.setpoint import VelocitySetpoint
from companion_firmware.truth_feed import MavlinkTruth

log = logging.getLogger(__name__)

COLUMNS = (
    "t_s",
    "phase",
    "truth_n_m",
    "truth_e_m",
    "truth_d_m",
    "truth_vn_m_s",
    "truth_ve_m_s",
    "truth_vd_m_s",
    "est_n_m",
    "est_e_m",
    "est_d_m",
    "est_vn_m_s",
    "est_ve_m_s",
    "est_vd_m_s",
    "sp_vn_m_s",
    "sp_vd_m_s",
    "landed",
    "truth_roll_rad",
    "truth_pitch_rad",
    "truth_yaw_rad",
    "est_roll_rad",
    "est_pitch_rad",
    "est_yaw_rad",
)


@dataclass
class _Recorder:
    ap: Autopilot
    truth: MavlinkTruth
    rows: list[list[Any]]
    t0: float
    phase: str = "ground"
    sp: tuple[float, float] = (0.0, 0.0)

    def sample(self) -> None:
        p = self.ap.telemetry.position_ned
        st = self.ap.telemetry.status
        att = self.ap.telemetry.attitude
        if p is None or att is None or self.truth.age_s > 0.5:
            return
        tr = self.truth
        self.rows.append(
            [
                time.monotonic() - self.t0,
                self.phase,
                tr.pn,
                tr.pe,
                tr.pd,
                tr.vn,
                tr.ve,
                tr.vd,
                p.north_m,
                p.east_m,
                p.down_m,
                p.north_m_s,
                p.east_m_s,
                p.down_m_s,
                self.sp[0],
                self.sp[1],
                st.landed.value if st is not None else "",
                tr.roll,
                tr.pitch,
                tr.yaw,
                att.roll_rad,
                att.pitch_rad,
                att.yaw_rad,
            ]
        )


async def _hold_velocity(
    rec: _Recorder, ap: Autopilot, vn: float, vd: float, seconds: float, until: Callable[[], bool] | None = None
) -> None:
    rec.sp = (vn, vd)
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        if until is not None and until():
            return
        ap.set_velocity_ned(VelocitySetpoint(vn, 0.0, vd, 0.0))
        rec.sample()
        await asyncio.sleep(0.02)


async def hover_in_offboard(ap: Autopilot, truth: MavlinkTruth, alt_m: float) -> None:
    """Arm, take off to ``alt_m`` (on truth, within 40 s), settle 2 s and enter offboard / GUIDED
    velocity on a zero setpoint (streamed first, as the autopilot requires)."""
    await ap.arm()
    await ap.takeoff(alt_m)
    t_end = time.monotonic() + 40.0
    while truth.pd > -(alt_m - 0.5):
        if time.monotonic() > t_end:
            raise TimeoutError(f"take-off to {alt_m} m not done within 40 s (truth down {truth.pd:.2f} m)")
        await asyncio.sleep(0.05)
    await asyncio.sleep(2.0)
    for _ in range(10):
        ap.set_velocity_ned(VelocitySetpoint(0.0, 0.0, 0.0, 0.0))
        await asyncio.sleep(0.05)
    await ap.start_offboard()


async def fly_probe(ap: Autopilot, truth: MavlinkTruth, alt_m: float = 6.0) -> list[list[Any]]:
    """The probe flight (the autopilot connected and healthy, truth started); returns the rows."""
    rows: list[list[Any]] = []
    rec = _Recorder(ap, truth, rows, time.monotonic())
    sampler = asyncio.create_task(_sample_forever(rec))
    try:
        rec.phase = "takeoff"
        await hover_in_offboard(ap, truth, alt_m)
        rec.phase = "hover"
        await _hold_velocity(rec, ap, 0.0, 0.0, 15.0)
        rec.phase = "step"
        await _hold_velocity(rec, ap, 2.0, 0.0, 6.0)
        rec.phase = "stop"
        await _hold_velocity(rec, ap, 0.0, 0.0, 6.0)
        rec.phase = "descent"

        def landed() -> bool:
            st = ap.telemetry.status
            return st is not None and st.landed is LandedState.ON_GROUND

        await _hold_velocity(rec, ap, 0.0, 0.7, 60.0, until=landed)
        rec.phase = "on_ground"
        await _hold_velocity(rec, ap, 0.0, 0.7, 2.0)
    finally:
        sampler.cancel()
    return rows


async def _sample_forever(rec: _Recorder) -> None:
    while True:
        if rec.phase in ("ground", "takeoff"):
            rec.sample()
        await asyncio.sleep(0.02)


def _autocorr_time(x: np.ndarray, dt: float) -> float:
    """Lag (s) where the normalised autocorrelation of ``x`` first drops below 1/e."""
    x = x - x.mean()
    if len(x) < 10 or float(np.dot(x, x)) == 0.0:
        return math.nan
    ac = np.correlate(x, x, mode="full")[len(x) - 1 :]
    ac = ac / ac[0]
    below = np.nonzero(ac < math.exp(-1.0))[0]
    return float(below[0] * dt) if len(below) else math.nan


def analyse(rows: list[list[Any]]) -> dict[str, Any]:
    """The profile figures from the probe rows (see the module doc)."""
    col = {c: i for i, c in enumerate(COLUMNS)}
    if len(rows) < 100:
        raise ValueError(f"probe: {len(rows)} samples; a probe flight gives thousands")

    def arr(name: str, sel: list[list[Any]] | None = None) -> np.ndarray:
        return np.array([float(r[col[name]]) for r in (rows if sel is None else sel)])

    air = [r for r in rows if r[col["phase"]] in ("hover", "step", "stop", "descent")]
    first_air = next(r for r in rows if r[col["phase"]] == "takeoff")
    # the local origin is arbitrary: the estimate error is taken about its value at take-off
    off = [float(first_air[col[f"est_{a}_m"]]) - float(first_air[col[f"truth_{a}_m"]]) for a in "ned"]
    pos_err = {a: arr(f"est_{a}_m", air) - arr(f"truth_{a}_m", air) - off[i] for i, a in enumerate("ned")}
    vel_err = {a: arr(f"est_v{a}_m_s", air) - arr(f"truth_v{a}_m_s", air) for a in "ned"}
    h = -arr("truth_d_m", air)
    low = h < 1.0
    t = arr("t_s", air)
    dt = float(np.median(np.diff(t))) if len(t) > 1 else 0.02
    vh = np.hypot(vel_err["n"], vel_err["e"])
    out: dict[str, Any] = {
        "samples": len(rows),
        "position_error_std_m": {a: float(np.std(pos_err[a])) for a in "ned"},
        "position_error_max_m": {a: float(np.max(np.abs(pos_err[a] - pos_err[a].mean()))) for a in "ned"},
        "position_error_correlation_s": {a: _autocorr_time(pos_err[a], dt) for a in "ne"},
        "velocity_error_rms_m_s": {a: float(np.sqrt(np.mean(vel_err[a] ** 2))) for a in "ned"},
        "velocity_error_horizontal_rms_below_1m_m_s": float(np.sqrt(np.mean(vh[low] ** 2))) if low.any() else math.nan,
        "velocity_error_horizontal_max_m_s": float(np.max(vh)),
        "velocity_error_correlation_s": {a: _autocorr_time(vel_err[a], dt) for a in "ne"},
    }
    # attitude: what the autopilot reports against truth (the landing EKF compares the two)
    for a in ("roll", "pitch", "yaw") if len(rows[0]) == len(COLUMNS) else ():
        d = np.angle(np.exp(1j * (arr(f"est_{a}_rad", air) - arr(f"truth_{a}_rad", air))))
        out[f"{a}_error_mean_deg"] = float(np.degrees(np.mean(d)))
        out[f"{a}_error_std_deg"] = float(np.degrees(np.std(d)))
    # velocity step response, on the autopilot's own velocity estimate (what its loop tracks;
    # the truth differs by the estimate error): 63 % of the 2 m/s step, and where it ends
    step = [r for r in rows if r[col["phase"]] == "step"]
    if step:
        ts, vn = arr("t_s", step), arr("est_vn_m_s", step)
        v0 = vn[0]
        hit = np.nonzero(vn - v0 >= 0.63 * (2.0 - v0))[0]
        out["velocity_step_rise_63pct_s"] = float(ts[hit[0]] - ts[0]) if len(hit) else math.nan
        out["velocity_step_final_m_s"] = float(np.mean(vn[-25:]))
        out["velocity_step_final_truth_m_s"] = float(np.mean(arr("truth_vn_m_s", step)[-25:]))
        stop = [r for r in rows if r[col["phase"]] == "stop"]
        if stop:
            vs = arr("truth_vn_m_s", stop)
            out["velocity_stop_overshoot_m_s"] = float(max(0.0, -np.min(vs)))
    # land detector: true touchdown (down within 5 cm of its final value, vertical speed ~0)
    desc = [r for r in rows if r[col["phase"]] in ("descent", "on_ground")]
    if desc:
        td, tvd, tt = arr("truth_d_m", desc), arr("truth_vd_m_s", desc), arr("t_s", desc)
        ground = td[-1]
        touch = np.nonzero((td > ground - 0.05) & (np.abs(tvd) < 0.1))[0]
        landed_idx = [i for i, r in enumerate(desc) if r[col["landed"]] == LandedState.ON_GROUND.value]
        if len(touch) and landed_idx:
            out["land_detect_s"] = float(tt[landed_idx[0]] - tt[touch[0]])
        out["descent_speed_m_s"] = float(np.median(tvd[(td < ground - 1.0)])) if (td < ground - 1.0).any() else math.nan
    return out


def write_csv(path: Path, columns: Sequence[str], rows: Iterable[Sequence[object]]) -> None:
    """A probe's rows under a header row."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(columns)
        w.writerows(rows)


def write_probe(rows: list[list[Any]], out_dir: Path) -> dict[str, Any]:
    out_dir.mkdir(parents=True, exist_ok=True)
    write_csv(out_dir / "probe.csv", COLUMNS, rows)
    figures = analyse(rows)
    (out_dir / "probe.json").write_text(json.dumps(figures, indent=2, sort_keys=True) + "\n")
    return figures


async def run_probe_async(autopilot: str, out_dir: Path, alt_m: float = 6.0) -> dict[str, Any]:
    """Start the real SITL (companion_firmware.real_vehicle), fly the probe, write probe.csv/json."""
    from companion.config import CompanionConfig
    from companion_firmware.real_vehicle import real_vehicle

    async with real_vehicle(autopilot, out_dir) as rv:
        ap = rv.backend(CompanionConfig())
        await ap.connect(timeout_s=20.0)
        try:
            t_end = time.monotonic() + 120.0
            while not ((st := ap.telemetry.status) is not None and st.healthy):
                if time.monotonic() > t_end:
                    raise TimeoutError(f"{autopilot} SITL not healthy within 120 s")
                await asyncio.sleep(0.2)
            rows = await fly_probe(ap, rv.truth, alt_m)
        finally:
            await ap.close()
    return write_probe(rows, out_dir)


def run_probe(autopilot: str, out_dir: Path, alt_m: float = 6.0) -> dict[str, Any]:
    return asyncio.run(run_probe_async(autopilot, out_dir, alt_m))
