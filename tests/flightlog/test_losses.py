"""Storage faults in the log writers: a full disk (ENOSPC) or an I/O error stops the file, never
the caller; what is lost is counted, said once by cause and count, and known by run folder
(``companion.flightlog.losses``). Each writer is given a file that fails through its public
``fh`` seam, or a real full tmpfs where the writer (the MCAP SDK, the logging process) opens its
own file."""

from __future__ import annotations

import errno
import io
import logging
import time
from pathlib import Path

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.autopilot.mavlink_messages import MavlinkPacker
from companion.autopilot.types import FlightMode
from companion.flightlog import logproc
from companion.flightlog.csv_file import CsvFile, read_csv
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.losses import (
    Loss,
    LossCause,
    cause_of,
    describe,
    fault_of,
    forget,
    logs_incomplete,
    losses,
    note_fault,
    note_lost,
)
from companion.flightlog.mcap_file import McapFile
from companion.flightlog.tlog import read_tlog
from companion.flightlog.tlog_replay import TlogReplayer
from companion.flightlog.tlog_writer import TlogWriter
from companion.guidance.setpoint import VelocitySetpoint

from ..tmpfs import fill, mounted_tmpfs

T0 = 1_700_000_000.0
ENOSPC = OSError(errno.ENOSPC, "No space left on device")


class DiskFills:
    """A file that takes ``room`` bytes, then raises ENOSPC on every write (a full disk)."""

    def __init__(self, real: io.IOBase, room: int) -> None:
        self.real = real
        self.room = room
        self.closed = False

    def write(self, data: str | bytes) -> int:
        if len(data) > self.room:
            raise OSError(errno.ENOSPC, "No space left on device")
        self.room -= len(data)
        return self.real.write(data)  # type: ignore[arg-type]

    def flush(self) -> None:
        self.real.flush()

    def fileno(self) -> int:
        return self.real.fileno()

    def close(self) -> None:
        self.closed = True
        self.real.close()


def _errors(caplog: pytest.LogCaptureFixture) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.levelno >= logging.ERROR]


@pytest.mark.parametrize(
    "code, cause",
    [
        (errno.ENOSPC, LossCause.DISK_FULL),
        (errno.EDQUOT, LossCause.DISK_FULL),
        (errno.EROFS, LossCause.READ_ONLY),
        (errno.EIO, LossCause.IO_ERROR),
    ],
)
def test_the_cause_is_the_errno(code: int, cause: LossCause):
    assert cause_of(OSError(code, "x")) is cause


def test_an_error_without_errno_is_named_by_the_disk(tmp_path: Path):
    assert cause_of(RuntimeError("I/O error from writing"), tmp_path / "f") is LossCause.IO_ERROR
    with mounted_tmpfs(tmp_path / "full", "1m") as d:
        fill(d)
        assert cause_of(RuntimeError("I/O error from writing"), d / "f") is LossCause.DISK_FULL
    with mounted_tmpfs(tmp_path / "ro", "1m", read_only=True) as d:
        assert cause_of(RuntimeError("I/O error from writing"), d / "f") is LossCause.READ_ONLY


def test_losses_are_kept_by_run_folder_and_described(tmp_path: Path, caplog):
    run, other = tmp_path / "run", tmp_path / "other"
    assert not logs_incomplete(run) and describe(run) == ""
    note_fault(run / "ekf.csv", LossCause.DISK_FULL)
    note_fault(run / "ekf.csv", LossCause.IO_ERROR)  # the first cause is kept
    assert fault_of(run / "ekf.csv") is LossCause.DISK_FULL
    assert logs_incomplete(run) and not logs_incomplete(other)
    with caplog.at_level(logging.WARNING):
        note_lost(run / "flight.csv", LossCause.DISK_FULL, 483)
        note_lost(run / "ekf.csv", LossCause.DISK_FULL, 469)
        note_lost(run / "imu.csv", LossCause.QUEUE_FULL, 3)
        note_lost(run / "gps.csv", LossCause.DISK_FULL, 0)  # nothing lost: nothing said
    assert [r.getMessage() for r in caplog.records] == [
        f"disk full: 483 rows of flight.csv lost ({run})",
        f"disk full: 469 rows of ekf.csv lost ({run})",
        f"the writer could not keep up: 3 rows of imu.csv lost ({run})",
    ]
    assert [r.levelno for r in caplog.records] == [logging.ERROR, logging.ERROR, logging.WARNING]
    assert losses(run) == [
        Loss(run / "ekf.csv", LossCause.DISK_FULL, 469, "rows"),
        Loss(run / "flight.csv", LossCause.DISK_FULL, 483, "rows"),
        Loss(run / "imu.csv", LossCause.QUEUE_FULL, 3, "rows"),
    ]
    assert describe(run) == (
        "logs incomplete: disk full (flight.csv 483 rows, ekf.csv 469 rows); "
        "the writer could not keep up (imu.csv 3 rows)"
    )
    note_fault(other / "ekf.csv", LossCause.IO_ERROR)
    forget(run)  # a new run in that folder
    assert not logs_incomplete(run) and losses(run) == [] and logs_incomplete(other)


