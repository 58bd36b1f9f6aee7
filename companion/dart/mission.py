"""The Dart mission (dart sec. 5): hover in front of the wall marker, then a straight approach
with a triangular velocity profile, then hover again close to the marker.

dart sec. 5 and 5.3: the drone is driven manually to where the camera sees the marker and
switched to the autonomous mode, which first *hovers* ("the reference trajectory is a point and
the velocity profile is constantly equal to zero"); then the navigation software generates a
rectilinear trajectory towards the marker whose speed rises linearly to ``max_speed_m_s``
(0.1 m/s in the paper) and falls linearly back to zero (triangular profile); "the mission ends
when the drone reaches a distance of 1.5 m away from the marker. At that distance, the drone
automatically returns to the autonomous hovering mode and stops moving."

Positions are in the marker frame of the Dart estimators (x right, y up, z out of the wall
towards the drone, metres), so the start point is (x, y, 4.0) and the end (x, y, 1.5).

Triangular profile over a path of length D with peak speed v: duration T = 2 D / v, acceleration
a = v^2 / D; distance travelled s(t) = a t^2 / 2 for t <= T/2 and D - a (T - t)^2 / 2 after, so
the speed is a t, peaking at v at mid-path (t = T/2, s = D/2).

Engagement (the pilot's switch, read by the RC mixer) drives the state machine: disengaged ->
MANUAL (no setpoint is used; the pilot flies); every engagement starts the mission over with the
hover at the start point. The module is pure and synchronous: time and the switch are inputs.

:func:`model_from_table` loads a TOML table into its schema (companion.param_kinds), and
:func:`dataclass_from_table` into a frozen dataclass, with errors naming the file, key, value and
rule (params/dart_hover.toml, here and in the simulator).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import tomllib
from collections.abc import Mapping
from dataclasses import dataclass
from enum import Enum
from pathlib import Path
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from companion.config import _format_errors
from companion.dart.control import DartSetpoint
from companion.param_kinds import DartMissionTable

logger = logging.getLogger(__name__)

T = TypeVar("T")
M = TypeVar("M", bound=BaseModel)


class DartParamsError(ValueError):
    """A Dart parameter file or value is invalid; the message names file, key, value, rule."""


# ------------------------------------------------------------------------------ params
def _coerce(value: Any, default: Any, where: str) -> Any:
    if isinstance(default, bool):
        if not isinstance(value, bool):
            raise DartParamsError(f"{where} = {value!r}: must be true or false")
        return value
    if isinstance(default, float):
        if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
            raise DartParamsError(f"{where} = {value!r}: must be a finite number")
        return float(value)
    if isinstance(default, int):
        if isinstance(value, bool) or not isinstance(value, int):
            raise DartParamsError(f"{where} = {value!r}: must be an integer")
        return value
    if isinstance(default, str):
        if not isinstance(value, str):
            raise DartParamsError(f"{where} = {value!r}: must be a string")
        return value
    if isinstance(default, tuple):
        if not isinstance(value, list) or len(value) != len(default):
            raise DartParamsError(f"{where} = {value!r}: must be a list of {len(default)} values")
        return tuple(_coerce(v, d, f"{where}[{i}]") for i, (v, d) in enumerate(zip(value, default, strict=True)))
    raise DartParamsError(f"{where}: unsupported parameter type {type(default).__name__}")


def dataclass_from_table(cls: type[T], table: Mapping[str, Any], source: str | Path, section: str) -> T:
    """Build the frozen dataclass ``cls`` (all fields with defaults) from a TOML table.

    Unknown keys, wrong types and values its ``__post_init__`` rejects raise
    :class:`DartParamsError` naming ``source``, ``[section] key``, the value and the rule.
    """
    if not isinstance(table, Mapping):
        raise DartParamsError(f"{source}: [{section}] = {table!r}: must be a table")
    defaults = cls()  # type: ignore[call-arg]
    names = [f.name for f in dataclasses.fields(cls)]  # type: ignore[arg-type]
    kwargs: dict[str, Any] = {}
    for key, value in table.items():
        where = f"{source}: [{section}] {key}"
        if key not in names:
            raise DartParamsError(f"{where} = {value!r}: unknown key (allowed: {', '.join(names)})")
        kwargs[key] = _coerce(value, getattr(defaults, key), where)
    try:
        return cls(**kwargs)
    except ValueError as exc:
        raise DartParamsError(f"{source}: [{section}] {exc}") from exc


def model_from_table(cls: type[M], table: Mapping[str, Any], source: str | Path, section: str) -> M:
    """A table of a Dart parameter file validated against its schema ``cls`` (companion.param_kinds);
    a bad key or value raises :class:`DartParamsError` naming ``source``, ``[section] key``, the
    value and the rule."""
    if not isinstance(table, Mapping):
        raise DartParamsError(f"{source}: [{section}] = {table!r}: must be a table")
    try:
        return cls.model_validate(dict(table))
    except ValidationError as err:
        unknown = [e for e in err.errors() if e["type"] == "extra_forbidden"]
        if unknown:  # as dataclass_from_table says it: the allowed keys with it
            e = unknown[0]
            problem = f"{e['loc'][0]} = {e['input']!r}: unknown key (allowed: {', '.join(cls.model_fields)})"
        else:
            problem = "; ".join(_format_errors(err, dict(table)))
        raise DartParamsError(f"{source}: [{section}] {problem}") from None


def read_toml(path: str | Path) -> dict[str, Any]:
    """A TOML file as a dict; unreadable or invalid files raise :class:`DartParamsError`."""
    p = Path(path)
    try:
        with p.open("rb") as fh:
            return tomllib.load(fh)
    except OSError as exc:
        raise DartParamsError(f"{p}: cannot read: {exc}") from exc
    except tomllib.TOMLDecodeError as exc:
        raise DartParamsError(f"{p}: not valid TOML: {exc}") from exc
    except UnicodeDecodeError as exc:
        raise DartParamsError(f"{p}: not UTF-8 text, as TOML must be: {exc}") from None


# ------------------------------------------------------------------------------ mission
#: ``[mission]`` of a Dart parameter file: its schema (unit, limits, description of each key) is
#: declared once, in companion.param_kinds
DartMissionConfig = DartMissionTable


def load_mission_config(path: str | Path) -> DartMissionConfig:
    """The ``[mission]`` table of a Dart parameter file (params/dart_hover.toml)."""
    doc = read_toml(path)
    return model_from_table(DartMissionConfig, doc.get("mission", {}), path, "mission")


def triangular_profile(t_s: float, length_m: float, max_speed_m_s: float) -> tuple[float, float]:
    """(distance travelled, speed) at ``t_s`` after the start of a triangular velocity profile
    over ``length_m`` peaking at ``max_speed_m_s`` (clamped to [0, length] outside the profile)."""
    if not (length_m > 0.0 and max_speed_m_s > 0.0):
        raise ValueError("need length_m > 0 and max_speed_m_s > 0")
    duration = 2.0 * length_m / max_speed_m_s
    a = max_speed_m_s * max_speed_m_s / length_m
    if t_s <= 0.0:
        return 0.0, 0.0
    if t_s >= duration:
        return length_m, 0.0
    if t_s <= 0.5 * duration:
        return 0.5 * a * t_s * t_s, a * t_s
    rem = duration - t_s
    return length_m - 0.5 * a * rem * rem, a * rem


class DartPhase(Enum):
    MANUAL = "manual"  # the pilot flies (switch off); no setpoint is used
    HOVER_START = "hover_start"  # autonomous hovering at the start point
    APPROACH = "approach"  # straight line towards the marker, triangular velocity profile
    HOVER_END = "hover_end"  # arrived: autonomous hovering at the end point


@dataclass(frozen=True, slots=True)
class DartMissionStep:
    """The mission's output at one control step: phase, setpoint (None in MANUAL), the
    along-path speed of the reference (m/s, towards the marker) and the distance covered."""

    time_s: float
    phase: DartPhase
    setpoint: DartSetpoint | None
    speed_m_s: float = 0.0
    progress_m: float = 0.0


class DartMission:
    """Hover -> approach (triangular velocity) -> hover, restarted on every engagement."""

    def __init__(self, config: DartMissionConfig | None = None) -> None:
        self.config = config or DartMissionConfig()
        self.phase = DartPhase.MANUAL
        self._t_engaged: float | None = None
        self.transitions: list[tuple[float, DartPhase]] = []

    def _enter(self, time_s: float, phase: DartPhase) -> None:
        if phase is not self.phase:
            logger.info("dart mission: %s -> %s at %.2f s", self.phase.value, phase.value, time_s)
            self.phase = phase
            self.transitions.append((time_s, phase))

    def _point(self, distance_m: float) -> DartSetpoint:
        c = self.config
        return DartSetpoint(x_m=c.x_m, y_m=c.y_m, z_m=distance_m, yaw_rad=c.yaw_rad)

    @property
    def start_setpoint(self) -> DartSetpoint:
        return self._point(self.config.start_distance_m)

    def update(self, time_s: float, engaged: bool) -> DartMissionStep:
        """The setpoint for the control step at ``time_s``; ``engaged`` is the pilot's switch."""
        if not math.isfinite(time_s):
            raise ValueError(f"time_s = {time_s!r}: must be finite")
        c = self.config
        if not engaged:
            self._t_engaged = None
            self._enter(time_s, DartPhase.MANUAL)
            return DartMissionStep(time_s, DartPhase.MANUAL, None)
        if self._t_engaged is None:
            self._t_engaged = time_s
        elapsed = time_s - self._t_engaged
        t_app = elapsed - c.hover_s
        if not c.approach or t_app < 0.0:
            self._enter(time_s, DartPhase.HOVER_START)
            return DartMissionStep(time_s, DartPhase.HOVER_START, self.start_setpoint)
        s, v = triangular_profile(t_app, c.path_length_m, c.max_speed_m_s)
        if t_app >= c.approach_duration_s:
            self._enter(time_s, DartPhase.HOVER_END)
            return DartMissionStep(time_s, DartPhase.HOVER_END, self._point(c.end_distance_m), 0.0, c.path_length_m)
        self._enter(time_s, DartPhase.APPROACH)
        return DartMissionStep(time_s, DartPhase.APPROACH, self._point(c.start_distance_m - s), v, s)


__all__ = [
    "DartMission",
    "DartMissionConfig",
    "DartMissionStep",
    "DartParamsError",
    "DartPhase",
    "dataclass_from_table",
    "load_mission_config",
    "model_from_table",
    "read_toml",
    "triangular_profile",
]
