"""Telemetry JSON into the ground station and ground commands into the vehicle's verifier.

Rule: a telemetry payload is decoded or refused with SchemaError, and the ground counts it
(received + malformed = samples, every refusal recorded in rejected.jsonl); a command payload is
a GroundCommand or CommandRefused, and a mutated command is never accepted as another command."""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from hypothesis import strategies as st

from companion.telemetry.auth import CommandKind, CommandRefused, CommandSettings, CommandVerifier, sign_command
from companion.telemetry.ground import GroundStation
from companion.telemetry.schema import (
    LandingMessage,
    LogMessage,
    MissionMessage,
    Phase,
    SchemaError,
    StateMessage,
    Topic,
    decode,
    encode,
    topic_key,
    topic_of,
)
from companion.telemetry.session import ZenohSettings

from . import harness

pytestmark = pytest.mark.fuzz

MESSAGES = [
    StateMessage(1.0, 0, 0, 0, 0, 0, 0, 0, 0, 0),
    MissionMessage(3.0, Phase.OUTBOUND, sector=3, lyapunov_v_m2=0.25, speed_ref_m_s=5.0, sense=1),
    LandingMessage(6.0, True, markers_seen=(0, 7, 42), pad_rel_north_m=0.3, uwb_anchors_used=4),
    LogMessage(9.0, 4, "GPS glitch — ünïcödé ok", source="autopilot"),
]
SEEDS = [encode("drone-1", m, seq=i, sent_unix_s=1.7e9) for i, m in enumerate(MESSAGES)]
#: known-nasty payloads: deep nesting, a huge integer, non-JSON constants, wrong types, BOM, empty
NASTY = [
    b"",
    b"[" * 5000 + b"]" * 5000,
    b'{"schema":"companion.telemetry/1","vehicle_id":"drone-1","topic":"state","seq":' + b"9" * 5000 + b"}",
    b'{"schema":"companion.telemetry/1","vehicle_id":"drone-1","topic":"state","seq":0,"sent_unix_s":NaN,"msg":{}}',
    b'{"schema":"companion.telemetry/1","vehicle_id":"drone-1","topic":"state","seq":-1,"sent_unix_s":0,"msg":{}}',
    b'{"schema":"companion.telemetry/1","vehicle_id":"../x","topic":"log","seq":0,"sent_unix_s":0,"msg":[]}',
    b'\xef\xbb\xbf{"schema":"companion.telemetry/1"}',
    b'"just a string"',
    b"\xff\xfe\x00{",
    SEEDS[0].replace(b'"time_s":1.0', b'"time_s":1e999'),
    SEEDS[3].replace(b'"level":4', b'"level":true'),
]
KEYS = [topic_key("drone-1", topic_of(m)) for m in MESSAGES] + ["companion/drone-1", "other/x/state", ""]


def _ground(tmp_path):
    return GroundStation(ZenohSettings(), tmp_path / "ground", clock=lambda: 1.7e9)


def test_telemetry_json_into_the_ground(tmp_path, fuzz_budget) -> None:
    ground = _ground(tmp_path)
    (tmp_path / "ground").mkdir()
    fed = 0

    def feed(item: tuple[bytes, str]) -> str:
        nonlocal fed
        payload, key = item
        before = ground.counters()
        ground._on_sample(SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: payload)))
        fed += 1
        after = ground.counters()
        got = (after.received - before.received, after.malformed - before.malformed)
        assert got in ((1, 0), (0, 1)), f"sample counted as {got} (received, malformed)"
        c = ground.counters()
        assert c.received + c.malformed == fed
        return "decoded" if got == (1, 0) else "refused (counted)"

    def body(item: tuple[bytes, str]) -> None:
        harness.check("telemetry json (ground)", feed, item, ())

    for p in SEEDS + NASTY:
        for k in KEYS[:1]:
            body((p, k))
    run_strategy = st.tuples(harness.fuzz_bytes(SEEDS + NASTY), st.sampled_from(KEYS))
    harness.run(run_strategy, body, fuzz_budget)
    ground.flush()
    rejected = (tmp_path / "ground" / "rejected.jsonl").read_text().splitlines()
    assert len(rejected) == ground.counters().malformed  # every refusal recorded


def test_telemetry_json_decode(fuzz_budget) -> None:
    def feed(payload: bytes) -> str:
        env = decode(payload)
        assert isinstance(env.topic, Topic)
        return "decoded"

    for p in SEEDS + NASTY:
        harness.check("telemetry json (decode)", feed, p, (SchemaError,))
    harness.run(
        harness.fuzz_bytes(SEEDS + NASTY),
        lambda p: harness.check("telemetry json (decode)", feed, p, (SchemaError,)),
        fuzz_budget,
    )


SECRET = b"0123456789abcdef-fuzz"
NOW = 1.7e9
CMD_SEEDS = [
    sign_command("drone1", k, SECRET, issued_unix_s=NOW, nonce=f"{i:032x}", note=n)
    for i, (k, n) in enumerate([(CommandKind.HOLD, ""), (CommandKind.LAND, "pad 2"), (CommandKind.ABORT, "ü")])
]
CMD_NASTY = [
    b"",
    b"{}",
    b"[]",
    b"null",
    CMD_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":' + b"9" * 5000),
    CMD_SEEDS[0].replace(b'"note":""', b'"note":' + json.dumps("x" * 100000).encode()),
    CMD_SEEDS[1].replace(b'"land"', b'"LAND"'),
    CMD_SEEDS[0].replace(b'"issued_unix_ms":', b'"issued_unix_ms":1e308,"x":'),
]


def test_ground_commands(fuzz_budget) -> None:
    accepted_docs = {json.dumps(json.loads(s), sort_keys=True) for s in CMD_SEEDS}

    def feed(payload: bytes) -> str:
        v = CommandVerifier("drone1", CommandSettings(enabled=True, secret=SECRET), clock=lambda: NOW)
        cmd = v.verify(payload)
        doc = {"note": "", **json.loads(payload)}  # a missing note is the empty one, as the verifier reads it
        signed = {k: doc[k] for k in json.loads(CMD_SEEDS[0])}
        assert json.dumps(signed, sort_keys=True) in accepted_docs, f"accepted a command nobody signed: {cmd}"
        return "accepted (signed)"

    for p in CMD_SEEDS + CMD_NASTY:
        harness.check("ground commands", feed, p, (CommandRefused,))
    harness.run(
        harness.fuzz_bytes(CMD_SEEDS + CMD_NASTY),
        lambda p: harness.check("ground commands", feed, p, (CommandRefused,)),
        fuzz_budget,
    )
