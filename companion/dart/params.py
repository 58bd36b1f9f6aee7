"""Dart parameters for flight: the controller gains ``[control]``, the mission ``[mission]``, the
runtime ``[runtime]`` and the estimators' filters ``[estimator]`` (with ``[estimator.madgwick]``
and ``[estimator.complementary]``) of a Dart parameter file (params/dart_hover.toml). Every key
is declared once, with its unit, limits and description, in companion.param_kinds; the
components take the tables as they are: ``[runtime]`` is the RC mixer's config and the attitude
map, ``[estimator]`` the estimators' settings (plus the geometry from ``[runtime]``).

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

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import field_validator

from companion.dart.control import DartControllerConfig, PidGains
from companion.dart.estimators import ESTIMATORS, DartTaskRates
from companion.dart.mission import (
    DartMissionConfig,
    DartParamsError,
    load_mission_config,
    model_from_table,
    read_toml,
)
from companion.param_kinds import DART_RC_CHANNELS, DartControlTable, DartEstimatorTable, DartRuntimeTable
from companion.vision.opencv_threads import check_opencv_threads

#: tables of a Dart parameter file; [sim] belongs to the simulator
DART_TABLES = ("sim", "control", "mission", "runtime", "estimator")
N_RC_CHANNELS = DART_RC_CHANNELS


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
            max_dt_s=gains.max_dt_s,
        )

    g = gains
    h = pid(g.horizontal_kp, g.horizontal_ki, g.horizontal_kd, g.horizontal_limit_us, g.horizontal_i_limit_us)
    v = pid(g.vertical_kp, g.vertical_ki, g.vertical_kd, g.vertical_limit_us, g.vertical_i_limit_us)
    yaw = PidGains(kp=g.yaw_kp, out_min=-g.yaw_limit_us, out_max=g.yaw_limit_us, wrap_error=True, max_dt_s=g.max_dt_s)
    return DartControllerConfig(x=h, y=v, z=h, yaw=yaw, rate_hz=rate_hz, max_estimate_age_s=g.max_estimate_age_s)


class DartRuntimeConfig(DartRuntimeTable):
    """The Dart runtime on a real autopilot (companion.dart.shell.DartShell): ``[runtime]``, its
    keys declared once in :class:`companion.param_kinds.DartRuntimeTable` (channels 1-based, stick
    tuples (roll, pitch, throttle, yaw)). Here only what needs the Dart's own modules: the
    estimator's name among the estimators, OpenCV's thread setting, the task rates."""

    @field_validator("estimator")
    @classmethod
    def _known_estimator(cls, v: str) -> str:
        if v.strip().upper().replace("_", "-") not in ESTIMATORS:
            raise ValueError(f"must be one of {', '.join(ESTIMATORS)}")
        return v

    @field_validator("opencv_threads", mode="before")
    @classmethod
    def _opencv_threads(cls, v: object) -> object:
        return check_opencv_threads(v) if isinstance(v, int) else v  # the schema names a wrong type

    @property
    def rates(self) -> DartTaskRates:
        return DartTaskRates(
            vision_hz=self.vision_hz, imu_hz=self.imu_hz, control_hz=self.control_hz,
            command_hz=self.command_hz, log_hz=self.log_hz,
        )  # fmt: skip

    def replaced(self, **changes: Any) -> DartRuntimeConfig:
        """A copy with ``changes``, checked as a file's values are."""
        return type(self).model_validate({**self.model_dump(), **changes})


@dataclass(frozen=True, slots=True)
class DartFlightParams:
    """What flight needs from a Dart parameter file."""

    control: DartControlGains = field(default_factory=DartControlGains)
    mission: DartMissionConfig = field(default_factory=DartMissionConfig)
    runtime: DartRuntimeConfig = field(default_factory=DartRuntimeConfig)
    estimator: DartEstimatorTable = field(default_factory=DartEstimatorTable)


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
    return model_from_table(DartRuntimeConfig, doc.get("runtime", {}), path, "runtime")


def load_dart_flight_params(path: str | Path) -> DartFlightParams:
    """[control], [mission], [runtime] and [estimator] of a Dart parameter file ([sim] is the
    simulator's)."""
    doc = read_toml(path)
    check_tables(doc, path)
    return DartFlightParams(
        control=model_from_table(DartControlGains, doc.get("control", {}), path, "control"),
        mission=load_mission_config(path),
        runtime=model_from_table(DartRuntimeConfig, doc.get("runtime", {}), path, "runtime"),
        estimator=model_from_table(DartEstimatorTable, doc.get("estimator", {}), path, "estimator"),
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
