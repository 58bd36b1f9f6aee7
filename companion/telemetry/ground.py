"""The ground station: watch a fleet, record everything, send authenticated commands.

Library use::

    station = GroundStation(ZenohSettings(connect=("tcp/10.0.0.2:7447",)), out_dir=Path("rec"))
    station.start()
    rows = station.snapshot()          # {vehicle_id: VehicleRow}
    station.query_info("drone1")
    station.send_command("drone1", CommandKind.HOLD, secret)
    station.stop()

Command line: ``companion ground`` (see :mod:`.commands`) shows a live ``rich`` table.

Recording (``out_dir``): one JSON-lines file per vehicle and topic,
``<out_dir>/<vehicle_id>/<topic>.jsonl``, each line ``{"rx_unix_s": <receive time>,
"env": <the envelope exactly as received>}``; presence changes go to
``<vehicle_id>/alive.jsonl`` (``{"rx_unix_s", "alive"}``) and payloads that fail validation
to ``<out_dir>/rejected.jsonl`` (``{"rx_unix_s", "key", "reason", "size"}``). Vehicle ids are
validated (letters, digits, ``_``, ``-``) before they name a folder.
"""

from __future__ import annotations

import json
import logging
import signal
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Any

import zenoh
from rich.console import Console
from rich.live import Live
from rich.table import Table

from companion.events import Phase
from companion.telemetry.auth import CommandKind, sign_command
from companion.telemetry.orders import OrderPad, sign_order
from companion.telemetry.schema import (
    ALL_ALIVE_KEY,
    ALL_VEHICLES_KEY,
    Envelope,
    HealthMessage,
    LandingMessage,
    MissionMessage,
    SchemaError,
    StateMessage,
    Topic,
    command_key,
    decode,
    info_key,
    order_key,
    parse_json,
    parse_key,
)
from companion.telemetry.session import ZenohSettings
from companion.units import format_m

log = logging.getLogger(__name__)

Listener = Callable[[Envelope, float], None]


@dataclass(frozen=True, slots=True)
class VehicleRow:
    """One line of the ground table (None: not received yet)."""

    vehicle_id: str
    alive: bool
    phase: Phase | None = None
    mode: str | None = None
    status_age_s: float | None = None  # age of the autopilot status behind mode/armed when sent
    armed: bool | None = None
    north_m: float | None = None
    east_m: float | None = None
    alt_m: float | None = None  # height above home (-down_m)
    lat_deg: float | None = None
    lon_deg: float | None = None
    ground_speed_m_s: float | None = None
    battery_pct: float | None = None
    link_ok: bool | None = None
    heartbeat_age_s: float | None = None
    telemetry_dropped: int | None = None
    landing_error_m: float | None = None
    distance_to_pad_m: float | None = None  # from the estimate flown on to the configured pad
    sector: int | None = None
    last_event: str = ""
    received: int = 0
    lost: int = 0
    last_rx_unix_s: float | None = None


@dataclass(frozen=True)
class GroundCounters:
    received: int
    malformed: int
    lost: int
    recorded: int
    presence_changes: int


@dataclass(frozen=True)
class CommandReply:
    """What a vehicle answered to a command (``replied`` False: no answer before timeout)."""

    replied: bool
    accepted: bool
    reason: str


