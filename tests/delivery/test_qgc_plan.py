"""QGroundControl plan files (companion.delivery.qgc_plan, `fly --plan`, `companion plan`): plans
written here in the JSON QGroundControl writes (its keys, nulls for unused params, version 2),
read into the pad, the alternate and the fence by the autopilot-mission rule; every refusal names
the key or item; the export reads back to the same delivery; a plan's pad is flown over real
MAVLink against the sim vehicle."""

from __future__ import annotations

import copy
import json
import math
import subprocess
import sys

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.cli import exits
from companion.config import shipped_params_path
from companion.delivery.qgc_plan import (
    FenceCircle,
    PlanFileError,
    circle_polygon,
    config_from_plan,
    export_plan,
    parse_plan,
    read_plan,
)
from companion.geometry.earth import GeoPoint, geo_to_ned, ned_to_geo

REL, MISSION = 3, 2


def _home(config) -> GeoPoint:
    h = config.sim.home
    return GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)


def _item(n: int, command: int, frame: int, params: list, alt: float | None = None) -> dict:
    it = {
        "autoContinue": True,
        "command": command,
        "doJumpId": n,
        "frame": frame,
        "params": params,
        "type": "SimpleItem",
    }
    if alt is not None:
        it.update({"AMSLAltAboveTerrain": None, "Altitude": alt, "AltitudeMode": 1})
    return it


def _plan(home: GeoPoint, pad_ne: tuple[float, float], items_after=(), fence=None, rally=()) -> dict:
    """A drop as QGC plans it: take-off, a waypoint at the pad, a gripper release, return."""
    pad = ned_to_geo(home, *pad_ne, 0.0)
    items = [
        _item(1, 22, REL, [0, 0, 0, None, home.lat_deg, home.lon_deg, 8], 8),
        _item(2, 16, REL, [0, 0, 0, None, pad.lat_deg, pad.lon_deg, 8], 8),
        _item(3, 211, MISSION, [1, 0, 0, 0, 0, 0, 0]),
        *items_after,
        _item(4 + len(items_after), 20, MISSION, [0, 0, 0, 0, 0, 0, 0]),
    ]
    return {
        "fileType": "Plan",
        "geoFence": fence or {"circles": [], "polygons": [], "version": 2},
        "groundStation": "QGroundControl",
        "mission": {
            "cruiseSpeed": 15,
            "firmwareType": 3,
            "globalPlanAltitudeMode": 1,
            "hoverSpeed": 5,
            "items": items,
            "plannedHomePosition": [home.lat_deg, home.lon_deg, home.alt_amsl_m],
            "vehicleType": 2,
            "version": 2,
        },
        "rallyPoints": {"points": [list(p) for p in rally], "version": 2},
        "version": 1,
    }


def _ne(home: GeoPoint, lat: float, lon: float) -> tuple[float, float]:
    n, e, _ = geo_to_ned(home, GeoPoint(lat, lon, home.alt_amsl_m))
    return n, e


def _off(home: GeoPoint, lat: float, lon: float, ne: tuple[float, float]) -> float:
    """Metres between (lat, lon) and the point ``ne`` (north, east) from home."""
    n, e = _ne(home, lat, lon)
    return math.hypot(n - ne[0], e - ne[1])


def _ring(home: GeoPoint, corners) -> list[list[float]]:
    out = []
    for n, e in corners:
        g = ned_to_geo(home, n, e, 0.0)
        out.append([g.lat_deg, g.lon_deg])
    return out


