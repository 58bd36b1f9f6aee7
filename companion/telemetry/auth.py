"""Ground commands: wire format, application-level authentication and replay protection.

Commands (hold, return, land, abort) reach a vehicle as the payload of a Zenoh query on
``companion/<vehicle_id>/command``. They are **off by default**; enabling them requires a
shared secret (>= 16 bytes). Two independent layers authenticate them:

1. Zenoh transport authentication (``transport.auth.usrpwd``, see :mod:`.session`): a session
   without valid credentials never connects, so it cannot even send the query.
2. This module: every command carries an HMAC-SHA256 over a canonical byte string, made with
   the shared secret, plus the time it was issued and a random nonce. The vehicle refuses a
   command whose MAC is wrong, whose ``issued_unix_ms`` is outside +-``window_s`` of its own
   clock (stale or from the future), or whose nonce it has already seen inside the window
   (replay).

Wire format (UTF-8 JSON object, schema ``companion.command/1``)::

    {"schema": "companion.command/1", "vehicle_id": "drone1", "command": "land",
     "issued_unix_ms": 1763750000123, "nonce": "<16-64 hex chars>", "sender": "ground",
     "note": "", "hmac_sha256": "<64 hex chars>"}

The MAC input is the newline-joined fields, in this order, as text (integers in decimal)::

    companion.command/1\\n<vehicle_id>\\n<command>\\n<issued_unix_ms>\\n<nonce>\\n<sender>\\n<note>

An accepted command becomes a :class:`GroundCommand` handed to the mission. **A ground command
never bypasses the safety contract**: it is a *request* to the mission state machine, which
decides whether and how to act on it in its current phase, and every setpoint it then produces
still goes through the same clamps (speed, climb, tilt, geofence); the pilot's RC override
still ends autonomy within one control period, whatever the ground asked for.
"""

from __future__ import annotations

import enum
import hashlib
import hmac
import json
import logging
import re
import secrets
import threading
import time
from collections import OrderedDict
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from companion.secret_files import read_private
from companion.telemetry.schema import SchemaError, check_vehicle_id, parse_json

log = logging.getLogger(__name__)

COMMAND_SCHEMA = "companion.command/1"
MIN_SECRET_BYTES = 16
_NONCE = re.compile(r"^[0-9a-f]{16,64}$")
_SENDER = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
MAX_NOTE_CHARS = 256


def sender_ok(sender: str) -> bool:
    """Whether ``sender`` is a valid sender name (1-64 of letters, digits, ``_ . @ -``)."""
    return bool(_SENDER.match(sender))


class CommandKind(enum.Enum):
    HOLD = "hold"  # stop and hold position
    RETURN = "return"  # fly back home along the path
    LAND = "land"  # land where the vehicle is
    ABORT = "abort"  # the mission's abort procedure (hold, then land)


