"""CLI of the delivery on a vehicle: ``fly`` (a delivery on the configured real autopilot).
:func:`make_autopilot` is where the backend named in the parameters is built, the embedded
simulator for ``autopilot = "sim"`` included."""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
from collections.abc import Awaitable, Callable
from pathlib import Path
from typing import Any

from companion.autopilot import factory
from companion.autopilot.interface import Autopilot, ConnectionUrlError, LinkDeviceMissing
from companion.cli import exits
from companion.cli.args import FLIGHT_LOGS_MIN_BYTES, Once, made_run_folder
from companion.cli.exits import StartupError
from companion.config import CompanionConfig, load_config
from companion.delivery.mission import FailureKind, MissionSummary
from companion.delivery.shell import DeliveryShell
from companion.delivery.signals import OPERATOR_ABORT, abort_on_signals
from companion.flightlog.recorder import FlightRecorder
from companion.secret_files import configured_secret_files, exposed_secret

log = logging.getLogger(__name__)


def make_autopilot(config: CompanionConfig, tlog_path: Path | None = None, **kwargs: Any) -> Autopilot:
    """The backend ``config.autopilot`` names: the embedded simulator for "sim", else the PX4 or
    ArduPilot backend (:func:`companion.autopilot.factory.make_autopilot`); ``tlog_path``: the
    MAVLink log of the link."""
    if config.autopilot == "sim":
        log.info("autopilot backend sim on embedded simulator")
        from companion_sitl.autopilot import SimAutopilot
        from companion_sitl.params import SimulatedConfig, simulated_config_from_dict

        if not isinstance(config, SimulatedConfig):  # the application's config: [sim] not validated yet
            config = simulated_config_from_dict(config.model_dump(), "the parameters' [sim]")
        return SimAutopilot(config.sim, tlog_path=tlog_path, **kwargs)
    if tlog_path is not None:
        from companion.flightlog.tlog_writer import open_tlog

        kwargs["tlog"] = open_tlog(tlog_path)
    return factory.make_autopilot(config, **kwargs)


def register(subparsers: Any) -> None:
    """Add ``fly`` to the CLI's subparsers."""
    p = subparsers.add_parser("fly", help="fly the delivery mission on the configured real autopilot")
    p.add_argument(
        "--params", action=Once, required=True, help="parameter file (TOML); autopilot/connection select the vehicle"
    )
    p.add_argument("--connection", help="MAVLink connection URL (default: connection in the parameters)")
    p.add_argument("--timeout", type=float, default=1800.0, help="give up after this many seconds")
    p.add_argument("--out", help="run folder for flight.tlog and the per-stream CSV logs (default runs/fly-<time>)")
    p.add_argument(
        "--record-camera",
        metavar="VIDEO",
        help="record the landing camera's frames as the flight reads them to VIDEO (.avi MJPG, .mkv lossless, .mp4) "
        "and their exposure times to VIDEO.csv, for `companion demo --camera-file` (default: not recorded)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help="print only one JSON line at the end (delivered, returned, failure, run_dir), for scripts "
        "(default: the phase, distance to go and progress while flying, then the summary table)",
    )
    p.add_argument(
        "--no-preflight",
        action="store_true",
        help="skip the pre-flight check of the autopilot's parameters, sensors and clock (default: checked "
        "after connecting, before arming; see `companion preflight`)",
    )
    p.add_argument(
        "--plan",
        metavar="FILE.plan",
        help="a QGroundControl plan file: its delivery item is the pad (NAV_PAYLOAD_PLACE, or a waypoint or landing "
        "followed by a gripper release), a second one or a rally point the alternate pad, its geofence the fence "
        "(docs/gcs.md; default: the pad in the parameters)",
    )
    p.add_argument(
        "--orders",
        action="store_true",
        help="take delivery orders from the ground over Zenoh, one after another, until Ctrl-C: each accepted "
        "order is flown to its pad in a run folder of its own under --out (docs/orders.md; default: one delivery "
        "to the pad in the parameters)",
    )
    p.set_defaults(func=cmd_fly)


