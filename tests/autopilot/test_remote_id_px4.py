"""The PX4 backend's Remote ID (companion.autopilot.px4.remote_id): what it sends and when, and
the JSON MavlinkDirect packs (char arrays as strings, byte arrays as lists)."""

from __future__ import annotations

import json

from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4.remote_id import odid_json, px4_due
from companion.autopilot.remote_id.messages import operator_id, self_id
from companion.autopilot.types import HomePosition
from companion.config import CompanionConfig, RemoteIdConfig

CFG = RemoteIdConfig(enabled=True, uas_id="SN42", operator_id="OP1", self_id="parcel", static_rate_hz=0.5)
HOME = HomePosition(0.0, 47.3977419, 8.5455938, 488.0)


def test_json_for_mavlink_direct() -> None:
    m = operator_id(CFG, 1)
    assert m is not None
    f = json.loads(odid_json(m))
    assert f["operator_id"] == "OP1" and f["id_or_mac"] == [0] * 20 and f["target_component"] == 1
    s = self_id(CFG, 1)
    assert s is not None and json.loads(odid_json(s))["description"] == "parcel"


def test_px4_gets_what_it_reads_system_at_the_update_rate() -> None:
    state: dict[str, float] = {}
    sent = [(i / 10, m.name) for i in range(30) for m in px4_due(CFG, state, i / 10, 1.7e9, HOME, 1)]
    assert [t for t, n in sent if n == "OPEN_DRONE_ID_SYSTEM"] == [0.0, 1.0, 2.0]  # 1 Hz: no SYSTEM_UPDATE on PX4
    assert [t for t, n in sent if n == "OPEN_DRONE_ID_OPERATOR_ID"] == [0.0, 2.0]
    assert not any(n in ("OPEN_DRONE_ID_BASIC_ID", "OPEN_DRONE_ID_SYSTEM_UPDATE") for _, n in sent)
    assert [m.name for m in px4_due(CFG, {}, 0.0, 1.7e9, None, 1)] == [  # home not known yet
        "OPEN_DRONE_ID_SELF_ID",
        "OPEN_DRONE_ID_OPERATOR_ID",
    ]


def test_from_config() -> None:
    on = CompanionConfig.model_validate({"autopilot": "px4", "remote_id": {"enabled": True, "uas_id": "SN42"}})
    assert Px4Autopilot.from_config(on).remote_id == on.remote_id
    assert Px4Autopilot.from_config(CompanionConfig.model_validate({"autopilot": "px4"})).remote_id is None
    assert not Px4Autopilot("udpin://127.0.0.1:1").send_odid(operator_id(CFG, 1))  # type: ignore[arg-type]
