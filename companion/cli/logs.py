"""CLI commands of the flight logs: ``replay RUN_DIR`` and ``report RUN_DIR``."""

from __future__ import annotations

import argparse
import logging
import sys
from typing import Any

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    """Add ``replay`` and ``report`` to the CLI's subparsers."""
    rp = subparsers.add_parser(
        "replay",
        help="re-run estimation and guidance over a recorded run folder; check the estimates are bit for bit the same",
    )
    rp.add_argument("run_dir", metavar="RUN_DIR", help="run folder written by `companion demo` or `companion fly`")
    rp.add_argument("--out", help="where the replayed ekf.csv, guidance.csv, events.csv go (default RUN_DIR/replay)")
    rp.set_defaults(func=cmd_replay)
    rep = subparsers.add_parser("report", help="PNG figures of a run folder, like the papers' figures")
    rep.add_argument("run_dir", metavar="RUN_DIR", help="run folder (a demo or fly run, a landing or Dart campaign)")
    rep.add_argument("--out", help="folder for the PNGs (default RUN_DIR)")
    rep.set_defaults(func=cmd_report)


def cmd_replay(args: argparse.Namespace) -> int:
    from companion.delivery.replay import replay_run
    from companion.flightlog.reader import LogFormatError

    try:
        result = replay_run(args.run_dir, args.out)
    except LogFormatError as err:
        print(f"companion replay: {err}", file=sys.stderr)
        return 2
    for line in result.lines():
        print(line)
    return 0 if result.identical else 1


def cmd_report(args: argparse.Namespace) -> int:
    from companion.flightlog.reader import LogFormatError
    from companion.flightlog.report import make_report
    from companion_lab.campaign_output import CAMPAIGN_FIGURES

    try:
        figures = make_report(args.run_dir, args.out, extra=CAMPAIGN_FIGURES)
    except LogFormatError as err:
        print(f"companion report: {err}", file=sys.stderr)
        return 2
    width = max(len(f.title) for f in figures)
    for f in figures:
        print(f"  {f.title:<{width}}  {f.path if f.path is not None else 'skipped: ' + f.skipped}")
    written = [f for f in figures if f.path is not None]
    print(f"{len(written)} figure(s) written, {len(figures) - len(written)} skipped")
    return 0 if written else 1