def test_the_drop_s_waypoint_is_the_pad_and_the_fence_and_rally_point_come_along(mav, tmp_path):
    config = mav.short_config()
    home = _home(config)
    square = _ring(home, ((-60, -60), (-60, 60), (60, 60), (60, -60)))
    hole = _ring(home, ((30, -40), (30, -30), (40, -30), (40, -40)))
    far, near = ned_to_geo(home, -20.0, 25.0, 0.0), ned_to_geo(home, 5.0, 25.0, 0.0)
    fence = {
        "circles": [
            {"circle": {"center": [home.lat_deg, home.lon_deg], "radius": 80.0}, "inclusion": True, "version": 1}
        ],
        "polygons": [
            {"inclusion": True, "polygon": square, "version": 1},
            {"inclusion": False, "polygon": hole, "version": 1},
        ],
        "version": 2,
    }
    rally = [(far.lat_deg, far.lon_deg, 10.0), (near.lat_deg, near.lon_deg, 10.0)]
    f = tmp_path / "drop.plan"
    f.write_text(json.dumps(_plan(home, (10.0, 20.0), fence=fence, rally=rally), indent=4))
    flown, said = config_from_plan(config, read_plan(f))
    m = flown.mission
    assert _off(home, m.pad.lat_deg, m.pad.lon_deg, (10.0, 20.0)) < 0.01
    assert m.pad.alt_amsl_m is None  # a waypoint's altitude is where it flies: the pad on the home's ground
    # the rally point nearest the pad is the alternate
    assert _off(home, m.alternate_pad.lat_deg, m.alternate_pad.lon_deg, (5.0, 25.0)) < 0.01
    assert flown.fence.enabled and len(flown.fence.inclusion) == 2 and len(flown.fence.exclusion) == 1
    assert said.startswith(f"destination: {f}: mission item 2 NAV_WAYPOINT (16), alternate rallyPoints.points[1]")
    assert "fence: 2 polygon(s), 1 circle(s)" in said
    assert config.mission.pad.north_m == 14.0  # the parameters themselves are untouched


def test_a_landing_in_an_amsl_frame_gives_the_pad_its_ground_altitude(mav):
    config = mav.short_config()
    home = _home(config)
    plan = _plan(home, (8.0, 8.0))
    pad = plan["mission"]["items"][1]
    pad.update(command=21, frame=0)  # NAV_LAND in MAV_FRAME_GLOBAL: its altitude is the ground's, AMSL
    pad["params"][6] = home.alt_amsl_m + 1.5
    flown, _ = config_from_plan(config, parse_plan(plan, "land.plan"))
    assert flown.mission.pad.alt_amsl_m == pytest.approx(home.alt_amsl_m + 1.5)


def test_a_fence_circle_becomes_a_polygon_on_its_safe_side():
    c_in = FenceCircle(47.0, 8.0, 100.0, inclusion=True)
    c_out = FenceCircle(47.0, 8.0, 100.0, inclusion=False)
    centre = GeoPoint(47.0, 8.0, 0.0)
    r_in = [math.hypot(*geo_to_ned(centre, GeoPoint(lat, lon, 0.0))[:2]) for lat, lon in circle_polygon(c_in)]
    r_out = [math.hypot(*geo_to_ned(centre, GeoPoint(lat, lon, 0.0))[:2]) for lat, lon in circle_polygon(c_out)]
    assert len(r_in) == 32 and max(abs(r - 100.0) for r in r_in) < 0.01  # inscribed: vertices on the circle
    apothem = min(r_out) * math.cos(math.pi / 32)  # circumscribed: the edges touch the circle from outside
    assert apothem == pytest.approx(100.0, abs=0.01) and min(r_out) > 100.0


