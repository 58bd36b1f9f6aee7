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
   (replay). "Its own clock" is :class:`~companion.timebase.VehicleClock`: the wall clock carried
   forward on the monotonic clock, so a clock step neither refuses fresh requests nor re-opens a
   used nonce (nonces expire on monotonic age), and signed requests are refused while the
   pre-flight clock verdict is OFF. A sender's newest accepted issued time is kept too: a request
   older than it by more than the window is refused whatever the clock says. Each signed sender
   has a token bucket (``rate_per_s``, ``burst``).

Every refusal carries a :class:`RefusalKind`; :class:`RefusalLog` counts them and logs a sample
(one line per ``interval_s``), so a flood costs a counter, not a log line each.

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

from companion.events import CommandKind as CommandKind  # the mission's vocabulary; parsed here
from companion.secret_files import read_private
from companion.telemetry.schema import SchemaError, check_vehicle_id, parse_json
from companion.timebase import VehicleClock, vehicle_clock

log = logging.getLogger(__name__)

COMMAND_SCHEMA = "companion.command/1"
MIN_SECRET_BYTES = 16
_NONCE = re.compile(r"^[0-9a-f]{16,64}$")
_SENDER = re.compile(r"^[A-Za-z0-9_.@-]{1,64}$")
MAX_NOTE_CHARS = 256
MAX_ISSUED_MS = 1 << 53  # an issued time beyond this is no time (and no float holds it exactly)


def sender_ok(sender: str) -> bool:
    """Whether ``sender`` is a valid sender name (1-64 of letters, digits, ``_ . @ -``)."""
    return bool(_SENDER.match(sender))


class RefusalKind(enum.Enum):
    """Why a signed request was refused, for counting and deciding (the reason text is for people)."""

    DISABLED = "disabled"  # no secret on this vehicle
    MALFORMED = "malformed"  # not the schema's form (a field missing, out of range, not a number)
    AUTHENTICATION = "authentication"  # no MAC, or not the shared secret's
    WRONG_VEHICLE = "wrong_vehicle"  # signed for another vehicle
    UNKNOWN_COMMAND = "unknown_command"  # signed, but no command this vehicle knows
    CLOCK = "clock"  # the pre-flight clock verdict is OFF: freshness cannot be judged
    STALE = "stale"  # issued outside the window (either way), or older than the sender's newest
    REPLAY = "replay"  # a nonce already used
    RATE = "rate"  # the sender's token bucket is empty
    OVERLOAD = "overload"  # a cache or queue full, no decision in time
    VEHICLE = "vehicle"  # signed and fresh, refused by the vehicle's own checks (busy, range, ...)

    @property
    def before_decision(self) -> bool:
        """Refused before the vehicle's own checks ran: counted and sampled, not a mission event."""
        return self is not RefusalKind.VEHICLE


class CommandRefused(Exception):
    """A command was refused; ``reason`` says why (it is sent back to the ground), ``kind`` which
    rule refused it."""

    def __init__(self, reason: str, kind: RefusalKind = RefusalKind.VEHICLE):
        super().__init__(reason)
        self.reason = reason
        self.kind = kind


@dataclass(frozen=True)
class CommandSettings:
    """Ground command access. ``enabled`` is False by default; when True ``secret`` is required.

    ``window_s``: how far ``issued_unix_ms`` may be from the vehicle clock (both directions);
    vehicle and ground clocks must agree within this (GPS time or NTP).
    ``max_nonces``: replay cache size; when full of unexpired nonces, commands are refused.
    ``rate_per_s`` / ``burst``: each signed sender's token bucket (requests per second, at most
    ``burst`` at once); ``max_senders``: senders remembered (bucket, newest issued time).
    ``max_requests_per_s``: requests of any sender, signed or not, read per second (a bucket of a
    second's worth): beyond it a request is refused unread, so a flood costs its Zenoh callback
    and a fixed answer, never a parse or a MAC.
    """

    enabled: bool = False
    secret: bytes | None = field(default=None, repr=False)
    window_s: float = 5.0
    max_nonces: int = 4096
    rate_per_s: float = 2.0
    burst: int = 10
    max_senders: int = 256
    max_requests_per_s: float = 50.0

    def __post_init__(self) -> None:
        if self.secret is not None and not isinstance(self.secret, bytes):
            raise ValueError("commands.secret must be bytes")
        if self.enabled and (self.secret is None or len(self.secret) < MIN_SECRET_BYTES):
            raise ValueError(f"commands.enabled needs a shared secret of at least {MIN_SECRET_BYTES} bytes")
        if not 0.1 <= self.window_s <= 300.0:
            raise ValueError(f"commands.window_s {self.window_s} outside [0.1, 300] s")
        if not 16 <= self.max_nonces <= 1_000_000:
            raise ValueError(f"commands.max_nonces {self.max_nonces} outside [16, 1e6]")
        if not 0.01 <= self.rate_per_s <= 1000.0:
            raise ValueError(f"commands.rate_per_s {self.rate_per_s} outside [0.01, 1000]")
        if not 1 <= self.burst <= 10_000:
            raise ValueError(f"commands.burst {self.burst} outside [1, 10000]")
        if not 1 <= self.max_senders <= 100_000:
            raise ValueError(f"commands.max_senders {self.max_senders} outside [1, 1e5]")
        if not 1.0 <= self.max_requests_per_s <= 100_000.0:
            raise ValueError(f"commands.max_requests_per_s {self.max_requests_per_s} outside [1, 1e5]")

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