async def run_delivery(
    config: CompanionConfig,
    autopilot: Autopilot,
    timeout_s: float = 1800.0,
    run_dir: Path | None = None,
    landing: Any = None,
    before_flight: Callable[[], Awaitable[None]] | None = None,
    on_tick: Callable[[DeliveryShell, Any], None] | None = None,
) -> MissionSummary:
    """Run :class:`DeliveryShell` on ``autopilot``; SIGINT/SIGTERM abort (hold, then land).
    With ``run_dir`` the per-stream CSV logs go there (closed on landing, abort or crash);
    ``before_flight`` is awaited once connected, before the mission starts (the pre-flight check)."""
    recorder = FlightRecorder(run_dir, config) if run_dir is not None else None
    # the ground link publishes by default (docs/architecture.md); [telemetry] enabled = false turns it off
    shell = DeliveryShell(
        config,
        autopilot,
        telemetry=config.telemetry.enabled,
        recorder=recorder,
        landing=landing,
        before_flight=before_flight,
        on_tick=on_tick,
    )
    try:
        with abort_on_signals(shell):
            return await shell.run(timeout_s=timeout_s)
    finally:
        try:
            await autopilot.close()
        finally:
            if recorder is not None:
                recorder.close()


def preflight_hook(
    config: CompanionConfig, autopilot: Autopilot, kit: Any, params_file: str
) -> Callable[[], Awaitable[None]]:
    """The pre-flight check as the shell's ``before_flight``: run on the connected autopilot (and
    the started landing sensors) before anything is armed; a wrong check raises
    :class:`StartupError` (exit :data:`~companion.cli.exits.PREFLIGHT_FAILED`)."""

    async def check() -> None:
        from companion.autopilot.preflight.report import requirements_from_config
        from companion.autopilot.preflight.runner import preflight
        from companion.cli.preflight import probe_realtime, probe_sensors, report_line, sensor_requirements

        req = sensor_requirements(config, requirements_from_config(config), kit)
        cam, uwb = await asyncio.to_thread(probe_sensors, config, kit, True)  # the sensors run already
        report = await preflight(autopilot, req, camera=cam, uwb=uwb, realtime=probe_realtime(config))
        from companion.timebase import vehicle_clock

        vehicle_clock().judge(report.clock, report.clock_offset_s)  # decides on signed ground requests
        for c in report.checks:
            log.info("pre-flight %s: %s (%s) %s", c.name, c.status.value, c.value, c.detail)
        if not report.passed:
            raise StartupError(report_line(report, params_file), exits.PREFLIGHT_FAILED)

    return check


def _drop_unflown_run_folder(run_dir: Path) -> None:
    """A start that failed before any stream logged a row (no autopilot answering, a bad key, a busy
    telemetry port): the stream files hold only their header lines and say nothing, so they go (the
    CSVs and flight.mcap); what was tried stays: run.json and the link's traffic in flight.tlog, or
    nothing at all, folder included, when the link carried nothing. A stream that logged a row (a
    pre-flight check that failed after telemetry came) keeps the folder as it is."""
    csvs = list(run_dir.glob("*.csv"))
    try:
        if any(f.read_bytes().count(b"\n") > 1 for f in csvs):
            return
        for f in [*csvs, run_dir / "flight.mcap"]:
            f.unlink(missing_ok=True)
        tlog = run_dir / "flight.tlog"
        if not (tlog.exists() and tlog.stat().st_size > 0):
            for f in (tlog, run_dir / "run.json"):
                f.unlink(missing_ok=True)
            run_dir.rmdir()
    except OSError as err:  # a folder someone else writes into: leave the rest
        log.debug("keeping %s: %s", run_dir, err)


