"""One landing of a landing campaign: the variants, the random draw, its scenario, and the task a
worker flies and scores (:func:`fly_landing`), the same row in any process.

A landing is *on the pad* when the true touchdown point lies inside the 1 x 1 m square.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.config import PadConfig
from companion_lab.demo import run_demo
from companion_sitl.camera_conditions import CONDITION_KEYS, condition_tables
from companion_sitl.params import SimConfig, SimulatedConfig, load_simulated_config
from companion_sitl.profiles import get_profile

# the unknown camera latencies of the clock variants (docs/clock.md), and their landing.camera_time
LATENCY_MS = (0, 30, 80)
LATENCY_MODES = {"": "configured", "_driver": "driver", "_measured": "measured"}
CLOCK_VARIANTS = tuple(f"latency_{ms}ms{tail}" for ms in LATENCY_MS for tail in LATENCY_MODES)

# [landing] overrides of each variant. gps_only is the paper's baseline: it has no pad lock, so it
# opts out of the no-release-off-the-pad policy explicitly (docs/delivery-policy.md) and is scored
# where it lands, as before.
VARIANTS: dict[str, dict[str, Any]] = {
    "fusion": {},
    "gps_only": {"fusion": False, "policy": {"require_pad_lock": False}},
    "no_camera": {"use_camera": False},
    "no_uwb": {"use_uwb": False},
    "outer_only": {"markers": "outer"},
    "inner_only": {"markers": "inner"},
    "sensors_failed": {},
    "camera_blind_5m": {},
    "pad_4m": {},
    "pad_4m_search": {"use_uwb": False, "policy": {"search_height_m": 5.0}},
    "pad_missing_alternate": {"policy": {"fallback": "alternate"}},
    "pad_heading": {},
    "winch": {},
    # a real board camera's images ([sim.camera], companion_sitl.camera_conditions): one condition
    # each at params/camera_real.toml's level, and camera_real with all of them
    **{f"camera_{name}": {} for name in CONDITION_KEYS},
    "camera_real": {},
    # one clock (docs/clock.md): frames LATENCY_MS later than landing.camera_latency_s says, the
    # configured latency (before), the driver's capture stamp, the latency measured from it (after)
    **{f"latency_{ms}ms{tail}": {"camera_time": mode} for ms in LATENCY_MS for tail, mode in LATENCY_MODES.items()},
    # GNSS lost near the pad (docs/external-nav.md; the arducopter-sitl and px4-sih profiles): with external
    # navigation, and GPS-only beside it on the same draws
    **{f"gnss_lost_{h}m": {} for h in (10, 3)},
    **{f"gnss_lost_{h}m_gps_only": {"fusion": False, "policy": {"require_pad_lock": False}} for h in (10, 3)},
    # a pad on a moving vehicle (docs/moving-pad.md): the EKF's pad-velocity states on
    **{f"moving_pad_{v}ms": {"moving_pad": {"enabled": True}} for v in (1, 2, 3)},
}

# [sim] overrides (failures of the sensors fitted and configured, in flight)
SIM_VARIANTS: dict[str, dict[str, Any]] = {
    "sensors_failed": {"camera_fails_below_m": 10000.0, "uwb_fails_below_m": 10000.0},
    "camera_blind_5m": {"camera_fails_below_m": 5.0},
    # no UWB and a camera that detects the pad only below 6 m: a pad 4 m away is outside its view on
    # the way down and at the approach height; only the search (at 5 m) can find it
    "pad_4m_search": {"camera_range_m": 6.0},
    # the first pad is not there; the real one (camera target, UWB anchors) is at the alternate
    "pad_missing_alternate": {"pad_at_alternate": True},
    **{f"camera_{name}": {"camera": table} for name, table in condition_tables().items() if name != "all"},
    "camera_real": {"camera": condition_tables()["all"]},
    **{
        f"latency_{ms}ms{tail}": {"camera": {"unknown_latency_s": ms / 1e3, "driver_stamp": mode != "configured"}}
        for ms in LATENCY_MS
        for tail, mode in LATENCY_MODES.items()
    },
    **{f"gnss_lost_{h}m{k}": {"gnss_lost_below_m": float(h)} for h in (10, 3) for k in ("", "_gps_only")},
}
# the variants that fly with [external_nav] on (docs/external-nav.md)
EXTERNAL_NAV_VARIANTS = ("gnss_lost_10m", "gnss_lost_3m")

# [mission] overrides: the alternate pad, 25 m north of params/landing_campaign.toml's pad (beyond
# what the search around the first pad sees: 6 m radius, the camera's view from 8 m, UWB's 10 m)
MISSION_VARIANTS: dict[str, dict[str, Any]] = {
    "pad_missing_alternate": {"alternate_pad": {"lat_deg": -19.868667, "lon_deg": -43.9637141, "alt_amsl_m": 850.0}},
}

# moving_pad_<v>ms: the pad drives off at v m/s from MOVING_PAD_START_S (the approach: the landing
# starts at ~39 s on params/landing_campaign.toml's path), straight, on a course drawn per draw
MOVING_PAD_START_S = 34.0
MOVING_PAD_VARIANTS = {f"moving_pad_{v}ms": float(v) for v in (1, 2, 3)}


def moving_pad_course_deg(seed: int) -> float:
    """The moving_pad variants' course for a draw's seed (its own generator: the other draws
    of the campaign are unchanged)."""
    return float(np.random.default_rng([seed, 41]).uniform(0.0, 360.0))


# pad_heading: a dock with a heading drawn per draw (uniform over the circle), placed up to
# PAD_HEADING_PLACED_DEG off its configured heading (the camera's measured heading must win)
PAD_HEADING_PLACED_DEG = 5.0
HEADING_VARIANTS = ("pad_heading",)


def pad_heading_draw(seed: int) -> tuple[float, float]:
    """The pad_heading variant's (configured heading, true - configured) in degrees for a draw's
    seed: from their own generator, so the other draws of the campaign are unchanged."""
    rng = np.random.default_rng([seed, 37])
    return float(rng.uniform(-180.0, 180.0)), float(rng.uniform(-PAD_HEADING_PLACED_DEG, PAD_HEADING_PLACED_DEG))


def with_pad_heading(config: SimulatedConfig, seed: int) -> SimulatedConfig:
    """``config`` with the pad_heading variant's draw for ``seed``: the pad's configured heading and
    the true pad's rotation from it (the real-firmware campaign, whose configuration is per variant)."""
    heading_deg, placed_deg = pad_heading_draw(seed)
    pad = PadConfig.model_validate({**config.mission.pad.model_dump(), "heading_deg": heading_deg})
    sim = SimConfig.model_validate({**config.sim.model_dump(), "pad_heading_offset_deg": placed_deg})
    return config.model_copy(update={"mission": config.mission.model_copy(update={"pad": pad}), "sim": sim})


