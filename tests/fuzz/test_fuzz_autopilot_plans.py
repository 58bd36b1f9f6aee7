"""Mission and fence items downloaded from the autopilot: random and hostile MISSION_ITEM_INT lists
(any command and frame, NaN / infinite / huge params, positions at 0, 0 or past the poles, a
release with no place, pads on top of each other) answered by a vehicle to the ArduPilot backend's
mission download, into ``config_from_autopilot_mission``; and fence items (polygons torn, counts
that lie, other kinds of items) into the backend's fence download and ``fence_mismatch``.

Rule (mission): the delivery is a new configuration whose pad is the mission's first delivery item
(the alternate its second), or ``MissionPlanError`` naming the item; the configuration given is
never changed. Rule (fence): polygons holding every item read back, in order, or an
``AutopilotError`` naming the item; never another exception."""

from __future__ import annotations

import asyncio
import math
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.fence import AutopilotFence, FencePolygon, fence_items, fence_mismatch
from companion.autopilot.interface import AutopilotError
from companion.config import load_config, shipped_params_path
from companion.delivery.autopilot_mission import MissionPlanError, config_from_autopilot_mission

from . import harness

pytestmark = pytest.mark.fuzz

CONFIG = load_config(shipped_params_path("sitl_short.toml"))
HOME = (-198690000, -439638000)  # params/sitl_short.toml's sim.home in 1e-7 degrees
MISSION, FENCE = 0, 1
#: (command, frame, param1, param2, param3, param4, x, y, z) as MISSION_ITEM_INT carries them
Item = tuple[int, int, float, float, float, float, int, int, float]
NAN, INF = math.nan, math.inf


def _at(dn: int, de: int) -> tuple[int, int]:
    return HOME[0] + dn, HOME[1] + de  # 1e-7 deg: about 1.1 cm north, 1.05 cm east


def _wp(cmd: int, frame: int, pos: tuple[int, int], z: float = 10.0, p2: float = 0.0) -> Item:
    return (cmd, frame, 0.0, p2, 0.0, 0.0, pos[0], pos[1], z)


_RELEASE: Item = (211, 0, 1.0, 0.0, 0.0, 0.0, 0, 0, 0.0)
_TAKEOFF: Item = _wp(22, 3, HOME, 10.0)
MISSION_SEEDS: list[list[Item]] = [
    [_TAKEOFF, _wp(94, 3, _at(1200, 1300))],  # a payload place
    [_TAKEOFF, _wp(16, 6, _at(1200, 1300)), _RELEASE],  # a waypoint, then the release
    [_TAKEOFF, _wp(21, 5, _at(1200, 1300), 851.0), _RELEASE, _wp(94, 6, _at(-900, 800))],  # pad and alternate
    [_TAKEOFF, _wp(21, 3, _at(1200, 1300), 0.2), _RELEASE],
    [],  # no mission
    [_TAKEOFF, _wp(16, 3, _at(1200, 1300))],  # no delivery item
    [_RELEASE, _wp(94, 3, _at(1200, 1300))],  # a release first
    [_TAKEOFF, _wp(94, 3, _at(1, 1)), _wp(94, 3, _at(2, 2))],  # two pads on top of each other
    [_wp(94, 3, _at(10, 10)), _wp(94, 3, _at(2000, 10)), _wp(94, 3, _at(10, 2000))],  # three
    [_wp(94, 1, _at(1200, 1300))],  # a local frame
    [_wp(94, 3, (0, 0))],  # never set
    [_wp(94, 3, (900_000_001, 0))],  # past the pole
    [_wp(21, 3, _at(1200, 1300), 30.0), _RELEASE],  # landing 30 m above home
    [_wp(21, 0, _at(1200, 1300), NAN), _RELEASE],
    # a gripper action of NaN or infinity: round() raised (an escape) before it was refused
    [_wp(16, 3, _at(1200, 1300)), (211, 0, 1.0, NAN, 0.0, 0.0, 0, 0, 0.0)],
    [_wp(16, 3, _at(1200, 1300)), (211, 0, 1.0, INF, 0.0, 0.0, 0, 0, 0.0)],
    [_wp(94, 3, _at(5_000_000, 0))],  # 55 km away
    [_wp(94, 3, _at(1200, 1300), INF, NAN)],
]


def _poly(cmd: int, verts: list[tuple[int, int]], group: float = 0.0, count: float | None = None) -> list[Item]:
    n = float(len(verts)) if count is None else count
    return [(cmd, 0, n, group, 0.0, 0.0, lat, lon, 0.0) for lat, lon in verts]


