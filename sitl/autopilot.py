"""The embedded simulator behind the :class:`companion.autopilot.Autopilot` interface.

A physics task steps :class:`SimVehicle` at its physics rate on the running loop's clock and
publishes telemetry at the configured stream rates, like an autopilot streaming MAVLink. Under
:class:`companion_sitl.clock.VirtualTimeEventLoop` this runs in lock-step far faster than real
time; under a normal loop it runs in real time (``companion demo --realtime``).

With ``tlog_path`` it writes a MAVLink ``.tlog`` although no MAVLink crosses this link: what
the autopilot reports and what the companion sends are encoded as the MAVLink 2 a PX4 would
exchange (:class:`companion.flightlog.tlog_encoder.TelemetryEncoder`), stamped on the loop's clock;
virtual time is mapped onto :data:`SIM_TLOG_EPOCH_S`, so the file is identical for a seed. The
flight only queues the field values (:class:`companion.flightlog.telemetry_tlog.TelemetryTlog`); the
logging process encodes and writes them.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from pathlib import Path
from typing import Any

from companion.autopilot.external_nav import ExternalNavPose
from companion.autopilot.fence import AutopilotFence
from companion.autopilot.interface import Autopilot, AutopilotError, TelemetryCache
from companion.autopilot.mission_plan import PlanItem
from companion.autopilot.types import FlightMode, LandingTarget, StatusText, Wind
from companion.autopilot.winch import WinchCommand, WinchStatus
from companion.flightlog.telemetry_tlog import TelemetryTlog
from companion.guidance.setpoint import VelocitySetpoint
from companion.scheduling import LoopClock, RateLoop
from companion_sitl.clock import VirtualTimeEventLoop
from companion_sitl.gnss_loss import GnssLossError
from companion_sitl.params import SimConfig
from companion_sitl.vehicle import SimCommandError, SimVehicle

log = logging.getLogger(__name__)

SIM_TLOG_EPOCH_S = 1_735_689_600.0  # 2025-01-01T00:00:00Z: virtual time 0 in a simulated .tlog

# the COMMAND_LONG a PX4 companion would send for each command (MAV_CMD, params)
_MAV_COMMANDS: dict[str, tuple[int, tuple[float, ...]]] = {
    "arm": (400, (1.0,)),  # COMPONENT_ARM_DISARM
    "disarm": (400, (0.0,)),
    "takeoff": (22, ()),  # NAV_TAKEOFF (param7: altitude, filled in)
    "start_offboard": (176, (1.0, 6.0)),  # DO_SET_MODE custom, PX4 OFFBOARD
    "hold": (176, (1.0, 4.0, 3.0)),  # DO_SET_MODE custom, PX4 AUTO.LOITER
    "land": (21, ()),  # NAV_LAND
    "precision_land": (176, (1.0, 4.0, 9.0)),  # DO_SET_MODE custom, PX4 AUTO.PRECLAND
    "release_payload": (211, (1.0, 0.0)),  # DO_GRIPPER 1 release
    "winch": (42600, ()),  # DO_WINCH (params filled in)
}


class SimAutopilot(Autopilot):
    def __init__(self, cfg: SimConfig, vehicle: SimVehicle | None = None, tlog_path: str | Path | None = None):
        self.cfg = cfg
        self.vehicle = vehicle or SimVehicle(cfg)
        self.telemetry = TelemetryCache()
        self.tlog_path = tlog_path
        self.tlog: TelemetryTlog | None = None
        # a FlightRecorder on self.telemetry that queues the .tlog's sample records from its own
        # rows (FlightRecorder.share_samples; set before connect()): the .tlog then needs no listener
        self.sample_rows: Any = None
        self._clock = LoopClock()
        self._task: asyncio.Task[None] | None = None
        self._link_up = True
        self._texts_sent = 0
        self.setpoints_received = 0

    # ------------------------------------------------------------------ link
    async def connect(self, timeout_s: float = 10.0) -> None:
        if self._task is None:
            if self.tlog_path is not None and self.tlog is None:
                self._open_tlog(self.tlog_path)
            self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-physics")
        await asyncio.sleep(0)

    async def close(self) -> None:
        try:
            if self._task is not None:
                self._task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await self._task
                self._task = None
        finally:
            tlog, self.tlog = self.tlog, None
            if tlog is not None:
                if self.sample_rows is not None:
                    self.sample_rows.unshare_samples(tlog)
                self.telemetry.remove_listener(tlog.sample)
                tlog.close()

    def _open_tlog(self, path: str | Path) -> None:
        from companion_sitl.mavlink.px4 import px4_custom_mode

        loop = asyncio.get_running_loop()
        boot = loop.time()
        # virtual time -> a fixed epoch (same file for a seed); real time -> the wall clock
        offset = SIM_TLOG_EPOCH_S if isinstance(loop, VirtualTimeEventLoop) else time.time() - boot
        # the hooks queue the field values; the logging process encodes and writes them
        self.tlog = TelemetryTlog(path, boot_s=boot, clock=loop.time, epoch_s=offset, custom_mode=px4_custom_mode)
        rows = self.sample_rows
        if rows is None or not rows.share_samples(self.telemetry, self.tlog):
            self.telemetry.add_listener(self.tlog.sample)

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
        enc = self.tlog
        cmd, params = _MAV_COMMANDS.get(name, (0, ()))
        if enc is not None and cmd:
            if name == "winch":
                w = args[0]
                params = (float(w.instance), float(int(w.action)), w.length_m, w.rate_m_s)
            if name == "takeoff":  # PX4 takes the altitude AMSL in param7
                home = self.telemetry.home
                alt = (home.alt_amsl_m if home is not None else 0.0) + float(args[0])
                params = (0.0, 0.0, 0.0, math.nan, 0.0, 0.0, alt)
            enc.command(cmd, params)
        await asyncio.sleep(self.cfg.vehicle.command_latency_s)
        self.vehicle.step_to(self._clock.now())
        try:
            fn(*args)
        except SimCommandError as err:
            if enc is not None and cmd:
                enc.command_ack(cmd, 4)  # MAV_RESULT_FAILED
            raise AutopilotError(f"{name}: {err}") from None
        if enc is not None and cmd:
            enc.command_ack(cmd, 0)  # MAV_RESULT_ACCEPTED

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
        if self.tlog is not None:
            self.tlog.setpoint(setpoint)

    async def start_offboard(self) -> None:
        await self._command("start_offboard", self.vehicle.start_offboard)

    async def hold(self) -> None:
        await self._command("hold", self.vehicle.hold)

    async def land(self) -> None:
        await self._command("land", self.vehicle.land)

    async def release_payload(self) -> None:
        await self._command("release_payload", self.vehicle.release_payload)

    async def precision_land(self) -> None:
        await self._command("precision_land", self.vehicle.precision_land)

    async def winch(self, command: WinchCommand) -> None:
        command.validate()
        await self._command("winch", self.vehicle.winch_command, command)

    # the autopilot's fence storage: kept as sent, checked as the firmware checks the items
    fence: AutopilotFence | None = None

    async def upload_fence(self, fence: AutopilotFence) -> None:
        if not self.link_ok:
            raise AutopilotError("fence upload: link is down")
        for i, p in enumerate(fence.polygons):
            if len(p.vertices_e7) < 3:
                raise AutopilotError(f"fence upload refused: polygon {i} has {len(p.vertices_e7)} vertices")
        self.fence = fence

    async def download_fence(self) -> AutopilotFence:
        if not self.link_ok:
            raise AutopilotError("fence download: link is down")
        return self.fence if self.fence is not None else AutopilotFence(())

    # the autopilot's mission storage (what a GCS uploaded), numbered as a GCS shows it
    mission_items: tuple[PlanItem, ...] = ()

    async def download_mission(self) -> tuple[PlanItem, ...]:
        if not self.link_ok:
            raise AutopilotError("mission download: link is down")
        return self.mission_items

    def send_landing_target(self, target: LandingTarget) -> None:
        """The in-process vehicle reads the local-NED form (as PX4 does); angles are not used."""
        if not self.link_ok:
            return
        self.vehicle.step_to(self._clock.now())
        if target.position_valid:
            self.vehicle.set_landing_target(target.north_m, target.east_m)

    def send_external_nav(self, pose: ExternalNavPose) -> None:
        """The pose as the vehicle's external navigation (sitl/gnss_loss.py; the ArduCopter and PX4 SIH
        profiles)."""
        pose.validate()
        if not self._link_up:
            return
        try:
            self.vehicle.gnss.on_pose(self.vehicle.time_s, pose.north_m, pose.east_m, pose.down_m)
        except GnssLossError as err:
            raise AutopilotError(str(err)) from None

    def external_nav_source_name(self, source_set: int) -> str:
        m = self.vehicle.gnss.model
        if m is not None and not m.needs_source_set:  # PX4: the backend's own words
            return "EKF2 external vision (EKF2_EV_CTRL), fused beside GNSS until it went"
        return super().external_nav_source_name(source_set)

    async def use_external_nav(self, source_set: int) -> None:
        try:
            await self._command("EKF source set", self.vehicle.gnss.use_source_set, source_set)
        except GnssLossError as err:
            raise AutopilotError(str(err)) from None

    async def use_gnss(self) -> None:
        try:
            await self._command("EKF source set", self.vehicle.gnss.use_source_set, 1)
        except GnssLossError as err:
            raise AutopilotError(str(err)) from None

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
                tc.push_wind(Wind(t, *v.wind_ned()))  # the autopilot's wind estimate (no listener sees it)
                if v.winch is not None:  # WINCH_STATUS (ArduCopter streams it with EXTRA3)
                    w = v.winch
                    tension = v.payload.line_tension_kg()
                    tc.push_winch(WinchStatus(t, w.length_m, w.speed_m_s, w.flags(), tension))
                home = v.home()
                if home is not None:
                    tc.push(home)
                while self._texts_sent < len(v.status_texts):
                    ts, text = v.status_texts[self._texts_sent]
                    tc.push(StatusText(ts, 6, text))
                    self._texts_sent += 1
