"""Delivery orders on the command line (docs/orders.md).

- ``companion order``: the ground side; signs one order, sends it to a vehicle over Zenoh and
  prints the vehicle's answer (exit 0 accepted, 1 refused, 5 no answer).
- ``companion fly --params F --orders``: the vehicle side (:func:`serve_orders`); connects to the
  autopilot once, takes order after order (:class:`~companion.delivery.orders.OrderDesk`), flies
  each accepted one as a normal delivery in a run folder of its own, leaves the autopilot ready for
  the next, and ends on Ctrl-C (in flight: the mission's abort first, hold then land).
"""

from __future__ import annotations

import argparse
import asyncio
import contextlib
import functools
import logging
import math
import signal
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.cli.args import FLIGHT_LOGS_MIN_BYTES, made_run_folder
from companion.config import CompanionConfig
from companion.delivery.mission import FailureKind
from companion.delivery.observers import TickCallback
from companion.delivery.order_session import FlownOrder, OrderSession
from companion.events import MissionEvent
from companion.telemetry.session import SettingsError, ZenohSettings

log = logging.getLogger(__name__)

NO_ANSWER = exits.TELEMETRY_UNAVAILABLE  # no vehicle answered on Zenoh


def register(subparsers: Any) -> None:
    """Add the ``order`` subcommand (the ground side)."""
    p = subparsers.add_parser(
        "order",
        help="send a delivery order to a vehicle over Zenoh and print its answer",
        description="Sign a delivery order with the shared secret of [telemetry.commands] and send it to "
        "companion/<vehicle>/order; the vehicle (`companion fly --orders`) answers accepted or refused with "
        "the reason. Exit 0 accepted, 1 refused, 5 no answer.",
    )
    p.add_argument("--vehicle", required=True, help="vehicle id (its parameter file's vehicle_id)")
    p.add_argument("--lat", type=float, required=True, help="pad latitude, degrees (WGS-84)")
    p.add_argument("--lon", type=float, required=True, help="pad longitude, degrees (WGS-84)")
    p.add_argument("--alt", type=float, help="pad ground altitude AMSL, metres (default: the home's ground altitude)")
    p.add_argument(
        "--alternate-lat", type=float, help="alternate pad latitude, with --alternate-lon (default: no alternate)"
    )
    p.add_argument(
        "--alternate-lon", type=float, help="alternate pad longitude, with --alternate-lat (default: no alternate)"
    )
    p.add_argument(
        "--alternate-alt", type=float, help="alternate pad altitude AMSL, metres (default: the home's ground altitude)"
    )
    p.add_argument("--secret-file", required=True, help="file holding the shared secret (the vehicle's secret_file)")
    p.add_argument("--order-id", help="the order's id (default: the UTC time and 4 random hex digits)")
    p.add_argument("--sender", default="ground", help="who sends it, for the vehicle's logs (default: ground)")
    p.add_argument("--note", default="", help="free text carried with the order, signed (default: none)")
    p.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="TOML file with a [zenoh] table (params/zenoh_*.toml); flags override it (default: Zenoh's defaults)",
    )
    p.add_argument(
        "--connect",
        action="append",
        metavar="EP",
        help="connect endpoint, e.g. tcp/10.0.0.2:7447, repeatable (default: none, or the session file's)",
    )
    p.add_argument(
        "--listen",
        action="append",
        metavar="EP",
        help="listen endpoint, repeatable (default: none, or the session file's)",
    )
    p.add_argument(
        "--no-multicast", action="store_true", help="disable multicast scouting (default: the session file's, else on)"
    )
    p.add_argument("--timeout", type=float, default=5.0, help="seconds to wait for the answer (default: %(default)s)")
    p.set_defaults(func=cmd_order)


def _pad_problem(args: argparse.Namespace, prefix: str) -> str:
    """Why the pad of --{prefix}lat/lon/alt cannot be a pad ("" if it can): the vehicle's own pad
    schema ([mission.pad]), so the ground refuses what the vehicle would, in the same words."""
    from pydantic import ValidationError

    from companion.config import PadConfig

    lat, lon, alt = (getattr(args, f"{prefix}{k}") for k in ("lat", "lon", "alt"))
    if lat is None:
        return ""
    try:
        PadConfig(lat_deg=lat, lon_deg=lon, alt_amsl_m=alt)
    except ValidationError as e:
        err = e.errors()[0]
        field = {"lat_deg": "lat", "lon_deg": "lon", "alt_amsl_m": "alt"}.get(str(err["loc"][0]), str(err["loc"][0]))
        opt = f"--{prefix.replace('_', '-')}{field}"
        return f"{opt} {getattr(args, prefix + field)}: {err['msg'].lower()}"
    return ""


