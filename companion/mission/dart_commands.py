"""CLI subcommand ``companion campaign dart``: the Dart hover campaign on the embedded simulator.

``register(subparsers)`` adds a ``campaign`` command with a ``dart`` action to the application's
argparse subparsers. The handler prints a table like dart Tables 1-2: the corrected sample
standard deviation (dart eq 22) of the position error per estimator and axis.
"""

from __future__ import annotations

import argparse
import json
import logging
from typing import Any

log = logging.getLogger(__name__)


def _cmd_campaign_dart(args: argparse.Namespace) -> int:
    from rich.console import Console
    from rich.progress import Progress

    from companion.mission.dart import DartParamsError

    try:
        from companion_sitl.dart_campaign import campaign_table, resolve_estimators, run_dart_campaign
    except ImportError as exc:  # the simulator ships with the distribution; a stripped install may lack it
        print(f"error: the embedded simulator is not installed: {exc}")
        return 2
    try:
        names = resolve_estimators(args.estimator)
    except ValueError as exc:
        print(f"error: {exc}")
        return 2
    console = Console()
    if not console.is_terminal:  # piped: wide enough for the whole table
        console = Console(width=max(console.width, 120))
    try:
        with Progress(console=console, transient=True, disable=args.quiet) as bar:
            task = bar.add_task("dart hover campaign", total=len(names) * args.n)

            def progress(name: str, k: int) -> None:
                bar.update(task, advance=1, description=f"{name} run {k}/{args.n}")

            result = run_dart_campaign(
                names, args.n, args.seed, duration_s=args.duration, settle_s=args.settle,
                params=args.params, progress=progress,
            )
    except DartParamsError as exc:
        print(f"error: bad parameters: {exc}")
        return 2
    except ValueError as exc:
        print(f"error: {exc}")
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
    d.add_argument("--estimator", default="all",
                   help="all, or comma-separated FCF-CF, FCF-MF, SCF-MF-2DOF, SCF-MF-3DOF (default: all)")
    d.add_argument("--n", type=int, default=3, help="runs per estimator (default 3)")
    d.add_argument("--seed", type=int, default=0, help="seed of the first run (run k uses seed + k)")
    d.add_argument("--duration", type=float, default=25.0, help="simulated hover per run, s (default 25)")
    d.add_argument("--settle", type=float, default=8.0, help="left out at the start of each run, s (default 8)")
    d.add_argument("--params", help="Dart parameter file (default: the shipped params/dart_hover.toml)")
    d.add_argument("--json", help="also write the result as JSON to this file")
    d.add_argument("--quiet", action="store_true", help="no progress bar")
    d.set_defaults(func=_cmd_campaign_dart)
