"""Precision landings on the real autopilot SITL (``companion campaign landing --autopilot``) and
the sim-to-real check against the embedded simulator's profile (``companion campaign parity``).

The draws are the embedded campaign's (:func:`draw_scenarios`, same seed, same numbers). A real
SITL cannot bias its GPS, so each draw's GPS bias joins its pad displacement: the pad lies
``pad_offset + gps_bias`` (north, east) from where the parameters put it, which is the same
geometry for everything that lands (the vehicle arrives on its GPS at the configured pad; the
landing sensors see the true one). The pad is placed relative to where the vehicle starts (the
firmware sets home at arming), so one ArduCopter SITL flies every landing of a campaign (it
needs ~41 s of simulated time to become armable, ~4 s at its boot speed-up); PX4 SIH is
restarted from clean parameters for each (~6 s).
Wind: ArduCopter's SIM_WIND_SPD / SIM_WIND_DIR from the draw (SIM_WIND_TURB = 0); PX4 SIH v1.16
has no wind model, so its landings fly in still air (the ``px4-sih`` profile drops wind too).
``weather=True`` (ArduCopter only) adds the embedded campaign's gusts, GPS error and sensor noise
(lab/real_weather.py).

Landings are scored on the firmware's truth (HIL_STATE_QUATERNION / SIM_STATE) at the first
ON_GROUND of the landing phase, as the embedded campaign scores its truth.

The GNSS-lost variants (GNSS_VARIANTS, docs/external-nav.md) fly each landing on a fresh SITL
booted with the firmware's external-navigation parameters, and cut its GPS (lab/gnss_cut.py:
SIM_GPS1_ENABLE = 0 on ArduCopter, ``sensor_gps_sim stop`` on PX4 SIH) when the true vehicle first
comes down through the variant's [sim] gnss_lost_below_m within gnss_lost_within_m of the true pad.
Their ``*_gps_only`` twins fly the same draw and cut GPS-only with the no-release-off-the-pad policy
on: the autopilot's own failsafe answers the loss and the companion never releases (no pad lock
is possible without pad sensors), where the embedded campaign scores the paper's opt-out baseline.
"""

from __future__ import annotations

import asyncio
import contextlib
import csv
import json
import logging
import math
import os
import platform
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel

from companion.config import PadConfig, shipped_params_path
from companion.delivery.planning import pad_position_ned
from companion.flightlog.recorder import FlightRecorder
from companion.geometry.earth import GeoPoint
from companion.units import format_cm
from companion_firmware.real_vehicle import REAL_AUTOPILOTS, RealVehicle, real_vehicle
from companion_firmware.truth_harness import LANDING_TRACE_FIELDS, fly_on_truth
from companion_lab.campaign_landing import (
    EXTERNAL_NAV_VARIANTS,
    HEADING_VARIANTS,
    SIM_VARIANTS,
    VARIANTS,
    WINCH_VARIANTS,
    Draw,
    draw_scenarios,
    on_pad,
    pad_heading_draw,
    with_pad_heading,
)
from companion_lab.gnss_cut import (
    GPS_ENABLE_PARAM,
    cut_gps_when_low,
    gnss_loss_boot_params,
    loss_flight,
    modes_after,
    sitl_gps_cut,
)
from companion_lab.landing_campaign import run_landing_campaign, summarize
from companion_lab.real_weather import FirmwareWeather, WeatherDriver, WeatherError, WeatherProcess, static_params
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)

PROFILE_FOR = {"px4": "px4-sih", "ardupilot": "arducopter-sitl"}
FIRMWARE_OF_PROFILE = {v: k for k, v in PROFILE_FOR.items()}
# the companion's landing settings shipped for each firmware (params/px4_sih_quad.toml,
# params/ardupilot_quad.toml): the same in the real and in the profile campaign
FIRMWARE_PARAMS = {"px4": "px4_sih_quad.toml", "ardupilot": "ardupilot_quad.toml"}
FIRMWARE_TUNING_KEYS = {
    "landing": (
        "ekf",  # the whole [landing.ekf] table
        "ekf_velocity_bias_tau_s",
        "ekf_level_pad",
    ),
    "mission": (
        "land_speed_m_s",
        "descent",  # the whole [mission.descent] table
        "velocity_bias_tau_s",
        "velocity_bias_source",
        "autopilot_accel_xy_m_s2",
        "autopilot_accel_z_m_s2",
    ),
}
LANDING_TIMEOUT_S = 300.0
MAV_CMD_DO_SET_HOME = 179
# the variants that cut the GPS in the descent ([sim] gnss_lost_below_m), flown one SITL each
GNSS_VARIANTS = tuple(v for v in VARIANTS if SIM_VARIANTS.get(v, {}).get("gnss_lost_below_m", 0.0) > 0.0)


