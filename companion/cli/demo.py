"""``companion demo``: the delivery flown on the embedded simulator, with its progress and summary."""

from __future__ import annotations

import argparse
import logging
import math
import time
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.cli.args import output_folder
from companion.cli.exits import StartupError
from companion.cli.fly_display import PHASES  # the mission's phases in flight order: the bar's steps
from companion.config import DEFAULT_PARAMS, ConfigError, shipped_params_path
from companion.delivery.mission import FailureKind
from companion.units import format_m
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)


def _load_demo_config(args: argparse.Namespace) -> SimulatedConfig:
    paths = [Path(p) for p in args.params] if args.params else [shipped_params_path(DEFAULT_PARAMS)]
    sim: dict[str, Any] = {}
    if args.seed is not None:
        sim["seed"] = args.seed
    if args.wind is not None:
        sim["wind_speed_m_s"] = args.wind
    if args.wind_from is not None:
        sim["wind_from_deg"] = args.wind_from
    if args.gps_bias is not None:
        sim["gps_bias_m"] = _parse_vec(args.gps_bias, "--gps-bias")
    if args.pad_offset is not None:
        sim["pad_offset_m"] = _parse_vec(args.pad_offset, "--pad-offset", "north,east")
    overrides: dict[str, Any] = {"sim": sim} if sim else {}
    if args.gps_only:  # the paper's GPS-only baseline: released where it lands (docs/delivery-policy.md)
        overrides["landing"] = {"fusion": False, "policy": {"require_pad_lock": False}}
    if getattr(args, "zenoh_config", None):
        overrides["telemetry"] = {"zenoh_config": args.zenoh_config}
    return load_simulated_config(*paths, overrides=overrides or None)


def _parse_vec(text: str, opt: str, form: str = "north[,east[,down]]") -> list[float]:
    """``text`` as metres in ``form``: "north[,east[,down]]" (1 to 3 numbers, the rest 0) or
    "north,east" (exactly 2)."""
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(opt, [f"{text!r}: expected numbers separated by commas, e.g. 2,0 or 1.5,-1,0"]) from None
    if form == "north,east":
        if len(vals) != 2:
            raise ConfigError(opt, [f"{text!r}: expected 2 components (north,east) in metres, e.g. 0.4,-0.6"])
        return vals
    if len(vals) == 1:
        vals = [vals[0], 0.0, 0.0]
    elif len(vals) == 2:
        vals.append(0.0)
    if len(vals) != 3:
        raise ConfigError(opt, [f"{text!r}: expected 1 to 3 components (north[,east[,down]]) in metres"])
    return vals


def _fmt_m(v: float) -> str:
    return format_m(v)


def _fmt_rms_max(rms_m: float, max_m: float) -> str:
    return f"{format_m(rms_m)} / {format_m(max_m)}"


def flight_time_s(shell: Any) -> float:
    """Time since take-off on the shell's clock (0 before it). In real time that clock is the
    machine's monotonic clock, whose absolute value is the machine's uptime, not the flight's."""
    t0 = shell.mission.summary.takeoff_time_s
    return float(shell.now() - t0) if t0 is not None else 0.0


def _camera_playback(args: argparse.Namespace, cfg: SimulatedConfig) -> Any:
    """``--camera-file`` and its options as a ``companion_sitl.landing_sensors.CameraPlayback`` (None without
    it); misuse is a StartupError naming the option."""
    from companion_sitl.landing_sensors import CameraPlayback

    for opt in ("camera_times", "camera_time_offset", "camera_calibration"):
        if getattr(args, opt) is not None and not args.camera_file:
            raise StartupError(f"--{opt.replace('_', '-')} needs --camera-file VIDEO", exits.BAD_INPUT)
    if args.camera_file and args.record_camera:
        raise StartupError("--camera-file and --record-camera: play a recording or make one, not both", exits.BAD_INPUT)
    if (args.camera_file or args.record_camera) and not (cfg.landing.fusion and cfg.landing.use_camera):
        raise StartupError(
            "--camera-file/--record-camera need the fused landing with the camera "
            "(not --gps-only; landing.fusion and landing.use_camera true)",
            exits.BAD_INPUT,
        )
    if args.mavlink and (args.camera_file or args.record_camera):
        raise StartupError(
            "--camera-file/--record-camera run on the lock-step simulator, not with --mavlink", exits.BAD_INPUT
        )
    if not args.camera_file:
        return None
    video = Path(args.camera_file)
    if not video.is_file():
        raise StartupError(f"--camera-file {video}: no such file", exits.BAD_INPUT)
    times: Path | None
    if args.camera_times is not None:
        times = Path(args.camera_times)
        if not times.is_file():
            raise StartupError(f"--camera-times {times}: no such file", exits.BAD_INPUT)
    else:  # the CSV a recording writes beside the video, else the container's timestamps
        beside = Path(f"{video}.csv")
        times = beside if beside.is_file() else None
    offset = args.camera_time_offset if args.camera_time_offset is not None else 0.0
    if not math.isfinite(offset):
        raise StartupError(f"--camera-time-offset {offset!r}: expected a finite number of seconds", exits.BAD_INPUT)
    return CameraPlayback(video, times, offset, args.camera_calibration)


