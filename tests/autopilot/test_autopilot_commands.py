"""The autopilot CLI commands: parser wiring and the link bench (short)."""

from __future__ import annotations

from companion.autopilot.commands import bench_link


def test_register_adds_fly_and_bench_link():
    from companion.cli import build_parser

    parser, failed = build_parser()
    assert not failed
    a = parser.parse_args(["fly", "--params", "x.toml", "--connection", "udpin:0.0.0.0:14550"])
    assert a.func.__name__ == "cmd_fly" and a.connection == "udpin:0.0.0.0:14550"
    b = parser.parse_args(["bench", "link", "--seconds", "1"])
    assert b.func.__name__ == "cmd_bench_link" and b.seconds == 1.0


def test_bench_link_measures_both_backends():
    r = bench_link(seconds=0.6)
    for backend in ("ardupilot_pymavlink", "px4_mavsdk"):
        res = r[backend]
        assert res["20hz"]["received"] == res["20hz"]["sent"] == 12
        # latencies are benchmark figures (`companion bench link`), not asserted against wall-clock bounds
        assert res["50hz"]["jitter_p99_ms"] >= 0.0 and res["command_rtt_p50_ms"] > 0.0
