"""CLI of the simulator runs: ``demo``, ``bench`` (sim, estimation, ekf, uwb, vision) and
``campaign landing``; the one place the delivery application meets the embedded simulator."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.cli.exits import StartupError
from companion.config import (
    DEFAULT_PARAMS,
    CompanionConfig,
    ConfigError,
    load_config,
    shipped_params_path,
)
from companion.units import format_cm, format_m

log = logging.getLogger(__name__)


def _load_demo_config(args: argparse.Namespace) -> CompanionConfig:
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
        sim["pad_offset_m"] = _parse_vec(args.pad_offset, "--pad-offset")[:2]
    overrides: dict[str, Any] = {"sim": sim} if sim else {}
    if args.gps_only:
        overrides["landing"] = {"fusion": False}
    if getattr(args, "zenoh_config", None):
        overrides["telemetry"] = {"zenoh_config": args.zenoh_config}
    return load_config(*paths, overrides=overrides or None)


def _parse_vec(text: str, opt: str) -> list[float]:
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise ConfigError(opt, [f"{text!r}: expected numbers separated by commas, e.g. 2,0 or 1.5,-1,0"]) from None
    if len(vals) == 1:
        vals = [vals[0], 0.0, 0.0]
    elif len(vals) == 2:
        vals.append(0.0)
    if len(vals) != 3:
        raise ConfigError(opt, [f"{text!r}: expected 1 to 3 components (north[,east[,down]]) in metres"])
    return vals


def _positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n}: need at least 1")
    return n


def _fmt_m(v: float) -> str:
    return format_m(v)


def _fmt_rms_max(rms_m: float, max_m: float) -> str:
    return f"{format_m(rms_m)} / {format_m(max_m)}"


def flight_time_s(shell: Any) -> float:
    """Time since take-off on the shell's clock (0 before it). In real time that clock is the
    machine's monotonic clock, whose absolute value is the machine's uptime, not the flight's."""
    t0 = shell.mission.summary.takeoff_time_s
    return float(shell._clock.now() - t0) if t0 is not None else 0.0


def _camera_playback(args: argparse.Namespace, cfg: CompanionConfig) -> Any:
    """``--camera-file`` and its options as a ``companion_sitl.demo.CameraPlayback`` (None without
    it); misuse is a StartupError naming the option."""
    from companion_sitl.demo import CameraPlayback

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


