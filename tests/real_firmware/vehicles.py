"""Helpers for the tests of tests/real_firmware/: the real SITL of either firmware started with its
ground truth, and the companion's autopilot for it (imported as ``from .vehicles import ...``)."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from companion_firmware.real_vehicle import ARDUCOPTER_GRIPPER_SERVO9
from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.mavlink.link import free_udp_port

# ArduCopter's optional features a delivery needs, set from boot (they need a reboot): servo
# gripper on output 9 (tests/real_ardupilot/conftest.py's GRIPPER_SERVO9)
GRIPPER_SERVO9 = ARDUCOPTER_GRIPPER_SERVO9

# what a delivery test adds per firmware: boot parameters (ArduCopter: the gripper from boot), the
# configuration's autopilot, and the mission's wait for ArduCopter's EKF3 to use GPS (~41 s after
# boot, the ready timeout)
DELIVERY_BOOT_PARAMS: dict[str, dict[str, float]] = {"px4": {}, "ardupilot": GRIPPER_SERVO9}
AUTOPILOT_OVERRIDES: dict[str, dict[str, Any]] = {"px4": {}, "ardupilot": {"autopilot": "ardupilot"}}
READY_MISSION: dict[str, dict[str, Any]] = {"px4": {}, "ardupilot": {"ready_timeout_s": 120.0}}

# the companion's link to the started SITL: PX4 SIH's offboard port, ArduCopter's from the SITL
PX4_CONNECTION = "udpin://127.0.0.1:14540"
# seconds the truth feed is given for its first sample (what tests/real_px4/ and
# tests/real_ardupilot/ each waited)
TRUTH_WAIT_S = {"px4": 30.0, "ardupilot": 15.0}


@contextlib.contextmanager
def sitl_with_truth(
    name: str, root: Path, log_dir: Path, extra_params: dict[str, float] | None = None
) -> Iterator[tuple[str, MavlinkTruth, Path]]:
    """The started SITL of ``name`` ("px4", "ardupilot") and its ground truth, the truth origin the
    vehicle's true position at boot (the true home, on the ground): the companion's connection, the
    truth feed and the SITL's log. PX4 SIH (``extra_params`` unused): HIL_STATE_QUATERNION on UDP
    14550; ArduCopter SITL (clean eeprom, ``extra_params`` set from boot): SIM_STATE on SERIAL1."""
    if name == "px4":
        from companion_firmware.px4_sitl import Px4Sitl

        log = log_dir / "px4.log"
        with Px4Sitl(root, log_path=log), MavlinkTruth("udpin:127.0.0.1:14550") as truth:
            truth.wait(TRUTH_WAIT_S[name])
            yield PX4_CONNECTION, truth, log
        return
    from companion_firmware.ardupilot_sitl import ArduCopterSitl

    port = free_udp_port()
    log = log_dir / "arducopter.log"
    sitl = ArduCopterSitl(
        root, extra_params=dict(extra_params or {}), serials={1: f"udpclient:127.0.0.1:{port}"}, log_path=log
    )
    feed = MavlinkTruth(f"udpin:127.0.0.1:{port}", message="SIM_STATE")
    with sitl, feed as truth:
        truth.wait(TRUTH_WAIT_S[name])
        yield sitl.connection, truth, log


def autopilot(name: str, config: Any) -> Any:
    """The companion's autopilot of ``name`` from ``config`` (not connected); ArduPilot's waits 30 s
    for the arming (its pre-arm checks pass only once EKF3 uses GPS)."""
    if name == "px4":
        from companion.autopilot.px4 import Px4Autopilot

        return Px4Autopilot.from_config(config)
    from companion.autopilot.ardupilot import ArduPilotAutopilot

    return ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
