"""The embedded simulator behind the :class:`companion.autopilot.Autopilot` interface.

A physics task steps :class:`SimVehicle` at its physics rate on the running loop's clock and
publishes telemetry at the configured stream rates, like an autopilot streaming MAVLink. Under
:class:`companion_sitl.clock.VirtualTimeEventLoop` this runs in lock-step far faster than real
time; under a normal loop it runs in real time (``companion demo --realtime``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging

from companion.autopilot.interface import Autopilot, AutopilotError, TelemetryCache
from companion.autopilot.types import FlightMode, StatusText, VelocitySetpoint
from companion.config import SimConfig
from companion.scheduling import LoopClock, RateLoop
from companion_sitl.vehicle import SimCommandError, SimVehicle

log = logging.getLogger(__name__)


class SimAutopilot(Autopilot):
    def __init__(self, cfg: SimConfig, vehicle: SimVehicle | None = None):
        self.cfg = cfg
        self.vehicle = vehicle or SimVehicle(cfg)
        self.telemetry = TelemetryCache()
        self._clock = LoopClock()
        self._task: asyncio.Task[None] | None = None
        self._link_up = True
        self._texts_sent = 0
        self.setpoints_received = 0

    # ------------------------------------------------------------------ link
    async def connect(self, timeout_s: float = 10.0) -> None:
        if self._task is None:
            self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-physics")
        await asyncio.sleep(0)

    async def close(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self._task
            self._task = None

    @property
    def link_ok(self) -> bool:
        return self._link_up and self._task is not None and not self._task.done()

    def set_link(self, up: bool) -> None:
        """Test hook: cut or restore the link (telemetry and commands stop passing)."""
        self._link_up = up

    # ------------------------------------------------------------------ commands
    async def _command(self, name: str, fn, *args) -> None:  # type: ignore[no-untyped-def]
        if not self.link_ok:
            raise AutopilotError(f"{name}: link is down")
        await asyncio.sleep(self.cfg.vehicle.command_latency_s)
        self.vehicle.step_to(self._clock.now())
        try:
            fn(*args)
        except SimCommandError as err:
            raise AutopilotError(f"{name}: {err}") from None

    async def arm(self) -> None:
        await self._command("arm", self.vehicle.arm)

    async def disarm(self) -> None:
        await self._command("disarm", self.vehicle.disarm)

    async def takeoff(self, alt_rel_m: float) -> None:
        await self._command("takeoff", self.vehicle.takeoff, alt_rel_m)

    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        if not self.link_ok:
            return
        self.vehicle.step_to(self._clock.now())
        self.vehicle.set_velocity(setpoint)
        self.setpoints_received += 1

    async def start_offboard(self) -> None:
        await self._command("start_offboard", self.vehicle.start_offboard)

    async def hold(self) -> None:
        await self._command("hold", self.vehicle.hold)

    async def land(self) -> None:
        await self._command("land", self.vehicle.land)

    async def release_payload(self) -> None:
        await self._command("release_payload", self.vehicle.release_payload)

    def pilot_set_mode(self, mode: FlightMode) -> None:
        self.vehicle.pilot_set_mode(mode)

    # ------------------------------------------------------------------ physics + streams
    async def _run(self) -> None:
        c, v = self.cfg, self.vehicle
        phys = RateLoop(self._clock, c.vehicle.physics_rate_hz)
        rate = c.vehicle.physics_rate_hz

        def every(hz: float) -> int:
            return max(1, round(rate / hz))

        n_pos, n_att, n_imu = every(c.position_rate_hz), every(c.attitude_rate_hz), every(c.imu_rate_hz)
        n_gps, n_status = every(c.gps_rate_hz), every(c.status_rate_hz)
        tc = self.telemetry
        k = 0
        while True:
            t = await phys.tick()
            v.step_to(t)
            k += 1
            if not self._link_up:
                continue
            if k % n_att == 0:
                tc.push(v.attitude())
            if k % n_imu == 0:
                tc.push(v.imu())
            if k % n_pos == 0 and v.healthy:
                tc.push(v.position_ned())
                tc.push(v.global_position())
            if k % n_gps == 0:
                tc.push(v.gps_raw())
            if k % n_status == 0:
                tc.push(v.status())
                home = v.home()
                if home is not None:
                    tc.push(home)
                while self._texts_sent < len(v.status_texts):
                    ts, text = v.status_texts[self._texts_sent]
                    tc.push(StatusText(ts, 6, text))
                    self._texts_sent += 1
