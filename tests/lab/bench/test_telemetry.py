"""The fleet benchmark through a Zenoh router process: nothing lost, the result's structure."""

from __future__ import annotations

import json

import pytest

from companion.cli.telemetry import format_fleet_result
from companion.telemetry import router_host
from companion.telemetry.loopback import free_tcp_port
from companion_lab.bench.telemetry import RouterProcess, bench_fleet


def test_router_fleet_3_and_6_vehicles_lose_nothing() -> None:
    fleet = bench_fleet([3, 6], rate_hz=20.0, duration_s=0.5, via_router=True)
    assert fleet["topology"] == "router" and [r["vehicles"] for r in fleet["runs"]] == [3, 6]
    for run in fleet["runs"]:
        n = run["vehicles"]
        assert run["topology"] == "router"
        assert run["submitted"] == n * 10 and run["published"] == n * 10
        assert run["delivered"] == n * 10 and run["lost"] == 0 and run["lost_by_seq"] == 0
        assert run["duplicates"] == 0 and run["vehicles_with_loss"] == 0
        assert sorted(run["lost_per_vehicle"]) == [f"bench{i:03d}" for i in range(n)]
        assert set(run["lost_per_vehicle"].values()) == {0}
        assert 0 < run["latency_p50_ms"] <= run["latency_p99_ms"] <= run["latency_max_ms"]
        # the router process does work for every message, and it is part of the total
        assert run["router_cpu_us_per_msg"] > 0
        assert run["cpu_us_per_msg"] > run["router_cpu_us_per_msg"]
    assert fleet["cpu_per_msg_ratio_largest_to_smallest"] > 0
    json.dumps(fleet)  # --json prints it
    text = format_fleet_result(fleet)
    lines = text.splitlines()
    assert lines[1].split()[:4] == ["vehicles", "msgs", "lost", "lost/seq"]
    assert lines[2].split()[:3] == ["3", "30", "0"] and lines[3].split()[:3] == ["6", "60", "0"]
    assert "6 vs 3 vehicles" in text


def test_bench_fleet_rejects_bad_input() -> None:
    with pytest.raises(ValueError, match="at least one fleet size"):
        bench_fleet([], rate_hz=20.0, duration_s=0.5, via_router=True)
    with pytest.raises(ValueError, match="vehicles must be in"):
        bench_fleet([0], rate_hz=20.0, duration_s=0.5, via_router=True)


def test_router_process_reports_cpu_and_stops() -> None:
    router = RouterProcess(free_tcp_port())
    try:
        a = router.cpu_s()
        b = router.cpu_s()
        assert 0 <= a <= b
    finally:
        router.stop()


def test_router_host_usage_errors(capsys: pytest.CaptureFixture[str]) -> None:
    assert router_host.main([]) == 2
    assert "usage" in capsys.readouterr().err
    assert router_host.main(["udp:nowhere"]) == 2
    assert "is not an endpoint" in capsys.readouterr().err
