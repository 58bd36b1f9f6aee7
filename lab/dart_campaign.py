"""The Dart hover campaign (dart secs. 5.2-5.3, Tables 1-2) on the embedded simulator.

For every estimator, ``n`` seeded hover flights 4 m in front of the wall marker, each estimator
with the gimbal it is flown with in the paper (FCF-* fixed camera, SCF-MF-2DOF on the 2-DOF
gimbal, SCF-MF-3DOF on the 3-DOF gimbal). Run k of every estimator uses the same seed, so all
estimators meet the same wind, turbulence, IMU biases and camera noise (common random numbers).

Metric (dart eq 22): the corrected sample standard deviation of the error
epsilon = estimated position - desired position, per marker axis (x right, y up = altitude,
z distance from the wall), over the control steps after ``settle_s`` of every run, all runs
pooled. The same statistic of the *true* position error is reported beside it: the paper's
metric only sees what the estimator believes, and an estimator that drifts (e.g. the Madgwick
yaw, unobservable without a magnetometer) carries the drone away while its own error stays small.

Import as ``from companion_lab.dart_campaign import run_dart_campaign``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from companion.dart.estimators import ESTIMATORS, corrected_sample_std
from companion.dart.mission import DartMissionConfig
from companion.dart.params import controller_config
from companion_sitl.dart_sim import ESTIMATOR_GIMBAL, DartParams, DartSim, load_dart_params, shipped_dart_params

log = logging.getLogger(__name__)

AXES = ("x", "y", "z")


def resolve_estimators(names: Sequence[str] | str) -> list[str]:
    """ "all" or names (case and '_' / '-' ignored) -> canonical names in the paper's order."""
    items = [names] if isinstance(names, str) else list(names)
    out: list[str] = []
    for item in items:
        for part in str(item).split(","):
            key = part.strip().upper().replace("_", "-")
            if not key:
                continue
            if key == "ALL":
                out.extend(n for n in ESTIMATORS if n not in out)
                continue
            if key not in ESTIMATORS:
                raise ValueError(f"unknown Dart estimator {part.strip()!r}; choose 'all' or some of {list(ESTIMATORS)}")
            if key not in out:
                out.append(key)
    if not out:
        raise ValueError("no estimator given")
    return [n for n in ESTIMATORS if n in out]


def _std_cm(rows: np.ndarray) -> list[float]:
    return [100.0 * corrected_sample_std(rows[:, i].tolist()) for i in range(3)]


def run_dart_campaign(
    estimators: Sequence[str] | str = "all",
    n: int = 1,
    seed: int = 0,
    *,
    duration_s: float = 25.0,
    settle_s: float = 8.0,
    params: DartParams | str | Path | None = None,
    progress: Callable[[str, int], None] | None = None,
) -> dict[str, Any]:
    """Run ``n`` hover flights per estimator; returns

    ``{"n", "seed", "duration_s", "settle_s", "estimators": {name: {"gimbal", "std_cm" (x, y, z),
    "truth_std_cm", "truth_mean_cm", "samples", "frames", "detections", "ambiguous",
    "estimates", "max_blur_px", "wall_s"}}}``.
    """
    if isinstance(n, bool) or not isinstance(n, int) or n < 1:
        raise ValueError(f"n = {n!r}: must be an integer >= 1")
    if not duration_s > settle_s >= 0.0:
        raise ValueError(f"need duration_s > settle_s >= 0 (got {duration_s}, {settle_s})")
    names = resolve_estimators(estimators)
    loaded = params if isinstance(params, DartParams) else load_dart_params(params or shipped_dart_params())
    hover_only = {**loaded.mission.model_dump(), "approach": False, "hover_s": 0.0}
    mission: DartMissionConfig = DartMissionConfig.model_validate(hover_only)
    result: dict[str, Any] = {
        "n": n,
        "seed": seed,
        "duration_s": duration_s,
        "settle_s": settle_s,
        "estimators": {},
    }
    for name in names:
        est_rows: list[np.ndarray] = []
        truth_rows: list[np.ndarray] = []
        counts = {"frames": 0, "detections": 0, "ambiguous": 0, "estimates": 0}
        max_blur = 0.0
        t0 = time.perf_counter()
        for k in range(n):
            sim = DartSim(
                name,
                loaded.sim,
                mission,
                seed=seed + k,
                controller=controller_config(loaded.control),
                estimator_table=loaded.estimator,
            )
            sim.run_until(duration_s)
            est_rows.append(sim.errors(settle_s))
            truth_rows.append(sim.errors(settle_s, truth=True))
            for key in counts:
                counts[key] += getattr(sim.stats, key)
            max_blur = max(max_blur, sim.stats.max_blur_px)
            if progress is not None:
                progress(name, k + 1)
        est = np.vstack(est_rows)
        truth = np.vstack(truth_rows)
        result["estimators"][name] = {
            "gimbal": ESTIMATOR_GIMBAL[name].value,
            "std_cm": _std_cm(est),
            "truth_std_cm": _std_cm(truth),
            "truth_mean_cm": [100.0 * float(v) for v in truth.mean(axis=0)] if len(truth) else [float("nan")] * 3,
            "samples": len(est),
            "max_blur_px": max_blur,
            "wall_s": time.perf_counter() - t0,
            **counts,
        }
        log.info("dart campaign %s: %s", name, result["estimators"][name])
    return result


def campaign_table(result: dict[str, Any]) -> Any:
    """A rich Table of the campaign result, laid out like dart Tables 1 and 2 (cm)."""
    from rich.table import Table

    table = Table(
        title=(
            f"Dart hover at 4 m, corrected sample std of the position error (dart eq 22), cm - "
            f"{result['n']} run(s) x {result['duration_s']:g} s per estimator, seed {result['seed']}, "
            f"after {result['settle_s']:g} s"
        ),
    )
    table.add_column("Algorithm", no_wrap=True)
    table.add_column("Gimbal", no_wrap=True)
    for a in AXES:
        table.add_column(f"eps {a}", justify="right", no_wrap=True)
    for a in AXES:
        table.add_column(f"true {a}", justify="right", no_wrap=True)
    table.add_column("det.", justify="right", no_wrap=True)
    for name, r in result["estimators"].items():
        det = r["detections"] / r["frames"] if r["frames"] else float("nan")
        table.add_row(
            name,
            r["gimbal"],
            *(f"{v:.2f}" for v in r["std_cm"]),
            *(f"{v:.2f}" for v in r["truth_std_cm"]),
            f"{100 * det:.0f} %",
        )
    table.caption = (
        "eps: estimated - desired position (the paper's s_eps); true: true - desired position; "
        "det.: frames with the marker detected. x right, y up (altitude, Table 1), z distance from the wall."
    )
    return table


__all__ = ["campaign_table", "resolve_estimators", "run_dart_campaign"]
