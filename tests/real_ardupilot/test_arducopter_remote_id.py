"""Remote ID against a real ArduCopter SITL build's OpenDroneID (AP_OpenDroneID.cpp), no flight.

The SITL boots with DID_ENABLE = 1 and DID_MAVPORT = 1: SERIAL1 goes to a UDP port where this
test plays the transponder (a transponder is hardware: it answers OPEN_DRONE_ID_ARM_STATUS, as
ArduPilot's own autotest "OpenDroneID" does). The companion, on SERIAL0, sends what ``[remote_id]``
says; the firmware must forward its BASIC_ID, OPERATOR_ID, SELF_ID and SYSTEM to the transponder
with our values, and (DID_OPTIONS = 1, EnforceArming, set after the boot) its own pre-arm check must
pass only with them and a good ARM_STATUS. The companion's gate: no ARM_STATUS, or a failing one,
and the arm for a delivery is refused with the reason; a good one and it arms.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.interface import CommandRejected, CommandResult
from companion.autopilot.remote_id.arm_status import ArmStatus, GateVerdict
from companion.config import RemoteIdConfig
from companion_firmware.ardupilot_sitl import ArduCopterSitl

from .conftest import free_udp_port, wait_for

pytestmark = pytest.mark.firmware

RID = RemoteIdConfig(
    enabled=True,
    uas_id="1581F0000TEST0042",
    operator_id="FIN87astrdge12k8",
    self_id="parcel delivery",
    operator_location="fixed",
    operator_lat_deg=-35.3632000,
    operator_lon_deg=149.1651000,
    operator_alt_m=600.0,
    static_rate_hz=1.0,
    system_update_rate_hz=1.0,
)
FEW_STREAMS = {30: 4.0, 33: 4.0, 1: 2.0, 245: 2.0}  # ATTITUDE, GLOBAL_POSITION_INT, SYS_STATUS, EXT_SYS_STATE
ODID = ("OPEN_DRONE_ID_BASIC_ID", "OPEN_DRONE_ID_OPERATOR_ID", "OPEN_DRONE_ID_SELF_ID", "OPEN_DRONE_ID_SYSTEM")


def forwarded_ours(got: dict[str, Any]) -> bool:
    if not all(n in got for n in ODID):
        return False
    b, o, d, s = (got[n] for n in ODID)
    return (
        bytes(b.uas_id).rstrip(b"\0") == RID.uas_id.encode()
        and (b.id_type, b.ua_type) == (1, 2)
        and o.operator_id == RID.operator_id
        and d.description == RID.self_id
        and (s.operator_latitude, s.operator_longitude) == (-353632000, 1491651000)
    )


class Transponder:
    """The transponder on DID_MAVPORT: keeps what the autopilot forwards, sends its HEARTBEAT and,
    once ``status`` is set, OPEN_DRONE_ID_ARM_STATUS at 2 Hz (as MAV_COMP_ID_ODID_TXRX_1)."""

    def __init__(self, port: int):
        self.conn = mavutil.mavlink_connection(
            f"udpin:127.0.0.1:{port}", source_system=1, source_component=mavutil.mavlink.MAV_COMP_ID_ODID_TXRX_1
        )
        self.got: dict[str, Any] = {}
        self.status: tuple[int, str] | None = None
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        next_send = 0.0
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= next_send and self.conn.clients:  # udpin: once the SITL has sent to us (its address)
                next_send = now + 0.5
                self.conn.mav.heartbeat_send(
                    mavutil.mavlink.MAV_TYPE_ODID, mavutil.mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0
                )
                if self.status is not None:
                    self.conn.mav.open_drone_id_arm_status_send(self.status[0], self.status[1].encode())
            m = self.conn.recv_match(blocking=True, timeout=0.05)
            if m is not None and m.get_type().startswith("OPEN_DRONE_ID"):
                self.got[m.get_type()] = m

    def __enter__(self) -> Transponder:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(2.0)
        self.conn.close()


def free_instance() -> int:
    """A SITL instance whose SERIAL0 port (5760 + 10 * instance) nobody listens on (another SITL
    on this machine: another test run)."""
    for instance in range(10):
        with socket.socket() as s:
            if s.connect_ex(("127.0.0.1", 5760 + 10 * instance)) != 0:
                return instance
    return 0


@pytest.fixture(scope="module")
def copter_with_did(ardupilot_root, tmp_path_factory) -> Iterator[tuple[ArduCopterSitl, int]]:
    port = free_udp_port()
    log_dir = tmp_path_factory.mktemp("arducopter-remote-id")
    sitl = ArduCopterSitl(
        ardupilot_root,
        instance=free_instance(),
        extra_params={"DID_ENABLE": 1, "DID_MAVPORT": 1, "SERIAL1_PROTOCOL": 2},
        serials={1: f"udpclient:127.0.0.1:{port}"},
        log_path=log_dir / "arducopter.log",
    )
    with sitl:
        yield sitl, port


async def test_remote_id_reaches_the_transponder_and_gates_arming(copter_with_did):
    sitl, port = copter_with_did
    with Transponder(port) as tx:
        ap = ArduPilotAutopilot(sitl.connection, stream_rates_hz=FEW_STREAMS, arm_timeout_s=3.0, remote_id=RID)
        await ap.connect(timeout_s=10.0)
        try:
            # the autopilot forwards our messages to the transponder, our values in them (its copies
            # go round from boot, empty until ours arrive: the latest of each counts)
            await wait_for(lambda: forwarded_ours(tx.got), 10.0, "our BASIC_ID/OPERATOR_ID/SELF_ID/SYSTEM forwarded")
            s = tx.got["OPEN_DRONE_ID_SYSTEM"]
            assert s.operator_location_type == 2 and s.operator_altitude_geo == pytest.approx(600.0)
            assert abs(s.timestamp - (time.time() - 1546300800)) < 5
            assert all(tx.got[n].get_srcComponent() == 1 for n in ODID)  # the autopilot's copies

            # no ARM_STATUS from the transponder: the companion refuses to arm for a delivery
            assert ap.remote_id_gate().verdict is GateVerdict.ABSENT
            with pytest.raises(CommandRejected, match="no OPEN_DRONE_ID_ARM_STATUS") as err:
                await ap.arm()
            assert err.value.kind is CommandResult.DENIED
            assert not ap._armed

            # ArduPilot's own check from here on (EnforceArming): it needs our BASIC_ID, SYSTEM and
            # a good ARM_STATUS, which it takes only on DID_MAVPORT and forwards to us
            assert await ap.read_param("DID_ENABLE") == 1  # this build has AP_OPENDRONEID_ENABLED
            ap._send(lambda mav: mav.param_set_send(1, 1, b"DID_OPTIONS", 1.0, mavutil.mavlink.MAV_PARAM_TYPE_REAL32))
            await wait_for(lambda: ap.params.get("DID_OPTIONS") == 1, 5.0, "DID_OPTIONS = 1 (EnforceArming)")
            await wait_for(lambda: ap._prearm_ok is False, 10.0, "ArduPilot's pre-arm failing without ARM_STATUS")
            tx.status = (mavutil.mavlink.MAV_ODID_ARM_STATUS_PRE_ARM_FAIL_GENERIC, "operator id not registered")
            await wait_for(
                lambda: (
                    ap.remote_id_arm_status is not None
                    and ap.remote_id_arm_status.status is ArmStatus.PRE_ARM_FAIL_GENERIC
                ),
                10.0,
                "the transponder's ARM_STATUS forwarded to the companion",
            )
            with pytest.raises(CommandRejected, match=r"PRE_ARM_FAIL_GENERIC.*operator id not registered"):
                await ap.arm()
            assert ap._prearm_ok is False
            # past our gate, the firmware refuses too, with the transponder's words
            with pytest.raises(CommandRejected, match="OpenDroneID: operator id not registered"):
                await ap._command(mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, what="arm", retries=1)

            # a good ARM_STATUS: ArduPilot's pre-arm passes (our BASIC_ID and SYSTEM are in it), we arm
            tx.status = (mavutil.mavlink.MAV_ODID_ARM_STATUS_GOOD_TO_ARM, "")
            await wait_for(lambda: ap.remote_id_gate().verdict is GateVerdict.GOOD, 10.0, "a good ARM_STATUS")
            await wait_for(lambda: ap._prearm_ok is True, 10.0, "ArduPilot's pre-arm passing")
            await ap.arm()
            await wait_for(lambda: ap._armed, 5.0, "armed")
            await ap.disarm()
        finally:
            await ap.close()
    assert ap.remote_id_sent > 0
