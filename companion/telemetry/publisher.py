"""The vehicle side: publish telemetry over Zenoh without ever slowing the control loop.

Use from the asyncio shell::

    pub = TelemetryPublisher(TelemetrySettings(vehicle_id="drone1"), zenoh_settings,
                             params={"pad_size_m": 1.0}, on_command=call_in_loop(loop, mission.on_ground_command))
    pub.start()
    ...
    pub.publish(StateMessage.from_samples(estimate, global_position, status, gps))   # hot path
    pub.publish(MissionMessage.for_event(event))                                     # never dropped
    ...
    await pub.astop()

``publish`` only takes a lock, stores the message and wakes the worker thread (a few
microseconds); encoding and ``put`` happen on the worker. Two lanes:

- **keep-newest** (state, estimate, mission status, landing, health): one slot per topic; a
  newer sample replaces an unsent one (counted as ``superseded``), and the worker publishes at
  most ``<topic>_rate_hz`` (downsampling). Zenoh congestion control DROP, so a slow ground link
  drops stale samples instead of queueing them.
- **never-drop** (mission messages carrying an event, log text): a FIFO, published in order
  before any slot, with congestion control BLOCK (a congested link blocks the *worker*, never
  the caller). The FIFO is bounded (``event_queue_size``, far above any mission's event count);
  if it ever fills, the event is counted in ``fifo_overflow`` and logged as an error rather
  than blocking the control loop.

All publishers are declared reliable and use Zenoh's batching (``express=False``): with
``express=True`` every sample takes a transmit-queue slot of its own, and on a loaded 2-core
board back-to-back DROP samples were then occasionally dropped on loopback; batching costs
under a millisecond of latency (``companion bench telemetry``). ``publish`` only hands the sample
over; encoding runs on the worker. Presence: a liveliness token ``companion/<id>/alive`` exists
while the publisher runs. A queryable ``companion/<id>/info`` answers identity, versions
and the params given at construction. A queryable ``companion/<id>/command`` refuses every
command unless command access is enabled with a secret (see :mod:`.auth`); accepted commands
go to ``on_command`` (called on a Zenoh thread: use :func:`call_in_loop` to hop to asyncio).
Commands are verified on that Zenoh thread, never on the flight loop; refusals are counted by kind
and logged as a sample (:class:`~.auth.RefusalLog`, one line a second), and the health topic
carries the counts (:meth:`TelemetryPublisher.refusal_counts`).
The mission decides what to do with a command; nothing here touches setpoints.
"""

from __future__ import annotations

import asyncio
import json
import logging
import platform
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

import zenoh

from companion.telemetry.auth import (
    CommandRefused,
    CommandSettings,
    CommandVerifier,
    GroundCommand,
    RefusalKind,
    RefusalLog,
)
from companion.telemetry.schema import (
    SCHEMA,
    Message,
    SchemaError,
    Topic,
    alive_key,
    check_vehicle_id,
    command_key,
    encode,
    info_key,
    topic_key,
    topic_of,
)
from companion.telemetry.session import ZenohSettings

log = logging.getLogger(__name__)

INFO_SCHEMA = "companion.info/1"
COMMAND_REPLY_SCHEMA = "companion.command-reply/1"

_FIFO_TOPICS = (Topic.MISSION, Topic.LOG)  # the topics whose publishers BLOCK


@dataclass(frozen=True)
class TelemetrySettings:
    """Per-vehicle telemetry: identity, per-topic maximum rates (Hz), queue bound, commands."""

    vehicle_id: str
    state_rate_hz: float = 20.0
    estimate_rate_hz: float = 10.0
    mission_rate_hz: float = 5.0  # mission *status*; events are sent immediately, never dropped
    landing_rate_hz: float = 10.0
    health_rate_hz: float = 1.0
    event_queue_size: int = 1024
    express: bool = False  # True: bypass batching (lower latency, but more drops under load)
    commands: CommandSettings = field(default_factory=CommandSettings)

    def __post_init__(self) -> None:
        check_vehicle_id(self.vehicle_id)
        for topic in (Topic.STATE, Topic.ESTIMATE, Topic.MISSION, Topic.LANDING, Topic.HEALTH):
            rate = self.rate_hz(topic)
            if not 0.01 <= rate <= 1000.0:
                raise ValueError(f"telemetry.{topic.value}_rate_hz {rate} outside [0.01, 1000]")
        if not 16 <= self.event_queue_size <= 1_000_000:
            raise ValueError(f"telemetry.event_queue_size {self.event_queue_size} outside [16, 1e6]")

    def rate_hz(self, topic: Topic) -> float:
        return float(getattr(self, f"{topic.value}_rate_hz"))