_SQUARE = [_at(-5000, -5000), _at(-5000, 5000), _at(5000, 5000), _at(5000, -5000)]
_HOLE = [_at(100, 100), _at(100, 300), _at(300, 200)]
SENT = AutopilotFence((FencePolygon(True, tuple(_SQUARE)), FencePolygon(False, tuple(_HOLE))))
FENCE_SEEDS: list[list[Item]] = [
    _poly(5001, _SQUARE) + _poly(5002, _HOLE),  # what was sent
    _poly(5001, _SQUARE),  # the hole lost
    _poly(5001, _SQUARE) + _poly(5001, _HOLE, group=1.0),  # the hole as an inclusion
    [],
    _poly(5001, _SQUARE)[:3] + _poly(5002, _HOLE),  # torn: a vertex missing
    _poly(5001, _SQUARE, count=5.0),  # a count that lies
    _poly(5001, _SQUARE, count=NAN),  # NaN or infinite counts: round() raised (an escape)
    _poly(5001, _SQUARE, count=INF),
    _poly(5001, _SQUARE, group=NAN),
    _poly(5001, _SQUARE, count=-4.0),
    _poly(5001, _SQUARE, count=2.0)[:2],
    [(5003, 0, 100.0, 0.0, 0.0, 0.0, HOME[0], HOME[1], 0.0)],  # a circle
    [(5000, 0, 0.0, 0.0, 0.0, 0.0, HOME[0], HOME[1], 0.0)],  # the return point
    _poly(5001, [(v[0] + 1, v[1] - 1) for v in _SQUARE]) + _poly(5002, _HOLE),  # within one unit
    _poly(5001, [(v[0] + 2, v[1]) for v in _SQUARE]) + _poly(5002, _HOLE),  # two units off
]

_FLOAT = st.one_of(
    st.sampled_from([0.0, 1.0, -1.0, 0.49, 0.5, -0.5, 2.0, NAN, INF, -INF, 1e10, -1e10, 3.4e38]),
    st.floats(allow_nan=True, allow_infinity=True, width=32),
)
_INT32 = st.one_of(
    st.integers(-(2**31), 2**31 - 1), st.sampled_from([0, HOME[0], HOME[1], 900_000_000, -1_800_000_000])
)
_NEAR = st.tuples(st.integers(-3000, 3000), st.integers(-3000, 3000)).map(lambda d: _at(*d))
_ITEM = st.tuples(
    st.one_of(st.sampled_from([16, 21, 22, 94, 211, 17, 20, 5000, 5001, 5002, 5003, 5004]), st.integers(0, 65535)),
    st.one_of(st.sampled_from([0, 3, 5, 6, 1, 2, 10]), st.integers(0, 255)),
    _FLOAT,
    _FLOAT,
    _FLOAT,
    _FLOAT,
    _INT32,
    _INT32,
    _FLOAT,
)
_ITEM_NEAR = st.tuples(_ITEM, _NEAR).map(lambda t: (*t[0][:6], t[1][0], t[1][1], t[0][8]))


@st.composite
def _mutated(draw: st.DrawFn, seeds: list[list[Item]]) -> list[Item]:
    """A seed with items dropped, duplicated, swapped, or one field replaced by a hostile value."""
    items = list(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 3))):
        op = draw(st.sampled_from(("drop", "dup", "swap", "field", "insert")))
        n = len(items)
        if op == "insert" or not n:
            items.insert(draw(st.integers(0, n)), draw(st.one_of(_ITEM, _ITEM_NEAR)))
        elif op == "drop":
            del items[draw(st.integers(0, n - 1))]
        elif op == "dup":
            i = draw(st.integers(0, n - 1))
            items.insert(i, items[i])
        elif op == "swap":
            i, j = draw(st.integers(0, n - 1)), draw(st.integers(0, n - 1))
            items[i], items[j] = items[j], items[i]
        else:
            i, k = draw(st.integers(0, n - 1)), draw(st.integers(0, 8))
            new = list(items[i])
            new[k] = draw(st.integers(0, 65535) if k < 2 else _INT32 if k in (6, 7) else _FLOAT)
            items[i] = tuple(new)  # type: ignore[assignment]
    return items


def _lists(seeds: list[list[Item]]) -> st.SearchStrategy[list[Item]]:
    return st.one_of(st.sampled_from(seeds), _mutated(seeds), st.lists(st.one_of(_ITEM, _ITEM_NEAR), max_size=10))


class _Vehicle:
    """The mission protocol's vehicle side, as pymavlink calls on the backend's ``mav``: every
    request answered at once with real MISSION_COUNT / MISSION_ITEM_INT messages (packed and
    parsed, as the reader thread hands them on) for ``items`` (ArduPilot's home first)."""

    def __init__(self, ap: ArduPilotAutopilot, items: list[Item], mission_type: int) -> None:
        self.ap, self.type = ap, mission_type
        self.items = ([_wp(16, 0, HOME, 850.0)] if mission_type == MISSION else []) + items
        self.enc = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        self.dec = mavlink.MAVLink(None)

    def _answer(self, msg: Any) -> None:
        (m,) = self.dec.parse_buffer(msg.pack(self.enc))
        self.ap._on_mission_message(m)

    def mission_request_list_send(self, ts: int, tc: int, mission_type: int) -> None:
        self._answer(mavlink.MAVLink_mission_count_message(255, 191, len(self.items), mission_type))

    def mission_request_int_send(self, ts: int, tc: int, seq: int, mission_type: int) -> None:
        c, f, p1, p2, p3, p4, x, y, z = self.items[seq]
        self._answer(
            mavlink.MAVLink_mission_item_int_message(255, 191, seq, f, c, 0, 1, p1, p2, p3, p4, x, y, z, mission_type)
        )

    def mission_ack_send(self, *args: Any) -> None:
        pass


