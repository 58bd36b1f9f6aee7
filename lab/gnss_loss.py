"""GNSS lost near the pad on the real ArduCopter SITL (docs/external-nav.md): the sitl_short delivery
with camera and UWB rendered from the SITL's truth, its GPS switched off (SIM_GPS1_ENABLE = 0 over
MAVLink on the truth link) when the true vehicle comes down through ``loss_height_m`` above the
ground within ``loss_radius_m`` of the pad.

With ``external_nav`` the companion streams the fused pose (VISION_POSITION_ESTIMATE) once the pad
is locked and switches EKF3 to source set 2 when GPS_RAW_INT says the fix is gone; without it
(GPS-only, ``fusion`` false, or fused without external navigation) the autopilot's own EKF failsafe
acts. The flight is scored on truth: where it touched down, whether anything was released and where.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.real_vehicle import ARDUCOPTER_GRIPPER_SERVO9
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import fly_on_truth, true_pad_ne
from companion_lab.gnss_cut import (
    ARDUCOPTER_EXTERNAL_NAV_PARAMS,
    GPS_ENABLE_PARAM,
    GnssLossFlight,
    cut_gps_when_low,
    loss_flight,
    sitl_gps_cut,
)
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)

# the no-release-off-the-pad policy on, short (a 2 s hold, one more try): a lost pad never waits long
POLICY = {"require_pad_lock": True, "hold_s": 2.0, "descent_tries": 2}


def gnss_loss_config(
    connection: str, loss_external_nav: bool, fusion: bool = True, height_m: float = 8.0
) -> SimulatedConfig:
    """sitl_short on ArduCopter with ArduCopter's landing tuning, no return home (the shortest flight
    that lands on the pad), the no-release-off-the-pad policy on."""
    tuning = firmware_tuning("ardupilot")
    return load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "autopilot": "ardupilot",
            "connection": connection,
            "mission": {**tuning["mission"], "ready_timeout_s": 120.0, "return_home": False, "height_m": height_m},
            "landing": {**tuning["landing"], "fusion": fusion, "policy": POLICY if fusion else {}},
            "external_nav": {"enabled": loss_external_nav},
        },
    )


async def fly_gnss_loss(
    root: Path,
    work: Path,
    loss_height_m: float,
    external_nav: bool = True,
    fusion: bool = True,
    pad_offset_m: tuple[float, float] = (0.5, -0.4),
    loss_radius_m: float = 6.0,
    height_m: float = 8.0,
    timeout_s: float = 240.0,
) -> GnssLossFlight:
    """One delivery on a fresh ArduCopter SITL (clean eeprom) with the GPS cut at ``loss_height_m``."""
    from companion.autopilot.ardupilot import ArduPilotAutopilot

    port = free_udp_port()
    params = {**ARDUCOPTER_GRIPPER_SERVO9, **ARDUCOPTER_EXTERNAL_NAV_PARAMS}
    sitl = ArduCopterSitl(
        root, extra_params=params, serials={1: f"udpclient:127.0.0.1:{port}"}, log_path=work / "arducopter.log"
    )
    feed = MavlinkTruth(f"udpin:127.0.0.1:{port}", message="SIM_STATE")
    with sitl, feed as truth:
        truth.wait(15.0)
        await asyncio.to_thread(truth.get_param, GPS_ENABLE_PARAM)  # exists on this build, or TimeoutError
        config = gnss_loss_config(sitl.connection, external_nav, fusion, height_m)
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        clock = asyncio.get_running_loop().time
        cut = sitl_gps_cut("ardupilot", truth)
        return await fly_with_gps_cut(
            config, ap, truth, work, pad_offset_m, loss_height_m, loss_radius_m, clock, cut, timeout_s
        )


async def fly_with_gps_cut(
    config: SimulatedConfig,
    ap: Any,
    truth: MavlinkTruth,
    work: Path,
    pad_offset_m: tuple[float, float],
    loss_height_m: float,
    loss_radius_m: float,
    clock: Callable[[], float],
    cut: Callable[[], Any],
    timeout_s: float,
) -> GnssLossFlight:
    """The delivery on the real SITL ``truth`` watches, recorded in ``work/run``, with ``cut()``
    called once the true vehicle comes down through ``loss_height_m`` within ``loss_radius_m`` of
    the pad (its time on ``clock``); the autopilot ``ap`` is closed at the end."""
    assert truth.origin is not None
    pad_ne = true_pad_ne(config, truth.origin, pad_offset_m)
    shells: list[DeliveryShell] = []
    loss: dict[str, float] = {}
    rec = FlightRecorder(work / "run", config)
    cutter = asyncio.get_running_loop().create_task(
        cut_gps_when_low(truth, pad_ne, loss_height_m, loss_radius_m, loss, clock, cut)
    )
    t0 = time.monotonic()
    try:
        r = await fly_on_truth(
            config, ap, truth, truth.origin, pad_offset_m, timeout_s=timeout_s, recorder=rec, on_shell=shells.append
        )
    finally:
        wall = time.monotonic() - t0
        cutter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await cutter
        rec.close()
        await ap.close()
    return loss_flight(r, shells[0], loss, wall, t0)
