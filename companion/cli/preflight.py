"""CLI of the pre-flight check: ``companion preflight --params FILE`` reads the autopilot's
parameters (and probes the landing camera, the UWB tag and the clock) and prints one row per
check: ok, wrong (with what to set) or unknown (with why). ``companion fly`` runs the same check
after connecting, before it arms (:func:`companion.cli.fly.preflight_hook`)."""

from __future__ import annotations

import argparse
import asyncio
import dataclasses
import json
import logging
from typing import Any

from companion.autopilot import factory
from companion.autopilot.interface import Autopilot, AutopilotUnreachable, ConnectionUrlError, LinkDeviceMissing
from companion.autopilot.preflight.readers import probe_camera, probe_uwb
from companion.autopilot.preflight.report import (
    CameraProbe,
    PreflightReport,
    RealtimeProbe,
    Requirements,
    Status,
    UwbProbe,
    requirements_from_config,
)
from companion.autopilot.preflight.runner import preflight
from companion.cli import exits
from companion.cli.args import Once
from companion.cli.console import make_console
from companion.cli.exits import StartupError
from companion.config import CompanionConfig, load_config

log = logging.getLogger(__name__)

SENSOR_PROBE_S = 2.0


def register(subparsers: Any) -> None:
    p = subparsers.add_parser(
        "preflight",
        help="check the autopilot's parameters, the landing sensors and the clock against the configuration",
    )
    p.add_argument(
        "--params", action=Once, required=True, help="parameter file (TOML); autopilot/connection select the vehicle"
    )
    p.add_argument("--connection", help="MAVLink connection URL (default: connection in the parameters)")
    p.add_argument("--json", action="store_true", help="print the result as JSON instead of a table")
    p.add_argument(
        "--no-sensors", action="store_true", help="do not open the landing camera and UWB tag (default: probe them)"
    )
    p.set_defaults(func=cmd_preflight)


def sensor_requirements(config: CompanionConfig, req: Requirements, kit: Any) -> Requirements:
    """``req`` with the camera size and anchor ids of the landing kit's calibration and layout."""
    if kit is None:
        return req
    upd: dict[str, Any] = {}
    if kit.camera is not None and kit.detector is not None:
        cam = kit.detector.camera
        upd["camera_size_px"] = (int(cam.width_px), int(cam.height_px))
    if kit.uwb is not None and kit.multilaterator is not None:
        upd["uwb_anchor_ids"] = frozenset(kit.multilaterator.layout.anchor_ids)
    return dataclasses.replace(req, **upd)


def probe_sensors(config: CompanionConfig, kit: Any, started: bool) -> tuple[CameraProbe | None, UwbProbe | None]:
    """Read the landing kit's camera and UWB tag for :data:`SENSOR_PROBE_S` each (``started``: they
    run already, as in ``fly``; else each is started and stopped here)."""
    if kit is None:
        return None, None
    lc = config.landing
    cam = uwb = None
    if kit.camera is not None:
        what = f"landing.camera_source = {lc.camera_source!r}"
        cam = probe_camera(kit.camera, SENSOR_PROBE_S, started=started, what=what)
    if kit.uwb is not None:
        uwb = probe_uwb(kit.uwb, SENSOR_PROBE_S, started=started, what=f"landing.uwb_port = {lc.uwb_port!r}")
    return cam, uwb


def probe_realtime(config: CompanionConfig) -> RealtimeProbe | None:
    """Whether ``runtime.realtime_priority`` can be had here (None when it is 0)."""
    prio = config.runtime.realtime_priority
    if prio <= 0:
        return None
    from companion.scheduling import probe_realtime as probe

    return RealtimeProbe(prio, probe(prio) or "")


