"""Order after order over real Zenoh (docs/orders.md): one `fly --orders` session against one PX4
MAVLink sim vehicle over UDP that is never restarted, the ground on a Zenoh peer session of its own
on 127.0.0.1. Order 1 is accepted and delivered; an order sent while it flies is refused as busy;
an order out of range is refused with its reason (through `companion order`, the ground CLI); order
2 to another pad is accepted and delivered once order 1 is done. Each flight has its run folder."""

from __future__ import annotations

import asyncio
import csv
import json
import re
import signal
import subprocess
import sys
import time

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import FlightMode
from companion.cli import exits
from companion.cli.main import main as companion_main
from companion.cli.orders import serve_orders
from companion.config import shipped_params_path
from companion.events import EventKind
from companion.geometry.earth import GeoPoint, ned_to_geo
from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import free_tcp_port, loopback_settings
from companion.telemetry.orders import OrderPad
from companion.telemetry.schema import MissionMessage
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.flight

SECRET = b"orders-test-secret-0123456789"
VEHICLE = "sitl1"


def _params(tmp_path, udp_port: int):  # type: ignore[no-untyped-def]
    secret = tmp_path / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(0o600)  # a secret others can read is refused
    text = shipped_params_path("sitl_short.toml").read_text()
    text = text.replace('autopilot = "sim"', 'autopilot = "px4"')
    text = text.replace('connection = "udpin://0.0.0.0:14540"', f'connection = "udpin://127.0.0.1:{udp_port}"')
    text += (
        "\n[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n"
        f'[telemetry.commands]\nenabled = true\nsecret_file = "{secret}"\n'
    )
    f = tmp_path / "vehicle.toml"
    f.write_text(text)
    return load_simulated_config(f), secret


def _pad(home: GeoPoint, north_m: float, east_m: float) -> OrderPad:
    g = ned_to_geo(home, north_m, east_m, 0.0)
    return OrderPad(g.lat_deg, g.lon_deg)


async def test_order_after_order_over_zenoh(mav, udp_port, tmp_path, capsys) -> None:  # type: ignore[no-untyped-def]
    config, secret_file = _params(tmp_path, udp_port)
    zport = free_tcp_port()
    zfile = tmp_path / "ground_zenoh.toml"
    zfile.write_text(
        f'[zenoh]\nmode = "peer"\nlisten = []\nconnect = ["tcp/127.0.0.1:{zport}"]\n'
        "multicast_scouting = false\ngossip_scouting = false\n"
    )
    h = config.sim.home
    home = GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m)
    pad1, pad2, far = _pad(home, 14.0, 14.0), _pad(home, -12.0, 10.0), _pad(home, 0.0, 150.0)
    received: list = []
    station = GroundStation(loopback_settings(connect_port=zport), listener=lambda env, _t: received.append(env))
    events = []
    stop = asyncio.Event()
    session_dir = tmp_path / "session"

    def flown(order_id: str) -> bool:
        return any(e.detail.startswith(f"order {order_id} flown") for e in events)

    async def send(pad: OrderPad, order_id: str):  # type: ignore[no-untyped-def]
        return await asyncio.to_thread(station.send_order, VEHICLE, pad, SECRET, order_id=order_id, timeout_s=5.0)

    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
        task = asyncio.get_running_loop().create_task(
            serve_orders(
                config,
                ap,
                session_dir,
                zenoh_settings=loopback_settings(listen_port=zport),
                flight_timeout_s=120.0,
                stop=stop,
                on_event=events.append,
            )
        )
        try:
            await mav.wait_for(lambda: ap.telemetry.home is not None and ap.telemetry.status is not None, 30.0, "home")
            await mav.wait_for(lambda: ap.telemetry.status.healthy, 30.0, "a healthy vehicle")
            await asyncio.to_thread(station.start)

            r1 = None
            for _ in range(50):  # until the ground's session reaches the desk's queryable
                r1 = await send(pad1, "o-1")
                if r1.replied:
                    break
                await asyncio.sleep(0.1)
            assert r1 is not None and r1.accepted and r1.reason == "accepted: flying it now", r1

            await mav.wait_for(lambda: sim.vehicle.armed, 30.0, "order 1 armed")
            busy = await send(pad2, "o-busy")
            assert busy.replied and not busy.accepted and busy.reason == "busy: flying order o-1", busy

            await mav.wait_for(lambda: flown("o-1"), 90.0, "order 1 flown")
            assert sim.vehicle.mode is FlightMode.HOLD and not sim.vehicle.armed  # ready for the next

            capsys.readouterr()
            argv = [
                "order", "--vehicle", VEHICLE, "--lat", f"{far.lat_deg:.7f}", "--lon", f"{far.lon_deg:.7f}",
                "--secret-file", str(secret_file), "--zenoh-config", str(zfile), "--order-id", "o-far",
            ]  # fmt: skip
            code = await asyncio.to_thread(companion_main, argv)
            out = capsys.readouterr().out
            assert code == exits.FAILED, out
            # 150 m from the configured home; the home PX4 reports carries its GPS noise
            assert re.fullmatch(
                rf"order to {VEHICLE}: REFUSED: out of range: the pad is 1(49\.\d|50\.\d) m from home, beyond "
                r"limits\.geofence_radius_m = 100 m",
                out.strip(),
            ), out

            r2 = await send(pad2, "o-2")
            assert r2.accepted, r2
            await mav.wait_for(lambda: flown("o-2"), 90.0, "order 2 flown")
        finally:
            stop.set()
            session = await asyncio.wait_for(task, 30.0)
            await asyncio.to_thread(station.stop)
        assert len(sim.vehicle.touchdowns) == 4  # two deliveries, out and home each

    assert [(f.order_id, f.delivered, f.returned, f.failure) for f in session.flights] == [
        ("o-1", True, True, ""),
        ("o-2", True, True, ""),
    ]
    assert (session.accepted, session.refused) == (2, 2)
    assert all(e.kind is EventKind.ORDER for e in session.events)
    # each flight in its own folder, its pad the order's
    for n, (oid, pad) in enumerate((("o-1", pad1), ("o-2", pad2)), start=1):
        run = json.loads((session_dir / f"{n:02d}-{oid}" / "run.json").read_text())
        flown_pad = run["config"]["mission"]["pad"]
        assert (flown_pad["lat_deg"], flown_pad["lon_deg"]) == (pad.as_signed().lat_deg, pad.as_signed().lon_deg)
        assert (session_dir / f"{n:02d}-{oid}" / "events.csv").stat().st_size > 0
    rows = list(csv.DictReader((session_dir / "orders.csv").open()))
    assert [(r["order_id"], r["accepted"]) for r in rows] == [
        ("o-1", "1"),
        ("o-busy", "0"),
        ("o-far", "0"),
        ("o-2", "1"),
    ]
    # the busy refusal came while order 1 flew: the ground saw it as a mission event on telemetry
    order_events = [
        env.msg.event.detail
        for env in received
        if isinstance(env.msg, MissionMessage) and env.msg.event is not None and env.msg.event.kind is EventKind.ORDER
    ]
    assert "order o-busy from ground: REFUSED: busy: flying order o-1" in order_events


