"""`companion order` (the ground side) and `fly --orders`' start-up: bad input gets a clear error
and its exit code; no vehicle answering is exit 5; an accepted and a refused order over real
Zenoh (a desk on a loopback peer session) print the vehicle's answer."""

from __future__ import annotations

import asyncio

import pytest
import zenoh

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.types import FlightMode, HomePosition, LandedState, PositionNed, VehicleStatus
from companion.cli import exits
from companion.cli.main import main
from companion.config import shipped_params_path
from companion.delivery.orders import OrderDesk
from companion.telemetry.auth import CommandSettings
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion_sitl.params import load_simulated_config

SECRET = b"cli-test-secret-0123456789"


@pytest.fixture
def secret_file(tmp_path):  # type: ignore[no-untyped-def]
    f = tmp_path / "secret"
    f.write_bytes(SECRET + b"\n")
    f.chmod(0o600)  # a secret others can read is refused
    return f


def _zenoh_file(tmp_path, port: int):  # type: ignore[no-untyped-def]
    f = tmp_path / "z.toml"
    f.write_text(
        f'[zenoh]\nmode = "peer"\nlisten = []\nconnect = ["tcp/127.0.0.1:{port}"]\n'
        "multicast_scouting = false\ngossip_scouting = false\n"
    )
    return f


def _argv(secret_file, *extra: str) -> list[str]:  # type: ignore[no-untyped-def]
    return [
        "order",
        "--vehicle",
        "sitl1",
        "--lat",
        "-19.8688",
        "--lon",
        "-43.9637",
        "--secret-file",
        str(secret_file),
        *extra,
    ]


@pytest.mark.parametrize(
    ("extra", "words"),
    [
        (["--alternate-lat", "1.0"], "--alternate-lat and --alternate-lon go together"),
        (["--alternate-alt", "3"], "--alternate-alt needs --alternate-lat and --alternate-lon"),
        (["--order-id", "a b"], "--order-id 'a b': expected 1-64 letters"),
        (["--sender", "a/b"], "--sender 'a/b': expected"),
        (["--timeout", "0"], "--timeout 0.0: expected > 0 s"),
        (["--alt", "nan"], "--alt nan: expected a finite number"),
        # the vehicle's own pad schema ([mission.pad]): it was sent, and the vehicle refused it (exit 5 or 1)
        (["--lat", "95"], "--lat 95.0: input should be less than or equal to 90"),
        (["--alternate-lat", "1", "--alternate-lon", "-181"], "--alternate-lon -181.0: input should be greater than"),
        (["--alt", "99999"], "--alt 99999.0: input should be less than or equal to 9000"),
    ],
)
def test_bad_input_is_refused_before_sending(secret_file, capsys, extra: list[str], words: str) -> None:  # type: ignore[no-untyped-def]
    assert main(_argv(secret_file, *extra)) == exits.BAD_INPUT
    assert words in capsys.readouterr().err