def _figures(run_dir: Path) -> list[Path]:
    """The run's path.png and lyapunov.png (none without summary.json); a full disk is logged:
    the result is printed all the same."""
    from companion.flightlog.plots import plot_run

    if not (run_dir / "summary.json").exists():
        return []
    try:
        return plot_run(run_dir)
    except OSError as err:
        log.error("%s: cannot write the figures: %s", run_dir, err)
        return []


def _print_demo_header(console: Any, cfg: SimulatedConfig, realtime: bool) -> None:
    m = cfg.mission
    console.print(
        f"[bold]companion demo[/]: h = {m.height_m} m, r = {m.arc_radius_m} m, v = {list(m.sector_speed_m_s)} m/s, "
        f"k_f = {m.convergence_gain}; wind {cfg.sim.wind_speed_m_s} m/s, GPS bias {list(cfg.sim.gps_bias_m)} m, "
        f"pad offset {list(cfg.sim.pad_offset_m)} m, "
        f"{'EKF fusion (GPS + camera + UWB)' if cfg.landing.fusion else 'GPS-only'}; "
        f"seed {cfg.sim.seed}{' (real time)' if realtime else ''}"
    )


def _fly_demo(args: argparse.Namespace, cfg: SimulatedConfig, run_dir: Path, playback: Any, console: Any) -> Any:
    """The demo flown with a progress bar of its phases; its ``DemoResult``."""
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from companion.delivery.landing_setup import LandingSetupError
    from companion_lab.demo import run_demo

    with Progress(
        TextColumn("{task.description:<16}"),
        BarColumn(),
        TextColumn("flight t = {task.fields[t]:6.1f} s"),
        TextColumn("{task.fields[where]}"),
        TimeElapsedColumn(),
        console=console,
        disable=args.quiet,
    ) as progress:
        task = progress.add_task("preflight", total=len(PHASES) - 1, t=0.0, where="")

        def on_tick(shell: Any, out: Any) -> None:
            ph = out.phase.value
            done = PHASES.index(ph) if ph in PHASES else progress.tasks[0].completed
            e = shell.estimate
            where = f"S{out.sector}  alt {-e.down_m:5.1f} m" if e is not None and out.sector else ""
            progress.update(task, description=ph, completed=done, t=flight_time_s(shell), where=where)

        try:
            return run_demo(
                cfg,
                run_dir,
                realtime=args.realtime,
                on_tick=on_tick,
                telemetry=args.telemetry,
                mavlink=args.mavlink,
                camera_playback=playback,
                record_camera=Path(args.record_camera) if args.record_camera else None,
                mcap=not args.no_mcap,
            )
        except LandingSetupError as err:
            raise StartupError(str(err), exits.BAD_INPUT) from None


def _folder_size(run_dir: Path) -> str:
    """What the run folder keeps on disk, and how to keep less (a demo a day fills runs/)."""
    total = sum(f.stat().st_size for f in run_dir.iterdir() if f.is_file())
    mcap = run_dir / "flight.mcap"
    if mcap.exists():
        share = (
            f"{mcap.stat().st_size / 1e6:.0f} MB of it flight.mcap (Foxglove, camera frames): --no-mcap leaves it out"
        )
    else:
        share = "no flight.mcap (--no-mcap)"
    return f"run folder size {total / 1e6:.0f} MB, {share}"


def _result_rows(result: Any, run_dir: Path, plots: list[Path]) -> list[tuple[str, str]]:
    """The summary's label / value rows."""
    return [
        ("flight time", f"{result.flight_time_s:.1f} s"),
        (
            "path RMS / max distance (truth, to the scored reference)",
            _fmt_rms_max(result.path_rms_truth_m, result.path_max_truth_m),
        ),
        (
            "path RMS / max distance (truth, to the mission's own path)",
            _fmt_rms_max(result.path_rms_planned_m, result.path_max_planned_m),
        ),
        ("path RMS distance (estimate, sqrt(2V), delivery Fig. 9)", _fmt_m(result.path_rms_estimate_m)),
        ("landing error on the pad (truth)", _fmt_m(result.pad_landing_error_m)),
        ("landing error at home (truth)", _fmt_m(result.home_landing_error_m)),
        *(
            [("parcel touchdown from the pad centre (truth, winch)", _fmt_m(result.parcel_touchdown_error_m))]
            if math.isfinite(result.parcel_touchdown_error_m)
            else []
        ),
        ("setpoints sent / clamped", f"{result.setpoints_sent} / {result.setpoints_clamped}"),
        (
            "simulated / wall time",
            f"{result.sim_time_s:.1f} s / {result.wall_time_s:.2f} s ({result.speedup:.0f}x real time)",
        ),
        (
            "run folder",
            f"{run_dir}  (flight.csv, truth.csv, events.csv"
            f"{', summary.json' if (run_dir / 'summary.json').exists() else ''}"
            f"{', ' + ', '.join(p.name for p in plots) if plots else ''})",
        ),
    ]


