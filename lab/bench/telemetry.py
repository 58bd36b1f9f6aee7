"""Telemetry benchmark: N vehicles publishing state to one ground station over loopback.

Two topologies:

- **direct** (default): every vehicle is a peer connected to the ground's listener.
- **router** (``via_router=True``, ``companion bench telemetry --router``): a Zenoh router runs
  in its own process (:mod:`companion.telemetry.router_host`, zenohd's role); every vehicle and
  the ground are *clients* connected to it, so every message crosses the router
  (vehicle -> router -> ground). The router's CPU time is read from it before and after the run
  and reported apart from this process's.

Every vehicle is a real :class:`TelemetryPublisher` on its own Zenoh session (peer, connected to
the ground's loopback listener, no scouting), so the measured path is the flight path: the
``publish`` call, the keep-newest slot, the worker thread, JSON encoding, Zenoh, the ground's
validation and bookkeeping. All vehicles share this process (one pacing thread submits every
vehicle's samples, spread evenly over each period), which keeps the thread count low.

Loss is counted per vehicle from the envelopes' sequence numbers: a vehicle's ``state`` messages
carry seq 0, 1, ... in publication order, so ``published - distinct seqs received`` is what the
ground never got (duplicates are counted apart).

Latency is measured from the ``publish`` call (the sample's ``time_s``, ``time.monotonic``) to
the ground callback, both in this process. CPU cost is ``time.process_time`` for the whole
process (vehicles + ground) during the run, divided by the messages delivered; with the router,
plus the router process's CPU time over the same interval.
"""

from __future__ import annotations

import logging
import subprocess
import sys
import threading
import time
from collections.abc import Sequence
from typing import IO, Any

from companion.telemetry.ground import GroundStation
from companion.telemetry.loopback import client_settings, free_tcp_port, loopback_settings
from companion.telemetry.publisher import TelemetryPublisher, TelemetrySettings
from companion.telemetry.schema import Envelope, StateMessage

log = logging.getLogger(__name__)


class RouterProcess:
    """The Zenoh router of the fleet bench in a child process (see :mod:`.router_host`)."""

    def __init__(self, port: int, start_timeout_s: float = 10.0):
        self.port = port
        self.endpoint = f"tcp/127.0.0.1:{port}"
        self._proc = subprocess.Popen(
            [sys.executable, "-m", "companion.telemetry.router_host", self.endpoint],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            bufsize=1,
        )
        line = self._readline(start_timeout_s)
        if line != "ready":
            err = self._stop_and_stderr()
            raise RuntimeError(f"the bench's Zenoh router on {self.endpoint} did not start: {line!r} {err}")

    def _readline(self, timeout_s: float) -> str:
        out: IO[str] | None = self._proc.stdout
        assert out is not None
        box: list[str] = []
        t = threading.Thread(target=lambda: box.append(out.readline()), daemon=True)
        t.start()
        t.join(timeout_s)
        return box[0].strip() if box else ""

    def cpu_s(self) -> float:
        """The router process's CPU time so far (all its threads)."""
        stdin = self._proc.stdin
        assert stdin is not None
        stdin.write("cpu\n")
        stdin.flush()
        line = self._readline(5.0)
        try:
            return float(line)
        except ValueError:
            raise RuntimeError(f"the bench's Zenoh router answered {line!r} to 'cpu' (expected seconds)") from None

    def _stop_and_stderr(self) -> str:
        if self._proc.stdin is not None and not self._proc.stdin.closed:
            self._proc.stdin.close()
        try:
            self._proc.wait(timeout=5.0)
        except subprocess.TimeoutExpired:
            self._proc.kill()
            self._proc.wait()
        err = self._proc.stderr.read() if self._proc.stderr is not None else ""
        return err.strip()[-500:]

    def stop(self) -> None:
        err = self._stop_and_stderr()
        if self._proc.returncode not in (0, None) and err:
            log.warning("bench router exited with %s: %s", self._proc.returncode, err)


