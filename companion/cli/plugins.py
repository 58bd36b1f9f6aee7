"""CLI of the driver plugins: ``plugins``."""

from __future__ import annotations

import argparse
from typing import Any


def cmd_plugins(args: argparse.Namespace) -> int:
    from companion.plugin_api import API_VERSION, GROUPS, discover

    bad = 0
    print(f"plugin API version {API_VERSION}")
    for group in GROUPS:
        _, report = discover(group)
        print(f"{group}:")
        if not report:
            print("  (none installed)")
        for r in report:
            state = "ok" if r.ok else f"FAILED: {r.error}"
            bad += not r.ok
            print(f"  {r.name:<14} {r.target:<55} [{r.distribution}] {state}")
    return 1 if bad and args.strict else 0


def register(sub: Any) -> None:
    """Add ``companion plugins``."""
    pl = sub.add_parser("plugins", help="list installed driver plugins (cameras, UWB, payloads)")
    pl.add_argument("--strict", action="store_true", help="exit 1 if any plugin failed to load")
    pl.set_defaults(func=cmd_plugins)