async def check_before_flight(
    config: CompanionConfig,
    autopilot: Autopilot,
    req: Requirements,
    camera: CameraProbe | None = None,
    uwb: UwbProbe | None = None,
) -> PreflightReport:
    """Connect ``autopilot`` (within ``runtime.connect_timeout_s``) and run the check on it; the
    link stays open for the flight."""
    await autopilot.connect(timeout_s=config.runtime.connect_timeout_s)
    return await preflight(autopilot, req, camera=camera, uwb=uwb, realtime=probe_realtime(config))


def report_line(report: PreflightReport, params_file: str) -> str:
    """The one start-up line of a failed check: every wrong row with what to set."""
    wrong = "; ".join(f"{c.name} = {c.value}: {c.detail}" for c in report.wrong)
    return (
        f"pre-flight check failed ({len(report.wrong)} wrong): {wrong}; "
        f"`companion preflight --params {params_file}` shows every check"
    )


def print_report(report: PreflightReport) -> None:
    from rich.markup import escape
    from rich.table import Table

    console = make_console()
    table = Table(title=f"pre-flight check ({report.autopilot})")
    for col in ("check", "status", "value", "detail"):
        table.add_column(col, overflow="fold")
    style = {Status.OK: "green", Status.WRONG: "bold red", Status.UNKNOWN: "yellow", Status.WARN: "magenta"}
    for c in report.checks:
        table.add_row(escape(c.name), f"[{style[c.status]}]{c.status.value}[/]", escape(c.value), escape(c.detail))
    console.print(table)
    n_unknown = sum(c.status is Status.UNKNOWN for c in report.checks)
    n_warn = sum(c.status is Status.WARN for c in report.checks)
    verdict = "PASSED" if report.passed else f"FAILED: {len(report.wrong)} wrong"
    warned = f", {n_warn} warn" if n_warn else ""
    console.print(f"{verdict}, {n_unknown} unknown, {len(report.checks)} checks{warned}")


def cmd_preflight(args: argparse.Namespace) -> int:
    overrides = {"connection": args.connection} if args.connection else None
    config = load_config(args.params, overrides=overrides)
    where = f"in {args.params}" + (" (--connection)" if args.connection else " (or --connection)")
    if config.autopilot not in ("px4", "ardupilot"):
        raise StartupError(
            f"autopilot = {config.autopilot!r} in {args.params}: the pre-flight check needs a vehicle, "
            "set autopilot = 'px4' or 'ardupilot'",
            exits.BAD_INPUT,
        )
    try:
        factory.check_connection(config)
    except ConnectionUrlError as err:
        raise StartupError(f"{err}; change connection {where}", exits.BAD_INPUT) from None
    except LinkDeviceMissing as err:
        raise StartupError(f"{err}; plug the autopilot in or change connection {where}", exits.DEVICE_MISSING) from None
    req = requirements_from_config(config)
    cam = uwb = None
    if not args.no_sensors:
        from companion.delivery.landing_setup import LandingSetupError, build_landing_kit

        try:
            kit = build_landing_kit(config)
        except LandingSetupError as err:  # a bad file or a plugin that is not there: the kit is not built
            code = exits.DEVICE_MISSING if err.device_missing else exits.BAD_INPUT
            raise StartupError(f"{args.params}: {err}", code) from None
        req = sensor_requirements(config, req, kit)
        cam, uwb = probe_sensors(config, kit, started=False)
    try:
        autopilot = factory.make_autopilot(config)
    except Exception as err:  # the backend refuses the configuration (e.g. release 'actuator' on ArduPilot)
        raise StartupError(f"{args.params}: {err}", exits.BAD_INPUT) from None

    async def run() -> PreflightReport:
        try:
            return await check_before_flight(config, autopilot, req, cam, uwb)
        finally:
            await autopilot.close()

    try:
        report = asyncio.run(run())
    except (AutopilotUnreachable, LinkDeviceMissing) as err:
        raise exits.link_startup_error(err, where, config.runtime.connect_timeout_s) from None
    if args.json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        print_report(report)
    return exits.OK if report.passed else exits.PREFLIGHT_FAILED
