"""A bench's instruments of the logs (:class:`LogHooks`): stages timed where they are bound, the
same files; a hand-over that drops; the null log and recorder open and close their files with
nothing in them."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import Attitude, Imu
from companion.flightlog import logproc
from companion.flightlog.csvlog import CsvLog, NullCsvLog
from companion.flightlog.hooks import (
    FLIGHT,
    HAND_OVER,
    SAMPLES,
    LogHooks,
    batch_stage,
    drop_batches,
    row_stage,
)
from companion.flightlog.recorder import FlightRecorder, NullRecorder
from companion.flightlog.telemetry_tlog import TelemetryTlog
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.px4 import px4_custom_mode

from .conftest import short_config

COLS = ("time_s", "x_m")


def _counting() -> tuple[LogHooks, Counter[str], Counter[str]]:
    """Hooks whose stage timer counts the stages bound (``bound``) and the calls (``called``)."""
    bound: Counter[str] = Counter()
    called: Counter[str] = Counter()

    def timer(stage: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        bound[stage] += 1

        def timed(*args: Any) -> Any:
            called[stage] += 1
            return fn(*args)

        return timed

    return LogHooks(stage_timer=timer), bound, called


def _lines(path: Path) -> list[str]:
    return path.read_text(encoding="utf-8").splitlines()


def test_a_flight_s_hooks_time_nothing():
    fn = lambda: None  # noqa: E731
    assert LogHooks() == FLIGHT and FLIGHT.timed(SAMPLES, fn) is fn


def test_a_log_s_batches_are_timed_and_its_file_is_the_same(tmp_path):
    hooks, bound, called = _counting()
    plain = CsvLog(tmp_path / "plain.csv", COLS)
    timed = CsvLog(tmp_path / "timed.csv", COLS, hooks=hooks)
    assert bound[batch_stage("timed.csv")] == 1  # bound once, where the writer thread takes it
    for i in range(500):
        plain.write((i * 0.1, float(i)))
        timed.write((i * 0.1, float(i)))
    plain.close()
    timed.close()
    assert (tmp_path / "timed.csv").read_bytes() == (tmp_path / "plain.csv").read_bytes()
    assert called[batch_stage("timed.csv")] >= 1  # the close's last batch at least
    assert timed.written == 500


def test_the_hand_over_that_drops_leaves_the_header_only(tmp_path):
    if logproc.client() is None:
        pytest.skip("logging in process: nothing is handed over")
    lg = CsvLog(tmp_path / "dropped.csv", COLS, hooks=LogHooks(hand_over=drop_batches))
    for i in range(300):
        lg.write((i * 0.1, float(i)))
    lg.close()
    assert _lines(tmp_path / "dropped.csv") == [",".join(COLS)]


def test_a_null_log_is_opened_and_closed_with_no_rows(tmp_path):
    lg = NullCsvLog(tmp_path / "null.csv", COLS)
    lg.write((0.0, 1.0))
    lg.put((0.1, 2.0))
    lg.close()
    assert _lines(tmp_path / "null.csv") == [",".join(COLS)] and lg.written == 0


def _tlog(path: Path, clock: list[float]) -> TelemetryTlog:
    return TelemetryTlog(path, boot_s=0.0, clock=lambda: clock[0], epoch_s=1.7e9, custom_mode=px4_custom_mode)


def _fly(rec: FlightRecorder, tc: TelemetryCache, tl: TelemetryTlog, clock: list[float]) -> None:
    for i in range(200):
        clock[0] = t = 0.01 * i
        for s in (Attitude(t, 0.1, 0.2, 0.3, 0.0, 0.0, 0.0), Imu(t, 0.0, 0.0, -9.8, 0.0, 0.0, 0.0)):
            for fn in tc.listeners:  # what TelemetryCache.push does once the sample is valid
                fn(s)
        tl.setpoint(VelocitySetpoint(1.0, 0.0, 0.0, 0.0))
        tl.command(176, (1.0, 6.0))
        tl.command_ack(176, 0)
        rec.on_setpoint(t, VelocitySetpoint(1.0, 0.0, 0.0, 0.0))


def test_the_recorder_hands_its_hooks_to_the_tlog_that_shares_its_samples(tmp_path):
    files: dict[str, bytes] = {}
    for name, hooks in (("plain", FLIGHT), ("timed", _counting()[0])):
        clock = [0.0]
        tc = TelemetryCache()
        rec = FlightRecorder(tmp_path / name, short_config(), mcap=False, hooks=hooks)
        rec.attach(tc, landing=False)
        tl = _tlog(tmp_path / name / "flight.tlog", clock)
        assert rec.share_samples(tc, tl)
        _fly(rec, tc, tl, clock)
        rec.unshare_samples(tl)
        tl.close()
        rec.close()
        files |= {f"{name}/{f.name}": f.read_bytes() for f in (tmp_path / name).iterdir() if f.name != "run.json"}
    for key, data in files.items():
        if key.startswith("plain/"):
            assert files["timed/" + key.removeprefix("plain/")] == data, key


def test_the_recorder_s_stages(tmp_path):
    hooks, bound, called = _counting()
    clock = [0.0]
    tc = TelemetryCache()
    rec = FlightRecorder(tmp_path / "run", short_config(), mcap=False, hooks=hooks)
    rec.attach(tc, landing=False)
    tl = _tlog(tmp_path / "run" / "flight.tlog", clock)
    assert rec.share_samples(tc, tl)
    _fly(rec, tc, tl, clock)
    rec.unshare_samples(tl)
    tl.close()
    rec.close()
    assert bound[SAMPLES] == 1 and called[SAMPLES] == 400  # the listener, bound once at attach
    assert called[row_stage("flight.tlog")] == 600  # the .tlog's own hooks (its samples: the recorder's)
    assert called[batch_stage("flight.tlog")] >= 1 and called[batch_stage("setpoints.csv")] >= 1
    assert rec.meta["rows"]["setpoints.csv"] == 200
    assert set(called) <= {SAMPLES, HAND_OVER, row_stage("flight.tlog")} | {
        batch_stage(name) for name in [*rec.logs, "flight.tlog"]
    }


def test_the_null_recorder_opens_and_closes_the_run_folder_with_nothing_logged(tmp_path):
    clock = [0.0]
    tc = TelemetryCache()
    rec = NullRecorder(tmp_path / "run", short_config(), mcap=False)
    rec.attach(tc, landing=False)
    tl = _tlog(tmp_path / "run" / "flight.tlog", clock)
    assert not rec.share_samples(tc, tl)  # the .tlog's own sample hook listens: it takes nothing
    tc.add_listener(tl.sample)
    _fly(rec, tc, tl, clock)
    tl.close()
    rec.close()
    assert (tmp_path / "run" / "flight.tlog").stat().st_size == 0
    assert set(rec.meta["rows"].values()) == {0}
    for name, lg in rec.logs.items():
        assert _lines(tmp_path / "run" / name) == [",".join(lg.columns)], name
