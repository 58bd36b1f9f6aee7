"""The fence in the delivery: refused before take-off with the leg that leaves it; uploaded to
the autopilot and read back before arming; a read-back that differs refuses (embedded simulator)."""

from __future__ import annotations

import asyncio

import pytest

from companion.autopilot.fence import AutopilotFence, FencePolygon
from companion.config import shipped_params_path
from companion.delivery.shell import DeliveryShell
from companion.events import EventKind
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion_lab.demo import run_demo
from companion_sitl.autopilot import SimAutopilot
from companion_sitl.clock import run_virtual
from companion_sitl.params import load_simulated_config
from companion_sitl.vehicle import SimVehicle

HOME = GeoPoint(-19.869, -43.9638, 850.0)  # delivery_paper.toml's sim home; the pad 100 m away at 45 deg


def square(n0: float, e0: float, n1: float, e1: float) -> list[list[float]]:
    pts = [ned_to_geo(HOME, n, e, 0.0) for n, e in ((n0, e0), (n1, e0), (n1, e1), (n0, e1))]
    return [[p.lat_deg, p.lon_deg] for p in pts]


def cfg(fence: dict[str, object]):  # type: ignore[no-untyped-def]
    return load_simulated_config(shipped_params_path("delivery_paper.toml"), overrides={"fence": fence})


def test_a_path_through_an_exclusion_is_refused_before_take_off() -> None:
    config = cfg(
        {
            "enabled": True,
            "inclusion": [{"vertices_deg": square(-50, -50, 150, 150)}],
            "exclusion": [{"vertices_deg": square(30, 25, 40, 45)}],  # across the 45 deg line
        }
    )
    r = run_demo(config)
    assert r.phase == "failed" and not r.delivered
    assert "refused before take-off: the outbound leg leaves the fence in S3 cruise" in r.failure
    assert "exclusion polygon 0" in r.failure
    # the pad's line (bearing 45 deg, a hair east of it) comes within the 5 m margin of the
    # exclusion's corner (30, 25) near N 25 m, E 25 m: 35.4 m along
    assert "35.4 m along it (N 25.0 m, E 25.1 m" in r.failure, r.failure
    assert not any(kind == "armed" for _, kind, _, _ in r.events)
    assert any(kind == "go_no_go" for _, kind, _, _ in r.events)


@pytest.mark.flight
def test_a_path_inside_flies_and_the_autopilot_holds_the_fence() -> None:
    config = cfg({"enabled": True, "inclusion": [{"vertices_deg": square(-50, -50, 150, 150)}]})
    r = run_demo(config)
    assert r.delivered and r.returned, r.failure
    gng = [d for _, kind, _, d in r.events if kind == "go_no_go"]
    assert gng == ["fence uploaded to the autopilot and read back: 1 inclusion and 0 exclusion polygons, 4 vertices"]


class _LossyFence(SimAutopilot):
    """An autopilot that stores the fence with one vertex moved 1 m (a corrupted transfer)."""

    async def download_fence(self) -> AutopilotFence:
        f = await super().download_fence()
        p = f.polygons[0]
        (lat, lon), rest = p.vertices_e7[0], p.vertices_e7[1:]
        return AutopilotFence((FencePolygon(p.inclusion, ((lat + 90, lon), *rest)),))


def test_a_fence_read_back_that_differs_refuses_and_nothing_is_armed() -> None:
    config = cfg({"enabled": True, "inclusion": [{"vertices_deg": square(-50, -50, 150, 150)}]})

    async def go() -> tuple[DeliveryShell, SimVehicle]:
        vehicle = SimVehicle(config.sim)
        ap = _LossyFence(config.sim, vehicle)
        shell = DeliveryShell(config, ap)
        try:
            await shell.run(timeout_s=60.0)
        finally:
            await ap.close()
        return shell, vehicle

    shell, vehicle = run_virtual(go())
    s = shell.mission.summary
    assert s.failure.startswith("refused before take-off: the autopilot's fence: the fence read back differs")
    assert "polygon 0 (inclusion) vertex 0" in s.failure
    assert s.takeoff_time_s is None and not vehicle.armed
    assert [e.kind for e in s.events] == [EventKind.GO_NO_GO, EventKind.PHASE]
    assert asyncio.iscoroutinefunction(_LossyFence.download_fence)
