"""The delivery planned in the GCS: the rule that finds the pad in the autopilot's mission, every
refusal naming the item, and the shell flying to it or refusing before anything is armed
(embedded simulator)."""

from __future__ import annotations

import math

import pytest

from companion.autopilot.interface import AutopilotError
from companion.autopilot.mission_plan import PlanItem
from companion.delivery.autopilot_mission import (
    MissionDownloadError,
    MissionPlanError,
    config_from_autopilot_mission,
    destination_from_mission,
)
from companion.delivery.shell import DeliveryShell
from companion.geometry.earth import GeoPoint, geo_to_ned, ned_to_geo
from companion_sitl.autopilot import SimAutopilot
from companion_sitl.clock import run_virtual
from companion_sitl.params import simulated_config_from_dict
from companion_sitl.vehicle import SimVehicle

LAT, LON = 47.3977, 8.5456
REL, AMSL, REL_INT, MISSION, LOCAL_NED, TERRAIN = 3, 0, 6, 2, 1, 10


def item(index: int, command: int, frame: int = REL, lat: float = LAT, lon: float = LON, z: float = 10.0, **p: float):
    return PlanItem(
        index, index, frame, command, p.get("p1", 0.0), p.get("p2", 0.0), 0.0, 0.0,
        round(lat * 1e7), round(lon * 1e7), z,
    )  # fmt: skip


def takeoff(i: int) -> PlanItem:
    return item(i, 22, lat=0.0, lon=0.0)


def wp(i: int, lat: float = LAT, lon: float = LON, frame: int = REL, z: float = 10.0) -> PlanItem:
    return item(i, 16, frame, lat, lon, z)


def release(i: int) -> PlanItem:
    return item(i, 211, MISSION, 0.0, 0.0, 0.0, p1=1.0, p2=0.0)


def grab(i: int) -> PlanItem:
    return item(i, 211, MISSION, 0.0, 0.0, 0.0, p1=1.0, p2=1.0)


# ---------------------------------------------------------------- the rule: what is a delivery


def test_a_waypoint_followed_by_a_gripper_release_is_the_pad() -> None:
    d = destination_from_mission([takeoff(1), wp(2), release(3), item(4, 20, lat=0, lon=0)])
    assert (d.pad.lat_deg, d.pad.lon_deg, d.pad.alt_amsl_m) == (pytest.approx(LAT), pytest.approx(LON), None)
    assert d.alternate is None
    assert d.source == "autopilot mission item 2 NAV_WAYPOINT (16)"


def test_a_payload_place_is_the_pad_and_its_altitude_is_where_it_flies_not_the_ground() -> None:
    d = destination_from_mission([takeoff(1), item(2, 94, AMSL, z=520.0)])
    assert d.pad.alt_amsl_m is None and d.source == "autopilot mission item 2 NAV_PAYLOAD_PLACE (94)"


def test_a_landing_in_an_amsl_frame_gives_the_pads_ground_altitude() -> None:
    d = destination_from_mission([takeoff(1), item(2, 21, AMSL, z=488.5), release(3)])
    assert d.pad.alt_amsl_m == 488.5
    d = destination_from_mission([takeoff(1), item(2, 21, REL_INT, z=0.2), release(3)])
    assert d.pad.alt_amsl_m is None  # at the home's ground


def test_a_second_delivery_item_is_the_alternate_pad() -> None:
    d = destination_from_mission([takeoff(1), wp(2), release(3), item(4, 94, lat=LAT + 0.0003)])
    assert d.alternate is not None and d.alternate.lat_deg == pytest.approx(LAT + 0.0003)
    assert d.source == "autopilot mission item 2 NAV_WAYPOINT (16), alternate item 4 NAV_PAYLOAD_PLACE (94)"


def test_a_gripper_grab_is_not_a_delivery() -> None:
    d = destination_from_mission([takeoff(1), wp(2, lat=LAT + 0.001), grab(3), wp(4), release(5)])
    assert d.pad.lat_deg == pytest.approx(LAT) and d.alternate is None


# ---------------------------------------------------------------- the rule: every refusal


@pytest.mark.parametrize(
    ("items", "words"),
    [
        ([], "the autopilot holds no mission"),
        (
            [takeoff(1), wp(2), item(3, 20, lat=0, lon=0)],
            "mission (items 1 NAV_TAKEOFF (22), 2 NAV_WAYPOINT (16), 3 NAV_RETURN_TO_LAUNCH (20)) "
            "has no delivery item: "
            "expected a NAV_PAYLOAD_PLACE (94) at the pad, or a NAV_WAYPOINT (16) or NAV_LAND (21) at the pad "
            "immediately followed by DO_GRIPPER (211) with param2 = 0 (release)",
        ),
        ([release(1), wp(2)], "item 1 DO_GRIPPER (211) (release) is the mission's first item"),
        ([takeoff(1), release(2), wp(3)], "item 2 DO_GRIPPER (211) (release) follows item 1 NAV_TAKEOFF (22)"),
        (
            [wp(1), release(2), item(3, 94, lat=LAT + 0.001), item(4, 94, lat=LAT + 0.002)],
            "has 3 delivery items (item 1 NAV_WAYPOINT (16), item 3 NAV_PAYLOAD_PLACE (94), item 4 NAV_PAYLOAD_PLACE "
            "(94)): ambiguous; expected one (the pad) or two (the pad, then the alternate pad)",
        ),
        (
            [wp(1), release(2), item(3, 94, lat=LAT + 0.000001)],
            "item 1 NAV_WAYPOINT (16) and item 3 NAV_PAYLOAD_PLACE (94) are 0.11 m apart: ambiguous",
        ),
        (
            [takeoff(1), wp(2, frame=LOCAL_NED), release(3)],
            "item 2 NAV_WAYPOINT (16) is in MAV_FRAME_LOCAL_NED (1): expected a global frame",
        ),
        (
            [takeoff(1), item(2, 94, TERRAIN)],
            "item 2 NAV_PAYLOAD_PLACE (94) is in MAV_FRAME_GLOBAL_TERRAIN_ALT (10): expected a global frame",
        ),
        (
            [wp(1, lat=0.0, lon=0.0), release(2)],
            "item 1 NAV_WAYPOINT (16) is at latitude 0.0000000, longitude 0.0000000",
        ),
        (
            [item(1, 21, REL, z=6.0), release(2)],
            "item 1 NAV_LAND (21): landing altitude 6 m above home in MAV_FRAME_GLOBAL_RELATIVE_ALT: expected 0",
        ),
        ([item(1, 21, AMSL, z=math.nan), release(2)], "item 1 NAV_LAND (21): landing altitude nan"),
    ],
)
def test_a_mission_the_companion_cannot_fly_is_refused_naming_the_item(items: list[PlanItem], words: str) -> None:
    with pytest.raises(MissionPlanError) as err:
        destination_from_mission(items)
    assert words in err.value.reason, err.value.reason


