"""Publisher and ground station over real Zenoh sessions on 127.0.0.1."""

from __future__ import annotations

import json
import threading
import time
from pathlib import Path

import pytest
import zenoh

from companion.events import EventKind, MissionEvent, Phase
from companion.telemetry.auth import CommandKind, CommandSettings, GroundCommand, sign_command
from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import (
    HealthMessage,
    LandingMessage,
    LogMessage,
    MissionMessage,
    StateMessage,
    Topic,
    decode,
)
from companion.telemetry.session import ZenohSettings

from .conftest import SECRET, wait_until


def state(t: float, north: float = 0.0) -> StateMessage:
    return StateMessage(t, north, 2.0, -10.0, 3.0, 4.0, 0.0, 0.0, 0.0, 0.1, battery_pct=88.0)


def alive(ground: GroundStation, vid: str) -> bool:
    row = ground.snapshot().get(vid)
    return row is not None and row.alive


def test_presence_appears_and_vanishes(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    pub = TelemetryPublisher(TelemetrySettings("v1"), vehicle_settings).start()
    try:
        assert wait_until(lambda: alive(ground, "v1"))
    finally:
        pub.stop()
    assert wait_until(lambda: not alive(ground, "v1"))
    lines = (ground.out_dir / "v1" / "alive.jsonl").read_text().splitlines()  # type: ignore[operator]
    assert [json.loads(x)["alive"] for x in lines] == [True, False]


def test_ground_started_late_sees_a_vehicle_already_alive(port: int) -> None:
    # The vehicle listens, the ground connects afterwards: liveliness history brings it in.
    pub = TelemetryPublisher(TelemetrySettings("early"), loopback_settings(listen_port=port)).start()
    ground = GroundStation(loopback_settings(connect_port=port)).start()
    try:
        assert wait_until(lambda: alive(ground, "early"))
    finally:
        ground.stop()
        pub.stop()


def test_info_queryable_answers(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    params = {"pad_size_m": 1.0, "mission": {"height_m": 45.0}}
    with TelemetryPublisher(TelemetrySettings("v1", state_rate_hz=25.0), vehicle_settings, params=params) as pub:
        assert wait_until(lambda: alive(ground, "v1"))
        info = ground.query_info("v1")
        assert info is not None
        assert info["vehicle_id"] == "v1" and info["schema"] == "companion.info/1"
        assert info["params"] == params
        assert info["commands_enabled"] is False
        assert info["versions"]["telemetry_schema"] == "companion.telemetry/1"
        assert info["versions"]["eclipse-zenoh"] == "1.10.2"
        assert info["telemetry"]["rates_hz"]["state"] == 25.0
        assert info["zenoh_id"] == str(pub.session.zid())
        assert ground.query_info("nobody", timeout_s=0.3) is None


def test_params_must_be_json() -> None:
    with pytest.raises(ValueError, match="JSON"):
        TelemetryPublisher(TelemetrySettings("v1"), ZenohSettings(), params={"x": object()})


def test_commands_refused_when_disabled(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    got: list[GroundCommand] = []
    with TelemetryPublisher(TelemetrySettings("v1"), vehicle_settings, on_command=got.append) as pub:
        assert wait_until(lambda: alive(ground, "v1"))
        reply = ground.send_command("v1", CommandKind.LAND, SECRET)
        assert reply.replied and not reply.accepted and "disabled" in reply.reason
        assert pub.counters().commands_refused == 1
    assert got == []


def test_commands_authenticated_replay_and_malformed(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    got: list[GroundCommand] = []
    settings = TelemetrySettings("v1", commands=CommandSettings(enabled=True, secret=SECRET))
    with TelemetryPublisher(settings, vehicle_settings, on_command=got.append) as pub:
        assert wait_until(lambda: alive(ground, "v1"))
        # without credentials / wrong secret / malformed
        no_mac = json.loads(sign_command("v1", CommandKind.HOLD, SECRET))
        del no_mac["hmac_sha256"]
        for payload, why in [
            (json.dumps(no_mac).encode(), "no hmac"),
            (sign_command("v1", CommandKind.HOLD, b"wrong-secret-wrong-secret"), "bad HMAC"),
            (b"\x00garbage", "malformed"),
            (b"", "empty"),
            (sign_command("v1", CommandKind.HOLD, SECRET, issued_unix_s=time.time() - 60), "stale"),
        ]:
            reply = ground.send_raw_command("v1", payload)
            assert reply.replied and not reply.accepted and why in reply.reason, (why, reply)
        assert got == []
        # accepted
        reply = ground.send_command("v1", CommandKind.RETURN, SECRET, sender="gcs", note="weather")
        assert reply.accepted, reply
        assert len(got) == 1 and got[0].kind is CommandKind.RETURN and got[0].note == "weather"
        # replay of a captured, valid command
        payload = sign_command("v1", CommandKind.ABORT, SECRET)
        assert ground.send_raw_command("v1", payload).accepted
        replay = ground.send_raw_command("v1", payload)
        assert not replay.accepted and "replayed" in replay.reason
        assert [c.kind for c in got] == [CommandKind.RETURN, CommandKind.ABORT]
        c = pub.counters()
        assert (c.commands_accepted, c.commands_refused) == (2, 6)


def test_command_callback_failure_is_reported(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    def broken(cmd: GroundCommand) -> None:
        raise RuntimeError("mission busy")

    settings = TelemetrySettings("v1", commands=CommandSettings(enabled=True, secret=SECRET))
    with TelemetryPublisher(settings, vehicle_settings, on_command=broken):
        assert wait_until(lambda: alive(ground, "v1"))
        reply = ground.send_command("v1", CommandKind.HOLD, SECRET)
        assert reply.replied and not reply.accepted and "RuntimeError" in reply.reason


def test_enabled_commands_need_a_callback() -> None:
    with pytest.raises(ValueError, match="on_command"):
        TelemetryPublisher(
            TelemetrySettings("v1", commands=CommandSettings(enabled=True, secret=SECRET)), ZenohSettings()
        )


def test_zenoh_usrpwd_refuses_wrong_credentials(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("ground:ground-pass\nv1:v1-pass\n")
    users.chmod(0o600)  # a dictionary of passwords others can read is refused
    port = free_tcp_port()
    base = loopback_settings(listen_port=port)
    vehicle_settings = ZenohSettings(**{**base.__dict__, "auth_dictionary_file": str(users)})
    got: list[GroundCommand] = []
    settings = TelemetrySettings("v1", commands=CommandSettings(enabled=True, secret=SECRET))

    def ground_with(user: str | None, password: str | None) -> ZenohSettings:
        s = loopback_settings(connect_port=port)
        return ZenohSettings(**{**s.__dict__, "user": user, "password": password, "connect_timeout_ms": 500})

    with TelemetryPublisher(settings, vehicle_settings, on_command=got.append):
        for user, password in [("ground", "wrong"), ("mallory", "ground-pass"), (None, None)]:
            with pytest.raises(zenoh.ZError):
                GroundStation(ground_with(user, password)).start()
        # Without exit_on_failure the session opens but never joins: no vehicle, no command path.
        lax = ZenohSettings(**{**ground_with("ground", "wrong").__dict__, "connect_exit_on_failure": False})
        intruder = GroundStation(lax).start()
        try:
            assert not wait_until(lambda: alive(intruder, "v1"), timeout_s=0.5)
            assert not intruder.send_command("v1", CommandKind.LAND, SECRET, timeout_s=0.3).replied
        finally:
            intruder.stop()
        assert got == []
        good = GroundStation(ground_with("ground", "ground-pass")).start()
        try:
            assert wait_until(lambda: alive(good, "v1"))
            assert good.send_command("v1", CommandKind.LAND, SECRET).accepted
        finally:
            good.stop()
    assert [c.kind for c in got] == [CommandKind.LAND]


def test_malformed_samples_are_counted_and_recorded(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    session = vehicle_settings.open()
    try:
        assert wait_until(lambda: len(list(session.info.peers_zid())) > 0)
        time.sleep(0.1)
        session.put("companion/v9/state", b"{not json")
        session.put("companion/v9/state", b'{"schema":"companion.telemetry/9"}')
        session.put("companion/v9/health", _encode_valid_for("v8"))  # payload of another vehicle
        session.put("companion/v9/extra/deep", b"{}")
        session.put("companion/v9/state", _encode_valid_for("v9"))  # one good sample
        pretty = json.dumps(json.loads(_encode_valid_for("v9")), indent=2)  # valid, multi-line
        session.put("companion/v9/state", pretty.encode())
        assert wait_until(lambda: ground.counters().received == 2)
        assert wait_until(lambda: ground.counters().malformed == 4)
    finally:
        session.close()
    assert set(ground.snapshot()) == {"v9"}
    ground.flush()
    rejected = [json.loads(x) for x in (ground.out_dir / "rejected.jsonl").read_text().splitlines()]  # type: ignore[operator]
    assert len(rejected) == 4 and all(r["reason"] for r in rejected)
    good = (ground.out_dir / "v9" / "state.jsonl").read_text().splitlines()  # type: ignore[operator]
    assert len(good) == 2 and all(json.loads(x)["env"]["vehicle_id"] == "v9" for x in good)


def _encode_valid_for(vid: str) -> bytes:
    from companion.telemetry.schema import encode

    return encode(vid, state(1.0), 0, time.time())


def test_keep_newest_downsamples_and_events_are_never_dropped(
    ground: GroundStation, vehicle_settings: ZenohSettings
) -> None:
    settings = TelemetrySettings("v1", state_rate_hz=5.0)
    with TelemetryPublisher(settings, vehicle_settings) as pub:
        assert wait_until(lambda: alive(ground, "v1"))
        time.sleep(0.1)
        t0 = time.perf_counter()
        for i in range(500):  # a 200 Hz fusion loop's worth of samples, submitted in a burst
            pub.publish(state(float(i), north=float(i)))
            if i % 5 == 0:
                pub.publish(MissionMessage.for_event(MissionEvent(float(i), EventKind.WARNING, Phase.OUTBOUND, str(i))))
        burst_s = time.perf_counter() - t0
        pub.publish(LogMessage(1.0, 6, "end"))
        assert wait_until(lambda: pub.pending() == 0)
        c = pub.counters()
    assert burst_s < 0.5  # 600 publish calls; they never wait for the network
    assert c.submitted["state"] == 500 and c.published["state"] + c.superseded["state"] == 500
    assert c.published["state"] <= 3  # a burst at 5 Hz: first sample, then the newest
    assert c.submitted["mission"] == c.published["mission"] == 100 and c.dropped == 0
    assert wait_until(lambda: ground.snapshot()["v1"].received == c.published["state"] + 101)
    ground.flush()
    rec = ground.out_dir / "v1"  # type: ignore[operator]
    states = [decode(json.dumps(json.loads(x)["env"])).msg for x in (rec / "state.jsonl").read_text().splitlines()]
    assert states[-1].north_m == 499.0  # the newest sample is the one that went out
    events = [json.loads(x)["env"]["msg"]["event"]["detail"] for x in (rec / "mission.jsonl").read_text().splitlines()]
    assert events == [str(i) for i in range(0, 500, 5)]  # every event, in order
    assert ground.snapshot()["v1"].lost == 0


def test_fifo_overflow_is_counted_not_blocking(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    settings = TelemetrySettings("v1", event_queue_size=16)
    pub = TelemetryPublisher(settings, vehicle_settings).start()
    gate = threading.Event()
    real_send = pub._send

    def slow_send(topic, msg):  # a congested link: the worker is stuck in put
        gate.wait(5.0)
        real_send(topic, msg)

    pub._send = slow_send  # type: ignore[method-assign]
    try:
        results = [pub.publish(LogMessage(float(i), 6, f"m{i}")) for i in range(40)]
        c = pub.counters()
        # the worker holds at most one batch; the FIFO takes 16 more; the rest overflow
        assert results.count(False) == c.fifo_overflow > 0
        assert c.fifo_high_water <= 16
        assert pub.publish(state(0.0))  # keep-newest lane still accepts
    finally:
        gate.set()
        pub.stop()
    assert pub.counters().published["log"] == 40 - pub.counters().fifo_overflow


def test_publish_after_stop_is_refused(vehicle_settings: ZenohSettings, ground: GroundStation) -> None:
    pub = TelemetryPublisher(TelemetrySettings("v1"), vehicle_settings)
    assert not pub.publish(state(0.0))
    pub.start()
    pub.stop()
    assert not pub.publish(state(0.0))


def test_fleet_five_vehicles_nothing_lost(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    vehicles, rate_hz, duration_s = 5, 20.0, 2.0
    pubs = [
        TelemetryPublisher(TelemetrySettings(f"fleet{i}", state_rate_hz=50.0, health_rate_hz=50.0), vehicle_settings)
        for i in range(vehicles)
    ]
    for p in pubs:
        p.start()
    try:
        assert wait_until(lambda: all(alive(ground, f"fleet{i}") for i in range(vehicles)))
        assert wait_until(lambda: all(p.has_subscribers(t) for p in pubs for t in Topic))
        ticks = int(duration_s * rate_hz)
        t0 = time.monotonic()
        for k in range(ticks):
            for i, p in enumerate(pubs):
                p.publish(state(time.monotonic(), north=float(k)))
                if k % 10 == 0:
                    p.publish(HealthMessage(float(k), link_ok=True, heartbeat_age_s=0.1))
                    p.publish(LandingMessage(float(k), pad_visible=True, landing_error_m=0.05 * i))
                if k % 20 == 0:
                    p.publish(MissionMessage.for_event(MissionEvent(float(k), EventKind.PHASE, Phase.OUTBOUND)))
            time.sleep(max(0.0, t0 + (k + 1) / rate_hz - time.monotonic()))
        for p in pubs:
            assert wait_until(lambda p=p: p.pending() == 0)
        counters = [p.counters() for p in pubs]
    finally:
        for p in pubs:
            p.stop()
    per_vehicle = ticks + 2 * (ticks // 10) + ticks // 20
    for c in counters:
        assert c.superseded["state"] == 0 and c.dropped == 0
        assert sum(c.published.values()) == per_vehicle
    assert wait_until(lambda: ground.counters().received == vehicles * per_vehicle)
    time.sleep(0.1)
    assert ground.counters().received == vehicles * per_vehicle  # exact: nothing lost, nothing extra
    assert ground.counters().lost == 0 and ground.counters().malformed == 0
    rows = ground.snapshot()
    for i in range(vehicles):
        row = rows[f"fleet{i}"]
        assert row.received == per_vehicle and row.lost == 0
        assert row.phase is Phase.OUTBOUND and row.link_ok is True and row.battery_pct == 88.0
        assert row.landing_error_m == pytest.approx(0.05 * i)
        assert row.ground_speed_m_s == pytest.approx(5.0)
        assert row.north_m == ticks - 1
    ground.flush()
    lines = (ground.out_dir / "fleet3" / "state.jsonl").read_text().splitlines()  # type: ignore[operator]
    assert len(lines) == ticks
    assert [json.loads(x)["env"]["seq"] for x in lines] == list(range(ticks))


def test_unencodable_message_is_counted_and_worker_survives(
    ground: GroundStation, vehicle_settings: ZenohSettings
) -> None:
    with TelemetryPublisher(TelemetrySettings("v1"), vehicle_settings) as pub:
        assert wait_until(lambda: alive(ground, "v1"))
        pub.publish(LogMessage(0.0, 6, 123))  # type: ignore[arg-type]
        pub.publish(StateMessage(float("nan"), 0, 0, 0, 0, 0, 0, 0, 0, 0))
        assert wait_until(lambda: pub.pending() == 0)
        pub.publish(state(1.0))
        assert wait_until(lambda: ground.counters().received == 1)
        assert pub.counters().encode_errors == 2 and pub.counters().dropped == 2


async def test_from_an_asyncio_shell(ground: GroundStation, vehicle_settings: ZenohSettings) -> None:
    """The shell publishes from a coroutine and receives commands on its loop."""
    import asyncio

    from companion.telemetry.publisher import call_in_loop

    loop = asyncio.get_running_loop()
    commands: asyncio.Queue[GroundCommand] = asyncio.Queue()
    settings = TelemetrySettings("v1", state_rate_hz=100.0, commands=CommandSettings(enabled=True, secret=SECRET))
    pub = TelemetryPublisher(settings, vehicle_settings, on_command=call_in_loop(loop, commands.put_nowait))
    pub.start()
    try:
        for _ in range(300):
            if alive(ground, "v1"):
                break
            await asyncio.sleep(0.01)
        durations = []
        for k in range(20):
            t = time.perf_counter()
            pub.publish(state(float(k)))
            durations.append(time.perf_counter() - t)
            await asyncio.sleep(0.012)
        reply = await asyncio.to_thread(ground.send_command, "v1", CommandKind.HOLD, SECRET)
        assert reply.accepted
        cmd = await asyncio.wait_for(commands.get(), 2.0)
        assert cmd.kind is CommandKind.HOLD
        # publish never waits on the network: microseconds (the worst case is a GIL switch)
        assert sorted(durations)[len(durations) // 2] < 0.001 and max(durations) < 0.05
    finally:
        await pub.astop()
    assert wait_until(lambda: ground.counters().received == 20)
