"""Delivery orders into the vehicle's order desk, and ground commands into a running publisher over
Zenoh on loopback.

Rule: every payload is answered (accepted or refused, never an exception: a 401-digit latitude or
issued time is refused as malformed before any float conversion); a refused one is counted once
and changes nothing (no order queued, the desk not busy, no command handed to the mission); only a
payload whose signed fields are a seed's is ever accepted."""

from __future__ import annotations

import asyncio
import csv
import json
import time
from pathlib import Path

import pytest

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import FlightMode, HomePosition, LandedState, PositionNed, VehicleStatus
from companion.config import load_config, shipped_params_path
from companion.delivery.orders import OrderDesk
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion.telemetry.auth import CommandKind, CommandSettings, GroundCommand, sign_command
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.orders import OrderPad, sign_order
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import command_key

from . import harness

pytestmark = pytest.mark.fuzz

SECRET = b"0123456789abcdef-fuzz-orders"
NOW = 1.7e9
HOME = GeoPoint(-19.869, -43.9638, 850.0)  # params/sitl_short.toml's sim.home
SIGNED_KEYS = ("vehicle_id", "order_id", "pad", "alternate", "issued_unix_ms", "nonce", "sender", "note")


def _pad(north_m: float, east_m: float) -> OrderPad:
    g = ned_to_geo(HOME, north_m, east_m, 0.0)
    return OrderPad(g.lat_deg, g.lon_deg)


ORDER_SEEDS = [
    sign_order("sitl1", _pad(14, 14), SECRET, order_id="o-1", issued_unix_s=NOW, nonce=f"{1:032x}"),
    sign_order("sitl1", _pad(500, 0), SECRET, order_id="o-2", issued_unix_s=NOW, nonce=f"{2:032x}", note="far"),
    sign_order("sitl1", _pad(-10, 12), SECRET, order_id="o-3", alternate=_pad(5, 5), issued_unix_s=NOW),
]
_BIG = b"4" + b"0" * 400  # a 401-digit integer: float() of it raises OverflowError
ORDER_NASTY = [
    b"",
    b"{}",
    b"[" * 5000 + b"]" * 5000,
    ORDER_SEEDS[0].replace(b'"lat_deg":', b'"lat_deg":' + _BIG + b',"x":', 1),
    ORDER_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":' + _BIG + b',"x":'),
    ORDER_SEEDS[0].replace(b'"lon_deg":', b'"lon_deg":-' + _BIG + b',"x":', 1),
    ORDER_SEEDS[0].replace(b'"lat_deg":', b'"lat_deg":1e308,"x":', 1),
    ORDER_SEEDS[0].replace(b'"lat_deg":', b'"lat_deg":NaN,"x":', 1),
    ORDER_SEEDS[2].replace(b'"alternate":{', b'"alternate":{"alt_amsl_m":' + _BIG + b","),
    ORDER_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":-1,"x":'),
    ORDER_SEEDS[0].replace(b'"pad":{', b'"pad":[{'),
    ORDER_SEEDS[0].replace(b'"note":""', b'"note":' + json.dumps("x" * 100000).encode()),
]


def _signed(payload: bytes, keys: tuple[str, ...]) -> str:
    doc = {"note": "", "alternate": None, **json.loads(payload)}
    return json.dumps({k: doc.get(k) for k in keys}, sort_keys=True)


