"""The simulator's ``.tlog`` encoded off the control path (:class:`TelemetryTlog`): the same
bytes as a :class:`TelemetryEncoder` writing at once, through the logging process and in
process; a parent killed outright leaves every record it handed over; a logging process that
dies or never starts leaves the file to this process, with one ERROR."""

from __future__ import annotations

import dataclasses
import logging
import math
import struct
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    PositionNed,
    StatusText,
    VehicleStatus,
)
from companion.flightlog import logproc
from companion.flightlog.logproc import LogProcess
from companion.flightlog.recorder import FlightRecorder
from companion.flightlog.streams import SAMPLE_ENCODERS, SAMPLE_FILES
from companion.flightlog.telemetry_tlog import TelemetryTlog
from companion.flightlog.tlog import cut_torn_record, read_tlog, record_time_s
from companion.flightlog.tlog_encoder import TelemetryEncoder
from companion.flightlog.tlog_replay import sample_from_row
from companion.flightlog.tlog_writer import TlogWriter
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.px4 import px4_custom_mode

from .conftest import short_config, wait_gone

EPOCH = 1_735_689_600.0
BOOT = 3.0


def _calls(n: int, seed: int = 7) -> list[tuple[float, str, Any]]:
    """A flight's worth of encoder calls: (clock time, method, argument)."""
    rng = np.random.default_rng(seed)
    out: list[tuple[float, str, Any]] = []
    t = BOOT
    modes, landed = list(FlightMode), list(LandedState)
    for i in range(n):
        t += float(rng.uniform(0.0, 0.01))
        k = i % 11
        x = [float(v) for v in rng.normal(0.0, 10.0, 7)]
        if k in (0, 1):
            out.append((t, "sample", Attitude(t, *x[:6])))
        elif k == 2:
            out.append((t, "sample", Imu(t, *x[:6])))
        elif k == 3:
            out.append((t, "sample", PositionNed(t, *x[:6])))
        elif k == 4:
            out.append((t, "sample", GlobalPosition(t, -19.8 + x[0] * 1e-5, -43.9 + x[1] * 1e-5, 870.0, x[2])))
        elif k == 5:
            eph = math.inf if i % 4 == 1 else abs(x[3])
            out.append((t, "sample", GpsRaw(t, -19.8, -43.9, 870.0 + x[0], 3, 12, eph)))
        elif k == 6:
            mode, ld = modes[i % len(modes)], landed[i % len(landed)]
            out.append((t, "sample", VehicleStatus(t, i % 2 == 0, mode, ld, True, 50.0 + x[0], False)))
        elif k == 7:
            out.append((t, "sample", HomePosition(t, -19.8, -43.9, 870.0, x[0], x[1], x[2])))
        elif k == 8:
            out.append((t, "setpoint", VelocitySetpoint(*x[:4])))
        elif k == 9:
            out.append(
                (t, "command", (176, (1.0, 6.0)) if i % 2 else (22, (0.0, 0.0, 0.0, float("nan"), 0.0, 0.0, 5.0)))
            )
        else:
            out.append((t, "command_ack", (176, i % 5)) if i % 3 else (t, "sample", StatusText(t, 4, f"text {i}")))
    return out


def _replay(calls: list[tuple[float, str, Any]], target: Any, clock: list[float]) -> None:
    for t, what, arg in calls:
        clock[0] = t
        if what in ("command", "command_ack"):
            getattr(target, what)(*arg)
        else:
            getattr(target, what)(arg)


def _at_once(path: Path, calls: list[tuple[float, str, Any]]) -> bytes:
    """The file a TelemetryEncoder writing each packet at once gives (the previous code path)."""
    clock = [0.0]
    with TlogWriter(path, drop_when_full=False, clock=lambda: EPOCH + clock[0]) as w:
        enc = TelemetryEncoder(w, boot_s=BOOT, clock=lambda: clock[0], custom_mode=px4_custom_mode)
        _replay(calls, enc, clock)
    return path.read_bytes()


def _tlog(path: Path, clock: list[float]) -> TelemetryTlog:
    return TelemetryTlog(path, boot_s=BOOT, clock=lambda: clock[0], epoch_s=EPOCH, custom_mode=px4_custom_mode)


def test_the_same_bytes_through_the_logging_process_and_in_process(tmp_path, monkeypatch):
    calls = _calls(3000)
    want = _at_once(tmp_path / "ref.tlog", calls)
    assert len(want) > 100_000
    clock = [0.0]
    remote = _tlog(tmp_path / "remote.tlog", clock)
    assert not remote.in_process
    for k in range(0, len(calls), 700):
        _replay(calls[k : k + 700], remote, clock)
        remote.drain()  # handed over mid-stream, as the writer thread would
    remote.close()
    assert (tmp_path / "remote.tlog").read_bytes() == want
    n = len(list(read_tlog(tmp_path / "ref.tlog")))
    assert (remote.written, remote.dropped, remote.encode_errors) == (n, 0, 0)

    monkeypatch.setattr(logproc, "IN_PROCESS", True)
    local = _tlog(tmp_path / "local.tlog", clock)
    _replay(calls, local, clock)
    local.close()
    assert local.in_process and (tmp_path / "local.tlog").read_bytes() == want
    assert (local.written, local.dropped) == (n, 0)


