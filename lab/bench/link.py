"""The MAVLink link bench (for ``companion bench link``): setpoint-stream jitter and command
round trips of both backends against the MAVLink sim vehicle on loopback UDP."""

from __future__ import annotations

import asyncio
import itertools
import statistics
import time
from typing import Any

from companion.guidance.setpoint import VelocitySetpoint
from companion.scheduling import LoopClock, RateLoop
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimConfig


def _pct(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    ys = sorted(xs)
    return ys[min(len(ys) - 1, int(q * (len(ys) - 1) + 0.5))]


def _autopilot(backend: str, port: int) -> Any:
    if backend == "px4":
        from companion.autopilot.px4 import Px4Autopilot

        return Px4Autopilot(f"udpin://127.0.0.1:{port}")
    from companion.autopilot.ardupilot import ArduPilotAutopilot

    return ArduPilotAutopilot(f"udpin:127.0.0.1:{port}")


async def _stream(ap: Any, arrivals: list[float], hz: float, seconds: float) -> dict[str, Any]:
    """The setpoint stream at ``hz``: how many arrived, their jitter, the send call's cost."""
    arrivals.clear()
    sp = VelocitySetpoint(0.0, 0.0, 0.0, 0.0)
    rate = RateLoop(LoopClock(), hz)
    call_us: list[float] = []
    for _ in range(int(seconds * hz)):
        await rate.tick()
        t = time.perf_counter()
        ap.set_velocity_ned(sp)
        call_us.append((time.perf_counter() - t) * 1e6)
    await asyncio.sleep(0.1)
    jitter_ms = [abs((b - a) - 1.0 / hz) * 1e3 for a, b in itertools.pairwise(arrivals)]
    return {
        "received": len(arrivals),
        "sent": int(seconds * hz),
        "jitter_p50_ms": round(_pct(jitter_ms, 0.5), 3),
        "jitter_p99_ms": round(_pct(jitter_ms, 0.99), 3),
        "send_call_p50_us": round(statistics.median(call_us), 1),
    }


async def _command_rtt_ms(ap: Any, backend: str) -> list[float]:
    """30 COMMAND_LONG round trips (MAV_CMD_REQUEST_MESSAGE AUTOPILOT_VERSION), ms."""
    rtt: list[float] = []
    for _ in range(30):
        t = time.perf_counter()
        if backend == "px4":
            await ap._direct_command("request", 512, 148)
        else:
            await ap._command(512, 148)
        rtt.append((time.perf_counter() - t) * 1e3)
    return rtt


async def _bench(backend: str, seconds: float) -> dict[str, Any]:
    from companion_sitl.mavlink.factory import mavlink_sim_vehicle

    port = free_udp_port()
    dialect = "px4" if backend == "px4" else "ardupilot"
    sim = mavlink_sim_vehicle(SimConfig(ready_delay_s=0.0), dialect, remote=("127.0.0.1", port)).start()
    arrivals: list[float] = []

    def on_msg(m: Any) -> None:
        if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED":
            arrivals.append(time.monotonic())

    sim.on_message = on_msg
    ap = _autopilot(backend, port)
    out: dict[str, Any] = {}
    try:
        await ap.connect(timeout_s=5.0)
        await asyncio.sleep(0.5)
        for hz in (20.0, 50.0):
            out[f"{int(hz)}hz"] = await _stream(ap, arrivals, hz, seconds)
        rtt = await _command_rtt_ms(ap, backend)
        out["command_rtt_p50_ms"] = round(_pct(rtt, 0.5), 3)
        out["command_rtt_p99_ms"] = round(_pct(rtt, 0.99), 3)
    finally:
        await ap.close()
        sim.stop()
    return out


def bench_link(seconds: float = 3.0) -> dict[str, Any]:
    """Setpoint-stream jitter (p50/p99 of |inter-arrival - period| at the vehicle) at 20 and 50 Hz
    and COMMAND_LONG round-trip latency, for both backends against the MAVLink sim vehicle."""
    return {
        "ardupilot_pymavlink": asyncio.run(_bench("ardupilot", seconds)),
        "px4_mavsdk": asyncio.run(_bench("px4", seconds)),
    }
