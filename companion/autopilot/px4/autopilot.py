"""The PX4 backend: its configuration, the flight commands and the setpoints.

Setpoints. MAVSDK's Offboard plugin re-sends the last setpoint at 20 Hz on its own thread until
``offboard.stop()``: a stale setpoint would be resent forever if the control task died, which
defeats the shell's stale-setpoint watchdog and PX4's offboard-loss failsafe. So by default
(``setpoint_transport="direct"``) each setpoint is one SET_POSITION_TARGET_LOCAL_NED sent through
MavlinkDirect (synchronous and non-blocking), and OFFBOARD is entered with MAV_CMD_DO_SET_MODE
(PX4 refuses unless setpoints streamed first). ``setpoint_transport="offboard"`` uses the plugin's
synchronous ``set_velocity_ned`` and ``start()`` instead (see :mod:`.telemetry` for its guard).

Commands. Arming is refused (TEMPORARILY_REJECTED) in POSCTL without RC and in AUTO.LAND /
AUTO.TAKEOFF, and (DENIED) in OFFBOARD once our setpoints stopped, which is the mode a
companion-flown landing leaves the vehicle in; :meth:`Px4Autopilot.arm` therefore switches to
HOLD (AUTO.LOITER, where PX4 arms) first. An arm DENIED because a health or pre-flight check
fails for now ("Arming denied: Resolve system health failures first" after e.g. "Preflight Fail:
No valid data from Baro 0", or while PX4's health says not armable) is asked again every second
until ``arm_timeout_s``, as ArduPilot's backend does while its EKF settles. The parcel is
released with MAV_CMD_DO_GRIPPER or MAV_CMD_DO_SET_ACTUATOR (an output whose function is
"Peripheral via Actuator Set N"); PX4 answers MAV_CMD_DO_SET_SERVO with UNSUPPORTED. Both go out
as COMMAND_LONG through MavlinkDirect: MAVSDK's Gripper plugin can leave a native call blocked.
"""

from __future__ import annotations

import asyncio
import json
import logging
import math
import time
from collections.abc import Callable
from typing import Any, Literal

from companion.autopilot.interface import (
    AttitudeTarget,
    Autopilot,
    AutopilotError,
    CommandRejected,
    LinkLatch,
    OpenPacketSink,
    PacketSink,
    TelemetryCache,
)
from companion.autopilot.liveness import LoopLiveness
from companion.autopilot.mavlink_messages import VELOCITY_ACCEL_YAW_MASK, VELOCITY_YAW_MASK
from companion.autopilot.px4.component import Px4Component
from companion.autopilot.px4.external_nav import Px4ExternalNav
from companion.autopilot.px4.fence import Px4Fence
from companion.autopilot.px4.mavsdk_core import InterceptCounters
from companion.autopilot.px4.mission import Px4Mission
from companion.autopilot.px4.remote_id import Px4RemoteId
from companion.autopilot.px4.requests import MavResult, Px4CommandRejected, Px4Requests
from companion.autopilot.px4.telemetry import MAV_MODE_FLAG_SAFETY_ARMED
from companion.autopilot.timesync import ClockOffset, ClockOffsetEstimator
from companion.autopilot.types import (
    FlightMode,
    LandedState,
    LandingTarget,
)
from companion.geometry import euler_to_quat
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

ATTITUDE_TARGET_RATES_IGNORED = 0b0000_0011  # SET_ATTITUDE_TARGET: use q, yaw rate, thrust
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
LANDING_TARGET_TYPE_VISION_FIDUCIAL = 2
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_DO_GRIPPER = 211
GRIPPER_ACTION_RELEASE = 0
PX4_MAIN_AUTO = 4
PX4_AUTO_LOITER = 3
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
PX4_MAIN_OFFBOARD = 6
ARM_RETRY_S = 1.0  # between arms PX4 denied for a failing check
# PX4's arming-check texts (commander's health and arming checks); lower case. A decision on
# text, kept: PX4 says which check refused an arm only in the STATUSTEXT that follows the ack
# (the COMMAND_ACK's MAV_RESULT is DENIED for a failing check and for a wrong mode alike)
ARM_CHECK_TEXTS = ("resolve system health failures", "preflight fail")
# the MAV_RESULTs a failing check is refused with
ARM_CHECK_RESULTS = frozenset({MavResult.DENIED, MavResult.TEMPORARILY_REJECTED})


