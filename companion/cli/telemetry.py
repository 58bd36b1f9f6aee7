"""CLI of the telemetry: the ground station and its benchmark.

- ``register(subparsers)`` adds ``companion ground``:
  ``companion ground [--listen EP]... [--connect EP]... [--router] [--out DIR] [--duration S]
  [--zenoh-config FILE] [--no-multicast]``
- ``register_bench(bench_subparsers)`` adds ``companion bench telemetry``:
  ``companion bench telemetry [--vehicles 20 | --vehicles 10,50,100] [--rate-hz 50]
  [--duration-s 5] [--router] [--json]``
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from dataclasses import replace
from pathlib import Path
from typing import Any

from companion.cli import exits
from companion.telemetry.session import SettingsError, ZenohSettings, load_settings

DEFAULT_ROUTER_LISTEN = "tcp/0.0.0.0:7447"


def register(subparsers: Any) -> None:
    """Add the ``ground`` subcommand."""
    p = subparsers.add_parser(
        "ground",
        help="ground station: live fleet table over Zenoh, recording everything received",
        description="Subscribe to companion/** and show every vehicle in a live table; "
        "record every message as JSON lines under --out.",
    )
    p.add_argument(
        "--listen",
        action="append",
        metavar="EP",
        help="listen endpoint, e.g. tcp/0.0.0.0:7447, repeatable (default: none, or the session file's)",
    )
    p.add_argument(
        "--connect",
        action="append",
        metavar="EP",
        help="connect endpoint, e.g. tcp/10.0.0.2:7447, repeatable (default: none, or the session file's)",
    )
    p.add_argument(
        "--router",
        action="store_true",
        help=f"run as the fleet's Zenoh router (listens on {DEFAULT_ROUTER_LISTEN} unless --listen)",
    )
    p.add_argument(
        "--out", metavar="DIR", help="record to this folder, JSON lines per vehicle and topic (default: not recording)"
    )
    p.add_argument("--duration", type=float, metavar="S", help="stop after S seconds (default: until Ctrl-C)")
    p.add_argument(
        "--zenoh-config",
        metavar="FILE",
        help="TOML file with a [zenoh] table (params/zenoh_*.toml); flags override it (default: Zenoh's defaults)",
    )
    p.add_argument("--no-multicast", action="store_true", help="disable multicast scouting")
    p.add_argument("--refresh", type=float, default=4.0, help="table refreshes per second")
    p.add_argument(
        "--foxglove",
        action="store_true",
        help="also serve the live fleet over the Foxglove WebSocket protocol (open ws://HOST:PORT in Foxglove)",
    )
    p.add_argument(
        "--foxglove-port", type=int, default=8765, metavar="N", help="Foxglove WebSocket port (default 8765; 0: any)"
    )
    p.add_argument(
        "--foxglove-host",
        default="127.0.0.1",
        metavar="ADDR",
        help="address the Foxglove WebSocket server binds (default 127.0.0.1; 0.0.0.0 for other machines)",
    )
    p.set_defaults(func=cmd_ground)


def register_bench(bench_subparsers: Any) -> None:
    """Add ``telemetry`` to the ``bench`` subcommands."""
    p = bench_subparsers.add_parser("telemetry", help="N vehicles x rate to one ground station over loopback Zenoh")
    p.add_argument(
        "--vehicles",
        type=vehicle_counts,
        default="20",  # argparse applies vehicle_counts to a string default
        metavar="N[,N...]",
        help="simulated vehicles publishing; a comma list runs each fleet size in turn (default: 20)",
    )
    p.add_argument(
        "--rate-hz", "--rate", dest="rate", type=float, default=50.0, help="state messages per second per vehicle"
    )
    p.add_argument("--duration-s", "--duration", dest="duration", type=float, default=5.0, help="seconds of publishing")
    p.add_argument(
        "--router",
        action="store_true",
        help="route everything through a Zenoh router process (vehicles and ground are its clients)",
    )
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.set_defaults(func=cmd_bench_telemetry)


def vehicle_counts(text: str) -> tuple[int, ...]:
    """``--vehicles``: one fleet size or a comma list, each in [1, 200]."""
    out: list[int] = []
    for part in text.split(","):
        try:
            n = int(part.strip())
        except ValueError:
            raise argparse.ArgumentTypeError(
                f"--vehicles: {part.strip()!r} in {text!r} is not an integer (expected e.g. 20 or 10,50,100)"
            ) from None
        if not 1 <= n <= 200:
            raise argparse.ArgumentTypeError(f"--vehicles: {n} in {text!r} is outside [1, 200]")
        out.append(n)
    return tuple(out)


def ground_settings(args: argparse.Namespace) -> ZenohSettings:
    """The ground's Zenoh settings from the CLI flags (and optional config file); ``companion ground``
    and ``companion order`` share them (``--router`` only the former)."""
    base = load_settings(args.zenoh_config) if args.zenoh_config else ZenohSettings()
    changes: dict[str, Any] = {}
    if args.listen:
        changes["listen"] = tuple(args.listen)
    if args.connect:
        changes["connect"] = tuple(args.connect)
    if args.no_multicast:
        changes["multicast_scouting"] = False
    if getattr(args, "router", False):
        changes["mode"] = "router"
        if not (args.listen or base.listen):
            changes["listen"] = (DEFAULT_ROUTER_LISTEN,)
    return replace(base, **changes)


def cmd_ground(args: argparse.Namespace) -> int:
    from companion.cli.console import make_console
    from companion.telemetry.ground import GroundStation, run_live

    try:
        settings = ground_settings(args)
    except SettingsError as e:
        print(f"companion ground: {e}", file=sys.stderr)
        return 2
    if args.duration is not None and not (args.duration > 0 and math.isfinite(args.duration)):
        print("companion ground: --duration must be > 0", file=sys.stderr)
        return 2
    bridge = None
    if args.foxglove:
        from companion.telemetry.foxglove_bridge import FoxgloveBridge

        if not 0 <= args.foxglove_port <= 65535:
            print(f"companion ground: --foxglove-port {args.foxglove_port}: expected 0..65535", file=sys.stderr)
            return 2
        try:
            bridge = FoxgloveBridge(host=args.foxglove_host, port=args.foxglove_port).start()
        except Exception as e:  # port in use, bad address
            print(
                f"companion ground: cannot start the Foxglove WebSocket server on "
                f"{args.foxglove_host}:{args.foxglove_port}: {e}",
                file=sys.stderr,
            )
            return 1
    console = make_console()
    station = GroundStation(
        settings,
        out_dir=Path(args.out) if args.out else None,
        listener=bridge.on_envelope if bridge is not None else None,
    )
    try:
        station.start()
    except Exception as e:  # zenoh.ZError: bad endpoint, port in use, router unreachable
        print(f"companion ground: cannot open the Zenoh session: {e}", file=sys.stderr)
        if bridge is not None:
            bridge.stop()
        return 1
    where = ", ".join(settings.listen or ()) or "-"
    # from here on the session is open: a Ctrl-C anywhere (even while the banner prints) must still
    # close it, or its threads keep the process alive after the interrupt
    try:
        console.print(
            f"ground station: mode {settings.mode}, listen {where}, "
            f"connect {', '.join(settings.all_connect_endpoints) or '-'}, "
            f"recording to {args.out or '(not recording)'}"
        )
        if bridge is not None:
            console.print(
                f"Foxglove: open ws://{args.foxglove_host}:{bridge.port} (Open connection -> Foxglove WebSocket)"
            )
        interrupted = run_live(station, duration_s=args.duration, refresh_hz=args.refresh, console=console)
    except KeyboardInterrupt:  # before the live table was up
        interrupted = True
    finally:
        station.stop()
        if bridge is not None:
            bridge.stop()
    c = station.counters()
    console.print()
    console.print(f"received {c.received}, lost {c.lost}, malformed {c.malformed}, recorded {c.recorded}")
    return exits.INTERRUPTED if interrupted else exits.OK  # Ctrl-C: 130, as every command (exits.py)


def format_bench_result(result: dict[str, Any]) -> str:
    """A short human-readable report of :func:`bench_telemetry`'s result."""
    r = result
    target_ok = r["lost"] == 0 and r["latency_p99_ms"] <= 10.0
    return "\n".join(
        [
            f"telemetry bench ({r.get('topology', 'direct')}): {r['vehicles']} vehicles x {r['rate_hz']:g} Hz"
            f" for {r['duration_s']:g} s",
            f"  submitted {r['submitted']}, delivered {r['delivered']}, lost {r['lost']}"
            f" (by sequence number {r['lost_by_seq']}, {r['vehicles_with_loss']} vehicles with loss)"
            f" (superseded {r['superseded']}, late submissions {r['late_submissions']})",
            f"  latency p50 {r['latency_p50_ms']:.2f} ms, p99 {r['latency_p99_ms']:.2f} ms,"
            f" max {r['latency_max_ms']:.2f} ms",
            f"  CPU {r['cpu_us_per_msg']:.0f} us/msg ("
            + (
                f"bench process + router, the router {r['router_cpu_us_per_msg']:.0f}"
                if r.get("router_cpu_us_per_msg") is not None
                else "whole process"
            )
            + "), "
            f"{r['cpu_pct_of_one_core']:.0f} % of one core, {r['throughput_msg_s']:.0f} msg/s",
            f"  target (0 lost, p99 <= 10 ms): {'MET' if target_ok else 'NOT MET'}",
        ]
    )