def test_a_csv_file_on_a_disk_that_fills_stops_and_counts(tmp_path: Path, caplog):
    p = tmp_path / "flight.csv"
    fh = DiskFills(p.open("w", newline="", encoding="utf-8"), room=200)
    f = CsvFile(p, ("time_s", "x_m"), fh=fh)  # type: ignore[arg-type]
    rows = [(float(i), 0.25) for i in range(10)]  # "0.0,0.25\r\n": 10 lines, about 110 bytes
    with caplog.at_level(logging.ERROR):
        for _ in range(4):
            f.write_batch(rows)  # never raises
        f.close()
    assert (f.written, f.dropped) == (10, 30)
    assert f.failed is not None and f.failed.errno == errno.ENOSPC
    assert fault_of(p) is LossCause.DISK_FULL
    assert _errors(caplog) == [
        f"{p}: disk full: cannot write the log any more ([Errno 28] No space left on device); the flight goes on"
    ]
    kept = read_csv(p)["time_s"]  # everything before is kept, and part of the batch that failed at most
    assert kept[:10] == [str(float(i)) for i in range(10)] and len(kept) < 20


@pytest.mark.parametrize("in_process", [True, False], ids=["in-process", "logging-process"])
def test_a_csv_log_on_a_full_disk_says_how_many_rows_it_lost(tmp_path: Path, caplog, monkeypatch, in_process):
    monkeypatch.setattr(logproc, "IN_PROCESS", in_process)
    with mounted_tmpfs(tmp_path / "disk", "1m") as d:
        p = d / "flight.csv"
        lg = CsvLog(p, ("time_s", "x_m"))
        assert lg.in_process is in_process
        for i in range(20):
            lg.write((float(i), 1.0))
        lg.drain()
        logproc.flush_current()
        fill(d)
        with caplog.at_level(logging.WARNING):
            for k in range(3):  # well past the file's last page: every later batch is lost
                for i in range(2000):
                    lg.write((float(k * 2000 + i), 1.0 / 3.0))
                lg.drain()
                logproc.flush_current()
            # the flight's process knows before the close, also from the logging process
            deadline = time.monotonic() + 10.0
            while fault_of(p) is None and time.monotonic() < deadline:
                logproc.flush_current()
                time.sleep(0.02)
            assert fault_of(p) is LossCause.DISK_FULL
            assert logs_incomplete(d)
            lg.close()
        lost = [x for x in losses(d) if x.lost]
        assert lost == [Loss(p, LossCause.DISK_FULL, lg.dropped, "rows")] and lg.dropped > 0
        assert lg.written + lg.dropped == 6020
        lines = [r.getMessage() for r in caplog.records]
        assert f"disk full: {lg.dropped} rows of flight.csv lost ({d})" in lines, lines
        assert not any("could not keep up" in m for m in lines), lines


def test_an_mcap_on_a_full_disk_is_named_disk_full(tmp_path: Path, caplog):
    cols = ("time_s", "x_m")
    with mounted_tmpfs(tmp_path / "disk", "1m") as d:
        m = McapFile(d / "flight.mcap", {"a.csv": cols})
        fill(d)
        sink = m.stream_sink("a.csv")
        rows = [(float(i), float(i) / 7.0) for i in range(20000)]
        with caplog.at_level(logging.ERROR):
            for k in range(0, len(rows), 2000):
                batch = rows[k : k + 2000]
                _text, payloads = sink.encode(batch)
                sink.publish(batch, payloads)  # never raises
                m.flush()
            m.close()
        assert m.errors >= 1 and fault_of(d / "flight.mcap") is LossCause.DISK_FULL
        assert sum("cannot write the MCAP any more" in e for e in _errors(caplog)) == 1


def _replayer_params() -> dict[str, object]:
    return {"boot_s": 0.0, "epoch_s": T0, "custom_modes": {m: 0 for m in FlightMode}, "encoder": {}}


def test_a_simulator_tlog_on_a_disk_that_fills_stops_and_counts(tmp_path: Path, caplog):
    p = tmp_path / "flight.tlog"
    fh = DiskFills(p.open("wb", buffering=0), room=400)
    r = TlogReplayer(p, _replayer_params(), append=False, fh=fh)  # type: ignore[arg-type]
    batch = [(0.1 * i, VelocitySetpoint, 1.0, 0.0, 0.0, 0.0) for i in range(5)]
    with caplog.at_level(logging.ERROR):
        for _ in range(4):
            r.apply(batch)  # never raises
        r.close()
    assert r.written == 5 and r.dropped == 15 and r.failed is not None
    assert fault_of(p) is LossCause.DISK_FULL
    assert sum("disk full: cannot write the MAVLink log any more" in e for e in _errors(caplog)) == 1
    assert len(list(read_tlog(p))) == 5


def test_a_link_tlog_on_a_disk_that_fills_stops_and_counts(tmp_path: Path, caplog):
    packer = MavlinkPacker()
    p = tmp_path / "g.tlog"
    w = TlogWriter(p, clock=lambda: T0, fh=DiskFills(p.open("wb", buffering=0), room=30 * 25))  # type: ignore[arg-type]
    hb = lambda k: packer.pack(mav2.MAVLink_heartbeat_message(2, 12, 0, k, 4, 3), 1, 1)  # noqa: E731
    with caplog.at_level(logging.WARNING):
        for k in range(20):
            w.write(hb(k))
        assert w.flush()
        for k in range(20, 40):
            w.write(hb(k))  # never raises
        assert not w.flush()
        assert not w.write(hb(40))  # refused and counted
        w.close()
    assert fault_of(p) is LossCause.DISK_FULL
    assert w.written == 20 and w.dropped == 21 and w.queue_dropped == 0
    assert f"disk full: 21 MAVLink packets of g.tlog lost ({tmp_path})" in [r.getMessage() for r in caplog.records]
    assert [m.custom_mode for m in read_tlog(p)] == list(range(20))
