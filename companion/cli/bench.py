"""``companion bench``: every bench's command line (the benches themselves are in ``companion_lab.bench``)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import time
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.cli.args import positive_int
from companion.cli.exits import StartupError
from companion.config import DEFAULT_PARAMS, shipped_params_path
from companion.units import format_m
from companion_sitl.params import load_simulated_config

log = logging.getLogger(__name__)


def cmd_bench_sim(args: argparse.Namespace) -> int:
    from companion_lab.demo import run_demo

    cfg = load_simulated_config(shipped_params_path(DEFAULT_PARAMS), overrides={"sim": {"seed": args.seed}})
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

    from companion_lab.landing_campaign import run_landing_campaign, usable_cpus
    from companion_lab.real_campaign import FIRMWARE_OF_PROFILE, firmware_tuning

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
    from companion_lab.bench.log import bench_log

    cfg = load_simulated_config(shipped_params_path(DEFAULT_PARAMS), overrides={"sim": {"seed": args.seed}})
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
    from companion_lab.bench.dart import bench_estimation

    _print_bench(f"bench estimation (microseconds per call, n = {args.n}):", bench_estimation(args.n))
    return 0


def cmd_bench_ekf(args: argparse.Namespace) -> int:
    from companion_lab.bench.estimation import bench_ekf

    _print_bench(f"bench ekf (microseconds per call, n = {args.n}):", bench_ekf(args.n))
    return 0


def cmd_bench_uwb(args: argparse.Namespace) -> int:
    from companion_lab.bench.uwb import bench_multilateration

    _print_bench(f"bench uwb (microseconds per solve, n = {args.n}):", bench_multilateration(args.n))
    return 0


def cmd_bench_vision(args: argparse.Namespace) -> int:
    from companion_lab.bench.vision import bench_vision

    if args.conditions:
        return _bench_vision_conditions(args)
    if args.range or args.ambiguity:
        return _bench_vision_extra(args)
    frames = 120 if args.frames is None else args.frames
    r = bench_vision(frames, args.seed)
    _print_bench(f"bench vision ({frames} rendered 640x480 frames of a descent, same frames in one run):", r)
    return 0


def _bench_vision_conditions(args: argparse.Namespace) -> int:
    from companion_lab.bench.vision import bench_vision_conditions

    frames = 120 if args.frames is None else args.frames
    if frames < 2:
        raise StartupError(f"--frames {frames}: must be >= 2", exits.BAD_INPUT)
    r = bench_vision_conditions(frames, args.seed)
    if args.json:
        print(json.dumps(r, indent=2))
        return exits.OK
    print(
        f"bench vision --conditions: the pad detector on {frames} rendered frames of a descent (12 -> 1.2 m, "
        f"seed {args.seed}) per real-camera condition (companion_sitl.camera_conditions, params/camera_real.toml)"
    )
    print(f"  {'condition':<16} {'detected':>9} {'fused':>7} {'median':>9} {'p90':>9} {'max':>9} {'ms/frame':>9}")
    for name, c in r["conditions"].items():
        print(
            f"  {name:<16} {c['detection_rate']:>9.2f} {c['fused_rate']:>7.2f} "
            f"{format_m(c['median_position_error_m']):>9} {format_m(c['p90_position_error_m']):>9} "
            f"{format_m(c['max_position_error_m']):>9} {c['ms_per_frame']:>9.1f}"
        )
    return exits.OK


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
    from companion_lab.bench.vision import bench_ambiguity, bench_dart_ambiguity, bench_vision_range

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
    bc.add_argument("--n", type=positive_int, default=5, help="fused landings (default 5)")
    bc.add_argument("--seed", type=int, default=1, help="seed of the first draw")
    bc.add_argument(
        "--jobs",
        type=positive_int,
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
    be.add_argument("--n", type=positive_int, default=5000, help="calls timed per filter and estimator")
    be.set_defaults(func=cmd_bench_estimation)


def cmd_bench_link(args: argparse.Namespace) -> int:
    from companion_lab.bench.link import bench_link

    print(json.dumps(bench_link(seconds=args.seconds), indent=2))
    return 0


def register_bench_link(bsub: Any) -> None:
    """Add ``companion bench link``."""
    bl = bsub.add_parser("link", help="setpoint jitter and command latency over MAVLink against the sim vehicle")
    bl.add_argument("--seconds", type=float, default=3.0, help="stream duration per rate")
    bl.set_defaults(func=cmd_bench_link)


def cmd_bench_orders(args: argparse.Namespace) -> int:
    import asyncio

    from companion.cli.orders import serve_orders
    from companion_lab.bench.orders import report, run_orders_bench

    r = asyncio.run(run_orders_bench(serve_orders, tuple(args.large_mb), args.flood_hz, args.command_hz, args.flood_s))
    print(json.dumps(r, indent=2) if args.json else report(r))
    return 0 if r["delivered"] else 1


def register_bench_orders(bsub: Any) -> None:
    """Add ``companion bench orders`` (docs/orders.md#under-attack)."""
    bo = bsub.add_parser(
        "orders", help="a delivery flown while its order and command queryables are flooded and sent huge queries"
    )
    bo.add_argument(
        "--large-mb", type=int, nargs="*", default=[200, 200, 200, 200, 900], help="sizes of the large queries, MiB"
    )
    bo.add_argument("--flood-hz", type=float, default=500.0, help="hostile orders a second (default: %(default)s)")
    bo.add_argument("--command-hz", type=float, default=100.0, help="forged commands a second (default: %(default)s)")
    bo.add_argument("--flood-s", type=float, default=20.0, help="how long the flood lasts (default: %(default)s)")
    bo.add_argument("--json", action="store_true", help="print the figures as JSON")
    bo.set_defaults(func=cmd_bench_orders)


def register_bench_micro(bsub: Any) -> None:
    """Add ``companion bench ekf``, ``bench uwb``, ``bench vision`` and ``bench orders``."""
    register_bench_orders(bsub)
    bk = bsub.add_parser("ekf", help="microseconds per EKF predict and per update of each sensor")
    bk.add_argument("--n", type=positive_int, default=2000, help="calls timed per step")
    bk.set_defaults(func=cmd_bench_ekf)
    bu = bsub.add_parser("uwb", help="microseconds per TWR / TDoA multilateration solve")
    bu.add_argument("--n", type=positive_int, default=300, help="solves timed per method")
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
    bv.add_argument(
        "--conditions",
        action="store_true",
        help="detection rate and pose error per real-camera condition (motion blur, rolling shutter, auto-exposure "
        "steps, shadow, glare, low light, JPEG, all together) on the same rendered descent",
    )
    bv.add_argument("--json", action="store_true", help="print --range / --ambiguity / --conditions results as JSON")
    bv.set_defaults(func=cmd_bench_vision)


# ---------------------------------------------------------------------------- bench check
CHECK_APP_PARAMS = "sitl_short.toml"  # the pad in view from about 10 s: vision's share counts


def cmd_bench_check(args: argparse.Namespace) -> int:
    """Run the benches that carry targets (companion_lab.bench.targets) and fail when a figure is past its limit."""
    from companion_lab.bench.estimation import bench_ekf
    from companion_lab.bench.targets import BENCHES, judge
    from companion_lab.bench.vision import bench_vision

    only = [b.strip() for b in args.only.split(",")] if args.only else list(BENCHES)
    unknown = [b for b in only if b not in BENCHES]
    if unknown or not only:
        raise StartupError(
            f"--only {args.only!r}: expected a comma-separated subset of {', '.join(BENCHES)}", exits.BAD_INPUT
        )
    if not (args.app_duration_s > 0 and math.isfinite(args.app_duration_s)):
        raise StartupError(
            f"--app-duration-s {args.app_duration_s}: must be a positive number of seconds", exits.BAD_INPUT
        )
    results: dict[str, dict[str, Any]] = {}
    for bench in only:
        if bench == "ekf":
            results[bench] = dict(bench_ekf(args.ekf_n))
        elif bench == "vision":
            results[bench] = dict(bench_vision(args.vision_frames, 0))
        else:
            from companion_lab.bench.app import bench_app

            results[bench] = bench_app(args.app_duration_s, "ardupilot", [shipped_params_path(CHECK_APP_PARAMS)])
    verdicts = [v for bench in only for v in judge(bench, results[bench])]
    failed = [v for v in verdicts if not v.ok]
    if args.json:
        print(
            json.dumps(
                {
                    "targets": [
                        {
                            "bench": v.target.bench,
                            "figure": v.target.key,
                            "limit": v.target.limit,
                            "unit": v.target.unit,
                            "measured": v.measured,
                            "ok": v.ok,
                        }
                        for v in verdicts
                    ],
                    "failed": len(failed),
                },
                indent=2,
            )
        )
    else:
        print(f"bench check: {len(verdicts)} targets of {', '.join(only)} (load average {os.getloadavg()[0]:.2f})")
        for v in verdicts:
            print("  " + v.line())
        print(f"  {len(failed)} past their limit" if failed else "  every figure within its target")
    return exits.FAILED if failed else exits.OK


def register_bench_check(bsub: Any) -> None:
    bc = bsub.add_parser(
        "check", help="run the benches with targets (ekf, vision, app) and fail when a figure is past its target"
    )
    bc.add_argument("--only", help="comma-separated benches to run (default: ekf,vision,app)")
    bc.add_argument("--ekf-n", type=positive_int, default=2000, help="calls timed per EKF step")
    bc.add_argument("--vision-frames", type=positive_int, default=120, help="rendered frames for the vision bench")
    bc.add_argument(
        "--app-duration-s", type=float, default=45.0, help=f"seconds of the app bench on params/{CHECK_APP_PARAMS}"
    )
    bc.add_argument("--json", action="store_true", help="print the verdicts as JSON")
    bc.set_defaults(func=cmd_bench_check)


# ---------------------------------------------------------------------------- bench app
def _ok(flag: bool) -> str:
    return "ok" if flag else "NOT MET"


def print_app_report(r: dict[str, Any]) -> None:
    cpu = r["cpu"]
    print(f"bench app: {r['app']} over {r['backend']} MAVLink, {r['duration_s']:.1f} s real time")
    print(f"  mission phase at the end: {r['mission_phase_at_end']}")
    print(
        f"  CPU (% of one core): process {cpu['process_total_pct']:.1f}, simulator taken out "
        f"{sum(cpu['excluded_simulator_pct'].values()):.1f}, logging process added "
        f"{cpu['logging_process_pct']:.1f} -> companion {cpu['companion_total_pct']:.1f}"
    )
    for task, v in cpu["tasks_pct"].items():
        print(f"    {task:<16} {v:6.2f}")
    child_rss = r["logging_process_peak_rss_mib"]
    print(f"  peak RSS: {r['peak_rss_mib']:.0f} MiB" + (f" (logging process {child_rss:.0f} MiB)" if child_rss else ""))
    cam = r["camera"]
    print(
        f"  camera: {cam['frames_processed']} frames processed "
        f"({cam['frames_with_detection']} with the pad detected), "
        f"capture latency {cam['capture_latency_ms']:.0f} ms" + (f", read by {cam['read']}" if cam.get("read") else "")
    )
    for key in (
        "detect_ms",
        "exposure_to_setpoint_ms",
        "exposure_to_setpoint_detected_ms",
        "exposure_to_setpoint_fused_ms",
    ):
        p = r.get(key, {"n": 0})
        if p["n"]:
            print(f"  {key:<34} n={p['n']:<5} p50 {p['p50']:7.2f}  p99 {p['p99']:7.2f}  max {p['max']:7.2f}")
        else:
            print(f"  {key:<34} n=0")
    for key, p in r["stages_ms"].items():
        if p["n"]:
            print(f"    stage {key:<28} p50 {p['p50']:7.2f}  p99 {p['p99']:7.2f}  max {p['max']:7.2f}")
    print("  CPU by thread (% of one core):")
    for name, v in r["cpu"]["threads_pct"].items():
        print(f"    {name:<40} {v:6.2f}")
    for lp in r["loops"]:
        print(f"  loop {lp['loop']:<22} ticks {lp['ticks']:6d}  overruns {lp['overruns']}")
    print("  targets:")
    for name, t in r["targets"].items():
        on = f" ({t['judged_on']})" if "judged_on" in t else ""
        print(f"    {name:<30} {t['target']:<60} measured {t['measured']}{on}  {_ok(t['ok'])}")
    _print_cap_lines(r)
    print("  method: " + cpu["method"].replace("\n", " "))


def _print_cap_lines(r: dict[str, Any]) -> None:
    """The delivery run's budget figures (with or without --cpu-cap)."""
    if "setpoint_stream" not in r:
        return
    cap = r.get("cpu_cap")
    if cap:
        sim = "inside the cap" if cap["simulator_inside_the_cap"] else "outside the cap"
        print(
            f"  CPU cap: {cap['cgroup']}; simulator {sim}; throttled in {cap['throttled_periods']} of "
            f"{cap['periods']} periods ({cap['throttled_ms']:.0f} ms); logging process: {cap['logging_process']}"
        )
    ss = r["setpoint_stream"]
    trips = ", ".join(f"{k} {'TRIPS' if v else 'holds'}" for k, v in ss["would_trip"].items())
    print(
        f"  setpoint stream: {ss['setpoints']} sent, largest gap {ss['max_gap_ms']} ms, "
        f"{ss['gaps_over_100_ms']} gaps > 100 ms: {trips}; sim vehicle failsafes: {len(r['offboard_failsafes'])}"
    )
    cam = r["camera"]
    print(
        f"  guidance overruns {r['guidance_overruns_pct']:.2f} % (target < 1 %); camera frames dropped "
        f"{cam['frames_dropped']} ({cam['frames_dropped_pct']:.1f} % of those readable; "
        f"{cam['frames_paced']} wake-ups paced by the vision budget {r['vision_cpu_budget']:g} core)"
    )
    if r.get("realtime"):
        print(f"  runtime.realtime_priority {r['realtime_priority']}: {r['realtime']}")
    err = r.get("pad_landing_error_m")
    print(
        f"  delivered: {r['delivered']}; pad landing error "
        + (f"{100 * err:.1f} cm (truth)" if err is not None else "none (no touchdown at the pad)")
    )


def cmd_bench_app(args: argparse.Namespace) -> int:
    from companion_lab.bench.app import BenchInputError, BenchStartError, bench_app, bench_dart
    from companion_lab.cpu_cap import CpuCapError, parse_cap

    cap: float | None = None
    if args.cpu_cap is not None:
        if args.dart:
            raise StartupError("--cpu-cap: the Dart bench has no CPU cap; drop --dart or --cpu-cap", exits.BAD_INPUT)
        try:
            cap = parse_cap(args.cpu_cap)
        except CpuCapError as err:
            raise StartupError(str(err), exits.BAD_INPUT) from None
    if cap is not None and args.realtime_priority:
        raise StartupError(
            "--cpu-cap with --realtime-priority: real-time threads are not held by the cap's CFS quota (cgroup v1 "
            "gives them cpu.rt_runtime_us instead, none in the cap's group); drop one of them",
            exits.BAD_INPUT,
        )
    if not (args.duration_s > 0 and math.isfinite(args.duration_s)):
        raise StartupError(f"--duration-s {args.duration_s}: must be a positive number of seconds", exits.BAD_INPUT)
    if args.dart:
        if args.params:
            raise StartupError(
                "--params: the Dart bench flies the shipped Dart parameters; drop --params", exits.BAD_INPUT
            )
        if args.backend != "ardupilot":
            raise StartupError(
                f"--backend {args.backend} with --dart: the Dart bench runs the ArduPilot RC-override path only "
                "(over PX4 the cyber-pilot did not engage in this bench); use --backend ardupilot",
                exits.BAD_INPUT,
            )
        r = bench_dart(args.duration_s, args.backend)
    else:
        try:
            r = bench_app(
                args.duration_s,
                args.backend,
                [Path(p) for p in args.params] if args.params else None,
                cap,
                logging_core=not args.cap_logging_with_app,
                vision_cpu_budget=args.vision_cpu_budget,
                vision_thread_nice=args.vision_thread_nice,
                realtime_priority=args.realtime_priority,
                cap_period_us=None if args.cpu_cap_period_ms is None else round(args.cpu_cap_period_ms * 1000),
            )
        except CpuCapError as err:
            raise StartupError(str(err), exits.FAILED) from None
        except BenchInputError as err:
            raise StartupError(str(err), exits.BAD_INPUT) from None
        except BenchStartError as err:
            raise StartupError(str(err), exits.FAILED) from None
    if args.json:
        print(json.dumps(r, indent=2))
    else:
        print_app_report(r)
    return exits.OK


def register_bench_app(bench_subparsers: Any) -> None:
    """Add ``app`` to the ``bench`` subcommands."""
    p = bench_subparsers.add_parser(
        "app", help="the whole delivery app in real time against the MAVLink sim vehicle: CPU per task, latency"
    )
    p.add_argument("--duration-s", type=float, default=60.0, help="seconds of real time")
    p.add_argument("--backend", choices=("ardupilot", "px4"), default="ardupilot", help="MAVLink backend")
    p.add_argument(
        "--params",
        action="append",
        help="parameter file; again for an overlay, later files override earlier ones, e.g. params/slow_board.toml "
        "(default: the shipped delivery_paper.toml)",
    )
    p.add_argument(
        "--dart",
        action="store_true",
        help="bench the Dart shell (IMU 200 Hz, vision 30 Hz, control 22 Hz, commands 44 Hz) against the Dart link sim",
    )
    p.add_argument(
        "--cpu-cap",
        metavar="FRACTION",
        help="run the companion (not the simulator) in a cgroup capped to this share of one core: "
        "'pi4' (one Raspberry Pi 4 core, see docs/cpu-budget.md), a fraction (0.25) or a percentage (25%%) "
        "(default: no cap)",
    )
    p.add_argument(
        "--cpu-cap-period-ms",
        type=float,
        metavar="MS",
        help="with --cpu-cap: the CFS period (default 10 ms: a capped app stalls at most the rest of a period; "
        "the kernel's usual 100 ms stalls it up to 87 ms at the pi4 cap)",
    )
    p.add_argument(
        "--cap-logging-with-app",
        action="store_true",
        help="with --cpu-cap: the logging process shares the app's cap (default: its own, the same size: another core)",
    )
    p.add_argument(
        "--vision-cpu-budget",
        type=float,
        metavar="CORE",
        help="runtime.vision_cpu_budget for this run: the share of one core the detector may use (0: every frame; "
        "default: the parameter file's)",
    )
    p.add_argument(
        "--vision-thread-nice",
        type=int,
        metavar="N",
        help="runtime.vision_thread_nice for this run: the detector thread's nice value (0-19; default: the "
        "parameter file's)",
    )
    p.add_argument(
        "--realtime-priority",
        type=int,
        metavar="N",
        help="runtime.realtime_priority for this run: SCHED_RR priority of the loop's thread, the detector's one "
        "lower (1-98, 0: normal policy; default: the parameter file's)",
    )
    p.add_argument("--json", action="store_true", help="print the report as JSON")
    p.set_defaults(func=cmd_bench_app)
