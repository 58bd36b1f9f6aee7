"""DWM1001 ``lec`` bytes as the driver's reader thread takes them off the port: arbitrary chunks
into the line buffer, each complete line classified and stamped.

Rule: every line ends as a reading or a counted line (ignored, malformed, partial, binary,
overflow); readings queued plus readings dropped unread add up to the readings counted; no
complete line is lost without a count."""

from __future__ import annotations

import itertools
import math

import pytest
from hypothesis import strategies as st

from companion_plugins.dwm1001 import MAX_LINE_BYTES, Dwm1001Driver, LecParser

from . import harness

pytestmark = pytest.mark.fuzz

GOOD = (
    b"DIST,4,AN0,1151,0.00,0.00,0.00,3.26,AN1,0CA8,0.00,3.35,0.00,2.45,"
    b"AN2,111C,3.35,3.35,0.00,1.89,AN3,1150,3.35,0.00,0.00,2.64,POS,1.87,1.49,0.46,53"
)
SEEDS = [
    GOOD + b"\r\n" + GOOD + b"\r\n",
    b"DIST,2,AN0,1A01,1.0,2.0,0.5,4.25,AN1,1a02,-1.0,2.0,2.5,3.5\r\nDIST,0,POS,0.10,-0.20,2.00,90\r\n",
    b"dwm> lec\r\n" + GOOD + b"\r\n\r\n",
]
NASTY = [
    b"DIST,x,AN0\r\n",
    b"DIST,1,AN1,1151,0,0,0,3.2\r\n",
    b"DIST,4,AN0,1151,nan,inf,-inf,1e999\r\n",
    b"DIST,99999999999999999999,AN0\r\n",
    b"\x00\xff\xfe\r\n",
    b"A" * (MAX_LINE_BYTES + 10) + b"\n" + GOOD + b"\n",
    b"A" * (3 * MAX_LINE_BYTES),
    GOOD[:40] + b"\n",
    b"\n" * 50,
]


class _Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        self.t += 0.001
        return self.t


def test_lec_bytes_into_the_driver(fuzz_budget) -> None:
    def feed(item: tuple[bytes, list[int]]) -> str:
        data, cuts = item
        drv = Dwm1001Driver("/dev/fuzz", clock=_Clock())
        drv._ser = object()  # read() refuses to run before start()
        bounds = sorted({0, len(data), *(c % (len(data) + 1) for c in cuts)})
        for a, b in itertools.pairwise(bounds):
            drv._buf += data[a:b]
            drv._parse_buffer()
        got = drv.read()
        s = drv.stats
        assert s.lines == s.readings + s.ignored + s.malformed + s.partial + s.binary
        assert len(got) + s.unread == s.readings
        assert all(math.isfinite(r.time_s) for r in got)
        assert data.count(b"\n") <= s.lines + s.overflow, "a complete line went uncounted"
        return "readings" if got else ("dropped (counted)" if s.dropped else "ignored (counted)")

    cuts = st.lists(st.integers(0, 4096), max_size=8)
    for data in SEEDS + NASTY:
        harness.check("dwm1001 lec bytes (driver)", feed, (data, []), ())
    harness.run(
        st.tuples(harness.fuzz_bytes(SEEDS + NASTY, max_random=2048), cuts),
        lambda item: harness.check("dwm1001 lec bytes (driver)", feed, item, ()),
        fuzz_budget,
    )


def test_lec_lines_as_text(fuzz_budget) -> None:
    parser = LecParser()

    def feed(line: str) -> str:
        before = parser.stats.lines
        r = parser.feed(line, 1.0)
        s = parser.stats
        assert s.lines == before + 1
        assert s.lines == s.readings + s.ignored + s.malformed + s.partial + s.binary
        return "reading" if r is not None else "dropped or ignored (counted)"

    text_seeds = [ln.decode() for s in SEEDS for ln in s.split(b"\n")]
    for line in text_seeds:
        harness.check("dwm1001 lec lines (parser)", feed, line, ())
    harness.run(
        st.one_of(
            st.text(max_size=300),
            st.sampled_from(text_seeds),
            harness.mutated([t.encode() for t in text_seeds if t]).map(lambda b: b.decode("utf-8", "replace")),
        ),
        lambda line: harness.check("dwm1001 lec lines (parser)", feed, line, ()),
        fuzz_budget,
    )