class _Holding:
    """An autopilot that holds ``items`` (or fails the download)."""

    def __init__(self, items: tuple[PlanItem, ...] | None) -> None:
        self.items = items

    async def download_mission(self) -> tuple[PlanItem, ...]:
        if self.items is None:
            raise AutopilotError("mission download: no item 2 of 4")
        return self.items


def test_the_parameters_still_decide_a_pad_outside_the_fence_or_a_failed_download(mav) -> None:  # type: ignore[no-untyped-def]
    base = mav.shipped_config("px4_sih_quad.toml")
    data = base.model_dump()
    box = [[47.39, 8.54], [47.39, 8.55], [47.40, 8.55], [47.40, 8.54]]
    data["fence"] = {"enabled": True, "inclusion": [{"vertices_deg": box}]}
    fenced = simulated_config_from_dict(data, "fenced")
    flown, said = run_virtual(config_from_autopilot_mission(fenced, _Holding((wp(1), release(2)))))  # type: ignore[arg-type]
    assert flown.mission.pad.lat_deg == pytest.approx(LAT) and flown.mission.pad.north_m is None
    assert said.startswith("destination: autopilot mission item 1 NAV_WAYPOINT (16): pad 47.3977000, 8.5456000")
    with pytest.raises(MissionPlanError, match=r"autopilot mission item 1 NAV_WAYPOINT \(16\): .*mission\.pad"):
        run_virtual(config_from_autopilot_mission(fenced, _Holding((wp(1, lat=47.45), release(2)))))  # type: ignore[arg-type]
    with pytest.raises(MissionDownloadError, match="no item 2 of 4"):
        run_virtual(config_from_autopilot_mission(fenced, _Holding(None)))  # type: ignore[arg-type]


# ---------------------------------------------------------------- the shell on the embedded simulator


# the short scenario flown to the pad of the mission uploaded to the autopilot (mav.shipped_config)
FROM_THE_AUTOPILOT = {"mission": {"destination": "autopilot_mission"}, "landing": {"fusion": False}}


def _fly(config, items):  # type: ignore[no-untyped-def]
    async def go():  # type: ignore[no-untyped-def]
        vehicle = SimVehicle(config.sim)
        ap = SimAutopilot(config.sim, vehicle)
        ap.mission_items = tuple(items)
        shell = DeliveryShell(config, ap)
        try:
            await shell.run(timeout_s=200.0)
        finally:
            await ap.close()
        return shell, vehicle

    return run_virtual(go())


def test_a_plan_without_a_delivery_is_refused_before_anything_is_armed(mav) -> None:  # type: ignore[no-untyped-def]
    config = mav.shipped_config(**FROM_THE_AUTOPILOT)
    armed: list[bool] = []

    class Watched(SimAutopilot):
        async def arm(self) -> None:
            armed.append(True)
            await super().arm()

    async def go() -> None:
        ap = Watched(config.sim, SimVehicle(config.sim))
        ap.mission_items = (takeoff(1), wp(2))
        try:
            await DeliveryShell(config, ap).run(timeout_s=60.0)
        finally:
            await ap.close()

    with pytest.raises(MissionPlanError, match="has no delivery item"):
        run_virtual(go())
    assert armed == []


@pytest.mark.flight
def test_the_shell_flies_to_the_pad_of_the_uploaded_mission(mav) -> None:  # type: ignore[no-untyped-def]
    config = mav.shipped_config(**FROM_THE_AUTOPILOT)
    h = config.sim.home
    home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    pad = ned_to_geo(home, -12.0, 15.0, 0.0)  # not the parameters' pad (N 14, E 14)
    shell, vehicle = _fly(config, [takeoff(1), wp(2, pad.lat_deg, pad.lon_deg), release(3)])
    s = shell.mission.summary
    assert s.delivered and s.returned and not s.failure, s.failure
    assert shell.config.mission.pad.lat_deg == pytest.approx(pad.lat_deg)
    said = [e.detail for e in s.events if e.kind.value == "go_no_go"]
    assert said and said[0].startswith("destination: autopilot mission item 2 NAV_WAYPOINT (16): pad "), said
    td = next(t for t in vehicle.touchdowns if not t.payload_released)
    n, e, _ = geo_to_ned(home, GeoPoint(pad.lat_deg, pad.lon_deg, h.alt_amsl_m))
    assert math.hypot(td.north_m - n, td.east_m - e) < 1.0, (td, n, e)