class TokenBucket:
    """``rate_per_s`` tokens a second, at most ``burst`` held; a request takes one."""

    __slots__ = ("burst", "rate_per_s", "t", "tokens")

    def __init__(self, rate_per_s: float, burst: int, now: float):
        self.rate_per_s, self.burst = rate_per_s, burst
        self.tokens, self.t = float(burst), now

    def take(self, now: float) -> bool:
        self.tokens = min(float(self.burst), self.tokens + max(0.0, now - self.t) * self.rate_per_s)
        self.t = now
        if self.tokens < 1.0:
            return False
        self.tokens -= 1.0
        return True


class RefusalLog:
    """Refusals counted by kind and logged as a sample: the first refusal of each ``interval_s``
    (monotonic) is logged with how many were refused since the last line; :meth:`note` says
    whether this refusal is that sample (its caller writes a row for it only then). Thread-safe."""

    def __init__(self, what: str, interval_s: float = 1.0, monotonic: Callable[[], float] = time.monotonic):
        self.what = what
        self.interval_s = interval_s
        self._mono = monotonic
        self._lock = threading.Lock()
        self._counts = dict.fromkeys(RefusalKind, 0)
        self._last_logged = -float("inf")
        self._unlogged = 0

    def note(self, kind: RefusalKind, reason: str) -> int | None:
        """Count one refusal. Returns the refusals left unlogged before it when it is the sample
        (logged now), None when it is only counted."""
        with self._lock:
            self._counts[kind] += 1
            now = self._mono()
            if now - self._last_logged < self.interval_s:
                self._unlogged += 1
                return None
            self._last_logged, skipped, self._unlogged = now, self._unlogged, 0
        more = f" (+{skipped} more refused since the last line)" if skipped else ""
        log.warning("%s REFUSED (%s): %s%s", self.what, kind.value, reason, more)
        return skipped

    def counts(self) -> dict[RefusalKind, int]:
        with self._lock:
            return dict(self._counts)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())


def _bounded_put(cache: OrderedDict[str, Any], key: str, value: Any, limit: int) -> None:
    cache[key] = value
    cache.move_to_end(key)
    while len(cache) > limit:
        cache.popitem(last=False)