def _backend(items: list[Item], mission_type: int) -> ArduPilotAutopilot:
    ap = ArduPilotAutopilot("udpin:127.0.0.1:14550", target_system=1)
    ap.attach_loop(asyncio.get_running_loop())
    vehicle = _Vehicle(ap, items, mission_type)

    def send(fn: Any) -> bool:
        fn(vehicle)
        return True

    ap._send = send  # type: ignore[method-assign]
    return ap


def _decoded(items: list[Item]) -> list[Item]:
    """The items as MISSION_ITEM_INT carries them (floats to 32 bits)."""
    enc, dec = mavlink.MAVLink(None), mavlink.MAVLink(None)
    out = []
    for c, f, p1, p2, p3, p4, x, y, z in items:
        (m,) = dec.parse_buffer(
            mavlink.MAVLink_mission_item_int_message(1, 1, 0, f, c, 0, 1, p1, p2, p3, p4, x, y, z).pack(enc)
        )
        out.append((m.command, m.frame, m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z))
    return out


def _delivery_positions(items: list[Item]) -> list[tuple[int, int]]:
    """The rule's delivery items, read independently: a payload place, or a waypoint / landing
    right before a DO_GRIPPER release."""
    out = []
    for i, it in enumerate(items):
        if it[0] == 94:
            out.append((it[6], it[7]))
        elif it[0] == 211 and math.isfinite(it[3]) and round(it[3]) == 0 and i > 0 and items[i - 1][0] in (16, 21):
            out.append((items[i - 1][6], items[i - 1][7]))
    return out


def _in_range(items: list[Item]) -> list[Item]:
    """MISSION_ITEM_INT's field ranges: the command and frame as pymavlink packs them."""
    return [(c % 65536, f % 256, *rest) for c, f, *rest in items]  # type: ignore[misc]


async def _mission(items: list[Item]) -> str:
    ap = _backend(items, MISSION)
    before = CONFIG.model_dump()
    try:
        flown, said = await config_from_autopilot_mission(CONFIG, ap)
    except MissionPlanError as err:
        assert CONFIG.model_dump() == before, "a refused mission changed the configuration"
        assert "item" in err.reason or "mission" in err.reason, f"a refusal naming nothing: {err.reason}"
        raise
    assert CONFIG.model_dump() == before, "the configuration given was changed"
    want = _delivery_positions(_decoded(items))
    assert 1 <= len(want) <= 2, f"accepted a mission of {len(want)} delivery items"
    pads = [flown.mission.pad, flown.mission.alternate_pad][: len(want)]
    got = [(round(float(p.lat_deg or 0) * 1e7), round(float(p.lon_deg or 0) * 1e7)) for p in pads if p is not None]
    assert got == want, f"the pads are not the mission's delivery items: {said}"
    return "delivery taken" + (" with an alternate" if len(want) == 2 else "")


async def _fence(items: list[Item]) -> str:
    ap = _backend(items, FENCE)
    got = await ap.download_fence()
    verts = [v for p in got.polygons for v in p.vertices_e7]
    assert verts == [(it[6], it[7]) for it in items], "a fence vertex read back was lost or moved"
    assert fence_mismatch(got, got) is None
    same = [(i.command, i.lat_e7, i.lon_e7) for i in fence_items(SENT)] == [(c, x, y) for c, *_, x, y, _ in items]
    why = fence_mismatch(SENT, got)
    assert (why is None) >= same, f"the fence sent, read back as it is, differs: {why}"
    return "the fence sent" if why is None else "a fence that differs (said)"


def test_mission_items_into_the_delivery(fuzz_budget: int) -> None:
    loop = asyncio.new_event_loop()

    def feed(items: list[Item]) -> str:
        return loop.run_until_complete(_mission(_in_range(items)))

    try:
        for items in MISSION_SEEDS:
            harness.check("autopilot mission items -> delivery", feed, items, (MissionPlanError,))
        harness.run(
            _lists(MISSION_SEEDS),
            lambda items: harness.check("autopilot mission items -> delivery", feed, items, (MissionPlanError,)),
            fuzz_budget,
        )
    finally:
        loop.close()
    c = harness.COUNTS["autopilot mission items -> delivery"]
    assert c.outcomes["delivery taken"] and c.outcomes["delivery taken with an alternate"], c.outcomes


def test_fence_items_read_back(fuzz_budget: int) -> None:
    loop = asyncio.new_event_loop()

    def feed(items: list[Item]) -> str:
        return loop.run_until_complete(_fence(_in_range(items)))

    try:
        for items in FENCE_SEEDS:
            harness.check("autopilot fence items -> read back", feed, items, (AutopilotError,))
        harness.run(
            _lists(FENCE_SEEDS),
            lambda items: harness.check("autopilot fence items -> read back", feed, items, (AutopilotError,)),
            fuzz_budget,
        )
    finally:
        loop.close()
    c = harness.COUNTS["autopilot fence items -> read back"]
    assert c.outcomes["the fence sent"] and c.outcomes["AutopilotError"], c.outcomes
