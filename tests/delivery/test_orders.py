"""The vehicle's checks of a delivery order (companion.delivery.orders): each refusal with its
reason, the configuration an accepted order is flown with, and the desk's busy rule and log."""

from __future__ import annotations

import asyncio
import csv
import math
from types import SimpleNamespace

import pytest

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import FlightMode, HomePosition, LandedState, PositionNed, VehicleStatus, Wind
from companion.config import config_from_dict, load_config, shipped_params_path
from companion.delivery.orders import OrderDesk, VehicleSnapshot, check_order
from companion.events import EventKind
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion.telemetry.auth import CommandSettings
from companion.telemetry.orders import DeliveryOrder, OrderPad, OrderRefused, sign_order

SECRET = b"0123456789abcdef-secret"
HOME = GeoPoint(-19.869, -43.9638, 850.0)  # params/sitl_short.toml's sim.home


def pad_at(north_m: float, east_m: float, alt: float | None = None) -> OrderPad:
    g = ned_to_geo(HOME, north_m, east_m, 0.0)
    return OrderPad(g.lat_deg, g.lon_deg, alt)


def order(pad: OrderPad, alternate: OrderPad | None = None, order_id: str = "o-1") -> DeliveryOrder:
    return DeliveryOrder("sitl1", order_id, pad.as_signed(), alternate, 0.0, 0.0, "ab" * 8, "ground")


