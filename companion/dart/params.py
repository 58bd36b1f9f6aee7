"""Dart parameters for flight: the controller gains ``[control]``, the mission ``[mission]`` and
the runtime ``[runtime]`` of a Dart parameter file (params/dart_hover.toml).

The same file also carries the simulator's ``[sim]`` table (companion_sitl.dart_sim); flight
code accepts the table and does not read it. Every key is optional; an unknown table or key, a
wrong type or an out-of-range value fails at start-up naming the file, key, value and rule.

``[runtime]`` is what the asyncio shell (companion.dart.shell) needs to fly a real autopilot:
the estimator, the task rates of dart sec. 4, the RC channel map of the hybrid mixer, the camera
and marker geometry.

RC channels with ArduPilot. ArduPilot reports RC_CHANNELS *after* applying
RC_CHANNELS_OVERRIDE (RC_Channel::update: ``radio_in = override_value``), so while the
cyber-pilot overrides the flight channels (``stick_channels``, RCMAP 1-4) the autopilot cannot
show the pilot's own sticks there. The transmitter therefore mirrors its four sticks onto
``pilot_channels`` (default 9-12, channels ArduPilot does not fly on and nobody overrides) and the
mixer reads the pilot there; releasing the overrides hands channels 1-4 back to the receiver,
i.e. to the pilot's sticks. For an autopilot that reports the raw receiver (PX4), set
``pilot_channels`` equal to ``stick_channels``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

from companion.dart.control import DartControllerConfig, PidGains
from companion.dart.estimators import ESTIMATORS, DartTaskRates
from companion.dart.mission import (
    DartMissionConfig,
    DartParamsError,
    dataclass_from_table,
    load_mission_config,
    model_from_table,
    read_toml,
)
from companion.param_kinds import DartControlTable
from companion.vision.opencv_threads import check_opencv_threads

#: tables of a Dart parameter file; [sim] belongs to the simulator
DART_TABLES = ("sim", "control", "mission", "runtime")
N_RC_CHANNELS = 18


def _check(name: str, v: float, *, low: float | None = None, positive: bool = False) -> None:
    if not math.isfinite(v):
        raise ValueError(f"{name} = {v!r}: must be finite")
    if positive and not v > 0.0:
        raise ValueError(f"{name} = {v!r}: must be > 0")
    if low is not None and v < low:
        raise ValueError(f"{name} = {v!r}: must be >= {low}")


#: ``[control]`` of a Dart parameter file, declared once (unit, limits, description of each
#: gain) in companion.param_kinds
DartControlGains = DartControlTable


def controller_config(gains: DartControlGains, rate_hz: float = 22.0) -> DartControllerConfig:
    """The four PIDs (companion.dart.control.DartController) from the file's gains: the
    horizontal ones on C_x and C_z, the vertical one on C_y, yaw proportional and wrapped."""

    def pid(kp: float, ki: float, kd: float, lim: float, ilim: float) -> PidGains:
        return PidGains(
            kp=kp,
            ki=ki,
            kd=kd,
            d_filter_tau_s=gains.d_filter_tau_s,
            out_min=-lim,
            out_max=lim,
            i_min=-ilim,
            i_max=ilim,
        )

    g = gains
    h = pid(g.horizontal_kp, g.horizontal_ki, g.horizontal_kd, g.horizontal_limit_us, g.horizontal_i_limit_us)
    v = pid(g.vertical_kp, g.vertical_ki, g.vertical_kd, g.vertical_limit_us, g.vertical_i_limit_us)
    yaw = PidGains(kp=g.yaw_kp, out_min=-g.yaw_limit_us, out_max=g.yaw_limit_us, wrap_error=True)
    return DartControllerConfig(x=h, y=v, z=h, yaw=yaw, rate_hz=rate_hz)


@dataclass(frozen=True, slots=True)
class DartRuntimeConfig:
    """The Dart runtime on a real autopilot (companion.dart.shell.DartShell). Channels are
    1-based (MAVLink chanN_raw); stick tuples are (roll, pitch, throttle, yaw)."""

    estimator: str = "SCF-MF-3DOF"
    # task rates, dart sec. 4 (vision is aperiodic: the camera's frame rate; vision_hz is its poll)
    imu_hz: float = 200.0
    vision_hz: float = 30.0
    control_hz: float = 22.0
    command_hz: float = 44.0
    log_hz: float = 20.0
    # hybrid mixer (dart sec. 2.2): the pilot's switch engages, the sticks are read on
    # pilot_channels and the autopilot flies on stick_channels
    switch_channel: int = 7
    engage_above_us: float = 1700.0
    stick_channels: tuple[int, int, int, int] = (1, 2, 3, 4)
    pilot_channels: tuple[int, int, int, int] = (9, 10, 11, 12)
    stick_reversed: tuple[bool, bool, bool, bool] = (False, False, False, False)
    max_contribution_us: tuple[float, float, float, float] = (300.0, 300.0, 250.0, 300.0)
    # full stick deflection (500 us) for attitude setpoints (PX4; match ArduPilot's ANGLE_MAX)
    max_tilt_deg: float = 35.0
    max_yaw_rate_deg_s: float = 150.0
    # watchdogs
    contribution_timeout_s: float = 0.15  # an older control output is not mixed (pilot only)
    rc_timeout_s: float = 0.3  # no RC_CHANNELS for this long: pilot unknown -> disengage, release
    release_repeat: int = 5  # release messages sent after a disengagement (then silence)
    # geometry: heading (NED, deg) of a drone facing the wall marker; the 3-DOF gimbal holds it
    marker_heading_deg: float = 0.0
    align_yaw_to_autopilot: bool = True  # Madgwick yaw := autopilot heading at each engagement
    lens_offset_m: tuple[float, float, float] = (0.08, 0.0, 0.03)  # lens from the CoT, body FRD
    # camera (a companion.cameras plugin) and the marker
    camera_plugin: str = "opencv"
    camera_source: str = "0"
    camera_latency_s: float = 0.0  # subtracted from the capture time stamp (exposure -> read)
    camera_file: str = ""  # calibration TOML ("" = the shipped Raspberry Pi camera v2)
    camera_scale: float = 1.0
    outer_size_m: float = 0.5
    inner_size_m: float = 0.09
    pad_size_m: float = 0.6
    # threads OpenCV's parallel loops may use (companion.vision.opencv_threads; -1: OpenCV's default)
    opencv_threads: int = 1
    # Linux SCHED_RR priority of the shell's threads (the loop's and those it starts; the vision
    # thread one lower), as the delivery's runtime.realtime_priority (docs/flying.md); 0: normal
    realtime_priority: int = 0

    def __post_init__(self) -> None:
        key = self.estimator.strip().upper().replace("_", "-")
        if key not in ESTIMATORS:
            raise ValueError(f"estimator = {self.estimator!r}: must be one of {', '.join(ESTIMATORS)}")
        for name in (
            "imu_hz",
            "vision_hz",
            "control_hz",
            "command_hz",
            "log_hz",
            "max_tilt_deg",
            "max_yaw_rate_deg_s",
            "contribution_timeout_s",
            "rc_timeout_s",
            "camera_scale",
            "outer_size_m",
            "inner_size_m",
            "pad_size_m",
        ):
            _check(name, getattr(self, name), positive=True)
        _check("camera_latency_s", self.camera_latency_s, low=0.0)
        for name in ("marker_heading_deg", "engage_above_us"):
            _check(name, getattr(self, name))
        for v in (*self.lens_offset_m, *self.max_contribution_us):
            _check("lens_offset_m / max_contribution_us", v)
        if any(v < 0.0 for v in self.max_contribution_us):
            raise ValueError(f"max_contribution_us = {self.max_contribution_us!r}: must be >= 0")
        check_opencv_threads(self.opencv_threads)
        if isinstance(self.realtime_priority, bool) or not 0 <= self.realtime_priority <= 98:
            raise ValueError(f"realtime_priority = {self.realtime_priority!r}: an integer 0..98 (0: normal policy)")
        if not self.max_tilt_deg < 80.0:
            raise ValueError(f"max_tilt_deg = {self.max_tilt_deg!r}: must be < 80")
        chans = (*self.stick_channels, *self.pilot_channels, self.switch_channel)
        if any(not 1 <= c <= N_RC_CHANNELS for c in chans):
            raise ValueError(f"channels must be in 1..{N_RC_CHANNELS}: {chans}")
        if len(set(self.stick_channels)) != 4 or self.switch_channel in self.stick_channels:
            raise ValueError(
                f"stick_channels = {self.stick_channels!r} and switch_channel = {self.switch_channel}: must all differ"
            )
        if len(set(self.pilot_channels)) != 4 or self.switch_channel in self.pilot_channels:
            raise ValueError(
                f"pilot_channels = {self.pilot_channels!r}: four different channels, not the switch channel"
            )
        if set(self.pilot_channels) & set(self.stick_channels) and self.pilot_channels != self.stick_channels:
            raise ValueError(
                f"pilot_channels = {self.pilot_channels!r}: either the stick_channels themselves or channels "
                f"apart from them (stick_channels = {self.stick_channels!r})"
            )
        if self.release_repeat < 1:
            raise ValueError(f"release_repeat = {self.release_repeat!r}: must be >= 1")
        if self.command_hz < self.control_hz:
            raise ValueError(f"command_hz = {self.command_hz!r}: must be >= control_hz = {self.control_hz!r}")

    @property
    def estimator_name(self) -> str:
        return self.estimator.strip().upper().replace("_", "-")

    @property
    def rates(self) -> DartTaskRates:
        return DartTaskRates(
            vision_hz=self.vision_hz, imu_hz=self.imu_hz, control_hz=self.control_hz,
            command_hz=self.command_hz, log_hz=self.log_hz,
        )  # fmt: skip

    @property
    def pilot_mirrored(self) -> bool:
        """The pilot's sticks are read on other channels than the ones the autopilot flies on."""
        return self.pilot_channels != self.stick_channels


