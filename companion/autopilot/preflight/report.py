"""What the pre-flight check reads and says: the values read from the vehicle and the sensors
(parameters, camera, UWB, clock and stream probes), what the configuration needs from them
(:class:`Requirements`), and the verdict rows (:class:`CheckResult`, :class:`PreflightReport`)."""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from companion.timebase import ClockVerdict


class Status(enum.Enum):
    OK = "ok"
    WRONG = "wrong"
    UNKNOWN = "unknown"
    WARN = "warn"  # off, but not a flight-safety matter: said, does not fail the check


@dataclass(frozen=True)
class CheckResult:
    """One row: what was checked, the value found, the verdict and the explanation (for ``wrong``:
    what to set; for ``unknown``: why it could not be read)."""

    name: str
    status: Status
    value: str
    detail: str

    def to_json(self) -> dict[str, str]:
        return {"check": self.name, "status": self.status.value, "value": self.value, "detail": self.detail}


@dataclass(frozen=True)
class ParamUnavailable:
    """A parameter that could not be read, and why (no answer, not on this firmware, ...)."""

    reason: str


ParamValue = float | ParamUnavailable


@dataclass(frozen=True)
class CameraProbe:
    """What the configured camera plugin delivered in a short read: frame size and rate; ``error``
    when it could not be opened or gave no frame."""

    width_px: int | None = None
    height_px: int | None = None
    fps: float | None = None
    frames: int = 0
    error: str = ""


@dataclass(frozen=True)
class UwbProbe:
    """The anchor ids the UWB tag reported ranges to in a short read; ``error`` when the tag could
    not be opened or reported nothing."""

    anchors_seen: frozenset[str] = frozenset()
    readings: int = 0
    error: str = ""


@dataclass(frozen=True)
class ClockProbe:
    """The autopilot's UTC (SYSTEM_TIME.time_unix_usec) minus the companion's wall clock at
    arrival, seconds; ``error`` when no SYSTEM_TIME arrived or it carried no UTC."""

    offset_s: float | None = None
    error: str = ""


@dataclass(frozen=True)
class RealtimeProbe:
    """Whether the companion may run its threads real time (``runtime.realtime_priority``):
    ``refused`` says why not, empty when it may."""

    priority: int
    refused: str = ""


@dataclass(frozen=True)
class StreamProbe:
    """Telemetry samples the backend accepted per second over ``window_s``, by sample type
    (``PositionNed``: LOCAL_POSITION_NED / PX4's position-velocity, ``Attitude``)."""

    rates_hz: Mapping[str, float]
    window_s: float


@dataclass(frozen=True)
class Requirements:
    """What the companion's configuration needs from the vehicle (from :func:`requirements_from_config`)."""

    autopilot: Literal["px4", "ardupilot"]
    setpoint_rate_hz: float
    link_loss_resume_modes: tuple[str, ...]
    landing_controller: Literal["companion", "autopilot"] = "companion"
    landing_target_output: str = "off"
    release: str = "gripper"
    servo_channel: int = 9
    pad_size_m: float = 1.0
    camera_rate_hz: float = 30.0
    camera_size_px: tuple[int, int] | None = None  # (width, height) from the calibration, when the camera is used
    uwb_anchor_ids: frozenset[str] | None = None  # from the anchor layout, when UWB is used
    # a simulator's GPS time may lag by about a second; a real GPS's UTC is within milliseconds
    clock_tolerance_s: float = 2.0
    guidance_rate_hz: float = 20.0
    # go / no-go (docs/go-no-go.md): what the autopilot's own fence, battery failsafe and Remote ID
    # must do for the companion's [fence] and [go_no_go]
    fence_enabled: bool = False
    fence_max_alt_rel_m: float | None = None
    battery_check: bool = False
    battery_reserve_pct: float = 20.0
    remote_id_required: bool = False
    # [external_nav] enabled: the EKF source set that navigates on the companion's pose (else None)
    external_nav_source_set: int | None = None
    # [landing.moving_pad] enabled: the vehicle lands on a pad that moves (docs/moving-pad.md)
    moving_pad: bool = False


@dataclass(frozen=True)
class PreflightReport:
    """The rows, and the clock check's verdict (it decides whether signed ground requests are
    accepted: :class:`~companion.timebase.ClockVerdict`), with the offset it measured."""

    autopilot: str
    checks: tuple[CheckResult, ...] = field(default_factory=tuple)
    clock: ClockVerdict = ClockVerdict.NOT_CHECKED
    clock_offset_s: float | None = None

    @property
    def wrong(self) -> tuple[CheckResult, ...]:
        return tuple(c for c in self.checks if c.status is Status.WRONG)

    @property
    def passed(self) -> bool:
        """No check is wrong (unknown ones do not fail the check)."""
        return not self.wrong

    def to_json(self) -> dict[str, Any]:
        return {
            "autopilot": self.autopilot,
            "passed": self.passed,
            "wrong": len(self.wrong),
            "unknown": sum(c.status is Status.UNKNOWN for c in self.checks),
            "warn": sum(c.status is Status.WARN for c in self.checks),
            "checks": [c.to_json() for c in self.checks],
        }


def requirements_from_config(config: Any) -> Requirements:
    """The :class:`Requirements` of a :class:`companion.config.CompanionConfig` (``autopilot`` must
    be px4 or ardupilot). The camera size and the anchor ids are added by the caller from the
    landing kit it builds (``companion.cli.preflight.sensor_requirements``)."""
    if config.autopilot not in ("px4", "ardupilot"):
        raise ValueError(f"autopilot = {config.autopilot!r}: the pre-flight check needs 'px4' or 'ardupilot'")
    lc = config.landing
    return Requirements(
        autopilot=config.autopilot,
        setpoint_rate_hz=config.runtime.setpoint_rate_hz,
        guidance_rate_hz=config.runtime.guidance_rate_hz,
        link_loss_resume_modes=tuple(config.mission.link_loss_resume_modes),
        landing_controller=lc.controller,
        landing_target_output=lc.landing_target_output,
        release=config.payload.release,
        servo_channel=config.payload.servo_channel,
        pad_size_m=config.mission.pad.size_m,
        camera_rate_hz=lc.camera_rate_hz,
        fence_enabled=config.fence.enabled,
        fence_max_alt_rel_m=config.fence.max_alt_rel_m,
        battery_check=config.go_no_go.battery_check,
        battery_reserve_pct=config.go_no_go.battery_reserve_pct,
        remote_id_required=config.go_no_go.remote_id_required,
        external_nav_source_set=config.external_nav.source_set if config.external_nav.enabled else None,
        moving_pad=lc.moving_pad.enabled,
    )
