"""``companion campaign landing --faults``: the fault campaign of the safety contract
(docs/companion-death.md#a-fault-campaign), on the MAVLink sim vehicle in real time."""

from __future__ import annotations

import argparse
import json
import sys
import time

from companion.cli import exits
from companion.cli.args import RESULTS_MIN_BYTES, output_folder


def cmd_campaign_faults(args: argparse.Namespace) -> int:
    """``campaign landing --faults``: the fault campaign on the MAVLink sim vehicle, in real time."""
    from rich.table import Table

    from companion.cli.console import make_console
    from companion_lab.fault_campaign import contract_broken, parse_faults, run_fault_campaign

    other = [
        flag
        for flag, given in (
            ("--autopilot", args.autopilot),
            ("--cluster", args.cluster),
            ("--jobs", args.jobs is not None),
            ("--variants", args.variants),
            ("--failures", args.failures),
            ("--weather", args.weather),
            ("--profile", args.profile != "ideal"),
        )
        if given
    ]
    if other:
        print(f"companion campaign landing: --faults and {', '.join(other)} exclude each other", file=sys.stderr)
        return exits.BAD_INPUT
    try:
        faults = parse_faults(args.faults)
    except ValueError as err:
        print(f"companion campaign landing: --faults: {err}", file=sys.stderr)
        return exits.BAD_INPUT
    out = output_folder(args.out, time.strftime("faults-%Y%m%d-%H%M%S"), RESULTS_MIN_BYTES)

    def on_progress(fault: str, done: int, total: int) -> None:
        if not args.quiet:
            print(f"{done} of {total} landings flown ({fault})", file=sys.stderr)

    result = run_fault_campaign(args.n, args.seed, faults, args.params, on_progress)
    path = out / "fault_campaign.json"
    path.write_text(json.dumps(result, indent=1, default=lambda o: None))
    table = Table(title=f"{args.n} landings per fault, seed {args.seed}, MAVLink sim vehicle in real time")
    columns = ("fault", "landings", "off the pad", "on the pad", "failsafe reached", "failsafe unasked", "lost")
    for col in columns:
        table.add_column(col, justify="right" if col != "fault" else "left")
    for f, s in result["summary"].items():
        table.add_row(
            f,
            f"{s['landings']} ({s['dialects']['ardupilot']} ArduPilot, {s['dialects']['px4']} PX4)",
            str(s["released_off_pad"]),
            str(s["released_on_pad"]),
            f"{s['failsafe_reached']} of {s['failsafe_required']}",
            str(s["failsafe_unrequired"]),
            str(s["lost"]),
        )
    console = make_console()
    console.print(table)
    console.print(f"written: {path}")
    broken = contract_broken(result)
    for line in broken:
        print(f"companion campaign landing: {line}", file=sys.stderr)
    return exits.FAILED if broken else 0