class GroundStation:
    """Subscribes to ``companion/**`` and to vehicle presence; thread-safe snapshot."""

    def __init__(
        self,
        settings: ZenohSettings,
        out_dir: str | Path | None = None,
        *,
        listener: Listener | None = None,
        clock: Callable[[], float] = time.time,
    ):
        self.settings = settings
        self.out_dir = Path(out_dir) if out_dir is not None else None
        self._listener = listener
        self._clock = clock
        self._lock = threading.Lock()
        self._rows: dict[str, VehicleRow] = {}
        self._last_seq: dict[tuple[str, Topic], int] = {}
        self._files: dict[tuple[str, str], IO[str]] = {}
        self._received = 0
        self._malformed = 0
        self._lost = 0
        self._recorded = 0
        self._presence = 0
        self._last_flush = time.monotonic()
        self._session: zenoh.Session | None = None
        self._entities: list[Any] = []

    # ---- lifecycle ---------------------------------------------------------------------------

    @property
    def session(self) -> zenoh.Session:
        if self._session is None:
            raise RuntimeError("ground station not started")
        return self._session

    def start(self) -> GroundStation:
        if self._session is not None:
            return self
        if self.out_dir is not None:
            self.out_dir.mkdir(parents=True, exist_ok=True)
        self._session = self.settings.open()
        self._entities.append(self._session.declare_subscriber(ALL_VEHICLES_KEY, self._on_sample))
        self._entities.append(
            self._session.liveliness().declare_subscriber(ALL_ALIVE_KEY, self._on_presence, history=True)
        )
        log.info("ground station started (mode %s), recording to %s", self.settings.mode, self.out_dir)
        return self

    def stop(self) -> None:
        if self._session is None:
            return
        for entity in reversed(self._entities):
            try:
                entity.undeclare()
            except Exception:
                log.debug("undeclare failed", exc_info=True)
        self._entities.clear()
        self._session.close()
        self._session = None
        with self._lock:
            for fh in self._files.values():
                fh.close()
            self._files.clear()
        log.info("ground station stopped: %s", self.counters())

    def __enter__(self) -> GroundStation:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ---- state -------------------------------------------------------------------------------

    def snapshot(self) -> dict[str, VehicleRow]:
        with self._lock:
            return dict(self._rows)

    def counters(self) -> GroundCounters:
        with self._lock:
            return GroundCounters(
                received=self._received,
                malformed=self._malformed,
                lost=self._lost,
                recorded=self._recorded,
                presence_changes=self._presence,
            )

    def flush(self) -> None:
        with self._lock:
            for fh in self._files.values():
                fh.flush()

    # ---- callbacks (Zenoh threads) -----------------------------------------------------------

    def _on_sample(self, sample: zenoh.Sample) -> None:
        rx = self._clock()
        key = str(sample.key_expr)
        raw = sample.payload.to_bytes()
        try:
            env = decode(raw, key=key)
        except SchemaError as e:
            self._reject(rx, key, str(e), len(raw))
            return
        with self._lock:
            self._received += 1
            self._update_row(env, rx)
            if self.out_dir is not None:
                text = raw.decode()
                if "\n" in text or "\r" in text:  # valid JSON whitespace, but it would split the line
                    text = json.dumps(json.loads(text), separators=(",", ":"))
                self._write(env.vehicle_id, env.topic.value, f'{{"rx_unix_s":{rx!r},"env":{text}}}')
        if self._listener is not None:
            try:
                self._listener(env, rx)
            except Exception:
                log.exception("ground listener failed")

    def _reject(self, rx: float, key: str, reason: str, size: int) -> None:
        with self._lock:
            self._malformed += 1
            n = self._malformed
            if self.out_dir is not None:
                line = json.dumps({"rx_unix_s": rx, "key": key, "reason": reason, "size": size})
                self._write(None, "rejected", line, flush=True)
        if n <= 10 or n % 1000 == 0:
            log.warning("malformed telemetry on %s (%d so far): %s", key, n, reason)

    def _on_presence(self, sample: zenoh.Sample) -> None:
        rx = self._clock()
        try:
            vehicle_id, _leaf = parse_key(str(sample.key_expr))
        except SchemaError as e:
            log.warning("ignored liveliness token %s: %s", sample.key_expr, e)
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            self._presence += 1
            row = self._rows.get(vehicle_id) or VehicleRow(vehicle_id=vehicle_id, alive=alive)
            self._rows[vehicle_id] = replace(row, alive=alive)
            if self.out_dir is not None:
                self._write(vehicle_id, "alive", json.dumps({"rx_unix_s": rx, "alive": alive}), flush=True)
        log.info("vehicle %s %s", vehicle_id, "appeared" if alive else "vanished")

    def _update_row(self, env: Envelope, rx: float) -> None:
        vid = env.vehicle_id
        row = self._rows.get(vid) or VehicleRow(vehicle_id=vid, alive=False)
        lost = row.lost
        last = self._last_seq.get((vid, env.topic))
        if last is not None and env.seq > last + 1:
            gap = env.seq - last - 1
            lost += gap
            self._lost += gap
        self._last_seq[(vid, env.topic)] = env.seq  # a restart (seq back to 0) resynchronises
        changes: dict[str, Any] = {"received": row.received + 1, "lost": lost, "last_rx_unix_s": rx}
        msg = env.msg
        if isinstance(msg, StateMessage):
            changes.update(
                mode=msg.mode.value if msg.status_age_s is not None or msg.mode.value != "unknown" else None,
                status_age_s=msg.status_age_s,
                armed=msg.armed,
                north_m=msg.north_m,
                east_m=msg.east_m,
                alt_m=-msg.down_m,
                lat_deg=msg.lat_deg,
                lon_deg=msg.lon_deg,
                ground_speed_m_s=msg.ground_speed_m_s,
                battery_pct=msg.battery_pct,
            )
        elif isinstance(msg, MissionMessage):
            changes.update(phase=msg.phase, sector=msg.sector, distance_to_pad_m=msg.distance_to_pad_m)
            if msg.event is not None:
                ev = msg.event
                changes["last_event"] = ev.kind.value + (f": {ev.detail}" if ev.detail else "")
        elif isinstance(msg, HealthMessage):
            changes.update(
                link_ok=msg.link_ok,
                heartbeat_age_s=msg.heartbeat_age_s,
                telemetry_dropped=msg.telemetry_dropped,
            )
        elif isinstance(msg, LandingMessage) and msg.landing_error_m is not None:
            # the last estimate stays shown after the landing
            changes.update(landing_error_m=msg.landing_error_m)
        self._rows[vid] = replace(row, **changes)

    def _write(self, vehicle_id: str | None, name: str, line: str, flush: bool = False) -> None:
        assert self.out_dir is not None
        key = (vehicle_id or "", name)
        fh = self._files.get(key)
        if fh is None:
            folder = self.out_dir / vehicle_id if vehicle_id else self.out_dir
            folder.mkdir(parents=True, exist_ok=True)
            fh = (folder / f"{name}.jsonl").open("a", encoding="utf-8")
            self._files[key] = fh
        fh.write(line + "\n")
        self._recorded += 1
        if flush:
            fh.flush()
        now = time.monotonic()
        if now - self._last_flush > 1.0:  # bound what a crash can lose to about a second
            self._last_flush = now
            for f in self._files.values():
                f.flush()

    # ---- queries -----------------------------------------------------------------------------

    def query_info(self, vehicle_id: str, timeout_s: float = 2.0) -> dict[str, Any] | None:
        """The vehicle's ``info`` document, or None if it did not answer in time."""
        for reply in self.session.get(info_key(vehicle_id), timeout=timeout_s):
            if reply.ok is not None:
                try:
                    doc = parse_json(reply.ok.payload.to_bytes())
                except SchemaError as e:
                    log.warning("bad info reply from %s: %s", vehicle_id, e)
                    continue
                if isinstance(doc, dict):
                    return doc
        return None

    def send_command(
        self,
        vehicle_id: str,
        kind: CommandKind,
        secret: bytes,
        *,
        sender: str = "ground",
        note: str = "",
        timeout_s: float = 2.0,
    ) -> CommandReply:
        """Sign and send one command; the vehicle's answer (accepted or the refusal reason)."""
        payload = sign_command(vehicle_id, kind, secret, sender=sender, note=note)
        return self.send_raw_command(vehicle_id, payload, timeout_s=timeout_s)

    def send_raw_command(self, vehicle_id: str, payload: bytes, *, timeout_s: float = 2.0) -> CommandReply:
        """Send an already-encoded command payload (also used to test refusals)."""
        return self._signed_query(command_key(vehicle_id), payload, timeout_s)

    def send_order(
        self,
        vehicle_id: str,
        pad: OrderPad,
        secret: bytes,
        *,
        order_id: str | None = None,
        alternate: OrderPad | None = None,
        sender: str = "ground",
        note: str = "",
        timeout_s: float = 5.0,
    ) -> CommandReply:
        """Sign and send one delivery order (docs/orders.md); the vehicle's answer."""
        payload = sign_order(vehicle_id, pad, secret, order_id=order_id, alternate=alternate, sender=sender, note=note)
        return self.send_raw_order(vehicle_id, payload, timeout_s=timeout_s)

    def send_raw_order(self, vehicle_id: str, payload: bytes, *, timeout_s: float = 5.0) -> CommandReply:
        """Send an already-encoded order payload (also used to test refusals)."""
        return self._signed_query(order_key(vehicle_id), payload, timeout_s)

    def _signed_query(self, key: str, payload: bytes, timeout_s: float) -> CommandReply:
        replies = self.session.get(key, payload=payload, timeout=timeout_s)
        for reply in replies:
            ok, err = reply.ok, reply.err
            if ok is not None:
                body = ok.payload.to_bytes()
            elif err is not None:
                body = err.payload.to_bytes()
            else:
                continue
            try:
                doc = parse_json(body)
            except SchemaError as e:
                return CommandReply(replied=True, accepted=False, reason=f"unreadable reply: {e}")
            if not isinstance(doc, dict):
                return CommandReply(replied=True, accepted=False, reason="unreadable reply")
            return CommandReply(
                replied=True,
                accepted=ok is not None and doc.get("accepted") is True,
                reason=str(doc.get("reason", "")),
            )
        return CommandReply(replied=False, accepted=False, reason="no reply (timeout)")


