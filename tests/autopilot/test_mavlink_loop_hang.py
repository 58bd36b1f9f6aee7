"""A hung control loop looks dead to the autopilot (companion.autopilot.liveness): the event loop
blocks 15 s in the descent over the pad (a blocking time.sleep in the shell's public on_tick hook),
on the MAVLink sim vehicle in real time, both dialects with the vehicle parameters the pre-flight
check expects. The watchdog thread says so within the stall limit; the companion's heartbeats and
setpoints stop; the sim vehicle's own failsafe lands it (ArduCopter's GCS failsafe, FS_GCS_ENABLE =
5; PX4's offboard loss, COM_OBL_RC_ACT = 4); when the loop is back the mission finds LAND, ends
autonomy and releases nothing."""

from __future__ import annotations

import asyncio
import logging
import math
import threading
import time

import pytest

from companion.autopilot import FlightMode
from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.liveness import WATCHDOG_THREAD_NAME
from companion.autopilot.px4 import Px4Autopilot
from companion.delivery.mission import FailureKind
from companion.delivery.shell import DeliveryShell
from companion.events import Phase

pytestmark = pytest.mark.flight

HANG_S = 15.0
HANG_BELOW_M = 5.0
# what the pre-flight check expects of each vehicle (docs/companion-death.md)
FAILSAFE_PARAMS = {
    "ardupilot": {"GRIP_ENABLE": 1.0, "FS_GCS_ENABLE": 5.0},
    "px4": {"COM_OBL_RC_ACT": 4.0},
}
COMPANION_IDS = {"ardupilot": {(255, 191), (1, 191)}, "px4": {(1, 191)}}


class Watch:
    """The sim vehicle seen from a thread of the test's own (the test's loop is the one that hangs):
    its mode over time, and every heartbeat and setpoint the companion sent it."""

    def __init__(self, sim, dialect: str) -> None:
        self.sim, self.ids = sim, COMPANION_IDS[dialect]
        self.modes: list[tuple[float, FlightMode]] = []
        self.received: list[tuple[float, str]] = []
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)
        sim.on_message = self._on_message

    def _on_message(self, m) -> None:
        t = m.get_type()
        if (
            t in ("HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED")
            and (m.get_srcSystem(), m.get_srcComponent()) in self.ids
        ):
            self.received.append((time.monotonic(), t))

    def _run(self) -> None:
        while not self._stop.wait(0.02):
            mode = self.sim.vehicle.mode
            if not self.modes or self.modes[-1][1] is not mode:
                self.modes.append((time.monotonic(), mode))

    def __enter__(self) -> Watch:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join(1.0)

    def count(self, kind: str, t0: float, t1: float) -> int:
        return sum(1 for t, k in self.received if k == kind and t0 <= t <= t1)


