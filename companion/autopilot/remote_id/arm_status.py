"""The Remote ID transponder's OPEN_DRONE_ID_ARM_STATUS, typed, and the arming gate on it
(docs/remote-id.md): with ``remote_id.enabled`` a delivery is armed only while the latest
ARM_STATUS is fresh (``remote_id.arm_status_max_age_s``) and says GOOD_TO_ARM."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum, IntEnum


class ArmStatus(IntEnum):
    """MAV_ODID_ARM_STATUS, plus UNKNOWN for a value the spec does not define (not good)."""

    GOOD_TO_ARM = 0
    PRE_ARM_FAIL_GENERIC = 1
    UNKNOWN = 255

    @classmethod
    def from_wire(cls, value: int) -> ArmStatus:
        try:
            status = cls(int(value))
        except ValueError:
            return cls.UNKNOWN
        return status


@dataclass(frozen=True, slots=True)
class ArmStatusReport:
    """One ARM_STATUS as received: ``time_s`` on the shell's monotonic clock, who sent it."""

    time_s: float
    status: ArmStatus
    error: str
    raw_status: int
    src_system: int
    src_component: int

    @classmethod
    def decode(
        cls, time_s: float, status: int, error: str | bytes, src_system: int, src_component: int
    ) -> ArmStatusReport:
        text = error.decode("ascii", "replace") if isinstance(error, bytes) else str(error)
        return cls(
            time_s, ArmStatus.from_wire(status), text.rstrip("\x00").strip(), int(status), src_system, src_component
        )


class GateVerdict(Enum):
    """What the arming gate decided."""

    OFF = "off"  # remote_id.enabled is false: no gate
    GOOD = "good"  # a fresh GOOD_TO_ARM
    ABSENT = "absent"  # no ARM_STATUS received
    STALE = "stale"  # the latest is older than arm_status_max_age_s
    NOT_GOOD = "not_good"  # the transponder says it is not ready (its error text with it)


@dataclass(frozen=True, slots=True)
class GateDecision:
    verdict: GateVerdict
    reason: str

    @property
    def may_arm(self) -> bool:
        return self.verdict in (GateVerdict.OFF, GateVerdict.GOOD)


def arm_gate(enabled: bool, report: ArmStatusReport | None, now_s: float, max_age_s: float) -> GateDecision:
    """May the vehicle be armed for a delivery, on the transponder's latest ARM_STATUS?"""
    if not enabled:
        return GateDecision(GateVerdict.OFF, "remote_id.enabled is false")
    if report is None:
        return GateDecision(
            GateVerdict.ABSENT, "Remote ID: no OPEN_DRONE_ID_ARM_STATUS from the transponder (is it connected?)"
        )
    age = now_s - report.time_s
    if not math.isfinite(age) or age > max_age_s:
        return GateDecision(
            GateVerdict.STALE,
            f"Remote ID: the transponder's last ARM_STATUS is {age:.1f} s old (remote_id.arm_status_max_age_s = "
            f"{max_age_s:g} s)",
        )
    if report.status is not ArmStatus.GOOD_TO_ARM:
        said = f": {report.error}" if report.error else ""
        return GateDecision(
            GateVerdict.NOT_GOOD,
            f"Remote ID: the transponder says {report.status.name} (status {report.raw_status}){said}",
        )
    return GateDecision(GateVerdict.GOOD, "Remote ID: the transponder is good to arm")
