"""GNSS lost near the pad on the real PX4 v1.16 SIH (docs/external-nav.md, the PX4 section): the
sitl_short delivery with camera and UWB rendered from SIH's truth, its GPS stopped when the true
vehicle comes down through ``loss_height_m`` within ``loss_radius_m`` of the pad.

How the GPS is stopped: SIH v1.16 ignores MAV_CMD_INJECT_FAILURE for GPS (only the gazebo bridge,
simulator_mavlink, handles it: measured, no COMMAND_ACK, GPS_RAW_INT unchanged), so the harness
stops the simulated receiver in PX4's shell over MAVLink (``sensor_gps_sim stop``): GPS_RAW_INT
then says fix type 0 with 255 satellites at 1 Hz, as a receiver that lost the sky.

With ``external_nav`` PX4 is booted with EKF2_EV_CTRL = 1 and the companion streams ODOMETRY once
the pad is locked; EKF2 fuses it beside GNSS and goes on with it alone. Without it PX4's own
failsafe acts (no position: "blind land" where it is).
"""

from __future__ import annotations

import asyncio
import contextlib
import time
from pathlib import Path

from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.px4_sitl import Px4Sitl
from companion_firmware.real_vehicle import PX4_GCS_URL, PX4_OFFBOARD_URL
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import fly_on_truth, true_pad_ne
from companion_lab.gnss_loss import POLICY, GnssLossFlight, cut_gps_when_low, loss_flight
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.params import SimulatedConfig, load_simulated_config

#: PX4's parameters for external navigation (companion.autopilot.preflight.external_nav), from boot
EXTERNAL_NAV_PARAMS = {"EKF2_EV_CTRL": 1}
#: the shell line that stops SIH's simulated GPS receiver (see the module doc)
GPS_STOP = "sensor_gps_sim stop"


def px4_gnss_loss_config(external_nav: bool, fusion: bool = True, height_m: float = 8.0) -> SimulatedConfig:
    """sitl_short on PX4 SIH with PX4's landing tuning, no return home, the no-release-off-the-pad
    policy on (with fusion)."""
    tuning = firmware_tuning("px4")
    return load_simulated_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "autopilot": "px4",
            "connection": PX4_OFFBOARD_URL,
            "mission": {**tuning["mission"], "ready_timeout_s": 60.0, "return_home": False, "height_m": height_m},
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
    timeout_s: float = 120.0,
) -> GnssLossFlight:
    """One delivery on a fresh PX4 SIH (instance 0, clean parameters) with the GPS stopped at
    ``loss_height_m``."""
    from companion.autopilot.px4 import Px4Autopilot

    params = dict(EXTERNAL_NAV_PARAMS) if external_nav else {}
    sitl = Px4Sitl(root, params={k: float(v) for k, v in params.items()}, log_path=work / "px4.log")
    shells: list[DeliveryShell] = []
    loss: dict[str, float] = {}
    with sitl, MavlinkTruth(PX4_GCS_URL) as truth:
        await asyncio.to_thread(truth.wait, 30.0)
        config = px4_gnss_loss_config(external_nav, fusion, height_m)
        assert truth.origin is not None
        pad_ne = true_pad_ne(config, truth.origin, pad_offset_m)
        ap = Px4Autopilot.from_config(config)
        rec = FlightRecorder(work / "run", config)
        loop = asyncio.get_running_loop()
        cut = lambda: truth.shell(GPS_STOP)  # noqa: E731
        cutter = loop.create_task(cut_gps_when_low(truth, pad_ne, loss_height_m, loss_radius_m, loss, loop.time, cut))
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