# ---- rendering ---------------------------------------------------------------------------------


#: An autopilot status older than this when it was published is shown with its age.
STALE_S = 2.0


def _fmt(value: float | None, fmt: str) -> str:
    return "-" if value is None else format(value, fmt)


def render_table(rows: dict[str, VehicleRow], now_unix_s: float | None = None) -> Table:
    """The fleet as a ``rich`` table (a vanished vehicle's name is shown red)."""
    now = time.time() if now_unix_s is None else now_unix_s
    table = Table(title="companion fleet", expand=False, pad_edge=False)
    for name, justify in (
        ("vehicle", "left"), ("phase", "left"), ("mode", "left"), ("N/E/alt m", "right"),
        ("m/s", "right"), ("to pad", "right"), ("batt", "right"), ("link", "center"), ("land err", "right"),
        ("rx/lost", "right"), ("age", "right"), ("last event", "left"),
    ):  # fmt: skip
        table.add_column(name, justify=justify, no_wrap=name != "last event")  # type: ignore[arg-type]
    for vid in sorted(rows):
        r = rows[vid]
        pos = "-" if r.north_m is None else f"{r.north_m:.1f}/{r.east_m:.1f}/{r.alt_m:.1f}"
        # a vanished vehicle's last link state and mode are history, not its present state
        link = "-" if r.link_ok is None or not r.alive else ("[green]ok" if r.link_ok else "[red]LOST")
        if r.alive and r.link_ok is not None and r.heartbeat_age_s is not None:
            link += f" ({r.heartbeat_age_s:.1f}s)"  # since the autopilot's last HEARTBEAT
        mode = r.mode or "-"
        if r.mode and not r.alive:
            mode = f"[dim]{r.mode} (last)"
        elif r.mode and r.status_age_s is not None and r.status_age_s > STALE_S:
            mode = f"{r.mode} ({r.status_age_s:.0f}s old)"
        age = None if r.last_rx_unix_s is None else now - r.last_rx_unix_s
        lost = str(r.lost) if r.lost == 0 else f"[red]{r.lost}[/red]"
        table.add_row(
            f"[green]{vid}" if r.alive else f"[red]{vid} (gone)",
            r.phase.value if r.phase else "-",
            mode,
            pos,
            _fmt(r.ground_speed_m_s, ".1f"),
            "-" if r.distance_to_pad_m is None else format_m(r.distance_to_pad_m),
            "-" if r.battery_pct is None else f"{r.battery_pct:.0f}%",
            link,
            "-" if r.landing_error_m is None else format_m(r.landing_error_m),
            f"{r.received}/{lost}",
            "-" if age is None else f"{age:.1f}s",
            r.last_event,
        )
    return table


def run_live(
    station: GroundStation,
    duration_s: float | None = None,
    refresh_hz: float = 4.0,
    console: Console | None = None,
) -> bool:
    """Show the live table until ``duration_s`` elapses (None: until Ctrl-C); True if Ctrl-C
    ended it. On the main thread Ctrl-C only sets a flag the loop reads each refresh: an interrupt
    raised wherever the main thread happened to be (inside rich's or Zenoh's calls) once left the
    command running after it (CI, under load)."""
    end = None if duration_s is None else time.monotonic() + duration_s
    stop = threading.Event()
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGINT, lambda signum, frame: stop.set())
    try:
        with Live(render_table(station.snapshot()), console=console, refresh_per_second=refresh_hz) as live:
            while not stop.is_set() and (end is None or time.monotonic() < end):
                stop.wait(1.0 / refresh_hz)
                live.update(render_table(station.snapshot()))
                station.flush()
    except KeyboardInterrupt:  # off the main thread, or before the handler was in place
        return True
    finally:
        if previous is not None:
            signal.signal(signal.SIGINT, previous)
    return stop.is_set()
