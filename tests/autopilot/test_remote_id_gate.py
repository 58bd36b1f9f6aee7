"""The transponder's ARM_STATUS and the arming gate on it, the schedule of the messages, the
``[remote_id]`` parameters, and the ArduPilot backend's part (companion.autopilot.remote_id,
companion.autopilot.ardupilot.remote_id)."""

from __future__ import annotations

import asyncio

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.interface import CommandRejected, CommandResult
from companion.autopilot.remote_id.arm_status import ArmStatus, ArmStatusReport, GateVerdict, arm_gate
from companion.autopilot.remote_id.schedule import RemoteIdSchedule
from companion.autopilot.types import HomePosition
from companion.config import CompanionConfig, RemoteIdConfig

CFG = RemoteIdConfig(enabled=True, uas_id="SN42", static_rate_hz=0.5, system_update_rate_hz=1.0)
HOME = HomePosition(0.0, -35.36, 149.16, 584.0)


def report(t: float, status: int, error: str = "") -> ArmStatusReport:
    return ArmStatusReport.decode(t, status, error, 1, 236)


def test_arm_status_is_typed() -> None:
    assert ArmStatus.from_wire(0) is ArmStatus.GOOD_TO_ARM
    assert ArmStatus.from_wire(1) is ArmStatus.PRE_ARM_FAIL_GENERIC
    assert ArmStatus.from_wire(7) is ArmStatus.UNKNOWN  # not in the spec: not good
    r = ArmStatusReport.decode(1.0, 1, b"no GPS\x00\x00", 1, 236)
    assert (r.status, r.error, r.raw_status) == (ArmStatus.PRE_ARM_FAIL_GENERIC, "no GPS", 1)


def test_gate_decides_on_the_status() -> None:
    assert arm_gate(False, None, 10.0, 3.0).verdict is GateVerdict.OFF
    assert arm_gate(False, None, 10.0, 3.0).may_arm
    d = arm_gate(True, None, 10.0, 3.0)
    assert d.verdict is GateVerdict.ABSENT and not d.may_arm and "no OPEN_DRONE_ID_ARM_STATUS" in d.reason
    d = arm_gate(True, report(6.0, 0), 10.0, 3.0)
    assert d.verdict is GateVerdict.STALE and "4.0 s old" in d.reason
    d = arm_gate(True, report(9.0, 1, "UAS ID not set"), 10.0, 3.0)
    assert d.verdict is GateVerdict.NOT_GOOD and d.reason.endswith("PRE_ARM_FAIL_GENERIC (status 1): UAS ID not set")
    assert arm_gate(True, report(9.0, 9), 10.0, 3.0).verdict is GateVerdict.NOT_GOOD
    d = arm_gate(True, report(9.0, 0), 10.0, 3.0)
    assert d.verdict is GateVerdict.GOOD and d.may_arm


def test_schedule_rates() -> None:
    s = RemoteIdSchedule(CFG, 1)
    sent: list[tuple[float, str]] = []
    for i in range(40):  # 10 Hz ticks, as the backend's sender
        t = i / 10
        sent += [(t, m.name) for m in s.due(t, 1.7e9 + t, HOME)]
    static = [t for t, n in sent if n == "OPEN_DRONE_ID_BASIC_ID"]
    assert static == [0.0, 2.0]  # 0.5 Hz
    system_times = [t for t, n in sent if n in ("OPEN_DRONE_ID_SYSTEM", "OPEN_DRONE_ID_SYSTEM_UPDATE")]
    assert system_times == [0.0, 1.0, 2.0, 3.0]  # the operator location at 1 Hz, SYSTEM included
    assert not any(n in ("OPEN_DRONE_ID_SELF_ID", "OPEN_DRONE_ID_OPERATOR_ID") for _, n in sent)  # none set


def test_schedule_without_updates_or_home() -> None:
    s = RemoteIdSchedule(CFG.model_copy(update={"system_update_rate_hz": 0.0}), 1)
    names = [m.name for t in range(5) for m in s.due(float(t), 1.7e9, None)]
    assert names == ["OPEN_DRONE_ID_BASIC_ID"] * 3  # no home yet: no SYSTEM, no SYSTEM_UPDATE


