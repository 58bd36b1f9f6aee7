"""Helpers for the tests against a real ArduCopter SITL build (the build: ``ardupilot_root`` in tests/conftest.py)."""

from __future__ import annotations

import asyncio
import contextlib
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.real_vehicle import ARDUCOPTER_GRIPPER_SERVO9
from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.mavlink.link import free_udp_port

# ArduCopter's optional features used here, set from boot (they need a reboot): servo gripper on output 9
GRIPPER_SERVO9 = ARDUCOPTER_GRIPPER_SERVO9


@contextlib.contextmanager
def arducopter(
    root: Path, log_dir: Path, extra_params: dict[str, float] | None = None, truth: bool = True
) -> Iterator[tuple[ArduCopterSitl, MavlinkTruth | None]]:
    """One SITL (clean eeprom) and, with ``truth``, SIM_STATE ground truth on SERIAL1; the truth
    origin is the vehicle's true position at boot (the true home, on the ground)."""
    port = free_udp_port()
    sitl = ArduCopterSitl(
        root,
        extra_params=dict(extra_params or {}),
        serials={1: f"udpclient:127.0.0.1:{port}"} if truth else {},
        log_path=log_dir / "arducopter.log",
    )
    feed = MavlinkTruth(f"udpin:127.0.0.1:{port}", message="SIM_STATE") if truth else None
    with sitl:
        if feed is None:
            yield sitl, None
            return
        with feed:
            feed.wait(15.0)
            yield sitl, feed


async def wait_for(cond: Callable[[], bool], timeout_s: float, what: str) -> float:
    """Seconds it took until ``cond()``; fails the test with ``what`` after ``timeout_s``."""
    t0 = time.monotonic()
    while not cond():
        if time.monotonic() - t0 > timeout_s:
            pytest.fail(f"{what}: not within {timeout_s} s")
        await asyncio.sleep(0.05)
    return time.monotonic() - t0