def cmd_order(args: argparse.Namespace) -> int:
    from companion.telemetry.auth import MAX_NOTE_CHARS, CommandSettings, sender_ok
    from companion.telemetry.ground import GroundStation
    from companion.telemetry.orders import ORDER_ID_RULE, OrderPad, order_id_ok
    from companion.telemetry.schema import SchemaError, check_vehicle_id

    def bad(msg: str) -> int:
        print(f"companion order: {msg}", file=sys.stderr)
        return exits.BAD_INPUT

    try:
        check_vehicle_id(args.vehicle)
    except SchemaError as e:
        return bad(f"--vehicle {args.vehicle!r}: {e}")
    for name in ("lat", "lon", "alt", "alternate_lat", "alternate_lon", "alternate_alt"):
        v = getattr(args, name)
        if v is not None and not math.isfinite(v):
            return bad(f"--{name.replace('_', '-')} {v}: expected a finite number")
    if (args.alternate_lat is None) != (args.alternate_lon is None):
        return bad("--alternate-lat and --alternate-lon go together")
    for prefix in ("", "alternate_"):
        problem = _pad_problem(args, prefix)
        if problem:
            return bad(problem)
    if args.alternate_alt is not None and args.alternate_lat is None:
        return bad("--alternate-alt needs --alternate-lat and --alternate-lon")
    if args.order_id is not None and not order_id_ok(args.order_id):
        return bad(f"--order-id {args.order_id!r}: expected {ORDER_ID_RULE}")
    if not sender_ok(args.sender):
        return bad(f"--sender {args.sender!r}: expected 1-64 letters, digits, '_', '.', '@' or '-'")
    if len(args.note) > MAX_NOTE_CHARS:
        return bad(f"--note: {len(args.note)} characters, at most {MAX_NOTE_CHARS}")
    if not (args.timeout > 0 and math.isfinite(args.timeout)):
        return bad(f"--timeout {args.timeout}: expected > 0 s")
    try:
        secret = CommandSettings.read_secret(args.secret_file)
    except OSError as e:
        return bad(f"--secret-file {args.secret_file}: {e.strerror or e}")
    except ValueError as e:
        return bad(f"--secret-file: {e}")
    try:
        from companion.cli.telemetry import ground_settings

        settings = ground_settings(args)
    except SettingsError as e:
        return bad(str(e))
    pad = OrderPad(args.lat, args.lon, args.alt)
    alternate = (
        OrderPad(args.alternate_lat, args.alternate_lon, args.alternate_alt) if args.alternate_lat is not None else None
    )
    station = GroundStation(settings)
    try:
        station.start()
    except Exception as e:  # zenoh.ZError: bad endpoint, port in use
        print(f"companion order: cannot open the Zenoh session: {e}", file=sys.stderr)
        return exits.FAILED
    t0 = time.monotonic()
    try:
        reply = station.send_order(
            args.vehicle,
            pad,
            secret,
            order_id=args.order_id,
            alternate=alternate,
            sender=args.sender,
            note=args.note,
            timeout_s=args.timeout,
        )
    finally:
        station.stop()
    if not reply.replied:
        waited_s = time.monotonic() - t0
        if waited_s < 0.9 * args.timeout:  # Zenoh ends a query at once that no queryable matches
            why = f"nobody answers orders for {args.vehicle} on the Zenoh network (the query ended in {waited_s:.1f} s)"
        else:
            why = f"no answer within {args.timeout:g} s"
        print(f"order to {args.vehicle}: {why} (is `fly --orders` running there?)")
        return NO_ANSWER
    print(f"order to {args.vehicle}: {'ACCEPTED' if reply.accepted else 'REFUSED'}: {reply.reason}")
    return exits.OK if reply.accepted else exits.FAILED


# ---- the vehicle side --------------------------------------------------------------------------


def order_settings(config: CompanionConfig) -> Any:
    """The order desk's authentication: the shared secret and window of ``[telemetry.commands]``."""
    from companion.config import ConfigError
    from companion.telemetry.auth import CommandSettings

    c = config.telemetry.commands
    if not c.enabled or not c.secret_file:
        raise ConfigError(
            "telemetry.commands",
            ["fly --orders needs enabled = true and secret_file (orders are signed with the commands' shared secret)"],
        )
    try:
        secret = CommandSettings.read_secret(c.secret_file)
        return CommandSettings(
            enabled=True,
            secret=secret,
            window_s=c.window_s,
            max_nonces=c.max_nonces,
            rate_per_s=c.rate_per_s,
            burst=c.burst,
            max_requests_per_s=c.max_requests_per_s,
        )
    except (OSError, ValueError) as err:
        raise ConfigError("telemetry.commands.secret_file", [str(err)]) from None


