"""Requests to the autopilot: one in flight at a time, numbered, and the one retry path (a
request the autopilot refused for now is asked again after a delay, up to a number of tries)."""

from __future__ import annotations

import logging
from dataclasses import dataclass

from companion.autopilot.winch import WinchCommand
from companion.delivery.mission.types import Request, RequestKind, RequestResult

log = logging.getLogger(__name__)

MAX_REQUEST_TRIES = 3
REQUEST_RETRY_DELAY_S = 1.0  # between tries of a request the autopilot refused for now


@dataclass(frozen=True, slots=True)
class Pending:
    request: Request
    tries: int = 1


@dataclass(frozen=True, slots=True)
class Retry:
    kind: RequestKind
    alt_rel_m: float
    not_before_s: float
    tries: int


class RequestBook:
    def __init__(self) -> None:
        self._next_id = 1
        self.pending: Pending | None = None
        self.retry: Retry | None = None  # dropped by a phase change: a retry belongs to the phase that asked

    def idle(self) -> bool:
        """No request in flight and none waiting for its retry: a phase may issue a new one."""
        return self.pending is None and self.retry is None

    def make(self, kind: RequestKind, alt_rel_m: float, tries: int = 1, winch: WinchCommand | None = None) -> Request:
        req = Request(self._next_id, kind, alt_rel_m, winch)
        self._next_id += 1
        self.pending = Pending(req, tries)
        return req

    def take(self, result: RequestResult) -> Pending | None:
        """The pending request this result answers (no longer pending), None for an unknown id."""
        p = self.pending
        if p is None or p.request.id != result.id:
            log.warning("result for unknown request %s ignored", result)
            return None
        self.pending = None
        return p

    def final(self, p: Pending, result: RequestResult) -> bool:
        """A refusal that ends the request: permanent, or the last try."""
        return result.permanent or p.tries >= MAX_REQUEST_TRIES

    def schedule_retry(self, p: Pending, now_s: float) -> None:
        self.retry = Retry(p.request.kind, p.request.alt_rel_m, now_s + REQUEST_RETRY_DELAY_S, p.tries + 1)

    def due_retry(self, now_s: float) -> Retry | None:
        """The retry to send now (taken off the book), if one is due and nothing is in flight."""
        r = self.retry
        if r is None or self.pending is not None or now_s < r.not_before_s:
            return None
        self.retry = None
        return r

    def waiting_for(self) -> str:
        if self.pending is not None:
            r = self.pending.request
            return f"waiting for the answer to {r.kind.value} #{r.id} (try {self.pending.tries})"
        if self.retry is not None:
            return f"{self.retry.kind.value} to be retried at t = {self.retry.not_before_s:.1f} s"
        return "no request in flight"
