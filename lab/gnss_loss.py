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
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.autopilot.preflight.external_nav import ARMING_CHECKS_BUT_VISION
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.flightlog.recorder import FlightRecorder
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.real_vehicle import ARDUCOPTER_GRIPPER_SERVO9
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import HarnessResult, fly_on_truth, true_pad_ne
from companion_lab.real_campaign import firmware_tuning
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)

#: ArduCopter's parameters for external navigation on source set 2 (companion.autopilot.preflight.
#: external_nav), set from boot: VISO_TYPE needs a reboot
EXTERNAL_NAV_PARAMS = {
    "VISO_TYPE": 1,
    "EK3_SRC2_POSXY": 6,
    "EK3_SRC2_VELXY": 0,
    "EK3_SRC2_POSZ": 1,
    "EK3_SRC2_YAW": 1,
    "FS_EKF_ACTION": 1,
    # VISO_TYPE = 1 makes "VisOdom: not healthy" a pre-arm failure until a pose arrives, and the pose
    # exists only near the pad: the vision check is skipped (bit 18), every other check kept
    "ARMING_CHECK": ARMING_CHECKS_BUT_VISION,
}
#: the SITL's simulated GPS on or off (ArduCopter 4.7-dev; SIM_GPS_DISABLE = 1 before the 2024 rename)
GPS_ENABLE_PARAM = "SIM_GPS1_ENABLE"
# the no-release-off-the-pad policy on, short (a 2 s hold, one more try): a lost pad never waits long
POLICY = {"require_pad_lock": True, "hold_s": 2.0, "descent_tries": 2}


@dataclass(frozen=True)
class GnssLossFlight:
    result: HarnessResult
    loss_height_m: float  # the true height above the ground when the GPS went off (nan: never)
    loss_time_s: float  # the shell's clock when the GPS went off
    gnss_lost_seen_s: float  # how long after that the companion found it lost (nan: never)
    switch_accepted_s: float  # how long after the loss the source switch was accepted (nan: never)
    switch_jump_m: float  # the autopilot's position's jump at the switch, horizontal (nan: not measured)
    poses_sent: int
    flight_wall_s: float
    events: tuple[str, ...]
    # the autopilot's mode changes after the loss, "<s after it> <mode>" (PX4: from its heartbeats)
    autopilot_modes: tuple[str, ...] = ()


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


def sitl_gps_cut(autopilot: str, truth: MavlinkTruth) -> Callable[[], Any]:
    """The blocking call that switches the SITL's GPS off over ``truth``'s link: ArduCopter's
    GPS_ENABLE_PARAM to 0, PX4 SIH's receiver stopped in its shell (lab/gnss_loss_px4.py's GPS_STOP)."""
    if autopilot == "ardupilot":
        return lambda: truth.set_param(GPS_ENABLE_PARAM, 0.0)
    if autopilot == "px4":
        from companion_lab.gnss_loss_px4 import GPS_STOP

        return lambda: truth.shell(GPS_STOP)
    raise ValueError(f"autopilot {autopilot!r}: the GPS cut is built for 'ardupilot' and 'px4'")


async def cut_gps_when_low(
    truth: MavlinkTruth,
    pad_ne: tuple[float, float],
    loss_height_m: float,
    loss_radius_m: float,
    out: dict[str, float],
    clock: Any,
    cut: Any,
) -> None:
    """``cut()`` (blocking, run in a thread) once the true vehicle comes down through
    ``loss_height_m`` within ``loss_radius_m`` of the pad; the height and time into ``out``."""
    ground = truth.pd
    been_above = False
    while True:
        await asyncio.sleep(0.05)
        if truth.age_s > 1.0:
            continue
        h = ground - truth.pd
        been_above = been_above or h > loss_height_m + 1.0
        near = math.hypot(truth.pn - pad_ne[0], truth.pe - pad_ne[1]) <= loss_radius_m
        if been_above and near and h <= loss_height_m:
            out["height_m"], out["time_s"] = h, clock()
            await asyncio.to_thread(cut)
            log.warning(
                "SITL GPS off at %.2f m above the ground, %.2f m from the pad",
                h,
                math.dist((truth.pn, truth.pe), pad_ne),
            )
            return


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
    params = {**ARDUCOPTER_GRIPPER_SERVO9, **EXTERNAL_NAV_PARAMS}
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


def loss_flight(
    r: HarnessResult, shell: DeliveryShell, loss: dict[str, float], wall: float, t0: float
) -> GnssLossFlight:
    """The flight's figures from its shell's external-navigation feed and the cut's record."""
    feed_ = shell.external_nav
    lost_seen = switch = jump = math.nan
    sent = 0
    t_loss = loss.get("time_s", math.nan)
    if feed_ is not None:
        st = feed_.stats
        lost_seen = st.gnss_lost_at_s - t_loss
        switch = st.switch_accepted_at_s - t_loss
        sent = st.poses_sent
        b, a = st.position_before_switch_ned_m, st.position_after_switch_ned_m
        if a is not None and b is not None:
            jump = math.hypot(a[0] - b[0], a[1] - b[1])
    return GnssLossFlight(
        r,
        loss.get("height_m", math.nan),
        t_loss,
        lost_seen,
        switch,
        jump,
        sent,
        wall,
        tuple(f"{e.time_s - t0:.1f} {e.kind.value} {e.detail}" for e in shell.events),
    )
