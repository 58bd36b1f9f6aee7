"""Every `companion COMMAND [SUBCOMMAND]` the README and docs/ name is one the CLI has (docs/
simulation.md named a `companion logs show` that never existed)."""

from __future__ import annotations

import argparse
import re
from pathlib import Path

from companion.cli.main import build_parser

ROOT = Path(__file__).resolve().parents[1]
NAMED = re.compile(r"`companion ([a-z][a-z-]*)(?: ([a-z][a-z-]*))?")


def _choices(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    for action in parser._actions:  # argparse keeps subcommands only there
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def test_every_command_the_docs_name_exists():
    parser, failed = build_parser()
    assert not failed
    commands = _choices(parser)
    missing = []
    for page in [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]:
        for n, line in enumerate(page.read_text(encoding="utf-8").splitlines(), 1):
            for cmd, sub in NAMED.findall(line):
                if cmd not in commands:
                    missing.append(f"{page.relative_to(ROOT)}:{n}: companion {cmd}")
                    continue
                subs = _choices(commands[cmd])
                if subs and sub and sub not in subs and not sub.startswith("-"):
                    missing.append(f"{page.relative_to(ROOT)}:{n}: companion {cmd} {sub}")
    assert not missing, "\n".join(missing)
