"""The logging process (:mod:`companion.flightlog.logproc`): the logs it writes are the bytes the
in-process path writes; a parent that crashes leaves complete files; a child that cannot start,
dies, or cannot write its file is reported and nothing queued is lost."""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader

from companion.flightlog import logproc
from companion.flightlog.csv_file import read_csv
from companion.flightlog.csvlog import CsvLog, close_logs
from companion.flightlog.logproc import LogProcess
from companion.flightlog.losses import Loss, LossCause, losses
from companion.flightlog.mcap_encoding import stream_topic
from companion.flightlog.mcaplog import McapFlightLog

from .conftest import wait_gone

COLS = ("time_s", "x_m", "n", "label", "y_m")
STREAMS = {"a.csv": COLS}


def _rows(n: int) -> list[tuple[object, ...]]:
    rng = np.random.default_rng(5)
    out: list[tuple[object, ...]] = []
    for i in range(n):
        x = float(rng.normal(0.0, 10.0 ** rng.integers(-12, 12)))
        out.append((i * 0.01, x if i % 3 else np.float64(x), i, ["", "a,b", 'q"t', "ok"][i % 4], math.nan))
    return out


def _messages(path: Path) -> dict[str, list[bytes]]:
    with path.open("rb") as fh:
        reader = make_reader(fh)
        assert reader.get_summary() is not None  # closed: the summary is there
        out: dict[str, list[bytes]] = {}
        for _, channel, message in reader.iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append(message.data)
    return out


def test_the_logging_process_writes_the_bytes_the_in_process_path_writes(tmp_path, monkeypatch):
    rows = _rows(2000)
    ref = io.StringIO(newline="")
    w = csv.writer(ref)
    w.writerow(COLS)
    w.writerows(rows)
    with CsvLog(tmp_path / "remote.csv", COLS, max_queue=10**6) as lg:
        assert not lg.in_process and LogProcess._current is not None and LogProcess._current.child.pid != os.getpid()
        for i, row in enumerate(rows):
            lg.write(row)
            if i % 500 == 0:
                lg.drain()  # handed over mid-stream, as the writer thread would
    assert (lg.written, lg.dropped) == (len(rows), 0)
    monkeypatch.setattr(logproc, "IN_PROCESS", True)
    with CsvLog(tmp_path / "local.csv", COLS, max_queue=10**6) as local:
        assert local.in_process
        for row in rows:
            local.write(row)
    want = ref.getvalue().encode("utf-8")
    assert (tmp_path / "remote.csv").read_bytes() == want == (tmp_path / "local.csv").read_bytes()


def test_one_logging_process_for_every_log(tmp_path):
    logs = [CsvLog(tmp_path / f"{i}.csv", ("time_s",)) for i in range(5)]
    procs = {id(lg.log_process) for lg in logs}
    for lg in logs:
        lg.close()
    assert len(procs) == 1 and None not in {lg.log_process for lg in logs}