def format_fleet_result(fleet: dict[str, Any]) -> str:
    """:func:`bench_fleet`'s result as a table, one row per fleet size."""
    lines = [
        f"telemetry fleet bench ({fleet['topology']}): {fleet['rate_hz']:g} Hz per vehicle, "
        f"{fleet['duration_s']:g} s per fleet size",
        f"{'vehicles':>8} {'msgs':>7} {'lost':>5} {'lost/seq':>8} {'dup':>4} {'p50 ms':>7} {'p99 ms':>7} "
        f"{'max ms':>7} {'us/msg':>7} {'router':>7} {'core %':>7} {'late':>5}",
    ]
    for r in fleet["runs"]:
        router = r["router_cpu_us_per_msg"]
        lines.append(
            f"{r['vehicles']:>8} {r['delivered']:>7} {r['lost']:>5} {r['lost_by_seq']:>8} {r['duplicates']:>4} "
            f"{r['latency_p50_ms']:>7.2f} {r['latency_p99_ms']:>7.2f} {r['latency_max_ms']:>7.2f} "
            f"{r['cpu_us_per_msg']:>7.0f} {'-' if router is None else f'{router:.0f}':>7} "
            f"{r['cpu_pct_of_one_core']:>7.0f} {r['late_submissions']:>5}"
        )
    ratio = fleet["cpu_per_msg_ratio_largest_to_smallest"]
    if ratio is not None:
        first, last = fleet["runs"][0], fleet["runs"][-1]
        lines.append(f"CPU per message, {last['vehicles']} vs {first['vehicles']} vehicles: x{ratio:.2f}")
    lines.append(
        "lost: submitted - delivered (includes samples superseded in the keep-newest slot before sending); "
        "lost/seq: sequence numbers published but never received; us/msg: CPU of every process "
        "(vehicles + ground, and the router) per delivered message; router: the router process's share; "
        "core %: CPU / wall time; late: submissions more than one period behind schedule"
    )
    return "\n".join(lines)


def cmd_bench_telemetry(args: argparse.Namespace) -> int:
    from companion_lab.bench.telemetry import bench_fleet, bench_telemetry

    counts: tuple[int, ...] = args.vehicles
    try:
        if len(counts) == 1:
            result = bench_telemetry(counts[0], args.rate, args.duration, via_router=args.router)
            text = format_bench_result(result)
        else:
            result = bench_fleet(counts, args.rate, args.duration, via_router=args.router)
            text = format_fleet_result(result)
    except ValueError as e:
        print(f"companion bench telemetry: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result, indent=2) if args.json else text)
    return 0
