"""The delivery planned in the GCS, over real MAVLink on loopback UDP against the MAVLink sim
vehicle: a second MAVLink connection (the operator's GCS) uploads a plan, the companion downloads
it after connecting (pymavlink for ArduPilot, MAVSDK's mission_raw for PX4) and flies to its pad;
`companion fly` refuses a plan without a delivery before arming, with exit 2 and the item named."""

from __future__ import annotations

import math
import subprocess
import sys

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.px4 import Px4Autopilot
from companion.cli import exits
from companion.config import shipped_params_path
from companion.geometry.earth import GeoPoint, geo_to_ned
from companion_firmware.gcs_plan import delivery_plan
from companion_firmware.gcs_probe import MAV_FRAME_GLOBAL_RELATIVE_ALT, GcsMissionItem, GcsProbe


def _plan(home: GeoPoint, north_m: float, east_m: float) -> tuple[list[GcsMissionItem], GeoPoint]:
    """Take-off, a waypoint at the pad, a gripper release, return: as QGroundControl plans it."""
    return delivery_plan(home.lat_deg, home.lon_deg, north_m, east_m)


def _upload(sim, items: list[GcsMissionItem], dialect: str) -> None:
    with GcsProbe(f"udpout:127.0.0.1:{sim.address[1]}") as gcs:
        assert gcs.upload_mission(1, items, home_item=dialect == "ardupilot") == 0  # MAV_MISSION_ACCEPTED


@pytest.mark.flight
@pytest.mark.parametrize("dialect", ["ardupilot", "px4"])
async def test_the_plan_uploaded_from_the_gcs_is_flown(mav, udp_port, dialect: str) -> None:
    config = mav.short_config(destination="autopilot_mission")
    h = config.sim.home
    home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    items, pad = _plan(home, -10.0, 16.0)  # the parameters' pad is N 14, E 14
    with (
        mav.sim_vehicle(config, dialect, udp_port, route_peers=True) as sim,
        GcsProbe(f"udpout:127.0.0.1:{sim.address[1]}") as gcs,
    ):
        assert gcs.upload_mission(1, items, home_item=dialect == "ardupilot") == 0  # MAV_MISSION_ACCEPTED
        ap = (
            ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
            if dialect == "ardupilot"
            else Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
        )
        _shell, summary = await mav.fly(config, ap)
        assert sim.mission_downloads == 1 and sim.mission_uploads == 1
    # the operator's GCS is told which plan is flown (the companion's component, docs/gcs.md)
    texts = [t for _, t in gcs.texts(1, 191)]
    assert any(t.startswith("go_no_go: destination: autopilot mission item 2 NAV_WAYPOINT (16)") for t in texts), texts
    assert summary.delivered and summary.returned, summary.failure
    said = [e.detail for e in summary.events if e.kind.value == "go_no_go"]
    # the operator's numbering on both firmwares: item 2 (ArduPilot seq 2 after its home, PX4 seq 1)
    assert said[0].startswith("destination: autopilot mission item 2 NAV_WAYPOINT (16): pad "), said
    td = [t for t in sim.vehicle.touchdowns if not t.payload_released]
    assert td, "no touchdown on the way out"
    n, e, _ = geo_to_ned(home, GeoPoint(pad.lat_deg, pad.lon_deg, home.alt_amsl_m))
    err = math.hypot(td[0].north_m - n, td[0].east_m - e)
    print(f"\n{dialect}: landed {err:.2f} m from the uploaded pad (N {n:.1f}, E {e:.1f})")
    assert err < 1.0, (td[0], n, e)


def _fly_params(tmp_path, port: int) -> str:
    text = shipped_params_path("sitl_short.toml").read_text()
    text = text.replace('autopilot = "sim"', 'autopilot = "ardupilot"')
    text = text.replace('connection = "udpin://0.0.0.0:14540"', f'connection = "udpin:127.0.0.1:{port}"')
    text = text.replace("[mission]\n", '[mission]\ndestination = "autopilot_mission"\n', 1)
    text += "\n[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n[telemetry]\nenabled = false\n"
    f = tmp_path / "vehicle.toml"
    f.write_text(text)
    return str(f)


def test_fly_refuses_a_plan_without_a_delivery_before_arming(mav, udp_port, tmp_path) -> None:
    config = mav.short_config()
    h = config.sim.home
    items, _ = _plan(GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m), 10.0, 10.0)
    del items[2]  # no gripper release after the waypoint
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        _upload(sim, items, "ardupilot")
        proc = subprocess.run(
            [sys.executable, "-m", "companion", "fly", "--params", _fly_params(tmp_path, udp_port), "--no-preflight"],
            capture_output=True,
            text=True,
            timeout=60,
            cwd=tmp_path,
        )
        assert not sim.vehicle.armed and sim.mission_downloads == 1
    assert proc.returncode == exits.BAD_INPUT, proc.stderr
    assert "Traceback" not in proc.stderr and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert proc.stderr.startswith("companion fly: the autopilot's mission (items 1 NAV_TAKEOFF (22), 2 NAV_WAYPOINT")
    assert "has no delivery item: expected a NAV_PAYLOAD_PLACE (94)" in proc.stderr
    assert "or set mission.destination = 'params' in" in proc.stderr and "nothing was armed" in proc.stderr


@pytest.mark.parametrize(
    ("item", "answer"),
    [
        (GcsMissionItem(MAV_FRAME_GLOBAL_RELATIVE_ALT, 20, 0.0, 0.0, 0.0), 3),  # RTL in a global frame: UNSUPPORTED
        (GcsMissionItem(MAV_FRAME_GLOBAL_RELATIVE_ALT, 94, 47.4, 8.5, 8.0), 3),  # NAV_PAYLOAD_PLACE: UNSUPPORTED
        (GcsMissionItem(11, 16, 47.4, 8.5, 8.0), 2),  # a terrain frame: MAV_MISSION_UNSUPPORTED_FRAME
        (GcsMissionItem(1, 16, 47.4, 8.5, 8.0), 2),  # a local frame
    ],
)
def test_the_px4_sim_vehicle_refuses_at_upload_what_px4_refuses(mav, udp_port, item: GcsMissionItem, answer: int):
    config = mav.short_config()
    with mav.sim_vehicle(config, "px4", udp_port) as sim, GcsProbe(f"udpout:127.0.0.1:{sim.address[1]}") as gcs:
        assert gcs.upload_mission(1, [item]) == answer
        assert sim.mission_items == ()
