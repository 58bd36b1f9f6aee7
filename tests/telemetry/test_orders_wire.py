"""Delivery orders on the wire: the signed format, and every refusal of the form and the signature."""

from __future__ import annotations

import json

import pytest

from companion.telemetry.auth import CommandKind, CommandRefused, CommandSettings, compute_mac, sign_command
from companion.telemetry.orders import (
    ORDER_SCHEMA,
    OrderPad,
    OrderVerifier,
    order_mac_input,
    sign_order,
)

SECRET = b"0123456789abcdef-secret"
NOW = 1_763_750_000.0
PAD = OrderPad(-19.8688741, -43.9636659, 850.0)
ALT = OrderPad(-19.8692, -43.9640)


class Clock:
    def __init__(self, t: float = NOW):
        self.t = t

    def __call__(self) -> float:
        return self.t


def verifier(clock: Clock | None = None, **kw) -> OrderVerifier:  # type: ignore[no-untyped-def]
    clock = clock or Clock()  # one clock for wall and monotonic time: advancing it is time passing
    return OrderVerifier("drone1", CommandSettings(enabled=True, secret=SECRET, **kw), clock=clock, monotonic=clock)


def refused(v: OrderVerifier, payload: bytes | None) -> str:
    with pytest.raises(CommandRefused) as info:
        v.verify(payload)
    return info.value.reason


def signed(**kw) -> bytes:  # type: ignore[no-untyped-def]
    kw.setdefault("issued_unix_s", NOW - 0.5)
    kw.setdefault("order_id", "o-1")
    return sign_order("drone1", kw.pop("pad", PAD), kw.pop("secret", SECRET), **kw)


def resign(doc: dict, secret: bytes = SECRET) -> bytes:  # type: ignore[type-arg]
    """``doc`` with a MAC recomputed over its (possibly altered) fields, as a sender with the secret would."""
    pad = OrderPad(**doc["pad"])
    alt = OrderPad(**doc["alternate"]) if doc.get("alternate") else None
    data = order_mac_input(
        doc["vehicle_id"], doc["order_id"], pad, alt, doc["issued_unix_ms"], doc["nonce"], doc["sender"], doc["note"]
    )
    doc["hmac_sha256"] = compute_mac(secret, data)
    return json.dumps(doc).encode()


def test_accepts_a_signed_order_with_its_alternate() -> None:
    order = verifier().verify(signed(alternate=ALT, note="parcel 7", sender="ops-1"))
    assert order.order_id == "o-1" and order.vehicle_id == "drone1" and order.sender == "ops-1"
    assert order.pad == PAD and order.alternate == ALT and order.note == "parcel 7"
    assert order.issued_unix_s == pytest.approx(NOW - 0.5) and order.received_unix_s == NOW


def test_mac_is_over_the_documented_canonical_string() -> None:
    payload = signed(nonce="ab" * 8, pad=OrderPad(-19.86887414999, -43.9636659), sender="gcs-1")
    doc = json.loads(payload)
    assert doc["schema"] == ORDER_SCHEMA and doc["alternate"] is None
    assert doc["pad"] == {"lat_deg": -19.8688741, "lon_deg": -43.9636659}  # as signed: 7 decimals
    ms = int((NOW - 0.5) * 1000)
    canonical = f"companion.order/1\ndrone1\no-1\n-19.8688741\n-43.9636659\n\n\n\n\n{ms}\n{'ab' * 8}\ngcs-1\n".encode()
    assert doc["hmac_sha256"] == compute_mac(SECRET, canonical)


def test_the_coordinates_flown_are_the_ones_signed() -> None:
    """A value with more decimals than the MAC covers is flown as signed (7 decimals), so a sender
    cannot have the MAC cover one pad and the vehicle fly another."""
    doc = json.loads(signed())
    doc["pad"]["lat_deg"] = -19.868874149  # the same 7-decimal text: same MAC, same pad flown
    order = verifier().verify(json.dumps(doc).encode())
    assert order.pad.lat_deg == -19.8688741


def test_disabled_refuses_every_order() -> None:
    v = OrderVerifier("drone1", CommandSettings(), clock=Clock())
    assert refused(v, signed()) == "orders are disabled on this vehicle"


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda d: d["pad"].update(lat_deg=-19.87), "authentication failed: bad HMAC"),  # moved pad
        (lambda d: d.update(alternate={"lat_deg": -19.86, "lon_deg": -43.96}), "authentication failed: bad HMAC"),
        (lambda d: d.update(order_id="o-2"), "authentication failed: bad HMAC"),
        (lambda d: d.update(note="x"), "authentication failed: bad HMAC"),
        (lambda d: d.update(hmac_sha256="0" * 64), "authentication failed: bad HMAC"),
        (lambda d: d.pop("hmac_sha256"), "authentication failed: no hmac_sha256"),
    ],
)
def test_a_tampered_order_fails_authentication(change, words: str) -> None:  # type: ignore[no-untyped-def]
    doc = json.loads(signed())
    change(doc)
    assert refused(verifier(), json.dumps(doc).encode()) == words