class CommandRefused(Exception):
    """A command was refused; ``reason`` says why (it is sent back to the ground)."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True)
class CommandSettings:
    """Ground command access. ``enabled`` is False by default; when True ``secret`` is required.

    ``window_s``: how far ``issued_unix_ms`` may be from the vehicle clock (both directions);
    vehicle and ground clocks must agree within this (GPS time or NTP).
    ``max_nonces``: replay cache size; when full of unexpired nonces, commands are refused.
    """

    enabled: bool = False
    secret: bytes | None = field(default=None, repr=False)
    window_s: float = 5.0
    max_nonces: int = 4096

    def __post_init__(self) -> None:
        if self.secret is not None and not isinstance(self.secret, bytes):
            raise ValueError("commands.secret must be bytes")
        if self.enabled and (self.secret is None or len(self.secret) < MIN_SECRET_BYTES):
            raise ValueError(f"commands.enabled needs a shared secret of at least {MIN_SECRET_BYTES} bytes")
        if not 0.1 <= self.window_s <= 300.0:
            raise ValueError(f"commands.window_s {self.window_s} outside [0.1, 300] s")
        if not 16 <= self.max_nonces <= 1_000_000:
            raise ValueError(f"commands.max_nonces {self.max_nonces} outside [16, 1e6]")

    @staticmethod
    def read_secret(path: str | Path) -> bytes:
        """A secret from a file (surrounding whitespace stripped), so it stays out of params. A
        file its group or others can read or write is refused with
        :class:`~companion.secret_files.SecretFileExposed` (a ``ValueError``) naming it, its mode
        and the ``chmod 600``."""
        secret = read_private(path, "ground-command secret file").strip()
        if len(secret) < MIN_SECRET_BYTES:
            raise ValueError(f"{path}: secret shorter than {MIN_SECRET_BYTES} bytes")
        return secret


@dataclass(frozen=True, slots=True)
class GroundCommand:
    """An authenticated request from the ground, for the mission to decide on."""

    vehicle_id: str
    kind: CommandKind
    issued_unix_s: float
    received_unix_s: float
    nonce: str
    sender: str
    note: str = ""


def mac_input(vehicle_id: str, command: str, issued_unix_ms: int, nonce: str, sender: str, note: str) -> bytes:
    return "\n".join((COMMAND_SCHEMA, vehicle_id, command, str(issued_unix_ms), nonce, sender, note)).encode("utf-8")


def compute_mac(secret: bytes, data: bytes) -> str:
    return hmac.new(secret, data, hashlib.sha256).hexdigest()


def sign_command(
    vehicle_id: str,
    kind: CommandKind,
    secret: bytes,
    *,
    sender: str = "ground",
    note: str = "",
    issued_unix_s: float | None = None,
    nonce: str | None = None,
) -> bytes:
    """The signed wire payload of one command (used by the ground station)."""
    issued_ms = round((time.time() if issued_unix_s is None else issued_unix_s) * 1000.0)
    nonce = secrets.token_hex(16) if nonce is None else nonce
    doc = {
        "schema": COMMAND_SCHEMA,
        "vehicle_id": vehicle_id,
        "command": kind.value,
        "issued_unix_ms": issued_ms,
        "nonce": nonce,
        "sender": sender,
        "note": note,
        "hmac_sha256": compute_mac(secret, mac_input(vehicle_id, kind.value, issued_ms, nonce, sender, note)),
    }
    return json.dumps(doc, separators=(",", ":")).encode()


class SignedRequestGuard:
    """The checks every signed request from the ground shares (commands, delivery orders): the MAC
    over the request's canonical bytes, the vehicle it is for, the issued time against the
    vehicle clock (+-``window_s``) and the nonce replay cache. ``what`` names the request in the
    refusal reasons ("command", "order"). Thread-safe; ``clock`` returns Unix seconds."""

    def __init__(
        self,
        vehicle_id: str,
        settings: CommandSettings,
        what: str,
        clock: Callable[[], float] = time.time,
    ):
        self.vehicle_id = check_vehicle_id(vehicle_id)
        self.settings = settings
        self.what = what
        self._clock = clock
        self._seen: OrderedDict[str, float] = OrderedDict()  # nonce -> expiry (unix s)
        self._lock = threading.Lock()

    def secret(self) -> bytes:
        """The shared secret, or :class:`CommandRefused` when signed requests are off."""
        s = self.settings
        if not s.enabled or s.secret is None:
            raise CommandRefused(f"{self.what}s are disabled on this vehicle")
        return s.secret

    def authenticate(self, data: bytes, mac: str, vehicle_id: str) -> None:
        """The MAC over ``data`` is the shared secret's, and the request is for this vehicle."""
        if not hmac.compare_digest(compute_mac(self.secret(), data), mac):
            raise CommandRefused("authentication failed: bad HMAC")
        if vehicle_id != self.vehicle_id:
            raise CommandRefused(f"{self.what} is for vehicle {vehicle_id!r}, this is {self.vehicle_id!r}")

    def admit(self, issued_ms: int, nonce: str) -> float:
        """Refuse a stale (or future) or replayed request; else remember its nonce. Returns now."""
        s = self.settings
        now = self._clock()
        issued = issued_ms / 1000.0
        if abs(now - issued) > s.window_s:
            raise CommandRefused(
                f"stale {self.what}: issued {now - issued:+.1f} s from the vehicle clock (window +-{s.window_s:g} s)"
            )
        with self._lock:
            # A nonce may be forgotten once issued + window has passed: from then on the time
            # check above refuses its request anyway. Entries are in arrival order, which is
            # nearly expiry order; the full sweep below catches the rest when the cache fills.
            while self._seen and next(iter(self._seen.values())) < now:
                self._seen.popitem(last=False)
            if nonce in self._seen:
                raise CommandRefused(f"replayed {self.what}: nonce already used")
            if len(self._seen) >= s.max_nonces:
                for n in [n for n, exp in self._seen.items() if exp < now]:
                    del self._seen[n]
                if len(self._seen) >= s.max_nonces:
                    raise CommandRefused(f"too many {self.what}s in the replay window; try later")
            self._seen[nonce] = issued + s.window_s
        return now