def _stop_sensors(kit: Any) -> None:
    """Stop the landing sensors (idempotent: the shell stops them too when it ran)."""
    if kit is None:
        return
    for dev in (kit.camera, kit.uwb):
        if dev is not None:
            try:
                dev.stop()
            except Exception as err:  # keep closing the rest
                log.error("stopping %s failed: %s", type(dev).__name__, err)


def _checked_config(args: argparse.Namespace) -> tuple[CompanionConfig, str]:
    """The parameters, refused before anything is started: the embedded simulator, a wrong
    connection, a missing device, a secret file others can read. Also where the connection came from."""
    overrides = {"connection": args.connection} if args.connection else None
    config = load_config(args.params, overrides=overrides)
    where = f"in {args.params}" + (" (--connection)" if args.connection else " (or --connection)")
    if config.autopilot == "sim":
        raise StartupError(
            f"autopilot = 'sim' in {args.params}: use `companion demo` for the embedded simulator, "
            "or set autopilot = 'px4' or 'ardupilot'",
            exits.BAD_INPUT,
        )
    try:
        factory.check_connection(config)  # before anything is started
    except ConnectionUrlError as err:
        raise StartupError(f"{err}; change connection {where}", exits.BAD_INPUT) from None
    except LinkDeviceMissing as err:
        raise StartupError(f"{err}; plug the autopilot in or change connection {where}", exits.DEVICE_MISSING) from None
    for key, what, path in configured_secret_files(config):  # before any device or link is opened
        exposed = exposed_secret(path, what)
        if exposed is not None:
            raise StartupError(f"{exposed} ({key} in {args.params})", exits.BAD_INPUT)
    plan = getattr(args, "plan", None)
    if plan:
        config = config_with_plan(config, plan, args.params, orders=getattr(args, "orders", False))
    return config, where


def config_with_plan(config: CompanionConfig, plan: str, params: str, orders: bool = False) -> CompanionConfig:
    """``config`` with the pad, alternate and fence of a QGroundControl plan file (--plan)."""
    from companion.delivery.qgc_plan import PlanFileError, config_from_plan, read_plan

    if orders:
        raise StartupError("--plan with --orders: each order names its own pad; drop one of them", exits.BAD_INPUT)
    if config.mission.destination != "params":
        raise StartupError(
            f"--plan with mission.destination = {config.mission.destination!r} in {params}: two sources of the "
            "pad; set destination = 'params' or drop --plan",
            exits.BAD_INPUT,
        )
    try:
        config, said = config_from_plan(config, read_plan(plan))
    except PlanFileError as err:
        raise StartupError(err.reason, exits.BAD_INPUT) from None
    log.info("%s", said)
    return config


def _started_landing_kit(args: argparse.Namespace, config: CompanionConfig) -> Any:
    """The landing sensors set up and started on the ground: a missing one stops us here."""
    from companion.delivery.landing_setup import LandingSetupError, build_landing_kit, record_camera, start_sensors

    kit = None
    try:
        kit = build_landing_kit(config)
        if kit is not None and getattr(args, "record_camera", None):
            kit = record_camera(kit, Path(args.record_camera), config.landing.camera_rate_hz)
        if kit is not None:
            start_sensors(kit)
    except LandingSetupError as err:
        _stop_sensors(kit)  # what was built or started before the one that failed
        code = exits.DEVICE_MISSING if err.device_missing else exits.BAD_INPUT
        raise StartupError(f"{args.params}: {err}", code) from None
    except BaseException:
        _stop_sensors(kit)
        raise
    return kit