def _percentile(sorted_values: list[float], q: float) -> float:
    if not sorted_values:
        return float("nan")
    idx = min(len(sorted_values) - 1, max(0, round(q * (len(sorted_values) - 1))))
    return sorted_values[idx]


class _Receiver:
    """The ground's side of the bench: every state message's latency, and the sequence numbers
    each vehicle's messages arrived with (loss and duplicates); called on Zenoh's thread."""

    def __init__(self, vehicles: int) -> None:
        self.lock = threading.Lock()
        self.latencies: list[float] = []
        self.delivered = 0
        self.seqs: dict[str, set[int]] = {f"bench{i:03d}": set() for i in range(vehicles)}
        self.duplicates = 0

    def on_message(self, env: Envelope, _rx: float) -> None:
        if isinstance(env.msg, StateMessage):
            lat = time.monotonic() - env.msg.time_s
            with self.lock:
                self.delivered += 1
                self.latencies.append(lat)
                got = self.seqs.setdefault(env.vehicle_id, set())
                if env.seq in got:
                    self.duplicates += 1
                got.add(env.seq)

    def wait_for(self, submitted: int, timeout_s: float) -> None:
        """Until every submitted message arrived, or ``timeout_s``."""
        settle = time.monotonic() + timeout_s
        while time.monotonic() < settle:
            with self.lock:
                if self.delivered >= submitted:
                    break
            time.sleep(0.01)


def _check_bench_args(vehicles: int, rate_hz: float, duration_s: float) -> None:
    if not 1 <= vehicles <= 200:
        raise ValueError("vehicles must be in [1, 200]")
    if not 0.1 <= rate_hz <= 1000.0:
        raise ValueError("rate_hz must be in [0.1, 1000]")
    if not 0.1 <= duration_s <= 3600.0:
        raise ValueError("duration_s must be in [0.1, 3600]")


def _start_fleet(vehicles: int, rate_hz: float, vehicle_zenoh: Any, pubs: list[TelemetryPublisher]) -> None:
    """Start the vehicles' publishers into ``pubs`` (the caller stops them, even half started)."""
    for i in range(vehicles):
        settings = TelemetrySettings(
            vehicle_id=f"bench{i:03d}",
            # Above the submission rate: the bench measures the path, not downsampling.
            state_rate_hz=min(1000.0, 2.0 * rate_hz),
        )
        pubs.append(TelemetryPublisher(settings, vehicle_zenoh).start())


def _wait_for_fleet(ground: GroundStation, pubs: list[TelemetryPublisher], vehicles: int) -> None:
    """Until every vehicle is alive at the ground and the ground's subscription reached it (10 s)."""
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


def _publish_paced(pubs: list[TelemetryPublisher], ticks: int, period: float, wall0: float) -> int:
    """Every vehicle's state, ``ticks`` times, spread evenly over each period; the submissions late
    by more than a period."""
    vehicles = len(pubs)
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
    return late


def _lost_per_vehicle(rx: _Receiver, counters: list[Any]) -> dict[str, int]:
    """Per vehicle: published minus the distinct sequence numbers the ground received (the caller holds the lock)."""
    lost: dict[str, int] = {}
    for i, c in enumerate(counters):
        vid = f"bench{i:03d}"
        sent = c.published["state"]
        lost[vid] = sent - sum(1 for q in rx.seqs[vid] if q < sent)
    return lost


