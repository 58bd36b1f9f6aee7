"""Session settings, the `companion ground` / `companion bench telemetry` commands, router mode
and the benchmark."""

from __future__ import annotations

import argparse
import json
import threading
import time
from pathlib import Path

import pytest

from companion.cli.telemetry import (
    cmd_ground,
    format_bench_result,
    ground_settings,
    register,
    register_bench,
)
from companion.telemetry.ground import GroundStation, VehicleRow, render_table
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import StateMessage
from companion.telemetry.session import SettingsError, ZenohSettings, load_settings
from companion_lab.bench.telemetry import bench_telemetry

from .conftest import wait_until

PARAMS = Path(__file__).resolve().parents[2] / "params"


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="companion")
    sub = p.add_subparsers(dest="command")
    register(sub)
    bench = sub.add_parser("bench")
    register_bench(bench.add_subparsers(dest="bench"))
    return p


def test_settings_to_config() -> None:
    s = ZenohSettings(
        mode="client", connect=("tcp/127.0.0.1:7447",), router_endpoint="tcp/10.0.0.1:7447",
        multicast_scouting=False, user="u", password="p", scouting_delay_ms=0,
    )  # fmt: skip
    conf = s.to_config()
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:7447", "tcp/10.0.0.1:7447"]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("transport/auth/usrpwd/user")) == "u"
    assert "password" not in repr(s)  # secrets stay out of logs
    default = ZenohSettings()
    assert default.mode == "peer"
    assert json.loads(default.to_config().get_json("mode")) == "peer"


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"mode": "satellite"}, "mode"),
        ({"listen": ("localhost:7447",)}, "endpoint"),
        ({"listen": "tcp/127.0.0.1:7447"}, "tuple"),
        ({"mode": "router"}, "listen"),
        ({"user": "u"}, "together"),
        ({"auth_dictionary_file": "/nonexistent/users.txt"}, "not a file"),
        ({"scouting_delay_ms": -1}, "scouting_delay_ms"),
        ({"router_endpoint": "10.0.0.1"}, "router_endpoint"),
        ({"mode": "client", "multicast_scouting": False}, "connect"),
    ],
)
def test_settings_validation(kwargs: dict, match: str) -> None:
    with pytest.raises(SettingsError, match=match):
        ZenohSettings(**kwargs)


