"""The delivery mission: a state machine on enum phases (delivery Algorithm 1, made complete),
in parts: ``core`` (the step and what the phases share), ``phases`` (the handler table),
``states`` (one state per phase), ``requests``, ``linkwatch``, ``padpolicy``, ``routes``,
``winch_phase``, ``yaw``, ``commands``, and ``types`` (what goes in and out). docs/architecture.md
shows who calls whom."""

from companion.delivery.mission.base import FOLLOW_PHASES
from companion.delivery.mission.commands import CommandOutcome, CommandReply
from companion.delivery.mission.core import DeliveryMission
from companion.delivery.mission.phases import TOUCHDOWN_REPORT_MARGIN_S
from companion.delivery.mission.requests import MAX_REQUEST_TRIES, REQUEST_RETRY_DELAY_S
from companion.delivery.mission.types import (
    FailureKind,
    Leg,
    MissionInputs,
    MissionOutput,
    MissionSummary,
    Request,
    RequestKind,
    RequestResult,
    Step,
)

__all__ = [
    "FOLLOW_PHASES",
    "MAX_REQUEST_TRIES",
    "REQUEST_RETRY_DELAY_S",
    "TOUCHDOWN_REPORT_MARGIN_S",
    "CommandOutcome",
    "CommandReply",
    "DeliveryMission",
    "FailureKind",
    "Leg",
    "MissionInputs",
    "MissionOutput",
    "MissionSummary",
    "Request",
    "RequestKind",
    "RequestResult",
    "Step",
]