def _shared(tmp_path: Path, name: str, calls: list[tuple[float, str, Any]], detach_at: int | None = None) -> Any:
    """The .tlog with its sample records queued by a FlightRecorder's telemetry hook
    (``share_samples``) instead of its own listener; ``detach_at``: the recorder closes after
    that many calls and the .tlog listens for itself from there."""
    clock = [0.0]
    tc = TelemetryCache()
    rec = FlightRecorder(tmp_path / f"{name}-run", short_config(), mcap=False)
    rec.attach(tc, landing=False)
    tl = _tlog(tmp_path / f"{name}.tlog", clock)
    assert rec.share_samples(tc, tl)
    assert not rec.share_samples(tc, tl)  # once
    for i, (t, what, arg) in enumerate(calls):
        if i == detach_at:
            rec.close()
            assert tc.listeners == (tl.sample,)  # the .tlog listens for itself again
        clock[0] = t
        if what == "sample":
            for fn in tc.listeners:  # what TelemetryCache.push does once the sample is valid
                fn(arg)
        elif what in ("command", "command_ack"):
            getattr(tl, what)(*arg)
        else:
            getattr(tl, what)(arg)
        if i % 700 == 699:
            tl.drain()  # handed over mid-stream, as the writer thread would
    rec.unshare_samples(tl)
    tl.close()
    rec.close()
    return tl, rec


def test_the_recorder_s_rows_give_the_same_tlog_as_its_own_listener(tmp_path, monkeypatch):
    calls = _calls(3000)
    want = _at_once(tmp_path / "ref.tlog", calls)
    n = len(list(read_tlog(tmp_path / "ref.tlog")))
    samples = sum(1 for _, what, _ in calls if what == "sample")
    for name, detach_at in (("shared", None), ("detached", 1800)):
        tl, rec = _shared(tmp_path, name, calls, detach_at)
        assert not tl.in_process
        assert (tmp_path / f"{name}.tlog").read_bytes() == want, name
        assert (tl.written, tl.dropped, tl.encode_errors) == (n, 0, 0)
        rows = sum(rec.meta["rows"][f] for f in SAMPLE_FILES.values())
        assert rows == (samples if detach_at is None else sum(1 for c in calls[:detach_at] if c[1] == "sample"))
    monkeypatch.setattr(logproc, "IN_PROCESS", True)
    tl, _ = _shared(tmp_path, "local", calls)
    assert tl.in_process and (tmp_path / "local.tlog").read_bytes() == want


def test_sample_from_row_gives_back_the_sample():
    for _, what, s in _calls(200):
        if what == "sample":
            row = SAMPLE_ENCODERS[type(s)](17, s)
            assert sample_from_row(type(s), row) == s


_CRASH = """
import os, sys, time
from companion.autopilot.types import Attitude
from companion.flightlog.logproc import LogProcess
from companion.flightlog.telemetry_tlog import TelemetryTlog
from companion_sitl.mavlink.px4 import px4_custom_mode
clock = [0.0]
t = TelemetryTlog(sys.argv[1], boot_s=0.0, clock=lambda: clock[0], epoch_s=1.7e9, custom_mode=px4_custom_mode)
for i in range(400):
    clock[0] = 0.01 * i
    t.sample(Attitude(clock[0], 0.1, 0.2, 0.3, 0.0, 0.0, float(i)))
time.sleep(1.0)  # the writer thread hands everything over
print(LogProcess._current.child.pid, flush=True)
os._exit(1)  # a crash: no close(), no atexit
"""


