"""The ArduPilot (ArduCopter) backend: its configuration and the flight commands.

Companion control is GUIDED (mapped to :attr:`FlightMode.OFFBOARD`), GUIDED velocity times out
after 3 s on the vehicle (it stops and holds), arming is refused until the EKF uses GPS (arm()
retries until ``arm_timeout_s``), takeoff is MAV_CMD_NAV_TAKEOFF in GUIDED, hold is BRAKE (or
LOITER), land is LAND mode, and the parcel is released with MAV_CMD_DO_GRIPPER or
MAV_CMD_DO_SET_SERVO. Velocity setpoints are a single non-blocking SET_POSITION_TARGET_LOCAL_NED
send. The link, the requests and the telemetry decoding are its base classes
(:mod:`.link`, :mod:`.requests`, :mod:`.telemetry`).
"""

from __future__ import annotations

import asyncio
import collections
import logging
import math
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

from companion.autopilot.ardupilot.component import ArduPilotComponent
from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.external_nav import ArduPilotExternalNav
from companion.autopilot.ardupilot.fence import ArduPilotFence
from companion.autopilot.ardupilot.link import LinkCounters, LoopPoster
from companion.autopilot.ardupilot.mission import ArduPilotMission
from companion.autopilot.ardupilot.modes import COPTER_MODES
from companion.autopilot.ardupilot.remote_id import ArduPilotRemoteId
from companion.autopilot.ardupilot.requests import (
    DEFAULT_STREAM_RATES_HZ,
    STREAM_CHECK_PERIOD_S,
    configured_stream_rates,
)
from companion.autopilot.ardupilot.telemetry import ArduPilotTelemetry
from companion.autopilot.interface import (
    Autopilot,
    AutopilotError,
    CommandRejected,
    CommandResult,
    LinkLatch,
    OpenPacketSink,
    PacketSink,
    TelemetryCache,
)
from companion.autopilot.liveness import LoopLiveness
from companion.autopilot.mavlink_messages import velocity_setpoint_message
from companion.autopilot.signing import (
    SigningSetup,
    read_key_file,
    read_timestamp_file,
)
from companion.autopilot.timesync import ClockOffset, ClockOffsetEstimator
from companion.autopilot.types import (
    LandedState,
    LandingTarget,
)
from companion.autopilot.winch import MAV_CMD_DO_WINCH, WinchCommand
from companion.config import RemoteIdConfig
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

WIND_MSG_ID = 168  # WIND (ardupilotmega): EKF3's wind estimate
WINCH_STATUS_MSG_ID = 9005  # WINCH_STATUS: the winch's line length (AP_Winch)
DISTANCE_SENSOR_MSG_ID = 132  # DISTANCE_SENSOR: a rangefinder (RNGFND1_TYPE != 0)

# arming refusals that clear by themselves (pre-arm checks while the EKF converges)
ARM_RETRY_RESULTS = frozenset(
    {CommandResult.FAILED, CommandResult.TEMPORARILY_REJECTED, CommandResult.DENIED, CommandResult.LOST}
)


