"""The vehicle's order desk (docs/orders.md): takes delivery orders from the ground over Zenoh,
checks each and answers accepted or refused with the reason, and hands an accepted one to
`fly --orders` (:mod:`companion.cli.orders`) to fly.

The checks, in order (the first that fails is the reason sent back):

1. authentication and form (:class:`~companion.telemetry.orders.OrderVerifier`: MAC, time window,
   replay, malformed fields): "authentication failed: ...", "stale order: ...", "replayed order: ...",
   "malformed order: ...";
2. busy: one order at a time, from its acceptance until its flight has ended ("busy: flying order X");
   an armed vehicle is busy too (the pilot or another mission flies it);
3. the destination as a configuration (:func:`~companion.delivery.destination.config_for_destination`:
   coordinates in range, pads inside the fence polygons): "destination: ...";
4. the vehicle: a status, home and local position from the autopilot ("vehicle not ready: ...");
5. the path: planned from where the vehicle stands, as the mission will ("path: ..."); range: the pad
   (and the alternate) within ``limits.geofence_radius_m`` of home ("out of range: ..."); the legs
   inside the fence polygons, below the ceilings and within the companion's clamps ("outside the
   flyable area: ...");
6. go / no-go (docs/go-no-go.md), with the mission's own checks: the wind the autopilot estimates and
   the charge for the round trip ("no-go: ...").

A refused order changes nothing on the vehicle. Check 1 runs on the Zenoh thread that received the
order, never on the flight loop; only a signed, fresh order within its sender's rate goes on to the
loop for checks 2-6, at most :data:`MAX_PENDING` at a time. Every decision of checks 2-6 is a mission
event (``EventKind.ORDER``), logged, written to ``orders.csv`` and handed to ``on_event``; refusals of
check 1 are counted by kind (:attr:`OrderDesk.refusals`) and sampled: one a second becomes the event,
the log line and the ``orders.csv`` row, saying how many were refused since the last.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import csv
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import zenoh

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import HomePosition, PositionNed, VehicleStatus, Wind
from companion.config import CompanionConfig
from companion.delivery.destination import Destination, DestinationError, GeoPad, config_for_destination
from companion.delivery.gonogo import BatteryMonitor, WindMonitor, round_trip_problem, way_home
from companion.delivery.planning import pad_position_ned, plan_delivery
from companion.events import EventKind, MissionEvent, Phase
from companion.geometry.earth import GeoPoint
from companion.guidance.geofence import fence_in_ned, legs_problem
from companion.guidance.path import PathGeometryError
from companion.telemetry.auth import CommandRefused, CommandSettings, RefusalKind, RefusalLog
from companion.telemetry.orders import DeliveryOrder, OrderPad, OrderRefused, OrderVerifier, order_reply
from companion.telemetry.schema import order_key

log = logging.getLogger(__name__)

DECIDE_TIMEOUT_S = 3.0  # a Zenoh query waits this long for the loop's decision
MAX_PENDING = 4  # signed orders waiting for the loop's decision at once; more are refused
MAX_EVENTS = 1000  # the desk's recent order events kept in memory (all are in the log and orders.csv)
REFUSAL_SAMPLE_S = 1.0  # refusals before the decision: one event, log line and row per this

ORDERS_CSV_COLUMNS = (
    "time_s",
    "unix_s",
    "order_id",
    "sender",
    "pad_lat_deg",
    "pad_lon_deg",
    "pad_alt_amsl_m",
    "alternate_lat_deg",
    "alternate_lon_deg",
    "alternate_alt_amsl_m",
    "accepted",
    "reason",
    "nonce",
)


@dataclass(frozen=True, slots=True)
class VehicleSnapshot:
    """What the autopilot last said, for the checks (``now_s`` on the telemetry's clock)."""

    now_s: float
    status: VehicleStatus | None
    home: HomePosition | None
    position_ned: PositionNed | None
    wind: Wind | None

    @classmethod
    def of(cls, telemetry: TelemetryCache, now_s: float) -> VehicleSnapshot:
        return cls(now_s, telemetry.status, telemetry.home, telemetry.position_ned, telemetry.wind)


@dataclass(frozen=True, slots=True)
class AcceptedOrder:
    """An order that passed every check, and the configuration it is flown with."""

    order: DeliveryOrder
    config: CompanionConfig


def destination_of(order: DeliveryOrder) -> Destination:
    def pad(p: OrderPad) -> GeoPad:
        return GeoPad(p.lat_deg, p.lon_deg, p.alt_amsl_m)

    return Destination(
        pad=pad(order.pad),
        source=f"order {order.order_id} from {order.sender}",
        alternate=pad(order.alternate) if order.alternate is not None else None,
    )


def check_order(
    config: CompanionConfig, order: DeliveryOrder, snap: VehicleSnapshot, busy_with: str | None
) -> CompanionConfig:
    """The configuration ``order`` is flown with, or :class:`OrderRefused` with the reason
    (checks 2-6 of the module docstring; ``busy_with``: the order being flown, if any)."""
    if busy_with is not None:
        raise OrderRefused(f"busy: flying order {busy_with}")
    st = snap.status
    if st is not None and st.armed:
        raise OrderRefused("busy: the vehicle is armed (a flight is under way)")
    try:
        cfg = config_for_destination(config, destination_of(order))
    except DestinationError as err:
        raise OrderRefused(f"destination: {err.reason}") from None
    if st is None or snap.home is None or snap.position_ned is None:
        have = (("status", st), ("home", snap.home), ("local position", snap.position_ned))
        missing = [n for n, v in have if v is None]
        raise OrderRefused(f"vehicle not ready: no {', '.join(missing)} from the autopilot yet")
    h = snap.home
    home_geo = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    home_ned = (h.north_m, h.east_m, h.down_m)
    p = snap.position_ned
    start = np.array([p.north_m, p.east_m, p.down_m])
    try:
        _, path, _ = plan_delivery(cfg.mission, home_geo, start, home_ned)
    except (PathGeometryError, ValueError) as err:
        raise OrderRefused(f"path: {err}") from None
    pad_ned = np.asarray(home_ned) + pad_position_ned(cfg.mission, home_geo)
    radius = cfg.limits.geofence_radius_m
    pads = [("the pad", pad_ned)]
    if cfg.mission.alternate_pad is not None:
        alt_cfg = cfg.mission.model_copy(update={"pad": cfg.mission.alternate_pad})
        pads.append(("the alternate pad", np.asarray(home_ned) + pad_position_ned(alt_cfg, home_geo)))
    for what, ned in pads:
        r = math.hypot(ned[0] - home_ned[0], ned[1] - home_ned[1])
        if r > radius:
            raise OrderRefused(
                f"out of range: {what} is {r:.1f} m from home, beyond limits.geofence_radius_m = {radius:g} m"
            )
    fence = fence_in_ned(cfg.fence, home_geo, home_ned) if cfg.fence.enabled else None
    why = legs_problem(fence, cfg.limits, home_geo, home_ned, start, pad_ned, cfg.mission)
    if why:
        raise OrderRefused(f"outside the flyable area: {why}")
    g = cfg.go_no_go
    if g.wind_limit_m_s > 0:
        wind = WindMonitor(g.wind_limit_m_s, g.wind_exceed_s, g.wind_max_age_s)
        wind_why = wind.take_off_problem(snap.now_s, snap.wind)
        if wind_why:
            raise OrderRefused(f"no-go: {wind_why}")
    if g.battery_check:
        battery = BatteryMonitor(g.battery_reserve_pct, g.battery_use_pct_per_s, g.battery_measure_s)
        why = round_trip_problem(battery, way_home(cfg.mission), path.d, st.battery_pct)
        if why:
            raise OrderRefused(f"no-go: {why}")
    return cfg


class OrderDesk:
    """Answers orders on ``companion/<vehicle_id>/order`` (a Zenoh queryable on ``session``).
    The decision is taken on the asyncio loop (the Zenoh thread waits for it), so the checks see
    one consistent state; an accepted order waits in :meth:`next_order` and keeps the desk busy
    until :meth:`finished`."""

    def __init__(
        self,
        config: CompanionConfig,
        telemetry: TelemetryCache,
        settings: CommandSettings,
        *,
        csv_path: Path | None = None,
        on_event: Callable[[MissionEvent], None] | None = None,
        wall_clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ):
        self.config = config
        self.telemetry = telemetry
        self.vehicle_id = config.vehicle_id
        self.verifier = OrderVerifier(config.vehicle_id, settings, clock=wall_clock, monotonic=monotonic)
        self.on_event = on_event
        self.events: deque[MissionEvent] = deque(maxlen=MAX_EVENTS)
        self.busy_with: str | None = None
        self.phase = Phase.PREFLIGHT  # the flying mission's phase, for the events
        self.accepted = 0
        self.refused_by_vehicle = 0  # checks 2-6
        self.refusals = RefusalLog("order", REFUSAL_SAMPLE_S, monotonic)  # check 1, and overload
        self._pending = threading.BoundedSemaphore(MAX_PENDING)
        self._csv_lock = threading.Lock()
        self._wall = wall_clock
        self._queue: asyncio.Queue[AcceptedOrder] = asyncio.Queue()
        self._loop: asyncio.AbstractEventLoop | None = None
        self._queryable: Any = None
        self._csv_file: IO[str] | None = None
        self._csv: Any = None
        if csv_path is not None:
            csv_path.parent.mkdir(parents=True, exist_ok=True)
            self._csv_file = csv_path.open("w", newline="", encoding="utf-8")
            self._csv = csv.writer(self._csv_file)
            self._csv.writerow(ORDERS_CSV_COLUMNS)
            self._csv_file.flush()

    # ---- lifecycle ---------------------------------------------------------------------------

    def start(self, session: Any) -> OrderDesk:
        """Declare the queryable (call on the loop that runs the flights)."""
        self._loop = asyncio.get_running_loop()
        self._queryable = session.declare_queryable(order_key(self.vehicle_id), self._on_query)
        log.info("taking delivery orders on %s", order_key(self.vehicle_id))
        return self

    def stop(self) -> None:
        if self._queryable is not None:
            try:
                self._queryable.undeclare()
            except Exception:  # the session is gone already
                log.debug("undeclare failed", exc_info=True)
            self._queryable = None
        if self._csv_file is not None:
            self._csv_file.close()
            self._csv_file = None

    async def next_order(self) -> AcceptedOrder:
        return await self._queue.get()

    def finished(self, order_id: str, outcome: str) -> None:
        """The flight of ``order_id`` has ended (``outcome`` says how): the desk takes orders again."""
        self.busy_with = None
        self.phase = Phase.PREFLIGHT
        self._event(f"order {order_id} flown: {outcome}")

    @property
    def refused(self) -> int:
        """Orders refused, whichever check refused them."""
        return self.refused_by_vehicle + self.refusals.total

    # ---- deciding ------------------------------------------------------------------------------

    def decide(self, payload: bytes | None) -> tuple[bool, str | None, str]:
        """Check one order payload: (accepted, order id if readable, reason). On the loop thread
        (the queryable runs check 1 on its own thread and hands the loop :meth:`decide_order`)."""
        try:
            order = self.verifier.verify(payload)
        except CommandRefused as err:
            self._refused_early(err, on_loop=True)
            return False, None, err.reason
        return self.decide_order(order)

    def _refused_early(self, err: CommandRefused, on_loop: bool) -> None:
        """Count a refusal of check 1 (or an overload); the sampled one is recorded on the loop."""
        skipped = self.refusals.note(err.kind, err.reason)
        if skipped is None:
            return
        reason = err.reason + (f" (+{skipped} orders refused since the last row)" if skipped else "")
        loop = self._loop
        if on_loop or loop is None:
            self._record(None, False, reason)
        elif not loop.is_closed():
            loop.call_soon_threadsafe(self._record, None, False, reason)

    def decide_order(self, order: DeliveryOrder) -> tuple[bool, str | None, str]:
        """Checks 2-6 on a verified order: (accepted, order id, reason). On the loop thread."""
        try:
            snap = VehicleSnapshot.of(self.telemetry, asyncio.get_running_loop().time())
            cfg = check_order(self.config, order, snap, self.busy_with)
        except CommandRefused as err:
            self.refused_by_vehicle += 1
            self._record(order, False, err.reason)
            return False, order.order_id, err.reason
        self.busy_with = order.order_id
        self.accepted += 1
        reason = "accepted: flying it now"
        self._record(order, True, reason)
        self._queue.put_nowait(AcceptedOrder(order, cfg))
        return True, order.order_id, reason

    def _record(self, order: DeliveryOrder | None, accepted: bool, reason: str) -> None:
        verdict = "ACCEPTED" if accepted else "REFUSED"
        who = f"order {order.order_id} from {order.sender}" if order is not None else "an unreadable order"
        self._event(f"{who}: {verdict}: {reason}")
        if self._csv is not None and self._csv_file is not None:
            pad, alt = (order.pad, order.alternate) if order is not None else (None, None)

            def cols(p: OrderPad | None) -> list[object]:
                if p is None:
                    return ["", "", ""]
                return [p.lat_deg, p.lon_deg, "" if p.alt_amsl_m is None else p.alt_amsl_m]

            now = self._loop.time() if self._loop is not None else math.nan
            with self._csv_lock:
                self._write_row(now, order, accepted, reason, cols(pad), cols(alt))

    def _write_row(
        self,
        now: float,
        order: DeliveryOrder | None,
        accepted: bool,
        reason: str,
        pad: list[object],
        alt: list[object],
    ) -> None:
        if self._csv is not None and self._csv_file is not None:
            self._csv.writerow(
                [
                    now,
                    self._wall(),
                    order.order_id if order is not None else "",
                    order.sender if order is not None else "",
                    *pad,
                    *alt,
                    int(accepted),
                    reason,
                    order.nonce if order is not None else "",
                ]
            )
            self._csv_file.flush()

    def _event(self, detail: str) -> None:
        now = self._loop.time() if self._loop is not None else 0.0
        ev = MissionEvent(now, EventKind.ORDER, self.phase, detail)
        self.events.append(ev)
        log.warning("%s", detail)
        if self.on_event is not None:
            try:
                self.on_event(ev)
            except Exception:  # a display or publisher problem must not lose the decision
                log.exception("order event listener failed")

    # ---- the queryable (a Zenoh thread) ------------------------------------------------------

    def _on_query(self, query: Any) -> None:
        """Check 1 here, on the Zenoh thread; a verified order waits for the loop's checks 2-6."""
        payload = query.payload
        raw = payload.to_bytes() if payload is not None else None  # bounded by the session's limit
        order_id: str | None = None
        try:
            order = self.verifier.verify(raw)
        except CommandRefused as err:
            self._refused_early(err, on_loop=False)
            self._reply(query, None, False, err.reason)
            return
        if not self._pending.acquire(blocking=False):
            reason = f"overloaded: {MAX_PENDING} orders already wait for a decision; try later"
            self._refused_early(CommandRefused(reason, RefusalKind.OVERLOAD), on_loop=False)
            self._reply(query, order.order_id, False, reason)
            return
        try:
            accepted, order_id, reason = self._decide_on_loop(order)
        finally:
            self._pending.release()
        self._reply(query, order_id, accepted, reason)

    def _decide_on_loop(self, order: DeliveryOrder) -> tuple[bool, str | None, str]:
        loop = self._loop
        fut: concurrent.futures.Future[tuple[bool, str | None, str]] = concurrent.futures.Future()

        def run() -> None:
            if not fut.set_running_or_notify_cancel():
                return  # the ground has been told "no decision": the order is not taken
            try:
                fut.set_result(self.decide_order(order))
            except BaseException as err:  # reported to the ground below
                fut.set_exception(err)

        try:
            if loop is None or loop.is_closed():
                raise RuntimeError("the vehicle is shutting down")
            loop.call_soon_threadsafe(run)
            return fut.result(timeout=DECIDE_TIMEOUT_S)
        except concurrent.futures.TimeoutError:
            fut.cancel()
            reason = f"no decision within {DECIDE_TIMEOUT_S:g} s (the vehicle is overloaded)"
            self.refusals.note(RefusalKind.OVERLOAD, reason)
            return False, order.order_id, reason
        except Exception as err:
            log.exception("order decision failed")
            return False, order.order_id, f"order not handled: {type(err).__name__}: {err}"

    def _reply(self, query: Any, order_id: str | None, accepted: bool, reason: str) -> None:
        body = order_reply(self.vehicle_id, order_id, accepted, reason)
        try:
            if accepted:
                query.reply(query.key_expr, body, encoding=zenoh.Encoding.APPLICATION_JSON)
            else:
                query.reply_err(body, encoding=zenoh.Encoding.APPLICATION_JSON)
        except Exception:
            log.exception("order reply failed")