def firmware_tuning(autopilot: str) -> dict[str, dict[str, Any]]:
    """The landing tuning (fusion and final descent) the shipped parameters of ``autopilot``
    carry (see FIRMWARE_PARAMS), as config overrides by table."""
    cfg = load_simulated_config(shipped_params_path(FIRMWARE_PARAMS[autopilot]))

    def value(table: str, key: str) -> Any:
        v = getattr(getattr(cfg, table), key)
        return v.model_dump() if isinstance(v, BaseModel) else v

    return {table: {k: value(table, k) for k in keys} for table, keys in FIRMWARE_TUNING_KEYS.items()}


def real_pad_displacement(d: Draw) -> tuple[float, float]:
    """Where the true pad lies from the configured one on a SITL without GPS bias (module doc)."""
    return d.pad_offset_m[0] + d.gps_bias_m[0], d.pad_offset_m[1] + d.gps_bias_m[1]


def real_config(base: Path, autopilot: str, variant: str) -> SimulatedConfig:
    """The campaign parameters for a real SITL: the pad as north/east offsets from home (where it
    lies from ``[sim.home]`` in ``base``), the firmware's landing tuning, the variant."""
    if variant not in VARIANTS:
        raise ValueError(f"unknown variant {variant!r}; choose from {sorted(VARIANTS)}")
    if autopilot not in REAL_AUTOPILOTS:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {REAL_AUTOPILOTS}")
    if variant in WINCH_VARIANTS:
        raise ValueError(
            "variant 'winch' scores the parcel on the embedded simulator's line model; on real firmware the "
            "winch delivery is tested by tests/real_ardupilot/test_arducopter_winch.py (docs/winch.md)"
        )
    tuning = firmware_tuning(autopilot)
    overrides: dict[str, Any] = {"mission": tuning["mission"], "landing": {**tuning["landing"], **VARIANTS[variant]}}
    if variant in GNSS_VARIANTS:
        g = SIM_VARIANTS[variant]
        overrides["sim"] = {k: g[k] for k in ("gnss_lost_below_m", "gnss_lost_within_m") if k in g}
        overrides["external_nav"] = {"enabled": variant in EXTERNAL_NAV_VARIANTS}
        if not overrides["landing"].get("fusion", True):  # GPS-only: never released (module doc)
            overrides["landing"]["policy"] = {"require_pad_lock": True}
    cfg = load_simulated_config(base, overrides=overrides)
    h = cfg.sim.home
    pn, pe, _ = pad_position_ned(cfg.mission, GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m))
    pad = PadConfig(north_m=float(pn), east_m=float(pe), size_m=cfg.mission.pad.size_m)
    mission = cfg.mission.model_copy(update={"pad": pad, "ready_timeout_s": max(cfg.mission.ready_timeout_s, 120.0)})
    return cfg.model_copy(update={"mission": mission, "autopilot": autopilot})


def landing_config(config: SimulatedConfig, variant: str, d: Draw) -> SimulatedConfig:
    """The variant's configuration for draw ``d``: the draw's seed drives the noise of the camera
    and UWB rendered from the truth, as in the embedded campaign (scenario_config), so that no two
    landings share a noise sequence; the pad_heading variant takes its draw too."""
    cfg = with_pad_heading(config, d.seed) if variant in HEADING_VARIANTS else config
    return cfg.model_copy(update={"sim": cfg.sim.model_copy(update={"seed": d.seed})})


def draw_weather(config: SimulatedConfig, d: Draw) -> FirmwareWeather:
    """The draw's weather as the embedded campaign flies it: its wind, the [sim] gusts and noise."""
    return FirmwareWeather.of(
        config.sim.model_copy(update={"wind_speed_m_s": d.wind_speed_m_s, "wind_from_deg": d.wind_from_deg})
    )


