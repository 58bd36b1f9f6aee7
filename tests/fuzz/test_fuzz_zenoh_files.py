"""Zenoh session files (``params/zenoh_*.toml``) into both of their readers: ``params check``'s
(the ``zenoh`` kind, ``companion.param_kinds``) and the one the vehicle and the ground station open
their session with (``companion.telemetry.session.load_settings``, then ``to_config``). The shipped
files as bytes mutated, and with one value replaced by a hostile one.

Rule: each reader loads the file or refuses it with its typed error naming the file
(``ConfigError``, ``SettingsError``); a file the vehicle's reader takes gives a ``zenoh.Config``;
and the two agree: what ``params check`` passes, the session opens with, and the reverse."""

from __future__ import annotations

import itertools
import tomllib
from pathlib import Path
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.cli.params import load_params_file
from companion.config import ConfigError
from companion.telemetry.session import SettingsError, load_settings

from . import harness

pytestmark = pytest.mark.fuzz

PARAMS = Path(__file__).resolve().parents[2] / "params"
SEEDS = [p.read_bytes() for p in sorted(PARAMS.glob("zenoh_*.toml"))]
KEYS = (
    "mode", "listen", "connect", "router_endpoint", "multicast_scouting", "gossip_scouting", "scouting_delay_ms",
    "connect_exit_on_failure", "connect_timeout_ms", "user", "password", "overrides", "max_message_bytes",
    "shared_memory", "max_sessions", "accept_pending", "unknown_key",
)  # fmt: skip
VALUES = (
    '"peer"', '"client"', '"router"', '"PEER"', '""', "0", "-1", "1", "65535", "65536", "1073741824",
    "1073741825", "10000", "10001", "99999999999999999999", "1.5", "nan", "inf", "true", "false", "[]",
    '["tcp/127.0.0.1:7447"]', '["tcp/"]', '["tcp/a b"]', '["bogus/x"]', '["tcp/[::1]:7447", "udp/0.0.0.0:1"]',
    '[1, 2]', '"tcp/10.0.0.1:7447"', '"tcp/"', "{}", '{ "a/b" = "1" }', '{ "mode" = "\\"client\\"" }',
    '{ "x" = 1 }', '"x"', '"\\u0000"',
)  # fmt: skip


def _with_value(seed: bytes, key: str, value: str) -> bytes:
    """``seed`` with ``key = value`` set in its [zenoh] table (replacing the line that sets it)."""
    lines = [ln for ln in seed.decode().splitlines() if ln.split("=")[0].strip() != key]
    at = next(i for i, ln in enumerate(lines) if ln.strip() == "[zenoh]") + 1
    lines.insert(at, f"{key} = {value}")
    return "\n".join(lines).encode() + b"\n"


CASES = st.one_of(
    harness.fuzz_bytes(SEEDS, max_random=256),
    st.builds(_with_value, st.sampled_from(SEEDS), st.sampled_from(KEYS), st.sampled_from(VALUES)),
)


def _table(data: bytes) -> dict[str, Any] | None:
    try:
        doc = tomllib.loads(data.decode())
    except (UnicodeDecodeError, tomllib.TOMLDecodeError):
        return None
    t = doc.get("zenoh")
    return t if isinstance(t, dict) else None


def test_zenoh_session_files(tmp_path: Path, fuzz_budget: int) -> None:
    n = itertools.count()

    def feed(data: bytes) -> str:
        p = tmp_path / f"zenoh_{next(n)}.toml"
        p.write_bytes(data)
        p.chmod(0o600)
        checked = opened = ""
        try:
            load_params_file(p, "zenoh")
        except ConfigError as err:
            assert str(p) in str(err), f"params check's refusal names no file: {err}"
            checked = str(err)
        try:
            load_settings(p).to_config()
        except SettingsError as err:
            assert str(p) in str(err) or "zenoh config" in str(err), f"the refusal names no file: {err}"
            opened = str(err)
        finally:
            p.unlink()
        if _table(data) is not None:  # both read a [zenoh] table: they must agree on it
            assert bool(checked) == bool(opened), (
                f"params check {'refuses' if checked else 'passes'} what the session "
                f"{'refuses' if opened else 'opens with'}: {checked or opened}"
            )
        return "refused by both" if checked and opened else "refused" if checked or opened else "loaded by both"

    for data in SEEDS:
        assert feed(data) == "loaded by both"
    # a limit written above [zenoh]: the session's reader used to ignore it without a word
    assert feed(b"max_message_bytes = 65536\n" + SEEDS[0]) == "refused by both"
    harness.run(CASES, lambda d: harness.check("zenoh session files", feed, d, ()), fuzz_budget)
    c = harness.COUNTS["zenoh session files"]
    assert c.outcomes["loaded by both"] and c.outcomes["refused by both"], c.outcomes