def _refusal(plan: dict | str) -> str:
    with pytest.raises(PlanFileError) as info:
        parse_plan(json.loads(plan) if isinstance(plan, str) else plan, "x.plan")
    return info.value.reason


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda p: p.update(fileType="Mission"), "x.plan: fileType = 'Mission': expected 'Plan'"),
        (lambda p: p["mission"].update(version=1), "mission.version = 1: expected 2"),
        (lambda p: p["mission"]["items"][1]["params"].pop(), "mission.items[1].params has 6 values: expected 7"),
        (lambda p: p["mission"]["items"][1]["params"].__setitem__(4, "47.4"), "mission.items[1].params[4] = '47.4'"),
        (
            lambda p: p["mission"]["items"][1]["params"].__setitem__(5, float("nan")),
            "params[5] = nan: expected a finite",
        ),
        (lambda p: p["mission"]["items"][1]["params"].__setitem__(4, 95.0), "latitude within +-90"),
        (lambda p: p["mission"]["items"][1].update(command="16"), "mission.items[1].command = '16'"),
        (
            lambda p: p["mission"]["items"].insert(1, {"type": "ComplexItem", "complexItemType": "survey"}),
            "mission item 2 is a survey: the companion flies its own path",
        ),
        (lambda p: p["geoFence"]["polygons"].append({"polygon": [[47, 8], [47.1, 8]]}), "polygon has 2 vertices"),
        (
            lambda p: p["geoFence"]["circles"].append({"circle": {"center": [47, 8], "radius": -5}}),
            "geoFence.circles[0].circle.radius = -5: expected metres > 0",
        ),
        (lambda p: p["rallyPoints"]["points"].append([47.0]), "rallyPoints.points[0] = [47.0]: expected [latitude"),
    ],
)
def test_what_is_not_a_plan_is_refused_with_the_key_named(mav, edit, words):
    plan = _plan(_home(mav.short_config()), (10.0, 10.0))
    edit(plan)
    assert words in _refusal(plan)


def test_plans_without_a_delivery_are_refused_naming_the_items(mav, tmp_path):
    config = mav.short_config()
    plan = _plan(_home(config), (10.0, 10.0))
    del plan["mission"]["items"][2]  # the waypoint without its release: a survey point, not a drop
    with pytest.raises(PlanFileError, match=r"mission \(items 1 NAV_TAKEOFF \(22\), 2 NAV_WAYPOINT \(16\), 3 "):
        config_from_plan(config, parse_plan(plan, "survey.plan"))
    plan = _plan(_home(config), (5000.0, 0.0))  # beyond the 3 km the parameters allow from home
    with pytest.raises(PlanFileError, match=r"survey\.plan: "):
        config_from_plan(config, parse_plan(plan, "survey.plan"))
    for text, words in (("{", "not JSON: "), ("[1, 2]", "the file: expected a JSON object")):
        f = tmp_path / "bad.plan"
        f.write_text(text)
        with pytest.raises(PlanFileError, match=words):
            read_plan(f)
    with pytest.raises(PlanFileError, match="cannot read"):
        read_plan(tmp_path / "missing.plan")


def test_the_export_reads_back_to_the_same_delivery(mav):
    config = mav.short_config()
    home = _home(config)
    alt = ned_to_geo(home, 20.0, 5.0, 0.0)
    data = config.model_dump()
    data["mission"]["alternate_pad"] = {"lat_deg": alt.lat_deg, "lon_deg": alt.lon_deg, "size_m": 1.0}
    box = _ring(home, ((-50, -50), (-50, 50), (50, 50), (50, -50)))
    data["fence"].update(enabled=True, inclusion=[{"vertices_deg": box}])
    config = type(config).model_validate(data)
    plan = export_plan(config, home)
    assert [it["command"] for it in plan["mission"]["items"]] == [22, 16, 211, 20]
    assert plan["mission"]["plannedHomePosition"] == [home.lat_deg, home.lon_deg, home.alt_amsl_m]
    back, _said = config_from_plan(config, parse_plan(copy.deepcopy(plan), "ours.plan"))
    p, q = back.mission.pad, back.mission.alternate_pad
    assert (
        _off(home, p.lat_deg, p.lon_deg, (14.0, 14.0)) < 0.01 and _off(home, q.lat_deg, q.lon_deg, (20.0, 5.0)) < 0.01
    )
    assert back.fence.inclusion[0].vertices_deg == config.fence.inclusion[0].vertices_deg
    assert json.loads(json.dumps(plan)) == plan  # plain JSON, as QGC reads it


