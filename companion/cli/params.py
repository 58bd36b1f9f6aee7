"""CLI of the parameter files: ``params show`` and ``params check``."""

from __future__ import annotations

import argparse
import sys
from typing import Any

from companion.config import CompanionConfig, ConfigError, load_config


def cmd_params_show(args: argparse.Namespace) -> int:
    from companion.config import describe_parameters

    cfg = load_config(args.file) if args.file else CompanionConfig()
    for line in describe_parameters(cfg):
        print(line)
    return 0


def cmd_params_check(args: argparse.Namespace) -> int:
    bad = 0
    for f in args.files:
        try:
            load_config(f)
            print(f"{f}: OK")
        except ConfigError as err:
            bad += 1
            print(f"{err.source}:", file=sys.stderr)
            for p in err.problems:
                print(f"  {p}", file=sys.stderr)
    return 1 if bad else 0


def register(sub: Any) -> None:
    """Add ``companion params``."""
    params = sub.add_parser("params", help="show or check parameter files")
    psub = params.add_subparsers(dest="params_cmd", metavar="ACTION", required=True)
    ps = psub.add_parser("show", help="every parameter with its unit, limits, description and value")
    ps.add_argument("file", nargs="?")
    ps.set_defaults(func=cmd_params_show)
    pc = psub.add_parser("check", help="validate parameter files")
    pc.add_argument("files", nargs="+")
    pc.set_defaults(func=cmd_params_check)
