"""``companion bench log`` on the short flight: every figure present and consistent."""

from __future__ import annotations

import pytest

from companion.config import shipped_params_path
from companion.flightlog.streams import SAMPLE_FILES, STREAM_FILES
from companion_lab.bench.log import bench_log
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.flight


def short_config():
    return load_simulated_config(shipped_params_path("sitl_short.toml"), overrides={"sim": {"seed": 3}})


def test_bench_log_reports_shares_and_per_stream_costs():
    r = bench_log(config=short_config())
    for k in ("bare_wall_s", "csv_logs_wall_s", "full_run_folder_wall_s"):
        assert r[k] > 0.0
    assert r["csv_logging_share"] == pytest.approx((r["csv_logs_wall_s"] - r["bare_wall_s"]) / r["bare_wall_s"])
    for key in ("csv", "csv_mcap", "full"):  # CPU time: this process's, and the logging process's
        assert isinstance(r[f"{key}_cpu_share"], float)
        assert r[f"{key}_logging_process_cpu_share"] > 0.0
    per_stream = {k.removesuffix("_us_per_row") for k in r if k.endswith("_us_per_row")} - {"all_streams"}
    # the busy streams of a GPS-only flight, and the simulator's two
    assert {
        "ap_position.csv",
        "ap_attitude.csv",
        "guidance.csv",
        "setpoints.csv",
        "flight.csv",
        "truth.csv",
    } <= per_stream
    assert "flight.tlog" in per_stream  # the simulator's .tlog records, queued in this process
    assert per_stream <= set(STREAM_FILES) | {"flight.csv", "truth.csv", "flight.tlog"}
    assert sum(r[f"{s}_rows"] for s in per_stream) == r["rows"]
    # the clock's own cost is subtracted: a stream with next to nothing to do may come out at 0
    assert all(r[f"{s}_us_per_row"] >= 0.0 for s in per_stream) and r["all_streams_us_per_row"] > 0.0
    assert 0.0 < r["clock_overhead_us"] < 100.0
    # the whole folder's share, split three ways from the same rounds' flights
    split = r["split_open_close_share"] + r["split_rows_share"] + r["split_handover_share"]
    assert split == pytest.approx(r["full_logging_share"])
    # the .tlog's sample records come from the recorder's rows: its own hooks queue the rest
    assert r["tlog_records"] == r["tlog_records_of_samples"] + r["flight.tlog_rows"]
    samples = sum(r.get(f"{name}_rows", 0) for name in SAMPLE_FILES.values())
    assert r["tlog_records_of_samples"] >= samples > 0  # a status gives four messages
    assert r["this_process_ms"] == pytest.approx(r["this_process_share"] * r["bare_wall_s"] * 1e3)
