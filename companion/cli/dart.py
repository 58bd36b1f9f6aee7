"""CLI subcommands of the Dart cyber-pilot.

``companion dart``: fly the Dart mission (dart sec. 5) on the asyncio shell (companion.dart.shell)
against a real autopilot (``--params FILE [--connection URL] [--autopilot ardupilot|px4]``, the
camera from the ``[runtime]`` camera plugin), or with ``--sim ardupilot`` against the MAVLink
stick vehicle on loopback UDP in real time (companion_sitl.dart_link), printing the true hover
precision (dart eq 22) and, with ``--pilot-test``, the time from the pilot's switch flip to the
overrides' release at the vehicle. :func:`register` adds it to the application's subparsers.

``companion campaign dart``: the Dart hover campaign on the embedded lock-step simulator
(:func:`register_campaign`); it prints a table like dart Tables 1-2: the corrected sample
standard deviation (dart eq 22) of the position error per estimator and axis.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import sys
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from companion.cli.args import RESULTS_MIN_BYTES, Once, check_writable, positive_int

log = logging.getLogger(__name__)


def _cmd_campaign_dart(args: argparse.Namespace) -> int:
    from rich.progress import Progress

    from companion.cli.console import make_console
    from companion.dart.mission import DartParamsError

    try:
        from companion_lab.dart_campaign import campaign_table, resolve_estimators, run_dart_campaign
    except ImportError as exc:  # the simulator ships with the distribution; a stripped install may lack it
        print(f"companion campaign dart: the embedded simulator is not installed: {exc}", file=sys.stderr)
        return 2
    try:
        names = resolve_estimators(args.estimator)
    except ValueError as exc:
        print(f"companion campaign dart: {exc}", file=sys.stderr)
        return 2
    if args.json:  # its folder first: an hour of campaign must not end on a missing folder
        try:
            Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            print(f"companion campaign dart: --json {args.json}: {exc}", file=sys.stderr)
            return 2
        check_writable(Path(args.json).parent, RESULTS_MIN_BYTES, "--json")  # read-only, full: exit 2
    console = make_console()
    try:
        with Progress(console=console, transient=True, disable=args.quiet) as bar:
            task = bar.add_task("dart hover campaign", total=len(names) * args.n)

            def progress(name: str, k: int) -> None:
                bar.update(task, advance=1, description=f"{name} run {k}/{args.n}")

            result = run_dart_campaign(
                names,
                args.n,
                args.seed,
                duration_s=args.duration,
                settle_s=args.settle,
                params=args.params,
                progress=progress,
            )
    except DartParamsError as exc:
        print(f"companion campaign dart: bad parameters: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"companion campaign dart: {exc}", file=sys.stderr)
        return 2
    console.print(campaign_table(result))
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(result, fh, indent=2)
        console.print(f"wrote {args.json}")
    return 0


def register_campaign(csub: Any) -> None:
    """Add ``dart`` to the ``campaign`` subcommands."""
    d = csub.add_parser(
        "dart",
        help="Dart hover 4 m from the wall marker per estimator; std of the position error (dart eq 22, Tables 1-2)",
    )
    d.add_argument(
        "--estimator",
        default="all",
        help="all, or comma-separated FCF-CF, FCF-MF, SCF-MF-2DOF, SCF-MF-3DOF (default: all)",
    )
    d.add_argument("--n", type=positive_int, default=3, help="runs per estimator (default 3)")
    d.add_argument("--seed", type=int, default=0, help="seed of the first run (run k uses seed + k)")
    d.add_argument("--duration", type=float, default=25.0, help="simulated hover per run, s (default: %(default)s)")
    d.add_argument(
        "--settle", type=float, default=8.0, help="left out at the start of each run, s (default: %(default)s)"
    )
    d.add_argument("--params", action=Once, help="Dart parameter file (default: the shipped params/dart_hover.toml)")
    d.add_argument(
        "--json", help="also write the result as JSON to this file, creating its folder (default: not written)"
    )
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_campaign_dart)


# ------------------------------------------------------------------------------ companion dart
def _load(args: argparse.Namespace) -> Any:
    """DartParams (simulation) or DartFlightParams (flight) with the command-line overrides."""
    from companion.dart.params import load_dart_flight_params

    if args.sim:
        from companion_sitl.dart_sim import load_dart_params, shipped_dart_params

        params: Any = load_dart_params(args.params or shipped_dart_params())
    else:
        if not args.params:
            raise ValueError("--params FILE is required to fly a real autopilot (or use --sim ardupilot)")
        params = load_dart_flight_params(args.params)
    mission = params.mission
    upd: dict[str, Any] = {}
    if args.hover_only:
        upd["approach"] = False
    if args.hover_s is not None:
        upd["hover_s"] = args.hover_s
    if args.max_speed is not None:
        upd["max_speed_m_s"] = args.max_speed
    if upd:
        params = replace(params, mission=replace(mission, **upd))
    if args.estimator:
        params = replace(params, runtime=params.runtime.replaced(estimator=args.estimator))
    return params


def _cm(v: float) -> str:
    return f"{100.0 * v:6.2f}" if math.isfinite(v) else "   n/a"


def _print_hover(result: Any, params: Any) -> None:
    import numpy as np

    from companion.dart.estimators import corrected_sample_std
    from companion.dart.mission import DartPhase

    m = params.mission
    for phase, target, settle in (
        (DartPhase.HOVER_START, (m.x_m, m.y_m, m.start_distance_m), 5.0),
        (DartPhase.HOVER_END, (m.x_m, m.y_m, m.end_distance_m), 4.0),
    ):
        rows = result.truth_in(phase, after_s=settle)
        if len(rows) < 2:
            continue
        err = rows - np.array(target)
        std = [corrected_sample_std(err[:, i].tolist()) for i in range(3)]
        mean = err.mean(axis=0)
        print(
            f"{phase.value:11s} truth - setpoint, cm ({len(rows)} samples from {settle:.0f} s after the start):"
            f"  mean x {_cm(mean[0])} y {_cm(mean[1])} z {_cm(mean[2])}"
            f"  std (eq 22) x {_cm(std[0])} y {_cm(std[1])} z {_cm(std[2])}"
        )


def _pilot_test_script(flips: int, latencies: list[float]) -> Any:
    """The pilot deflects the roll stick while engaged, flips the switch off (the time until the
    vehicle receives the release is recorded, vehicle side) and on again, ``flips`` times."""

    async def script(sim: Any, shell: Any) -> None:
        pending: dict[str, float] = {}

        def on_message(m: Any) -> None:  # the sim vehicle's thread
            t0 = pending.get("flip")
            if t0 is not None and m.get_type() == "RC_CHANNELS_OVERRIDE" and m.chan1_raw == 0:
                latencies.append(time.monotonic() - t0)
                pending.clear()

        sim.link.on_message = on_message
        sim.set_pilot(switch_on=True)
        await asyncio.sleep(6.0)
        for _ in range(flips):
            sim.set_pilot(roll_us=1600.0)
            await asyncio.sleep(2.0)
            sim.set_pilot(switch_on=False)
            pending["flip"] = time.monotonic()
            await asyncio.sleep(1.0)
            sim.set_pilot(roll_us=1500.0, switch_on=True)
            await asyncio.sleep(3.0)

    return script


def _cmd_dart(args: argparse.Namespace) -> int:
    from companion.autopilot.interface import AutopilotError
    from companion.dart.mission import DartParamsError

    try:
        params = _load(args)
    except DartParamsError as exc:
        print(f"companion dart: bad parameters: {exc}", file=sys.stderr)
        return 2
    except ValueError as exc:
        print(f"companion dart: {exc}", file=sys.stderr)
        return 2
    try:
        if args.sim and getattr(args, "signing_key", None):
            print(
                "companion dart: --signing-key signs the link to a real autopilot; --sim flies unsigned",
                file=sys.stderr,
            )
            return 2
        return _fly_sim(args, params) if args.sim else _fly(args, params)
    except AutopilotError as exc:
        print(f"companion dart: {exc}", file=sys.stderr)
        return 1


def _fly_sim(args: argparse.Namespace, params: Any) -> int:
    from companion_sitl.dart_link import fly_dart_link

    m = params.mission
    if args.pilot_test and args.sim != "ardupilot":
        print("companion dart: --pilot-test measures the release of RC overrides: use --sim ardupilot", file=sys.stderr)
        return 2
    latencies: list[float] = []
    flips = 5
    duration = args.duration
    if duration is None:
        duration = (
            6.0 + 6.0 * flips if args.pilot_test else m.hover_s + (m.approach_duration_s if m.approach else 0.0) + 10.0
        )
    script = _pilot_test_script(flips, latencies) if args.pilot_test else None
    print(
        f"dart over MAVLink ({args.sim} dialect, loopback UDP, real time): {params.runtime.estimator}, "
        f"{duration:.0f} s, seed {args.seed}"
    )
    result = asyncio.run(
        fly_dart_link(params, duration_s=duration, seed=args.seed, dialect=args.sim, pilot=script, log_path=args.log)
    )
    s = result.summary
    t0 = s.transitions[0][0] if s.transitions else 0.0
    print("phases: " + ", ".join(f"{ph.value} at {t - t0:.1f} s" for t, ph in s.transitions))
    st = s.stats
    print(
        f"IMU samples {st.imu_samples} ({st.imu_samples / s.duration_s:.0f}/s), frames {st.frames}, detections "
        f"{st.detections}, ambiguous (gated) {st.ambiguous}, estimates fused {st.estimates}, overrides sent "
        f"{st.overrides_sent}, releases {st.releases_sent}, attitude setpoints {st.attitude_targets_sent}, "
        f"stale contributions {st.stale_contributions}"
    )
    if not args.pilot_test:
        _print_hover(result, params)
    if latencies:
        ms = sorted(1000.0 * v for v in latencies)
        print(
            f"switch off -> overrides released at the vehicle: {len(ms)} flips, median {ms[len(ms) // 2]:.1f} ms, "
            f"max {ms[-1]:.1f} ms (control period {1000.0 / params.runtime.control_hz:.1f} ms)"
        )
    elif args.pilot_test:
        print("no release seen at the vehicle")
        return 1
    return 0


def _fly(args: argparse.Namespace, params: Any) -> int:
    from companion import plugin_api
    from companion.autopilot.interface import Autopilot
    from companion.autopilot.signing import SigningKeyError, SigningSetup, read_key_file
    from companion.dart.shell import DART_STREAM_RATES_HZ, DartShell

    signing = None  # read before anything is started: a bad key file stops us here
    if getattr(args, "signing_key", None):
        if args.autopilot == "px4":
            print(
                "companion dart: --signing-key: the PX4 backend cannot sign (mavsdk 4.1 has no signing API)",
                file=sys.stderr,
            )
            return 2
        try:
            signing = SigningSetup(read_key_file(args.signing_key))
        except SigningKeyError as exc:
            print(f"companion dart: --signing-key: {exc}", file=sys.stderr)
            return 2
    rt = params.runtime
    try:
        camera = plugin_api.create(
            "companion.cameras", rt.camera_plugin, source=rt.camera_source, latency_s=rt.camera_latency_s
        )
    except plugin_api.PluginError as exc:
        print(f"companion dart: camera: {exc}", file=sys.stderr)
        return 2
    ap: Autopilot
    if args.autopilot == "px4":
        from companion.autopilot.px4 import Px4Autopilot

        ap = Px4Autopilot(args.connection or "udpin://0.0.0.0:14540")
    else:
        from companion.autopilot.ardupilot import ArduPilotAutopilot

        ap = ArduPilotAutopilot(
            args.connection or "udpin:0.0.0.0:14550", stream_rates_hz=DART_STREAM_RATES_HZ, signing=signing
        )

    async def fly() -> Any:
        await ap.connect(timeout_s=15.0)
        try:
            shell = DartShell(ap, camera, params, log_path=args.log, keep_steps=False)
            return await shell.run(args.duration)
        finally:
            await ap.close()

    summary = asyncio.run(fly())
    st = summary.stats
    print(
        f"dart: {summary.duration_s:.0f} s, {summary.estimator}, phase {summary.phase.value}, estimates "
        f"{st.estimates}, ambiguous (gated) {st.ambiguous}, overrides {st.overrides_sent}, attitude setpoints "
        f"{st.attitude_targets_sent}, releases {st.releases_sent}"
    )
    return 0


def register(subparsers: Any) -> None:
    """Add ``dart`` to the application's subcommands."""
    d = subparsers.add_parser(
        "dart",
        help="fly the Dart cyber-pilot (hover, approach to 1.5 m) against an autopilot, or --sim ardupilot",
    )
    d.add_argument(
        "--params",
        action=Once,
        help="Dart parameter file: [control], [mission], [runtime] (and [sim] for --sim); "
        "default with --sim: the shipped dart_hover.toml, required otherwise",
    )
    d.add_argument(
        "--connection",
        help="autopilot link (ArduPilot default udpin:0.0.0.0:14550, or /dev/ttyACM0:115200; "
        "PX4 default udpin://0.0.0.0:14540)",
    )
    d.add_argument(
        "--autopilot",
        choices=("ardupilot", "px4"),
        default="ardupilot",
        help="ArduPilot: RC_CHANNELS_OVERRIDE; PX4: offboard SET_ATTITUDE_TARGET (default ardupilot)",
    )
    d.add_argument(
        "--sim",
        choices=("ardupilot", "px4"),
        help="fly against the MAVLink sim vehicle on loopback UDP, in real time, through the ArduPilot "
        "(RC override) or the PX4 (offboard attitude) backend (default: a real autopilot at --connection)",
    )
    d.add_argument(
        "--estimator", help="FCF-CF, FCF-MF, SCF-MF-2DOF or SCF-MF-3DOF (default: [runtime] of the parameters)"
    )
    d.add_argument(
        "--duration", type=float, help="seconds to fly (default: until Ctrl-C; with --sim the mission plus 10 s)"
    )
    d.add_argument("--hover-only", action="store_true", help="hover at the start point, no approach")
    d.add_argument("--hover-s", type=float, help="hover before the approach, s (default: [mission] of the parameters)")
    d.add_argument(
        "--max-speed", type=float, help="peak speed of the approach, m/s (default: [mission] of the parameters)"
    )
    d.add_argument("--seed", type=int, default=0, help="--sim: seed of the simulated world")
    d.add_argument(
        "--pilot-test",
        action="store_true",
        help="--sim: the pilot deflects the stick and flips the switch off 5 times; prints the "
        "time until the overrides are released at the vehicle",
    )
    d.add_argument("--log", help="CSV flight log of the shell, 20 Hz (default: none)")
    d.add_argument(
        "--signing-key",
        metavar="FILE",
        help="ArduPilot: sign the link with this MAVLink 2 key file and drop the vehicle's unsigned packets "
        "(64 hex digits or 32 bytes; see docs/signing.md; default: unsigned)",
    )
    d.set_defaults(func=_cmd_dart)