def test_parameters() -> None:
    assert not RemoteIdConfig().enabled
    assert CompanionConfig().remote_id == RemoteIdConfig()
    with pytest.raises(ValueError, match=r"needs remote_id\.uas_id"):
        RemoteIdConfig(enabled=True)
    with pytest.raises(ValueError, match="needs operator_lat_deg"):
        RemoteIdConfig(enabled=True, uas_id="x", operator_location="fixed")
    with pytest.raises(ValueError, match="printable ASCII"):
        RemoteIdConfig(uas_id="näh")
    with pytest.raises(ValueError):
        RemoteIdConfig(operator_id="x" * 21)
    with pytest.raises(ValueError):
        RemoteIdConfig(self_id="x" * 24)
    with pytest.raises(ValueError):
        RemoteIdConfig(ua_type=16)
    for name, field in RemoteIdConfig.model_fields.items():
        extra = field.json_schema_extra
        assert field.description and isinstance(extra, dict) and extra.get("unit"), name


def _arm_status_message(status: int, error: bytes) -> mavlink.MAVLink_message:
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=mavlink.MAV_COMP_ID_ODID_TXRX_1)
    return mav.decode(bytearray(mavlink.MAVLink_open_drone_id_arm_status_message(status, error).pack(mav)))


async def test_backend_keeps_arm_status_and_refuses_to_arm() -> None:
    ap = ArduPilotAutopilot("udpin:127.0.0.1:1", arm_timeout_s=0.5, remote_id=CFG)
    ap.attach_loop(asyncio.get_running_loop())
    with pytest.raises(CommandRejected, match="no OPEN_DRONE_ID_ARM_STATUS") as err:
        await ap.arm()
    assert err.value.kind is CommandResult.DENIED and err.value.permanent
    # from the transponder's own system id, before the vehicle's is known: kept all the same
    ap.handle_message(_arm_status_message(1, b"operator id missing"))
    await asyncio.sleep(0)
    assert ap.remote_id_arm_status is not None
    assert ap.remote_id_arm_status.status is ArmStatus.PRE_ARM_FAIL_GENERIC
    assert ap.remote_id_arm_status.src_component == mavlink.MAV_COMP_ID_ODID_TXRX_1
    with pytest.raises(CommandRejected, match="operator id missing"):
        await ap.arm()
    ap.handle_message(_arm_status_message(0, b""))
    await asyncio.sleep(0)
    assert ap.remote_id_gate().verdict is GateVerdict.GOOD


def test_backend_from_config() -> None:
    rid = {"enabled": True, "uas_id": "SN42"}
    cfg = CompanionConfig.model_validate({"autopilot": "ardupilot", "remote_id": rid})
    assert ArduPilotAutopilot.from_config(cfg).remote_id == cfg.remote_id
    off = ArduPilotAutopilot.from_config(CompanionConfig.model_validate({"autopilot": "ardupilot"}))
    assert off.remote_id is None and off.remote_id_gate().verdict is GateVerdict.OFF


def test_backend_packs_every_message() -> None:
    ap = ArduPilotAutopilot("udpin:127.0.0.1:1", remote_id=CFG)
    packed: list[bytes] = []
    ap._send = lambda fn: (fn(_Capture(packed)), True)[1]  # type: ignore[method-assign]
    full = CFG.model_copy(update={"self_id": "parcel", "operator_id": "OP1"})
    for m in RemoteIdSchedule(full, 1).due(0.0, 1.7e9, HOME):
        assert ap.send_odid(m)
    assert ap.remote_id_sent == 4 and len(packed) == 4


class _Capture:
    def __init__(self, out: list[bytes]):
        self.out = out
        self.mav = mavlink.MAVLink(None)

    def send(self, msg: mavlink.MAVLink_message) -> None:
        self.out.append(msg.pack(self.mav))