class SignedRequestGuard:
    """The checks every signed request from the ground shares (commands, delivery orders): the MAC
    over the request's canonical bytes, the vehicle it is for, the pre-flight clock verdict, the
    issued time against the vehicle clock (+-``window_s``) and the sender's newest, the nonce
    replay cache (expiring on monotonic age) and the sender's token bucket. ``what`` names the
    request in the refusal reasons ("command", "order"). Thread-safe. ``clock``: a
    :class:`~companion.timebase.VehicleClock`, or a function of Unix seconds (a test's wall
    clock, carried on ``monotonic``); ``None`` or :func:`time.time`: the process's vehicle clock."""

    def __init__(
        self,
        vehicle_id: str,
        settings: CommandSettings,
        what: str,
        clock: VehicleClock | Callable[[], float] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
    ):
        self.vehicle_id = check_vehicle_id(vehicle_id)
        self.settings = settings
        self.what = what
        if isinstance(clock, VehicleClock):
            self.clock = clock
        elif clock is None or clock is time.time:
            self.clock = vehicle_clock()
        else:
            self.clock = VehicleClock(clock, monotonic)
        self._seen: OrderedDict[str, float] = OrderedDict()  # nonce -> expiry (monotonic s)
        self._newest: OrderedDict[str, int] = OrderedDict()  # sender -> newest accepted issued_unix_ms
        self._buckets: OrderedDict[str, TokenBucket] = OrderedDict()
        self._base: float | None = None  # vehicle time minus monotonic time at the last admit
        self._step_logged = 0.0  # the wall clock's step from the vehicle clock, as last logged
        self._lock = threading.Lock()
        rate = settings.max_requests_per_s
        self._gate = TokenBucket(rate, max(1, round(rate)), self.clock.monotonic())

    def gate(self) -> None:
        """Refuse a request unread when more than ``max_requests_per_s`` arrive (first of all checks)."""
        with self._lock:
            if self._gate.take(self.clock.monotonic()):
                return
        raise CommandRefused(
            f"overloaded: more than {self.settings.max_requests_per_s:g} {self.what}s a second; try later",
            RefusalKind.OVERLOAD,
        )

    def secret(self) -> bytes:
        """The shared secret, or :class:`CommandRefused` when signed requests are off."""
        s = self.settings
        if not s.enabled or s.secret is None:
            raise CommandRefused(f"{self.what}s are disabled on this vehicle", RefusalKind.DISABLED)
        return s.secret

    def authenticate(self, data: bytes, mac: str, vehicle_id: str) -> None:
        """The MAC over ``data`` is the shared secret's, and the request is for this vehicle."""
        if not hmac.compare_digest(compute_mac(self.secret(), data), mac):
            raise CommandRefused("authentication failed: bad HMAC", RefusalKind.AUTHENTICATION)
        if vehicle_id != self.vehicle_id:
            raise CommandRefused(
                f"{self.what} is for vehicle {vehicle_id!r}, this is {self.vehicle_id!r}", RefusalKind.WRONG_VEHICLE
            )

    def admit(self, issued_ms: int, nonce: str, sender: str) -> float:
        """Refuse on an OFF clock verdict, a stale (or future) or replayed request, or a sender
        over its rate; else remember the nonce. Returns the vehicle's Unix time now."""
        s = self.settings
        verdict = self.clock.verdict
        if not verdict.accepts_signed_requests:
            off = f"{self.clock.offset_s:+.1f} s" if self.clock.offset_s is not None else "unknown"
            raise CommandRefused(
                f"clock not trusted: the pre-flight check found the vehicle clock off the autopilot's UTC "
                f"({off}); signed {self.what}s are refused until a check agrees",
                RefusalKind.CLOCK,
            )
        mono = self.clock.monotonic()
        now = self.clock.now()
        self._log_step(s.window_s)
        issued = issued_ms / 1000.0
        if abs(now - issued) > s.window_s:
            raise CommandRefused(
                f"stale {self.what}: issued {now - issued:+.1f} s from the vehicle clock (window +-{s.window_s:g} s)",
                RefusalKind.STALE,
            )
        with self._lock:
            self._admit_locked(issued_ms, nonce, sender, now, mono)
        return now

    def _log_step(self, window_s: float) -> None:
        """Say once per change of more than the window that the wall clock has stepped."""
        step = self.clock.step_s()
        if abs(step - self._step_logged) <= window_s:
            return
        self._step_logged = step
        log.warning(
            "the wall clock is %+.1f s from the vehicle clock (stepped since it was anchored): signed %ss are "
            "judged on the vehicle clock",
            step,
            self.what,
        )

    def _admit_locked(self, issued_ms: int, nonce: str, sender: str, now: float, mono: float) -> None:
        s = self.settings
        base = now - mono
        if self._base is not None and base < self._base:
            # the vehicle time was re-anchored backwards: requests it had left behind are fresh
            # again, so their nonces are kept that much longer
            shift = self._base - base
            for n in self._seen:
                self._seen[n] += shift
        self._base = base
        # A nonce may be forgotten once twice the window has passed on the monotonic clock: a
        # request is fresh for at most that long. Entries are in arrival order, so expiry order.
        while self._seen and next(iter(self._seen.values())) < mono:
            self._seen.popitem(last=False)
        if nonce in self._seen:
            raise CommandRefused(f"replayed {self.what}: nonce already used", RefusalKind.REPLAY)
        newest = self._newest.get(sender)
        if newest is not None and issued_ms < newest - round(s.window_s * 1000.0):
            raise CommandRefused(
                f"stale {self.what}: issued {(newest - issued_ms) / 1000.0:.1f} s before {sender}'s newest "
                f"(window {s.window_s:g} s)",
                RefusalKind.STALE,
            )
        if len(self._seen) >= s.max_nonces:
            raise CommandRefused(f"too many {self.what}s in the replay window; try later", RefusalKind.OVERLOAD)
        self._seen[nonce] = mono + 2.0 * s.window_s
        bucket = self._buckets.get(sender)
        if bucket is None:
            bucket = TokenBucket(s.rate_per_s, s.burst, mono)
        _bounded_put(self._buckets, sender, bucket, s.max_senders)
        if not bucket.take(mono):
            raise CommandRefused(
                f"rate: {sender} is over {s.rate_per_s:g} {self.what}s/s (burst {s.burst})", RefusalKind.RATE
            )
        _bounded_put(self._newest, sender, max(issued_ms, newest or issued_ms), s.max_senders)


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
        raise CommandRefused(f"malformed {what}: not a JSON object", RefusalKind.MALFORMED)
    if doc.get("schema") != schema:
        raise CommandRefused(f"malformed {what}: schema is not {schema!r}", RefusalKind.MALFORMED)
    if "hmac_sha256" not in doc:
        raise CommandRefused("authentication failed: no hmac_sha256", RefusalKind.AUTHENTICATION)
    for name in ("vehicle_id", *own, "issued_unix_ms", "nonce", "sender"):
        if name not in doc:
            raise CommandRefused(f"malformed {what}: missing {name!r}", RefusalKind.MALFORMED)
    vehicle_id, issued_ms = doc["vehicle_id"], doc["issued_unix_ms"]
    nonce, sender, note, mac = doc["nonce"], doc["sender"], doc.get("note", ""), doc["hmac_sha256"]
    if not isinstance(vehicle_id, str):
        raise CommandRefused(f"malformed {what}: vehicle_id must be a short string", RefusalKind.MALFORMED)
    try:
        check_vehicle_id(vehicle_id)
    except SchemaError as e:
        raise CommandRefused(f"malformed {what}: {e}", RefusalKind.MALFORMED) from None
    if isinstance(issued_ms, bool) or not isinstance(issued_ms, int) or not 0 <= issued_ms < MAX_ISSUED_MS:
        raise CommandRefused(
            f"malformed {what}: issued_unix_ms must be an integer in [0, 2**53)", RefusalKind.MALFORMED
        )
    if not isinstance(nonce, str) or not _NONCE.match(nonce):
        raise CommandRefused(f"malformed {what}: nonce must be 16-64 lowercase hex characters", RefusalKind.MALFORMED)
    if not isinstance(sender, str) or not _SENDER.match(sender):
        raise CommandRefused(f"malformed {what}: bad sender", RefusalKind.MALFORMED)
    if not isinstance(note, str) or len(note) > MAX_NOTE_CHARS:
        raise CommandRefused(
            f"malformed {what}: note must be a string <= {MAX_NOTE_CHARS} chars", RefusalKind.MALFORMED
        )
    if not isinstance(mac, str) or not re.fullmatch(r"[0-9a-f]{64}", mac):
        raise CommandRefused(
            "authentication failed: hmac_sha256 must be 64 lowercase hex chars", RefusalKind.AUTHENTICATION
        )
    return SignedFields(vehicle_id, issued_ms, nonce, sender, note, mac)