def _telemetry() -> TelemetryCache:
    tc = TelemetryCache()
    tc.status = VehicleStatus(100.0, False, FlightMode.HOLD, LandedState.ON_GROUND, True, 90.0, False)
    tc.home = HomePosition(100.0, HOME.lat_deg, HOME.lon_deg, HOME.alt_amsl_m)
    tc.position_ned = PositionNed(100.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    return tc


def test_orders_into_the_desk(fuzz_budget: int, tmp_path: Path) -> None:
    config = load_config(shipped_params_path("sitl_short.toml"))
    signed = {_signed(s, SIGNED_KEYS) for s in ORDER_SEEDS}
    mono = [0.0]
    desk = OrderDesk(
        config,
        _telemetry(),
        CommandSettings(enabled=True, secret=SECRET, burst=10_000, max_nonces=1_000_000, max_requests_per_s=2000.0),
        csv_path=tmp_path / "orders.csv",
        wall_clock=lambda: NOW + mono[0],
        monotonic=lambda: mono[0],
    )
    loop = asyncio.new_event_loop()
    tried = [0]

    async def decide(payload: bytes) -> str:
        before = (desk.accepted, desk.refused)
        mono[0] += 0.001  # time moves on; the window of 5 s holds the seeds for the whole test
        accepted, order_id, reason = desk.decide(payload)
        tried[0] += 1
        assert desk.accepted + desk.refused == before[0] + before[1] + 1, "every order counted once"
        if not accepted:
            assert (desk.accepted, desk.busy_with) == (before[0], None), f"a refusal changed the desk: {reason}"
            assert reason and desk.refused == before[1] + 1
            return "refused"
        assert _signed(payload, SIGNED_KEYS) in signed, f"accepted an order nobody signed: {payload[:200]!r}"
        got = await asyncio.wait_for(desk.next_order(), 1.0)
        assert got.order.order_id == order_id == desk.busy_with
        desk.finished(order_id, "not flown (fuzz)")
        return "accepted (signed)"

    def feed(payload: bytes) -> str:
        return loop.run_until_complete(decide(payload))

    try:
        for p in ORDER_SEEDS + ORDER_NASTY:
            harness.check("delivery orders (desk)", feed, p, ())
        harness.run(
            harness.fuzz_bytes(ORDER_SEEDS + ORDER_NASTY),
            lambda p: harness.check("delivery orders (desk)", feed, p, ()),
            fuzz_budget,
        )
    finally:
        desk.stop()
        loop.close()
    assert desk.accepted >= 2  # o-1 and o-3 once each; o-2 is out of range
    rows = list(csv.DictReader((tmp_path / "orders.csv").open()))
    decided = [r for r in rows if r["order_id"]]  # rows of the vehicle's checks: one per decision
    assert len(decided) == desk.accepted + desk.refused_by_vehicle
    assert desk.refusals.total + desk.refused_by_vehicle + desk.accepted == tried[0]


CMD_SEEDS = [
    sign_command("drone1", k, SECRET, issued_unix_s=NOW, nonce=f"{i:032x}", note=n)
    for i, (k, n) in enumerate([(CommandKind.HOLD, ""), (CommandKind.LAND, "pad 2"), (CommandKind.ABORT, "ü")])
]
CMD_NASTY = [
    b"",
    CMD_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":' + _BIG + b',"x":'),
    CMD_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":1e308,"x":'),
    CMD_SEEDS[1].replace(b'"land"', b'"LAND"'),
    b"[" * 5000 + b"]" * 5000,
]
CMD_KEYS = ("vehicle_id", "command", "issued_unix_ms", "nonce", "sender", "note")


def test_ground_commands_into_a_running_publisher(fuzz_budget: int) -> None:
    port = free_tcp_port()
    handed: list[GroundCommand] = []
    settings = TelemetrySettings(
        "drone1",
        commands=CommandSettings(
            enabled=True, secret=SECRET, burst=10_000, max_nonces=1_000_000, max_requests_per_s=100_000.0
        ),
    )
    start = time.monotonic()
    pub = TelemetryPublisher(
        settings,
        loopback_settings(listen_port=port),
        on_command=handed.append,
        wall_clock=lambda: NOW + (time.monotonic() - start),
    ).start()
    ground = loopback_settings(connect_port=port).open()
    signed = {_signed(s, CMD_KEYS) for s in CMD_SEEDS}
    sent = [0]

    def feed(payload: bytes) -> str:
        before_handed, before = len(handed), pub.counters()
        replies = list(ground.get(command_key("drone1"), payload=payload, timeout=5.0))
        sent[0] += 1
        assert len(replies) == 1, "every command is answered"
        after = pub.counters()
        counted = (after.commands_accepted - before.commands_accepted, after.commands_refused - before.commands_refused)
        if replies[0].ok is None:
            assert counted == (0, 1) and len(handed) == before_handed, "a refusal reached the mission"
            return "refused"
        assert counted == (1, 0) and len(handed) == before_handed + 1
        assert _signed(payload, CMD_KEYS) in signed, f"accepted a command nobody signed: {payload[:200]!r}"
        return "accepted (signed)"

    try:
        deadline = time.monotonic() + 5.0
        while not list(ground.get(command_key("drone1"), payload=b"{}", timeout=1.0)):
            assert time.monotonic() < deadline, "the ground never reached the vehicle"
        sent[0] += 1
        for p in CMD_SEEDS + CMD_NASTY:
            harness.check("ground commands (publisher)", feed, p, ())
        harness.run(
            harness.fuzz_bytes(CMD_SEEDS + CMD_NASTY),
            lambda p: harness.check("ground commands (publisher)", feed, p, ()),
            fuzz_budget,
        )
        c = pub.counters()
        assert c.commands_accepted + c.commands_refused == sent[0]
        assert pub.refusal_counts()["ground_commands"] == c.commands_refused
    finally:
        ground.close()
        pub.stop()
