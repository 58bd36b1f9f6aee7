"""``flight.tlog`` as the companion meets it again: a file to continue after the logging process
died (``cut_torn_record``, then a ``TlogReplayer`` appending), whose bytes are mutated (torn,
truncated, flipped, spliced, random), read back with pymavlink (``read_tlog``); and ``companion
replay`` on a run folder whose flight.tlog is mutated, deleted or random.

Rule: the cut drops only a torn last record (at most one record's bytes, the rest kept as it
was); every record appended is read back after it, and every record that cannot be encoded is
counted (``encode_errors``); ``read_tlog`` raises on nothing. The replay does not read the
.tlog: it replays the run exactly as from the recorded one."""

from __future__ import annotations

import itertools
import math
import shutil
from pathlib import Path
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.autopilot.types import FlightMode
from companion.delivery.replay import replay_run
from companion.flightlog.tlog import MAX_RECORD_BYTES, cut_torn_record, read_tlog
from companion.flightlog.tlog_replay import ACK_RECORD, COMMAND_RECORD, TlogReplayer

from . import harness

pytestmark = pytest.mark.fuzz

PARAMS: dict[str, Any] = {
    "boot_s": 0.0,
    "epoch_s": 1.7e9,
    "custom_modes": {m: i for i, m in enumerate(FlightMode)},
    "encoder": {},
}
MAX_RECORD = MAX_RECORD_BYTES
GOOD: list[tuple[Any, ...]] = [
    (1.0, COMMAND_RECORD, 400, (1.0,)),
    (1.1, ACK_RECORD, 400, 0),
    (1.2, COMMAND_RECORD, 176, (1.0, 4.0, math.nan, math.inf)),
    (1.3, ACK_RECORD, 176, 4),
]
BAD: list[tuple[Any, ...]] = [
    (1.4, COMMAND_RECORD, "arm", ()),  # a command that is not a number
    (1.5, ACK_RECORD, 400, 999),  # a result past its uint8
    (1.6, COMMAND_RECORD, 70000, ()),  # a command past its uint16
]


def _tlog(tmp: Path, records: list[tuple[Any, ...]]) -> bytes:
    p = tmp / "seed.tlog"
    r = TlogReplayer(p, PARAMS, append=False)
    r.apply(records)
    r.close()
    return p.read_bytes()


def _messages(path: Path) -> list[str]:
    return [m.get_type() for m in read_tlog(path)]


def test_tlog_bytes_continued(tmp_path: Path, fuzz_budget: int) -> None:
    one = _tlog(tmp_path, GOOD[:1])
    many = _tlog(tmp_path, GOOD * 6)
    seeds = [b"", one, many, many[:-5], many + one[:9], one[:8], b"\x00" * 64, many[:100] + b"\xfd" + many[100:]]
    # the second record's magic flipped: the cut used to drop every whole record after it
    seeds.append(many[: len(one) + 8] + b"\x02" + many[len(one) + 9 :])
    # a record cut right after its length byte: the walk read the flags byte past the end (IndexError)
    seeds.append(one + one[:10])
    n = itertools.count()

    def feed(data: bytes) -> str:
        p = tmp_path / f"f{next(n)}.tlog"
        p.write_bytes(data)
        cut_torn_record(p)
        kept = p.read_bytes()
        assert data.startswith(kept), "the cut changed bytes it kept"
        assert len(data) - len(kept) <= MAX_RECORD, f"{len(data) - len(kept)} bytes cut: more than a torn record"
        before = _messages(p)  # read_tlog takes any bytes
        r = TlogReplayer(p, PARAMS, append=True)
        r.apply(GOOD + BAD)
        r.close()
        assert r.written + r.encode_errors == len(GOOD + BAD) and r.dropped == 0
        assert r.written >= len(GOOD), "a good record not written"
        tail = p.read_bytes()[len(kept) :]
        t = tmp_path / "tail.tlog"
        t.write_bytes(tail)
        assert len(_messages(t)) == r.written, "a record appended is not read back"
        after = _messages(p)
        assert len(after) >= len(before), "appending lost what the file held"
        p.unlink()
        return "cut a torn record" if len(kept) < len(data) else "continued as it was"

    for data in seeds:
        harness.check("flight.tlog -> continued", feed, data, ())
    harness.run(
        harness.fuzz_bytes(seeds, max_random=512),
        lambda d: harness.check("flight.tlog -> continued", feed, d, ()),
        fuzz_budget,
    )


TLOG_EDITS = ("delete", "empty", "truncate", "flip", "random")


def _edit(p: Path, op: str, k: int, junk: bytes) -> None:
    data = p.read_bytes()
    if op == "delete":
        p.unlink()
    elif op == "empty":
        p.write_bytes(b"")
    elif op == "truncate":
        p.write_bytes(data[: k % (len(data) + 1)])
    elif op == "flip" and data:
        b = bytearray(data)
        for j in range(1 + k % 8):
            b[(k * (j + 7919)) % len(b)] ^= 1 << (j % 8)
        p.write_bytes(bytes(b))
    else:
        p.write_bytes(junk)


def test_replay_of_a_run_whose_tlog_is_mutated(
    fuzz_run: Path, tmp_path: Path, fuzz_tier: str, run_folder_budget: int
) -> None:
    assert (fuzz_run / "flight.tlog").stat().st_size > 0
    base = replay_run(fuzz_run, tmp_path / "base")
    assert base.identical, base.lines()
    n = itertools.count()

    def feed(case: tuple[str, int, bytes]) -> str:
        k = next(n)
        run = tmp_path / f"run{k}"
        shutil.copytree(fuzz_run, run, ignore=shutil.ignore_patterns("replay"))
        _edit(run / "flight.tlog", *case)
        try:
            r = replay_run(run, tmp_path / f"out{k}")
        finally:
            shutil.rmtree(run, ignore_errors=True)
        assert r.identical, f"the replay changed with flight.tlog {case[0]}: {r.lines()}"
        assert (r.inputs, r.ticks, r.notes) == (base.inputs, base.ticks, base.notes)
        return "replayed as recorded"

    corpus = [("random", 0, b"\xfd\xff" * 100), ("delete", 0, b"")]  # the fast tier: the first (a replay is 1-2 s)
    for case in corpus if fuzz_tier == "fuzz" else corpus[:1]:
        harness.check("run folder flight.tlog -> replay", feed, case, ())
    harness.run(
        st.tuples(st.sampled_from(TLOG_EDITS), st.integers(0, 10_000_000), st.binary(max_size=256)),
        lambda c: harness.check("run folder flight.tlog -> replay", feed, c, ()),
        run_folder_budget,
    )