def test_fly_orders_answers_and_ends_cleanly_on_ctrl_c(mav, udp_port, tmp_path) -> None:  # type: ignore[no-untyped-def]
    """`companion fly --orders` as a process: it answers an order (refused: outside the range) and
    SIGINT while it waits ends it with its tally, exit 0 (nothing flown, nothing failed)."""
    config, _ = _params(tmp_path, udp_port)
    zport = free_tcp_port()
    vehicle_z = tmp_path / "vehicle_zenoh.toml"
    vehicle_z.write_text(
        f'[zenoh]\nmode = "peer"\nlisten = ["tcp/127.0.0.1:{zport}"]\nconnect = []\n'
        "multicast_scouting = false\ngossip_scouting = false\n"
    )
    params = tmp_path / "vehicle.toml"
    params.write_text(
        params.read_text().replace(
            "[telemetry.commands]", f'[telemetry]\nzenoh_config = "{vehicle_z}"\n[telemetry.commands]'
        )
    )
    h = config.sim.home
    far = _pad(GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m), 0.0, 150.0)
    with mav.sim_vehicle(config, "px4", udp_port):
        proc = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "companion",
                "fly",
                "--params",
                str(params),
                "--orders",
                "--no-preflight",
                "--out",
                str(tmp_path / "s"),
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            cwd=tmp_path,
        )
        station = GroundStation(loopback_settings(connect_port=zport))
        try:
            t0 = time.monotonic()
            while True:  # the vehicle's session comes up with the process
                try:
                    station.start()
                    break
                except Exception:
                    assert time.monotonic() - t0 < 20.0 and proc.poll() is None, (
                        "the vehicle's Zenoh session never came up"
                    )
                    time.sleep(0.2)
            reply = None
            while time.monotonic() - t0 < 30.0:
                reply = station.send_order(VEHICLE, far, SECRET, order_id="o-far", timeout_s=2.0)
                if reply.replied and not reply.reason.startswith("vehicle not ready"):
                    break
                time.sleep(0.3)
            assert reply is not None and reply.replied and not reply.accepted, reply
            assert reply.reason.startswith("out of range: the pad is 1"), reply
        finally:
            station.stop()
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=30)
    assert proc.returncode == exits.OK, (out, err[-3000:])
    assert "taking delivery orders for sitl1" in out and "REFUSED: out of range" in out
    # orders sent before the vehicle was ready were refused too ("vehicle not ready"): a loaded
    # machine makes more of them
    counts = re.search(r"orders: 0 accepted, (\d+) refused, 0 flown", out)
    assert counts is not None and int(counts.group(1)) >= 1, out
    rows = list(csv.DictReader((tmp_path / "s" / "orders.csv").open()))
    assert rows[-1]["order_id"] == "o-far" and rows[-1]["accepted"] == "0"
