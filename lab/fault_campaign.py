"""A fault campaign (``companion campaign landing --faults``): deliveries on the MAVLink sim
vehicle, in real time, each with one fault injected at a drawn moment, scored on the safety
contract (docs/companion-death.md): no parcel released off the pad, the autopilot's own failsafe
reached whenever the fault outlasts its timeout, no vehicle lost.

The faults are real-time ones, so they are flown where real time runs: the companion's real
backends (pymavlink for ArduPilot, MAVSDK for PX4) against the MAVLink sim vehicle, whose
ArduCopter GCS failsafe and PX4 offboard-loss action run on their own timers. A stall is a
blocking ``time.sleep`` on the control loop (the watchdog thread, the withheld heartbeats and
setpoints are the code that acts), a link cut drops every datagram both ways at the sim vehicle,
a forged command is COMMAND_LONGs (RTL, LAND, gripper release) to the companion's component from
a system that is not the GCS. A frozen process (SIGSTOP) cannot be injected in-process: it is
flown on both real firmwares by the companion-killed tests.
"""

from __future__ import annotations

import asyncio
import logging
import math
import socket
import threading
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from companion.autopilot import FlightMode
from companion.config import shipped_params_path
from companion.events import Phase
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.link import free_udp_port
from companion_sitl.params import SimulatedConfig, load_simulated_config

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Fault:
    kind: str  # "stall", "link_cut" or "forged_command"
    duration_s: float


FAULTS: dict[str, Fault] = {
    "stall_1s": Fault("stall", 1.0),
    "stall_3s": Fault("stall", 3.0),
    "stall_15s": Fault("stall", 15.0),
    "link_cut": Fault("link_cut", 8.0),
    "forged_command": Fault("forged_command", 3.0),
}
DEFAULT_FAULTS = tuple(FAULTS)
DIALECTS = ("ardupilot", "px4")
MOMENTS = ("climb", "cruise", "descent")
# the drawn height passed in the climb or the descent (sitl_short: take-off 2.5 m, cruise 8 m)
HEIGHT_RANGE_M = (3.0, 7.0)
# the drawn fraction of the way from home to the pad passed in the cruise
CRUISE_RANGE = (0.3, 0.7)
# the failsafe is required when the fault outlasts the autopilot's timeout by this much (the
# watchdog's poll, the vehicle's failsafe check and the mode's report on the link)
FAILSAFE_MARGIN_S = 0.5
# what the pre-flight check expects of each vehicle (docs/companion-death.md)
FAILSAFE_PARAMS = {"ardupilot": {"GRIP_ENABLE": 1.0, "FS_GCS_ENABLE": 5.0}, "px4": {"COM_OBL_RC_ACT": 4.0}}
ARDUCOPTER_FS_GCS_TIMEOUT_S = 5.0  # the sim vehicle's default, as ArduCopter's
FORGER_SYSTEM = 200
# MAV_CMD_NAV_RETURN_TO_LAUNCH, MAV_CMD_NAV_LAND, MAV_CMD_DO_GRIPPER (release)
FORGED_COMMANDS = ((20, 0.0), (21, 0.0), (211, 0.0))
SETTLE_S = 60.0  # after the mission: time for the autopilot's own landing to disarm


@dataclass(frozen=True)
class FaultDraw:
    """One landing of a fault campaign: its fault, the dialect flown and the moment it starts."""

    index: int
    seed: int
    fault: str
    dialect: str
    moment: str
    height_m: float  # climb and descent: the height passed
    fraction: float  # cruise: the fraction of the way to the pad passed


def parse_faults(text: str) -> tuple[str, ...]:
    """A comma-separated fault list (``all``: every fault), checked against :data:`FAULTS`."""
    names = [f.strip() for f in text.split(",") if f.strip()]
    if names == ["all"]:
        return DEFAULT_FAULTS
    unknown = [f for f in names if f not in FAULTS]
    if unknown or not names:
        raise ValueError(f"unknown fault(s) {unknown or [text]}; choose from {', '.join(FAULTS)} or all")
    return tuple(dict.fromkeys(names))


def draw_faults(n: int, seed: int, faults: tuple[str, ...]) -> list[FaultDraw]:
    """``n`` landings per fault, fault-major: the dialect, moment, height and fraction of each from
    one generator of ``seed``, so the same arguments give the same campaign."""
    if n < 1:
        raise ValueError(f"n = {n}: need at least one landing per fault")
    rng = np.random.default_rng([seed, 61])
    out: list[FaultDraw] = []
    for fault in faults:
        if fault not in FAULTS:
            raise ValueError(f"unknown fault {fault!r}; choose from {', '.join(FAULTS)}")
        for _ in range(n):
            k = len(out)
            out.append(
                FaultDraw(
                    index=k,
                    seed=seed * 1000 + k,
                    fault=fault,
                    dialect=DIALECTS[int(rng.integers(len(DIALECTS)))],
                    moment=MOMENTS[int(rng.integers(len(MOMENTS)))],
                    height_m=float(rng.uniform(*HEIGHT_RANGE_M)),
                    fraction=float(rng.uniform(*CRUISE_RANGE)),
                )
            )
    return out


