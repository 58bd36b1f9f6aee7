"""Per-stream flight logs: headers with units, exact values, one seq across all input streams."""

from __future__ import annotations

import json

import numpy as np
import pytest

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
from companion.config import CompanionConfig
from companion.delivery.replay import read_inputs
from companion.flightlog.reader import Table
from companion.flightlog.recorder import FlightRecorder
from companion.flightlog.streams import SAMPLE_FILES, STREAM_FILES

pytestmark = pytest.mark.flight

UNITS = ("_s", "_m", "_m_s", "_rad", "_rad_s", "_deg", "_m_s2", "_px", "_pct", "_m2", "_rad2", "_rad2_s2")
# columns without a physical unit: identifiers, flags, names, counts, matrix elements, DOP
UNITLESS = {
    "seq", "phase", "sector", "mode", "armed", "landed", "healthy", "payload_released", "fix_type", "satellites",
    "severity", "text", "ambiguous", "markers", "anchors_used", "frame", "pdop", "xi", "markers_used", "uwb_used",
    "link_ok", "est_source", "clamped", "request", "request_id", "id", "kind", "ok", "error", "permanent", "source",
    "detail", "reply", "hdop", "vdop", "vertical_weak", *(f"r{i}{j}" for i in range(3) for j in range(3)),
}  # fmt: skip


def test_every_stream_has_time_first_and_units_in_its_headers():
    for name, cols in STREAM_FILES.items():
        assert cols[0] == "time_s", name
        assert len(set(cols)) == len(cols), name
        for c in cols:
            assert c in UNITLESS or c.endswith(UNITS), f"{name}: column {c!r} has no unit"


def _samples(rng):
    r = lambda: float(rng.normal(0.0, 100.0))  # noqa: E731
    return [
        PositionNed(r(), r(), r(), r(), r(), r(), r()),
        Attitude(r(), r(), r(), r(), r(), r(), r()),
        GlobalPosition(r(), r(), r(), r(), r()),
        GpsRaw(r(), r(), r(), r(), 3, 11, r()),
        Imu(r(), r(), r(), r(), r(), r(), r()),
        VehicleStatus(r(), True, FlightMode.OFFBOARD, LandedState.IN_AIR, False, r(), True),
        HomePosition(r(), r(), r(), r()),
        StatusText(r(), 4, 'offboard lost, "hold", now'),
    ]


def test_samples_read_back_equal_to_what_was_recorded(tmp_path):
    rng = np.random.default_rng(11)
    samples = _samples(rng) + _samples(rng)
    rec = FlightRecorder(tmp_path, CompanionConfig())
    for s in samples:
        rec.on_sample(s)
    rec.close()
    inputs, _ = read_inputs(tmp_path)
    assert [i.seq for i in inputs] == list(range(len(samples)))
    back = [i.payload for i in inputs]
    assert back == samples  # dataclass equality: every float identical, enums and flags restored
    assert all(type(b) is type(s) for b, s in zip(back, samples, strict=True))
    assert {type(s) for s in samples} == set(SAMPLE_FILES)


