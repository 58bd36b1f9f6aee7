"""What every fuzz module shares: the per-surface counts, the check that turns an input's outcome
into "handled" (a typed error, a counted drop, a result) or an escape (any other exception, a
hang, counters that do not add up), the budget of the tier and the byte mutations of seeds."""

from __future__ import annotations

import contextlib
import os
import signal
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

#: examples per fuzz test and tier (``--tier fuzz`` and ``--tier all`` take the larger)
BUDGETS = {"fast": 25, "fuzz": 1000}
#: mutated run folders per test (a replay or a report takes about a second each)
RUN_FOLDER_BUDGETS = {"fast": 1, "fuzz": 60}
#: generated parameter files per test that may start the embedded simulator, and the simulated
#: seconds each accepted one flies (about 0.3 s of wall time per simulated second)
SIM_START_BUDGETS = {"fast": 6, "fuzz": 300}
SIM_START_S = {"fast": 4.0, "fuzz": 12.0}
#: one input may take this long; longer is a hang (an escape)
TIMEOUT_S = 30.0  # a report can take 10 s on a slow host under CI load; a hang takes for ever
#: COMPANION_FUZZ_KEEP_GOING=1: count escapes and go on instead of failing at the first (a survey)
KEEP_GOING = os.environ.get("COMPANION_FUZZ_KEEP_GOING") == "1"


@dataclass
class SurfaceCount:
    tried: int = 0
    escaped: int = 0
    outcomes: Counter[str] = field(default_factory=Counter)
    first_escape: str = ""


#: surface name -> what was tried there this session (printed by tests/fuzz/conftest.py)
COUNTS: dict[str, SurfaceCount] = {}


class Escape(AssertionError):
    """An input the surface did not handle by its rule."""


class Hang(BaseException):
    pass


@contextlib.contextmanager
def time_limit(seconds: float) -> Iterator[None]:
    """Raise :class:`Hang` in the main thread after ``seconds`` (SIGALRM; POSIX only)."""

    def on_alarm(signum: int, frame: Any) -> None:
        raise Hang

    old = signal.signal(signal.SIGALRM, on_alarm)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def check(surface: str, fn: Callable[[Any], str], value: Any, allowed: tuple[type[BaseException], ...]) -> str:
    """Feed ``value`` to ``fn`` (which returns an outcome label and asserts its own counters add
    up); an exception of an ``allowed`` type is the typed error. Anything else is counted as an
    escape and raised as :class:`Escape` naming the input."""
    c = COUNTS.setdefault(surface, SurfaceCount())
    c.tried += 1
    try:
        with time_limit(TIMEOUT_S):
            outcome = fn(value)
    except allowed as err:
        outcome = type(err).__name__
    except Hang:
        c.escaped += 1
        c.first_escape = c.first_escape or f"hang on {value!r:.200}"
        if KEEP_GOING:
            return "ESCAPE"
        raise Escape(f"{surface}: no answer within {TIMEOUT_S} s for {value!r:.300}") from None
    except Exception as err:
        c.escaped += 1
        c.first_escape = c.first_escape or f"{type(err).__name__}: {err!s:.200} on {value!r:.200}"
        if KEEP_GOING:
            c.outcomes[f"ESCAPE {type(err).__name__}"] += 1
            return "ESCAPE"
        raise Escape(f"{surface}: {type(err).__name__}: {err} for input {value!r:.300}") from err
    c.outcomes[outcome] += 1
    return outcome


def run(strategy: st.SearchStrategy[Any], body: Callable[[Any], object], max_examples: int) -> None:
    """``body`` on ``max_examples`` inputs from ``strategy``, derandomized (CI sees the same inputs
    every run), no example database, no deadline (hangs are :func:`check`'s job)."""

    @settings(
        max_examples=max_examples,
        deadline=None,
        derandomize=True,
        database=None,
        suppress_health_check=list(HealthCheck),
    )
    @given(strategy)
    def inner(value: Any) -> None:
        body(value)

    inner()


# ------------------------------------------------------------------------------ mutations
_OPS = ("truncate", "flip", "insert", "delete", "duplicate_line", "tear_line", "drop_line", "splice")
_NASTY = (b"\x00", b"\xff", b"\r", b"\n", b"\r\n", b",", b'"', b"\xfe\xfd", b"\xfd", b"nan", b"1e999", b"-", b"9" * 40)


@st.composite
def mutated(draw: st.DrawFn, seeds: Sequence[bytes]) -> bytes:
    """A seed with one to four mutations: truncation, byte flips, insertions (random or
    known-nasty bytes), deletions, duplicated, torn or dropped lines, a splice of two seeds."""
    b = bytearray(draw(st.sampled_from(seeds)))
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(_OPS))
        n = len(b)
        if op == "truncate":
            del b[draw(st.integers(0, n)) :]
        elif op == "flip" and n:
            i = draw(st.integers(0, n - 1))
            b[i] ^= 1 << draw(st.integers(0, 7))
        elif op == "insert":
            ins = draw(st.one_of(st.binary(min_size=1, max_size=8), st.sampled_from(_NASTY)))
            i = draw(st.integers(0, n))
            b[i:i] = ins
        elif op == "delete" and n:
            i = draw(st.integers(0, n - 1))
            del b[i : i + draw(st.integers(1, 8))]
        elif op in ("duplicate_line", "tear_line", "drop_line"):
            lines = bytes(b).split(b"\n")
            k = draw(st.integers(0, len(lines) - 1))
            if op == "duplicate_line":
                lines.insert(k, lines[k])
            elif op == "drop_line":
                del lines[k]
            else:
                lines[k] = lines[k][: draw(st.integers(0, len(lines[k])))]
            b = bytearray(b"\n".join(lines))
        elif op == "splice":
            other = draw(st.sampled_from(seeds))
            b = b[: draw(st.integers(0, n))] + other[draw(st.integers(0, len(other))) :]
    return bytes(b)


def fuzz_bytes(seeds: Sequence[bytes], max_random: int = 512) -> st.SearchStrategy[bytes]:
    """Random bytes, a seed as it is, or a mutated seed."""
    return st.one_of(st.binary(max_size=max_random), st.sampled_from(list(seeds)), mutated(seeds))