def failsafe_timeout_s(config: SimulatedConfig, dialect: str, fault: str) -> float | None:
    """How long the fault must last for the autopilot's own failsafe to fire (None: it stops
    nothing of ours). ArduCopter: FS_GCS_TIMEOUT from the last heartbeat, which a stall stops
    only once the watchdog shuts the gate, ``loop_stall_s`` in. PX4: COM_OF_LOSS_T from the last
    setpoint, which the loop itself sends."""
    f = FAULTS[fault]
    if f.kind == "forged_command":
        return None
    if dialect == "px4":
        return config.sim.vehicle.offboard_loss_timeout_s
    return ARDUCOPTER_FS_GCS_TIMEOUT_S + (config.runtime.loop_stall_s if f.kind == "stall" else 0.0)


def failsafe_required(config: SimulatedConfig, d: FaultDraw) -> bool:
    """The fault outlasts the autopilot's timeout (and the margin): its failsafe must fire."""
    timeout = failsafe_timeout_s(config, d.dialect, d.fault)
    return timeout is not None and FAULTS[d.fault].duration_s > timeout + FAILSAFE_MARGIN_S


class _Truth:
    """The sim vehicle seen from a thread of its own (the loop may be the one that hangs): its
    modes with their times, the farthest it went from home, where the parcel left it."""

    def __init__(self, sim: Any) -> None:
        self.sim = sim
        self.modes: list[tuple[float, FlightMode]] = []
        self.max_from_home_m = 0.0
        self.released_at: tuple[float, float, float] | None = None  # true north, east, down
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="fault-truth", daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            v = self.sim.vehicle
            if not self.modes or self.modes[-1][1] is not v.mode:
                self.modes.append((time.monotonic(), v.mode))
            self.max_from_home_m = max(self.max_from_home_m, math.hypot(v.pn, v.pe))
            if v.payload_released and self.released_at is None:
                self.released_at = (v.pn, v.pe, v.pd)

    def __enter__(self) -> _Truth:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(1.0)

    def land_after(self, t0: float, t1: float) -> float | None:
        """Seconds from ``t0`` to the first switch to LAND in [t0, t1]; None if none."""
        return next((t - t0 for t, m in self.modes if m is FlightMode.LAND and t0 <= t <= t1), None)


class _Forger:
    """Someone else on the link: COMMAND_LONGs to the companion's component from a system that is
    not the GCS, through the sim vehicle's routing, every 0.1 s while running."""

    def __init__(self, vehicle_addr: tuple[str, int], component_id: int) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink

        self.addr, self.component_id = vehicle_addr, component_id
        self.enc = mavlink.MAVLink(None, srcSystem=FORGER_SYSTEM, srcComponent=190)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sent = 0

    def run_for(self, seconds: float) -> None:
        t_end = time.monotonic() + seconds
        while time.monotonic() < t_end:
            cmd, p1 = FORGED_COMMANDS[self.sent % len(FORGED_COMMANDS)]
            msg = self.enc.command_long_encode(1, self.component_id, cmd, 0, p1, 0, 0, 0, 0, 0, 0)
            self.sock.sendto(msg.pack(self.enc), self.addr)
            self.sent += 1
            time.sleep(0.1)
        self.sock.close()


def pad_ne(config: SimulatedConfig) -> tuple[float, float]:
    """The pad's north and east of home (the sim vehicle's true frame), as the parameters give it."""
    pad = config.mission.pad
    if pad.north_m is None or pad.east_m is None:
        raise ValueError("the fault campaign needs [mission.pad] north_m and east_m (as params/sitl_short.toml)")
    return pad.north_m, pad.east_m


def _at_moment(config: SimulatedConfig, d: FaultDraw, shell: Any) -> bool:
    """The vehicle (as the companion sees it) has reached the draw's moment."""
    p = shell.autopilot.telemetry.position_ned
    if p is None:
        return False
    pad_n, pad_e = pad_ne(config)
    height, climb = -p.down_m, -p.down_m_s
    if d.moment == "climb":
        return climb > 0.2 and height > d.height_m
    if d.moment == "cruise":
        out_m = math.hypot(p.north_m, p.east_m)
        return height > 0.75 * config.mission.height_m and out_m > d.fraction * math.hypot(pad_n, pad_e)
    from_pad = math.hypot(p.north_m - pad_n, p.east_m - pad_e)
    return from_pad < 3.0 and climb < -0.2 and height < d.height_m


