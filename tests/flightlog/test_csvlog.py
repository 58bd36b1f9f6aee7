import multiprocessing as mp
import struct
import subprocess
import sys

import numpy as np
import pytest

from companion.delivery.observers import FLIGHT_LOG_COLUMNS
from companion.flightlog import CsvLog, read_csv


def test_header_time_first_and_units(tmp_path):
    with CsvLog(tmp_path / "a.csv", ("time_s", "north_m", "speed_m_s")) as lg:
        lg.write((0.5, 1.0, 2.0))
    cols = read_csv(tmp_path / "a.csv")
    assert list(cols) == ["time_s", "north_m", "speed_m_s"]
    assert cols["north_m"] == ["1.0"]
    with pytest.raises(ValueError, match="time_s"):
        CsvLog(tmp_path / "b.csv", ("north_m",))


def test_flight_log_columns_carry_units():
    unitless = {"phase", "sector", "mode", "armed", "clamped"}
    for c in FLIGHT_LOG_COLUMNS:
        assert c in unitless or c.rsplit("_", 1)[-1] in ("s", "m", "m2", "rad") or c.endswith("_m_s"), c


def test_row_length_checked(tmp_path):
    with CsvLog(tmp_path / "a.csv", ("time_s", "x_m")) as lg, pytest.raises(ValueError, match="1 fields"):
        lg.write((1.0,))


def _crash_after_rows(path, n):
    import os
    import time

    lg = CsvLog(path, ("time_s", "x_m"))
    for i in range(n):
        lg.write((float(i), 2.0 * i))
    # the writer flushes each period without close(): wait (up to 30 s, a loaded machine delays the
    # writer) until the rows are in the file, then crash; a writer that only flushed on close
    # leaves the file without them
    deadline = time.monotonic() + 30.0
    while path.read_bytes().count(b"\n") < n + 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    os._exit(1)  # a crash: no close(), no atexit


def test_rows_survive_a_crash(tmp_path):
    p = tmp_path / "crash.csv"
    proc = mp.get_context("fork").Process(target=_crash_after_rows, args=(p, 100))
    proc.start()
    proc.join(60)
    assert proc.exitcode == 1
    cols = read_csv(p)
    assert len(cols["time_s"]) == 100 and cols["x_m"][-1] == "198.0"


def test_floats_round_trip_exactly(tmp_path):
    rng = np.random.default_rng(7)
    values = [*rng.normal(0.0, 1e3, 200), *rng.uniform(-1e-9, 1e-9, 50), 0.1, -0.0, 1e300, 5e-324, np.float64(2) / 3]
    with CsvLog(tmp_path / "f.csv", ("time_s", "x_m")) as lg:
        for i, v in enumerate(values):
            lg.write((float(i), v))
    back = [float(v) for v in read_csv(tmp_path / "f.csv")["x_m"]]
    assert [struct.pack("<d", v) for v in back] == [struct.pack("<d", float(v)) for v in values]
    assert read_csv(tmp_path / "f.csv")["x_m"][-4] == "-0.0"


def test_open_logs_are_drained_and_closed_at_interpreter_exit(tmp_path):
    # many rows handed to the writer thread, then a normal exit without close(): the atexit hook
    # drains the queue (the writer is a daemon thread and would otherwise die with rows queued)
    p = tmp_path / "exit.csv"
    code = (
        "from companion.flightlog import CsvLog\n"
        f"lg = CsvLog({str(p)!r}, ('time_s', 'x_m'), max_queue=100000)\n"
        "for i in range(60000):\n"
        "    lg.write((float(i), 0.5 * i))\n"
        "raise SystemExit(3)\n"
    )
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 3, proc.stderr
    cols = read_csv(p)
    assert len(cols["time_s"]) == 60000 and cols["x_m"][-1] == "29999.5"


def test_a_last_line_cut_without_its_newline_is_torn_even_with_every_field(tmp_path, caplog):
    from companion.flightlog.reader import LogFormatError, Table

    f = tmp_path / "ap_position.csv"
    f.write_text("time_s,seq,north_m\r\n0.0,0,1.25\r\n0.05,1,1.5", encoding="utf-8")  # "1.5" of "1.5625\r\n"
    t = Table(f)
    assert t.torn and len(t) == 1 and t.floats("north_m").tolist() == [1.25]
    assert "torn last line dropped (no newline at its end)" in caplog.text
    f.write_text("time_s,seq,north_m\r\n0.0,0,1.25\r\n0.05,1,1.5\r\n", encoding="utf-8")
    t = Table(f)
    assert not t.torn and t.floats("north_m").tolist() == [1.25, 1.5]
    f.write_text("time_s,seq,north_m\r\n0.0,0\r\n0.05,1,1.5", encoding="utf-8")  # only one tear at the end
    with pytest.raises(LogFormatError, match="line 2: 2 fields, the header has 3"):
        Table(f)
