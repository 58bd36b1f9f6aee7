"""Zenoh's transport limits as the session settings set them: every shipped session file bounds the
largest message, and a message over the limit is dropped by Zenoh itself between two real sessions
on loopback, before the vehicle's callback (and its copy into Python) ever runs."""

from __future__ import annotations

import dataclasses
import json
import threading
import time
from pathlib import Path

import pytest

from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.session import SettingsError, ZenohSettings, load_settings

PARAMS = Path(__file__).resolve().parents[2] / "params"
LIMIT = 256 * 1024


@pytest.mark.parametrize(
    "name", ["zenoh_peer.toml", "zenoh_loopback.toml", "zenoh_fleet_vehicle.toml", "zenoh_fleet_router.toml"]
)
def test_every_shipped_session_file_bounds_the_transport(name: str) -> None:
    s = load_settings(PARAMS / name)
    conf = s.to_config()
    assert json.loads(conf.get_json("transport/link/rx/max_message_size")) == LIMIT
    assert json.loads(conf.get_json("transport/shared_memory/enabled")) is False
    sessions = json.loads(conf.get_json("transport/unicast/max_sessions"))
    pending = json.loads(conf.get_json("transport/unicast/accept_pending"))
    assert sessions < 1000 and pending < 100  # below Zenoh's defaults


def test_settings_bound_the_transport_even_without_a_file() -> None:
    conf = ZenohSettings().to_config()
    assert json.loads(conf.get_json("transport/link/rx/max_message_size")) == LIMIT


@pytest.mark.parametrize(
    "kwargs",
    [{"max_message_bytes": 1000}, {"max_message_bytes": 2 << 30}, {"max_sessions": 0}, {"accept_pending": True}],
)
def test_limits_out_of_range_are_refused(kwargs: dict) -> None:  # type: ignore[type-arg]
    with pytest.raises(SettingsError, match=next(iter(kwargs))):
        ZenohSettings(**kwargs)


def test_a_query_over_the_limit_is_dropped_by_zenoh_and_the_session_lives_on() -> None:
    port = free_tcp_port()
    vehicle = loopback_settings(listen_port=port).open()
    # the sender is unbounded: it can send what it likes, the receiver decides
    sender = dataclasses.replace(loopback_settings(connect_port=port), max_message_bytes=1 << 30).open()
    seen: list[int] = []
    lock = threading.Lock()

    def on_query(query):  # type: ignore[no-untyped-def]
        with lock:
            seen.append(len(query.payload.to_bytes()) if query.payload is not None else 0)
        query.reply(query.key_expr, b"ok")

    queryable = vehicle.declare_queryable("companion/limits/order", on_query)
    try:
        deadline = time.monotonic() + 5.0
        while not list(sender.get("companion/limits/order", payload=b"x", timeout=1.0)):
            assert time.monotonic() < deadline, "the two sessions never met"
        with lock:
            seen.clear()

        def ok_replies(size: int, timeout_s: float) -> int:
            replies = sender.get("companion/limits/order", payload=b"x" * size, timeout=timeout_s)
            return sum(r.ok is not None for r in replies)

        assert ok_replies(LIMIT - 4096, 5.0) == 1  # under the limit: delivered whole
        assert ok_replies(8 * LIMIT, 2.0) == 0  # over it: dropped while Zenoh reassembles it
        assert ok_replies(16 * 1024 * 1024, 2.0) == 0
        assert ok_replies(1000, 5.0) == 1  # the same session still answers
        with lock:
            assert seen == [LIMIT - 4096, 1000]
    finally:
        queryable.undeclare()
        sender.close()
        vehicle.close()
