import multiprocessing as mp

import pytest

from companion.app import FLIGHT_LOG_COLUMNS
from companion.flightlog import CsvLog, read_csv


def test_header_time_first_and_units(tmp_path):
    with CsvLog(tmp_path / "a.csv", ("time_s", "north_m", "speed_m_s")) as lg:
        lg.write((0.5, 1.0, 2.0))
    cols = read_csv(tmp_path / "a.csv")
    assert list(cols) == ["time_s", "north_m", "speed_m_s"]
    assert cols["north_m"] == ["1.000000"]
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
    time.sleep(0.5)  # the writer thread flushes as it goes
    os._exit(1)  # a crash: no close(), no atexit


def test_rows_survive_a_crash(tmp_path):
    p = tmp_path / "crash.csv"
    proc = mp.get_context("fork").Process(target=_crash_after_rows, args=(p, 100))
    proc.start()
    proc.join(10)
    assert proc.exitcode == 1
    cols = read_csv(p)
    assert len(cols["time_s"]) == 100 and cols["x_m"][-1] == "198.000000"