@pytest.mark.skipif(not Path("/proc").is_dir(), reason="waits on /proc")
def test_a_crashed_parent_leaves_every_record_it_handed_over(tmp_path):
    path = tmp_path / "crash.tlog"
    proc = subprocess.run([sys.executable, "-c", _CRASH, str(path)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1, proc.stderr
    wait_gone(int(proc.stdout.split()[0]))
    msgs = list(read_tlog(path))
    assert [m.yawspeed for m in msgs] == [float(i) for i in range(400)]


def test_a_dead_logging_process_leaves_the_file_to_this_process(tmp_path, own_process, caplog):
    calls = _calls(2000, seed=3)
    want = _at_once(tmp_path / "ref.tlog", calls)
    clock = [0.0]
    t = _tlog(tmp_path / "a.tlog", clock)
    proc = LogProcess._current
    assert proc is not None and not t.in_process
    _replay(calls[:1000], t, clock)
    t.drain()
    assert proc.cpu_s() is not None  # an answer: everything before it was written
    handed_over = (tmp_path / "a.tlog").stat().st_size
    assert 0 < handed_over < len(want)
    proc.child.kill()
    proc.child.wait()
    with (tmp_path / "a.tlog").open("ab") as fh:
        fh.write(b"\0" * 8 + b"\xfd\x20\0")  # a torn record, as a writer killed mid-write leaves
    _replay(calls[1000:], t, clock)
    with caplog.at_level(logging.ERROR):
        t.close()  # the hand-over fails: the rest is encoded and written here
    assert t.in_process
    got = (tmp_path / "a.tlog").read_bytes()
    assert got[:handed_over] == want[:handed_over]  # what the logging process wrote, then the torn tail cut
    ref = list(read_tlog(tmp_path / "ref.tlog"))
    msgs = list(read_tlog(tmp_path / "a.tlog"))
    assert len(msgs) == len(ref) and all(m.get_type() != "BAD_DATA" for m in msgs)
    # the same messages at the same times (the new encoder numbers its packets from 0 again)
    for a, b in zip(msgs, ref, strict=True):
        assert (a.get_type(), record_time_s(a), a.get_payload()) == (b.get_type(), record_time_s(b), b.get_payload())
    died = [r.getMessage() for r in caplog.records if "logging process" in r.getMessage()]
    assert sum("written in this process" in m for m in died) == 1, died


def test_a_logging_process_that_never_starts_leaves_the_tlog_in_process(tmp_path, own_process, monkeypatch, caplog):
    monkeypatch.setattr(logproc, "CHILD_COMMAND", [sys.executable, "-c", "raise SystemExit(3)"])
    calls = _calls(500, seed=5)
    want = _at_once(tmp_path / "ref.tlog", calls)
    clock = [0.0]
    with caplog.at_level(logging.ERROR):
        t = _tlog(tmp_path / "a.tlog", clock)
        _replay(calls, t, clock)
        t.close()
    assert t.in_process and (tmp_path / "a.tlog").read_bytes() == want
    assert len([r for r in caplog.records if "exit code 3" in r.getMessage()]) == 1


def test_an_unwritable_tlog_path_fails_at_once_naming_it(tmp_path):
    (tmp_path / "dir.tlog").mkdir()
    with pytest.raises(OSError, match=r"dir\.tlog"):
        _tlog(tmp_path / "dir.tlog", [0.0])


def test_cut_torn_record_keeps_the_whole_records(tmp_path):
    calls = _calls(50)
    whole = _at_once(tmp_path / "ref.tlog", calls)
    for cut in (1, 5, 9, 11, 30):
        p = tmp_path / f"torn{cut}.tlog"
        p.write_bytes(whole[:-cut])
        cut_torn_record(p)
        data = p.read_bytes()
        assert whole.startswith(data) and len(data) < len(whole)
        assert len(list(read_tlog(p))) == len(list(read_tlog(tmp_path / "ref.tlog"))) - 1
    p = tmp_path / "whole.tlog"
    p.write_bytes(whole)
    cut_torn_record(p)
    assert p.read_bytes() == whole
    assert struct.unpack(">Q", whole[:8])[0] > 0


def test_a_record_that_does_not_pickle_leaves_the_file_to_this_process(tmp_path, own_process, caplog):
    """A sample type the logging process cannot be handed (a class made in a function): the
    writer thread is not stopped; the logs go on in process, with one ERROR."""

    @dataclasses.dataclass(frozen=True)
    class Odd:
        time_s: float

    calls = _calls(300, seed=9)
    want = _at_once(tmp_path / "ref.tlog", calls)
    clock = [0.0]
    t = _tlog(tmp_path / "a.tlog", clock)
    assert not t.in_process
    with caplog.at_level(logging.ERROR):
        _replay(calls[:150], t, clock)
        t.sample(Odd(clock[0]))  # type: ignore[arg-type]  # no MAVLink for it: nothing written
        _replay(calls[150:], t, clock)
        t.drain()
        logproc.flush_current()
        t.close()
    assert t.in_process and len(want) > 0
    # every message, at its time (whatever the writer thread handed over before the odd record
    # was written by the logging process; the rest here, numbered from 0 again)
    got, ref = list(read_tlog(tmp_path / "a.tlog")), list(read_tlog(tmp_path / "ref.tlog"))
    assert [(m.get_type(), record_time_s(m), m.get_payload()) for m in got] == [
        (m.get_type(), record_time_s(m), m.get_payload()) for m in ref
    ]
    died = [r.getMessage() for r in caplog.records if "logging process" in r.getMessage()]
    assert len(died) == 1 and "does not pickle" in died[0], died