def bench_telemetry(vehicles: int, rate_hz: float, duration_s: float, *, via_router: bool = False) -> dict[str, Any]:
    """Run the benchmark; returns counts, loss per vehicle, latency percentiles (ms) and CPU per
    message. ``via_router``: vehicles and ground are clients of a router process."""
    _check_bench_args(vehicles, rate_hz, duration_s)
    rx = _Receiver(vehicles)
    port = free_tcp_port()
    router: RouterProcess | None = None
    if via_router:
        router = RouterProcess(port)
        ground_zenoh = client_settings(port)
        vehicle_zenoh = client_settings(port)
    else:
        ground_zenoh = loopback_settings(listen_port=port)
        vehicle_zenoh = loopback_settings(connect_port=port)
    pubs: list[TelemetryPublisher] = []
    ground: GroundStation | None = None
    try:
        ground = GroundStation(ground_zenoh, listener=rx.on_message).start()
        _start_fleet(vehicles, rate_hz, vehicle_zenoh, pubs)
        _wait_for_fleet(ground, pubs, vehicles)
        ticks = max(1, round(duration_s * rate_hz))
        router_cpu0 = router.cpu_s() if router is not None else 0.0
        cpu0 = time.process_time()
        wall0 = time.monotonic()
        late = _publish_paced(pubs, ticks, 1.0 / rate_hz, wall0)
        submitted = sum(p.counters().submitted["state"] for p in pubs)
        rx.wait_for(submitted, 3.0)
        wall = time.monotonic() - wall0
        cpu = time.process_time() - cpu0
        router_cpu = router.cpu_s() - router_cpu0 if router is not None else 0.0
        counters = [p.counters() for p in pubs]
    finally:
        for p in pubs:
            p.stop()
        if ground is not None:
            ground.stop()
        if router is not None:
            router.stop()

    published = sum(c.published["state"] for c in counters)
    superseded = sum(c.superseded["state"] for c in counters)
    with rx.lock:
        lat_ms = sorted(v * 1000.0 for v in rx.latencies)
        n = rx.delivered
        lost_per_vehicle = _lost_per_vehicle(rx, counters)
        dup = rx.duplicates
    total_cpu = cpu + router_cpu
    result = {
        "topology": "router" if via_router else "direct",
        "vehicles": vehicles,
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "submitted": submitted,
        "published": published,
        "superseded": superseded,
        "delivered": n,
        "lost": submitted - n,
        "lost_by_seq": sum(lost_per_vehicle.values()),
        "lost_per_vehicle": lost_per_vehicle,
        "vehicles_with_loss": sum(1 for v in lost_per_vehicle.values() if v),
        "duplicates": dup,
        "late_submissions": late,
        "latency_p50_ms": _percentile(lat_ms, 0.50),
        "latency_p99_ms": _percentile(lat_ms, 0.99),
        "latency_max_ms": lat_ms[-1] if lat_ms else float("nan"),
        "cpu_s": total_cpu,
        "cpu_us_per_msg": total_cpu / n * 1e6 if n else float("nan"),
        "cpu_pct_of_one_core": 100.0 * total_cpu / wall if wall > 0 else float("nan"),
        "bench_process_cpu_us_per_msg": cpu / n * 1e6 if n else float("nan"),
        "router_cpu_us_per_msg": router_cpu / n * 1e6 if (n and via_router) else None,
        "throughput_msg_s": n / wall if wall > 0 else 0.0,
    }
    log.info("telemetry bench: %s", {k: v for k, v in result.items() if k != "lost_per_vehicle"})
    return result


def bench_fleet(
    vehicle_counts: Sequence[int], rate_hz: float, duration_s: float, *, via_router: bool
) -> dict[str, Any]:
    """:func:`bench_telemetry` for each fleet size in one run (a fresh router and fleet each), and
    how CPU per message grows from the smallest to the largest fleet."""
    if not vehicle_counts:
        raise ValueError("vehicles: expected at least one fleet size")
    runs = [bench_telemetry(v, rate_hz, duration_s, via_router=via_router) for v in vehicle_counts]
    first, last = runs[0], runs[-1]
    growth = last["cpu_us_per_msg"] / first["cpu_us_per_msg"] if len(runs) > 1 and first["cpu_us_per_msg"] > 0 else None
    return {
        "topology": "router" if via_router else "direct",
        "rate_hz": rate_hz,
        "duration_s": duration_s,
        "runs": runs,
        "cpu_per_msg_ratio_largest_to_smallest": growth,
    }
