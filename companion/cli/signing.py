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
from companion.cli.args import Once, positive_int
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
    pu.add_argument("--params", action=Once, required=True, help="parameter file: connection and [signing] key_file")
    pu.add_argument("--connection", help="MAVLink connection URL (default: connection in the parameters)")
    pu.add_argument("--off", action="store_true", help="send the all-zero key instead: turn the vehicle's signing off")
    pu.add_argument("--timeout", type=float, default=10.0, help="seconds to wait for the vehicle")
    pu.set_defaults(func=cmd_push)


def register_bench(bench_subparsers: Any) -> None:
    """Add ``companion bench signing``."""
    b = bench_subparsers.add_parser("signing", help="cost of MAVLink 2 signing: pack and parse, unsigned vs signed")
    b.add_argument("--n", type=positive_int, default=5000, help="messages per timed batch")
    b.add_argument("--rounds", type=int, default=5, help="alternating batches per variant (median reported)")
    b.set_defaults(func=cmd_bench_signing)


def bench_signing(n: int, rounds: int) -> dict[str, float]:
    """Microseconds per SET_POSITION_TARGET_LOCAL_NED packed and parsed, unsigned and signed
    (the variants alternate in each round; the medians and their ratios come from one run)."""
    import os
    import statistics
    import time

    os.environ["MAVLINK20"] = "1"
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    from companion.autopilot.mavlink_messages import velocity_setpoint_message
    from companion.autopilot.signing import SigningSetup, apply_to_mavlink
    from companion.guidance.setpoint import VelocitySetpoint

    key = generate_key()

    class _Sink:
        def __init__(self) -> None:
            self.chunks: list[bytes] = []

        def write(self, b: bytes) -> None:
            self.chunks.append(bytes(b))

    def pack(signed: bool) -> tuple[float, list[bytes]]:
        sink = _Sink()
        mav = mavlink.MAVLink(sink, srcSystem=255, srcComponent=191)
        if signed:
            apply_to_mavlink(mav, SigningSetup(key, allow_unsigned=False), initial_timestamp=1)
        msgs = [velocity_setpoint_message(i, 1, 1, VelocitySetpoint(1.0, 0.5, -0.2, 0.1)) for i in range(n)]
        t0 = time.perf_counter()
        for m in msgs:
            mav.send(m)
        return (time.perf_counter() - t0) / n * 1e6, sink.chunks

    def parse(packets: list[bytes], signed: bool) -> float:
        rx = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
        if signed:
            apply_to_mavlink(rx, SigningSetup(key, allow_unsigned=False), initial_timestamp=0)
        t0 = time.perf_counter()
        got = 0
        for p in packets:
            got += len(rx.parse_buffer(p) or [])
        dt = (time.perf_counter() - t0) / n * 1e6
        if got != n or (signed and rx.signing.goodsig_count != n):
            raise RuntimeError(f"bench signing: {got} of {n} parsed, {rx.signing.goodsig_count} verified")
        return dt

    res: dict[str, list[float]] = {k: [] for k in ("pack_us", "pack_signed_us", "parse_us", "parse_verify_us")}
    sizes = (0, 0)
    for _ in range(rounds):
        t_u, pk_u = pack(False)
        t_s, pk_s = pack(True)
        res["pack_us"].append(t_u)
        res["pack_signed_us"].append(t_s)
        res["parse_us"].append(parse(pk_u, False))
        res["parse_verify_us"].append(parse(pk_s, True))
        sizes = (len(pk_u[0]), len(pk_s[0]))
    out = {k: statistics.median(v) for k, v in res.items()}
    out["pack_ratio_signed_over_unsigned"] = out["pack_signed_us"] / out["pack_us"]
    out["parse_ratio_verify_over_unsigned"] = out["parse_verify_us"] / out["parse_us"]
    out["bytes_unsigned"], out["bytes_signed"] = float(sizes[0]), float(sizes[1])
    return out


def cmd_bench_signing(args: argparse.Namespace) -> int:
    if args.n < 100 or args.rounds < 1:
        raise StartupError(f"--n {args.n} / --rounds {args.rounds}: need n >= 100 and rounds >= 1", exits.BAD_INPUT)
    r = bench_signing(args.n, args.rounds)
    print(f"MAVLink 2 signing, SET_POSITION_TARGET_LOCAL_NED, {args.n} messages x {args.rounds} rounds (median)")
    print(f"  packet size        {r['bytes_unsigned']:.0f} B unsigned, {r['bytes_signed']:.0f} B signed")
    print(
        f"  pack (encode+send) {r['pack_us']:.1f} us unsigned, {r['pack_signed_us']:.1f} us signed "
        f"(x{r['pack_ratio_signed_over_unsigned']:.2f})"
    )
    print(
        f"  parse              {r['parse_us']:.1f} us unsigned, {r['parse_verify_us']:.1f} us verified "
        f"(x{r['parse_ratio_verify_over_unsigned']:.2f})"
    )
    return exits.OK


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
    # the secret stays in the file: a terminal's scrollback, a screen share or a CI log keeps what
    # is printed (`signing show --hex` prints it on demand)
    print(f"wrote {path} (mode 0600), fingerprint {key.fingerprint}; the secret: companion signing show --hex {path}")
    fmt = ", key_format = 'passphrase'" if args.passphrase else ""
    print(f"companion: [signing] enabled = true, key_file = {str(path)!r}{fmt}")
    if args.passphrase:
        print(f'MAVProxy (same secret): signing setup "$(cat {path})"')
    else:
        print("MAVProxy takes a passphrase only (`signing setup PASSPHRASE`): use keygen --passphrase to share with it")
    print(
        "give it to the vehicle: companion signing push --params FILE; "
        "pymavlink: conn.setup_signing(bytes.fromhex(HEX))"
    )
    return exits.OK


def cmd_show(args: argparse.Namespace) -> int:
    try:
        key = read_key_file(args.file, args.format, passphrase_setting="--format passphrase")
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
    elif config.signing.key_file:  # checked above
        key = read_key_file(config.signing.key_file, config.signing.key_format)
        print(f"the vehicle signs with key {key.fingerprint}")
    sys.stdout.flush()
    return exits.OK