@dataclass(frozen=True)
class PublisherCounters:
    """Totals since start. ``submitted`` counts ``publish`` calls accepted into a lane;
    ``published`` successful puts; ``superseded`` keep-newest samples replaced before sending
    (downsampling); ``fifo_overflow`` never-drop messages refused because the FIFO was full."""

    submitted: Mapping[str, int]
    published: Mapping[str, int]
    superseded: Mapping[str, int]
    encode_errors: int
    put_errors: int
    fifo_overflow: int
    fifo_high_water: int
    commands_accepted: int
    commands_refused: int
    info_queries: int

    @property
    def dropped(self) -> int:
        """Messages lost to errors or overflow (superseding is by design, not counted)."""
        return self.encode_errors + self.put_errors + self.fifo_overflow


def call_in_loop(
    loop: asyncio.AbstractEventLoop, fn: Callable[[GroundCommand], Any]
) -> Callable[[GroundCommand], None]:
    """Wrap ``fn`` so a command arriving on a Zenoh thread is handled on the asyncio loop."""

    def handler(cmd: GroundCommand) -> None:
        loop.call_soon_threadsafe(fn, cmd)

    return handler


def _versions() -> dict[str, str]:
    out = {"python": platform.python_version(), "telemetry_schema": SCHEMA}
    for dist in ("companion", "eclipse-zenoh"):
        try:
            out[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist] = "unknown"
    return out