def test_calls_after_close_are_ignored_not_raised(tmp_path):
    rec = FlightRecorder(tmp_path, CompanionConfig())
    rec.on_sample(PositionNed(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    rec.close()
    rec.on_sample(PositionNed(2.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))  # an autopilot still streaming
    assert rec.ignored_after_close == 1
    assert len(Table(tmp_path / "ap_position.csv")) == 1
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["closed"] and meta["rows"]["ap_position.csv"] == 1


def test_a_failing_hook_is_counted_not_raised_into_the_flight(tmp_path):
    rec = FlightRecorder(tmp_path, CompanionConfig())
    rec.on_marker(1.0, object())  # not an observation: the hook fails inside
    rec.on_sample(PositionNed(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    rec.close()
    assert rec.errors == 1
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["errors"] == 1 and meta["rows"]["camera.csv"] == 0 and meta["rows"]["ap_position.csv"] == 1


def test_demo_run_folder_has_every_stream_closed_and_consistent(demo_run):
    meta = json.loads((demo_run / "run.json").read_text())
    assert meta["closed"] and meta["landing"] and not meta.get("dropped") and meta["errors"] == 0
    assert meta["fusion"]["ekf"]["gate_probability"] == 0.9999 and meta["mission"]["h_m"] == 8.0
    for name in STREAM_FILES:
        t = Table(demo_run / name, STREAM_FILES[name])
        assert len(t) == meta["rows"][name], name
        assert (demo_run / name).read_bytes().endswith(b"\n"), name
    for name in ("ap_position.csv", "ap_attitude.csv", "camera.csv", "uwb.csv", "ekf.csv", "guidance.csv"):
        assert meta["rows"][name] > 20, name  # the landing used the camera and the UWB
    # one counter across every input stream, no gap, no repeat
    inputs, _ = read_inputs(demo_run)
    assert [i.seq for i in inputs] == list(range(len(inputs)))


def test_estimates_are_written_exactly(demo_run):
    # the EKF's variances are tiny numbers with 17 significant digits: a fixed-decimal format
    # (such as %.6f) would round most of them away
    t = Table(demo_run / "ekf.csv")
    v = t.floats("var_gyro_bias_z_rad2_s2")
    assert np.all(v > 0) and np.all(v < 1e-2)
    texts = [t.text(k, "var_gyro_bias_z_rad2_s2") for k in range(len(t))]
    assert max(len(s) for s in texts) > 12


def test_a_sample_dropped_by_a_full_queue_is_counted_and_still_takes_its_seq(tmp_path):
    """The telemetry hook appends to the stream's queue itself: a full queue drops the row (counted,
    in run.json too) and the seq it took leaves a gap the replay reports."""
    rec = FlightRecorder(tmp_path, CompanionConfig(), max_queue=3, mcap=False)
    for lg in rec.logs.values():  # no writer wake-up while the samples are queued
        lg._shared.detach(lg)
    status = VehicleStatus(0.5, True, FlightMode.OFFBOARD, LandedState.IN_AIR, True, 80.0, False)
    for k in range(5):
        rec.on_sample(PositionNed(float(k), 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))  # seq 0..4: 3 and 4 dropped
    for _ in range(4):
        rec.on_sample(status)  # seq 5..8: an encoded type (flags, enums), 8 dropped
    rec.on_sample(Attitude(9.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))  # seq 9, queued
    rec.close()
    assert Table(tmp_path / "ap_position.csv").floats("seq").tolist() == [0.0, 1.0, 2.0]
    assert Table(tmp_path / "ap_status.csv").floats("seq").tolist() == [5.0, 6.0, 7.0]
    assert Table(tmp_path / "ap_attitude.csv").floats("seq").tolist() == [9.0]
    meta = json.loads((tmp_path / "run.json").read_text())
    assert meta["dropped"] == {"ap_position.csv": 2, "ap_status.csv": 1}


def test_run_json_on_a_disk_full_in_flight_keeps_its_last_version_and_closes_whole(tmp_path, caplog):
    from ..tmpfs import fill, mounted_tmpfs

    class Telemetry:
        def add_listener(self, fn):
            self.fn = fn

        def remove_listener(self, fn):
            pass

    with mounted_tmpfs(tmp_path / "disk", "2m") as d:
        rec = FlightRecorder(d / "run", CompanionConfig(), mcap=False)
        fill(d)
        rec.attach(Telemetry(), landing=True)  # rewrites run.json: the disk is full, the flight goes on
        assert rec.errors == 0 and not rec.logs_incomplete  # no row lost (run.json is rewritten at the close)
        assert json.loads((d / "run" / "run.json").read_text())["landing"] is None  # the last version, whole
        assert f"{d / 'run' / 'run.json'}: cannot rewrite it" in caplog.text
        rec.close()  # the room kept from the start holds the closing version
        meta = json.loads((d / "run" / "run.json").read_text())
        assert meta["closed"] and meta["landing"] is True
