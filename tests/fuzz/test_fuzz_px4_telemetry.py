"""MAVSDK's telemetry streams into the PX4 backend: items of every stream the backend pushes from
(position, attitude, IMU, raw GPS, status text, mode, armed, landed state, health) with fields
NaN, infinite, huge, None or of the wrong type, and MavlinkDirect's HEARTBEAT, HOME_POSITION and
RC_CHANNELS as their JSON (valid, torn, mutated, hostile), each through the backend's stream
consumer (``_consume``) as MAVSDK hands it over.

Rule: every item ends as a sample the telemetry cache takes in or rejects (counted in
``received`` / ``rejected``), a counted ``decode_errors``, a counted foreign heartbeat, or is
another system's message (ignored by design); the stream is never lost over an item (it ends
only when MAVSDK's does)."""

from __future__ import annotations

import asyncio
import json
import math
from collections.abc import AsyncIterator, Callable
from types import SimpleNamespace
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.autopilot.px4 import Px4Autopilot

from . import harness

pytestmark = pytest.mark.fuzz

SURFACE = "mavsdk telemetry -> px4 backend"
_F = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.sampled_from([0.0, 1.0, -1.0, math.nan, math.inf, -math.inf, 1e308, None, "x", True]),
)


def _ns(**kw: Any) -> SimpleNamespace:
    return SimpleNamespace(**kw)


#: stream handler name -> a strategy for its items (MAVSDK's objects, fields as they are named)
ITEMS: dict[str, st.SearchStrategy[Any]] = {
    "on_pv": st.builds(
        lambda a, b, c, d, e, f: _ns(
            position=_ns(north_m=a, east_m=b, down_m=c), velocity=_ns(north_m_s=d, east_m_s=e, down_m_s=f)
        ),
        _F,
        _F,
        _F,
        _F,
        _F,
        _F,
    ),
    "on_pos": st.builds(
        lambda a, b, c, d: _ns(latitude_deg=a, longitude_deg=b, absolute_altitude_m=c, relative_altitude_m=d),
        _F,
        _F,
        _F,
        _F,
    ),
    "on_att": st.builds(lambda a, b, c: _ns(roll_deg=a, pitch_deg=b, yaw_deg=c), _F, _F, _F),
    "on_imu": st.builds(
        lambda a, b, c, d, e, f: _ns(
            acceleration_frd=_ns(forward_m_s2=a, right_m_s2=b, down_m_s2=c),
            angular_velocity_frd=_ns(forward_rad_s=d, right_rad_s=e, down_rad_s=f),
        ),
        _F,
        _F,
        _F,
        _F,
        _F,
        _F,
    ),
    "on_raw_gps": st.builds(
        lambda a, b, c, d, e: _ns(
            latitude_deg=a, longitude_deg=b, absolute_altitude_m=c, horizontal_uncertainty_m=d, hdop=e
        ),
        _F,
        _F,
        _F,
        _F,
        _F,
    ),
    "on_text": st.builds(
        lambda t, n: _ns(text=t, type=_ns(name=n)),
        st.one_of(st.text(max_size=300), st.none(), st.binary(max_size=20)),
        st.sampled_from(["INFO", "CRITICAL", "?", ""]),
    ),
    "on_mode": st.one_of(st.builds(lambda n: _ns(name=n), st.text(max_size=12)), st.integers(), st.none()),
    "on_armed": st.one_of(st.booleans(), st.none(), st.integers(), st.text(max_size=3)),
    "on_landed": st.one_of(st.builds(lambda n: _ns(name=n), st.sampled_from(["IN_AIR", "ON_GROUND", "x"])), st.none()),
    "on_health": st.builds(
        lambda a, b, c: _ns(is_armable=a, is_global_position_ok=b, is_home_position_ok=c),
        st.booleans(),
        st.booleans(),
        st.one_of(st.booleans(), st.none()),
    ),
}
_HB = {"type": 2, "autopilot": 12, "base_mode": 157, "custom_mode": 0x04040000, "system_status": 4}
_HOME = {"latitude": -198690000, "longitude": -439638000, "altitude": 850000, "x": 0.0, "y": 0.0, "z": 0.0}
_RC = {"chancount": 8, **{f"chan{i}_raw": 1500 for i in range(1, 19)}}
JSON_SEEDS = {
    "on_heartbeat": [json.dumps(_HB).encode(), json.dumps({**_HB, "type": 6, "autopilot": 8}).encode()],
    "on_home_position": [
        json.dumps(_HOME).encode(),
        b'{"latitude": Infinity, "longitude": 0, "altitude": 0}',
        b'{"latitude": 1e400, "longitude": 0, "altitude": 0}',
        b'{"latitude": -198690000, "longitude": -439638000, "altitude": 850000, "x": NaN}',
        b'{"latitude": 900000001, "longitude": 0, "altitude": 0}',
        b"[1, 2, 3]",
    ],
    "on_rc_channels": [json.dumps(_RC).encode(), b'{"chancount": 1e400}', b'{"chancount": 18, "chan1_raw": "x"}'],
}
_SYSTEMS = st.sampled_from([1, 1, 1, 2, 255])
DIRECT = {
    name: st.builds(
        lambda s, c, j: _ns(system_id=s, component_id=c, fields_json=j.decode("utf-8", "replace")),
        _SYSTEMS,
        st.sampled_from([1, 1, 191]),
        harness.fuzz_bytes(seeds, max_random=120),
    )
    for name, seeds in JSON_SEEDS.items()
}
CASES = st.one_of(*(st.tuples(st.just(k), v) for k, v in {**ITEMS, **DIRECT}.items()))


