"""MAVSDK's intercepted messages (name and fields JSON, as MAVSDK's C callback hands them) into
the PX4 backend's MAVLink log: ``deliver_intercepted`` around ``message_logger`` into a real
``TlogWriter``.

Rule: every message ends as a record in flight.tlog or a counted drop: the interceptor's
``errors`` (a name or JSON that is not text), the writer's ``unknown_messages`` (a message the
dialect does not define), ``encode_errors`` (one that cannot be packed again) or ``dropped``;
nothing raises into MAVSDK's thread."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from hypothesis import strategies as st
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.px4.mavsdk_core import InterceptCounters, deliver_intercepted, message_logger
from companion.flightlog.tlog_writer import TlogWriter

from . import harness
from .mavlink_corpus import from_autopilot, from_ground

pytestmark = pytest.mark.fuzz


def _seed_messages() -> list[tuple[bytes, bytes]]:
    """(message_name, fields_json) of real messages, as MAVSDK writes them."""
    mav = mavlink.MAVLink(None)
    out = []
    for data in from_autopilot()[:2] + from_ground()[:3]:
        for m in mav.parse_buffer(data) or []:
            d = m.to_dict()
            d.pop("mavpackettype", None)
            d = {k: (v.decode("latin-1") if isinstance(v, bytes) else v) for k, v in d.items()}
            d["message_id"] = m.get_msgId()
            out.append((m.get_type().encode(), json.dumps(d).encode()))
    return out


SEEDS = _seed_messages()
NASTY = [
    (b"HEARTBEAT", b""),
    (b"HEARTBEAT", b"{}"),
    (b"NOT_A_MESSAGE", b"{}"),
    (b"ATTITUDE", b'{"message_id": 30, "roll": "x"}'),
    (b"ATTITUDE", b'{"message_id": 99999999, "roll": 1}'),
    (b"ATTITUDE", b'{"message_id": 30, "time_boot_ms": ' + b"9" * 5000 + b"}"),
    (b"ATTITUDE", b'{"message_id": 30, "roll": NaN, "pitch": Infinity}'),
    (b"STATUSTEXT", b'{"message_id": 253, "text": [1, 2, 3]}'),
    (b"\xff\xfe", b"{}"),
    (b"ATTITUDE", b"\xff{"),
    (b"ATTITUDE", b"[" * 5000),
    (b"ATTITUDE", b"[]"),
]


def test_intercepted_messages_into_the_tlog(tmp_path, fuzz_budget) -> None:
    tlog = TlogWriter(tmp_path / "flight.tlog")
    counters = InterceptCounters()
    log_message = message_logger(tlog)
    fed = 0

    def feed(item: tuple[tuple[bytes, bytes], int, int]) -> str:
        nonlocal fed
        (name, fields), sysid, compid = item
        msg = SimpleNamespace(message_name=name, fields_json=fields, system_id=sysid, component_id=compid)
        errors = counters.errors
        assert deliver_intercepted(log_message, msg, counters) == 1
        fed += 1
        assert counters.delivered + counters.errors == fed
        return "dropped (counted)" if counters.errors > errors else "handed to the tlog"

    items = st.tuples(
        st.one_of(
            st.sampled_from(SEEDS + NASTY),
            st.tuples(harness.fuzz_bytes([n for n, _ in SEEDS]), harness.fuzz_bytes([f for _, f in SEEDS])),
        ),
        st.integers(0, 255),
        st.integers(0, 255),
    )
    for seed in SEEDS + NASTY:
        harness.check("px4 interceptor -> tlog", feed, (seed, 1, 1), ())
    harness.run(items, lambda it: harness.check("px4 interceptor -> tlog", feed, it, ()), fuzz_budget)
    tlog.close()
    unknown = sum(tlog.unknown_messages.values())
    assert tlog.written + unknown + tlog.encode_errors + tlog.dropped == counters.delivered, (
        f"{counters.delivered} messages handed over, {tlog.written} written, {unknown} not in the dialect, "
        f"{tlog.encode_errors} not encodable, {tlog.dropped} dropped"
    )