async def _set_sensor_noise(rv: RealVehicle, w: FirmwareWeather) -> None:
    """The draw's sensor noise on the SITL (the same for every draw of a campaign: [sim] fields)."""
    for name in ("SIM_GPS1_GLTCH_X", "SIM_GPS1_GLTCH_Y"):  # the driver sends these unanswered: exist?
        try:
            await asyncio.to_thread(rv.truth.get_param, name)
        except TimeoutError:
            raise WeatherError(f"the SITL has no parameter {name}: it cannot fly the drawn GPS error") from None
    hover = await asyncio.to_thread(rv.truth.get_param, "MOT_THST_HOVER")
    for name, value in static_params(w, hover):
        await asyncio.to_thread(rv.truth.set_param, name, value)
    log.info("sensor noise set on the SITL (hover throttle %.3f): %s", hover, static_params(w, hover))


async def _one_landing(
    rv: RealVehicle,
    config: SimulatedConfig,
    d: Draw,
    rel_pad: tuple[float, float],
    weather: bool = False,
    flight_log: Path | None = None,
) -> dict[str, Any]:
    truth = rv.truth
    disp = real_pad_displacement(d)
    driver: WeatherDriver | None = None
    if rv.autopilot_name == "ardupilot":
        wind = (("SIM_WIND_SPD", d.wind_speed_m_s), ("SIM_WIND_DIR", d.wind_from_deg), ("SIM_WIND_TURB", 0.0))
        for name, value in wind:
            await asyncio.to_thread(truth.set_param, name, value)
        if weather:
            w = draw_weather(config, d)
            if rv.landings_flown == 0:
                await _set_sensor_noise(rv, w)
            origin = truth.origin
            lat = origin.lat_deg if origin is not None else config.sim.home.lat_deg
            driver = WeatherDriver(WeatherProcess(w, d.seed), truth.send_param, lat).start()
    if rv.autopilot_name == "ardupilot" and rv.landings_flown > 0:
        # the next landing starts where the last one ended: home there, as a ground station
        # would set it (ArduPilot sets home only at arming; the mission plans from home first)
        result = await asyncio.to_thread(truth.command, MAV_CMD_DO_SET_HOME, 1.0)
        if result != 0:
            raise RuntimeError(f"ArduCopter refused MAV_CMD_DO_SET_HOME (current location): MAV_RESULT {result}")
    start = (truth.pn, truth.pe)
    pad_ne = (start[0] + rel_pad[0] + disp[0], start[1] + rel_pad[1] + disp[1])
    ap = rv.backend(config)
    failure = ""
    rec = FlightRecorder(flight_log, config) if flight_log is not None else None
    cut = GpsCut(rv, config, pad_ne) if config.sim.gnss_lost_below_m > 0.0 else None
    gnss: dict[str, Any] = {}
    try:
        await ap.connect(timeout_s=20.0)
        if cut is not None:
            cut.start()
        r = await fly_on_truth(
            config,
            ap,
            truth,
            truth.origin,
            (0.0, 0.0),
            timeout_s=LANDING_TIMEOUT_S,
            pad_ne=pad_ne,
            recorder=rec,
            on_shell=cut.shells.append if cut is not None else None,
        )
        if cut is not None:
            gnss = await cut.record(r)
        err, td, delivered, failure = r.pad_landing_error_m, r.touchdown_truth_ne_m, r.delivered, r.failure
        heading_err = r.pad_heading_error_deg
        used = {
            "markers_used": r.markers_used,
            "uwb_used": r.uwb_used,
            "fusion_outcomes": r.fusion_outcomes,
            "believed_offset_m": r.believed_offset_m,
            "estimate_error_m": r.estimate_error_m,
            "guidance_overruns": r.guidance_overruns,
            "setpoint_overruns": r.setpoint_overruns,
            "landing_trace": r.landing_trace,
        }
    except Exception as exc:  # a landing that cannot be flown is a result, not the end of the campaign
        log.exception("landing seed %d failed", d.seed)
        err, td, delivered, failure = math.nan, (math.nan, math.nan), False, f"{type(exc).__name__}: {exc}"
        heading_err = math.nan
        used = {
            "markers_used": 0,
            "uwb_used": 0,
            "believed_offset_m": math.nan,
            "estimate_error_m": math.nan,
            "guidance_overruns": 0,
            "setpoint_overruns": 0,
        }
    finally:
        if cut is not None:
            await cut.stop()
        if rec is not None:
            rec.close()
        await ap.close()
        rv.landings_flown += 1
        if driver is not None:
            await asyncio.to_thread(driver.stop)
    if cut is not None and not gnss:  # a landing that could not be flown: the cut, if it came
        h, t = cut.loss.get("height_m", math.nan), cut.loss.get("time_s", math.nan)
        gnss = {"gnss_cut": {"below_m": config.sim.gnss_lost_below_m, "height_m": h, "time_s": t - cut.t0}}
    dn, de = td[0] - pad_ne[0], td[1] - pad_ne[1]
    return (
        {
            "seed": d.seed,
            "error_m": err,
            "north_m": dn,
            "east_m": de,
            "delivered": delivered,
            "failure": failure,
            "gps_bias_m": d.gps_bias_m[:2],
            "pad_offset_m": d.pad_offset_m,
            "pad_displacement_m": disp,
            "wind_m_s": d.wind_speed_m_s if rv.autopilot_name == "ardupilot" else 0.0,
            **used,
        }
        | (
            {
                "weather": {
                    "gust_std_m_s": driver.process.w.gust_std_m_s,
                    "max_gust_m_s": driver.max_gust_m_s,
                    "max_gps_error_m": driver.max_gps_error_m,
                    "ticks": driver.ticks,
                    "late_ticks": driver.overruns,
                }
            }
            if driver is not None
            else {}
        )
        | ({"heading_error_deg": heading_err} if config.mission.pad.heading_deg is not None else {})
        | gnss
    )


