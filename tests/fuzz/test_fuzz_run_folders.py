"""Run folders into ``companion replay`` (``replay_run``) and ``companion report``
(``make_report``): copies of one real run folder with files missing, emptied, truncated, torn at
the last line, mutated bytes, or nothing but flight.mcap.

Rule: the command finishes (a torn last line dropped and reported: replay's ``torn``) or refuses
with LogFormatError naming the file; a report skips a figure with the reason. Never another
exception, never a hang."""

from __future__ import annotations

import itertools
import shutil
from pathlib import Path

import pytest
from hypothesis import strategies as st

from companion.delivery.replay import replay_run
from companion.flightlog.reader import LogFormatError
from companion.flightlog.report import make_report

from . import harness

pytestmark = pytest.mark.fuzz

FILES = [
    "run.json", "flight.mcap", "summary.json", "truth.csv", "flight.csv", "ekf.csv", "guidance.csv", "events.csv",
    "ap_position.csv", "ap_attitude.csv", "ap_status.csv", "camera.csv", "uwb.csv", "commands.csv", "requests.csv",
]  # fmt: skip
OPS = ("delete", "empty", "truncate", "tear_last_line", "mutate", "random")

#: the known-nasty folders every tier tries (file -> operation), then the generated ones
CORPUS: list[list[tuple[str, str, int]]] = [
    [],  # the run as recorded
    [("*", "mcap_only", 0)],  # nothing but flight.mcap
    [("flight.mcap", "delete", 0)],
    [("truth.csv", "tear_last_line", 0), ("flight.csv", "tear_last_line", 0)],  # a killed flight
    [("ekf.csv", "truncate", 100_003)],
    [("run.json", "delete", 0), ("flight.mcap", "truncate", 1_000_003)],
    [("run.json", "random", 0)],
    [("guidance.csv", "empty", 0)],
]
#: the fast tier's share of it (a report takes two to three seconds)
CORPUS_FAST = [CORPUS[1], CORPUS[3]]


def _apply(run: Path, edits: list[tuple[str, str, int]], seed_bytes: bytes = b"") -> None:
    for name, op, k in edits:
        if op == "mcap_only":
            for f in run.iterdir():
                if f.name != "flight.mcap":
                    f.unlink()
            continue
        p = run / name
        if not p.exists():
            continue
        if op == "delete":
            p.unlink()
        elif op == "empty":
            p.write_bytes(b"")
        elif op == "truncate":
            data = p.read_bytes()
            p.write_bytes(data[: k % (len(data) + 1)])
        elif op == "tear_last_line":
            data = p.read_bytes().rstrip(b"\n")
            cut = data.rfind(b"\n") + 1
            p.write_bytes(data[: cut + (len(data) - cut) // 2])
        elif op == "mutate":
            data = bytearray(p.read_bytes())
            for j in range(1 + k % 4):
                if data:
                    data[(k * (j + 7919)) % len(data)] ^= 1 << (j % 8)
            p.write_bytes(bytes(data))
        elif op == "random":
            p.write_bytes(seed_bytes)


EDITS = st.lists(
    st.tuples(st.sampled_from(FILES), st.sampled_from(OPS), st.integers(0, 10_000_000)), min_size=1, max_size=3
)
FOLDERS = st.tuples(EDITS, st.binary(max_size=256))


def _folder(fuzz_run: Path, tmp_path: Path, n: int, item: tuple[list[tuple[str, str, int]], bytes]) -> Path:
    run = tmp_path / f"run{n}"
    shutil.copytree(fuzz_run, run)
    _apply(run, *item)
    return run


def _names_a_file(err: Exception, run: Path, seed: Path) -> bool:
    """The run folder, or one of its files (replay names an input as ``uwb.csv:2``)."""
    return str(run) in str(err) or any(f.name in str(err) for f in seed.iterdir())


def test_run_folders_into_replay(fuzz_run, tmp_path, fuzz_tier, run_folder_budget) -> None:
    n = itertools.count()

    def feed(item: tuple[list[tuple[str, str, int]], bytes]) -> str:
        k = next(n)
        run = _folder(fuzz_run, tmp_path, k, item)
        try:
            r = replay_run(run, tmp_path / f"out{k}")
        except LogFormatError as err:
            assert _names_a_file(err, run, fuzz_run), f"the error names no file of the run: {err}"
            raise
        finally:
            shutil.rmtree(run, ignore_errors=True)
        for name, op, _ in item[0]:
            if op == "tear_last_line" and name in r.streams:
                assert name in r.torn, f"{name}: a torn last line dropped without saying so"
        return "replayed" + (" (torn noted)" if r.torn else "")

    for edits in CORPUS if fuzz_tier == "fuzz" else CORPUS_FAST:
        harness.check("run folder -> replay", feed, (edits, b""), (LogFormatError,))
    harness.run(
        FOLDERS,
        lambda it: harness.check("run folder -> replay", feed, it, (LogFormatError,)),
        run_folder_budget,
    )


def test_run_folders_into_report(fuzz_run, tmp_path, fuzz_tier, run_folder_budget) -> None:
    n = itertools.count()

    def feed(item: tuple[list[tuple[str, str, int]], bytes]) -> str:
        k = next(n)
        run = _folder(fuzz_run, tmp_path, k, item)
        try:
            results = make_report(run, tmp_path / f"report{k}")
        except LogFormatError as err:
            assert _names_a_file(err, run, fuzz_run), f"the error names no file of the run: {err}"
            raise
        finally:
            shutil.rmtree(run, ignore_errors=True)
        for res in results:
            assert res.path is not None or res.skipped, f"{res.name}: neither drawn nor skipped with a reason"
        return "report" + (" (figures skipped)" if any(res.skipped for res in results) else "")

    for edits in CORPUS if fuzz_tier == "fuzz" else CORPUS_FAST:
        harness.check("run folder -> report", feed, (edits, b""), (LogFormatError,))
    harness.run(
        FOLDERS,
        lambda it: harness.check("run folder -> report", feed, it, (LogFormatError,)),
        run_folder_budget,
    )