_CRASH = """
import os, sys, time
from companion.flightlog import logproc
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.logproc import LogProcess
from companion.flightlog.mcaplog import McapFlightLog
run = sys.argv[1]
if len(sys.argv) > 2:  # a logging process slow to start: ready only after this many seconds
    logproc.CHILD_COMMAND = [sys.executable, "-c", "import runpy, sys, time; time.sleep(" + sys.argv[2] + "); "
        "runpy.run_module('companion.flightlog.logproc_child', run_name='__main__')"]
cols = ("time_s", "x_m")
m = McapFlightLog(run + "/flight.mcap", {"a.csv": cols})
lg = CsvLog(run + "/a.csv", cols, sink=m.stream_sink("a.csv"))
plain = CsvLog(run + "/b.csv", cols)
for i in range(300):
    lg.write((float(i), 0.5 * i))
    plain.write((float(i), -0.5 * i))
m.add_meta('{"closed": false}')
# the writer thread hands everything over (waiting on its count: a loaded machine delays it)
deadline = time.monotonic() + 30.0
while (lg.written < 300 or plain.written < 300) and time.monotonic() < deadline:
    time.sleep(0.01)
time.sleep(1.0)  # and the hand-over after it carries the metadata
print(LogProcess._current.child.pid, LogProcess._current.ready, flush=True)
os._exit(1)  # a crash: no close(), no atexit
"""


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="waits on /proc")
@pytest.mark.parametrize("child_start_delay_s", [None, "4"])
def test_a_crashed_parent_leaves_complete_files(tmp_path, child_start_delay_s):
    argv = [sys.executable, "-c", _CRASH, str(tmp_path), *([child_start_delay_s] if child_start_delay_s else [])]
    proc = subprocess.run(argv, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    pid, ready = proc.stdout.split()
    if child_start_delay_s:  # the parent died before its logging process was ready: nothing lost
        assert ready == "False"
    wait_gone(int(pid))
    a, b = read_csv(tmp_path / "a.csv"), read_csv(tmp_path / "b.csv")
    assert len(a["time_s"]) == len(b["time_s"]) == 300 and b["x_m"][-1] == "-149.5"
    msgs = _messages(tmp_path / "flight.mcap")  # the child closed it: summary and all
    assert [json.loads(m)["x_m"] for m in msgs[stream_topic("a.csv")]] == [0.5 * i for i in range(300)]
    with (tmp_path / "flight.mcap").open("rb") as fh:
        meta = [m.metadata for m in make_reader(fh).iter_metadata()]
    assert meta == [{"json": '{"closed": false}'}]


def test_a_dead_logging_process_hands_the_logs_back(tmp_path, own_process, caplog):
    cols = ("time_s", "x_m")
    m = McapFlightLog(tmp_path / "flight.mcap", {"a.csv": cols})
    lg = CsvLog(tmp_path / "a.csv", cols, sink=m.stream_sink("a.csv"))
    plain = CsvLog(tmp_path / "b.csv", cols)
    proc = LogProcess._current
    assert proc is not None and not lg.in_process
    for i in range(100):
        lg.write((float(i), 1.0 * i))
        plain.write((float(i), 2.0 * i))
    lg.drain()
    plain.drain()
    assert proc.cpu_s() is not None  # an answer: everything before it was written
    proc.child.kill()
    proc.child.wait()
    for i in range(100, 250):
        lg.write((float(i), 1.0 * i))
        plain.write((float(i), 2.0 * i))
    with caplog.at_level(logging.ERROR):
        lg.close()  # the hand-over fails: the rest is written here
        plain.close()
        m.close()
    assert lg.in_process and plain.in_process
    for p, k in ((tmp_path / "a.csv", 1.0), (tmp_path / "b.csv", 2.0)):
        cols_ = read_csv(p)
        assert cols_["x_m"] == [str(k * i) for i in range(250)], p
    died = [r for r in caplog.records if "logging process" in r.getMessage()]
    assert any("written in this process" in r.getMessage() and "exit code" in r.getMessage() for r in died)
    assert sum("written in this process" in r.getMessage() for r in died) == 1
    assert m.errors == 1 and any("the MCAP ends where it stopped" in r.getMessage() for r in died)
    # logs opened afterwards write in process; nothing raised into the caller
    with CsvLog(tmp_path / "c.csv", cols) as after:
        after.write((0.0, 0.0))
    assert after.in_process and read_csv(tmp_path / "c.csv")["x_m"] == ["0.0"]


def test_a_logging_process_that_never_starts_leaves_the_logs_in_process(tmp_path, own_process, monkeypatch, caplog):
    monkeypatch.setattr(logproc, "CHILD_COMMAND", [sys.executable, "-c", "raise SystemExit(3)"])
    cols = ("time_s", "x_m")
    with caplog.at_level(logging.ERROR):
        m = McapFlightLog(tmp_path / "flight.mcap", {"a.csv": cols})
        lg = CsvLog(tmp_path / "a.csv", cols, sink=m.stream_sink("a.csv"))
        for i in range(50):
            lg.write((float(i), 3.0 * i))
        m.add_meta("{}")
        lg.close()
        m.close()
    assert lg.in_process and read_csv(tmp_path / "a.csv")["x_m"] == [str(3.0 * i) for i in range(50)]
    # it never started the MCAP: written here in full
    assert len(_messages(tmp_path / "flight.mcap")[stream_topic("a.csv")]) == 50 and m.errors == 0
    assert [r.getMessage() for r in caplog.records if "logging process" in r.getMessage()] == [
        msg for msg in [r.getMessage() for r in caplog.records] if "exit code 3" in msg
    ]
    assert len([r for r in caplog.records if "exit code 3" in r.getMessage()]) == 1


def test_a_logging_process_that_cannot_be_spawned(tmp_path, own_process, monkeypatch, caplog):
    def no_spawn(*a, **k):
        raise OSError("no interpreter here")

    monkeypatch.setattr(logproc.subprocess, "Popen", no_spawn)
    with caplog.at_level(logging.ERROR):
        logs = [CsvLog(tmp_path / f"{i}.csv", ("time_s",)) for i in range(3)]
        for lg in logs:
            lg.write((1.5,))
            lg.close()
    assert all(lg.in_process for lg in logs) and read_csv(tmp_path / "2.csv")["time_s"] == ["1.5"]
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs == ["flight logs: cannot start the logging process (no interpreter here); writing in this process"]


@pytest.mark.skipif(not Path("/dev/full").exists(), reason="needs /dev/full")
def test_a_write_error_in_the_logging_process_is_logged_once_by_path(tmp_path, caplog):
    p = tmp_path / "full.csv"
    lg = CsvLog(p, ("time_s", "x_m"))
    assert not lg.in_process
    p.unlink()
    p.symlink_to("/dev/full")  # the logging process opens it at its first batch: every write fails
    with caplog.at_level(logging.ERROR):
        for _ in range(3):
            for i in range(10):
                lg.write((float(i), 0.0))
            lg.drain()
            logproc.flush_current()
        lg.close()
    errors = [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]
    # once, by path and cause, when it stopped; then once what it lost, at its close
    assert sum("cannot write the log any more" in e for e in errors) == 1, errors
    assert [e for e in errors if not e.startswith(f"{p}: disk full: ")] == [
        f"disk full: 30 rows of full.csv lost ({p.parent})"
    ], errors
    assert (lg.written, lg.dropped) == (0, 30)
    assert losses(tmp_path) == [Loss(p, LossCause.DISK_FULL, 30, "rows")]


def test_the_in_process_switch(tmp_path, monkeypatch):
    monkeypatch.setattr(logproc, "IN_PROCESS", True)
    m = McapFlightLog(tmp_path / "flight.mcap", STREAMS)
    with CsvLog(tmp_path / "a.csv", COLS, sink=m.stream_sink("a.csv")) as lg:
        for row in _rows(10):
            lg.write(row)
    m.close()
    assert lg.in_process and m.in_process
    assert len(_messages(tmp_path / "flight.mcap")[stream_topic("a.csv")]) == 10 and m.messages > 10


def test_an_mcap_the_logging_process_cannot_create_is_an_error_not_a_hang(tmp_path, own_process, caplog):
    cols = ("time_s", "x_m")
    m = McapFlightLog(tmp_path / "flight.mcap", {"a.csv": cols})
    (tmp_path / "flight.mcap").unlink()
    (tmp_path / "flight.mcap").mkdir()  # the logging process cannot open it
    with caplog.at_level(logging.ERROR):
        with CsvLog(tmp_path / "a.csv", cols, sink=m.stream_sink("a.csv")) as lg:
            lg.write((0.0, 1.0))
        m.close()
    assert not lg.in_process and read_csv(tmp_path / "a.csv")["x_m"] == ["1.0"]
    assert m.errors == 1 and any("mcap op failed" in r.getMessage() for r in caplog.records)
    assert not LogProcess._current.dead  # type: ignore[union-attr]


def test_closing_several_logs_waits_for_the_logging_process_once(tmp_path, monkeypatch):
    cols = ("time_s", "x_m")
    logs = [CsvLog(tmp_path / f"{k}.csv", cols) for k in range(5)]
    proc = LogProcess._current
    assert proc is not None and not any(lg.in_process for lg in logs)
    for k, lg in enumerate(logs):
        for i in range(50 + k):
            lg.write((float(i), k * 1.0 + i))
    waits: list[int] = []
    orig = LogProcess.request_all

    def counted(self: LogProcess, ops: list[tuple[object, ...]]) -> list[object]:
        waits.append(len(ops))
        return orig(self, ops)

    monkeypatch.setattr(LogProcess, "request_all", counted)
    close_logs([*logs, logs[0]])  # a log named twice is closed once
    assert waits == [5]  # every close in one message, one wait for the five answers
    for k, lg in enumerate(logs):
        assert lg.closed and not lg.in_process and lg.written == 50 + k and lg.dropped == 0
        assert read_csv(tmp_path / f"{k}.csv")["x_m"] == [str(k * 1.0 + i) for i in range(50 + k)]
    close_logs(logs)  # idempotent
    assert waits == [5]


def test_a_logging_process_that_dies_before_a_batched_close_leaves_every_log_complete(tmp_path, own_process, caplog):
    cols = ("time_s", "x_m")
    logs = [CsvLog(tmp_path / f"{k}.csv", cols) for k in range(3)]
    proc = LogProcess._current
    assert proc is not None
    for lg in logs:
        for i in range(40):
            lg.write((float(i), 0.5 * i))
        lg.drain()
    assert proc.cpu_s() is not None  # answered: the first 40 rows of each are written
    proc.child.kill()
    proc.child.wait()
    for lg in logs:
        for i in range(40, 90):
            lg.write((float(i), 0.5 * i))
    with caplog.at_level(logging.ERROR):
        close_logs(logs)
    for k, lg in enumerate(logs):
        assert lg.in_process and lg.closed
        assert read_csv(tmp_path / f"{k}.csv")["x_m"] == [str(0.5 * i) for i in range(90)]
    assert sum("written in this process" in r.getMessage() for r in caplog.records) == 1


def test_request_all_answers_none_for_what_a_dead_process_did_not_answer(own_process):
    proc = LogProcess.get()
    assert proc is not None
    assert proc.request_all([("cpu",), ("cpu",)])[1] is not None
    proc.child.kill()
    proc.child.wait()
    assert proc.request_all([("cpu",), ("cpu",)]) == [None, None]
    assert proc.dead


def test_rows_queued_while_the_writer_takes_a_batch_are_neither_lost_nor_doubled(tmp_path):
    """The writer takes a log's batch by slicing its list while the producer appends: every row
    is written once, in order (the flush period made as short as it goes)."""
    cols = ("time_s", "i")
    n = 60_000
    with CsvLog(tmp_path / "a.csv", cols, max_queue=n, flush_period_s=1e-4) as lg:
        done = threading.Event()

        def produce() -> None:
            for i in range(n):
                lg.put((i * 0.5, i))
            done.set()

        t = threading.Thread(target=produce)
        t.start()
        while not done.is_set():
            lg.drain()  # the writer thread drains too: two takers, one producer
        t.join()
    got = read_csv(tmp_path / "a.csv")["i"]
    assert got == [str(i) for i in range(n)] and lg.written == n and lg.dropped == 0


def test_the_writer_hands_over_before_the_period_while_rows_come_fast(tmp_path):
    """Rows that come faster than HANDOVER_ROWS a period are looked at every WAKE_PERIOD_S and
    handed over once HANDOVER_ROWS wait, before the period is over; fewer wait for the period."""
    from companion.flightlog import handover

    n = handover.HANDOVER_ROWS

    def wait_written(lg: CsvLog, rows: int, within_s: float) -> None:
        deadline = time.monotonic() + within_s
        while lg.written < rows and time.monotonic() < deadline:
            time.sleep(0.005)
        assert lg.written == rows

    with CsvLog(tmp_path / "a.csv", ("time_s", "x"), flush_period_s=2.0) as lg:
        assert not lg.in_process  # handed to the logging process: `written` counts the rows handed over
        for k in range(n + 50):  # faster than n rows a period: the first round (at 2 s) says so
            lg.write((float(k), 1.0))
        wait_written(lg, n + 50, 5.0)
        t0 = time.monotonic()
        for k in range(10):
            lg.write((float(k), 2.0))
        while time.monotonic() - t0 < 0.5:  # under HANDOVER_ROWS: they wait for the period
            assert lg.written == n + 50
            time.sleep(0.05)
        for k in range(n):
            lg.write((float(k), 3.0))
        wait_written(lg, 2 * n + 60, 1.0)  # the period is over ~2 s after the first round, not yet
    assert len(read_csv(tmp_path / "a.csv")["x"]) == 2 * n + 60


_REALTIME_PARENT = """
import os, time
from companion.flightlog.logproc import LogProcess
from companion.scheduling import set_thread_realtime
why = set_thread_realtime(5)
if why is not None:
    print("refused", why.split()[0], flush=True)
    raise SystemExit(0)
proc = LogProcess.get()
inherited = os.sched_getscheduler(proc.child.pid)  # before the child's interpreter has started
deadline = time.monotonic() + 30.0
while os.sched_getscheduler(proc.child.pid) != os.SCHED_OTHER and time.monotonic() < deadline:
    time.sleep(0.05)
print(os.sched_getscheduler(0), inherited, os.sched_getscheduler(proc.child.pid), flush=True)
"""


def test_the_logging_process_leaves_the_real_time_policy_it_inherits():
    proc = subprocess.run([sys.executable, "-c", _REALTIME_PARENT], capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    out = proc.stdout.split()
    if out[0] == "refused":
        pytest.skip("SCHED_RR refused on this machine")
    parent, inherited, child = map(int, out)
    assert parent == inherited == os.SCHED_RR  # the child started real time, from its parent
    assert child == os.SCHED_OTHER
