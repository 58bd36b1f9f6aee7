"""MAVLink signing key files in every format the code reads (``auto``, ``hex``, ``raw``,
``passphrase``) and the signing timestamp file, as bytes: valid ones, then truncated, flipped,
spliced, padded with whitespace, non-UTF-8, random; a key file others may read.

Rule: ``read_key_file`` gives the 32-byte key the format defines (64 hex digits, the 32 bytes
themselves, SHA-256 of the one line) or ``SigningKeyError`` naming the file; never another
exception, never a key the bytes do not define. ``read_timestamp_file`` gives the integer the
file holds (within 0..2^48-1) or ``SigningKeyError`` naming it, and a link's starting timestamp
is then never behind the stored one plus 60 s (as ArduPilot restarts) nor past 2^48-1."""

from __future__ import annotations

import hashlib
import itertools
import os
import string
from pathlib import Path

import pytest
from hypothesis import strategies as st

from companion.autopilot.signing import (
    AP_KEY_LOAD_OFFSET,
    KEY_LEN,
    TIMESTAMP_MAX,
    SigningKey,
    SigningKeyError,
    SigningSetup,
    clock_timestamp,
    read_key_file,
    read_timestamp_file,
    write_timestamp_file,
)

from . import harness

pytestmark = pytest.mark.fuzz

FORMATS = ("auto", "hex", "raw", "passphrase")
SECRET = hashlib.sha256(b"fuzz: the signing key").digest()
KEY_SEEDS = [
    SECRET.hex().encode() + b"\n",  # what `companion signing keygen` writes
    SECRET.hex().upper().encode(),
    " ".join(SECRET.hex()[i : i + 8] for i in range(0, 64, 8)).encode() + b"\r\n",
    SECRET,  # raw
    b"correct horse battery staple\n",  # a passphrase
    b"x" * 32,  # a 32-character passphrase reads as a raw key unless named
    b"0" * 64,
    b"\xff" * 32 + b"\n",
    b"\n",
    SECRET.hex().encode()[:-1] + b"g",
    "pässphrase\n".encode(),
    b"two\nlines\n",
    b"\xef\xbb\xbf" + SECRET.hex().encode(),  # a byte-order mark
    SECRET.hex().encode() * 2,
]
TS_SEEDS = [
    b"400000000000\n",
    b"0",
    str(TIMESTAMP_MAX).encode(),
    str(TIMESTAMP_MAX + 1).encode(),
    b"-1",
    b" 123 \n\n",
    b"1_000",
    b"",
    b"12.5",
    b"0x10",
    b"9" * 5000,  # past Python's limit on digits of an int from a string
    b"\xd9\xa1\xd9\xa2",  # Arabic-Indic digits: not ASCII
]


def _hex_digits(data: bytes) -> str | None:
    try:
        digits = "".join(data.decode("ascii").split())
    except UnicodeDecodeError:
        return None
    return digits if len(digits) == 64 and all(c in string.hexdigits for c in digits) else None


def _expected(data: bytes, fmt: str) -> bytes | None:
    """The secret the format makes of ``data``, or None where it makes none (read independently)."""
    if fmt == "auto":
        fmt = "hex" if _hex_digits(data) is not None else "raw" if len(data) == KEY_LEN else ""
    if fmt == "raw":
        return data if len(data) == KEY_LEN else None
    if fmt == "hex":
        try:
            digits = "".join(data.decode("utf-8").split())
        except UnicodeDecodeError:
            return None
        ok = len(digits) == 64 and all(c in string.hexdigits for c in digits)
        return bytes.fromhex(digits) if ok else None
    if fmt == "passphrase":
        try:
            line = data.decode("utf-8").removesuffix("\n").removesuffix("\r")
        except UnicodeDecodeError:
            return None
        return hashlib.sha256(line.encode()).digest() if line and "\n" not in line and "\r" not in line else None
    return None


def test_key_files(tmp_path: Path, fuzz_budget: int) -> None:
    n = itertools.count()

    def feed(case: tuple[bytes, str, bool]) -> str:
        data, fmt, exposed = case
        p = tmp_path / f"key{next(n)}"
        p.write_bytes(data)
        os.chmod(p, 0o640 if exposed else 0o600)
        want = None if exposed or not data else _expected(data, fmt)
        try:
            key = read_key_file(p, fmt)  # type: ignore[arg-type]
        except SigningKeyError as err:
            assert str(p) in str(err), f"the refusal does not name the file: {err}"
            assert want is None, f"a {fmt} key file refused: {err}"
            return "refused (exposed)" if exposed else "refused"
        finally:
            p.unlink()
        assert isinstance(key, SigningKey) and len(key.secret) == KEY_LEN
        assert key.secret == want, f"read a key the {fmt} file does not define"
        return f"key ({fmt})"

    for data in KEY_SEEDS:
        for fmt in FORMATS:
            harness.check("signing key file", feed, (data, fmt, False), ())
    harness.check("signing key file", feed, (KEY_SEEDS[0], "auto", True), ())
    harness.run(
        st.tuples(harness.fuzz_bytes(KEY_SEEDS, max_random=80), st.sampled_from(FORMATS), st.booleans()),
        lambda c: harness.check("signing key file", feed, c, ()),
        fuzz_budget,
    )
    c = harness.COUNTS["signing key file"]
    assert c.outcomes["refused (exposed)"] and c.outcomes["key (hex)"] and c.outcomes["key (raw)"], c.outcomes


def test_timestamp_files(tmp_path: Path, fuzz_budget: int) -> None:
    n = itertools.count()
    key = SigningKey(SECRET, "<fuzz>")

    def feed(data: bytes) -> str:
        p = tmp_path / f"ts{next(n)}"
        p.write_bytes(data)
        try:
            stored = read_timestamp_file(p)
        except SigningKeyError as err:
            assert str(p) in str(err), f"the refusal does not name the file: {err}"
            try:
                text = data.decode("ascii").strip()
                value: int | None = int(text) if text.isdigit() else None
            except (UnicodeDecodeError, ValueError):
                value = None
            assert value is None or value > TIMESTAMP_MAX, f"refused a timestamp file holding {text!r}"
            raise
        assert stored is not None and 0 <= stored <= TIMESTAMP_MAX
        assert stored == int(data.decode("ascii").strip()), "a timestamp the file does not hold"
        start = SigningSetup(key, timestamp_file=p).initial_timestamp()
        assert min(stored + AP_KEY_LOAD_OFFSET, TIMESTAMP_MAX) <= start <= TIMESTAMP_MAX
        assert start >= clock_timestamp() - 100_000  # never behind the clock (a second of slack)
        write_timestamp_file(p, start)  # kept again as the link keeps it: read back the same
        assert read_timestamp_file(p) == start
        return "timestamp"

    harness.check("signing timestamp file", lambda _: str(read_timestamp_file(tmp_path / "none")), None, ())
    for data in TS_SEEDS:
        harness.check("signing timestamp file", feed, data, (SigningKeyError,))
    harness.run(
        harness.fuzz_bytes(TS_SEEDS, max_random=40),
        lambda d: harness.check("signing timestamp file", feed, d, (SigningKeyError,)),
        fuzz_budget,
    )
