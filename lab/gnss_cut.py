"""The GPS cut of the real-firmware GNSS-lost flights (lab/gnss_loss.py, lab/gnss_loss_px4.py) and
campaign variants (lab/real_campaign.py, docs/external-nav.md): each firmware's external-navigation
parameters from boot, the call that switches its simulated GPS off, the watch that makes it when the
true vehicle comes down through a height near the pad, and the flight's record of the loss.

How the GPS is switched off: ArduCopter SITL's SIM_GPS1_ENABLE = 0 over MAVLink on the truth link;
PX4 v1.16 SIH ignores MAV_CMD_INJECT_FAILURE for GPS (only the gazebo bridge, simulator_mavlink,
handles it: measured, no COMMAND_ACK, GPS_RAW_INT unchanged), so its simulated receiver is stopped
in PX4's shell over MAVLink (``sensor_gps_sim stop``): GPS_RAW_INT then says fix type 0 with 255
satellites at 1 Hz, as a receiver that lost the sky.
"""

from __future__ import annotations

import asyncio
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.autopilot.preflight.external_nav import ARMING_CHECKS_BUT_VISION
from companion.delivery.shell import DeliveryShell
from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.truth_harness import HarnessResult

log = logging.getLogger(__name__)

#: ArduCopter's parameters for external navigation on source set 2 (companion.autopilot.preflight.
#: external_nav), set from boot: VISO_TYPE needs a reboot
ARDUCOPTER_EXTERNAL_NAV_PARAMS = {
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
#: PX4's parameters for external navigation (companion.autopilot.preflight.external_nav), from boot
PX4_EXTERNAL_NAV_PARAMS = {"EKF2_EV_CTRL": 1}
#: the shell line that stops SIH's simulated GPS receiver (see the module doc)
GPS_STOP = "sensor_gps_sim stop"
#: PX4's custom main modes and AUTO's sub modes (px4_custom_mode.h), for the flight's record
PX4_MAIN = {1: "MANUAL", 2: "ALTCTL", 3: "POSCTL", 4: "AUTO", 5: "ACRO", 6: "OFFBOARD", 7: "STABILIZED"}
PX4_AUTO = {2: "TAKEOFF", 3: "LOITER", 4: "MISSION", 5: "RTL", 6: "LAND", 9: "PRECLAND"}


def px4_mode_name(custom_mode: int) -> str:
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    name = PX4_MAIN.get(main, f"main {main}")
    return f"{name}.{PX4_AUTO.get(sub, f'sub {sub}')}" if main == 4 else name


def modes_after(truth: MavlinkTruth, since_monotonic: float) -> tuple[str, ...]:
    """PX4's mode changes from its heartbeats on the truth link since ``since_monotonic``."""
    out: list[str] = []
    last = None
    for t, m in truth.watched_messages("HEARTBEAT"):
        name = px4_mode_name(int(m.custom_mode)) + ("" if m.base_mode & 128 else " (disarmed)")
        if name != last and t >= since_monotonic:
            out.append(f"{t - since_monotonic:+.1f} s {name}")
        last = name
    return tuple(out)


def gnss_loss_boot_params(autopilot: str) -> dict[str, float]:
    """The firmware's external-navigation parameters, set from boot for the GNSS-lost variants (the
    same vehicle with and without the companion's pose): ArduCopter's and PX4's above."""
    if autopilot == "ardupilot":
        return {k: float(v) for k, v in ARDUCOPTER_EXTERNAL_NAV_PARAMS.items()}
    if autopilot == "px4":
        return {k: float(v) for k, v in PX4_EXTERNAL_NAV_PARAMS.items()}
    raise ValueError(f"autopilot {autopilot!r}: expected one of {('ardupilot', 'px4')}")


def sitl_gps_cut(autopilot: str, truth: MavlinkTruth) -> Callable[[], Any]:
    """The blocking call that switches the SITL's GPS off over ``truth``'s link: ArduCopter's
    GPS_ENABLE_PARAM to 0, PX4 SIH's receiver stopped in its shell (lab/gnss_loss_px4.py's GPS_STOP)."""
    if autopilot == "ardupilot":
        return lambda: truth.set_param(GPS_ENABLE_PARAM, 0.0)
    if autopilot == "px4":
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
