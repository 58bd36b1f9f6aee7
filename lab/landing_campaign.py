"""Monte Carlo precision landings (`companion campaign landing`).

Each landing is the short delivery of ``params/landing_campaign.toml`` (descent onto the pad
from 30 m) with a drawn GPS bias (~1.5 m per horizontal axis), a pad lying up to 1 m from its
configured position (delivery 5.2), wind and sensor noise, all from one seed. Every variant
flies the *same* draws, so fusion and GPS-only are compared on identical conditions:

- ``fusion``: EKF with GPS pose, camera (both markers) and UWB (delivery 4.2.3)
- ``gps_only``: the autopilot's GPS pose alone (the baseline, delivery Fig. 15 blue)
- failure variants (delivery 5.2, Fig. 14): ``no_camera``, ``no_uwb``, ``outer_only``, ``inner_only``
- the pad-lock policy's variants (docs/delivery-policy.md): ``sensors_failed``, ``camera_blind_5m``,
  ``pad_4m``, ``pad_4m_search``, and ``pad_missing_alternate`` (the divert, docs/divert.md)

One landing (draw, scenario, flight, score) is :mod:`companion_lab.campaign_landing`.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import load_config, shipped_params_path
from companion.units import format_cm
from companion_lab.campaign_landing import VARIANTS, CampaignLandingError, LandingTask, draw_scenarios, fly_landing
from companion_lab.campaign_pool import fly_in_pool

log = logging.getLogger(__name__)

DEFAULT_VARIANTS = ("fusion", "gps_only")
FAILURE_VARIANTS = (
    "no_camera",
    "no_uwb",
    "outer_only",
    "inner_only",
    "sensors_failed",
    "camera_blind_5m",
    "pad_4m",
    "pad_4m_search",
    "pad_missing_alternate",
)


def _outcomes(rows: list[dict[str, Any]]) -> dict[str, int]:
    """How each delivery ended under the no-release-off-the-pad policy (docs/delivery-policy.md);
    ``failed``: neither released nor brought home (no touchdown, a crash, a mission that failed)."""
    released = sum(bool(x["delivered"]) for x in rows)
    home = sum(bool(x.get("home_with_parcel")) for x in rows)
    failed = sum(not x["delivered"] and not x.get("home_with_parcel") for x in rows)
    return {"released": released, "home_with_parcel": home, "failed": failed}


def summarize(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One variant's summary: the touchdown figures over the landings that touched down on the
    pad's side of the flight (``landed`` of ``n``), and how every one of the ``n`` ended."""
    out = {**_stats([x["error_m"] for x in rows], [x["on_pad"] for x in rows]), **_outcomes(rows)}
    if any("heading_error_deg" in x for x in rows):
        out |= _heading_stats([x.get("heading_error_deg", math.nan) for x in rows])
    return out


def _heading_stats(errs: list[float]) -> dict[str, float]:
    """A pad with a heading: |true yaw - true pad heading| at touchdown (docs/pad-heading.md)."""
    a = np.array(errs, dtype=float)
    ok = a[np.isfinite(a)]
    return {
        "heading_mean_deg": float(ok.mean()) if ok.size else math.nan,
        "heading_p90_deg": float(np.percentile(ok, 90)) if ok.size else math.nan,
        "heading_max_deg": float(ok.max()) if ok.size else math.nan,
        "heading_within_3deg_pct": 100.0 * int((ok <= 3.0).sum()) / len(errs) if errs else math.nan,
    }


def _stats(errs: list[float], on_pad: list[bool]) -> dict[str, float]:
    a = np.array(errs)
    ok = a[np.isfinite(a)]
    return {
        "n": len(errs),
        "landed": int(ok.size),
        "mean_m": float(ok.mean()) if ok.size else math.nan,
        "median_m": float(np.median(ok)) if ok.size else math.nan,
        "p90_m": float(np.percentile(ok, 90)) if ok.size else math.nan,
        "p95_m": float(np.percentile(ok, 95)) if ok.size else math.nan,
        "max_m": float(ok.max()) if ok.size else math.nan,
        "on_pad_pct": 100.0 * sum(on_pad) / len(on_pad),
    }


def usable_cpus() -> int:
    """CPUs this process may run on (its affinity mask where the OS has one)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def run_landing_campaign(
    n: int,
    seed: int,
    variants: tuple[str, ...] = DEFAULT_VARIANTS,
    params: str | Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    profile: str = "ideal",
    tuning: dict[str, dict[str, Any]] | None = None,
    jobs: int = 1,
    cluster: str | None = None,
) -> dict[str, Any]:
    """Fly ``n`` draws from ``seed``, each as every variant, and summarise them.

    ``jobs`` > 1 flies the landings in that many worker processes (``companion_lab.campaign_pool``);
    the result is the same, bit for bit, as with ``jobs = 1`` (one after the other, in this process):
    each landing depends on its draw alone and the rows are put back in the campaign's order.
    ``cluster`` (a Dask scheduler's address) flies them on that cluster instead
    (``companion_lab.campaign_cluster``; the same result); a landing it could not fly because its
    workers died is a failed row, and named in the result's ``lost``.
    ``progress(variant, done, total)`` is called as each landing finishes."""
    if jobs < 1:
        raise ValueError(f"jobs = {jobs}: need at least one")
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ValueError(f"unknown variant(s) {unknown}; choose from {sorted(VARIANTS)}")
    base = Path(params) if params else shipped_params_path("landing_campaign.toml")
    draws = draw_scenarios(n, seed)
    pad_half = load_config(base).mission.pad.size_m / 2.0
    total = n * len(variants)
    tasks = [
        LandingTask(k, total, base, d, v, profile, tuning, pad_half)
        for k, (d, v) in enumerate((d, v) for d in draws for v in variants)
    ]
    t0 = time.perf_counter()

    def finished(task: LandingTask, row: dict[str, Any], done: int) -> None:
        log.info(
            "%s: %.1f s flown, error %s, %d of %d done after %.1f s",
            task.name(),
            row["sim_time_s"],
            format_cm(row["error_m"]),
            done,
            total,
            time.perf_counter() - t0,
        )
        if progress is not None:
            progress(task.variant, done, total)

    rows: list[dict[str, Any]]
    lost: list[str] = []
    if cluster is not None:
        from companion_lab.campaign_cluster import fly_on_cluster

        rows, lost = fly_on_cluster(tasks, cluster, finished)
    elif jobs == 1 or total == 1:
        rows = []
        for task in tasks:
            try:
                rows.append(fly_landing(task))
            except Exception as err:
                raise CampaignLandingError(f"{task.name()} failed: {type(err).__name__}: {err}") from err
            finished(task, rows[-1], len(rows))
    else:
        rows = fly_in_pool(tasks, min(jobs, total), finished)
    landings: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
    for task, row in zip(tasks, rows, strict=True):
        landings[task.variant].append(row)
    summary = {v: summarize(ls) for v, ls in landings.items()}
    out = {"n": n, "seed": seed, "params": str(base), "summary": summary, "landings": landings}
    if profile != "ideal":
        out["profile"] = profile
    if lost:
        out["lost"] = lost
    return out
