"""The autopilot CLI commands: parser wiring."""

from __future__ import annotations


def test_register_adds_fly_and_bench_link():
    from companion.cli.main import build_parser

    parser, failed = build_parser()
    assert not failed
    a = parser.parse_args(["fly", "--params", "x.toml", "--connection", "udpin:0.0.0.0:14550"])
    assert a.func.__name__ == "cmd_fly" and a.connection == "udpin:0.0.0.0:14550"
    b = parser.parse_args(["bench", "link", "--seconds", "1"])
    assert b.func.__name__ == "cmd_bench_link" and b.seconds == 1.0


def test_fly_writes_the_mavlink_log_into_the_run_folder(tmp_path, monkeypatch, capsys):
    from companion.cli import fly as commands
    from companion.cli.main import build_parser
    from companion.config import shipped_params_path
    from companion.delivery.mission import MissionSummary

    seen = {}

    def make_autopilot(config, **kwargs):
        seen.update(kwargs, backend=config.autopilot, connection=config.connection)
        return object()

    async def run_delivery(config, autopilot, timeout_s, run_dir, landing=None, before_flight=None, on_tick=None):
        seen["run_dir"], seen["landing"], seen["before_flight"] = run_dir, landing, before_flight
        return MissionSummary(delivered=True, returned=True)

    monkeypatch.setattr(commands, "make_autopilot", make_autopilot)
    monkeypatch.setattr(commands, "run_delivery", run_delivery)
    parser, _ = build_parser()
    params = str(shipped_params_path("ardupilot_quad.toml"))
    args = parser.parse_args(["fly", "--params", params, "--out", str(tmp_path / "run"), "--no-preflight", "--json"])
    assert args.func(args) == 0
    assert seen["run_dir"] == tmp_path / "run" and seen["tlog_path"] == tmp_path / "run" / "flight.tlog"
    assert (seen["backend"], seen["connection"]) == ("ardupilot", "tcpout://127.0.0.1:5760")
    assert '"delivered": true' in capsys.readouterr().out
    assert seen["before_flight"] is None  # --no-preflight


def test_a_flight_ended_by_ctrl_c_exits_130(tmp_path, monkeypatch):
    """SIGINT in flight aborts (hold, land); the mission's failure is then of the kind
    OPERATOR_ABORT, and fly exits 130 as for Ctrl-C before the flight, not 1; the text alone
    decides nothing."""
    from companion.cli import exits
    from companion.cli import fly as commands
    from companion.cli.main import build_parser
    from companion.config import shipped_params_path
    from companion.delivery.mission import FailureKind, MissionSummary

    outcome = {}

    async def run_delivery(config, autopilot, timeout_s, run_dir, landing=None, before_flight=None, on_tick=None):
        return outcome["summary"]

    monkeypatch.setattr(commands, "make_autopilot", lambda config, **kw: object())
    monkeypatch.setattr(commands, "run_delivery", run_delivery)
    parser, _ = build_parser()
    params = str(shipped_params_path("ardupilot_quad.toml"))
    args = parser.parse_args(["fly", "--params", params, "--out", str(tmp_path / "run"), "--no-preflight", "--json"])
    # the kind the shell's signal handler gives the abort
    outcome["summary"] = MissionSummary(
        failure=f"aborted: {commands.OPERATOR_ABORT} (SIGINT)", failure_kind=FailureKind.OPERATOR_ABORT
    )
    assert args.func(args) == exits.INTERRUPTED == 130
    outcome["summary"] = MissionSummary(
        failure="aborted: ground command from ground: land", failure_kind=FailureKind.ABORTED
    )
    assert args.func(args) == exits.FAILED
    outcome["summary"] = MissionSummary(failure=f"aborted: {commands.OPERATOR_ABORT}", failure_kind=FailureKind.ABORTED)
    assert args.func(args) == exits.FAILED
