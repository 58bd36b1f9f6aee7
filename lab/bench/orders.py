"""``companion bench orders``: one delivery flown by ``fly --orders`` (:func:`serve_orders`) on the
MAVLink sim vehicle while its Zenoh queryables are attacked over loopback, and what that cost the
flight: the largest gap between setpoints, the state telemetry rate a ground received, the vehicle
process's peak RSS, and every hostile request counted.

Three processes: this one is the vehicle (the companion and, on its own thread, the sim vehicle);
a *ground* child subscribes to the vehicle's state topic and counts samples per second; an
*attacker* child, on a Zenoh session with no message limit of its own, sends (1) large queries to
``companion/<id>/order`` one after another (each of ``--large-mb`` MiB: the vehicle's session drops
them while reassembling) and, alongside, for ``--flood-s`` seconds, ``--flood-hz`` orders a second
(unsigned, forged MAC, a 401-digit latitude, signed by an insider over its rate) and
``--command-hz`` ground commands with a forged MAC a second. Everything stays on 127.0.0.1.
Figures: docs/orders.md#under-attack.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

VEHICLE = "bench1"
SECRET = b"bench-orders-secret-0123456789"
BIG = "4" + "0" * 400  # a 401-digit integer


def _vm_kib(field: str) -> int:
    """``VmHWM`` / ``VmRSS`` of this process, KiB."""
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith(field + ":"):
            return int(line.split()[1])
    raise RuntimeError(f"no {field} in /proc/self/status")


def _reset_peak_rss() -> bool:
    """Reset VmHWM to the current RSS (Linux >= 4.0: write 5 to clear_refs); False if refused."""
    try:
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except OSError:
        return False


# ---------------------------------------------------------------------------- the child roles
def _session(port: int, unbounded: bool) -> Any:
    from companion.telemetry.loopback import loopback_settings

    s = loopback_settings(connect_port=port)
    if unbounded:  # the attacker sends what it likes; only the receiver's limit counts
        import dataclasses

        s = dataclasses.replace(s, max_message_bytes=1 << 30)
    return s.open()


def _flood_payloads(n: int, secret: bytes | None) -> list[bytes]:
    """``n`` hostile order payloads, cycling through four kinds."""
    from companion.telemetry.orders import OrderPad, sign_order

    out = []
    for i in range(n):
        kind = i % 4
        if kind == 3 and secret is not None:  # an insider over its rate: signed, fresh, new nonce
            out.append(sign_order(VEHICLE, OrderPad(47.0, 8.0), secret, order_id=f"flood-{i}", sender="insider"))
            continue
        doc = json.loads(sign_order(VEHICLE, OrderPad(47.0, 8.0), b"not-the-secret-0123456", order_id=f"f-{i}"))
        if kind == 0:
            del doc["hmac_sha256"]  # unsigned
        text = json.dumps(doc)
        if kind == 2:
            text = text.replace('"lat_deg": 47.0', '"lat_deg": ' + BIG, 1)
        out.append(text.encode())
    return out


def attacker(args: argparse.Namespace) -> dict[str, Any]:
    from companion.telemetry.auth import CommandKind, sign_command
    from companion.telemetry.schema import command_key, order_key

    secret = Path(args.secret_file).read_bytes().strip() if args.secret_file else None
    s = _session(args.port, unbounded=True)
    answered = {"ok": 0, "err": 0}
    lock = threading.Lock()

    def on_reply(reply: Any) -> None:
        with lock:
            answered["ok" if reply.ok is not None else "err"] += 1

    large: list[dict[str, Any]] = []

    def send_large() -> None:  # alongside the flood, one after another
        for mb in args.large_mb:
            payload = b'{"schema":"companion.order/1","pad":"' + b"x" * (mb << 20) + b'"}'
            t0 = time.monotonic()
            replies = list(s.get(order_key(VEHICLE), payload=payload, timeout=5.0))
            ok = sum(r.ok is not None for r in replies)
            large.append({"mib": mb, "answered": ok, "s": round(time.monotonic() - t0, 2)})
            del payload

    big = threading.Thread(target=send_large, name="large-queries")
    big.start()
    orders = _flood_payloads(max(1, int(args.flood_hz)), secret)
    bad_command = json.loads(sign_command(VEHICLE, CommandKind.LAND, b"not-the-secret-0123456"))
    bad_command["hmac_sha256"] = "0" * 64
    command = json.dumps(bad_command).encode()
    sent = {"orders": 0, "commands": 0}
    t0 = time.monotonic()
    step = 1.0 / args.flood_hz
    cstep = 1.0 / args.command_hz if args.command_hz > 0 else float("inf")
    next_o, next_c = t0, t0
    while (now := time.monotonic()) - t0 < args.flood_s:
        if now >= next_o:
            s.get(order_key(VEHICLE), on_reply, payload=orders[sent["orders"] % len(orders)], timeout=5.0)
            sent["orders"] += 1
            next_o += step
        if now >= next_c:
            s.get(command_key(VEHICLE), on_reply, payload=command, timeout=5.0)
            sent["commands"] += 1
            next_c += cstep
        time.sleep(max(0.0, min(next_o, next_c) - time.monotonic()))
    flood_s = time.monotonic() - t0
    big.join()
    time.sleep(2.0)  # the last answers
    s.close()
    return {"large": large, "sent": sent, "flood_s": round(flood_s, 2), "answered": answered}


def ground(args: argparse.Namespace) -> dict[str, Any]:
    from companion.telemetry.schema import Topic, topic_key

    s = _session(args.port, unbounded=False)
    stamps: list[float] = []
    refused: dict[str, int] = {}  # the health topic's counts of refused ground requests, latest

    def on_health(sample: Any) -> None:
        msg = json.loads(sample.payload.to_bytes())["msg"]
        refused.update({r["source"]: r["count"] for r in msg.get("rejected", ())})

    subs = [
        s.declare_subscriber(topic_key(VEHICLE, Topic.STATE), lambda _sample: stamps.append(time.time())),
        s.declare_subscriber(topic_key(VEHICLE, Topic.HEALTH), on_health),
    ]
    try:
        sys.stdout.write("ready\n")
        sys.stdout.flush()
        sys.stdin.readline()  # the bench writes a line when it is done
    finally:
        for sub in subs:
            sub.undeclare()
        s.close()
    return {"state_unix_s": stamps, "health_rejected": refused}


def child_main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="companion_lab.bench.orders")
    p.add_argument("role", choices=("attacker", "ground"))
    p.add_argument("--port", type=int, required=True)
    p.add_argument("--large-mb", type=int, nargs="*", default=[])
    p.add_argument("--flood-hz", type=float, default=500.0)
    p.add_argument("--command-hz", type=float, default=100.0)
    p.add_argument("--flood-s", type=float, default=20.0)
    p.add_argument("--secret-file")
    args = p.parse_args(argv)
    out = attacker(args) if args.role == "attacker" else ground(args)
    sys.stdout.write(json.dumps(out) + "\n")
    return 0


# ---------------------------------------------------------------------------- the vehicle
def _child(role: str, port: int, *extra: str) -> subprocess.Popen[str]:
    cmd = [sys.executable, "-m", "companion_lab.bench.orders", role, "--port", str(port), *extra]
    return subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)


def _config(tmp: Path, udp_port: int) -> Any:
    from companion.config import shipped_params_path
    from companion_sitl.params import load_simulated_config

    secret = tmp / "secret"
    secret.write_bytes(SECRET)
    secret.chmod(0o600)
    text = shipped_params_path("sitl_short.toml").read_text()
    text = text.replace('autopilot = "sim"', 'autopilot = "px4"')
    text = text.replace('connection = "udpin://0.0.0.0:14540"', f'connection = "udpin://127.0.0.1:{udp_port}"')
    text = text.replace('vehicle_id = "sitl1"', f'vehicle_id = "{VEHICLE}"')
    text += (
        "\n[landing]\nfusion = false\nuse_camera = false\nuse_uwb = false\n"
        f'[telemetry.commands]\nenabled = true\nsecret_file = "{secret}"\n'
    )
    f = tmp / "vehicle.toml"
    f.write_text(text)
    return load_simulated_config(f)


async def _until(pred: Any, timeout_s: float, what: str) -> None:
    t0 = time.monotonic()
    while not pred():
        if time.monotonic() - t0 > timeout_s:
            raise RuntimeError(f"bench orders: timed out after {timeout_s:g} s waiting for {what}")
        await asyncio.sleep(0.05)


async def _send_first_order(station: Any, config: Any) -> None:
    from companion.geometry.earth import GeoPoint, ned_to_geo
    from companion.telemetry.orders import OrderPad

    h = config.sim.home
    g = ned_to_geo(GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m), 14.0, 14.0, 0.0)
    for _ in range(100):  # until the ground's session reaches the desk's queryable
        reply = await asyncio.to_thread(
            station.send_order, VEHICLE, OrderPad(g.lat_deg, g.lon_deg), SECRET, order_id="o-1", timeout_s=5.0
        )
        if reply.replied:
            if not reply.accepted:
                raise RuntimeError(f"bench orders: the delivery order was refused: {reply.reason}")
            return
        await asyncio.sleep(0.1)
    raise RuntimeError("bench orders: the vehicle's order desk never answered")


async def run_orders_bench(
    serve_orders: Any,
    large_mb: tuple[int, ...] = (200, 200, 200, 200, 900),
    flood_hz: float = 500.0,
    command_hz: float = 100.0,
    flood_s: float = 20.0,
    out_dir: Path | None = None,
) -> dict[str, Any]:
    """Fly one order under attack (the module docstring) and return the figures. ``serve_orders``:
    the vehicle side of ``fly --orders`` (:func:`companion.cli.orders.serve_orders`; the command
    line hands it over, the lab sits below it)."""
    from companion.autopilot.px4 import Px4Autopilot
    from companion.delivery.order_session import OrderSession
    from companion.telemetry.ground import GroundStation
    from companion.telemetry.loopback import free_tcp_port, loopback_settings
    from companion_lab.bench.app import run_setpoint_stream
    from companion_sitl.mavlink.factory import mavlink_sim_vehicle
    from companion_sitl.mavlink.link import free_udp_port

    tmp = out_dir or Path(tempfile.mkdtemp(prefix="bench-orders-"))
    tmp.mkdir(parents=True, exist_ok=True)
    udp, zport = free_udp_port(), free_tcp_port()
    config = _config(tmp, udp)
    record = OrderSession()  # filled by serve_orders: a flight is in it before its "flown" event
    ended: list[float] = []  # the wall time the flight ended (its telemetry stops with it)

    def on_event(ev: Any) -> None:
        if record.flights and not ended:
            ended.append(time.time())

    stop = asyncio.Event()
    sim = mavlink_sim_vehicle(config.sim, "px4", remote=("127.0.0.1", udp)).start()
    ground = _child("ground", zport)
    station = GroundStation(loopback_settings(connect_port=zport))
    try:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp}")
        task = asyncio.get_running_loop().create_task(
            serve_orders(
                config,
                ap,
                tmp / "session",
                zenoh_settings=loopback_settings(listen_port=zport),
                flight_timeout_s=300.0,
                stop=stop,
                on_event=on_event,
                record=record,
            )
        )
        tc = ap.telemetry
        await _until(lambda: tc.status is not None and tc.home is not None and tc.status.healthy, 90.0, "ready")
        await asyncio.to_thread(station.start)
        await asyncio.to_thread(ground.stdout.readline)  # type: ignore[union-attr]
        await _send_first_order(station, config)
        await _until(lambda: tc.status is not None and tc.status.armed, 60.0, "armed")
        await asyncio.sleep(3.0)  # in the air, streaming setpoints
        peak_reset = _reset_peak_rss()
        rss0 = _vm_kib("VmRSS")
        extra = ["--large-mb", *map(str, large_mb)] if large_mb else []
        attack = _child(
            "attacker", zport, *extra, "--flood-hz", str(flood_hz), "--command-hz", str(command_hz),
            "--flood-s", str(flood_s), "--secret-file", str(tmp / "secret"),
        )  # fmt: skip
        t0 = time.time()
        a_out, _ = await asyncio.to_thread(attack.communicate)
        t1 = time.time()
        hwm = _vm_kib("VmHWM")
        flown = bool(record.flights)
        await _until(lambda: bool(record.flights), 300.0, "the flight")
    finally:
        stop.set()
        session = await asyncio.wait_for(task, 60.0) if "task" in locals() else None
        g_out, _ = await asyncio.to_thread(ground.communicate, "\n")  # a line on stdin: done
        await asyncio.to_thread(station.stop)
        sim.stop()
    att = json.loads(a_out.strip().splitlines()[-1])
    g_doc = json.loads(g_out.strip().splitlines()[-1])
    stamps = g_doc["state_unix_s"]
    flight = session.flights[0] if session is not None and session.flights else None
    t_end = min(t1, ended[0]) if ended else t1  # state is published while the flight runs
    in_attack = [s for s in stamps if t0 <= s <= t_end]
    return {
        "large_mib": list(large_mb),
        "flood_hz": flood_hz,
        "command_hz": command_hz,
        "attack": att,
        "attack_s": round(t1 - t0, 2),
        "flight_ended_during_attack": flown,
        "delivered": bool(flight and flight.delivered),
        "failure": flight.failure if flight else "not flown",
        "orders_refused": session.refused if session is not None else None,
        "setpoint_stream": run_setpoint_stream(flight.run_dir) if flight else None,
        "state_rate_hz": round(len(in_attack) / (t_end - t0), 2) if t_end > t0 else None,
        "state_window_s": round(t_end - t0, 2),
        "state_rate_hz_nominal": config.telemetry.state_rate_hz,
        "health_rejected": g_doc["health_rejected"],
        "rss_before_mib": round(rss0 / 1024, 1),
        "peak_rss_mib": round(hwm / 1024, 1),
        "peak_is_attack_only": peak_reset,
        "run_dir": str(tmp),
    }


def report(result: dict[str, Any]) -> str:
    ss = result["setpoint_stream"] or {}
    sent = result["attack"]["sent"]
    large = ", ".join(f"{x['mib']} MiB ({x['answered']} answered, {x['s']} s)" for x in result["attack"]["large"])
    return (
        f"bench orders: {large or 'no large queries'}; alongside, {sent['orders']} orders and "
        f"{sent['commands']} commands in {result['attack']['flood_s']} s\n"
        f"  flight: {'delivered' if result['delivered'] else 'NOT delivered'} {result['failure']}\n"
        f"  orders refused (counted): {result['orders_refused']}; the health topic's last counts: "
        f"{result['health_rejected']}\n"
        f"  setpoints: largest gap {ss.get('max_gap_ms')} ms, {ss.get('gaps_over_100_ms')} over 100 ms\n"
        f"  state telemetry in the {result['state_window_s']} s of the attack in flight: {result['state_rate_hz']} Hz "
        f"(rate {result['state_rate_hz_nominal']:g} Hz)\n"
        f"  vehicle process RSS: {result['rss_before_mib']} MiB before, peak {result['peak_rss_mib']} MiB "
        f"during the attack{'' if result['peak_is_attack_only'] else ' (peak since start: clear_refs refused)'}"
    )


if __name__ == "__main__":
    os.environ.setdefault("PYTHONUNBUFFERED", "1")
    raise SystemExit(child_main())