@dataclass
class _Live:
    """What the session's signal handler and event sink reach while it runs: the flight's shell and
    the connection being waited for."""

    shell: Any = None
    connecting: asyncio.Task[None] | None = None


@contextlib.contextmanager
def _signals(loop: asyncio.AbstractEventLoop, handler: Callable[[str], None]) -> Iterator[None]:
    """SIGINT and SIGTERM call ``handler(name)`` while in the block."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        with contextlib.suppress(NotImplementedError, RuntimeError):
            loop.add_signal_handler(sig, handler, signal.Signals(sig).name)
    try:
        yield
    finally:
        for sig in (signal.SIGINT, signal.SIGTERM):
            with contextlib.suppress(NotImplementedError, RuntimeError):
                loop.remove_signal_handler(sig)


async def _next_order(desk: Any, stop: asyncio.Event) -> Any:
    """The next accepted order, or None when ``stop`` came first."""
    getter = asyncio.ensure_future(desk.next_order())
    stopper = asyncio.ensure_future(stop.wait())
    done, _ = await asyncio.wait({getter, stopper}, return_when=asyncio.FIRST_COMPLETED)
    if getter not in done:
        getter.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await getter
        return None
    stopper.cancel()
    return getter.result()


async def _fly_order(
    live: _Live,
    cfg: CompanionConfig,
    flight_dir: Path,
    *,
    config: CompanionConfig,
    autopilot: Any,
    desk: Any,
    session: Any,
    flight_timeout_s: float,
    on_tick: Callable[[Any, Any], None] | None,
    landing_for: Callable[[CompanionConfig], Any] | None,
    before_flight_for: Callable[[CompanionConfig, Any], Any] | None,
) -> Any:
    """One accepted order's delivery: its summary, or why it could not start."""
    from companion.cli.exits import StartupError
    from companion.delivery.shell import DeliveryShell
    from companion.flightlog.recorder import FlightRecorder

    try:
        kit = landing_for(cfg) if landing_for is not None else None
    except Exception as err:  # a sensor that cannot start: this order is not flown
        log.error("order flight: landing sensors: %s", err)
        return f"landing sensors: {err}"
    recorder = FlightRecorder(flight_dir, cfg)
    shell = live.shell = DeliveryShell(
        cfg,
        autopilot,
        telemetry=config.telemetry.enabled,
        recorder=recorder,
        landing=kit,
        before_flight=before_flight_for(cfg, kit) if before_flight_for is not None else None,
        zenoh_session=session,
    )
    desk.phase = shell.mission.phase

    def follow(sh: Any, o: Any) -> None:
        desk.phase = sh.mission.phase
        if sh.telemetry is not None:  # the health topic counts refused orders too
            sh.telemetry.publisher.count_refusals("orders", lambda: desk.refused)
        if on_tick is not None:
            on_tick(sh, o)

    shell.add_observer(TickCallback(follow))
    try:
        return await shell.run(timeout_s=flight_timeout_s)
    except StartupError as err:  # the pre-flight check refused: nothing was armed
        return str(err)
    finally:
        recorder.close()


def _flown(out: OrderSession, desk: Any, order_id: str, flight_dir: Path, summary_or_why: Any, stopped: bool) -> None:
    """The order's flight in the session and its outcome told to the desk."""
    if isinstance(summary_or_why, str):
        # not started: interrupted when the operator's signal came meanwhile
        kind = FailureKind.OPERATOR_ABORT if stopped else FailureKind.NONE
        out.flights.append(FlownOrder(order_id, flight_dir, False, False, summary_or_why, kind))
        desk.finished(order_id, f"not flown: {summary_or_why}")
        return
    s = summary_or_why
    outcome = (
        ("delivered" if s.delivered else "not delivered")
        + (", returned home" if s.returned else "")
        + (f" ({s.failure})" if s.failure else "")
    )
    out.flights.append(FlownOrder(order_id, flight_dir, s.delivered, s.returned, s.failure, s.failure_kind))
    desk.finished(order_id, outcome)


async def _connect(
    live: _Live, autopilot: Any, config: CompanionConfig, stop: asyncio.Event, abort_reason: str
) -> None:
    """Connect to the autopilot; a signal while waiting ends the session before any flight."""
    from companion.delivery.shell import AbortedBeforeFlight

    live.connecting = asyncio.get_running_loop().create_task(
        autopilot.connect(timeout_s=config.runtime.connect_timeout_s)
    )
    try:
        await live.connecting
    except asyncio.CancelledError:
        if not stop.is_set():
            raise
        raise AbortedBeforeFlight(f"{abort_reason} while waiting for the autopilot") from None


