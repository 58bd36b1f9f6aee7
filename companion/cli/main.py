"""The ``companion`` command line."""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from collections.abc import Callable
from typing import Any

from companion import __version__
from companion.cli import bench, bench_dropzone, campaign, demo, exits, params, plugins
from companion.cli.exits import StartupError
from companion.cli.helptext import show_defaults
from companion.config import ConfigError

log = logging.getLogger(__name__)

# Capability modules that add their own sub-commands: module path -> what it provides.
COMMAND_MODULES: tuple[str, ...] = (
    "companion.cli.vision",
    "companion.cli.telemetry",
    "companion.cli.fly",
    "companion.cli.orders",
    "companion.cli.preflight",
    "companion.cli.logs",
    "companion.cli.dart",
    "companion.cli.signing",
    "companion.cli.plan",
)


def build_parser() -> tuple[argparse.ArgumentParser, list[str]]:
    parser = argparse.ArgumentParser(prog="companion", description=__doc__)
    parser.add_argument("--version", action="version", version=f"companion {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output (-vv for debug)")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    demo.register_demo(sub)
    bench_p = sub.add_parser("bench", help="benchmarks (ratios measured in one run)")
    bsub = bench_p.add_subparsers(dest="bench", metavar="WHAT", required=True)
    bench.register_bench(bsub)
    campaign_p = sub.add_parser("campaign", help="repeated simulated experiments with summary statistics")
    csub = campaign_p.add_subparsers(dest="campaign", metavar="WHAT", required=True)
    campaign.register_campaign(csub)
    try:
        importlib.import_module("companion.cli.dart").register_campaign(csub)
    except ImportError as err:
        log.error("campaign dart unavailable: %s", err)
    for mod in ("companion.cli.telemetry", "companion.cli.signing"):
        try:
            importlib.import_module(mod).register_bench(bsub)
        except ImportError as err:
            log.error("bench from %s unavailable: %s", mod, err)
    bench.register_bench_link(bsub)
    bench.register_bench_micro(bsub)
    bench.register_bench_app(bsub)
    bench.register_bench_check(bsub)
    bench_dropzone.register_bench_dropzone(bsub)
    params.register(sub)
    plugins.register(sub)

    failed = []
    for mod in COMMAND_MODULES:
        try:
            register: Callable[[Any], None] = importlib.import_module(mod).register
            register(sub)
        except Exception as err:  # a broken capability must not take the CLI down
            failed.append(f"{mod}: {type(err).__name__}: {err}")
    show_defaults(parser)
    return parser, failed


def main(argv: list[str] | None = None) -> int:
    parser, failed = build_parser()
    args = parser.parse_args(argv)
    level = logging.WARNING if args.verbose == 0 else logging.INFO if args.verbose == 1 else logging.DEBUG
    logging.basicConfig(level=level, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    for f in failed:
        log.error("command module failed to load: %s", f)
    if not getattr(args, "func", None):
        parser.print_help()
        return exits.BAD_INPUT
    try:
        return int(args.func(args))
    except ConfigError as err:  # one line: the file, then each key, value and rule
        print(f"companion {args.command}: bad configuration: {err.source}: {'; '.join(err.problems)}", file=sys.stderr)
        return exits.BAD_INPUT
    except StartupError as err:
        print(f"companion {args.command}: {err}", file=sys.stderr)
        return err.code
    except KeyboardInterrupt:
        print(f"companion {args.command}: interrupted", file=sys.stderr)
        return exits.INTERRUPTED
    except BrokenPipeError:
        # the reader closed the pipe (`companion params show | head`): end quietly, and keep the
        # interpreter's final flush from raising again (the recipe of Python's signal docs)
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return exits.FAILED


if __name__ == "__main__":
    sys.exit(main())