class TelemetryPublisher:
    """Publishes one vehicle's telemetry; see the module docstring."""

    def __init__(
        self,
        settings: TelemetrySettings,
        zenoh_settings: ZenohSettings | None = None,
        *,
        session: zenoh.Session | None = None,
        params: Mapping[str, Any] | None = None,
        on_command: Callable[[GroundCommand], None] | None = None,
        clock: Callable[[], float] = time.monotonic,
        wall_clock: Callable[[], float] = time.time,
    ):
        if (zenoh_settings is None) == (session is None):
            raise ValueError("give either zenoh_settings (the publisher opens a session) or session")
        if settings.commands.enabled and on_command is None:
            raise ValueError("commands are enabled but no on_command callback was given")
        self.settings = settings
        self.vehicle_id = settings.vehicle_id
        self._zenoh_settings = zenoh_settings
        self._session = session
        self._owns_session = session is None
        self._params = dict(params or {})
        try:
            json.dumps(self._params, allow_nan=False)
        except (TypeError, ValueError) as e:
            raise ValueError(f"info params must be JSON-serialisable: {e}") from e
        self._on_command = on_command
        self._verifier = CommandVerifier(self.vehicle_id, settings.commands, clock=wall_clock)
        self.refusals = RefusalLog("ground command")
        self._refusal_sources: dict[str, Callable[[], int]] = {"ground_commands": lambda: self.refusals.total}
        self._clock = clock
        self._wall = wall_clock

        self._cond = threading.Condition()
        self._fifo: deque[Message] = deque()
        self._slots: dict[Topic, Message] = {}
        self._period: dict[Topic, float] = {t: 1.0 / settings.rate_hz(t) for t in Topic if t is not Topic.LOG}
        self._next_due: dict[Topic, float] = {}
        self._seq = dict.fromkeys(Topic, 0)
        self._submitted = dict.fromkeys(Topic, 0)
        self._published = dict.fromkeys(Topic, 0)
        self._superseded = dict.fromkeys(Topic, 0)
        self._encode_errors = 0
        self._put_errors = 0
        self._fifo_overflow = 0
        self._fifo_high_water = 0
        self._inflight = 0
        self._commands_accepted = 0
        self._commands_refused = 0
        self._info_queries = 0

        self._publishers: dict[Topic, zenoh.Publisher] = {}
        self._declared: list[Any] = []
        self._worker: threading.Thread | None = None
        self._running = False
        self._stopping = False
        self._started_unix_s = 0.0

    # ---- lifecycle ---------------------------------------------------------------------------

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("publisher not started")
        return self._session

    @property
    def running(self) -> bool:
        return self._running

    def start(self) -> TelemetryPublisher:
        if self._running:
            return self
        if self._session is None:
            assert self._zenoh_settings is not None
            self._session = self._zenoh_settings.open_or_explain()
        try:
            self._declare()
        except BaseException:  # a half-declared start leaves no session (and its threads) behind
            self._undeclare_all()
            if self._owns_session and self._session is not None:
                self._session.close()
                self._session = None
            raise
        self._started_unix_s = self._wall()
        self._stopping = False
        self._running = True
        self._worker = threading.Thread(target=self._run, name=f"telemetry-{self.vehicle_id}", daemon=True)
        self._worker.start()
        log.info(
            "telemetry for %s started (commands %s)",
            self.vehicle_id,
            "ENABLED" if self.settings.commands.enabled else "disabled",
        )
        return self

    def _declare(self) -> None:
        s = self._session
        assert s is not None
        for topic in Topic:
            block = topic in _FIFO_TOPICS
            self._publishers[topic] = s.declare_publisher(
                topic_key(self.vehicle_id, topic),
                encoding=zenoh.Encoding.APPLICATION_JSON,
                congestion_control=(zenoh.CongestionControl.BLOCK if block else zenoh.CongestionControl.DROP),
                priority=zenoh.Priority.DATA_HIGH if block else zenoh.Priority.DATA,
                express=self.settings.express,
                reliability=zenoh.Reliability.RELIABLE,
            )
        self._declared.append(s.declare_queryable(info_key(self.vehicle_id), self._on_info_query))
        self._declared.append(s.declare_queryable(command_key(self.vehicle_id), self._on_command_query))
        # The token last: the ground sees the vehicle once everything above answers.
        self._declared.append(s.liveliness().declare_token(alive_key(self.vehicle_id)))

    def _undeclare_all(self) -> None:
        for entity in reversed(self._declared):
            try:
                entity.undeclare()
            except Exception:  # already gone with a closed session
                log.debug("undeclare failed", exc_info=True)
        self._declared.clear()
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._publishers.clear()

    def stop(self, flush_timeout_s: float = 2.0) -> None:
        """Send what is queued (up to ``flush_timeout_s``), withdraw presence, close."""
        if not self._running:
            return
        with self._cond:
            self._stopping = True
            self._cond.notify()
        if self._worker is not None:
            self._worker.join(flush_timeout_s)
            if self._worker.is_alive():
                log.warning("telemetry worker for %s did not flush in time", self.vehicle_id)
        self._running = False
        self._undeclare_all()
        if self._owns_session and self._session is not None:
            self._session.close()
            self._session = None
        log.info("telemetry for %s stopped: %s", self.vehicle_id, self.counters())

    async def astop(self, flush_timeout_s: float = 2.0) -> None:
        """:meth:`stop` without blocking the event loop."""
        await asyncio.to_thread(self.stop, flush_timeout_s)

    def __enter__(self) -> TelemetryPublisher:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- hot path ----------------------------------------------------------------------------

    def publish(self, msg: Message) -> bool:
        """Queue one message without blocking. False if it could not be queued (not running,
        or the never-drop FIFO is full - counted and logged)."""
        topic = topic_of(msg)
        fifo = topic is Topic.LOG or (topic is Topic.MISSION and msg.event is not None)  # type: ignore[union-attr]
        with self._cond:
            if not self._running or self._stopping:
                return False
            if fifo:
                if len(self._fifo) >= self.settings.event_queue_size:
                    self._fifo_overflow += 1
                    overflow = self._fifo_overflow
                else:
                    overflow = 0
                    self._fifo.append(msg)
                    self._fifo_high_water = max(self._fifo_high_water, len(self._fifo))
            else:
                overflow = 0
                if topic in self._slots:
                    self._superseded[topic] += 1
                self._slots[topic] = msg
            if not overflow:
                self._submitted[topic] += 1
                self._cond.notify()
        if overflow:
            log.error(
                "telemetry FIFO full (%d): %s message not sent (%d so far)",
                self.settings.event_queue_size,
                topic.value,
                overflow,
            )
            return False
        return True

    # ---- worker ------------------------------------------------------------------------------

    def _run(self) -> None:
        while True:
            with self._cond:
                while True:
                    now = self._clock()
                    due: list[tuple[Topic, Message]] = []
                    wait: float | None = None
                    for topic in list(self._slots):
                        left = self._next_due.get(topic, now) - now
                        if left <= 0.0 or self._stopping:
                            due.append((topic, self._slots.pop(topic)))
                        elif wait is None or left < wait:
                            wait = left
                    if self._fifo or due:
                        break
                    if self._stopping:
                        return
                    self._cond.wait(wait)
                fifo = list(self._fifo)
                self._fifo.clear()
                self._inflight = len(fifo) + len(due)
            for msg in fifo:
                self._send(topic_of(msg), msg)
            for topic, msg in due:
                self._send(topic, msg)
                period = self._period[topic]
                nxt = self._next_due.get(topic, now) + period
                self._next_due[topic] = nxt if nxt >= now else now + period
            with self._cond:
                self._inflight = 0

    def _send(self, topic: Topic, msg: Message) -> None:
        seq = self._seq[topic]
        try:
            payload = encode(self.vehicle_id, msg, seq, self._wall())
        except (SchemaError, TypeError, ValueError) as e:
            self._encode_errors += 1
            log.warning("telemetry %s message not encodable, dropped: %s", topic.value, e)
            return
        try:
            self._publishers[topic].put(payload)
        except Exception as e:
            self._put_errors += 1
            log.warning("telemetry %s put failed: %s", topic.value, e)
            return
        self._seq[topic] = seq + 1
        self._published[topic] += 1

    # ---- counters ----------------------------------------------------------------------------

    def counters(self) -> PublisherCounters:
        with self._cond:
            return PublisherCounters(
                submitted={t.value: n for t, n in self._submitted.items()},
                published={t.value: n for t, n in self._published.items()},
                superseded={t.value: n for t, n in self._superseded.items()},
                encode_errors=self._encode_errors,
                put_errors=self._put_errors,
                fifo_overflow=self._fifo_overflow,
                fifo_high_water=self._fifo_high_water,
                commands_accepted=self._commands_accepted,
                commands_refused=self._commands_refused,
                info_queries=self._info_queries,
            )

    def has_subscribers(self, topic: Topic = Topic.STATE) -> bool:
        """Whether any subscriber (the ground, a recorder) currently matches ``topic``."""
        pub = self._publishers.get(topic)
        if pub is None:
            return False
        try:
            status: Any = pub.matching_status  # a MatchingStatus at runtime (the stub says bool)
            return bool(getattr(status, "matching", status))
        except Exception:  # session closing
            return False

    def count_refusals(self, name: str, count: Callable[[], int]) -> None:
        """Add a count of refused ground requests (``name``: e.g. "orders") to :meth:`refusal_counts`."""
        self._refusal_sources[name] = count

    def refusal_counts(self) -> dict[str, int]:
        """Ground requests refused so far, by source (for the health topic)."""
        return {name: count() for name, count in self._refusal_sources.items()}

    def pending(self) -> int:
        """Messages queued or being sent, not yet published (or failed)."""
        with self._cond:
            return len(self._fifo) + len(self._slots) + self._inflight

    # ---- queryables (called on Zenoh threads) ------------------------------------------------

    def info(self) -> dict[str, Any]:
        """The identity document the ``info`` queryable answers."""
        s = self.settings
        return {
            "schema": INFO_SCHEMA,
            "vehicle_id": self.vehicle_id,
            "zenoh_id": str(self._session.zid()) if self._session is not None else None,
            "started_unix_s": self._started_unix_s,
            "versions": _versions(),
            "telemetry": {
                "schema": SCHEMA,
                "rates_hz": {t.value: s.rate_hz(t) for t in self._period},
                "never_drop": ["mission events", "log"],
            },
            "commands_enabled": s.commands.enabled,
            "params": self._params,
        }

    def _on_info_query(self, query: zenoh.Query) -> None:
        self._info_queries += 1
        try:
            body = json.dumps(self.info(), allow_nan=False)
            query.reply(query.key_expr, body, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception:
            log.exception("info query failed")

    def _on_command_query(self, query: zenoh.Query) -> None:
        payload = query.payload
        raw = payload.to_bytes() if payload is not None else None
        try:
            cmd = self._verifier.verify(raw)
        except CommandRefused as e:
            self._refuse(query, e.reason, e.kind)
            return
        try:
            assert self._on_command is not None  # enabled implies a callback (checked in init)
            self._on_command(cmd)
        except Exception as e:
            log.exception("ground command %s: mission callback failed", cmd.kind.value)
            self._refuse(query, f"mission callback failed: {type(e).__name__}", RefusalKind.VEHICLE)
            return
        self._commands_accepted += 1
        log.warning(
            "ground command ACCEPTED: %s from %s (nonce %s) - handed to the mission",
            cmd.kind.value,
            cmd.sender,
            cmd.nonce,
        )
        self._reply(
            query,
            {
                "accepted": True,
                "command": cmd.kind.value,
                "nonce": cmd.nonce,
                "reason": "handed to the mission; it decides, within the safety limits",
            },
            ok=True,
        )

    def _refuse(self, query: zenoh.Query, reason: str, kind: RefusalKind) -> None:
        self._commands_refused += 1
        self.refusals.note(kind, f"{self.vehicle_id}: {reason}")  # logged one a second, all counted
        self._reply(query, {"accepted": False, "reason": reason}, ok=False)

    def _reply(self, query: zenoh.Query, body: dict[str, Any], ok: bool) -> None:
        doc = json.dumps({"schema": COMMAND_REPLY_SCHEMA, "vehicle_id": self.vehicle_id, **body})
        try:
            if ok:
                query.reply(query.key_expr, doc, encoding=zenoh.Encoding.APPLICATION_JSON)
            else:
                query.reply_err(doc, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception:
            log.exception("command reply failed")