class GpsCut:
    """One landing's GPS cut (lab/gnss_cut.py's cut_gps_when_low on the firmware's cut, sitl_gps_cut)
    at [sim] gnss_lost_below_m within gnss_lost_within_m of the true pad, and its record."""

    def __init__(self, rv: RealVehicle, config: SimulatedConfig, pad_ne: tuple[float, float]):
        self.rv, self.config, self.pad_ne = rv, config, pad_ne
        self.shells: list[Any] = []  # the landing's DeliveryShell (fly_on_truth's on_shell)
        self.loss: dict[str, float] = {}
        self.task: asyncio.Task[None] | None = None
        self.t0 = time.monotonic()

    def start(self) -> None:
        sim = self.config.sim
        cut = sitl_gps_cut(self.rv.autopilot_name, self.rv.truth)
        self.t0 = time.monotonic()
        below, within = sim.gnss_lost_below_m, sim.gnss_lost_within_m
        self.task = asyncio.get_running_loop().create_task(
            cut_gps_when_low(self.rv.truth, self.pad_ne, below, within, self.loss, time.monotonic, cut)
        )

    async def stop(self) -> None:
        if self.task is not None:
            self.task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self.task

    async def record(self, r: Any) -> dict[str, Any]:
        """The landing's ``gnss_cut`` (times in s from the landing's start; ``seen_after_s``: when the
        companion's GnssWatch found the fix gone, nan without external navigation), its releases and
        whether the parcel came home."""
        await self.stop()
        f = loss_flight(r, self.shells[0], self.loss, time.monotonic() - self.t0, self.t0)
        t_cut = f.loss_time_s
        modes = modes_after(self.rv.truth, t_cut) if self.rv.autopilot_name == "px4" and math.isfinite(t_cut) else ()
        return {
            "releases": r.releases,
            "home_with_parcel": r.home_with_parcel,
            "gnss_cut": {
                "below_m": self.config.sim.gnss_lost_below_m,
                "height_m": f.loss_height_m,
                "time_s": t_cut - self.t0,
                "seen_after_s": f.gnss_lost_seen_s,
                "switch_accepted_after_s": f.switch_accepted_s,
                "switch_jump_m": f.switch_jump_m,
                "poses_sent": f.poses_sent,
                "autopilot_modes": list(modes),
                "events": [e for e in f.events if float(e.split(" ", 1)[0]) >= t_cut - self.t0 - 0.05],
            },
        }


