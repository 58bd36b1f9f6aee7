"""Application-level command authentication: HMAC, time window, replay, malformed input."""

from __future__ import annotations

import json

import pytest

from companion.telemetry.auth import (
    CommandKind,
    CommandRefused,
    CommandSettings,
    CommandVerifier,
    compute_mac,
    mac_input,
    sign_command,
)

SECRET = b"0123456789abcdef-secret"
NOW = 1_763_750_000.0


class Clock:
    def __init__(self, t: float = NOW):
        self.t = t

    def __call__(self) -> float:
        return self.t


def verifier(clock: Clock | None = None, **kw) -> CommandVerifier:
    clock = clock or Clock()  # one clock for wall and monotonic time: advancing it is time passing
    return CommandVerifier("drone1", CommandSettings(enabled=True, secret=SECRET, **kw), clock=clock, monotonic=clock)


def refused(v: CommandVerifier, payload: bytes | None) -> str:
    with pytest.raises(CommandRefused) as info:
        v.verify(payload)
    return info.value.reason


def test_accepts_a_signed_command() -> None:
    cmd = verifier().verify(sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=NOW - 1.0, note="wind"))
    assert cmd.kind is CommandKind.LAND and cmd.vehicle_id == "drone1" and cmd.note == "wind"
    assert cmd.issued_unix_s == pytest.approx(NOW - 1.0) and cmd.received_unix_s == NOW
    assert cmd.sender == "ground" and len(cmd.nonce) == 32


def test_mac_is_over_the_documented_canonical_string() -> None:
    payload = sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW, nonce="ab" * 8, sender="gcs-1")
    doc = json.loads(payload)
    canonical = f"companion.command/1\ndrone1\nhold\n{int(NOW * 1000)}\n{'ab' * 8}\ngcs-1\n".encode()
    assert mac_input("drone1", "hold", int(NOW * 1000), "ab" * 8, "gcs-1", "") == canonical
    assert doc["hmac_sha256"] == compute_mac(SECRET, canonical)


def test_disabled_refuses_everything() -> None:
    v = CommandVerifier("drone1", CommandSettings(), clock=Clock())
    assert "disabled" in refused(v, sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))


def test_enabling_needs_a_long_secret() -> None:
    with pytest.raises(ValueError, match="secret"):
        CommandSettings(enabled=True)
    with pytest.raises(ValueError, match="secret"):
        CommandSettings(enabled=True, secret=b"short")
    assert SECRET.decode() not in repr(CommandSettings(enabled=True, secret=SECRET))


def test_wrong_secret_and_tampering_refused() -> None:
    v = verifier()
    assert "HMAC" in refused(v, sign_command("drone1", CommandKind.HOLD, b"another-secret-of-16+", issued_unix_s=NOW))
    doc = json.loads(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
    doc["command"] = "abort"  # change the command, keep the MAC
    assert "HMAC" in refused(v, json.dumps(doc).encode())
    doc = json.loads(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW - 100))
    doc["issued_unix_ms"] = int(NOW * 1000)  # refresh the timestamp of an old command
    assert "HMAC" in refused(v, json.dumps(doc).encode())
    doc = json.loads(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
    del doc["hmac_sha256"]
    assert "no hmac" in refused(v, json.dumps(doc).encode())


def test_stale_future_and_replayed_refused() -> None:
    clock = Clock()
    v = verifier(clock, window_s=5.0)
    assert "stale" in refused(v, sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW - 5.5))
    assert "stale" in refused(v, sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW + 5.5))
    payload = sign_command("drone1", CommandKind.RETURN, SECRET, issued_unix_s=NOW - 1)
    assert v.verify(payload).kind is CommandKind.RETURN
    assert "replayed" in refused(v, payload)
    clock.t = NOW + 10  # later the nonce has expired from the cache, but the timestamp is stale
    assert "stale" in refused(v, payload)


def test_for_another_vehicle_or_unknown_command_refused() -> None:
    v = verifier()
    assert "drone2" in refused(v, sign_command("drone2", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
    issued = int(NOW * 1000)
    doc = {
        "schema": "companion.command/1", "vehicle_id": "drone1", "command": "self_destruct",
        "issued_unix_ms": issued, "nonce": "cd" * 8, "sender": "ground", "note": "",
        "hmac_sha256": compute_mac(SECRET, mac_input("drone1", "self_destruct", issued, "cd" * 8, "ground", "")),
    }  # fmt: skip
    assert "unknown command" in refused(v, json.dumps(doc).encode())


@pytest.mark.parametrize(
    "mutation",
    [
        {"schema": "companion.command/2"},
        {"issued_unix_ms": 1.5},
        {"issued_unix_ms": "1763750000000"},
        {"nonce": "short"},
        {"nonce": "ZZ" * 8},
        {"sender": "a b"},
        {"note": 5},
        {"vehicle_id": "../etc"},
        {"hmac_sha256": "00"},
        {"command": None},
    ],
)
def test_malformed_fields_refused(mutation: dict) -> None:
    doc = json.loads(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
    doc.update(mutation)
    reason = refused(verifier(), json.dumps(doc).encode())
    assert "malformed" in reason or "authentication" in reason


@pytest.mark.parametrize("payload", [None, b"", b"not json", b"[]", b"\xff", b'{"schema": "companion.command/1"}'])
def test_garbage_refused(payload: bytes | None) -> None:
    assert refused(verifier(), payload)


def test_replay_cache_bounded() -> None:
    v = verifier(max_nonces=16, burst=100)  # the cache fills before the sender's bucket empties
    for _ in range(16):
        v.verify(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
    assert "too many" in refused(v, sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=NOW))
