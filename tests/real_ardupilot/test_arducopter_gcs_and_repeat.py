"""On a real ArduCopter SITL, without restarting it: two sitl_short deliveries in a row, each by a
fresh companion, the second to the pad of a plan the GCS uploads to ArduCopter (a waypoint and a
gripper release, downloaded with the MAVLink mission protocol), then a third flight returned home
by the operator's GCS. The ground station is
on SERIAL2 (as QGroundControl on a telemetry radio); ArduPilot's routing passes it the
companion's own component (1/191): heartbeat and STATUSTEXTs (not ONBOARD_COMPUTER_STATUS), and passes
its NAV_RETURN_TO_LAUNCH addressed to 1/191 to the companion (docs/gcs.md, docs/flying.md)."""

from __future__ import annotations

import asyncio
import math

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.delivery.shell import DeliveryShell
from companion.events import Phase
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_firmware.gcs_plan import ReleaseWhere, delivery_plan
from companion_firmware.gcs_probe import GcsProbe
from companion_sitl.mavlink.link import free_udp_port

from .conftest import GRIPPER_SERVO9

pytestmark = pytest.mark.firmware

MAV_CMD_NAV_RETURN_TO_LAUNCH = 20


def _gcs_plan(config):
    """The same flight, to the pad of the mission the GCS uploaded (docs/gcs.md)."""
    return config.model_copy(update={"mission": config.mission.model_copy(update={"destination": "autopilot_mission"})})


async def _fly(config, on_tick=None) -> DeliveryShell:
    ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
    shell = DeliveryShell(config, ap, on_tick=on_tick)
    try:
        await shell.run(timeout_s=300.0)
        # back where this flight took off (the autopilot's HOME_POSITION moves when it re-arms on the pad)
        pos, start = ap.telemetry.position_ned, shell.mission.start_ned
        shell.home_error_m = (  # type: ignore[attr-defined]
            math.hypot(pos.north_m - start[0], pos.east_m - start[1])
            if pos is not None and start is not None
            else math.inf
        )
    finally:
        await ap.close()
    return shell


async def test_arducopter_delivery_after_delivery_and_a_return_from_the_gcs(ardupilot_root, tmp_path, mav):
    gcs_port = free_udp_port()
    sitl = ArduCopterSitl(
        ardupilot_root,
        extra_params=dict(GRIPPER_SERVO9),
        serials={2: f"udpclient:127.0.0.1:{gcs_port}"},
        log_path=tmp_path / "arducopter.log",
    )
    with sitl, GcsProbe(f"udpin:127.0.0.1:{gcs_port}") as gcs:
        config = mav.firmware_config("ardupilot", sitl.connection, 120.0)  # EKF3 uses GPS ~41 s after boot
        where = ReleaseWhere()
        home = None  # flight 1's, where the plan is drawn from
        pad = None
        for flight in (1, 2):
            if home is not None:  # the operator's plan: another pad (sitl_short's is N 14, E 14)
                plan, pad = delivery_plan(home.lat_deg, home.lon_deg, -12.0, 15.0)
                assert gcs.upload_mission(1, plan, home_item=True) == 0  # MAV_MISSION_ACCEPTED
            shell = await _fly(*((config, None) if flight == 1 else (_gcs_plan(config), where)))
            s = shell.mission.summary
            assert s.delivered and s.returned and not s.failure, (flight, s.failure)
            print(
                f"\nflight {flight}: delivered, landed {shell.home_error_m:.2f} m from its take-off; {shell.made_ready}"
            )
            if flight == 1:
                home = shell.autopilot.telemetry.home
                assert home is not None, "no HOME_POSITION from ArduCopter"
        said = [e.detail for e in s.events if e.kind.value == "go_no_go"]
        assert said[0].startswith("destination: autopilot mission item 2 NAV_WAYPOINT (16): pad "), said
        print(f"flight 2, the GCS's plan: released {where.distance_m(pad):.2f} m from the uploaded pad")
        assert pad is not None and where.distance_m(pad) < 1.5

        state: dict = {"sent": None}

        def tick(sh: DeliveryShell, out) -> None:
            if out.phase is Phase.OUTBOUND and sh.mission.sector >= 2 and state["sent"] is None:
                state["sent"] = asyncio.get_running_loop().run_in_executor(
                    None, gcs.command, 1, 191, MAV_CMD_NAV_RETURN_TO_LAUNCH
                )

        shell = await _fly(config, tick)
        assert state["sent"] is not None, "the flight never reached sector 2"
        assert await state["sent"] == 0  # COMMAND_ACK ACCEPTED from 1/191
        s = shell.mission.summary
        assert s.returned and not s.delivered and s.failure == "returned on ground command", s
        assert shell.home_error_m < 1.5, shell.home_error_m

    hb = gcs.messages(1, 191, "HEARTBEAT")
    assert hb and hb[0].type == 18 and hb[0].autopilot == 8
    texts = gcs.texts(1, 191)
    assert (6, "phase outbound") in texts and (5, "delivered: parcel released on the pad") in texts, texts
    assert any(sev == 4 and "ground command from gcs" in t for sev, t in texts), texts
    # ArduCopter 4.7 SITL passes neither a full nor a zero-trimmed ONBOARD_COMPUTER_STATUS on (measured;
    # docs/gcs.md): if this fails, it has started to, and the page should say so
    status = gcs.messages(1, 191, "ONBOARD_COMPUTER_STATUS")
    assert status == []
    print(f"GCS saw from 1/191: {len(hb)} heartbeats, {len(texts)} texts, {len(status)} computer status")