def cmd_demo(args: argparse.Namespace) -> int:
    from rich.markup import escape

    from companion.cli.console import make_console
    from companion.flightlog.losses import describe as describe_losses

    cfg = _load_demo_config(args)
    playback = _camera_playback(args, cfg)
    console = make_console()
    run_dir = output_folder(args.out, time.strftime("demo-%Y%m%d-%H%M%S"))
    _print_demo_header(console, cfg, args.realtime)
    result = _fly_demo(args, cfg, run_dir, playback, console)
    plots = _figures(run_dir) if result.phase != "preflight" else []
    ok = result.delivered and (result.returned or not cfg.mission.return_home)
    console.print()
    console.print(
        f"[bold]{'DELIVERED' if result.delivered else 'NOT DELIVERED'}[/]"
        f"{', returned home' if result.returned else ''}" + (f"  [red]{result.failure}[/]" if result.failure else "")
    )
    for k, v in _result_rows(result, run_dir, plots):
        console.print(f"  {k:<62} {v}")
    console.print(f"  scored reference: {result.path_reference}")
    console.print(f"  {_folder_size(run_dir)}")
    lost = describe_losses(run_dir)
    if lost:
        console.print(f"[bold red]{escape(lost)}[/]: {escape(str(run_dir))} holds the flight up to where they stopped")
    if result.failure_kind is FailureKind.OPERATOR_ABORT:  # Ctrl-C in flight: held, landed, ended
        return exits.INTERRUPTED
    return exits.FAILED if not ok else exits.LOGS_INCOMPLETE if lost else exits.OK


def register_demo(sub: Any) -> None:
    """Add ``companion demo``."""
    demo = sub.add_parser("demo", help="fly the delivery paper's experiment on the embedded simulator")
    demo.add_argument("--params", action="append", help="parameter file(s) (default: the shipped delivery_paper.toml)")
    demo.add_argument("--seed", type=int, help="random seed of the scenario (default: [sim] seed of the parameters)")
    demo.add_argument("--wind", type=float, help="mean wind speed, m/s (default: [sim] wind_speed_m_s)")
    demo.add_argument(
        "--wind-from", type=float, help="direction the wind blows from, deg, 0 = north (default: [sim] wind_from_deg)"
    )
    demo.add_argument("--gps-bias", help="constant GPS error, m: north[,east[,down]] (default: [sim] gps_bias_m)")
    demo.add_argument(
        "--pad-offset",
        help="the pad lies this far from its configured position: north,east, m (default: [sim] pad_offset_m)",
    )
    demo.add_argument("--gps-only", action="store_true", help="GPS-only baseline: no camera/UWB fusion")
    demo.add_argument("--realtime", action="store_true", help="run in real time instead of lock-step")
    demo.add_argument(
        "--mavlink",
        choices=("px4", "ardupilot"),
        help="serve the simulator over MAVLink on loopback UDP and fly it through the PX4 (MAVSDK) or "
        "ArduPilot (pymavlink) backend, in real time (use --params params/sitl_short.toml for a short flight; "
        "default: the in-process simulator, lock-step)",
    )
    demo.add_argument("--out", help="run folder (default: runs/demo-<time>)")
    demo.add_argument(
        "--no-mcap",
        action="store_true",
        help="do not write flight.mcap (Foxglove: every stream and the camera frames, ~3/4 of the folder)",
    )
    demo.add_argument("--quiet", action="store_true", help="no progress bar")
    demo.add_argument(
        "--telemetry",
        action="store_true",
        help="publish telemetry over Zenoh (session from [telemetry] zenoh_config; see `companion ground`)",
    )
    demo.add_argument(
        "--zenoh-config",
        help="Zenoh session file for --telemetry, e.g. params/zenoh_loopback.toml (default: [telemetry] zenoh_config)",
    )
    demo.add_argument(
        "--camera-file",
        metavar="VIDEO",
        help="hardware-in-the-loop with a recorded camera: play VIDEO through the OpenCV camera plugin at its own "
        "frame times on the simulated clock instead of rendering the landing camera (default: rendered)",
    )
    demo.add_argument(
        "--camera-times",
        metavar="CSV",
        help="exposure times of --camera-file's frames, columns frame,time_s (default: VIDEO.csv if it exists, "
        "else the video container's timestamps)",
    )
    demo.add_argument(
        "--camera-time-offset",
        type=float,
        metavar="S",
        help="seconds added to the frame times to put them on the simulated clock (default 0)",
    )
    demo.add_argument(
        "--camera-calibration",
        metavar="TOML",
        help="calibration of the recorded camera, e.g. from `companion calibrate` "
        "(default: landing.camera_calibration)",
    )
    demo.add_argument(
        "--record-camera",
        metavar="VIDEO",
        help="record the simulated landing camera's frames to VIDEO (.avi MJPG, .mkv lossless FFV1, .mp4) and their "
        "exposure times to VIDEO.csv, for --camera-file (default: not recorded)",
    )
    demo.set_defaults(func=cmd_demo)
