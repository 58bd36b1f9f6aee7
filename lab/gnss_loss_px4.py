"""GNSS lost near the pad on the real PX4 v1.16 SIH (docs/external-nav.md, the PX4 section): the
sitl_short delivery with camera and UWB rendered from SIH's truth, its GPS stopped when the true
vehicle comes down through ``loss_height_m`` within ``loss_radius_m`` of the pad.

How the GPS is stopped: lab/gnss_cut.py (``sensor_gps_sim stop`` in PX4's shell).

With ``external_nav`` PX4 is booted with EKF2_EV_CTRL = 1 and the companion streams ODOMETRY once
the pad is locked; EKF2 fuses it beside GNSS and goes on with it alone. Without it PX4's own
failsafe acts (no position: "blind land" where it is).
"""

from __future__ import annotations

import asyncio
import dataclasses
import time
from pathlib import Path

from companion.config import shipped_params_path
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.real_vehicle import PX4_GCS_URL, PX4_OFFBOARD_URL
from companion_firmware.truth_feed import MavlinkTruth
from companion_lab.gnss_cut import PX4_EXTERNAL_NAV_PARAMS, GnssLossFlight, modes_after, sitl_gps_cut
from companion_lab.gnss_loss import POLICY, fly_with_gps_cut
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import SimulatedConfig, load_simulated_config


def px4_gnss_loss_config(
    external_nav: bool, fusion: bool = True, height_m: float = 8.0, pad_m: tuple[float, float] | None = None
) -> SimulatedConfig:
    """sitl_short on PX4 SIH with PX4's landing tuning, no return home, the no-release-off-the-pad
    policy on (with fusion); ``pad_m``: the configured pad north/east of home (None: sitl_short's)."""
    tuning = firmware_tuning("px4")
    mission = {**tuning["mission"], "ready_timeout_s": 60.0, "return_home": False, "height_m": height_m}
    if pad_m is not None:
        mission["pad"] = {"north_m": pad_m[0], "east_m": pad_m[1]}
    return load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "autopilot": "px4",
            "connection": PX4_OFFBOARD_URL,
            "mission": mission,
            "landing": {**tuning["landing"], "fusion": fusion, "policy": POLICY if fusion else {}},
            "external_nav": {"enabled": external_nav},
        },
    )


async def fly_px4_gnss_loss(
    root: Path,
    work: Path,
    loss_height_m: float,
    external_nav: bool = True,
    fusion: bool = True,
    pad_offset_m: tuple[float, float] = (0.5, -0.4),
    loss_radius_m: float = 6.0,
    height_m: float = 8.0,
    pad_m: tuple[float, float] | None = None,
    timeout_s: float = 120.0,
) -> GnssLossFlight:
    """One delivery on a fresh PX4 SIH (instance 0, clean parameters) with the GPS stopped at
    ``loss_height_m``."""
    from companion.autopilot.px4 import Px4Autopilot

    params = dict(PX4_EXTERNAL_NAV_PARAMS) if external_nav else {}
    sitl = Px4Sitl(root, params={k: float(v) for k, v in params.items()}, log_path=work / "px4.log")
    with sitl, MavlinkTruth(PX4_GCS_URL, watch=("HEARTBEAT",)) as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        config = px4_gnss_loss_config(external_nav, fusion, height_m, pad_m)
        ap = Px4Autopilot.from_config(config)
        cut = sitl_gps_cut("px4", truth)
        clock = time.monotonic  # the cut's time on the heartbeats' clock
        f = await fly_with_gps_cut(
            config, ap, truth, work, pad_offset_m, loss_height_m, loss_radius_m, clock, cut, timeout_s
        )
        modes = modes_after(truth, f.loss_time_s)
    return dataclasses.replace(f, autopilot_modes=modes)
