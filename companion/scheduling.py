"""Clocks and fixed-rate loops for the asyncio shell.

Fixed-rate loops use absolute deadlines (t0 + k * period) on an injectable clock, count
overruns and never drift. The clock is the running loop's ``time()``: the real monotonic clock
in flight, the simulated clock under ``companion_sitl.clock.VirtualTimeEventLoop``.
"""

from __future__ import annotations

import asyncio
import contextlib
import errno
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar

log = logging.getLogger(__name__)


class Clock(Protocol):
    def now(self) -> float: ...

    async def sleep_until(self, t_s: float) -> None: ...


class LoopClock:
    """The running asyncio loop's clock (monotonic, or virtual in simulation)."""

    def now(self) -> float:
        return asyncio.get_running_loop().time()

    async def sleep_until(self, t_s: float) -> None:
        dt = t_s - self.now()
        await asyncio.sleep(dt if dt > 0 else 0)


class RateLoop:
    """Ticks at ``rate_hz`` on absolute deadlines.

    ``await tick()`` returns the scheduled tick time. When the caller is late by more than a
    period, the missed ticks are skipped (counted in ``overruns``) instead of bursting to catch
    up, and the schedule stays anchored to t0 (no drift).
    """

    def __init__(self, clock: Clock, rate_hz: float, start_s: float | None = None):
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz = {rate_hz}: must be a positive number")
        self.clock = clock
        self.period_s = 1.0 / rate_hz
        self._t0 = clock.now() if start_s is None else start_s
        self._k = 0
        self.overruns = 0
        self.ticks = 0
        self.early_ticks = 0

    def _next_deadline(self) -> tuple[int, float, int]:
        """The next tick's index and deadline, skipping ticks missed by more than a period, and
        how many were skipped (counted in ``overruns`` when the tick is taken)."""
        k = self._k + 1
        deadline = self._t0 + k * self.period_s
        now = self.clock.now()
        missed = 0
        if now > deadline + self.period_s:
            missed = math.floor((now - deadline) / self.period_s)
            k += missed
            deadline = self._t0 + k * self.period_s
        return k, deadline, missed

    async def tick(self) -> float:
        self._k, deadline, missed = self._next_deadline()
        self.overruns += missed
        await self.clock.sleep_until(deadline)
        self.ticks += 1
        return deadline

    async def tick_or(self, event: asyncio.Event) -> tuple[float, bool]:
        """The next tick, or earlier if ``event`` is set first: ``(time, early)``. An early tick
        returns the clock's time and leaves the schedule as it was (the periodic tick still comes
        at its deadline); ``event`` is cleared."""
        k, deadline, missed = self._next_deadline()
        if not event.is_set():
            timeout = deadline - self.clock.now()
            if timeout > 0:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(event.wait(), timeout)
        if event.is_set():
            event.clear()
            now = self.clock.now()
            if now < deadline:
                self.early_ticks += 1
                return now, True
        self._k = k
        self.overruns += missed
        await self.clock.sleep_until(deadline)
        self.ticks += 1
        return deadline, False


# How a bench or a test instruments a shell without changing its flight: a stage timer
# ``(stage, fn) -> fn`` the shell applies once where it binds a named stage (None: nothing
# wrapped), and the factory its fixed-rate loops are built with.
StageTimer = Callable[[str, Callable[..., Any]], Callable[..., Any]]
F = TypeVar("F", bound=Callable[..., Any])


class RateLoopFactory(Protocol):
    def __call__(self, clock: Clock, rate_hz: float, start_s: float | None = None) -> RateLoop: ...


def untimed(stage: str, fn: F) -> F:
    """The stage timer of a flight: ``fn`` itself."""
    return fn


def timed(timer: StageTimer | None, stage: str, fn: F) -> F:
    """``fn`` timed as ``stage`` when a stage timer is set, else ``fn`` itself."""
    return fn if timer is None else timer(stage, fn)  # type: ignore[return-value]


