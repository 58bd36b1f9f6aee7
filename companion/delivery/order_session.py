"""What a session of delivery orders did (``fly --orders``): each flight and the order events;
filled by :func:`companion.cli.orders.serve_orders`, which a caller may hand one to watch."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

from companion.delivery.mission import FailureKind
from companion.events import MissionEvent


@dataclass
class FlownOrder:
    """One accepted order and how its flight ended."""

    order_id: str
    run_dir: Path
    delivered: bool
    returned: bool
    failure: str
    failure_kind: FailureKind = FailureKind.NONE


@dataclass
class OrderSession:
    """What ``fly --orders`` did: the flights, and every order event (accepted, refused, flown)."""

    flights: list[FlownOrder] = field(default_factory=list)
    events: deque[MissionEvent] = field(default_factory=lambda: deque(maxlen=1000))  # the latest
    accepted: int = 0
    refused: int = 0