def test_zenoh_passwords_others_can_read_are_refused(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("ground:ground-pass\n")
    users.chmod(0o644)
    with pytest.raises(SettingsError, match=rf"^zenoh.auth_dictionary_file {users}: mode 0644: .*chmod 600 {users}`$"):
        ZenohSettings(auth_dictionary_file=str(users))
    users.chmod(0o600)
    assert ZenohSettings(auth_dictionary_file=str(users)).auth_dictionary_file == str(users)
    session = tmp_path / "z.toml"
    session.write_text('[zenoh]\nuser = "v1"\npassword = "v1-pass"\n')
    session.chmod(0o640)
    with pytest.raises(SettingsError, match=r"Zenoh session file \(it holds zenoh.password\) .*: mode 0640: group"):
        load_settings(session)
    session.chmod(0o600)
    assert load_settings(session).user == "v1"
    session.write_text('[zenoh]\nmode = "peer"\n')
    session.chmod(0o644)  # no password in it: an ordinary parameter file
    assert load_settings(session).mode == "peer"


def test_bad_override_fails_at_config_time() -> None:
    with pytest.raises(SettingsError, match="no/such/key"):
        ZenohSettings(overrides=(("no/such/key", "1"),)).to_config()


@pytest.mark.parametrize("name", ["zenoh_peer.toml", "zenoh_fleet_router.toml", "zenoh_fleet_vehicle.toml"])
def test_example_param_files_load(name: str) -> None:
    settings = load_settings(PARAMS / name)
    settings.to_config()
    assert settings.mode in ("peer", "router")


def test_load_settings_errors(tmp_path: Path) -> None:
    f = tmp_path / "z.toml"
    f.write_text('[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:1"]\nlisen = []\n')
    with pytest.raises(SettingsError, match="lisen"):
        load_settings(f)
    f.write_text("[zenoh]\nmulticast_scouting = 1\n")
    with pytest.raises(SettingsError, match="multicast_scouting"):
        load_settings(f)
    f.write_text("[other]\n")
    with pytest.raises(SettingsError, match=r"\[zenoh\]"):
        load_settings(f)


def test_ground_arguments() -> None:
    p = parser()
    args = p.parse_args(["ground", "--router", "--out", "rec", "--duration", "3"])
    assert args.func is cmd_ground and args.out == "rec" and args.duration == 3.0
    s = ground_settings(args)
    assert s.mode == "router" and s.listen == ("tcp/0.0.0.0:7447",)
    args = p.parse_args(
        ["ground", "--listen", "tcp/127.0.0.1:9000", "--connect", "tcp/10.0.0.5:7447", "--no-multicast"]
    )
    s = ground_settings(args)
    assert (s.mode, s.listen, s.connect, s.multicast_scouting) == (
        "peer", ("tcp/127.0.0.1:9000",), ("tcp/10.0.0.5:7447",), False,
    )  # fmt: skip
    args = p.parse_args(["ground", "--zenoh-config", str(PARAMS / "zenoh_fleet_router.toml")])
    assert ground_settings(args).mode == "router"
    args = p.parse_args(["bench", "telemetry", "--vehicles", "3", "--rate", "10"])
    assert (args.vehicles, args.rate, args.duration) == ((3,), 10.0, 5.0) and callable(args.func)
    args = p.parse_args(
        ["bench", "telemetry", "--router", "--vehicles", "10,50,100", "--rate-hz", "20", "--duration-s", "2"]
    )
    assert (args.vehicles, args.rate, args.duration, args.router) == ((10, 50, 100), 20.0, 2.0, True)
    for bad in ("10,x", "0"):
        with pytest.raises(SystemExit):
            p.parse_args(["bench", "telemetry", "--vehicles", bad])


def test_cmd_ground_records_a_vehicle(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    port = free_tcp_port()
    out = tmp_path / "rec"
    args = parser().parse_args(
        ["ground", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast", "--out", str(out), "--duration", "1.5"]
    )
    rc: list[int] = []
    thread = threading.Thread(target=lambda: rc.append(cmd_ground(args)))
    thread.start()
    time.sleep(0.3)
    pub = TelemetryPublisher(TelemetrySettings("cli1", state_rate_hz=50.0), loopback_settings(connect_port=port))
    pub.start()
    try:
        for i in range(10):
            pub.publish(StateMessage(float(i), i, 0, -5, 0, 0, 0, 0, 0, 0))
            time.sleep(0.03)
    finally:
        pub.stop()
    thread.join(5.0)
    assert rc == [0]
    assert len((out / "cli1" / "state.jsonl").read_text().splitlines()) == 10
    assert "received 10, lost 0" in capsys.readouterr().out


def test_cmd_ground_bad_endpoint_fails_cleanly(capsys: pytest.CaptureFixture[str]) -> None:
    args = parser().parse_args(["ground", "--listen", "nonsense", "--duration", "0.1"])
    assert cmd_ground(args) == 2
    assert "endpoint" in capsys.readouterr().err


def test_router_fleet_with_clients() -> None:
    """--router topology: the ground is the router; vehicles are clients that only know it."""
    port = free_tcp_port()
    router = ZenohSettings(mode="router", listen=(f"tcp/127.0.0.1:{port}",), multicast_scouting=False)
    client = ZenohSettings(
        mode="client", router_endpoint=f"tcp/127.0.0.1:{port}", multicast_scouting=False,
        connect_exit_on_failure=True, connect_timeout_ms=3000,
    )  # fmt: skip
    with GroundStation(router) as ground:
        pubs = [TelemetryPublisher(TelemetrySettings(f"c{i}", state_rate_hz=100.0), client).start() for i in range(2)]
        try:
            assert wait_until(lambda: all(r.alive for r in ground.snapshot().values()) and len(ground.snapshot()) == 2)
            time.sleep(0.1)
            for k in range(5):
                for p in pubs:
                    p.publish(StateMessage(float(k), k, 0, -5, 0, 0, 0, 0, 0, 0))
                time.sleep(0.02)
            assert wait_until(lambda: ground.counters().received == 10)
            assert ground.query_info("c1")["vehicle_id"] == "c1"  # type: ignore[index]
        finally:
            for p in pubs:
                p.stop()
        assert wait_until(lambda: not any(r.alive for r in ground.snapshot().values()))


def test_render_table() -> None:
    from rich.console import Console

    console = Console(width=200, record=True)
    rows = {
        "d1": VehicleRow("d1", True, north_m=1.0, east_m=2.0, alt_m=30.0, battery_pct=75.0, link_ok=False, lost=2),
        "d2": VehicleRow("d2", False),
    }
    console.print(render_table(rows))
    text = console.export_text()
    assert "d1" in text and "d2 (gone)" in text and "LOST" in text and "75%" in text and "1.0/2.0/30.0" in text
    assert "-/2" not in text and "0/2" in text  # received / lost


def test_render_table_shows_the_distance_to_the_pad_and_the_heartbeat_age() -> None:
    from rich.console import Console

    console = Console(width=200, record=True)
    row = VehicleRow("d1", True, link_ok=True, heartbeat_age_s=0.25, distance_to_pad_m=0.034)
    console.print(render_table({"d1": row}))
    text = console.export_text()
    assert "to pad" in text and "34 mm" in text  # millimetres under 10 cm, never 0.03 m
    assert "ok (0.2s)" in text or "ok (0.3s)" in text
    console = Console(width=200, record=True)
    console.print(render_table({"d1": VehicleRow("d1", True, link_ok=True)}))  # no heartbeat (simulator)
    assert "ok (" not in console.export_text()


def test_bench_small_run() -> None:
    result = bench_telemetry(vehicles=3, rate_hz=20.0, duration_s=0.5)
    assert result["submitted"] == 30 and result["delivered"] == 30 and result["lost"] == 0
    assert 0 < result["latency_p50_ms"] <= result["latency_p99_ms"]
    assert result["cpu_us_per_msg"] > 0
    text = format_bench_result(result)
    assert "lost 0" in text and "p99" in text
    with pytest.raises(ValueError):
        bench_telemetry(vehicles=0, rate_hz=10, duration_s=1)


def test_render_table_shows_a_gone_vehicle_as_history() -> None:
    from rich.console import Console

    console = Console(width=200, record=True)
    gone = VehicleRow("d3", False, mode="offboard", link_ok=True, landing_error_m=0.004, status_age_s=0.0)
    stale = VehicleRow("d4", True, mode="hold", link_ok=True, landing_error_m=1.234, status_age_s=5.0)
    console.print(render_table({"d3": gone, "d4": stale}))
    text = console.export_text().splitlines()
    lines = {vid: next(line for line in text if vid in line) for vid in ("d3", "d4")}
    assert "ok" not in lines["d3"] and "offboard (last)" in lines["d3"]  # no live link on a vanished vehicle
    assert "4.0 mm" in lines["d3"]  # never "0.00 m" for a non-zero error
    assert "ok" in lines["d4"] and "hold (5s old)" in lines["d4"] and "1.23 m" in lines["d4"]


def test_ctrl_c_ends_ground_with_its_counts_and_exit_130(tmp_path: Path) -> None:
    """Ctrl-C is how an operator ends `ground` without --duration: it still prints what it
    received, and exits 130 as every command does on Ctrl-C (companion.cli.exits); it exited 0."""
    import signal
    import subprocess
    import sys

    port = free_tcp_port()
    # Ctrl-C as from a terminal, whatever SIGINT disposition the test runner's shell leaves children
    code = (
        "import signal, sys; signal.signal(signal.SIGINT, signal.default_int_handler); "
        "from companion.cli.main import main; sys.exit(main())"
    )
    argv = [sys.executable, "-c", code, "ground", "--listen", f"tcp/127.0.0.1:{port}", "--no-multicast"]
    proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 30.0
        assert proc.stdout is not None
        while "ground station:" not in proc.stdout.readline():  # the session is open
            assert time.monotonic() < deadline and proc.poll() is None, proc.stderr.read() if proc.stderr else ""
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=30.0)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, (proc.returncode, out, err)
    assert "received 0, lost 0" in out and "Traceback" not in err, (out, err)