def test_a_missing_or_short_secret_is_bad_input(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    assert main(_argv(tmp_path / "nope")) == exits.BAD_INPUT
    assert "--secret-file" in capsys.readouterr().err
    short = tmp_path / "short"
    short.write_bytes(b"tooshort")
    short.chmod(0o600)
    assert main(_argv(short)) == exits.BAD_INPUT
    assert "secret shorter than 16 bytes" in capsys.readouterr().err


def test_no_vehicle_answering_is_exit_5(tmp_path, secret_file, capsys) -> None:  # type: ignore[no-untyped-def]
    port = free_tcp_port()
    z = tmp_path / "z.toml"
    z.write_text(f'[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:{port}"]\nmulticast_scouting = false\n')
    assert main(_argv(secret_file, "--zenoh-config", str(z), "--timeout", "10")) == exits.TELEMETRY_UNAVAILABLE
    out = capsys.readouterr().out
    # Zenoh ends a query no queryable matches at once: said so, not "no answer within 10 s" after 2 s
    assert "nobody answers orders for sitl1 on the Zenoh network (the query ended in" in out, out
    assert "within 10 s" not in out, out


async def test_accepted_and_refused_orders_print_the_answer(tmp_path, secret_file, capsys) -> None:  # type: ignore[no-untyped-def]
    config = load_simulated_config(shipped_params_path("sitl_short.toml"))
    h = config.sim.home
    tc = TelemetryCache()
    tc.status = VehicleStatus(0.0, False, FlightMode.HOLD, LandedState.ON_GROUND, True, 90.0, False)
    tc.home = HomePosition(0.0, h.lat_deg, h.lon_deg, h.alt_amsl_m)
    tc.position_ned = PositionNed(0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0)
    port = free_tcp_port()
    session = zenoh.open(loopback_settings(listen_port=port).to_config())
    desk = OrderDesk(config, tc, CommandSettings(enabled=True, secret=SECRET)).start(session)
    try:
        z = _zenoh_file(tmp_path, port)
        code = await asyncio.to_thread(main, _argv(secret_file, "--zenoh-config", str(z), "--order-id", "o-1"))
        assert (code, capsys.readouterr().out) == (exits.OK, "order to sitl1: ACCEPTED: accepted: flying it now\n")
        code = await asyncio.to_thread(main, _argv(secret_file, "--zenoh-config", str(z), "--order-id", "o-2"))
        assert (code, capsys.readouterr().out) == (exits.FAILED, "order to sitl1: REFUSED: busy: flying order o-1\n")
        assert (await desk.next_order()).order.order_id == "o-1"
    finally:
        desk.stop()
        session.close()


def test_fly_orders_needs_the_commands_secret(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    text = shipped_params_path("sitl_short.toml").read_text().replace('autopilot = "sim"', 'autopilot = "px4"')
    params = tmp_path / "v.toml"
    params.write_text(text)
    assert main(["fly", "--params", str(params), "--orders", "--out", str(tmp_path / "s")]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    assert "telemetry.commands" in err and "fly --orders needs enabled = true and secret_file" in err
    assert not (tmp_path / "s").exists()  # refused before anything was opened or created


def test_fly_orders_refuses_a_destination_from_the_autopilot_mission(tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret"
    secret.write_bytes(b"orders-cli-secret-0123456789")
    secret.chmod(0o600)  # a secret others can read is refused
    text = shipped_params_path("sitl_short.toml").read_text().replace('autopilot = "sim"', 'autopilot = "px4"')
    params = tmp_path / "v.toml"
    text = text.replace("[mission]\n", '[mission]\ndestination = "autopilot_mission"\n', 1)
    params.write_text(text + f'\n[telemetry.commands]\nenabled = true\nsecret_file = "{secret}"\n')
    code = main(["fly", "--params", str(params), "--orders", "--out", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == exits.BAD_INPUT, err
    assert "mission.destination = 'autopilot_mission'" in err and "each order names the pad" in err
    assert not (tmp_path / "s").exists()


@pytest.mark.parametrize("mode", [0o644, 0o640, 0o602])
def test_a_secret_group_or_others_can_read_or_write_is_refused_at_start_up(tmp_path, capsys, mode: int) -> None:  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(mode)
    assert main(_argv(secret)) == exits.BAD_INPUT  # the ground side
    err = capsys.readouterr().err
    assert f"ground-command secret file {secret}: mode {mode:04o}: " in err and f"chmod 600 {secret}" in err
    text = shipped_params_path("sitl_short.toml").read_text().replace('autopilot = "sim"', 'autopilot = "px4"')
    params = tmp_path / "v.toml"
    params.write_text(text + f'\n[telemetry.commands]\nenabled = true\nsecret_file = "{secret}"\n')
    for orders in ([], ["--orders"]):  # the vehicle: before the camera, the link or the run folder
        code = main(["fly", "--params", str(params), *orders, "--out", str(tmp_path / "s")])
        err = capsys.readouterr().err
        assert code == exits.BAD_INPUT, err
        assert err.count("\n") == 1 and err.startswith(f"companion fly: ground-command secret file {secret}: ")
        assert f"chmod 600 {secret}` (telemetry.commands.secret_file in {params})" in err
        assert not (tmp_path / "s").exists()