async def run_real_landing_campaign_async(
    autopilot: str,
    n: int,
    seed: int,
    variants: tuple[str, ...] = ("fusion", "gps_only"),
    params: str | Path | None = None,
    log_dir: Path | None = None,
    progress: Callable[[str, int, int], None] | None = None,
    weather: bool = False,
) -> dict[str, Any]:
    if autopilot not in REAL_AUTOPILOTS:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {REAL_AUTOPILOTS}")
    if weather and autopilot != "ardupilot":
        raise ValueError(f"weather on {autopilot}: only ArduCopter's SITL has wind and noise parameters to drive")
    gnss_variants = [v for v in variants if v in GNSS_VARIANTS]
    if weather and gnss_variants:
        raise ValueError(
            f"variants {gnss_variants} with weather: the GNSS-lost landings fly in the draw's wind only (a fresh "
            "SITL each, the drawn GPS error would be driven on a receiver the landing switches off); drop weather "
            "or fly them apart"
        )
    base = Path(params) if params else shipped_params_path("landing_campaign.toml")
    draws = draw_scenarios(n, seed)
    configs = {v: real_config(base, autopilot, v) for v in variants}
    rel = configs[variants[0]].mission.pad
    rel_pad = (float(rel.north_m or 0.0), float(rel.east_m or 0.0))
    pad_half = rel.size_m / 2.0
    logs = log_dir or Path("runs") / time.strftime(f"real-{autopilot}-%Y%m%d-%H%M%S")
    landings: dict[str, list[dict[str, Any]]] = {v: [] for v in variants}
    total, done = n * len(variants), 0
    t0 = time.monotonic()

    async def fly_all(rv: RealVehicle, todo: list[tuple[Draw, str]]) -> None:
        nonlocal done
        for d, v in todo:
            cfg = landing_config(configs[v], v, d)
            # every landing leaves its flight log (companion logs show / replay) and its descent trace
            row = await _one_landing(rv, cfg, d, rel_pad, weather, logs / "flights" / f"{v}-{d.seed}")
            _write_trace(logs / "landing_traces" / f"{v}-{d.seed}.csv", row.pop("landing_trace", ()))
            row["on_pad"] = on_pad(row["north_m"], row["east_m"], pad_half, row["delivered"])
            landings[v].append(row)
            done += 1
            log.info("%s %s seed %d: %.3f m (%s)", autopilot, v, d.seed, row["error_m"], row["failure"] or "ok")
            if progress is not None:
                progress(v, done, total)

    jobs = [(d, v) for d in draws for v in variants]
    boot = gnss_loss_boot_params(autopilot) if gnss_variants else {}
    if autopilot == "ardupilot":  # one SITL for the campaign (41 s of simulated time to become armable)
        shared = [j for j in jobs if j[1] not in GNSS_VARIANTS]
        if shared:
            async with real_vehicle("ardupilot", logs) as rv:
                await fly_all(rv, shared)
        # a GPS cut leaves EKF3 on its dead reckoning or source set 2: a fresh SITL for each
        for k, job in enumerate(j for j in jobs if j[1] in GNSS_VARIANTS):
            async with real_vehicle("ardupilot", logs / f"gnss-{k:03d}", boot, watch=("HEARTBEAT",)) as rv:
                await require_gps_cut(rv)
                await fly_all(rv, [job])
    else:  # PX4 SIH: a clean start for each landing
        for k, job in enumerate(jobs):
            gnss_job = job[1] in GNSS_VARIANTS
            async with real_vehicle(
                "px4", logs / f"{k:03d}", boot if gnss_job else None, watch=("HEARTBEAT",) if gnss_job else ()
            ) as rv:
                await fly_all(rv, [job])
    summary = {v: summarize(ls) for v, ls in landings.items()}
    for v in gnss_variants:  # the policy's figure: releases off the pad (issue 57: none)
        summary[v]["released_off_pad"] = sum(bool(x["delivered"]) and not x["on_pad"] for x in landings[v])
    return {
        "n": n,
        "seed": seed,
        "params": str(base),
        "autopilot": autopilot,
        "source": f"real {autopilot} SITL" + (" in drawn weather" if weather else ""),
        "weather": weather,
        "wall_time_s": time.monotonic() - t0,
        "summary": summary,
        "landings": landings,
    }


async def require_gps_cut(rv: RealVehicle) -> None:
    """ArduCopter: the SITL build has the parameter the cut sets (GPS_ENABLE_PARAM), else RuntimeError."""
    try:
        await asyncio.to_thread(rv.truth.get_param, GPS_ENABLE_PARAM)
    except TimeoutError:
        raise RuntimeError(
            f"the ArduCopter SITL has no parameter {GPS_ENABLE_PARAM}: it cannot cut its GPS for the GNSS-lost "
            "variants (ArduCopter 4.5+ SITL expected; SIM_GPS_DISABLE before the 2024 rename)"
        ) from None