class ArduPilotAutopilot(
    ArduPilotMission,
    ArduPilotFence,
    ArduPilotComponent,
    ArduPilotRemoteId,
    ArduPilotExternalNav,
    ArduPilotTelemetry,
    Autopilot,
):
    def __init__(
        self,
        connection: str = "udpin:0.0.0.0:14550",
        *,
        baud: int = 57600,
        link_timeout_s: float = 1.0,
        source_system: int = 255,
        source_component: int = 191,  # MAV_COMP_ID_ONBOARD_COMPUTER
        target_system: int | None = None,
        release: Literal["gripper", "servo"] = "gripper",
        release_servo: int = 9,
        release_pwm: int = 1900,
        hold_mode: Literal["BRAKE", "LOITER"] = "BRAKE",
        arm_timeout_s: float = 8.0,
        release_confirm_timeout_s: float = 2.0,
        command_timeout_s: float = 0.5,
        command_retries: int = 3,
        stream_rates_hz: dict[int, float] | None = None,
        tlog: OpenPacketSink | None = None,
        signing: SigningSetup | None = None,
        remote_id: RemoteIdConfig | None = None,
        timesync_period_s: float = 0.0,
        sample_time: Literal["receipt", "autopilot"] = "receipt",
    ):
        """``timesync_period_s`` > 0: a TIMESYNC request that often, the answers to
        :attr:`clock_offset` (:mod:`companion.autopilot.timesync`; 0: none sent).
        ``sample_time = "autopilot"``: attitude and position samples are stamped at their
        ``time_boot_ms`` mapped onto our clock through that offset, not at their receipt (needs
        TIMESYNC; docs/clock.md)."""
        if not (math.isfinite(timesync_period_s) and timesync_period_s >= 0.0):
            raise AutopilotError(f"timesync_period_s = {timesync_period_s!r}: expected finite and >= 0 (0: off)")
        if sample_time not in ("receipt", "autopilot"):
            raise AutopilotError(f"sample_time = {sample_time!r}: expected 'receipt' or 'autopilot'")
        if sample_time == "autopilot" and timesync_period_s <= 0.0:
            raise AutopilotError(
                "sample_time = 'autopilot' maps the samples' time_boot_ms through the TIMESYNC offset: "
                "set runtime.autopilot_timesync_hz > 0 (e.g. 2)"
            )
        self.timesync_period_s = float(timesync_period_s)
        self.sample_time = sample_time
        self.connection = connection
        self.remote_id = remote_id  # [remote_id]: sent and gated on when enabled (.remote_id)
        self.signing = signing
        self.baud = baud
        self.link_timeout_s = link_timeout_s
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.target_component = 1
        self.release = release
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.hold_mode = hold_mode
        self.arm_timeout_s = arm_timeout_s
        self.release_confirm_timeout_s = release_confirm_timeout_s
        self.command_timeout_s = command_timeout_s
        self.command_retries = command_retries
        self.stream_rates_hz = dict(DEFAULT_STREAM_RATES_HZ if stream_rates_hz is None else stream_rates_hz)
        self.open_tlog = tlog
        self._init_link_state()
        self._init_vehicle_state()

    def _init_link_state(self) -> None:
        """The link's own state: telemetry cache, counters, the reader thread and what waits on it."""
        self.telemetry = TelemetryCache()
        self.counters = LinkCounters()
        self.rc_channels: tuple[int, ...] = ()
        self.tlog: PacketSink | None = None
        self._tlog_opened = False  # a reconnect appends to the same file
        self._conn: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._poster = LoopPoster()  # calls from the reader thread waiting for the loop (_post)
        self._reader: threading.Thread | None = None
        self._running = False
        self._send_lock = threading.Lock()
        self._acks: dict[int, asyncio.Future[int]] = {}
        self._first_hb: asyncio.Future[None] | None = None
        self._last_hb = -math.inf
        self._last_rx = -math.inf
        self._latch = LinkLatch()
        self._last_attitude = -math.inf
        self._last_stream_request = -math.inf
        self._highres_accepted = False
        self.stream_check_period_s = STREAM_CHECK_PERIOD_S
        self._streams_refused: set[int] = set()
        self._stream_rerequests: dict[int, int] = {}
        self._stream_window: tuple[float, dict[int, int]] | None = None
        self._t_boot = time.monotonic()
        # TIMESYNC (docs/clock.md): the estimator is fed and read on the reader thread, read from the
        # loop through clock_offset; the lock keeps the two apart
        self.timesync = ClockOffsetEstimator() if self.timesync_period_s > 0.0 else None
        self._timesync_lock = threading.Lock()
        self._next_timesync_s = 0.0
        self._timesync_logged = -1  # accepted exchanges when the estimate was last logged
        self._sample_offset: ClockOffset | None = None  # the reader thread's copy, for the samples
        self._sample_ages_s: collections.deque[float] = collections.deque(maxlen=500)  # receipt - sample time
        self.sample_times_refused = 0  # samples whose mapped time_boot_ms was implausible (stamped at receipt)

    @property
    def clock_offset(self) -> ClockOffset | None:
        if self.timesync is None:
            return None
        with self._timesync_lock:
            return self.timesync.estimate

    def _init_vehicle_state(self) -> None:
        """The vehicle's state as received (the reader thread writes, the event loop reads)."""
        self.copter_mode = -1
        self._armed = False
        self._landed = LandedState.UNKNOWN
        self._battery_pct = math.nan
        self._prearm_ok: bool | None = None
        self._gps_fix = 0
        self._payload_released = False
        self._have_highres = False
        self._last_text = ""
        self._texts_seen = 0
        self.params: dict[str, float] = {}  # every PARAM_VALUE seen
        self._param_waiters: dict[str, asyncio.Future[float]] = {}
        self.servo_outputs: tuple[int, ...] = ()  # SERVO_OUTPUT_RAW port 0, index 0 = output 1, us
        self._servo_outputs_time = -math.inf
        self._gripper_output: tuple[int, int] | bool | None = False  # False: not looked up yet
        # last SYSTEM_TIME: (time_unix_usec, our wall clock at arrival)
        self._system_time: tuple[int, float] | None = None
        self._system_time_waiters: list[asyncio.Future[tuple[int, float]]] = []
        self.releases_unconfirmed = 0
        self._vehicle_signs = False  # the vehicle's heartbeats carry a signature block
        self._component: Any = None  # (system id, component id, on_command) once open_component
        self.component_commands = 0  # COMMAND_LONGs addressed to the companion's component
        self.foreign_heartbeats = 0  # autopilot HEARTBEATs from another system or component (ignored)
        self.liveness = LoopLiveness()  # heartbeats and setpoints leave only while the loop ticks

    @classmethod
    def from_config(cls, config: Any, **kwargs: Any) -> ArduPilotAutopilot:
        """Build from a :class:`companion.config.CompanionConfig` (``connection``, link timeout,
        ``[payload]``: gripper or servo; ArduPilot has no actuator-set command)."""
        pl = config.payload
        if pl.release == "actuator":
            raise AutopilotError(
                "payload.release = 'actuator' is PX4's DO_SET_ACTUATOR: on ArduPilot use 'gripper' "
                "(GRIP_ENABLE = 1, SERVOn_FUNCTION = 28) or 'servo' (payload.servo_channel)"
            )
        kwargs.setdefault("release", pl.release)
        kwargs.setdefault("release_servo", pl.servo_channel)
        kwargs.setdefault("release_pwm", pl.servo_pwm_us)
        rt = config.runtime
        if "stream_rates_hz" not in kwargs:
            kwargs["stream_rates_hz"] = configured_stream_rates(
                rt.autopilot_attitude_rate_hz, rt.autopilot_position_rate_hz
            )
            gng = getattr(config, "go_no_go", None)
            if gng is not None and gng.wind_limit_m_s > 0:
                kwargs["stream_rates_hz"][WIND_MSG_ID] = 2.0  # the wind check's input
        winch = getattr(config, "winch", None)
        if getattr(getattr(config, "mission", None), "delivery", "land") == "winch" and winch is not None:
            # the winch's line length, and the wind for the hover's correction (docs/winch.md)
            rates = dict(kwargs["stream_rates_hz"])
            rates[WINCH_STATUS_MSG_ID] = 5.0
            if winch.wind_drift_s_m > 0:
                rates[WIND_MSG_ID] = 2.0
            kwargs["stream_rates_hz"] = rates
        mission = getattr(config, "mission", None)
        if mission is not None and mission.rangefinder.enabled:
            # the final descent's height (docs/rangefinder.md): ArduCopter streams it only when asked
            kwargs["stream_rates_hz"] = {**kwargs["stream_rates_hz"], DISTANCE_SENSOR_MSG_ID: 10.0}
        rid = getattr(config, "remote_id", None)
        if rid is not None and rid.enabled:
            kwargs.setdefault("remote_id", rid)  # docs/remote-id.md
        sc = getattr(config, "signing", None)
        if sc is not None and sc.enabled and "signing" not in kwargs:
            key = read_key_file(sc.key_file, sc.key_format)
            ts_file = Path(sc.timestamp_file) if sc.timestamp_file else None
            if ts_file is not None:
                read_timestamp_file(ts_file)  # a bad file stops us here, before any link is opened
            kwargs["signing"] = SigningSetup(key, sc.link_id, sc.allow_unsigned, ts_file)
            log.info(
                "MAVLink signing on: key %s (%s), link id %d, %s",
                key.fingerprint,
                sc.key_file,
                sc.link_id,
                "unsigned accepted" if sc.allow_unsigned else "unsigned refused",
            )
        if rt.autopilot_timesync_hz > 0.0:
            kwargs.setdefault("timesync_period_s", 1.0 / rt.autopilot_timesync_hz)
        kwargs.setdefault("sample_time", rt.autopilot_sample_time)
        return cls(config.connection, link_timeout_s=config.runtime.link_timeout_s, **kwargs)

    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        if not self.link_ok or self.target_system is None or not self.liveness.may_send():
            self.counters.setpoints_dropped += 1
            return
        ts, tc = self.target_system, self.target_component
        t_ms = int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF
        msg = velocity_setpoint_message(t_ms, ts, tc, setpoint)
        ok = self._send(lambda mav: mav.send(msg))
        if ok:
            self.counters.setpoints_sent += 1
        else:
            self.counters.setpoints_dropped += 1

    def send_rc_override(self, channels: Sequence[int]) -> None:
        """RC_CHANNELS_OVERRIDE for channels 1..18 (channels 1-8: 0 = release to the radio,
        65535 = ignore; 9-18: 0 or 65535 = ignore, 65534 = release); missing channels are ignored."""
        vals = list(channels)[:18]
        ch = [*vals[:8], *[65535] * (8 - min(8, len(vals)))]
        ext = [*vals[8:], *[0] * (18 - max(8, len(vals)))]  # MAVLink 2 extensions, chan9..18
        ts, tc = self.target_system or 1, self.target_component
        self._send(lambda mav: mav.rc_channels_override_send(ts, tc, *ch, *ext))

    async def connect(self, timeout_s: float = 10.0) -> None:
        await super().connect(timeout_s)
        self._start_remote_id()  # with [remote_id] enabled: its messages, from now on

    async def close(self) -> None:
        await self._stop_remote_id()
        await super().close()

    # ------------------------------------------------------------------ commands
    async def set_mode(self, name: str) -> None:
        num = COPTER_MODES[name]
        await self._command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, num, what=name)
        self.copter_mode = num  # ACCEPTED means switched; the next heartbeat confirms
        self._push_status()

    async def arm(self) -> None:
        """GUIDED, then arm. Until EKF3 uses GPS ArduCopter answers FAILED to both: GUIDED
        with "Mode change to GUIDED failed: requires position", arming with "Arm: Need Position
        Estimate". Both are retried every second until ``arm_timeout_s``, then the last refusal
        is raised. Arming in LAND (the mode a LAND leaves it in) is refused for good ("Arm: LAND
        mode not armable"): GUIDED comes first. With ``[remote_id] enabled`` the transponder's
        ARM_STATUS must be fresh and good first (:meth:`remote_id_gate`), waited for as long, then
        refused (DENIED, with the gate's reason)."""
        deadline = time.monotonic() + self.arm_timeout_s
        while True:
            gate = self.remote_id_gate()
            if not gate.may_arm:
                if time.monotonic() + 1.0 > deadline:
                    raise CommandRejected("arm", CommandResult.DENIED, gate.reason)
                log.info("arming waits for Remote ID (%s): %s", gate.verdict.value, gate.reason)
                await asyncio.sleep(1.0)
                continue
            try:
                if self.copter_mode != COPTER_MODES["GUIDED"]:
                    await self.set_mode("GUIDED")
                await self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, what="arm")
                break
            except CommandRejected as err:
                if err.kind not in ARM_RETRY_RESULTS or time.monotonic() + 1.0 > deadline:
                    raise
                log.info("GUIDED/arming refused (EKF/GPS not ready?), retrying: %s", err)
                await asyncio.sleep(1.0)
        self._armed = True
        self._push_status()

    async def disarm(self) -> None:
        await self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, what="disarm")
        self._armed = False
        self._push_status()

    async def takeoff(self, alt_rel_m: float) -> None:
        if self.copter_mode != COPTER_MODES["GUIDED"]:
            await self.set_mode("GUIDED")
        await self._command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_rel_m, what="takeoff")

    async def start_offboard(self) -> None:
        await self.set_mode("GUIDED")

    async def hold(self) -> None:
        await self.set_mode(self.hold_mode)

    async def land(self) -> None:
        await self.set_mode("LAND")

    async def precision_land(self) -> None:
        """LAND: with PLND_ENABLED = 1 and PLND_TYPE = 1 (companion computer) ArduPilot's LAND
        steers onto the LANDING_TARGET it receives (landing.landing_target_output = "body_angles")."""
        await self.set_mode("LAND")

    def send_landing_target(self, target: LandingTarget) -> None:
        """LANDING_TARGET (MAVLink 2 fields included). AC_PrecLand_Companion reads angle_x /
        angle_y / distance (MAV_FRAME_BODY_FRD); the position form is sent as MAV_FRAME_LOCAL_NED."""
        t = target
        frame = mavlink.MAV_FRAME_LOCAL_NED if t.position_valid else mavlink.MAV_FRAME_BODY_FRD
        usec = max(0, int(t.time_s * 1e6))
        self._send(
            lambda mav: mav.landing_target_send(
                usec,
                0,
                frame,
                t.angle_x_rad,
                t.angle_y_rad,
                t.distance_m,
                t.size_x_rad,
                t.size_y_rad,
                t.north_m,
                t.east_m,
                t.down_m,
                [1.0, 0.0, 0.0, 0.0],
                mavlink.LANDING_TARGET_TYPE_VISION_FIDUCIAL,
                int(t.position_valid),
            )
        )

    async def winch(self, command: WinchCommand) -> None:
        """MAV_CMD_DO_WINCH (companion.autopilot.winch). ArduCopter answers FAILED without an enabled
        winch (WINCH_TYPE = 0, or no output at SERVOn_FUNCTION = 88). WINCH_STATUS, the line
        length the mission watches, is asked for at 5 Hz before the first command."""
        command.validate()
        if not self._winch_status_requested:
            self._winch_status_requested = True
            try:
                await self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, WINCH_STATUS_MSG_ID, 2e5, retries=2)
            except CommandRejected as err:
                log.warning("WINCH_STATUS not available: %s", err)
        await self._command(
            MAV_CMD_DO_WINCH,
            command.instance,
            int(command.action),
            command.length_m,
            command.rate_m_s,
            what=f"winch ({command.action.name.lower()}, {command.length_m:+.2f} m)",
        )

    _winch_status_requested = False

    async def release_payload(self) -> None:
        """DO_GRIPPER release (or DO_SET_SERVO), then confirmed on the output itself.

        ArduCopter ACCEPTs DO_GRIPPER once GRIP_ENABLE = 1 and moves the servo at once (GRIP_TYPE
        = 1: the SERVOn_FUNCTION = 28 output goes to GRIP_RELEASE); with GRIP_ENABLE = 0 it
        answers FAILED, for good. The release counts as done only when SERVO_OUTPUT_RAW shows
        the gripper's output (found from the GRIP_* and SERVOn_FUNCTION parameters) or the
        release servo at the release PWM; CommandRejected FAILED after
        ``release_confirm_timeout_s`` otherwise. An autopilot that sends no SERVO_OUTPUT_RAW or
        no parameters cannot confirm: its ACK is taken (counted in ``releases_unconfirmed``).
        """
        outputs_streamed = True  # the confirmation reads SERVO_OUTPUT_RAW at 10 Hz
        try:
            await self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 36, 1e5, retries=2)
        except CommandRejected as err:
            outputs_streamed = self._servo_outputs_time > -math.inf
            log.info("SERVO_OUTPUT_RAW not available: %s", err)
        if self.release == "gripper":
            what = "release (gripper)"
            target = await self._find_gripper_output() if outputs_streamed else None
            t_cmd = time.monotonic()
            await self._command(mavlink.MAV_CMD_DO_GRIPPER, 1, mavlink.GRIPPER_ACTION_RELEASE, what=what)
        else:
            what = "release (servo)"
            target = (self.release_servo, self.release_pwm) if outputs_streamed else None
            t_cmd = time.monotonic()
            await self._command(mavlink.MAV_CMD_DO_SET_SERVO, self.release_servo, self.release_pwm, what=what)
        if target is None:
            self.releases_unconfirmed += 1
            log.warning("%s accepted; its output cannot be watched, release not confirmed", what)
        else:
            await self._confirm_output(what, *target, t_cmd)
        self._payload_released = True
        self._push_status()

    async def _confirm_output(self, what: str, channel: int, pwm: int, since: float) -> None:
        end = time.monotonic() + self.release_confirm_timeout_s
        while time.monotonic() < end:
            out = self.servo_outputs
            if self._servo_outputs_time > since and len(out) >= channel and abs(out[channel - 1] - pwm) <= 20:
                log.info("%s confirmed: output %d at %d us", what, channel, out[channel - 1])
                return
            await asyncio.sleep(0.02)
        if self._servo_outputs_time == -math.inf:
            self.releases_unconfirmed += 1
            log.warning("%s accepted; no SERVO_OUTPUT_RAW from the autopilot, release not confirmed", what)
            return
        seen = self.servo_outputs[channel - 1] if len(self.servo_outputs) >= channel else None
        raise CommandRejected(
            what,
            CommandResult.FAILED,
            f"output {channel} at {seen} us, not {pwm} us, {self.release_confirm_timeout_s:.1f} s after",
        )

    async def _find_gripper_output(self) -> tuple[int, int] | None:
        """(output, release PWM) of a servo gripper (GRIP_TYPE = 1, SERVOn_FUNCTION = 28,
        GRIP_RELEASE), looked up once; None when the parameters do not say (or do not answer)."""
        if self._gripper_output is not False:
            return self._gripper_output  # type: ignore[return-value]
        found: tuple[int, int] | None = None
        grip_type = await self.read_param("GRIP_TYPE")
        release = await self.read_param("GRIP_RELEASE") if grip_type == 1 else None
        if release is not None:
            order = [self.release_servo, *(n for n in range(1, 17) if n != self.release_servo)]
            for n in order:
                fn = await self.read_param(f"SERVO{n}_FUNCTION")
                if fn is None:
                    break
                if int(fn) == 28:  # SRV_Channel::k_gripper
                    found = (n, round(release))
                    break
        log.info("gripper output: %s", found)
        self._gripper_output = found
        return found

    def not_ready_reason(self) -> str:
        """ArduPilot's pre-arm flag (SYS_STATUS) and GPS fix, with its last STATUSTEXT (it repeats
        its "PreArm: ..." reasons every 30 s while they hold)."""
        parts = []
        if self._prearm_ok is False:
            parts.append("ArduPilot pre-arm checks failing")
        if self._gps_fix < 3:
            parts.append(f"GPS fix type {self._gps_fix} (3D needed)")
        if self._last_text:
            parts.append(f'last ArduPilot message: "{self._last_text}"')
        return "; ".join(parts)
