"""``companion signing``: MAVLink 2 signing keys (keygen, show) and giving one to an ArduPilot
vehicle (push, SETUP_SIGNING). See :mod:`companion.autopilot.signing` and docs/signing.md."""

from __future__ import annotations

import argparse
import asyncio
import logging
import sys
from typing import Any

from companion.autopilot.interface import AutopilotUnreachable, ConnectionUrlError, LinkDeviceMissing
from companion.autopilot.signing import (
    SigningError,
    SigningKeyError,
    SigningSetup,
    generate_key,
    generate_passphrase,
    passphrase_key,
    read_key_file,
    write_key_file,
)
from companion.cli import exits
from companion.cli.exits import StartupError
from companion.config import load_config

log = logging.getLogger(__name__)


def register(subparsers: Any) -> None:
    p = subparsers.add_parser("signing", help="MAVLink 2 signing keys: keygen, show, push to an ArduPilot vehicle")
    sub = p.add_subparsers(dest="signing", metavar="WHAT", required=True)
    kg = sub.add_parser("keygen", help="write a new random 32-byte key as 64 hex digits (mode 0600)")
    kg.add_argument("file", help="key file to create")
    kg.add_argument("--force", action="store_true", help="replace an existing key file")
    kg.add_argument(
        "--passphrase",
        action="store_true",
        help="write a random passphrase instead (secret = SHA-256 of it, as MAVProxy `signing setup PASSPHRASE`)",
    )
    kg.set_defaults(func=cmd_keygen)
    sh = sub.add_parser("show", help="read a key file and print its fingerprint (and the key with --hex)")
    sh.add_argument("file", help="key file")
    sh.add_argument("--format", default="auto", choices=("auto", "hex", "raw", "passphrase"), help="key file format")
    sh.add_argument("--hex", action="store_true", help="also print the 64 hex digits of the secret")
    sh.set_defaults(func=cmd_show)
    pu = sub.add_parser(
        "push",
        help="give the vehicle the key in [signing] with SETUP_SIGNING, then check it signs with it",
    )
    pu.add_argument("--params", required=True, help="parameter file: connection and [signing] key_file")
    pu.add_argument("--connection", help="MAVLink connection URL (default: connection in the parameters)")
    pu.add_argument("--off", action="store_true", help="send the all-zero key instead: turn the vehicle's signing off")
    pu.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the vehicle")
    pu.set_defaults(func=cmd_push)


def cmd_keygen(args: argparse.Namespace) -> int:
    try:
        if args.passphrase:
            phrase = generate_passphrase()
            key = passphrase_key(phrase)
            path = write_key_file(args.file, phrase, overwrite=args.force)
        else:
            key = generate_key()
            path = write_key_file(args.file, key, overwrite=args.force)
    except SigningKeyError as err:
        raise StartupError(str(err), exits.BAD_INPUT) from None
    print(f"wrote {path} (mode 0600), fingerprint {key.fingerprint}")
    print(f"secret (hex): {key.hex}")
    fmt = ", key_format = 'passphrase'" if args.passphrase else ""
    print(f"companion: [signing] enabled = true, key_file = {str(path)!r}{fmt}")
    if args.passphrase:
        print(f"MAVProxy (same secret): signing setup {phrase}")
    else:
        print("MAVProxy takes a passphrase only (`signing setup PASSPHRASE`): use keygen --passphrase to share with it")
    print(
        "give it to the vehicle: companion signing push --params FILE; "
        "pymavlink: conn.setup_signing(bytes.fromhex(HEX))"
    )
    return exits.OK


def cmd_show(args: argparse.Namespace) -> int:
    try:
        key = read_key_file(args.file, args.format)
    except SigningKeyError as err:
        raise StartupError(str(err), exits.BAD_INPUT) from None
    print(f"{args.file}: fingerprint {key.fingerprint}")
    if args.hex:
        print(f"secret (hex): {key.hex}")
    return exits.OK


async def _push(config: Any, off: bool, timeout_s: float) -> None:
    from companion.autopilot.ardupilot import ArduPilotAutopilot

    sc = config.signing
    key = read_key_file(sc.key_file, sc.key_format) if sc.key_file else None
    # push: connect unsigned (ArduPilot takes an unsigned SETUP_SIGNING while it does not sign);
    # off: sign with our key and accept anything (a vehicle signing with our key drops an unsigned one)
    setup = SigningSetup(key, sc.link_id, allow_unsigned=True) if off and key is not None else None
    ap = ArduPilotAutopilot(
        config.connection, link_timeout_s=config.runtime.link_timeout_s, stream_rates_hz={}, signing=setup
    )
    try:
        await ap.connect(timeout_s=timeout_s)
        await ap.push_signing_key(None if off else key, timeout_s=min(timeout_s, 5.0))
    finally:
        await ap.close()


def cmd_push(args: argparse.Namespace) -> int:
    overrides = {"connection": args.connection} if args.connection else None
    config = load_config(args.params, overrides=overrides)
    if config.autopilot != "ardupilot":
        raise StartupError(
            f"autopilot = {config.autopilot!r} in {args.params}: SETUP_SIGNING is pushed to ArduPilot only "
            "(mavsdk 4.1 has no signing API)",
            exits.BAD_INPUT,
        )
    if not args.off and not config.signing.key_file:
        raise StartupError(f"{args.params}: signing.key_file is not set; nothing to push", exits.BAD_INPUT)
    try:
        asyncio.run(_push(config, args.off, args.timeout))
    except SigningKeyError as err:
        raise StartupError(f"{err}; fix signing.key_file in {args.params}", exits.BAD_INPUT) from None
    except SigningError as err:
        raise StartupError(str(err), exits.FAILED) from None
    except (AutopilotUnreachable, LinkDeviceMissing, ConnectionUrlError) as err:
        raise StartupError(
            f"{err}; change connection in {args.params} (or --connection)", exits.AUTOPILOT_UNREACHABLE
        ) from None
    if args.off:
        print("sent SETUP_SIGNING with the zero key: the vehicle's signing is off")
    else:
        key = read_key_file(config.signing.key_file, config.signing.key_format)
        print(f"the vehicle signs with key {key.fingerprint}")
    sys.stdout.flush()
    return exits.OK