def _autopilot(config: SimulatedConfig, dialect: str, port: int) -> Any:
    if dialect == "ardupilot":
        from companion.autopilot.ardupilot import ArduPilotAutopilot

        return ArduPilotAutopilot.from_config(config.model_copy(update={"connection": f"udpin:127.0.0.1:{port}"}))
    from companion.autopilot.px4 import Px4Autopilot

    return Px4Autopilot.from_config(config.model_copy(update={"connection": f"udpin://127.0.0.1:{port}"}))


async def _fly(config: SimulatedConfig, d: FaultDraw, sim: Any, truth: _Truth) -> dict[str, Any]:
    """The delivery with the fault injected at its moment, on the loop (a stall) or beside it."""
    from companion.delivery.shell import DeliveryShell

    fault = FAULTS[d.fault]
    fired: dict[str, Any] = {}
    forger = _Forger(sim.address, config.gcs.component_id) if fault.kind == "forged_command" else None

    def on_tick(shell: Any, out: Any) -> None:  # on the loop: a stall is the loop's own
        if fired or out.phase.terminal or not _at_moment(config, d, shell):
            return
        p = shell.autopilot.telemetry.position_ned
        fired.update(start=time.monotonic(), height_m=-p.down_m, phase=out.phase.value)
        if fault.kind == "stall":
            time.sleep(fault.duration_s)
        elif fault.kind == "link_cut":
            sim.set_link(False)
            threading.Timer(fault.duration_s, sim.set_link, (True,)).start()
        elif forger is not None:
            threading.Thread(target=forger.run_for, args=(fault.duration_s,), daemon=True).start()
        fired["end"] = fired["start"] + fault.duration_s

    ap = _autopilot(config, d.dialect, sim.remote[1])
    shell = DeliveryShell(config, ap, on_tick=on_tick)
    try:
        summary = await shell.run(timeout_s=150.0)
        await asyncio.sleep(1.0)
    finally:
        refused = shell.gcs.refused if shell.gcs is not None else 0
        await ap.close()
    return {
        "summary": summary,
        "pilot": shell.mission.phase is Phase.PILOT,
        "fired": fired,
        "forged_sent": forger.sent if forger else 0,
        "forged_refused": refused,
    }


def fly_fault_landing(config: SimulatedConfig, d: FaultDraw) -> dict[str, Any]:
    """Fly one landing of the fault campaign and score it: the campaign JSON's row."""
    cfg = config.model_copy(update={"sim": config.sim.model_copy(update={"seed": d.seed})})
    port = free_udp_port()
    sim = mavlink_sim_vehicle(
        cfg.sim, d.dialect, remote=("127.0.0.1", port), params=FAILSAFE_PARAMS[d.dialect], route_peers=True
    ).start()
    try:
        with _Truth(sim) as truth:
            r = asyncio.run(_fly(cfg, d, sim, truth))
            t_end = time.monotonic() + SETTLE_S
            while sim.vehicle.armed and time.monotonic() < t_end:
                time.sleep(0.1)
            time.sleep(0.1)
        armed = sim.vehicle.armed
        touchdowns = list(sim.vehicle.touchdowns)
        truth_log = list(sim.vehicle.truth_log)
    finally:
        sim.stop()
    return _score(cfg, d, r, truth, armed, touchdowns, truth_log)


def _touchdown_speed(truth_log: list[Any], t_td: float) -> float:
    """The fastest sink in the last metre above the ground before the touchdown at ``t_td``."""
    sinks = [s.down_m_s for s in truth_log if s.time_s <= t_td and s.down_m > -1.0]
    return max(sinks, default=0.0)


