"""On a real ArduCopter SITL, order after order over real Zenoh (docs/orders.md): one `fly --orders`
session (one companion, one autopilot link kept between flights, ArduCopter never restarted), the
ground on a Zenoh peer session of its own. Order 1 is delivered; an order while it flies is refused
as busy; an order beyond the range is refused with its reason; order 2 to another pad is delivered
(tests/conftest.py orders_scenario)."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.config import load_config, shipped_params_path
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_lab.real_campaign import firmware_tuning

from .conftest import GRIPPER_SERVO9

pytestmark = pytest.mark.firmware

SECRET = b"apm-orders-secret-0123456789"


async def test_arducopter_order_after_order_over_zenoh(ardupilot_root, tmp_path, mav) -> None:  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(0o600)  # a secret others can read is refused
    sitl = ArduCopterSitl(ardupilot_root, extra_params=dict(GRIPPER_SERVO9), log_path=tmp_path / "arducopter.log")
    with sitl:
        tuning = firmware_tuning("ardupilot")
        config = load_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "autopilot": "ardupilot",
                "connection": sitl.connection,
                "mission": {**tuning["mission"], "ready_timeout_s": 120.0},  # EKF3 uses GPS ~41 s after boot
                "landing": tuning["landing"],
                "telemetry": {"enabled": True, "commands": {"enabled": True, "secret_file": str(secret)}},
            },
        )
        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        session, replies = await mav.orders_scenario(
            config, ap, SECRET, tmp_path / "session", ready_timeout_s=150.0, flight_timeout_s=300.0
        )
    assert replies["o-busy"].reason == "busy: flying order o-1", replies["o-busy"]
    assert replies["o-far"].reason.startswith("out of range: the pad is 1"), replies["o-far"]
    flights = [(f.order_id, f.delivered, f.returned, f.failure) for f in session.flights]
    assert flights == [("o-1", True, True, ""), ("o-2", True, True, "")], flights
    assert (session.accepted, session.refused) == (2, 2)
    print("\n" + "\n".join(e.detail for e in session.events))
