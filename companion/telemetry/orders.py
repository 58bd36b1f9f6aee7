"""Delivery orders from the ground: wire format and authentication (docs/orders.md).

An order reaches a vehicle as the payload of a Zenoh query on ``companion/<vehicle_id>/order``
(:func:`~companion.telemetry.schema.order_key`); the vehicle answers accepted or refused with the
reason. Orders are authenticated exactly as ground commands are (:mod:`.auth`): the shared secret
of ``[telemetry.commands]``, an HMAC-SHA256 over a canonical byte string, the issued time within
+-``window_s`` of the vehicle clock, and a nonce never seen inside that window. This module only
checks the order's form and its signature; whether the vehicle can fly it (fence, range,
battery, wind, busy) is decided by :mod:`companion.delivery.orders`.

Wire format (UTF-8 JSON object, schema ``companion.order/1``)::

    {"schema": "companion.order/1", "vehicle_id": "drone1", "order_id": "o-42",
     "pad": {"lat_deg": -19.8688741, "lon_deg": -43.9636659, "alt_amsl_m": 850.0},
     "alternate": {"lat_deg": ..., "lon_deg": ...} | null,
     "issued_unix_ms": 1763750000123, "nonce": "<16-64 hex chars>", "sender": "ground",
     "note": "", "hmac_sha256": "<64 hex chars>"}

``alt_amsl_m`` may be left out (or null): the pad is then at the home's ground altitude. The MAC
input is the newline-joined fields, in this order, as text; the coordinates are written with 7
decimals (1.1 cm) and the altitudes with 3 (``%.7f``, ``%.3f``), an absent value as the empty
string, and the vehicle flies the coordinates as written there, so what is signed is what is flown::

    companion.order/1\\n<vehicle_id>\\n<order_id>\\n<pad lat>\\n<pad lon>\\n<pad alt>\\n
    <alternate lat>\\n<alternate lon>\\n<alternate alt>\\n<issued_unix_ms>\\n<nonce>\\n<sender>\\n<note>

The reply (schema ``companion.order-reply/1``): ``{"vehicle_id", "order_id", "accepted", "reason"}``,
as a Zenoh reply when accepted and as an error reply when refused.
"""

from __future__ import annotations

import json
import re
import secrets
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from companion.telemetry.auth import (
    CommandRefused,
    CommandSettings,
    RefusalKind,
    SignedRequestGuard,
    compute_mac,
    parse_payload,
    parse_signed_fields,
)
from companion.timebase import VehicleClock

ORDER_SCHEMA = "companion.order/1"
ORDER_REPLY_SCHEMA = "companion.order-reply/1"
_ORDER_ID = re.compile(r"^[A-Za-z0-9_.-]{1,64}$")
ORDER_ID_RULE = "1-64 letters, digits, '_', '.' or '-'"
#: no coordinate or altitude needs more: an integer beyond it is refused before any float
#: conversion (a 401-digit integer would raise OverflowError there)
MAX_MAGNITUDE = 1e9


def order_id_ok(order_id: str) -> bool:
    return bool(_ORDER_ID.match(order_id))


class OrderRefused(CommandRefused):
    """An order was refused; ``reason`` is sent back to the ground (``kind``: the vehicle's own
    checks unless said)."""


