"""A simulated delivery publishing over real Zenoh (loopback) to a ground station, which sees
the vehicle, receives every mission event, and sends an authenticated command the mission obeys."""

import time

import pytest

from companion.config import shipped_params_path
from companion.events import EventKind
from companion.telemetry.auth import CommandKind
from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config

SECRET = b"integration-secret-0123456789"


def _config(tmp_path, zenoh_config, commands):
    secret = tmp_path / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(0o600)  # a secret others can read is refused
    tele = {
        "zenoh_config": str(zenoh_config),
        "commands": {"enabled": commands, "secret_file": str(secret) if commands else None},
    }
    return load_simulated_config(
        shipped_params_path("delivery_paper.toml"), overrides={"sim": {"seed": 1}, "telemetry": tele}
    )


def _wait(pred, timeout_s=3.0):
    end = time.monotonic() + timeout_s
    while time.monotonic() < end and not pred():
        time.sleep(0.01)
    return pred()


@pytest.mark.flight
def test_demo_publishes_every_mission_event_to_the_ground(tmp_path, mav):
    port = free_tcp_port()
    with GroundStation(loopback_settings(listen_port=port), out_dir=tmp_path / "rec") as ground:
        r = run_demo(_config(tmp_path, mav.connect_only_zenoh(tmp_path, port), commands=False), telemetry=True)
        assert r.delivered and r.returned
        assert _wait(lambda: "drone1" in ground.snapshot() and not ground.snapshot()["drone1"].alive)
        ground.flush()
    events = (tmp_path / "rec" / "drone1" / "mission.jsonl").read_text().splitlines()
    with_event = [line for line in events if '"event": {' in line or '"event":{' in line]
    assert len(with_event) == len(r.events)  # never dropped
    assert ground.counters().lost == 0
    for topic in ("state", "estimate", "landing", "health", "log"):
        assert (tmp_path / "rec" / "drone1" / f"{topic}.jsonl").stat().st_size > 0, topic
    est = [line for line in (tmp_path / "rec" / "drone1" / "estimate.jsonl").read_text().splitlines() if line]
    assert '"source": "ekf"' in est[-1] or '"source":"ekf"' in est[-1]


@pytest.mark.flight
def test_ground_return_command_turns_the_vehicle_home(tmp_path, mav):
    port = free_tcp_port()
    replies = []
    with GroundStation(loopback_settings(listen_port=port), out_dir=None) as ground:

        def on_tick(shell, out):
            if not replies and out.phase.value == "outbound" and shell.now() > 40.0:
                replies.append(ground.send_command("drone1", CommandKind.RETURN, SECRET, sender="test"))
                bad = ground.send_command("drone1", CommandKind.LAND, b"wrong-secret-0123456789", sender="x")
                replies.append(bad)

        r = run_demo(
            _config(tmp_path, mav.connect_only_zenoh(tmp_path, port), commands=True), telemetry=True, on_tick=on_tick
        )
    assert replies[0].accepted and not replies[1].accepted and "HMAC" in replies[1].reason.upper()
    assert not r.delivered and r.returned and r.phase == "done"
    assert any(k == "warning" and "return home" in d for _, k, _, d in r.events)
    assert r.home_landing_error_m < 1.0
    assert EventKind.DELIVERED.value not in [k for _, k, _, _ in r.events]