# winch: the delivery lowers the parcel from a hover (docs/winch.md) on the simulated winch; scored
# where the parcel first touches the ground. The hover is corrected for the parcel's drift by its
# drag over g (sim.winch.parcel_drag_1_s's default, 0.3 1/s: 0.0306 s/m)
WINCH_VARIANTS = ("winch",)
WINCH_DRIFT_S_M = 0.3 / 9.80665


# the pad lies this far from its configured place (in the draw's direction): outside the camera's
# view at the approach height
PAD_MOVED_M = {"pad_4m": 4.0, "pad_4m_search": 4.0}


@dataclass(frozen=True)
class Draw:
    seed: int
    gps_bias_m: tuple[float, float, float]
    pad_offset_m: tuple[float, float]
    wind_speed_m_s: float
    wind_from_deg: float

    def sim_overrides(self) -> dict[str, Any]:
        """The draw as [sim] overrides: its seed, GPS bias, pad displacement and wind."""
        return {
            "seed": self.seed,
            "gps_bias_m": list(self.gps_bias_m),
            "pad_offset_m": list(self.pad_offset_m),
            "wind_speed_m_s": self.wind_speed_m_s,
            "wind_from_deg": self.wind_from_deg,
        }


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
) -> SimulatedConfig:
    """The draw ``d`` flown as ``variant`` on the embedded simulator with the autopilot ``profile``
    (sitl/profiles.py: a profile without wind flies the draw in still air); ``tuning``:
    config overrides by table (a firmware's landing tuning, see real_campaign.firmware_tuning)."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {sorted(VARIANTS)}")
    sim = d.sim_overrides()
    if profile != "ideal":
        sim["profile"] = profile
    sim.update(tuning.get("sim", {}) if tuning else {})  # e.g. profile_weather (docs/weather.md)
    sim.update(SIM_VARIANTS.get(variant, {}))
    if variant in PAD_MOVED_M:
        n, e = d.pad_offset_m
        r = math.hypot(n, e)
        u = (n / r, e / r) if r > 0 else (1.0, 0.0)
        sim["pad_offset_m"] = [PAD_MOVED_M[variant] * u[0], PAD_MOVED_M[variant] * u[1]]
    tuning = tuning or {}
    landing = {**tuning.get("landing", {}), **VARIANTS[variant]}
    # a copy of every table changed below: ``tuning`` is shared by all the campaign's landings, and
    # a variant's change to it would carry over into the next landing's configuration
    mission = {**tuning.get("mission", {}), **MISSION_VARIANTS.get(variant, {})}
    overrides = {**tuning, "sim": sim, "landing": landing, "mission": mission}
    if variant in EXTERNAL_NAV_VARIANTS:
        overrides["external_nav"] = {"enabled": True}
    if variant in WINCH_VARIANTS:
        mission["delivery"] = "winch"
        sim["winch"] = {"fitted": True}
        overrides["winch"] = {**tuning.get("winch", {}), "wind_drift_s_m": WINCH_DRIFT_S_M}
    if variant in MOVING_PAD_VARIANTS:
        sim["pad_motion"] = {
            "speed_m_s": MOVING_PAD_VARIANTS[variant],
            "course_deg": moving_pad_course_deg(d.seed),
            "start_s": MOVING_PAD_START_S,
        }
    if variant in HEADING_VARIANTS:
        heading_deg, placed_deg = pad_heading_draw(d.seed)
        mission["pad"] = {**mission.get("pad", {}), "heading_deg": heading_deg}
        sim["pad_heading_offset_deg"] = placed_deg
    return load_simulated_config(base_file, overrides=overrides)


def renders_camera(variant: str) -> bool:
    """The variant's landings render and search camera images (most of a landing's time)."""
    opts = VARIANTS[variant]
    return bool(opts.get("fusion", True) and opts.get("use_camera", True))


def on_pad(north_m: float, east_m: float, half_size_m: float, delivered: bool) -> bool:
    """The true touchdown lies inside the square pad (and the parcel was delivered there)."""
    return bool(math.isfinite(north_m) and abs(north_m) <= half_size_m and abs(east_m) <= half_size_m and delivered)


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


def unflown_row(task: LandingTask, failure: str) -> dict[str, Any]:
    """The row of a landing that could not be flown (every worker that tried it died): a failed
    landing with no touchdown, counted like any other (``failure`` says why)."""
    d = task.draw
    return {
        "seed": d.seed,
        "error_m": math.nan,
        "north_m": math.nan,
        "east_m": math.nan,
        "on_pad": False,
        "delivered": False,
        "home_with_parcel": False,
        "pad_tries": 0,
        "failure": failure,
        "sim_time_s": 0.0,
        "gps_bias_m": d.gps_bias_m[:2],
        "pad_offset_m": d.pad_offset_m,
        "wind_m_s": d.wind_speed_m_s if get_profile(task.profile).has_wind else 0.0,
    }


def fly_landing(task: LandingTask) -> dict[str, Any]:
    """Fly one landing on the embedded simulator and score it: the campaign JSON's row.

    Everything the landing draws comes from ``task.draw.seed`` (the vehicle, camera and UWB seed
    their own generators from it) and nothing it computes outlives it, except caches keyed by what
    they hold (the camera's lens maps per model): the same row in any process, after any other
    landings."""
    d = task.draw
    r = run_demo(scenario_config(task.base, d, task.variant, task.profile, task.tuning))
    winch = task.variant in WINCH_VARIANTS
    # a winch delivery is scored where the parcel touched the ground, not the vehicle
    dn, de = r.parcel_touchdown_ne_m if winch else r.pad_landing_error_ne_m
    return (
        {
            "seed": d.seed,
            "error_m": math.hypot(dn, de),
            "north_m": dn,
            "east_m": de,
            "on_pad": on_pad(dn, de, task.pad_half_m, r.delivered),
            "delivered": r.delivered,
            "home_with_parcel": r.home_with_parcel,
            "pad_tries": r.pad_tries,
            "failure": r.failure,
            "sim_time_s": r.sim_time_s,
            "gps_bias_m": d.gps_bias_m[:2],
            "pad_offset_m": d.pad_offset_m,
            "wind_m_s": d.wind_speed_m_s if get_profile(task.profile).has_wind else 0.0,
        }
        | ({"diverted": diverted(r.events)} if task.variant in MISSION_VARIANTS else {})
        | ({"heading_error_deg": r.pad_heading_error_deg} if task.variant in HEADING_VARIANTS else {})
    )


def diverted(events: list[tuple[float, str, str, str]]) -> bool:
    """The flight entered the divert to the alternate pad (a ``phase divert`` event)."""
    return any(kind == "phase" and detail == "divert" for _, kind, _, detail in events)