async def _take_orders(
    live: _Live, desk: Any, stop: asyncio.Event, run_dir: Path, out: OrderSession, fly: Callable[..., Any]
) -> None:
    """Order after order until ``stop``: each accepted one flown by ``fly(config, flight_dir)``."""
    n = 0
    while not stop.is_set():
        accepted = await _next_order(desk, stop)
        if accepted is None:
            break
        order_id = accepted.order.order_id
        if stop.is_set():  # accepted as Ctrl-C came: the operator ended the session first
            desk.finished(order_id, "not flown: the session was ended (Ctrl-C)")
            break
        n += 1
        flight_dir = run_dir / f"{n:02d}-{order_id}"
        try:
            summary_or_why = await fly(accepted.config, flight_dir)
        finally:
            live.shell = None
        _flown(out, desk, order_id, flight_dir, summary_or_why, stop.is_set())


async def serve_orders(
    config: CompanionConfig,
    autopilot: Any,
    run_dir: Path,
    *,
    zenoh_settings: ZenohSettings | None = None,
    flight_timeout_s: float = 1800.0,
    stop: asyncio.Event | None = None,
    on_event: Callable[[MissionEvent], None] | None = None,
    on_tick: Callable[[Any, Any], None] | None = None,
    landing_for: Callable[[CompanionConfig], Any] | None = None,
    before_flight_for: Callable[[CompanionConfig, Any], Any] | None = None,
    abort_reason: str = "operator abort",
    record: OrderSession | None = None,
) -> OrderSession:
    """Take order after order until ``stop`` is set (SIGINT/SIGTERM set it): each accepted order
    is flown by a :class:`DeliveryShell` with its own configuration and its own run folder
    ``run_dir/<n>-<order id>``; the autopilot stays connected between flights (its ``.tlog``
    covers the session). ``zenoh_settings``: the vehicle's session (default: ``[telemetry]``).
    ``landing_for(config)``: the flight's landing sensors, started (a shell stops them when its flight
    ends); ``before_flight_for(config, kit)``: the flight's pre-flight check. Either raising ends
    that flight, not the session: it is reported as the order's failure. ``record``: the session
    to fill and return (a caller watching it as the orders are flown; default a new one); each
    flight is in its ``flights`` before the desk's "flown" event."""
    from companion.delivery.orders import OrderDesk
    from companion.delivery.telemetry import zenoh_settings_from_config
    from companion.telemetry.schema import MissionMessage

    auth = order_settings(config)
    zs = zenoh_settings or zenoh_settings_from_config(config)
    stop = stop or asyncio.Event()
    loop = asyncio.get_running_loop()
    out = record if record is not None else OrderSession()
    live = _Live()

    def event(ev: MissionEvent) -> None:
        out.events.append(ev)
        if live.shell is not None and live.shell.telemetry is not None:
            live.shell.telemetry.publisher.publish(MissionMessage.for_event(ev))
        if on_event is not None:
            on_event(ev)

    def on_signal(name: str) -> None:
        stop.set()
        if live.connecting is not None and not live.connecting.done():
            live.connecting.cancel()  # nothing commanded yet: stop waiting for the autopilot
        if live.shell is not None:
            live.shell.abort(f"{abort_reason} ({name})", FailureKind.OPERATOR_ABORT)

    session = await asyncio.to_thread(zs.open_or_explain)
    desk = OrderDesk(config, autopilot.telemetry, auth, csv_path=run_dir / "orders.csv", on_event=event)
    fly = functools.partial(
        _fly_order,
        live,
        config=config,
        autopilot=autopilot,
        desk=desk,
        session=session,
        flight_timeout_s=flight_timeout_s,
        on_tick=on_tick,
        landing_for=landing_for,
        before_flight_for=before_flight_for,
    )
    try:
        with _signals(loop, on_signal):
            await _connect(live, autopilot, config, stop, abort_reason)
            desk.start(session)
            await _take_orders(live, desk, stop, run_dir, out, fly)
    finally:
        out.accepted, out.refused = desk.accepted, desk.refused
        desk.stop()
        try:
            await autopilot.close()
        finally:
            await asyncio.to_thread(session.close)
    return out


