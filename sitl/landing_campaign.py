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

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import CompanionConfig, load_config, shipped_params_path
from companion_sitl.demo import run_demo
from companion_sitl.profiles import get_profile

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
    (companion_sitl/profiles.py: a profile without wind flies the draw in still air); ``tuning``:
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


def run_landing_campaign(
    n: int,
    seed: int,
    variants: tuple[str, ...] = DEFAULT_VARIANTS,
    params: str | Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    profile: str = "ideal",
    tuning: dict[str, dict[str, Any]] | None = None,
) -> dict[str, Any]:
    base = Path(params) if params else shipped_params_path("landing_campaign.toml")
    draws = draw_scenarios(n, seed)
    pad_half = load_config(base).mission.pad.size_m / 2.0
    landings: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
    total, done = n * len(variants), 0
    for d in draws:
        for v in variants:
            r = run_demo(scenario_config(base, d, v, profile, tuning))
            dn, de = r.pad_landing_error_ne_m
            landed_on_pad = on_pad(dn, de, pad_half, r.delivered)
            landings[v].append(
                {
                    "seed": d.seed,
                    "error_m": r.pad_landing_error_m,
                    "north_m": dn,
                    "east_m": de,
                    "on_pad": landed_on_pad,
                    "delivered": r.delivered,
                    "failure": r.failure,
                    "sim_time_s": r.sim_time_s,
                    "gps_bias_m": d.gps_bias_m[:2],
                    "pad_offset_m": d.pad_offset_m,
                    "wind_m_s": d.wind_speed_m_s if get_profile(profile).has_wind else 0.0,
                }
            )
            done += 1
            if progress is not None:
                progress(v, done, total)
    summary = {v: _stats([x["error_m"] for x in ls], [x["on_pad"] for x in ls]) for v, ls in landings.items()}
    out = {"n": n, "seed": seed, "params": str(base), "summary": summary, "landings": landings}
    if profile != "ideal":
        out["profile"] = profile
    return out
