"""Telemetry benchmark: N vehicles publishing state to one ground station over loopback.

Every vehicle is a real :class:`TelemetryPublisher` on its own Zenoh session (peer, connected to
the ground's loopback listener, no scouting), so the measured path is the flight path: the
``publish`` call, the keep-newest slot, the worker thread, JSON encoding, Zenoh, the ground's
validation and bookkeeping. All vehicles share this process (one pacing thread submits every
vehicle's samples, spread evenly over each period), which keeps the thread count low.

Latency is measured from the ``publish`` call (the sample's ``time_s``, ``time.monotonic``) to
the ground callback, both in this process. CPU cost is ``time.process_time`` for the whole
process (vehicles + ground) during the run, divided by the messages delivered.
"""

from __future__ import annotations

import logging
import socket
import threading
import time
from typing import Any

from companion.telemetry.ground import GroundStation
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import Envelope, StateMessage
from companion.telemetry.session import ZenohSettings

log = logging.getLogger(__name__)


def free_tcp_port() -> int:
    """A currently free TCP port on 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def loopback_settings(listen_port: int | None = None, connect_port: int | None = None) -> ZenohSettings:
    """Peer settings confined to 127.0.0.1: explicit endpoints, no multicast, fast open."""
    return ZenohSettings(
        mode="peer",
        listen=(f"tcp/127.0.0.1:{listen_port}",) if listen_port is not None else (),
        connect=(f"tcp/127.0.0.1:{connect_port}",) if connect_port is not None else (),
        multicast_scouting=False,
        gossip_scouting=False,
        scouting_delay_ms=0,
        connect_exit_on_failure=connect_port is not None,
        connect_timeout_ms=3000 if connect_port is not None else None,
    )


def _percentile(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return float("nan")
    idx = min(len(sorted_values) - 1, max(0, round(q * (len(sorted_values) - 1))))
    return sorted_values[idx]


def bench_telemetry(vehicles: int, rate_hz: float, duration_s: float) -> dict[str, Any]:
    """Run the benchmark; returns counts, latency percentiles (ms) and CPU per message."""
    if not 1 <= vehicles <= 200:
        raise ValueError("vehicles must be in [1, 200]")
    if not 0.1 <= rate_hz <= 1000.0:
        raise ValueError("rate_hz must be in [0.1, 1000]")
    if not 0.1 <= duration_s <= 3600.0:
        raise ValueError("duration_s must be in [0.1, 3600]")

    lock = threading.Lock()
    latencies: list[float] = []
    delivered = 0

    def on_message(env: Envelope, _rx: float) -> None:
        nonlocal delivered
        if isinstance(env.msg, StateMessage):
            lat = time.monotonic() - env.msg.time_s
            with lock:
                delivered += 1
                latencies.append(lat)

    port = free_tcp_port()
    ground = GroundStation(loopback_settings(listen_port=port), listener=on_message).start()
    pubs: list[TelemetryPublisher] = []
    try:
        for i in range(vehicles):
            settings = TelemetrySettings(
                vehicle_id=f"bench{i:03d}",
                # Above the submission rate: the bench measures the path, not downsampling.
                state_rate_hz=min(1000.0, 2.0 * rate_hz),
            )
            pubs.append(TelemetryPublisher(settings, loopback_settings(connect_port=port)).start())
        deadline = time.monotonic() + 10.0
        while time.monotonic() < deadline:
            rows = ground.snapshot()
            if sum(1 for r in rows.values() if r.alive) >= vehicles:
                break
            time.sleep(0.02)
        else:
            raise RuntimeError("not every bench vehicle appeared at the ground within 10 s")
        while time.monotonic() < deadline and not all(p.has_subscribers() for p in pubs):
            time.sleep(0.01)  # let the ground's subscription reach every publisher

        ticks = max(1, round(duration_s * rate_hz))
        period = 1.0 / rate_hz
        cpu0 = time.process_time()
        wall0 = time.monotonic()
        late = 0
        for k in range(ticks):
            for i, pub in enumerate(pubs):
                due = wall0 + (k + i / vehicles) * period
                now = time.monotonic()
                if due > now:
                    time.sleep(due - now)
                elif now - due > period:
                    late += 1
                t = time.monotonic()
                pub.publish(
                    StateMessage(
                        time_s=t, north_m=float(k), east_m=float(i), down_m=-10.0,
                        north_m_s=1.0, east_m_s=0.0, down_m_s=0.0,
                        roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0,
                        lat_deg=-19.87, lon_deg=-43.96, battery_pct=90.0,
                    )
                )  # fmt: skip
        submitted = sum(p.counters().submitted["state"] for p in pubs)
        settle = time.monotonic() + 3.0
        while time.monotonic() < settle:
            with lock:
                if delivered >= submitted:
                    break
            time.sleep(0.01)
        wall = time.monotonic() - wall0
        cpu = time.process_time() - cpu0
        counters = [p.counters() for p in pubs]
    finally:
        for p in pubs:
            p.stop()
        ground.stop()

    published = sum(c.published["state"] for c in counters)
    superseded = sum(c.superseded["state"] for c in counters)
    with lock:
        lat_ms = sorted(v * 1000.0 for v in latencies)
        n = delivered
    result = {
        "vehicles": vehicles,
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "submitted": submitted,
        "published": published,
        "superseded": superseded,
        "delivered": n,
        "lost": submitted - n,
        "late_submissions": late,
        "latency_p50_ms": _percentile(lat_ms, 0.50),
        "latency_p99_ms": _percentile(lat_ms, 0.99),
        "latency_max_ms": lat_ms[-1] if lat_ms else float("nan"),
        "cpu_s": cpu,
        "cpu_us_per_msg": cpu / n * 1e6 if n else float("nan"),
        "cpu_pct_of_one_core": 100.0 * cpu / wall if wall > 0 else float("nan"),
        "throughput_msg_s": n / wall if wall > 0 else 0.0,
    }
    log.info("telemetry bench: %s", result)
    return result
