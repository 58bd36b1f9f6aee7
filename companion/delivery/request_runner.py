"""The mission's requests to the autopilot (arm, take off, offboard, hold, land, release, winch),
each run as a task of its own so a slow acknowledgement never stalls guidance, and every one
answered: its result (or why it failed, and whether that is permanent) goes to the observers,
then to the mission, which retries or gives up (``mission.requests.RequestBook``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Callable
from typing import Protocol

from companion.autopilot.interface import Autopilot, AutopilotError, CommandRejected
from companion.delivery.mission import DeliveryMission, Request, RequestKind, RequestResult
from companion.delivery.observers import ShellObserver
from companion.delivery.shell_stats import ShellStats
from companion.scheduling import LoopClock

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 10.0  # an autopilot call that takes longer has failed (and is retried)


class Owner(Protocol):
    """What the runner reads of the shell: the mission that hears each result."""

    mission: DeliveryMission


class RequestRunner:
    def __init__(
        self,
        owner: Owner,
        autopilot: Autopilot,
        clock: LoopClock,
        stats: ShellStats,
        watching: Callable[[], list[ShellObserver]],
    ):
        self.owner = owner
        self.autopilot = autopilot
        self.clock = clock
        self.stats = stats
        self.watching = watching
        self.task: asyncio.Task[None] | None = None  # the newest request's

    def submit(self, req: Request) -> None:
        """Run ``req`` as a task of its own (the mission issues one at a time)."""
        self.task = asyncio.get_running_loop().create_task(self.execute(req))

    async def cancel(self) -> None:
        """The request under way, if any, cancelled and waited for (the shell is stopping)."""
        if self.task is not None:
            self.task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await self.task

    async def execute(self, req: Request) -> None:
        ap = self.autopilot
        self.stats.requests += 1
        calls = {
            RequestKind.ARM: ap.arm,
            RequestKind.DISARM: ap.disarm,
            RequestKind.START_OFFBOARD: ap.start_offboard,
            RequestKind.HOLD: ap.hold,
            RequestKind.LAND: ap.land,
            RequestKind.PRECISION_LAND: ap.precision_land,
            RequestKind.RELEASE: ap.release_payload,
        }
        # Every way out of here answers the request: a request left without a result would keep
        # the mission from ever issuing another (an abort's HOLD and LAND included), silently.
        # a call the autopilot never answers ends here; an arm that waits for the autopilot's
        # checks by design (ArduPilot's arm_timeout_s, retried until then) gets its own time
        limit_s = REQUEST_TIMEOUT_S
        if req.kind is RequestKind.ARM:
            limit_s = max(limit_s, float(getattr(ap, "arm_timeout_s", 0.0)) + REQUEST_TIMEOUT_S)
        try:
            if req.kind is RequestKind.TAKEOFF:
                await asyncio.wait_for(ap.takeoff(req.alt_rel_m), limit_s)
            elif req.kind is RequestKind.WINCH:
                assert req.winch is not None
                await asyncio.wait_for(ap.winch(req.winch), limit_s)
            else:
                await asyncio.wait_for(calls[req.kind](), limit_s)
        except (AutopilotError, TimeoutError) as err:
            permanent = isinstance(err, CommandRejected) and err.permanent
            self._failed(req, str(err) or type(err).__name__, permanent)
            return
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None and task.cancelling():
                raise  # the shell is stopping
            # a cancellation from inside the backend (a native call's future cancelled under it)
            self._failed(req, "the autopilot call was cancelled inside the backend", False)
            return
        except Exception as err:  # a backend bug: said with its traceback, and the mission told
            log.exception("%s: the backend raised %s", req.kind.value, type(err).__name__)
            self._failed(req, f"backend error: {type(err).__name__}: {err}", False)
            return
        self._result(req, RequestResult(req.id, True))

    def _failed(self, req: Request, msg: str, permanent: bool) -> None:
        self.stats.requests_failed += 1
        log.warning("%s failed%s: %s", req.kind.value, " (not retried)" if permanent else "", msg)
        self._result(req, RequestResult(req.id, False, msg, permanent))

    def _result(self, req: Request, result: RequestResult) -> None:
        for ob in self.watching():
            ob.on_result(self.clock.now(), req.kind.value, result)
        self.owner.mission.on_result(result)