@dataclass(frozen=True, slots=True)
class DartFlightParams:
    """What flight needs from a Dart parameter file."""

    control: DartControlGains = field(default_factory=DartControlGains)
    mission: DartMissionConfig = field(default_factory=DartMissionConfig)
    runtime: DartRuntimeConfig = field(default_factory=DartRuntimeConfig)


def check_tables(doc: dict[str, object], path: str | Path) -> None:
    """An unknown top-level table fails naming the file and the allowed tables."""
    unknown = sorted(set(doc) - set(DART_TABLES))
    if unknown:
        raise DartParamsError(
            f"{path}: [{unknown[0]}] = {doc[unknown[0]]!r}: unknown table (allowed: {', '.join(DART_TABLES)})"
        )


def load_runtime_config(path: str | Path) -> DartRuntimeConfig:
    """The ``[runtime]`` table of a Dart parameter file."""
    doc = read_toml(path)
    return dataclass_from_table(DartRuntimeConfig, doc.get("runtime", {}), path, "runtime")


def load_dart_flight_params(path: str | Path) -> DartFlightParams:
    """[control], [mission] and [runtime] of a Dart parameter file ([sim] is the simulator's)."""
    doc = read_toml(path)
    check_tables(doc, path)
    return DartFlightParams(
        control=model_from_table(DartControlGains, doc.get("control", {}), path, "control"),
        mission=load_mission_config(path),
        runtime=dataclass_from_table(DartRuntimeConfig, doc.get("runtime", {}), path, "runtime"),
    )


__all__ = [
    "DART_TABLES",
    "DartControlGains",
    "DartFlightParams",
    "DartRuntimeConfig",
    "check_tables",
    "controller_config",
    "load_dart_flight_params",
    "load_runtime_config",
]
