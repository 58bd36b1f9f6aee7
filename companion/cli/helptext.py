"""Every option's help shows its default: one formatter for every parser of the command line."""

from __future__ import annotations

import argparse
from collections.abc import Iterator


class DefaultsHelpFormatter(argparse.HelpFormatter):
    """Appends ``(default: X)`` to an option's help unless the help already names its default,
    or the default is no value (None, False for a flag, or suppressed)."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if "%(default)" in text or "default" in text.lower():
            return text
        if default is None or default is False or default is argparse.SUPPRESS:
            return text
        if action.option_strings or action.nargs in (argparse.OPTIONAL, argparse.ZERO_OR_MORE):
            return f"{text} (default: %(default)s)"
        return text


def all_parsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, argparse.ArgumentParser]]:
    """The parser and every sub-command parser under it, with the command that reaches it."""
    yield parser.prog, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in dict.fromkeys(action.choices.values()):  # aliases share a parser
                yield from all_parsers(sub)


def show_defaults(parser: argparse.ArgumentParser) -> None:
    """Give every parser under ``parser`` the :class:`DefaultsHelpFormatter`."""
    for _name, p in all_parsers(parser):
        p.formatter_class = DefaultsHelpFormatter
