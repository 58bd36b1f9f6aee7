"""The shell's external-navigation feed (companion/delivery/external_nav.py): what it sends, when it
switches the autopilot's position source, and the events it says."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import numpy as np

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import GpsRaw
from companion.config import ExternalNavConfig
from companion.delivery.external_nav import GNSS_BACK_S, ExternalNavFeed
from companion.estimation.types import StateEstimate
from companion.events import Phase


class FakeAutopilot:
    def __init__(self) -> None:
        self.telemetry = TelemetryCache()
        self.poses: list = []
        self.calls: list[str] = []

    def send_external_nav(self, pose) -> None:  # type: ignore[no-untyped-def]
        self.poses.append(pose.validate())

    async def use_external_nav(self, source_set: int) -> None:
        self.calls.append(f"set {source_set}")

    def external_nav_source_name(self, source_set: int) -> str:
        return f"EKF source set {source_set}"  # ArduPilot's words (the interface's default)

    async def use_gnss(self) -> None:
        self.calls.append("gnss")


class FakeFusion:
    def __init__(self) -> None:
        self.pad_locked = True
        self.age_s = 0.1
        P = np.eye(12) * 0.01
        P[6:9, 6:9] = np.eye(3) * 0.04
        self.ekf = SimpleNamespace(P=P)
        self.t = 0.0

    def pad_data_age_s(self, now: float) -> float:
        return self.age_s

    def estimate(self) -> StateEstimate:
        return StateEstimate(self.t, 10.0, 5.0, -3.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, "fused", 0.4, -0.2, 0.0)


def _fly(streaming: bool) -> tuple[FakeAutopilot, list[str]]:
    ap, fusion = FakeAutopilot(), FakeFusion()
    fusion.age_s = 0.1 if streaming else 10.0
    feed = ExternalNavFeed(ExternalNavConfig(enabled=True), ap)  # type: ignore[arg-type]
    events: list[str] = []

    async def run() -> None:
        for k in range(400):  # 20 s at 20 Hz: GNSS good, lost at 5 s, back at 12 s
            t = k * 0.05
            fusion.t = t
            fix = 1 if 5.0 <= t < 12.0 else 3
            ap.telemetry.gps = GpsRaw(t, -35.0, 149.0, 584.0, fix, 10 if fix == 3 else 3, 0.8)
            events.extend(e.detail for e in feed.step(t, fusion, Phase.LANDING_PAD))
            await asyncio.sleep(0)
        await feed.stop()

    asyncio.run(run())
    return ap, events


def test_near_the_pad_the_pose_goes_out_in_the_autopilot_frame_and_the_source_follows_the_gnss() -> None:
    ap, events = _fly(streaming=True)
    assert len(ap.poses) == 400  # one per tick at 20 Hz
    p = ap.poses[0]
    assert (p.north_m, p.east_m, p.down_m) == (10.4, 4.8, -3.0)  # p + b
    assert abs(p.sigma_north_m - np.sqrt(0.05)) < 1e-9  # P_pp + P_bb
    assert ap.calls == ["set 2", "gnss"]
    assert "EKF source set 2" in events[0] and "GPS fix type 1" in events[0]
    assert events[1].startswith("GNSS back: the autopilot navigates on it again")
    assert len(events) == 2


def test_out_of_range_nothing_is_sent_nor_switched_and_it_says_so() -> None:
    ap, events = _fly(streaming=False)
    assert ap.poses == [] and ap.calls == []
    assert "out of camera and UWB range" in events[0] and "no release" in events[0]
    assert events[1] == "GNSS back" and GNSS_BACK_S == 2.0