def parse_payload(payload: bytes | bytearray | memoryview | None, what: str) -> Any:
    """The JSON document of a request payload, or :class:`CommandRefused` (empty, not JSON)."""
    if payload is None or len(payload) == 0:
        raise CommandRefused(f"malformed {what}: empty payload", RefusalKind.MALFORMED)
    try:
        return parse_json(payload)
    except SchemaError as e:
        raise CommandRefused(f"malformed {what}: {e}", RefusalKind.MALFORMED) from None


class CommandVerifier:
    """Checks command payloads for one vehicle: format, MAC, time window, nonce replay.

    Thread-safe (Zenoh calls queryables from its own threads). ``clock``: as
    :class:`SignedRequestGuard`'s.
    """

    def __init__(
        self,
        vehicle_id: str,
        settings: CommandSettings,
        clock: VehicleClock | Callable[[], float] | None = None,
        monotonic: Callable[[], float] = time.monotonic,
    ):
        self._guard = SignedRequestGuard(vehicle_id, settings, "command", clock, monotonic)
        self.vehicle_id = self._guard.vehicle_id
        self.settings = settings

    def verify(self, payload: bytes | bytearray | memoryview | None) -> GroundCommand:
        """The command in ``payload``, or :class:`CommandRefused` with the reason."""
        g = self._guard
        g.secret()
        g.gate()
        doc = parse_payload(payload, "command")
        f = parse_signed_fields(doc, COMMAND_SCHEMA, "command", ("command",))
        command = doc["command"]
        if not isinstance(command, str) or len(command) > 32:
            raise CommandRefused(
                "malformed command: vehicle_id and command must be short strings", RefusalKind.MALFORMED
            )
        g.authenticate(mac_input(f.vehicle_id, command, f.issued_ms, f.nonce, f.sender, f.note), f.mac, f.vehicle_id)
        try:
            kind = CommandKind(command)
        except ValueError:
            allowed = ", ".join(k.value for k in CommandKind)
            raise CommandRefused(
                f"unknown command {command!r} (allowed: {allowed})", RefusalKind.UNKNOWN_COMMAND
            ) from None
        now = g.admit(f.issued_ms, f.nonce, f.sender)
        return GroundCommand(
            vehicle_id=f.vehicle_id,
            kind=kind,
            issued_unix_s=f.issued_ms / 1000.0,
            received_unix_s=now,
            nonce=f.nonce,
            sender=f.sender,
            note=f.note,
        )