def is_check_refusal(err: CommandRejected, healthy: bool) -> bool:
    """A refusal a waiting pilot would see clear: PX4's health or pre-flight checks failing
    (said in its text, or ``healthy`` False: its health report at the time), not a mode or a
    switch; another backend's refusal (no PX4 MAV_RESULT) never is."""
    if not isinstance(err, Px4CommandRejected) or err.mav_result not in ARM_CHECK_RESULTS:
        return False
    return any(t in err.reason.lower() for t in ARM_CHECK_TEXTS) or not healthy


class Px4Autopilot(Px4ExternalNav, Px4Mission, Px4Fence, Px4Component, Px4RemoteId, Px4Requests, Autopilot):
    def __init__(
        self,
        connection: str = "udpin://0.0.0.0:14540",
        *,
        link_timeout_s: float = 1.0,
        setpoint_transport: Literal["direct", "offboard"] = "direct",
        setpoint_stale_s: float = 0.5,
        release: Literal["gripper", "servo", "actuator"] = "gripper",
        gripper_instance: int = 1,
        release_servo: int = 9,
        release_pwm: int = 1900,
        release_actuator: int = 1,
        release_actuator_value: float = 1.0,
        command_timeout_s: float = 5.0,
        arm_timeout_s: float = 10.0,
        destroy_timeout_s: float = 3.0,
        tlog: OpenPacketSink | None = None,
        component_id: int = 191,
        component_system_id: int = 1,
        timesync_period_s: float = 0.0,
    ):
        """``timesync_period_s`` > 0: TIMESYNC requests of our own through MavlinkDirect that often
        (MAVSDK's timesync is internal to it), the answers to :attr:`clock_offset` (docs/clock.md)."""
        if not (math.isfinite(timesync_period_s) and timesync_period_s >= 0.0):
            raise AutopilotError(f"timesync_period_s = {timesync_period_s!r}: expected finite and >= 0 (0: off)")
        self.timesync_period_s = float(timesync_period_s)
        self.connection = connection
        # MAVSDK's own identity, which is the companion's component (companion.autopilot.px4.component):
        # MAV_COMP_ID_ONBOARD_COMPUTER rather than MAVSDK's default 195 (MAV_COMP_ID_PATHPLANNER)
        self.component_id = component_id
        self.component_system_id = component_system_id
        self.component_commands = 0
        self.foreign_heartbeats = 0  # autopilot HEARTBEATs from another system or component (ignored)
        self._component_unhook: Callable[[], None] | None = None
        self.link_timeout_s = link_timeout_s
        self.setpoint_transport = setpoint_transport
        self.setpoint_stale_s = setpoint_stale_s
        self.release = release
        self.gripper_instance = gripper_instance
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.release_actuator = release_actuator
        self.release_actuator_value = release_actuator_value
        self.command_timeout_s = command_timeout_s
        self.arm_timeout_s = arm_timeout_s
        self.destroy_timeout_s = destroy_timeout_s
        self.open_tlog = tlog
        self._init_link_state()
        self._init_vehicle_state()

    def _init_link_state(self) -> None:
        """The link's own state: counters, telemetry cache, MAVSDK's plugins and the stream tasks."""
        self.streams_restarted = 0  # telemetry streams that ended or raised and were subscribed again
        self.decode_errors = 0  # stream items a handler could not take in (malformed fields, dropped)
        self.calls_unanswered = 0  # native calls abandoned at command_timeout_s (still blocked in MAVSDK)
        self.telemetry = TelemetryCache()
        self.setpoints_sent = 0
        self.setpoints_dropped = 0
        self.system_id = 1
        self.tlog: PacketSink | None = None
        self._tlog_opened = False  # a reconnect appends to the same file
        self._tlog_unhook: list[Callable[[], None]] = []
        self.intercept_counters = InterceptCounters()  # messages the MAVLink log's interceptor dropped
        self._mavsdk: Any = None
        self._system: Any = None
        self._action: Any = None
        self._tel: Any = None
        self._offboard: Any = None
        self._direct: Any = None
        self._direct_sync: Any = None
        self._param: Any = None
        self._offboard_sync: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._leaked: list[Any] = []
        self._connected = False
        self._last_rx = -math.inf
        self._last_hb = -math.inf
        self._latch = LinkLatch()
        self._last_sp_call = -math.inf
        self._plugin_streaming = False
        self._t_boot = time.monotonic()
        # TIMESYNC (docs/clock.md): fed and read on the event loop (MavlinkDirect's stream)
        self.timesync = ClockOffsetEstimator() if self.timesync_period_s > 0.0 else None
        self._timesync_logged = -1

    @property
    def clock_offset(self) -> ClockOffset | None:
        return None if self.timesync is None else self.timesync.estimate

    def _init_vehicle_state(self) -> None:
        """The vehicle's status as composed from MAVSDK's streams."""
        self._armed = False
        self._mode = FlightMode.UNKNOWN
        self._landed = LandedState.UNKNOWN
        self._healthy = False
        self._battery_pct = 100.0
        self._payload_released = False
        self._rates = (0.0, 0.0, 0.0)
        self._gps_fix = 0
        self._gps_sats = 0
        self._last_text = ""
        self._texts_seen = 0
        self._health: Any = None  # MAVSDK's last Telemetry.Health
        self.liveness = LoopLiveness()  # heartbeats and setpoints leave only while the loop ticks

    @classmethod
    def from_config(cls, config: Any, **kwargs: Any) -> Px4Autopilot:
        kwargs.setdefault("setpoint_stale_s", config.runtime.setpoint_stale_s)
        pl = config.payload
        kwargs.setdefault("release", pl.release)
        kwargs.setdefault("gripper_instance", pl.gripper_instance)
        kwargs.setdefault("release_servo", pl.servo_channel)
        kwargs.setdefault("release_pwm", pl.servo_pwm_us)
        kwargs.setdefault("release_actuator", pl.actuator_index)
        kwargs.setdefault("release_actuator_value", pl.actuator_value)
        gcs = getattr(config, "gcs", None)
        if gcs is not None and gcs.enabled:
            kwargs.setdefault("component_id", gcs.component_id)
            kwargs.setdefault("component_system_id", gcs.system_id or 1)
        if config.runtime.autopilot_sample_time != "receipt":
            raise AutopilotError(
                "runtime.autopilot_sample_time = 'autopilot' is ArduPilot's: MAVSDK's telemetry carries no "
                "autopilot time stamps to map (set it to 'receipt' on PX4)"
            )
        if config.runtime.autopilot_timesync_hz > 0.0:
            kwargs.setdefault("timesync_period_s", 1.0 / config.runtime.autopilot_timesync_hz)
        ap = cls(config.connection, link_timeout_s=config.runtime.link_timeout_s, **kwargs)
        gng = getattr(config, "go_no_go", None)
        ap.want_wind = gng is not None and gng.wind_limit_m_s > 0  # the wind check's input (WIND_COV)
        mission = getattr(config, "mission", None)
        ap.want_rangefinder = mission is not None and mission.rangefinder.enabled  # the descent's height
        ap.attitude_rate_hz = config.runtime.autopilot_attitude_rate_hz
        ap.position_rate_hz = config.runtime.autopilot_position_rate_hz
        rid = getattr(config, "remote_id", None)
        ap.remote_id = rid if rid is not None and rid.enabled else None  # docs/remote-id.md
        return ap

    async def connect(self, timeout_s: float = 10.0) -> None:
        await super().connect(timeout_s)
        self._start_remote_id()  # with [remote_id] enabled: OPERATOR_ID, SELF_ID, SYSTEM from now on

    async def arm(self) -> None:
        deadline = time.monotonic() + self.arm_timeout_s
        while True:
            try:
                await self._arm_once()
                return
            except CommandRejected as err:
                if not self._check_refusal(err) or time.monotonic() + ARM_RETRY_S > deadline:
                    raise
                log.info("PX4 denied the arm for a failing check, asking again in %.0f s: %s", ARM_RETRY_S, err)
                await asyncio.sleep(ARM_RETRY_S)

    def _check_refusal(self, err: CommandRejected) -> bool:
        """:func:`is_check_refusal` on the vehicle's health report now."""
        return is_check_refusal(err, self._healthy)

    async def _arm_once(self) -> None:
        if not self._armed and self._mode is not FlightMode.HOLD:
            # PX4 refuses to arm in the mode a landing leaves (OFFBOARD without setpoints,
            # AUTO.LAND) and in POSCTL without RC: arm in HOLD, then take off from there
            await self._direct_command(
                "arm (switch to HOLD first)",
                MAV_CMD_DO_SET_MODE,
                MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                PX4_MAIN_AUTO,
                PX4_AUTO_LOITER,
            )
            self._mode = FlightMode.HOLD
        await self._call("arm", self._action.arm)

    async def disarm(self) -> None:
        await self._call("disarm", self._action.disarm)

    async def takeoff(self, alt_rel_m: float) -> None:
        await self._call("takeoff", lambda: self._action.set_takeoff_altitude(float(alt_rel_m)))
        await self._call("takeoff", self._action.takeoff)

    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        if self._system is None or not self.link_ok or not self.liveness.may_send():
            self.setpoints_dropped += 1
            return
        sp = setpoint
        try:
            acc = sp.accel_ne_m_s2
            if self.setpoint_transport == "offboard":
                from mavsdk.plugins.offboard import AccelerationNed, PositionNedYaw, VelocityNedYaw

                vel = VelocityNedYaw(sp.north_m_s, sp.east_m_s, sp.down_m_s, math.degrees(sp.yaw_rad))
                if acc is None:
                    self._offboard_sync.set_velocity_ned(vel)
                else:
                    # NaN position: PX4's receiver leaves the position uncontrolled (offboard_control_mode
                    # from the setpoint's non-NaN parts) and adds the acceleration to its velocity loop
                    nan = math.nan
                    self._offboard_sync.set_position_velocity_acceleration_ned(
                        PositionNedYaw(nan, nan, nan, math.degrees(sp.yaw_rad)),
                        vel,
                        AccelerationNed(acc[0], acc[1], 0.0),
                    )
                self._plugin_streaming = True
            else:
                from mavsdk.plugins.mavlink_direct import MavlinkMessage

                t_ms = int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF
                mask = VELOCITY_YAW_MASK if acc is None else VELOCITY_ACCEL_YAW_MASK
                afx, afy = (0.0, 0.0) if acc is None else acc
                fields = (
                    f'{{"time_boot_ms":{t_ms},"target_system":{self.system_id},"target_component":1,'
                    f'"coordinate_frame":{MAV_FRAME_LOCAL_NED},"type_mask":{mask},'
                    f'"x":0,"y":0,"z":0,"vx":{sp.north_m_s!r},"vy":{sp.east_m_s!r},"vz":{sp.down_m_s!r},'
                    f'"afx":{afx!r},"afy":{afy!r},"afz":0,"yaw":{sp.yaw_rad!r},"yaw_rate":0}}'
                )
                self._direct_sync.send_message(
                    MavlinkMessage("SET_POSITION_TARGET_LOCAL_NED", 0, 0, self.system_id, 1, fields)
                )
        except Exception as err:
            self.setpoints_dropped += 1
            log.debug("setpoint not sent: %s", err)
            return
        self._last_sp_call = time.monotonic()
        self.setpoints_sent += 1

    def set_attitude_target(self, target: AttitudeTarget) -> None:
        """One SET_ATTITUDE_TARGET through MavlinkDirect (offboard attitude): roll, pitch and
        heading as a quaternion, the yaw rate as feed-forward, thrust 0..1; body roll and pitch
        rates ignored. Non-blocking; dropped (and counted) without a link or with a non-finite value."""
        a = target
        vals = (a.roll_rad, a.pitch_rad, a.yaw_rad, a.yaw_rate_rad_s, a.thrust)
        if self._system is None or not self.link_ok or not all(math.isfinite(v) for v in vals):
            self.setpoints_dropped += 1
            return
        if not self.liveness.may_send():
            self.setpoints_dropped += 1
            return
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        q = [float(v) for v in euler_to_quat(a.roll_rad, a.pitch_rad, a.yaw_rad)]
        fields = {
            "time_boot_ms": int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF,
            "target_system": self.system_id,
            "target_component": 1,
            "type_mask": ATTITUDE_TARGET_RATES_IGNORED,
            "q": q,
            "body_roll_rate": 0.0,
            "body_pitch_rate": 0.0,
            "body_yaw_rate": float(a.yaw_rate_rad_s),
            "thrust": min(1.0, max(0.0, float(a.thrust))),
        }
        try:
            self._direct_sync.send_message(
                MavlinkMessage("SET_ATTITUDE_TARGET", 0, 0, self.system_id, 1, json.dumps(fields))
            )
        except Exception as err:
            self.setpoints_dropped += 1
            log.debug("attitude setpoint not sent: %s", err)
            return
        self._last_sp_call = time.monotonic()
        self.setpoints_sent += 1

    async def start_offboard(self) -> None:
        if self.setpoint_transport == "offboard":
            await self._call("start_offboard", self._offboard.start)
            return
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if self._armed else 0)
        await self._direct_command("start_offboard", MAV_CMD_DO_SET_MODE, base, PX4_MAIN_OFFBOARD, 0)

    async def hold(self) -> None:
        if self.setpoint_transport == "offboard" and self._plugin_streaming:
            self._plugin_streaming = False
            await self._call("hold", self._offboard.stop)  # stops the re-send and switches to HOLD
            return
        await self._call("hold", self._action.hold)

    async def land(self) -> None:
        await self._call("land", self._action.land)

    async def precision_land(self) -> None:
        """AUTO.PRECLAND (main mode AUTO = 4, sub mode PRECLAND = 9): PX4's precision landing,
        which needs LANDING_TARGET (landing.landing_target_output = "local_ned")."""
        await self._direct_command(
            "precision_land", MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV_MODE_FLAG_SAFETY_ARMED, 4, 9
        )

    def send_landing_target(self, target: LandingTarget) -> None:
        """LANDING_TARGET through MAVSDK's MavlinkDirect. PX4 reads the position form
        (position_valid, MAV_FRAME_LOCAL_NED); time_usec is the exposure on the monotonic clock,
        which PX4 maps into its own through MAVSDK's TIMESYNC."""
        if self._system is None or not self.link_ok:
            return
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        t = target
        frame = MAV_FRAME_LOCAL_NED if t.position_valid else MAV_FRAME_BODY_FRD
        fields = json.dumps(
            {
                "time_usec": max(0, int(t.time_s * 1e6)),
                "target_num": 0,
                "frame": frame,
                "angle_x": t.angle_x_rad,
                "angle_y": t.angle_y_rad,
                "distance": t.distance_m,
                "size_x": t.size_x_rad,
                "size_y": t.size_y_rad,
                "x": t.north_m,
                "y": t.east_m,
                "z": t.down_m,
                "q": [1.0, 0.0, 0.0, 0.0],
                "type": LANDING_TARGET_TYPE_VISION_FIDUCIAL,
                "position_valid": int(t.position_valid),
            }
        )
        try:
            self._direct_sync.send_message(MavlinkMessage("LANDING_TARGET", 0, 0, self.system_id, 1, fields))
        except Exception as err:
            raise AutopilotError(f"LANDING_TARGET not sent: {err}") from err

    async def release_payload(self) -> None:
        """Release the parcel (``release``: gripper, servo or actuator; see the module doc). PX4
        gives no feedback beyond the COMMAND_ACK, so ACCEPTED counts as released."""
        if self.release == "gripper":
            await self._direct_command(
                "release (gripper)", MAV_CMD_DO_GRIPPER, self.gripper_instance, GRIPPER_ACTION_RELEASE
            )
        elif self.release == "actuator":
            # DO_SET_ACTUATOR with NaN for the other sets (left unchanged): MavlinkDirect's JSON
            # cannot carry a NaN, MAVSDK's Action.set_actuator sends exactly this command
            await self._call(
                "release (actuator)",
                lambda: self._action.set_actuator(self.release_actuator, self.release_actuator_value),
            )
        else:
            await self._direct_command("release (servo)", MAV_CMD_DO_SET_SERVO, self.release_servo, self.release_pwm)
        self._payload_released = True
        self._push_status()

    async def make_ready(self) -> str | None:
        """Disarmed in any mode but HOLD (OFFBOARD once our setpoints stopped, AUTO.LAND, POSCTL
        without RC: PX4 reports itself not armable in them, and refuses to arm): switch to HOLD
        (AUTO.LOITER), where PX4 arms and a pilot can take it from."""
        if self._system is None or self._armed or self._mode in (FlightMode.HOLD, FlightMode.UNKNOWN):
            return None
        was = self._mode.value
        await self._direct_command(
            "make ready (HOLD)", MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, PX4_MAIN_AUTO, PX4_AUTO_LOITER
        )
        self._mode = FlightMode.HOLD
        self._push_status()
        return f"disarmed in {was}: switched to HOLD so PX4 arms again"

    def not_ready_reason(self) -> str:
        h = self._health
        parts = []
        if h is not None:
            failing = [n for n in _HEALTH_FLAGS if not getattr(h, n, True)]
            bad = [n.removeprefix("is_").removesuffix("_ok").replace("_", " ") for n in failing]
            if bad:
                parts.append("PX4 health: not " + ", not ".join(bad))
        if not self._armed and self._mode not in (FlightMode.HOLD, FlightMode.UNKNOWN):
            parts.append(f"mode {self._mode.value} (PX4 arms in HOLD)")
        if self._last_text:
            parts.append(f'last PX4 message: "{self._last_text}"')
        return "; ".join(parts)


# MAVSDK Telemetry.Health flags, in the order worth reading
_HEALTH_FLAGS = (
    "is_armable",
    "is_global_position_ok",
    "is_home_position_ok",
    "is_local_position_ok",
    "is_gyrometer_calibration_ok",
    "is_accelerometer_calibration_ok",
    "is_magnetometer_calibration_ok",
)