def _fly(*args: str, cwd) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "companion", *args], capture_output=True, text=True, timeout=60, cwd=cwd
    )


def test_the_cli_checks_exports_and_refuses_plans(mav, tmp_path):
    params = str(shipped_params_path("sitl_short.toml"))
    out = tmp_path / "ours.plan"
    proc = _fly("plan", "export", "--params", params, "--out", str(out), cwd=tmp_path)
    assert proc.returncode == 0 and "4 mission items" in proc.stdout, proc.stderr
    proc = _fly("plan", "check", str(out), "--params", params, "--json", cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    got = json.loads(proc.stdout)
    home = _home(mav.short_config())
    assert _off(home, got["pad"]["lat_deg"], got["pad"]["lon_deg"], (14.0, 14.0)) < 0.01
    bad = tmp_path / "bad.plan"
    bad.write_text(json.dumps({"fileType": "Plan", "mission": {"version": 2, "items": []}}))
    proc = _fly("plan", "check", str(bad), "--params", params, cwd=tmp_path)
    assert proc.returncode == exits.BAD_INPUT and "Traceback" not in proc.stderr
    assert len(proc.stderr.splitlines()) == 1 and "has no mission items" in proc.stderr
    proc = _fly("fly", "--params", params, "--plan", str(out), cwd=tmp_path)  # the simulator is demo's
    assert proc.returncode == exits.BAD_INPUT and "autopilot = 'sim'" in proc.stderr


def _fly_params(tmp_path, port: int) -> str:
    """sitl_short on the ArduPilot backend against the sim vehicle at ``port``, GPS only."""
    text = shipped_params_path("sitl_short.toml").read_text()
    text = text.replace('autopilot = "sim"', 'autopilot = "ardupilot"')
    text = text.replace('connection = "udpin://0.0.0.0:14540"', f'connection = "udpin:127.0.0.1:{port}"')
    text += "\n[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n[telemetry]\nenabled = false\n"
    f = tmp_path / "vehicle.toml"
    f.write_text(text)
    return str(f)


def test_fly_refuses_a_plan_without_a_delivery_before_connecting(mav, udp_port, tmp_path):
    plan = _plan(_home(mav.short_config()), (10.0, 10.0))
    del plan["mission"]["items"][2]
    f = tmp_path / "survey.plan"
    f.write_text(json.dumps(plan))
    params = _fly_params(tmp_path, udp_port)
    proc = _fly("fly", "--params", params, "--plan", str(f), "--no-preflight", cwd=tmp_path)
    assert proc.returncode == exits.BAD_INPUT and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.startswith(f"companion fly: {f}: mission (items 1 NAV_TAKEOFF (22), 2 NAV_WAYPOINT (16)")
    proc = _fly("fly", "--params", params, "--plan", str(f), "--orders", cwd=tmp_path)
    assert proc.returncode == exits.BAD_INPUT and "--plan with --orders" in proc.stderr
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())  # nothing was started


@pytest.mark.flight
async def test_the_plan_s_pad_is_flown_over_mavlink(mav, udp_port, tmp_path):
    """The drop planned in QGC 10 m south, 16 m east of home (the parameters' pad is N 14, E 14):
    the ArduPilot backend against the sim vehicle over loopback UDP lands there."""
    config = mav.short_config()
    home = _home(config)
    f = tmp_path / "drop.plan"
    f.write_text(json.dumps(_plan(home, (-10.0, 16.0))))
    flown, _ = config_from_plan(config, read_plan(f))
    with mav.sim_vehicle(flown, "ardupilot", udp_port) as sim:
        _shell, summary = await mav.fly(flown, ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}"))
    assert summary.delivered and summary.returned, summary.failure
    td = [t for t in sim.vehicle.touchdowns if not t.payload_released]
    assert td and math.hypot(td[0].north_m + 10.0, td[0].east_m - 16.0) < 1.0, td
