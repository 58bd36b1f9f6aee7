"""Fixtures for the telemetry tests: Zenoh confined to 127.0.0.1, distinct free ports,
no multicast or gossip scouting, so tests never see each other or leave the machine."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator

import pytest

from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.session import ZenohSettings

SECRET = b"test-shared-secret-0123456789"


def wait_until(predicate: Callable[[], bool], timeout_s: float = 3.0, step_s: float = 0.01) -> bool:
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if predicate():
            return True
        time.sleep(step_s)
    return predicate()


@pytest.fixture
def port() -> int:
    return free_tcp_port()


@pytest.fixture
def ground_settings(port: int) -> ZenohSettings:
    """The ground listens on the test's port."""
    return loopback_settings(listen_port=port)


@pytest.fixture
def vehicle_settings(port: int) -> ZenohSettings:
    """A vehicle connects to the ground's port and listens nowhere."""
    return loopback_settings(connect_port=port)


@pytest.fixture
def ground(ground_settings: ZenohSettings, tmp_path) -> Iterator[GroundStation]:
    station = GroundStation(ground_settings, out_dir=tmp_path / "rec").start()
    yield station
    station.stop()