def _fly_exit(args: argparse.Namespace, summary: MissionSummary, run_dir: Path, display: _FlyDisplay) -> int:
    """The flight's result printed (JSON or the table) and its exit code."""
    if getattr(args, "json", False):
        print(
            json.dumps(
                {
                    "delivered": summary.delivered,
                    "returned": summary.returned,
                    "failure": summary.failure,
                    "run_dir": str(run_dir),
                }
            )
        )
    else:
        display.print_summary(summary, run_dir)
    lost = exits.say_logs_incomplete("fly", run_dir)  # a full disk: the flight went on, its logs stopped
    if summary.failure_kind is FailureKind.OPERATOR_ABORT:  # Ctrl-C / SIGTERM in flight: held, landed, ended
        return exits.INTERRUPTED
    if lost and summary.delivered and not summary.failure:  # delivered, but the logs were cut
        return exits.LOGS_INCOMPLETE
    return exits.OK if summary.delivered and not summary.failure else exits.FAILED


def cmd_fly(args: argparse.Namespace) -> int:
    """Fly the delivery. A start-up failure raises :class:`StartupError` (one line, an exit code of
    :mod:`companion.cli.exits`); whatever was started is closed first."""
    config, where = _checked_config(args)
    if getattr(args, "orders", False):
        from companion.cli.orders import cmd_fly_orders

        return cmd_fly_orders(args, config, make_autopilot, preflight_hook, OPERATOR_ABORT)
    kit = None
    try:
        kit = _started_landing_kit(args, config)
        run_dir = made_run_folder(args.out, "fly", FLIGHT_LOGS_MIN_BYTES)
        new_folder = not any(run_dir.iterdir())
        try:
            with exits.flight_startup_errors(where, args.params, config):
                autopilot = make_autopilot(config, tlog_path=run_dir / "flight.tlog")  # the MAVLink link traffic
                skip = getattr(args, "no_preflight", False)
                check = None if skip else preflight_hook(config, autopilot, kit, args.params)
                with _FlyDisplay(quiet=getattr(args, "json", False)) as display:
                    summary = asyncio.run(
                        run_delivery(
                            config,
                            autopilot,
                            args.timeout,
                            run_dir,
                            landing=kit,
                            before_flight=check,
                            **display.run_kwargs(),
                        )
                    )
        except StartupError:
            if new_folder:  # nothing flew: the folder would only hold empty logs
                _drop_unflown_run_folder(run_dir)
            raise
    finally:
        _stop_sensors(kit)
    return _fly_exit(args, summary, run_dir, display)


class _FlyDisplay:
    """The operator's view of a flight (:mod:`companion.cli.fly_display`): a rich progress line
    while flying, the summary table after; nothing with ``quiet`` (``--json``)."""

    def __init__(self, quiet: bool) -> None:
        self.quiet = quiet
        self.shell: DeliveryShell | None = None
        self._progress: Any = None
        self._task: Any = None
        self.console: Any = None

    def __enter__(self) -> _FlyDisplay:
        if self.quiet:
            return self
        from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

        from companion.cli.console import make_console
        from companion.cli.fly_display import PHASES

        self.console = make_console()
        self._progress = Progress(
            TextColumn("{task.description:<16}"),
            BarColumn(),
            TextColumn("{task.fields[where]}"),
            TimeElapsedColumn(),
            console=self.console,
        )
        self._progress.__enter__()
        self._task = self._progress.add_task("connecting", total=len(PHASES) - 1, where="")
        return self

    def __exit__(self, *exc: object) -> None:
        if self._progress is not None:
            self._progress.__exit__(None, None, None)

    def run_kwargs(self) -> dict[str, Any]:
        return {"on_tick": self.on_tick}

    def on_tick(self, shell: DeliveryShell, out: Any) -> None:
        self.shell = shell
        if self._progress is None:
            return
        from companion.cli.fly_display import progress_fields

        f = progress_fields(shell, out)
        if f["completed"] is None:
            del f["completed"]
        self._progress.update(self._task, **f)

    def print_summary(self, summary: MissionSummary, run_dir: Path) -> None:
        from companion.cli.fly_display import headline, summary_rows

        if self.console is None:
            return
        self.console.print()
        self.console.print(headline(summary))
        for k, v in summary_rows(summary, self.shell, run_dir):
            self.console.print(f"  {k:<46} {v}")