def _handlers(ap: Px4Autopilot) -> dict[str, Callable[[Any], None]]:
    ap._tel = SimpleNamespace(**{f"subscribe_{k}": None for k in _SUBSCRIPTIONS})  # only looked up here

    def now() -> float:
        return 1.0

    fns = [fn for _, fn in ap._motion_streams(now) + ap._state_streams(now)] + [fn for _, fn in ap._direct_streams(now)]
    return {fn.__name__: fn for fn in fns}


_SUBSCRIPTIONS = (
    "position_velocity_ned", "position", "attitude_euler", "attitude_angular_velocity_body", "imu", "gps_info",
    "raw_gps", "flight_mode", "armed", "landed_state", "battery", "health", "status_text", "home",
)  # fmt: skip


def _counts(ap: Px4Autopilot) -> tuple[int, int, int, int]:
    t = ap.telemetry
    return sum(t.received.values()), sum(t.rejected.values()), ap.decode_errors, ap.foreign_heartbeats


async def _through(ap: Px4Autopilot, fn: Callable[[Any], None], item: Any) -> None:
    async def one() -> AsyncIterator[Any]:
        yield item

    restarted = ap.streams_restarted
    task = asyncio.get_running_loop().create_task(ap._consume(one, fn))
    while ap.streams_restarted == restarted and not task.done():
        await asyncio.sleep(0)
    task.cancel()
    await asyncio.gather(task, return_exceptions=True)
    assert ap.streams_restarted == restarted + 1, "the stream was lost over one item"


def test_mavsdk_items_into_the_px4_backend(fuzz_budget: int) -> None:
    ap = Px4Autopilot("udpin://127.0.0.1:14540")
    fns = _handlers(ap)
    loop = asyncio.new_event_loop()

    def feed(case: tuple[str, Any]) -> str:
        name, item = case
        before = _counts(ap)
        loop.run_until_complete(_through(ap, fns[name], item))
        got, rejected, errors, foreign = (a - b for a, b in zip(_counts(ap), before, strict=True))
        if errors:
            return "decode error (counted)"
        if rejected:
            return "rejected (counted)"
        if got:
            return "taken in"
        if foreign:
            return "foreign heartbeat (counted)"
        theirs = getattr(item, "system_id", 1) != 1 or (name == "on_heartbeat" and item.component_id != 1)
        assert theirs, f"{name}: an item neither taken in nor counted: {item!r:.300}"
        return "another system's (ignored)"

    try:
        for name, seeds in JSON_SEEDS.items():
            for j in seeds:
                harness.check(SURFACE, feed, (name, _ns(system_id=1, component_id=1, fields_json=j.decode())), ())
        harness.run(CASES, lambda c: harness.check(SURFACE, feed, c, ()), fuzz_budget)
    finally:
        loop.close()
    c = harness.COUNTS[SURFACE]
    assert c.outcomes["taken in"] and c.outcomes["decode error (counted)"], c.outcomes