# ---------------------------------------------------------------------------- thread priority
@dataclass(frozen=True)
class ThreadPolicy:
    """A thread's scheduling policy (``os.SCHED_*``, reset-on-fork flag included) and its
    real-time priority, as read before a change, to put back."""

    tid: int
    policy: int
    priority: int


def thread_policy(tid: int | None = None) -> ThreadPolicy:
    """The scheduling policy of thread ``tid`` (Linux: a thread id is a pid to sched_*; None:
    the calling thread)."""
    tid = threading.get_native_id() if tid is None else tid
    return ThreadPolicy(tid, os.sched_getscheduler(tid), os.sched_getparam(tid).sched_priority)


def set_thread_realtime(priority: int, tid: int | None = None) -> str | None:
    """Run thread ``tid`` (None: the calling thread) under SCHED_RR at ``priority`` (1-99): it
    preempts every thread of the normal policy the moment it wakes, whatever else loads the core
    (a busy real-time thread is still bounded by the kernel's RT throttling, sched_rt_runtime_us).
    The threads it starts later inherit the policy: a Python thread of the normal policy preempted
    while it holds the interpreter lock would stall the real-time ones. Returns None when applied,
    otherwise why not (no CAP_SYS_NICE and an RLIMIT_RTPRIO below ``priority``, a cgroup v1
    without real-time runtime, not Linux); the thread then keeps its policy."""
    if not 1 <= priority <= 99:
        raise ValueError(f"real-time priority {priority!r}: expected 1..99")
    try:
        os.sched_setscheduler(0 if tid is None else tid, os.SCHED_RR, os.sched_param(priority))
    except AttributeError:
        return "this platform has no SCHED_RR"
    except OSError as err:
        if err.errno == errno.EPERM:
            return (
                f"not permitted ({err.strerror}): needs CAP_SYS_NICE or RLIMIT_RTPRIO >= {priority}, and on a "
                "cgroup v1 host real-time runtime in the process's cpu cgroup (docs/flying.md)"
            )
        return f"{type(err).__name__}: {err}"
    return None


def vision_thread_priority(loop_priority: int) -> int:
    """The vision thread's real-time priority: one below the loop's, so guidance and the setpoint
    stream get the core first when both are ready."""
    return max(1, loop_priority - 1)


def realtime_loop_thread(loop: asyncio.AbstractEventLoop, priority: int) -> tuple[ThreadPolicy | None, str]:
    """A shell's ``runtime.realtime_priority`` for the calling thread, the one running ``loop``, in
    real time only (a lock-step simulation runs flat out: real time would take the core from
    everything else); a refusal is logged once. Returns the policy to put back at the end (None:
    nothing changed) and what was done: ``"SCHED_RR <priority>"``, ``"not applied: virtual
    time"``, ``"refused: <why>"``, or ``""`` for priority 0."""
    if priority <= 0:
        return None, ""
    if abs(loop.time() - time.monotonic()) > 1.0:  # not the wall clock: virtual time
        return None, "not applied: virtual time"
    saved = thread_policy()
    why = set_thread_realtime(priority)
    if why is not None:
        log.warning("realtime_priority = %d: the loop's thread keeps the normal policy (%s)", priority, why)
        return None, f"refused: {why}"
    log.info("loop thread SCHED_RR %d, vision thread %d", priority, vision_thread_priority(priority))
    return saved, f"SCHED_RR {priority}"


def probe_realtime(priority: int) -> str | None:
    """Whether this process may run a thread under SCHED_RR at ``priority``, tried on a thread
    started for it (the caller's own keeps its policy): None when it may, otherwise why not."""
    out: list[str | None] = []
    t = threading.Thread(target=lambda: out.append(set_thread_realtime(priority)), name="realtime-probe")
    t.start()
    t.join()
    return out[0]


def restore_thread_policy(saved: ThreadPolicy) -> None:
    """Put the calling thread back to the policy :func:`thread_policy` read from it."""
    if saved.tid != threading.get_native_id():
        raise ValueError(f"policy of thread {saved.tid} restored on thread {threading.get_native_id()}")
    os.sched_setscheduler(0, saved.policy, os.sched_param(saved.priority))