def _write_trace(path: Path, rows: tuple[tuple[float, ...], ...]) -> None:
    """One landing's descent, tick by tick (LANDING_TRACE_FIELDS), for the parity work
    (docs/simulation.md); nothing when the landing never reached its descent."""
    if not rows:
        return
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(LANDING_TRACE_FIELDS)
        w.writerows(rows)


def run_real_landing_campaign(*args: Any, **kwargs: Any) -> dict[str, Any]:
    return asyncio.run(run_real_landing_campaign_async(*args, **kwargs))


# --------------------------------------------------------------------------- parity


def landing_diagnostics(rows: list[dict[str, Any]]) -> str:
    """One line per real landing: its error split into where the companion believed it was from
    the pad (its control error) and how far that belief was from the truth (its estimation
    error), loop overruns and sensor use; with the machine it ran on (real landings depend on it)."""
    model = platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text(encoding="ascii", errors="replace").splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else math.nan
    lines = [f"{model} x{os.cpu_count()}, load {load:.2f}"]
    for x in rows:
        lines.append(
            f"seed {x['seed']}: {x['error_m']:.3f} m (N {x['north_m']:+.3f} E {x['east_m']:+.3f}), believed "
            f"{x.get('believed_offset_m', math.nan):.3f} m, "
            f"estimate error {x.get('estimate_error_m', math.nan):.3f} m, "
            f"overruns {x.get('guidance_overruns', 0)}/{x.get('setpoint_overruns', 0)}, "
            f"markers {x['markers_used']}, uwb {x['uwb_used']}"
        )
    return "; ".join(lines)


def _figures(errs: list[float]) -> dict[str, float]:
    """Touchdown figures over the landings that touched down (``landed`` of ``n``; the others are
    failures, counted by the failure classes)."""
    a = np.array(errs, dtype=float)
    ok = a[np.isfinite(a)]
    counts = {"n": int(a.size), "landed": int(ok.size)}
    if not ok.size:
        return {"mean_m": math.nan, "p90_m": math.nan, "max_m": math.nan, **counts}
    return {"mean_m": float(ok.mean()), "p90_m": float(np.percentile(ok, 90)), "max_m": float(ok.max()), **counts}


def compare(
    predicted: dict[str, Any], real: dict[str, Any], variant: str = "fusion", factor: float = 1.5
) -> dict[str, Any]:
    """Sim-to-real agreement on the same seeds: mean and p90 within ``factor`` each way, and the
    same failure class on every draw (on the pad in both, or off it in both; a landing that failed
    is off the pad)."""
    p_rows = {x["seed"]: x for x in predicted["landings"][variant]}
    r_rows = {x["seed"]: x for x in real["landings"][variant]}
    seeds = sorted(set(p_rows) & set(r_rows))
    pf = _figures([p_rows[s]["error_m"] for s in seeds])
    rf = _figures([r_rows[s]["error_m"] for s in seeds])
    ratios = {k: (pf[k] / rf[k]) if rf[k] > 0 else math.nan for k in ("mean_m", "p90_m", "max_m")}
    disagree = [s for s in seeds if bool(p_rows[s]["on_pad"]) != bool(r_rows[s]["on_pad"])]
    within = all(1.0 / factor <= ratios[k] <= factor for k in ("mean_m", "p90_m"))
    return {
        "variant": variant,
        "seeds": seeds,
        "predicted": pf,
        "real": rf,
        "ratio_predicted_to_real": ratios,
        "within_factor": factor,
        "mean_and_p90_within_factor": within,
        "failure_class_disagreements": disagree,
        "failure_classes_agree": not disagree,
        "per_seed": [
            {
                "seed": s,
                "predicted_m": p_rows[s]["error_m"],
                "real_m": r_rows[s]["error_m"],
                "predicted_on_pad": p_rows[s]["on_pad"],
                "real_on_pad": r_rows[s]["on_pad"],
            }
            for s in seeds
        ],
    }