def test_signed_with_another_secret_fails_authentication() -> None:
    assert refused(verifier(), signed(secret=b"another-secret-of-16+bytes")) == "authentication failed: bad HMAC"


def test_an_order_for_another_vehicle_is_refused() -> None:
    payload = sign_order("drone2", PAD, SECRET, order_id="o-1", issued_unix_s=NOW)
    assert refused(verifier(), payload) == "order is for vehicle 'drone2', this is 'drone1'"


@pytest.mark.parametrize(
    ("age_s", "words"), [(6.0, "stale order: issued +6.0 s"), (-6.0, "stale order: issued -6.0 s")]
)
def test_stale_or_future_orders_are_refused(age_s: float, words: str) -> None:
    assert refused(verifier(), signed(issued_unix_s=NOW - age_s)).startswith(words)


def test_a_replayed_order_is_refused_and_the_nonce_forgotten_after_the_window() -> None:
    clock = Clock()
    v = verifier(clock)
    payload = signed(issued_unix_s=NOW)
    v.verify(payload)
    assert refused(v, payload) == "replayed order: nonce already used"
    clock.t = NOW + 10.0
    assert refused(v, payload).startswith("stale order")  # out of the window: the time check refuses it


def test_orders_and_commands_have_their_own_replay_caches_and_schemas() -> None:
    """A command's payload is not an order (its schema, and a MAC over another canonical string)."""
    cmd = sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=NOW)
    assert refused(verifier(), cmd) == f"malformed order: schema is not {ORDER_SCHEMA!r}"


@pytest.mark.parametrize(
    ("change", "words"),
    [
        (lambda d: d.pop("pad"), "malformed order: missing 'pad'"),
        (lambda d: d.pop("order_id"), "malformed order: missing 'order_id'"),
        (lambda d: d.update(pad=[1, 2]), "malformed order: pad must be an object"),
        (lambda d: d["pad"].pop("lon_deg"), "malformed order: pad.lon_deg is missing"),
        (lambda d: d["pad"].update(lat_deg="47.1"), "malformed order: pad.lat_deg = '47.1': expected a finite number"),
        (lambda d: d["pad"].update(lat_deg=True), "malformed order: pad.lat_deg = True: expected a finite number"),
        (lambda d: d["pad"].update(alt_m=3.0), "malformed order: pad has unknown keys ['alt_m']"),
        (lambda d: d.update(alternate={"lat_deg": 1.0}), "malformed order: alternate.lon_deg is missing"),
        (lambda d: d.update(order_id="a b"), "malformed order: order_id must be 1-64 letters"),
        (lambda d: d.update(order_id="x" * 65), "malformed order: order_id must be 1-64 letters"),
        (lambda d: d.update(issued_unix_ms=1.5), "malformed order: issued_unix_ms must be an integer"),
        (lambda d: d.update(nonce="XYZ"), "malformed order: nonce must be 16-64 lowercase hex"),
        (lambda d: d.update(sender="a b"), "malformed order: bad sender"),
        (lambda d: d.update(vehicle_id="../x"), "malformed order: "),
        (lambda d: d.update(schema="companion.order/2"), "malformed order: schema is not"),
    ],
)
def test_malformed_orders_are_refused_by_name(change, words: str) -> None:  # type: ignore[no-untyped-def]
    doc = json.loads(signed())
    change(doc)
    assert refused(verifier(), json.dumps(doc).encode()).startswith(words)


def test_a_non_finite_number_in_json_is_refused() -> None:
    text = signed().decode().replace('"lat_deg":-19.8688741', '"lat_deg":NaN')
    assert refused(verifier(), text.encode()).startswith("malformed order")


@pytest.mark.parametrize("payload", [None, b"", b"{", b"[1]", b"\xff\xfe"])
def test_unreadable_payloads_are_refused(payload: bytes | None) -> None:
    assert refused(verifier(), payload).startswith("malformed order")


def test_values_signed_correctly_but_wrong_are_left_to_the_vehicle_checks() -> None:
    """The form check passes a latitude of 95 deg signed with the secret: the range of a coordinate
    is the destination's check (companion.delivery.orders), which names the value."""
    doc = json.loads(signed())
    doc["pad"]["lat_deg"] = 95.0
    assert verifier().verify(resign(doc)).pad.lat_deg == 95.0
