"""The MAVLink link bench (short): both backends against the sim vehicle."""

from __future__ import annotations

from companion_lab.bench.link import bench_link


def test_bench_link_measures_both_backends():
    r = bench_link(seconds=0.6)
    for backend in ("ardupilot_pymavlink", "px4_mavsdk"):
        res = r[backend]
        assert res["20hz"]["received"] == res["20hz"]["sent"] == 12
        # latencies are benchmark figures (`companion bench link`), not asserted against wall-clock bounds
        assert res["50hz"]["jitter_p99_ms"] >= 0.0 and res["command_rtt_p50_ms"] > 0.0
