"""CLI of the parameter files: ``params show`` and ``params check``, for every kind of file in
``params/`` (:mod:`companion.param_kinds`): the file's kind is told from its keys, or given with
``--kind``."""

from __future__ import annotations

import argparse
import dataclasses
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from pydantic import BaseModel

from companion.config import ConfigError, describe_parameters, describe_schema, read_toml
from companion.param_kinds import KINDS, detect_kind, validate
from companion_sitl.params import SimulatedConfig, load_simulated_config

#: the kinds of file the command line shows and checks: a vehicle file's [sim] tables are the
#: embedded simulator's (``companion demo``, ``campaign``), so they are shown and checked too
CLI_KINDS = {**KINDS, "vehicle": dataclasses.replace(KINDS["vehicle"], schema=SimulatedConfig)}


def _loader_check(kind: str) -> Callable[[Path], object] | None:
    """The loader the application reads a file of ``kind`` with; its rules that tie keys together
    (a marker that does not fit on the pad, coplanar anchors, ...) run after the schema's."""
    if kind == "camera":
        from companion.vision.camera import load_camera

        return load_camera
    if kind == "pad":
        from companion.vision.pad import load_pad

        return load_pad
    if kind == "anchors":
        from companion.uwb.anchors import AnchorLayout

        return AnchorLayout.from_toml
    if kind == "zenoh":
        from companion.telemetry.session import load_settings

        return load_settings
    if kind == "dart":
        from companion_sitl.dart_sim import load_dart_params  # all four tables, [sim] included

        return load_dart_params
    return None


def load_params_file(path: str | Path, kind: str | None = None) -> tuple[str, BaseModel]:
    """(kind, validated contents) of one parameter file of any kind; :class:`ConfigError` naming
    the file and, per problem, the key, the value and what is expected."""
    p = Path(path)
    data = read_toml(p)
    k = kind or detect_kind(data, CLI_KINDS)
    if k == "vehicle":
        return k, load_simulated_config(p)
    model = validate(data, k, str(p), CLI_KINDS)
    check = _loader_check(k)
    if check is not None:
        try:
            check(p)
        except ValueError as err:  # each loader's error (a ValueError) names file, key, value, rule
            raise ConfigError(str(p), [str(err).removeprefix(f"{p}: ").removeprefix(f"{p}:")]) from None
    return k, model


def cmd_params_show(args: argparse.Namespace) -> int:
    if args.file:
        kind, model = load_params_file(args.file, args.kind)
        print(f"# {args.file}: kind {kind}, {KINDS[kind].what}; the values it sets, defaults for the rest")
        lines = describe_parameters(model)
    else:
        kind = args.kind or "vehicle"
        print(f"# defaults of kind {kind}, {KINDS[kind].what}; other kinds: --kind {{{','.join(KINDS)}}}")
        lines = describe_schema(CLI_KINDS[kind].schema)
    for line in lines:
        print(line)
    return 0


def cmd_params_check(args: argparse.Namespace) -> int:
    bad = 0
    for f in args.files:
        try:
            kind, _ = load_params_file(f, args.kind)
            print(f"{f}: OK ({kind})")
        except ConfigError as err:
            bad += 1
            print(f"{err.source}:", file=sys.stderr)
            for p in err.problems:
                print(f"  {p}", file=sys.stderr)
    return 1 if bad else 0


def register(sub: Any) -> None:
    """Add ``companion params``."""
    params = sub.add_parser("params", help="show or check parameter files (every kind in params/)")
    psub = params.add_subparsers(dest="params_cmd", metavar="ACTION", required=True)
    kinds = ", ".join(f"{k.name}: {k.what}" for k in KINDS.values())
    ps = psub.add_parser("show", help="every parameter with its unit, limits, description and value (or default)")
    ps.add_argument("file", nargs="?", help="parameter file to show (default: the built-in defaults)")
    ps.add_argument("--kind", choices=list(KINDS), help=f"kind of file (default: told from its keys). {kinds}")
    ps.set_defaults(func=cmd_params_show)
    pc = psub.add_parser("check", help="validate parameter files of any kind")
    pc.add_argument("files", nargs="+", help="parameter files to validate")
    pc.add_argument("--kind", choices=list(KINDS), help="check every file as this kind (default: told from its keys)")
    pc.set_defaults(func=cmd_params_check)
