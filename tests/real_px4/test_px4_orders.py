"""On the real PX4 v1.16 SIH, order after order over real Zenoh (docs/orders.md): one `fly --orders`
session (one companion, one autopilot link kept between flights, PX4 never restarted), the ground
on a Zenoh peer session of its own. Order 1 is delivered; an order while it flies is refused as
busy; an order beyond the range is refused with its reason; order 2 to another pad is delivered
(tests/conftest.py orders_scenario)."""

from __future__ import annotations

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import FlightMode
from companion.config import load_config, shipped_params_path
from companion_firmware.px4_sitl import Px4Sitl
from companion_lab.real_campaign import firmware_tuning

pytestmark = pytest.mark.firmware

SECRET = b"px4-orders-secret-0123456789"


async def test_px4_order_after_order_over_zenoh(px4_root, tmp_path, mav) -> None:  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(0o600)  # a secret others can read is refused
    tuning = firmware_tuning("px4")
    config = load_config(
        shipped_params_path("sitl_short.toml"),
        overrides={
            "connection": "udpin://127.0.0.1:14540",
            "autopilot": "px4",
            "mission": {**tuning["mission"], "ready_timeout_s": 60.0},
            "landing": tuning["landing"],
            "telemetry": {"enabled": True, "commands": {"enabled": True, "secret_file": str(secret)}},
        },
    )
    with Px4Sitl(px4_root, log_path=tmp_path / "px4.log"):
        ap = Px4Autopilot.from_config(config)
        session, replies = await mav.orders_scenario(config, ap, SECRET, tmp_path / "session", flight_timeout_s=240.0)
        assert ap.telemetry.status.mode is FlightMode.HOLD and not ap.telemetry.status.armed  # ready for the next
    assert replies["o-busy"].reason == "busy: flying order o-1", replies["o-busy"]
    assert replies["o-far"].reason.startswith("out of range: the pad is 1"), replies["o-far"]
    flights = [(f.order_id, f.delivered, f.returned, f.failure) for f in session.flights]
    assert flights == [("o-1", True, True, ""), ("o-2", True, True, "")], flights
    assert (session.accepted, session.refused) == (2, 2)
    print("\n" + "\n".join(e.detail for e in session.events))