@dataclass(frozen=True, slots=True)
class OrderPad:
    """A pad as an order names it (WGS-84 degrees; ``alt_amsl_m`` None: home's ground altitude)."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float | None = None

    def mac_lines(self) -> tuple[str, str, str]:
        alt = "" if self.alt_amsl_m is None else f"{self.alt_amsl_m:.3f}"
        return f"{self.lat_deg:.7f}", f"{self.lon_deg:.7f}", alt

    def as_signed(self) -> OrderPad:
        """The pad at the resolution the MAC covers (what the vehicle flies)."""
        lat, lon, alt = self.mac_lines()
        return OrderPad(float(lat), float(lon), float(alt) if alt else None)

    def to_json(self) -> dict[str, Any]:
        doc: dict[str, Any] = {"lat_deg": self.lat_deg, "lon_deg": self.lon_deg}
        if self.alt_amsl_m is not None:
            doc["alt_amsl_m"] = self.alt_amsl_m
        return doc


@dataclass(frozen=True, slots=True)
class DeliveryOrder:
    """An authenticated delivery order, for the vehicle to check and fly."""

    vehicle_id: str
    order_id: str
    pad: OrderPad
    alternate: OrderPad | None
    issued_unix_s: float
    received_unix_s: float
    nonce: str
    sender: str
    note: str = ""


def order_mac_input(
    vehicle_id: str,
    order_id: str,
    pad: OrderPad,
    alternate: OrderPad | None,
    issued_unix_ms: int,
    nonce: str,
    sender: str,
    note: str,
) -> bytes:
    alt_lines = alternate.mac_lines() if alternate is not None else ("", "", "")
    head = (ORDER_SCHEMA, vehicle_id, order_id, *pad.mac_lines(), *alt_lines)
    fields = (*head, str(issued_unix_ms), nonce, sender, note)
    return "\n".join(fields).encode("utf-8")


def new_order_id() -> str:
    """A fresh order id: the UTC time and 4 random hex digits (readable in the logs, unique)."""
    return time.strftime("%Y%m%d-%H%M%S", time.gmtime()) + "-" + secrets.token_hex(2)


def sign_order(
    vehicle_id: str,
    pad: OrderPad,
    secret: bytes,
    *,
    order_id: str | None = None,
    alternate: OrderPad | None = None,
    sender: str = "ground",
    note: str = "",
    issued_unix_s: float | None = None,
    nonce: str | None = None,
) -> bytes:
    """The signed wire payload of one order (used by the ground side)."""
    issued_ms = round((time.time() if issued_unix_s is None else issued_unix_s) * 1000.0)
    nonce = secrets.token_hex(16) if nonce is None else nonce
    order_id = new_order_id() if order_id is None else order_id
    pad = pad.as_signed()
    alternate = alternate.as_signed() if alternate is not None else None
    mac = compute_mac(secret, order_mac_input(vehicle_id, order_id, pad, alternate, issued_ms, nonce, sender, note))
    doc = {
        "schema": ORDER_SCHEMA,
        "vehicle_id": vehicle_id,
        "order_id": order_id,
        "pad": pad.to_json(),
        "alternate": alternate.to_json() if alternate is not None else None,
        "issued_unix_ms": issued_ms,
        "nonce": nonce,
        "sender": sender,
        "note": note,
        "hmac_sha256": mac,
    }
    return json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()


def _number(doc: dict[str, Any], key: str, what: str, required: bool) -> float | None:
    value = doc.get(key)
    if value is None:
        if required:
            raise OrderRefused(f"malformed order: {what}.{key} is missing", RefusalKind.MALFORMED)
        return None
    # ints first, compared as ints: math.isfinite / float() of a huge int raises OverflowError
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not -MAX_MAGNITUDE <= value <= MAX_MAGNITUDE:
        shown = (
            repr(value)
            if not isinstance(value, int) or abs(value) < 10**20
            else f"an integer of {len(str(value))} digits"
        )
        raise OrderRefused(
            f"malformed order: {what}.{key} = {shown[:40]}: expected a finite number within +-{MAX_MAGNITUDE:g}",
            RefusalKind.MALFORMED,
        )
    return float(value)


def _pad(value: Any, what: str) -> OrderPad:
    if not isinstance(value, dict):
        raise OrderRefused(
            f"malformed order: {what} must be an object with lat_deg, lon_deg and optional alt_amsl_m",
            RefusalKind.MALFORMED,
        )
    unknown = sorted(set(value) - {"lat_deg", "lon_deg", "alt_amsl_m"})
    if unknown:
        raise OrderRefused(
            f"malformed order: {what} has unknown keys {unknown[:8]} (lat_deg, lon_deg, alt_amsl_m)",
            RefusalKind.MALFORMED,
        )
    lat = _number(value, "lat_deg", what, True)
    lon = _number(value, "lon_deg", what, True)
    assert lat is not None and lon is not None
    # signed as written with 7 (3) decimals: the value flown is the one the MAC covers
    return OrderPad(lat, lon, _number(value, "alt_amsl_m", what, False)).as_signed()


class OrderVerifier:
    """Checks order payloads for one vehicle: form, MAC, time window, nonce replay (the same
    guard as commands, with its own replay cache). Thread-safe. ``clock``: as
    :class:`~companion.telemetry.auth.SignedRequestGuard`'s."""

    def __init__(
        self,
        vehicle_id: str,
        settings: CommandSettings,
        clock: VehicleClock | Callable[[], float] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
    ):
        self._guard = SignedRequestGuard(vehicle_id, settings, "order", clock, monotonic)
        self.vehicle_id = self._guard.vehicle_id

    def verify(self, payload: bytes | bytearray | memoryview | None) -> DeliveryOrder:
        """The order in ``payload``, or :class:`CommandRefused` with the reason."""
        g = self._guard
        g.secret()
        g.gate()
        doc = parse_payload(payload, "order")
        f = parse_signed_fields(doc, ORDER_SCHEMA, "order", ("order_id", "pad"))
        order_id = doc["order_id"]
        if not isinstance(order_id, str) or not _ORDER_ID.match(order_id):
            raise OrderRefused(f"malformed order: order_id must be {ORDER_ID_RULE}", RefusalKind.MALFORMED)
        pad = _pad(doc["pad"], "pad")
        alt_doc = doc.get("alternate")
        alternate = None if alt_doc is None else _pad(alt_doc, "alternate")
        g.authenticate(
            order_mac_input(f.vehicle_id, order_id, pad, alternate, f.issued_ms, f.nonce, f.sender, f.note),
            f.mac,
            f.vehicle_id,
        )
        now = g.admit(f.issued_ms, f.nonce, f.sender)
        return DeliveryOrder(
            vehicle_id=f.vehicle_id,
            order_id=order_id,
            pad=pad,
            alternate=alternate,
            issued_unix_s=f.issued_ms / 1000.0,
            received_unix_s=now,
            nonce=f.nonce,
            sender=f.sender,
            note=f.note,
        )


def order_reply(vehicle_id: str, order_id: str | None, accepted: bool, reason: str) -> str:
    return json.dumps(
        {
            "schema": ORDER_REPLY_SCHEMA,
            "vehicle_id": vehicle_id,
            "order_id": order_id,
            "accepted": accepted,
            "reason": reason,
        }
    )
