"""OpenCV's process-wide thread count: the setting applies, bad values are refused with the key,
and the delivery shell applies ``[runtime] opencv_threads`` when it has a camera or detector."""

from __future__ import annotations

import asyncio
from collections.abc import Iterator
from types import SimpleNamespace
from typing import Any

import cv2
import pytest

from companion.autopilot.interface import AutopilotError, TelemetryCache
from companion.config import ConfigError, load_config, shipped_params_path
from companion.dart.params import DartRuntimeConfig
from companion.delivery.shell import DeliveryShell, LandingKit
from companion.vision.opencv_threads import apply_opencv_threads


@pytest.fixture(autouse=True)
def _restore_threads() -> Iterator[None]:
    before = cv2.getNumThreads()
    yield
    cv2.setNumThreads(before)


def test_apply_sets_what_opencv_uses() -> None:
    assert apply_opencv_threads(1) == 1 == cv2.getNumThreads()
    assert apply_opencv_threads(3) == 3 == cv2.getNumThreads()
    # -1: back to OpenCV's default (one per CPU, at least one)
    assert apply_opencv_threads(-1) >= 1


@pytest.mark.parametrize("bad", [-2, 1.5, True, "2", None])
def test_apply_refuses_bad_values(bad: Any) -> None:
    before = cv2.getNumThreads()
    with pytest.raises(ValueError, match="opencv_threads"):
        apply_opencv_threads(bad)
    assert cv2.getNumThreads() == before


def test_config_limits_name_the_key() -> None:
    path = shipped_params_path("sitl_short.toml")
    assert load_config(path).runtime.opencv_threads == 1
    with pytest.raises(ConfigError, match=r"runtime\.opencv_threads"):
        load_config(path, overrides={"runtime": {"opencv_threads": -2}})
    with pytest.raises(ValueError, match="opencv_threads = -3"):
        DartRuntimeConfig(opencv_threads=-3)


class _NoAutopilot:
    """Refuses to connect: the shell stops right after its start-up settings."""

    def __init__(self) -> None:
        self.telemetry = TelemetryCache()

    async def connect(self, timeout_s: float = 10.0) -> None:
        raise AutopilotError("no autopilot here")

    async def close(self) -> None:
        pass


@pytest.mark.parametrize(("threads", "landing"), [(2, True), (1, True), (2, False)])
def test_shell_applies_the_setting_with_a_camera(threads: int, landing: bool) -> None:
    cfg = load_config(shipped_params_path("sitl_short.toml"), overrides={"runtime": {"opencv_threads": threads}})
    kit = (
        LandingKit(
            camera=SimpleNamespace(),
            uwb=None,
            detector=None,
            multilaterator=None,
            T_body_camera=None,
            T_pad_anchors=None,
        )
        if landing
        else None
    )
    cv2.setNumThreads(5)  # neither value above
    shell = DeliveryShell(cfg, _NoAutopilot(), landing=kit)  # type: ignore[arg-type]
    with pytest.raises(AutopilotError):
        asyncio.run(shell.run())
    # without a camera or detector the shell leaves OpenCV alone (a GPS-only flight need not load it)
    assert cv2.getNumThreads() == (threads if landing else 5)