def _check_orders_options(args: argparse.Namespace, config: CompanionConfig, where: str) -> None:
    """``--orders`` refused before anything is opened: with --record-camera, a mission whose pad is
    not the parameters' (each order names it), no order secret."""
    from companion.cli.exits import StartupError

    if getattr(args, "record_camera", None):
        raise StartupError("--record-camera is for one flight; leave it out with --orders", exits.BAD_INPUT)
    if config.mission.destination != "params":
        raise StartupError(
            f"mission.destination = {config.mission.destination!r} {where}: with --orders each order names the pad; "
            "set mission.destination = 'params' (the default) or fly without --orders",
            exits.BAD_INPUT,
        )
    order_settings(config)  # no secret: refused before anything is opened


def _print_session(session: OrderSession, run_dir: Path, quiet: bool) -> None:
    """The session's orders: one JSON line (``quiet``, ``--json``) or a line per flight."""
    import json

    flights = [
        {
            "order_id": f.order_id,
            "delivered": f.delivered,
            "returned": f.returned,
            "failure": f.failure,
            "run_dir": str(f.run_dir),
        }
        for f in session.flights
    ]
    if quiet:
        doc = {"accepted": session.accepted, "refused": session.refused, "flights": flights, "run_dir": str(run_dir)}
        print(json.dumps(doc))
    else:
        print(f"orders: {session.accepted} accepted, {session.refused} refused, {len(flights)} flown")
        for f in session.flights:
            what = ("DELIVERED" if f.delivered else "NOT DELIVERED") + (", returned home" if f.returned else "")
            print(f"  {f.order_id}: {what}{' - ' + f.failure if f.failure else ''} ({f.run_dir})")


def cmd_fly_orders(
    args: argparse.Namespace,
    config: CompanionConfig,
    make_autopilot: Callable[..., Any],
    preflight_hook: Callable[..., Any],
    abort_reason: str,
) -> int:
    """``fly --orders``: the session in ``--out`` (default runs/orders-<time>), one line per order
    event on the terminal (``--json``: one JSON line at the end). Start-up failures raise
    :class:`StartupError` as ``fly`` does; a flight's failure does not end the session. ``fly``
    hands over its autopilot factory, pre-flight hook and operator-abort reason."""
    from companion.cli.exits import StartupError
    from companion.delivery.landing_setup import LandingSetupError, build_landing_kit, start_sensors

    where = f"in {args.params}" + (" (--connection)" if args.connection else " (or --connection)")
    _check_orders_options(args, config, where)
    run_dir = made_run_folder(args.out, "orders", FLIGHT_LOGS_MIN_BYTES)
    quiet = getattr(args, "json", False)

    def say(ev: MissionEvent) -> None:
        if not quiet:
            print(f"[{time.strftime('%H:%M:%S')}] {ev.detail}", flush=True)

    def landing_for(cfg: CompanionConfig) -> Any:
        kit = build_landing_kit(cfg)
        if kit is not None:
            start_sensors(kit)
        return kit

    def before_flight_for(cfg: CompanionConfig, kit: Any) -> Any:
        return None if getattr(args, "no_preflight", False) else preflight_hook(cfg, autopilot, kit, args.params)

    try:  # a missing sensor is said now, not at the first order
        kit = landing_for(config)
    except LandingSetupError as err:
        code = exits.DEVICE_MISSING if err.device_missing else exits.BAD_INPUT
        raise StartupError(f"{args.params}: {err}", code) from None
    for dev in (kit.camera, kit.uwb) if kit is not None else ():
        if dev is not None:
            dev.stop()  # each flight starts its own (a flight's shell stops them when it ends)
    autopilot = make_autopilot(config, tlog_path=run_dir / "flight.tlog")
    if not quiet:
        print(f"taking delivery orders for {config.vehicle_id} (Ctrl-C ends); logs in {run_dir}", flush=True)
    with exits.flight_startup_errors(where, args.params, config, telemetry_optional=False):
        session = asyncio.run(
            serve_orders(
                config,
                autopilot,
                run_dir,
                flight_timeout_s=args.timeout,
                on_event=say,
                landing_for=landing_for,
                before_flight_for=before_flight_for,
                abort_reason=abort_reason,
            )
        )
    _print_session(session, run_dir, quiet)
    lost = exits.say_logs_incomplete("fly", run_dir)  # a full disk in a flight: its logs stopped, not it
    if any(f.failure_kind is FailureKind.OPERATOR_ABORT for f in session.flights):  # Ctrl-C in flight: ended
        return exits.INTERRUPTED
    if not all(f.delivered and not f.failure for f in session.flights):
        return exits.FAILED
    return exits.LOGS_INCOMPLETE if lost else exits.OK