@pytest.mark.parametrize("dialect", ["ardupilot", "px4"])
async def test_a_15_s_loop_hang_in_the_descent_lets_the_autopilot_fail_safe_and_nothing_is_released(
    mav, udp_port, dialect, caplog
):
    config = mav.short_config(return_home=False)
    url = f"udpin:127.0.0.1:{udp_port}" if dialect == "ardupilot" else f"udpin://127.0.0.1:{udp_port}"
    cfg = config.model_copy(update={"connection": url})
    ap = ArduPilotAutopilot.from_config(cfg) if dialect == "ardupilot" else Px4Autopilot.from_config(cfg)
    hang: dict[str, float] = {}

    def on_tick(shell, out) -> None:  # on the loop: the hang is the loop's own
        p = shell.autopilot.telemetry.position_ned
        if hang or p is None or out.phase.terminal:
            return
        pad = math.hypot(p.north_m - config.mission.pad.north_m, p.east_m - config.mission.pad.east_m)
        if pad < 3.0 and -p.down_m < HANG_BELOW_M and p.down_m_s > 0.2:  # over the pad, on the way down
            hang["start"], hang["height_m"] = time.monotonic(), -p.down_m
            hang["north_m"], hang["east_m"] = p.north_m, p.east_m
            time.sleep(HANG_S)
            hang["end"] = time.monotonic()

    caplog.set_level(logging.WARNING, logger="companion.autopilot.liveness")
    with mav.sim_vehicle(config, dialect, udp_port, params=FAILSAFE_PARAMS[dialect]) as sim, Watch(sim, dialect) as w:
        shell = DeliveryShell(config, ap, on_tick=on_tick)
        try:
            summary = await shell.run(timeout_s=120.0)
            # the mission may end on the first tick after the hang: the link stays open a moment,
            # so the heartbeat's return with the loop can be seen
            await asyncio.sleep(2.5)
        finally:
            await ap.close()
        await mav.wait_for(lambda: not sim.vehicle.armed, 30.0, "the failsafe landing to disarm")
        touchdowns = list(sim.vehicle.touchdowns)
        released = sim.vehicle.payload_released
    assert hang, f"never below {HANG_BELOW_M} m over the pad: {summary.failure}"
    t0, t1 = hang["start"], hang["end"]
    # the watchdog's thread said it while the loop was blocked, within the stall limit and a poll
    said = [r for r in caplog.records if r.getMessage().startswith("control loop stalled")]
    assert len(said) == 1 and said[0].threadName == WATCHDOG_THREAD_NAME
    said_s = said[0].created - (time.time() - time.monotonic())  # on the monotonic clock
    assert t0 + config.runtime.loop_stall_s <= said_s <= min(t1, t0 + config.runtime.loop_stall_s + 0.3)
    # nothing of ours reached the vehicle from the stall limit (and a heartbeat in flight) to the end
    quiet = t0 + config.runtime.loop_stall_s + 0.2
    assert w.count("HEARTBEAT", quiet, t1) == 0 and w.count("SET_POSITION_TARGET_LOCAL_NED", quiet, t1) == 0
    assert w.count("HEARTBEAT", t1, t1 + 2.0) >= 1  # back with the loop
    # the vehicle's own failsafe landed it: ArduCopter FS_GCS_TIMEOUT (5 s) after the last heartbeat,
    # PX4 COM_OF_LOSS_T after the last setpoint, both well inside the hang
    land = next((t for t, m in w.modes if m is FlightMode.LAND and t > t0), None)
    fs_s = (
        config.runtime.loop_stall_s + 5.0 + 1.5
        if dialect == "ardupilot"
        else config.sim.vehicle.offboard_loss_timeout_s
    )
    limit_s = fs_s + 0.5
    assert land is not None and land - t0 <= limit_s, w.modes
    assert touchdowns and not touchdowns[0].payload_released  # the failsafe's landing released nothing
    where = math.hypot(touchdowns[0].north_m - hang["north_m"], touchdowns[0].east_m - hang["east_m"])
    assert where < 1.0, where  # landed below where the hang began
    events = "; ".join(f"{e.phase.value} {e.kind.value} {e.detail}" for e in shell.events if e.time_s > 0)
    print(
        f"\n{dialect}: hung at {hang['height_m']:.2f} m; the watchdog said it {said_s - t0:.2f} s in; LAND "
        f"{land - t0:.2f} s in; touched down {where:.2f} m from the hang point; "
        f"mission: {summary.failure or 'delivered'}"
        f"\n  events: {events}"
    )
    # then the mission finds the vehicle in LAND, a mode it did not ask for, after a stall: armed,
    # the pilot's (or the failsafe's); landed and disarmed, the autopilot's landing, not its own
    # touchdown. Autonomy ended either way, nothing released
    assert not summary.delivered and not released, summary.failure
    assert (summary.failure_kind, shell.mission.phase) in (
        (FailureKind.PILOT_TAKEOVER, Phase.PILOT),
        (FailureKind.AUTOPILOT_LANDED, Phase.FAILED),
    ), summary.failure
    assert any("did not step for" in e.detail for e in shell.events), "the stall was not said"
    assert not any(td.payload_released for td in touchdowns)