def snapshot(
    battery_pct: float = 90.0, armed: bool = False, wind: Wind | None = None, now_s: float = 100.0, home: bool = True
) -> VehicleSnapshot:
    st = VehicleStatus(now_s, armed, FlightMode.HOLD, LandedState.ON_GROUND, True, battery_pct, False)
    h = HomePosition(now_s, HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m) if home else None
    pos = PositionNed(now_s, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return VehicleSnapshot(now_s, st, h, pos, wind)


@pytest.fixture
def config():  # type: ignore[no-untyped-def]
    return load_config(shipped_params_path("sitl_short.toml"))


def with_(config, **sections):  # type: ignore[no-untyped-def]
    data = config.model_dump()
    for k, v in sections.items():
        data[k] = {**data[k], **v}
    return config_from_dict(data, "test")


def refusal(config, o: DeliveryOrder, snap: VehicleSnapshot, busy: str | None = None) -> str:  # type: ignore[no-untyped-def]
    with pytest.raises(OrderRefused) as info:
        check_order(config, o, snap, busy)
    return info.value.reason


def test_an_order_in_range_is_flown_with_its_pad_and_alternate(config) -> None:  # type: ignore[no-untyped-def]
    alt = pad_at(-10.0, 12.0).as_signed()
    cfg = check_order(config, order(pad_at(14.0, 14.0, 851.0), alt), snapshot(), None)
    p = cfg.mission.pad
    assert p.north_m is None and p.lon_deg == pad_at(14.0, 14.0).as_signed().lon_deg
    assert p.lat_deg == pad_at(14.0, 14.0).as_signed().lat_deg and p.alt_amsl_m == 851.0
    assert cfg.mission.alternate_pad is not None and cfg.mission.alternate_pad.lat_deg == alt.lat_deg
    assert cfg.mission.height_m == config.mission.height_m and config.mission.pad.north_m == 14.0  # untouched


def test_busy_while_an_order_is_flown(config) -> None:  # type: ignore[no-untyped-def]
    assert refusal(config, order(pad_at(14, 14)), snapshot(), busy="o-7") == "busy: flying order o-7"


def test_busy_while_the_vehicle_is_armed(config) -> None:  # type: ignore[no-untyped-def]
    assert refusal(config, order(pad_at(14, 14)), snapshot(armed=True)).startswith("busy: the vehicle is armed")


@pytest.mark.parametrize(
    ("pad", "words"),
    [
        (OrderPad(95.0, -43.9638), "destination: pad.lat_deg = 95.0: expected a finite value within +-90 deg"),
        (OrderPad(-19.869, 190.0), "destination: pad.lon_deg = 190.0"),
        (OrderPad(math.nan, -43.9638), "destination: pad.lat_deg = nan"),  # the wire refuses it first, too
    ],
)
def test_malformed_values_are_refused_by_name(config, pad: OrderPad, words: str) -> None:  # type: ignore[no-untyped-def]
    assert refusal(config, order(pad), snapshot()).startswith(words)


def test_a_pad_far_above_home_is_refused_by_the_height_limit(config) -> None:  # type: ignore[no-untyped-def]
    why = refusal(config, order(pad_at(14, 14, HOME.alt_amsl_m + 40.0)), snapshot())
    assert why.startswith("outside the flyable area: the outbound leg leaves the fence")
    assert "above limits.geofence_max_alt_m = 30 m" in why


def test_a_pad_outside_the_fence_is_refused(config) -> None:  # type: ignore[no-untyped-def]
    ring = [ned_to_geo(HOME, n, e, 0.0) for n, e in ((-40, -40), (-40, 40), (40, 40), (40, -40))]
    fenced = with_(
        config,
        fence={
            "enabled": True,
            "upload": False,
            "inclusion": [{"vertices_deg": [[g.lat_deg, g.lon_deg] for g in ring]}],
        },
    )
    check_order(fenced, order(pad_at(14, 14)), snapshot(), None)  # inside: accepted
    why = refusal(fenced, order(pad_at(60, 0)), snapshot())
    assert why.startswith("destination: fence: mission.pad") and "outside inclusion polygon 0" in why
    # a pad inside, closer to the edge than fence.margin_m: the path check refuses it
    why = refusal(fenced, order(pad_at(37, 0)), snapshot())
    assert why.startswith("outside the flyable area: the outbound leg leaves the fence") and "margin_m" in why


def test_a_pad_beyond_the_range_is_refused(config) -> None:  # type: ignore[no-untyped-def]
    why = refusal(config, order(pad_at(150.0, 0.0)), snapshot())
    assert why == "out of range: the pad is 150.0 m from home, beyond limits.geofence_radius_m = 100 m"


def test_an_alternate_beyond_the_range_is_refused(config) -> None:  # type: ignore[no-untyped-def]
    why = refusal(config, order(pad_at(14, 14), pad_at(0.0, -120.0).as_signed()), snapshot())
    assert why == "out of range: the alternate pad is 120.0 m from home, beyond limits.geofence_radius_m = 100 m"


def test_a_pad_where_the_vehicle_stands_is_refused(config) -> None:  # type: ignore[no-untyped-def]
    assert refusal(config, order(pad_at(0.0, 0.0)), snapshot()).startswith("path: the pad is where the vehicle stands")


def test_no_home_yet_is_not_ready(config) -> None:  # type: ignore[no-untyped-def]
    assert refusal(config, order(pad_at(14, 14)), snapshot(home=False)) == (
        "vehicle not ready: no home from the autopilot yet"
    )


def test_wind_above_the_limit_or_unknown_is_no_go(config) -> None:  # type: ignore[no-untyped-def]
    windy = with_(config, go_no_go={"wind_limit_m_s": 8.0})
    why = refusal(windy, order(pad_at(14, 14)), snapshot(wind=Wind(99.0, 9.0, 3.0)))
    assert why.startswith("no-go: wind 9.5 m/s (the autopilot's estimate) above go_no_go.wind_limit_m_s = 8 m/s")
    assert refusal(windy, order(pad_at(14, 14)), snapshot(wind=None)) == (
        "no-go: no fresh wind estimate from the autopilot"
    )
    assert refusal(windy, order(pad_at(14, 14)), snapshot(wind=Wind(90.0, 1.0, 0.0))).startswith("no-go: no fresh")
    check_order(windy, order(pad_at(14, 14)), snapshot(wind=Wind(99.5, 3.0, 0.0)), None)


def test_a_battery_without_the_round_trip_is_no_go(config) -> None:  # type: ignore[no-untyped-def]
    cfg = with_(config, go_no_go={"battery_check": True, "battery_use_pct_per_s": 1.0, "battery_reserve_pct": 20.0})
    check_order(cfg, order(pad_at(14, 14)), snapshot(battery_pct=90.0), None)
    why = refusal(cfg, order(pad_at(14, 14)), snapshot(battery_pct=30.0))
    assert why.startswith("no-go: not enough charge for the round trip: battery 30.0 % left")
    # a farther pad needs more: the charge that covers the near one does not cover it
    near_ok = check_order(cfg, order(pad_at(14, 14)), snapshot(battery_pct=60.0), None)
    assert near_ok is not None
    assert refusal(cfg, order(pad_at(90, 0)), snapshot(battery_pct=60.0)).startswith("no-go: not enough charge")


# ---- the desk ------------------------------------------------------------------------------------


def _desk(config, tmp_path, telemetry: TelemetryCache):  # type: ignore[no-untyped-def]
    events = []
    desk = OrderDesk(
        config,
        telemetry,
        CommandSettings(enabled=True, secret=SECRET),
        csv_path=tmp_path / "orders.csv",
        on_event=events.append,
    )
    return desk, events


def _telemetry() -> TelemetryCache:
    tc = TelemetryCache()
    snap = snapshot()
    tc.status, tc.home, tc.position_ned = snap.status, snap.home, snap.position_ned
    return tc


async def test_the_desk_takes_one_order_at_a_time_and_logs_every_one(config, tmp_path) -> None:  # type: ignore[no-untyped-def]
    desk, events = _desk(config, tmp_path, _telemetry())
    # started on this loop with a session that takes the queryable and answers nothing
    desk.start(SimpleNamespace(declare_queryable=lambda key, on_query: SimpleNamespace(undeclare=lambda: None)))

    def send(pad: OrderPad, oid: str) -> tuple[bool, str | None, str]:
        return desk.decide(sign_order("sitl1", pad, SECRET, order_id=oid))

    assert send(pad_at(14, 14), "o-1") == (True, "o-1", "accepted: flying it now")
    accepted = await asyncio.wait_for(desk.next_order(), 1.0)
    assert accepted.order.order_id == "o-1" and accepted.config.mission.pad.lat_deg is not None
    assert send(pad_at(-10, 12), "o-2") == (False, "o-2", "busy: flying order o-1")
    desk.finished("o-1", "delivered, returned home")
    assert send(pad_at(-10, 12), "o-3")[0] is True
    desk.finished("o-3", "delivered")
    assert send(pad_at(500, 0), "o-4") == (
        False,
        "o-4",
        "out of range: the pad is 500.0 m from home, beyond limits.geofence_radius_m = 100 m",
    )
    assert desk.decide(b"{}") == (False, None, "malformed order: schema is not 'companion.order/1'")
    desk.stop()
    assert (desk.accepted, desk.refused) == (2, 3)
    assert all(e.kind is EventKind.ORDER for e in events)
    details = [e.detail for e in events]
    assert details[0] == "order o-1 from ground: ACCEPTED: accepted: flying it now"
    assert details[1] == "order o-2 from ground: REFUSED: busy: flying order o-1"
    assert "order o-1 flown: delivered, returned home" in details
    assert details[-1].startswith("an unreadable order: REFUSED: malformed order")
    rows = list(csv.DictReader((tmp_path / "orders.csv").open()))
    assert [(r["order_id"], r["accepted"]) for r in rows] == [
        ("o-1", "1"),
        ("o-2", "0"),
        ("o-3", "1"),
        ("o-4", "0"),
        ("", "0"),
    ]
    assert rows[1]["reason"] == "busy: flying order o-1" and math.isclose(
        float(rows[0]["pad_lat_deg"]), pad_at(14, 14).as_signed().lat_deg
    )