@dataclass(frozen=True, slots=True)
class SignedFields:
    """The fields every signed request carries besides its own."""

    vehicle_id: str
    issued_ms: int
    nonce: str
    sender: str
    note: str
    mac: str


def parse_signed_fields(doc: Any, schema: str, what: str, own: tuple[str, ...] = ()) -> SignedFields:
    """The common fields of a signed request ``doc`` (a JSON object of ``schema``), checked;
    ``own``: the request's own required keys, reported missing in the same words."""
    if not isinstance(doc, dict):
        raise CommandRefused(f"malformed {what}: not a JSON object")
    if doc.get("schema") != schema:
        raise CommandRefused(f"malformed {what}: schema is not {schema!r}")
    if "hmac_sha256" not in doc:
        raise CommandRefused("authentication failed: no hmac_sha256")
    for name in ("vehicle_id", *own, "issued_unix_ms", "nonce", "sender"):
        if name not in doc:
            raise CommandRefused(f"malformed {what}: missing {name!r}")
    vehicle_id, issued_ms = doc["vehicle_id"], doc["issued_unix_ms"]
    nonce, sender, note, mac = doc["nonce"], doc["sender"], doc.get("note", ""), doc["hmac_sha256"]
    if not isinstance(vehicle_id, str):
        raise CommandRefused(f"malformed {what}: vehicle_id must be a short string")
    try:
        check_vehicle_id(vehicle_id)
    except SchemaError as e:
        raise CommandRefused(f"malformed {what}: {e}") from None
    if isinstance(issued_ms, bool) or not isinstance(issued_ms, int):
        raise CommandRefused(f"malformed {what}: issued_unix_ms must be an integer")
    if not isinstance(nonce, str) or not _NONCE.match(nonce):
        raise CommandRefused(f"malformed {what}: nonce must be 16-64 lowercase hex characters")
    if not isinstance(sender, str) or not _SENDER.match(sender):
        raise CommandRefused(f"malformed {what}: bad sender")
    if not isinstance(note, str) or len(note) > MAX_NOTE_CHARS:
        raise CommandRefused(f"malformed {what}: note must be a string <= {MAX_NOTE_CHARS} chars")
    if not isinstance(mac, str) or not re.fullmatch(r"[0-9a-f]{64}", mac):
        raise CommandRefused("authentication failed: hmac_sha256 must be 64 lowercase hex chars")
    return SignedFields(vehicle_id, issued_ms, nonce, sender, note, mac)


def parse_payload(payload: bytes | bytearray | memoryview | None, what: str) -> Any:
    """The JSON document of a request payload, or :class:`CommandRefused` (empty, not JSON)."""
    if payload is None or len(payload) == 0:
        raise CommandRefused(f"malformed {what}: empty payload")
    try:
        return parse_json(payload)
    except SchemaError as e:
        raise CommandRefused(f"malformed {what}: {e}") from None


class CommandVerifier:
    """Checks command payloads for one vehicle: format, MAC, time window, nonce replay.

    Thread-safe (Zenoh calls queryables from its own threads). ``clock`` returns Unix seconds.
    """

    def __init__(
        self,
        vehicle_id: str,
        settings: CommandSettings,
        clock: Callable[[], float] = time.time,
    ):
        self._guard = SignedRequestGuard(vehicle_id, settings, "command", clock)
        self.vehicle_id = self._guard.vehicle_id
        self.settings = settings

    def verify(self, payload: bytes | bytearray | memoryview | None) -> GroundCommand:
        """The command in ``payload``, or :class:`CommandRefused` with the reason."""
        g = self._guard
        g.secret()
        doc = parse_payload(payload, "command")
        f = parse_signed_fields(doc, COMMAND_SCHEMA, "command", ("command",))
        command = doc["command"]
        if not isinstance(command, str) or len(command) > 32:
            raise CommandRefused("malformed command: vehicle_id and command must be short strings")
        g.authenticate(mac_input(f.vehicle_id, command, f.issued_ms, f.nonce, f.sender, f.note), f.mac, f.vehicle_id)
        try:
            kind = CommandKind(command)
        except ValueError:
            allowed = ", ".join(k.value for k in CommandKind)
            raise CommandRefused(f"unknown command {command!r} (allowed: {allowed})") from None
        now = g.admit(f.issued_ms, f.nonce)
        return GroundCommand(
            vehicle_id=f.vehicle_id,
            kind=kind,
            issued_unix_s=f.issued_ms / 1000.0,
            received_unix_s=now,
            nonce=f.nonce,
            sender=f.sender,
            note=f.note,
        )
