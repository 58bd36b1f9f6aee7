"""Monte Carlo precision landings (`companion campaign landing`).

Each landing is the short delivery of ``params/landing_campaign.toml`` (descent onto the pad
from 30 m) with a drawn GPS bias (~1.5 m per horizontal axis), a pad lying up to 1 m from its
configured position (delivery 5.2), wind and sensor noise, all from one seed. Every variant
flies the *same* draws, so fusion and GPS-only are compared on identical conditions:

- ``fusion``: EKF with GPS pose, camera (both markers) and UWB (delivery 4.2.3)
- ``gps_only``: the autopilot's GPS pose alone (the baseline, delivery Fig. 15 blue)
- failure variants (delivery 5.2, Fig. 14): ``no_camera``, ``no_uwb``, ``outer_only``, ``inner_only``

A landing is *on the pad* when the true touchdown point lies inside the 1 x 1 m square.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import CompanionConfig, load_config, shipped_params_path
from companion.units import format_cm
from companion_lab.demo import run_demo
from companion_sitl.profiles import get_profile

log = logging.getLogger(__name__)

VARIANTS: dict[str, dict[str, Any]] = {
    "fusion": {},
    "gps_only": {"fusion": False},
    "no_camera": {"use_camera": False},
    "no_uwb": {"use_uwb": False},
    "outer_only": {"markers": "outer"},
    "inner_only": {"markers": "inner"},
}
DEFAULT_VARIANTS = ("fusion", "gps_only")
FAILURE_VARIANTS = ("no_camera", "no_uwb", "outer_only", "inner_only")


@dataclass(frozen=True)
class Draw:
    seed: int
    gps_bias_m: tuple[float, float, float]
    pad_offset_m: tuple[float, float]
    wind_speed_m_s: float
    wind_from_deg: float


def draw_scenarios(
    n: int, seed: int, gps_sigma_m: float = 1.5, pad_offset_max_m: float = 1.0, wind_max_m_s: float = 5.0
) -> list[Draw]:
    if n < 1:
        raise ValueError(f"n = {n}: need at least one landing")
    rng = np.random.default_rng(seed)
    out = []
    for k in range(n):
        b = np.clip(rng.normal(0.0, gps_sigma_m, 2), -3 * gps_sigma_m, 3 * gps_sigma_m)
        r, th = pad_offset_max_m * math.sqrt(rng.uniform()), rng.uniform(0, 2 * math.pi)
        out.append(
            Draw(
                seed=seed * 1000 + k,
                gps_bias_m=(float(b[0]), float(b[1]), float(rng.normal(0.0, 0.5))),
                pad_offset_m=(r * math.cos(th), r * math.sin(th)),
                wind_speed_m_s=float(rng.uniform(0.0, wind_max_m_s)),
                wind_from_deg=float(rng.uniform(0.0, 360.0)),
            )
        )
    return out


def scenario_config(
    base_file: Path, d: Draw, variant: str, profile: str = "ideal", tuning: dict[str, dict[str, Any]] | None = None
) -> CompanionConfig:
    """The draw ``d`` flown as ``variant`` on the embedded simulator with the autopilot ``profile``
    (sitl/profiles.py: a profile without wind flies the draw in still air); ``tuning``:
    config overrides by table (a firmware's landing tuning, see real_campaign.firmware_tuning)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {sorted(VARIANTS)}")
    sim = {
        "seed": d.seed,
        "gps_bias_m": list(d.gps_bias_m),
        "pad_offset_m": list(d.pad_offset_m),
        "wind_speed_m_s": d.wind_speed_m_s,
        "wind_from_deg": d.wind_from_deg,
    }
    if profile != "ideal":
        sim["profile"] = profile
    tuning = tuning or {}
    landing = {**tuning.get("landing", {}), **VARIANTS[variant]}
    overrides = {**tuning, "sim": sim, "landing": landing}
    return load_config(base_file, overrides=overrides)


def renders_camera(variant: str) -> bool:
    """The variant's landings render and search camera images (most of a landing's time)."""
    opts = VARIANTS[variant]
    return bool(opts.get("fusion", True) and opts.get("use_camera", True))


def on_pad(north_m: float, east_m: float, half_size_m: float, delivered: bool) -> bool:
    """The true touchdown lies inside the square pad (and the parcel was delivered there)."""
    return bool(math.isfinite(north_m) and abs(north_m) <= half_size_m and abs(east_m) <= half_size_m and delivered)


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


@dataclass(frozen=True)
class LandingTask:
    """One landing of a campaign, all a worker process needs to fly it: the ``index``-th of the
    campaign's ``total`` (draw-major, variants in their order), flown from ``base`` (the scenario
    parameters) with the draw, variant, profile and tuning; ``pad_half_m`` scores it."""

    index: int
    total: int
    base: Path
    draw: Draw
    variant: str
    profile: str
    tuning: dict[str, dict[str, Any]] | None
    pad_half_m: float

    def name(self) -> str:
        return f"landing {self.index + 1} of {self.total} (seed {self.draw.seed}, {self.variant})"


class CampaignLandingError(RuntimeError):
    """A landing of the campaign failed (raised, or its worker process died); the message names
    the landing: its index, the draw's seed and the variant."""


def fly_landing(task: LandingTask) -> dict[str, Any]:
    """Fly one landing on the embedded simulator and score it: the campaign JSON's row.

    Everything the landing draws comes from ``task.draw.seed`` (the vehicle, camera and UWB seed
    their own generators from it) and nothing it computes outlives it, except caches keyed by what
    they hold (the camera's lens maps per model): the same row in any process, after any other
    landings."""
    d = task.draw
    r = run_demo(scenario_config(task.base, d, task.variant, task.profile, task.tuning))
    dn, de = r.pad_landing_error_ne_m
    return {
        "seed": d.seed,
        "error_m": r.pad_landing_error_m,
        "north_m": dn,
        "east_m": de,
        "on_pad": on_pad(dn, de, task.pad_half_m, r.delivered),
        "delivered": r.delivered,
        "failure": r.failure,
        "sim_time_s": r.sim_time_s,
        "gps_bias_m": d.gps_bias_m[:2],
        "pad_offset_m": d.pad_offset_m,
        "wind_m_s": d.wind_speed_m_s if get_profile(task.profile).has_wind else 0.0,
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
) -> dict[str, Any]:
    """Fly ``n`` draws from ``seed``, each as every variant, and summarise them.

    ``jobs`` > 1 flies the landings in that many worker processes (``companion_lab.campaign_pool``);
    the result is the same, bit for bit, as with ``jobs = 1`` (one after the other, in this process):
    each landing depends on its draw alone and the rows are put back in the campaign's order.
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
    if jobs == 1 or total == 1:
        rows = []
        for task in tasks:
            try:
                rows.append(fly_landing(task))
            except Exception as err:
                raise CampaignLandingError(f"{task.name()} failed: {type(err).__name__}: {err}") from err
            finished(task, rows[-1], len(rows))
    else:
        from companion_lab.campaign_pool import fly_in_pool

        rows = fly_in_pool(tasks, min(jobs, total), finished)
    landings: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
    for task, row in zip(tasks, rows, strict=True):
        landings[task.variant].append(row)
    summary = {v: _stats([x["error_m"] for x in ls], [x["on_pad"] for x in ls]) for v, ls in landings.items()}
    out = {"n": n, "seed": seed, "params": str(base), "summary": summary, "landings": landings}
    if profile != "ideal":
        out["profile"] = profile
    return out