def cmd_demo(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

    from companion.cli.console import make_console
    from companion.delivery.landing_setup import LandingSetupError
    from companion.flightlog.plots import plot_run
    from companion_sitl.demo import run_demo

    cfg = _load_demo_config(args)
    playback = _camera_playback(args, cfg)
    console = make_console()
    run_dir = Path(args.out) if args.out else Path("runs") / time.strftime("demo-%Y%m%d-%H%M%S")
    m = cfg.mission
    console.print(
        f"[bold]companion demo[/]: h = {m.height_m} m, r = {m.arc_radius_m} m, v = {list(m.sector_speed_m_s)} m/s, "
        f"k_f = {m.convergence_gain}; wind {cfg.sim.wind_speed_m_s} m/s, GPS bias {list(cfg.sim.gps_bias_m)} m, "
        f"pad offset {list(cfg.sim.pad_offset_m)} m, "
        f"{'EKF fusion (GPS + camera + UWB)' if cfg.landing.fusion else 'GPS-only'}; "
        f"seed {cfg.sim.seed}{' (real time)' if args.realtime else ''}"
    )
    phases = [
        "preflight",
        "arming",
        "takeoff",
        "outbound",
        "landing_pad",
        "release",
        "takeoff_return",
        "inbound",
        "landing_home",
        "done",
    ]
    with Progress(
        TextColumn("{task.description:<16}"),
        BarColumn(),
        TextColumn("flight t = {task.fields[t]:6.1f} s"),
        TextColumn("{task.fields[where]}"),
        TimeElapsedColumn(),
        console=console,
        disable=args.quiet,
    ) as progress:
        task = progress.add_task("preflight", total=len(phases) - 1, t=0.0, where="")

        def on_tick(shell: Any, out: Any) -> None:
            ph = out.phase.value
            done = phases.index(ph) if ph in phases else progress.tasks[0].completed
            e = shell.estimate
            where = f"S{out.sector}  alt {-e.down_m:5.1f} m" if e is not None and out.sector else ""
            progress.update(task, description=ph, completed=done, t=flight_time_s(shell), where=where)

        try:
            result = run_demo(
                cfg,
                run_dir,
                realtime=args.realtime,
                on_tick=on_tick,
                telemetry=args.telemetry,
                mavlink=args.mavlink,
                camera_playback=playback,
                record_camera=Path(args.record_camera) if args.record_camera else None,
            )
        except LandingSetupError as err:
            raise StartupError(str(err), exits.BAD_INPUT) from None
    plots = plot_run(run_dir) if result.phase != "preflight" and (run_dir / "summary.json").exists() else []
    ok = result.delivered and (result.returned or not m.return_home)
    console.print()
    console.print(
        f"[bold]{'DELIVERED' if result.delivered else 'NOT DELIVERED'}[/]"
        f"{', returned home' if result.returned else ''}" + (f"  [red]{result.failure}[/]" if result.failure else "")
    )
    rows = [
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
        ("setpoints sent / clamped", f"{result.setpoints_sent} / {result.setpoints_clamped}"),
        (
            "simulated / wall time",
            f"{result.sim_time_s:.1f} s / {result.wall_time_s:.2f} s ({result.speedup:.0f}x real time)",
        ),
        (
            "run folder",
            f"{run_dir}  (flight.csv, truth.csv, events.csv, summary.json"
            f"{', ' + ', '.join(p.name for p in plots) if plots else ''})",
        ),
    ]
    for k, v in rows:
        console.print(f"  {k:<62} {v}")
    console.print(f"  scored reference: {result.path_reference}")
    return 0 if ok else 1


def cmd_bench_sim(args: argparse.Namespace) -> int:
    from companion_sitl.demo import run_demo

    cfg = load_config(shipped_params_path(DEFAULT_PARAMS), overrides={"sim": {"seed": args.seed}})
    best = {}
    for label, fusion in (
        ("GPS-only (simulator + guidance)", False),
        ("with camera rendering + detection + EKF", True),
    ):
        speedups = []
        for i in range(args.repeat):
            r = run_demo(cfg, fusion=fusion)
            speedups.append(r.speedup)
            print(
                f"{label}, run {i + 1}: {r.sim_time_s:.1f} s simulated in {r.wall_time_s:.2f} s wall = "
                f"{r.speedup:.1f}x real time (delivered={r.delivered}, returned={r.returned})"
            )
        best[label] = max(speedups)
    for label, v in best.items():
        print(f"bench sim: {label}: {v:.1f}x faster than real time (best of {args.repeat})")
    print(
        "target >= 50x for the GPS-only demo flight; the fused flight renders and searches every camera frame "
        "(30 Hz) during the descent"
    )
    return 0


def _bench_value(key: str, value: Any) -> str:
    """A distance (``*_m``) in units that never read 0.00 for a non-zero error, a count as an
    integer, other figures with two decimals."""
    if not isinstance(value, float):
        return str(value)
    if key.endswith("_m"):
        return format_m(value)
    if value.is_integer() and key.startswith(("n_", "ours_full", "ours_roi")):
        return str(int(value))
    return f"{value:.2f}"


def _print_bench(title: str, result: dict[str, Any]) -> None:
    print(title)
    width = max(len(k) for k in result) if result else 0
    for k, v in result.items():
        print(f"  {k:<{width}}  {_bench_value(k, v)}")


def cmd_bench_campaign(args: argparse.Namespace) -> int:
    import resource

    from companion_sitl.landing_campaign import run_landing_campaign, usable_cpus
    from companion_sitl.real_campaign import FIRMWARE_OF_PROFILE, firmware_tuning

    fw = FIRMWARE_OF_PROFILE.get(args.profile)
    tuning = firmware_tuning(fw) if fw else None
    jobs = args.jobs if args.jobs is not None else usable_cpus()

    def children_cpu() -> float:
        ru = resource.getrusage(resource.RUSAGE_CHILDREN)  # the worker processes, once ended
        return ru.ru_utime + ru.ru_stime

    def timed(j: int) -> tuple[int, dict[str, Any], float, float, float, float]:
        t0, c0, m0, k0 = time.perf_counter(), time.process_time(), time.thread_time(), children_cpu()
        r = run_landing_campaign(args.n, args.seed, ("fusion",), None, profile=args.profile, tuning=tuning, jobs=j)
        wall, main = time.perf_counter() - t0, time.thread_time() - m0
        cpu = time.process_time() - c0 + children_cpu() - k0
        return j, r, sum(x["sim_time_s"] for x in r["landings"]["fusion"]), wall, cpu, main

    print(
        f"bench campaign: {args.n} fused landings on the {args.profile} profile, seed {args.seed} "
        f"(load average {os.getloadavg()[0]:.2f} on {usable_cpus()} usable CPUs)"
    )
    runs = [timed(jobs)] + ([timed(1)] if jobs > 1 else [])
    for j, _, sim, wall, cpu, main in runs:
        # one process: its main thread (the event loop, the detector, the EKF) is the critical path
        on_core = f"; main thread {main:.1f} s = {sim / main:.1f}x" if j == 1 else " in all processes"
        print(
            f"  {j} process{'es' if j > 1 else '  '}  {sim:.0f} s simulated in {wall:.1f} s wall = "
            f"{sim / wall:.1f}x real time (target >= 20x on a 2-core machine); CPU {cpu:.1f} s{on_core}"
        )
    if len(runs) == 2:
        (_, r_pool, _, w_pool, _, _), (_, r_one, _, w_one, _, _) = runs
        same = json.dumps(r_pool) == json.dumps(r_one)
        print(
            f"  {jobs} processes / 1: {w_one / w_pool:.2f}x faster on {usable_cpus()} usable CPU(s); "
            f"results {'identical' if same else 'DIFFERENT'}; load average now {os.getloadavg()[0]:.2f}"
        )
        if not same:
            return exits.FAILED
    return 0


def cmd_bench_log(args: argparse.Namespace) -> int:
    from companion_sitl.log_bench import bench_log

    cfg = load_config(shipped_params_path(DEFAULT_PARAMS), overrides={"sim": {"seed": args.seed}})
    if args.rounds < 1:
        raise StartupError(f"--rounds {args.rounds}: must be >= 1", exits.BAD_INPUT)
    r = bench_log(config=cfg, rounds=args.rounds)
    print(
        f"bench log: the GPS-only demo flight ({r['sim_time_s']:.0f} s simulated), each variant flown "
        f"{r['rounds']} times interleaved in this run (fastest counts), plus one timed flight"
    )
    print(f"  no logs                                 {r['bare_wall_s']:.2f} s wall")
    print(
        f"  CSV logs (recorder streams, flight.csv, truth.csv)  {r['csv_logs_wall_s']:.2f} s wall: "
        f"logging share {100 * r['csv_logging_share']:+.1f} % (target <= 10 %)"
    )
    print(
        f"  CSV logs + flight.mcap                              {r['csv_mcap_logs_wall_s']:.2f} s wall: "
        f"logging share {100 * r['csv_mcap_logging_share']:+.1f} % "
        f"(MCAP vs CSV logs alone {100 * r['mcap_vs_csv_share']:+.1f} %; {r['mcap_bytes'] / 1e6:.1f} MB MCAP)"
    )
    print(
        f"  whole run folder (CSV logs + MCAP + flight.tlog)    {r['full_run_folder_wall_s']:.2f} s wall: "
        f"logging share {100 * r['full_logging_share']:+.1f} %"
    )
    if "split_rows_share" in r:
        print(
            "    split (the same flights with nothing logged / rows queued but not handed over, fastest of each): "
            f"opening and closing {100 * r['split_open_close_share']:+.1f} %, building and queueing the rows on "
            f"the loop {100 * r['split_rows_share']:+.1f} %, handing them over + the logging process + closing's "
            f"wait {100 * r['split_handover_share']:+.1f} %"
        )
    print("  CPU time the logs add (uninstrumented flights, fastest of each; over the bare flight's CPU time):")
    for key, label in (("csv", "CSV logs"), ("csv_mcap", "CSV logs + flight.mcap"), ("full", "whole run folder")):
        child = r.get(f"{key}_logging_process_cpu_share")
        print(
            f"    {label:<24} this process {100 * r[f'{key}_cpu_share']:+.1f} %"
            + (f", the logging process (another core) {100 * child:.1f} %" if child is not None else "")
        )
    print(
        f"  per stream, in this process, with the whole run folder (recorder hook + queueing + taking the batch; "
        f"{r['rows']} rows and .tlog records; written {r['log_writer']}; the CPU clock's own "
        f"{r['clock_overhead_us']:.2f} us per timed call subtracted):"
    )
    for k, v in r.items():
        if k.endswith("_us_per_row") and k != "all_streams_us_per_row":
            name = k.removesuffix("_us_per_row")
            print(f"    {name:<20} {r[name + '_rows']:>7} rows  {v:6.2f} us/row")
    print(f"    {'all streams':<20} {r['rows']:>7} rows  {r['all_streams_us_per_row']:6.2f} us/row")
    print(f"    {'hand-over (pickle + send)':<28}      {r['us_per_row_handover']:6.2f} us/row")
    print(
        f"    {'this process in all':<28}      {r['us_per_row_this_process']:6.2f} us/row, "
        f"{r['this_process_ms']:.0f} ms ({100 * r['this_process_share']:.1f} % of the bare flight's wall time, "
        "in CPU time)"
    )
    print(
        f"  flight.tlog holds {r['tlog_records']} records: {r['tlog_records_of_samples']} of them encoded from "
        "the telemetry samples the recorder's telemetry hook queued for it (charged to the ap_* streams), "
        f"the other {r['flight.tlog_rows']} queued by the .tlog's own hooks"
    )
    if "us_per_row_logging_process" in r:
        print(
            f"  the logging process (formatting, MCAP, I/O; another core): {r['logging_process_cpu_s']:.2f} s CPU, "
            f"{r['us_per_row_logging_process']:.2f} us/row"
        )
    return 0


def cmd_bench_estimation(args: argparse.Namespace) -> int:
    from companion.dart.bench import bench_estimation

    _print_bench(f"bench estimation (microseconds per call, n = {args.n}):", bench_estimation(args.n))
    return 0


def cmd_bench_ekf(args: argparse.Namespace) -> int:
    from companion.estimation.bench import bench_ekf

    _print_bench(f"bench ekf (microseconds per call, n = {args.n}):", bench_ekf(args.n))
    return 0


def cmd_bench_uwb(args: argparse.Namespace) -> int:
    from companion.uwb.bench import bench_multilateration

    _print_bench(f"bench uwb (microseconds per solve, n = {args.n}):", bench_multilateration(args.n))
    return 0


def cmd_bench_vision(args: argparse.Namespace) -> int:
    from companion_sitl.vision_bench import bench_vision

    if args.range or args.ambiguity:
        return _bench_vision_extra(args)
    frames = 120 if args.frames is None else args.frames
    r = bench_vision(frames, args.seed)
    _print_bench(f"bench vision ({frames} rendered 640x480 frames of a descent, same frames in one run):", r)
    return 0


def format_range_result(r: dict[str, Any]) -> str:
    """``companion bench vision --range`` as a table."""

    def m(v: float | None) -> str:
        return "-" if v is None else f"{v:g} m"

    lines = [
        f"detection range of the nested pad (outer {r['outer_size_m']:g} m, inner {r['inner_size_m']:g} m): "
        f"largest height with the marker found in >= {100 * r['min_rate']:.0f} % of {r['frames_per_height']} "
        f"seeded frames (seed {r['seed']}), full-frame search",
        f"{'resolution':>10} {'tilt':>6} {'outer found':>16} {'inner found':>16}",
    ]
    for x in r["runs"]:
        outer = f"{m(x['outer_from_m'])} - {m(x['outer_range_m'])}"
        inner = f"{m(x['inner_from_m'])} - {m(x['inner_range_m'])}"
        lines.append(f"{x['resolution']:>10} {x['tilt_deg']:>4g} d {outer:>16} {inner:>16}")
    return "\n".join(lines)


def format_ambiguity_result(title: str, r: dict[str, Any]) -> str:
    """``companion bench vision --ambiguity``: before / after the attitude rule, one column each."""
    keys = [k for k in r["before"] if k != "resolved_by"]
    lines = [title, f"  {'':<36} {'before':>12} {'after':>12}"]
    for k in keys:
        lines.append(f"  {k:<36} {_bench_value(k, r['before'][k]):>12} {_bench_value(k, r['after'][k]):>12}")
    for name in ("before", "after"):
        how = ", ".join(f"{k} {v}" for k, v in r[name]["resolved_by"].items())
        lines.append(f"  resolved by ({name}): {how}")
    lines.append(f"  extra detections fused: {r['extra_fused']:+d}")
    return "\n".join(lines)


def _bench_vision_extra(args: argparse.Namespace) -> int:
    from companion_sitl.vision_bench import bench_ambiguity, bench_dart_ambiguity, bench_vision_range

    out: dict[str, Any] = {}
    text: list[str] = []
    if args.range:
        out["range"] = rr = bench_vision_range(args.range_frames, args.seed)
        text.append(format_range_result(rr))
    if args.ambiguity:
        out["ambiguity_pad"] = ra = bench_ambiguity(300 if args.frames is None else args.frames, args.seed)
        text.append(
            format_ambiguity_result(
                f"IPPE ambiguity, rendered approach to the pad 15 -> 3 m ({ra['n_frames']} frames, seed "
                f"{ra['seed']}): before = no attitude, after = attitude {ra['attitude_bias_deg']:g} deg bias "
                f"+ {ra['attitude_noise_deg']:g} deg noise",
                ra,
            )
        )
        out["ambiguity_dart"] = rd = bench_dart_ambiguity("FCF-CF", args.seed, args.dart_duration)
        text.append(
            format_ambiguity_result(
                f"IPPE ambiguity, Dart hover 1.5 m from the wall marker ({rd['estimator']}, "
                f"{rd['duration_s']:g} s, seed {rd['seed']}), two flights: before / after the attitude aid",
                rd,
            )
        )
    print(json.dumps(out, indent=2) if args.json else "\n\n".join(text))
    return 0


def cmd_campaign_landing(args: argparse.Namespace) -> int:
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    from companion.cli.console import make_console
    from companion_sitl.campaign_output import write_outputs
    from companion_sitl.landing_campaign import (
        FAILURE_VARIANTS,
        CampaignLandingError,
        run_landing_campaign,
        usable_cpus,
    )

    jobs = args.jobs if args.jobs is not None else usable_cpus()
    variants = ["fusion", "gps_only"] + (list(FAILURE_VARIANTS) if args.failures else [])
    if args.variants:
        variants = [v.strip() for v in args.variants.split(",") if v.strip()]
    console = make_console()
    with Progress(
        TextColumn("{task.description:<12}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        disable=args.quiet,
    ) as progress:
        task = progress.add_task("landing", total=args.n * len(variants))

        def on_progress(variant: str, done: int, total: int) -> None:
            progress.update(task, description=variant, completed=done)

        out = Path(args.out) if args.out else Path("runs") / time.strftime("landing-%Y%m%d-%H%M%S")
        if args.autopilot:
            from companion_sitl.real_campaign import run_real_landing_campaign

            result = run_real_landing_campaign(
                args.autopilot, args.n, args.seed, tuple(variants), args.params, out / "sitl", on_progress
            )
        else:
            from companion_sitl.real_campaign import FIRMWARE_OF_PROFILE, firmware_tuning

            # a firmware's profile flies with the landing tuning shipped for that firmware
            fw = FIRMWARE_OF_PROFILE.get(args.profile)
            tuning = firmware_tuning(fw) if fw else None
            try:
                result = run_landing_campaign(
                    args.n,
                    args.seed,
                    tuple(variants),
                    args.params,
                    on_progress,
                    profile=args.profile,
                    tuning=tuning,
                    jobs=jobs,
                )
            except CampaignLandingError as err:
                progress.stop()
                log.debug("the failed landing", exc_info=err)
                print(f"companion campaign landing: {err}", file=sys.stderr)
                return exits.FAILED
    files = write_outputs(result, out)
    where = f"real {args.autopilot} SITL" if args.autopilot else f"embedded simulator, {args.profile} profile"
    table = Table(title=f"{args.n} landings per variant, seed {args.seed}, {where} (true touchdown vs true pad centre)")
    for col in ("variant", "mean", "median", "p90", "p95", "max", "on the pad"):
        table.add_column(col, justify="right" if col != "variant" else "left")
    for v, s in result["summary"].items():
        table.add_row(
            v,
            *(format_cm(s[k]) for k in ("mean_m", "median_m", "p90_m", "p95_m", "max_m")),
            f"{s['on_pad_pct']:.0f} %",
        )
    console.print(table)
    console.print(f"written: {', '.join(str(f) for f in files)}")
    return 0


def cmd_campaign_parity(args: argparse.Namespace) -> int:
    from rich.table import Table

    from companion.cli.console import make_console
    from companion_sitl.real_campaign import run_parity

    variants = tuple(v.strip() for v in args.variants.split(",") if v.strip())
    out = Path(args.out) if args.out else None
    result = run_parity(args.autopilot, args.n, args.seed, args.params, out, variants)
    console = make_console()
    for v, c in result["comparison"].items():
        title = f"{v}: {result['profile']} profile vs real {args.autopilot} SITL, same {len(c['seeds'])} draws"
        table = Table(title=title)
        for col in ("", "mean", "p90", "max"):
            table.add_column(col, justify="right" if col else "left")
        for name in ("predicted", "real"):
            f = c[name]
            table.add_row(name, *(format_cm(f[k]) for k in ("mean_m", "p90_m", "max_m")))
        r = c["ratio_predicted_to_real"]
        table.add_row("predicted/real", *(f"{r[k]:.2f}" for k in ("mean_m", "p90_m", "max_m")))
        console.print(table)
        console.print(
            f"mean and p90 within {c['within_factor']}x: {'yes' if c['mean_and_p90_within_factor'] else 'NO'}; "
            f"failure classes agree: {'yes' if c['failure_classes_agree'] else 'NO'} "
            f"(disagreeing seeds: {c['failure_class_disagreements'] or 'none'})"
        )
    console.print(f"written: {result['out_dir']}/parity.json, parity.png")
    return 0


def cmd_campaign_probe(args: argparse.Namespace) -> int:
    from companion_sitl.firmware_probe import run_probe

    out = Path(args.out) if args.out else Path("runs") / time.strftime(f"probe-{args.autopilot}-%Y%m%d-%H%M%S")
    fig = run_probe(args.autopilot, out)
    for k, v in sorted(fig.items()):
        print(f"{k:48s} {json.dumps(v)}")
    print(f"written: {out}/probe.csv, {out}/probe.json")
    return 0


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


def register_bench(bsub: Any) -> None:
    """Add ``companion bench sim``, ``bench campaign``, ``bench log`` and ``bench estimation``."""
    bs = bsub.add_parser("sim", help="how many times faster than real time the demo flight runs")
    bs.add_argument("--repeat", type=int, default=2, help="flights per configuration (the best one is reported)")
    bs.add_argument("--seed", type=int, default=1, help="random seed of the scenario")
    bs.set_defaults(func=cmd_bench_sim)
    bc = bsub.add_parser(
        "campaign", help="how many times faster than real time the landing campaign flies on a profile"
    )
    bc.add_argument(
        "--profile",
        choices=("ideal", "px4-sih", "arducopter-sitl"),
        default="px4-sih",
        help="autopilot profile of the embedded simulator",
    )
    bc.add_argument("--n", type=int, default=5, help="fused landings (default 5)")
    bc.add_argument("--seed", type=int, default=1, help="seed of the first draw")
    bc.add_argument(
        "--jobs",
        type=_positive_int,
        help="worker processes (default: the CPUs this process may use); above 1 the bench also flies the "
        "landings in one process and prints both",
    )
    bc.set_defaults(func=cmd_bench_campaign)
    bl = bsub.add_parser(
        "log", help="the flight logs' share of the GPS-only demo's time and microseconds per row and stream"
    )
    bl.add_argument("--seed", type=int, default=1, help="random seed of the scenario")
    bl.add_argument(
        "--rounds",
        type=int,
        default=3,
        help="flights of each variant, interleaved (the fastest counts; more on a busy machine)",
    )
    bl.set_defaults(func=cmd_bench_log)
    be = bsub.add_parser("estimation", help="microseconds per Madgwick update and per Dart estimator step")
    be.add_argument("--n", type=int, default=5000, help="calls timed per filter and estimator")
    be.set_defaults(func=cmd_bench_estimation)


def register_bench_micro(bsub: Any) -> None:
    """Add ``companion bench ekf``, ``bench uwb`` and ``bench vision``."""
    bk = bsub.add_parser("ekf", help="microseconds per EKF predict and per update of each sensor")
    bk.add_argument("--n", type=int, default=2000, help="calls timed per step")
    bk.set_defaults(func=cmd_bench_ekf)
    bu = bsub.add_parser("uwb", help="microseconds per TWR / TDoA multilateration solve")
    bu.add_argument("--n", type=int, default=300, help="solves timed per method")
    bu.set_defaults(func=cmd_bench_uwb)
    bv = bsub.add_parser("vision", help="raw full-frame ArUco detection vs our ROI pipeline on the same frames")
    bv.add_argument("--frames", type=int, help="rendered frames of the descent (default: 120; 300 with --ambiguity)")
    bv.add_argument("--seed", type=int, default=0, help="seed of the rendering noise")
    bv.add_argument(
        "--range",
        action="store_true",
        help="detection range of each marker at 640x480 and 1280x720, straight down and tilted 10 deg",
    )
    bv.add_argument("--range-frames", type=int, default=20, help="seeded frames per height with --range")
    bv.add_argument(
        "--ambiguity",
        action="store_true",
        help="IPPE mirror pairs resolved by the attitude: detections fused and their error against truth, "
        "before / after (rendered approach; --frames, default 300 here) and on the Dart hover",
    )
    bv.add_argument("--dart-duration", type=float, default=10.0, help="seconds of Dart hover with --ambiguity")
    bv.add_argument("--json", action="store_true", help="print --range / --ambiguity results as JSON")
    bv.set_defaults(func=cmd_bench_vision)


def register_campaign(csub: Any) -> None:
    """Add ``companion campaign landing``."""
    cl = csub.add_parser("landing", help="Monte Carlo precision landings: fusion vs GPS-only (delivery Fig. 15)")
    cl.add_argument("--n", type=int, default=100, help="landings per variant")
    cl.add_argument("--seed", type=int, default=1, help="seed of the draws")
    cl.add_argument("--failures", action="store_true", help="also: no_camera, no_uwb, outer_only, inner_only")
    cl.add_argument(
        "--variants",
        help="comma-separated variants, overrides --failures (default: fusion,gps_only, and the failure "
        "variants with --failures)",
    )
    cl.add_argument("--params", help="scenario parameters (default: the shipped landing_campaign.toml)")
    cl.add_argument("--out", help="output folder (default runs/landing-<time>)")
    cl.add_argument("--quiet", action="store_true", help="no progress bar")
    cl.add_argument(
        "--jobs",
        type=_positive_int,
        help="embedded landings flown at once, each in a worker process (default: the CPUs this process may "
        "use; 1: one after the other in this process); the results are the same whatever the number",
    )
    where = cl.add_mutually_exclusive_group()
    where.add_argument(
        "--profile",
        choices=("ideal", "px4-sih", "arducopter-sitl"),
        default="ideal",
        help="embedded simulator behaving like this autopilot (measured on its SITL; default ideal)",
    )
    where.add_argument(
        "--autopilot",
        choices=("px4", "ardupilot"),
        help="fly the landings on the real SITL build (PX4_DIR / ARDUPILOT_DIR), in real time "
        "(default: the embedded simulator)",
    )
    cl.set_defaults(func=cmd_campaign_landing)
    cp = csub.add_parser(
        "parity",
        help="the embedded campaign with the firmware's profile against the real SITL on the same draws",
    )
    cp.add_argument("--autopilot", choices=("px4", "ardupilot"), required=True, help="the real SITL to compare with")
    cp.add_argument("--n", type=int, default=10, help="landings (each real one takes about a minute)")
    cp.add_argument("--seed", type=int, default=1, help="seed of the draws")
    cp.add_argument("--variants", default="fusion", help="comma-separated variants (default fusion)")
    cp.add_argument("--params", help="scenario parameters (default: the shipped landing_campaign.toml)")
    cp.add_argument("--out", help="output folder (default runs/parity-<autopilot>-<time>)")
    cp.set_defaults(func=cmd_campaign_parity)
    pr = csub.add_parser(
        "probe",
        help="measure a real SITL for its autopilot profile: estimate errors, velocity step, land detector",
    )
    pr.add_argument("--autopilot", choices=("px4", "ardupilot"), required=True, help="the real SITL to measure")
    pr.add_argument("--out", help="output folder (default runs/probe-<autopilot>-<time>)")
    pr.set_defaults(func=cmd_campaign_probe)