def _score(
    config: SimulatedConfig,
    d: FaultDraw,
    r: dict[str, Any],
    truth: _Truth,
    armed: bool,
    touchdowns: list[Any],
    truth_log: list[Any],
) -> dict[str, Any]:
    (pad_n, pad_e), fired, s = pad_ne(config), r["fired"], r["summary"]
    half = config.mission.pad.size_m / 2.0
    rel = truth.released_at
    # on the pad: inside the square and on the ground (not dropped from the air)
    on_pad = rel is not None and abs(rel[0] - pad_n) <= half and abs(rel[1] - pad_e) <= half and rel[2] > -0.3
    failsafe_s = truth.land_after(fired["start"], fired["end"] + 1.0) if fired else None
    td = touchdowns[0] if touchdowns else None
    speed = _touchdown_speed(truth_log, td.time_s) if td else math.nan
    lost = "did_not_land" if armed or td is None else ""
    # faster than the descent limit the mission itself flies to: a crash, not a firm landing
    lost = lost or ("crashed" if speed > config.limits.max_descent_m_s else "")
    lost = lost or ("left_area" if truth.max_from_home_m > config.limits.geofence_radius_m else "")
    return {
        **asdict(d),
        "fired": bool(fired),
        "fired_phase": fired.get("phase", ""),
        "fired_height_m": fired.get("height_m", math.nan),
        "duration_s": FAULTS[d.fault].duration_s,
        "failsafe_timeout_s": failsafe_timeout_s(config, d.dialect, d.fault),
        "failsafe_required": bool(fired) and failsafe_required(config, d),
        "failsafe_s": failsafe_s,
        "released": rel is not None,
        "released_on_pad": bool(on_pad),
        "released_off_pad": bool(rel is not None and not on_pad),
        "delivered": s.delivered,
        "failure_kind": s.failure_kind.value,
        "failure": s.failure,
        "pilot_phase": r["pilot"],
        "touchdown_ne_m": (td.north_m, td.east_m) if td else None,
        "touchdown_speed_m_s": speed,
        "max_from_home_m": truth.max_from_home_m,
        "lost": lost,
        "forged_sent": r["forged_sent"],
        "forged_refused": r["forged_refused"],
    }


def summarize_faults(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """One fault's figures: landings, faults fired, parcels released off and on the pad, the
    failsafe reached of required, spurious failsafes, vehicles lost."""
    required = [x for x in rows if x["failsafe_required"]]
    return {
        "landings": len(rows),
        "fired": sum(x["fired"] for x in rows),
        "released_off_pad": sum(x["released_off_pad"] for x in rows),
        "released_on_pad": sum(x["released_on_pad"] for x in rows),
        "failsafe_required": len(required),
        "failsafe_reached": sum(x["failsafe_s"] is not None for x in required),
        "failsafe_unrequired": sum(x["failsafe_s"] is not None for x in rows if not x["failsafe_required"]),
        "lost": sum(bool(x["lost"]) for x in rows),
        "touchdown_speed_max_m_s": max(
            (x["touchdown_speed_m_s"] for x in rows if x["touchdown_ne_m"]), default=math.nan
        ),
        "dialects": {k: sum(x["dialect"] == k for x in rows) for k in DIALECTS},
    }


def run_fault_campaign(
    n: int,
    seed: int,
    faults: tuple[str, ...] = DEFAULT_FAULTS,
    params: str | Path | None = None,
    progress: Any = None,
) -> dict[str, Any]:
    """Fly ``n`` landings per fault, one after the other (real time), and summarise them by fault.
    ``progress(fault, done, total)`` is called as each landing finishes."""
    base = Path(params) if params else shipped_params_path("sitl_short.toml")
    # the delivery's landing alone: a fault's consequences, not the flight home, are scored
    config = load_simulated_config(base, overrides={"mission": {"return_home": False}})
    draws = draw_faults(n, seed, faults)
    rows: dict[str, list[dict[str, Any]]] = {f: [] for f in faults}
    t0 = time.perf_counter()
    for k, d in enumerate(draws):
        row = fly_fault_landing(config, d)
        rows[d.fault].append(row)
        log.info(
            "fault landing %d of %d (%s, %s, %s): released %s, failsafe %s, lost %s; %.0f s so far",
            k + 1,
            len(draws),
            d.fault,
            d.dialect,
            d.moment,
            "off the pad" if row["released_off_pad"] else "on the pad" if row["released_on_pad"] else "nothing",
            "none" if row["failsafe_s"] is None else f"{row['failsafe_s']:.1f} s",
            row["lost"] or "no",
            time.perf_counter() - t0,
        )
        if progress is not None:
            progress(d.fault, k + 1, len(draws))
    summary = {f: summarize_faults(ls) for f, ls in rows.items()}
    return {"n": n, "seed": seed, "params": str(base), "faults": list(faults), "summary": summary, "landings": rows}


def contract_broken(result: dict[str, Any]) -> list[str]:
    """What the campaign's figures break of the contract: releases off the pad, failsafes missed,
    vehicles lost, faults that never fired (each a sentence; empty: none)."""
    out = []
    for f, s in result["summary"].items():
        if s["released_off_pad"]:
            out.append(f"{f}: {s['released_off_pad']} parcel(s) released off the pad")
        if s["failsafe_reached"] < s["failsafe_required"]:
            out.append(f"{f}: failsafe reached in {s['failsafe_reached']} of {s['failsafe_required']}")
        if s["lost"]:
            out.append(f"{f}: {s['lost']} vehicle(s) lost")
        if s["fired"] < s["landings"]:
            out.append(f"{f}: the fault fired in {s['fired']} of {s['landings']} landings")
    return out
