"""Helpers shared by the real-time MAVLink tests of every folder: free loopback ports, a sim vehicle,
a delivery run."""

from __future__ import annotations

import asyncio
import contextlib
import time

import pytest

from companion.config import load_config, shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.telemetry.loopback import free_tcp_port
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.link import free_udp_port


def short_config(**mission):
    return load_config(shipped_params_path("sitl_short.toml"), overrides={"mission": mission} if mission else None)


# A delivery vehicle has its release configured: ArduCopter's gripper library is off by default
# (GRIP_ENABLE = 0: DO_GRIPPER answers FAILED, as the sim vehicle does unless told otherwise).
DELIVERY_PARAMS = {"ardupilot": {"GRIP_ENABLE": 1.0}, "px4": {}}


@contextlib.contextmanager
def sim_vehicle(config, dialect, port, **kwargs):
    kwargs.setdefault("params", DELIVERY_PARAMS[dialect])
    sim = mavlink_sim_vehicle(config.sim, dialect, remote=("127.0.0.1", port), **kwargs).start()
    try:
        yield sim
    finally:
        sim.stop()


async def wait_for(pred, timeout_s: float, what: str = "condition") -> None:
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout_s:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what}")
        await asyncio.sleep(0.02)


async def fly(config, autopilot, monitor=None, timeout_s: float = 90.0):
    shell = DeliveryShell(config, autopilot)
    mon = asyncio.get_running_loop().create_task(monitor(shell)) if monitor else None
    try:
        summary = await shell.run(timeout_s=timeout_s)
    finally:
        if mon is not None:
            mon.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await mon
            if mon.done() and not mon.cancelled() and mon.exception() is not None:
                raise mon.exception()
        await autopilot.close()
    return shell, summary


@pytest.fixture
def udp_port() -> int:
    return free_udp_port()


@pytest.fixture
def mav():
    """The helpers above, for test modules (conftest is not importable under importlib mode)."""
    from types import SimpleNamespace

    return SimpleNamespace(
        free_udp_port=free_udp_port,
        free_tcp_port=free_tcp_port,
        short_config=short_config,
        sim_vehicle=sim_vehicle,
        wait_for=wait_for,
        fly=fly,
    )