def run_parity(
    autopilot: str,
    n: int,
    seed: int,
    params: str | Path | None = None,
    out_dir: Path | None = None,
    variants: tuple[str, ...] = ("fusion",),
    progress: Callable[[str, int, int], None] | None = None,
    weather: bool = False,
) -> dict[str, Any]:
    """The embedded campaign with the firmware's profile and the real-SITL campaign on the same
    draws (``weather``: both in the drawn weather, ArduCopter only); writes parity.json and
    parity.png into ``out_dir``."""
    if autopilot not in PROFILE_FOR:
        raise ValueError(f"autopilot {autopilot!r}: expected one of {tuple(PROFILE_FOR)}")
    out = out_dir or Path("runs") / time.strftime(f"parity-{autopilot}-%Y%m%d-%H%M%S")
    out.mkdir(parents=True, exist_ok=True)
    profile = PROFILE_FOR[autopilot]
    t0 = time.monotonic()
    tuning = firmware_tuning(autopilot)
    if weather:
        tuning["sim"] = {"profile_weather": True}
    predicted = run_landing_campaign(n, seed, variants, params, progress, profile=profile, tuning=tuning)
    t_pred = time.monotonic() - t0
    real = run_real_landing_campaign(autopilot, n, seed, variants, params, out / "sitl", progress, weather=weather)
    result = {
        "autopilot": autopilot,
        "profile": profile,
        "weather": weather,
        "n": n,
        "seed": seed,
        "predicted_wall_time_s": t_pred,
        "real_wall_time_s": real["wall_time_s"],
        "out_dir": str(out),
        "comparison": {v: compare(predicted, real, v) for v in variants},
        "predicted": predicted,
        "real": real,
    }
    (out / "parity.json").write_text(json.dumps(result, indent=1, default=lambda o: None))
    parity_figure(result, out / "parity.png")
    return result


def parity_figure(result: dict[str, Any], dest: Path) -> Path:
    """Error distributions side by side (profile prediction vs real firmware), seeds paired."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = list(result["comparison"])
    fig, axes = plt.subplots(1, len(variants), figsize=(5.0 * len(variants), 4.2), squeeze=False)
    for ax, v in zip(axes[0], variants, strict=True):
        c = result["comparison"][v]
        rows = c["per_seed"]
        pred = [r["predicted_m"] * 100 for r in rows]
        real = [r["real_m"] * 100 for r in rows]
        data = [[x for x in pred if math.isfinite(x)], [x for x in real if math.isfinite(x)]]
        ax.boxplot(data, positions=[0, 1], widths=0.4, showfliers=False)
        for p, r in zip(pred, real, strict=True):
            ax.plot([0, 1], [p, r], color="0.7", lw=0.8, zorder=1)
        ax.scatter([0] * len(pred), pred, s=18, color="tab:blue", zorder=2, label="predicted")
        ax.scatter([1] * len(real), real, s=18, color="tab:red", zorder=2, label="real")
        ax.set_xticks([0, 1], [f"embedded\n{result['profile']} profile", f"real {result['autopilot']}\nSITL"])
        ax.set_ylabel("landing error on truth (cm)")
        ax.set_ylim(bottom=0)
        pm, rm = format_cm(c["predicted"]["mean_m"]), format_cm(c["real"]["mean_m"])
        ax.set_title(f"{v}: mean {pm} vs {rm}, n = {len(rows)}", fontsize=10)
        ax.grid(axis="y", alpha=0.3)
    fig.tight_layout()
    dest.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(dest, dpi=110)
    plt.close(fig)
    return dest


def aligned_landing_problem(autopilot: str, out_dir: Path) -> str | None:
    """One ``pad_heading`` draw (seed 11, params/landing_campaign_short.toml) on the real SITL, the
    dock placed off its configured heading: None when it was delivered on the pad within 3 deg of
    the pad's true heading (docs/pad-heading.md), else what went wrong with the landing's
    diagnostics."""
    r = run_real_landing_campaign(
        autopilot, 1, 11, ("pad_heading",), shipped_params_path("landing_campaign_short.toml"), out_dir
    )
    (x,) = r["landings"]["pad_heading"]
    _, placed_deg = pad_heading_draw(x["seed"])
    if abs(placed_deg) <= 1.0:
        return f"the draw placed the dock {placed_deg:.2f} deg off: too close to test the measured heading"
    if not (x["delivered"] and x["failure"] == "" and x["on_pad"]):
        return f"not delivered on the pad: {x['failure'] or 'off the pad'}; {landing_diagnostics([x])}"
    err = x["heading_error_deg"]
    if not (math.isfinite(err) and err < 3.0):
        return f"heading error at touchdown {err} deg (within 3 expected); {landing_diagnostics([x])}"
    return None
