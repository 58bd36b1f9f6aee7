"""The autopilot's boot clock on the companion's monotonic clock, from MAVLink TIMESYNC
(docs/clock.md).

The exchange, as the firmware answers it (ArduPilot ``GCS_MAVLINK::handle_timesync``, PX4
``MavlinkTimesync`` / ``Timesync::process_timesync``): the companion sends ``TIMESYNC(tc1 = 0,
ts1 = its own time, ns)``; the autopilot answers a message with ``tc1 == 0`` by ``TIMESYNC(tc1 =
its boot time, ns, ts1 = the request's ts1)`` -- ArduPilot ``AP_HAL::micros64() * 1000``, PX4
``hrt_absolute_time() * 1000``. A message with ``tc1 != 0`` is an answer, never answered again. The
companion receives the answer at ``t_rx``:

    RTT    = t_rx - ts1
    offset = tc1 - (ts1 + t_rx) / 2        autopilot boot time minus companion time, ns

(NTP's midpoint estimate, exact when the link's delay is symmetric; its error is at most RTT / 2).
As PX4's timesync does, the estimate is taken from the exchanges with the shortest round trips:
:class:`ClockOffsetEstimator` keeps the last ``window`` accepted exchanges and reports the offset
of the one with the smallest RTT (the least queueing), the jitter (1.4826 x the median absolute
deviation of the offsets of the window's faster half around it) and the RTTs.

An answer is rejected (:class:`TimesyncRejection`, counted) when it is not one: ``tc1 <= 0`` (a
request, or a negative boot time), a ``ts1`` this estimator never sent or already took (a replay,
another client's exchange), a round trip not positive or longer than ``max_rtt_s``. A clock jump --
the autopilot rebooted (its boot clock restarts), or its clock stepped -- shows as ``jump_confirm``
fast exchanges in a row whose offset lies more than ``jump_threshold_s`` from the estimate: the
window is emptied, the estimate starts again from them, and :attr:`ClockOffsetEstimator.jumps`
counts it (a :class:`ClockJump` is returned, and logged).

Pure: no clock read, no I/O; the caller hands in its own times (``companion_ns``) and sends the
requests :meth:`ClockOffsetEstimator.request` returns.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass
from enum import StrEnum

import numpy as np

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
MAD_TO_STD = 1.4826  # a normal distribution's standard deviation per median absolute deviation
INT64_MAX = 2**63 - 1


class TimesyncError(ValueError):
    """A bad setting of the clock-offset estimator."""


class TimesyncRejection(StrEnum):
    """Why an answer was not taken."""

    NOT_AN_ANSWER = "not_an_answer"  # tc1 == 0: a request
    NEGATIVE_CLOCK = "negative_clock"  # tc1 < 0, or values outside int64
    UNKNOWN_REQUEST = "unknown_request"  # ts1 never sent by this estimator, or already answered (a replay)
    NEGATIVE_RTT = "negative_rtt"  # answered before it was sent
    SLOW = "slow"  # round trip longer than max_rtt_s


@dataclass(frozen=True, slots=True)
class TimesyncSample:
    """One accepted exchange: companion times (ns) of the request and the answer, the autopilot's."""

    sent_ns: int
    received_ns: int
    autopilot_ns: int

    @property
    def rtt_ns(self) -> int:
        return self.received_ns - self.sent_ns

    @property
    def offset_ns(self) -> float:
        """Autopilot minus companion, ns: tc1 - (ts1 + t_rx) / 2."""
        return self.autopilot_ns - 0.5 * (self.sent_ns + self.received_ns)


@dataclass(frozen=True, slots=True)
class ClockOffset:
    """The autopilot's boot clock against the companion's: ``offset_s`` (autopilot - companion),
    the ``jitter_s`` of the fast exchanges' offsets around it, the round trips (the best one bounds
    the offset's error by its half), over ``samples`` exchanges; ``jumps``: clock jumps seen."""

    offset_s: float
    jitter_s: float
    rtt_min_s: float
    rtt_median_s: float
    samples: int
    jumps: int

    def to_companion_s(self, autopilot_s: float) -> float:
        """An autopilot boot time (e.g. ``time_boot_ms / 1e3``) on the companion's clock."""
        return autopilot_s - self.offset_s

    def to_autopilot_s(self, companion_s: float) -> float:
        """A companion time on the autopilot's boot clock."""
        return companion_s + self.offset_s


@dataclass(frozen=True, slots=True)
class ClockJump:
    """The offset jumped from ``old_offset_s`` to ``new_offset_s`` at companion time ``at_s``."""

    at_s: float
    old_offset_s: float
    new_offset_s: float


class ClockOffsetEstimator:
    """Offset, jitter and RTT of the autopilot's clock from TIMESYNC exchanges (see the module)."""

    def __init__(
        self,
        window: int = 16,
        min_samples: int = 3,
        max_rtt_s: float = 0.5,
        jump_threshold_s: float = 0.05,
        jump_confirm: int = 3,
        pending_max: int = 64,
    ) -> None:
        if window < 2 or not 1 <= min_samples <= window:
            raise TimesyncError(f"window {window}, min_samples {min_samples}: need window >= 2, 1 <= min <= window")
        for name, v in (("max_rtt_s", max_rtt_s), ("jump_threshold_s", jump_threshold_s)):
            if not (math.isfinite(v) and v > 0.0):
                raise TimesyncError(f"{name} = {v!r}: expected finite and > 0")
        if jump_confirm < 1 or pending_max < 1:
            raise TimesyncError(f"jump_confirm {jump_confirm}, pending_max {pending_max}: need >= 1")
        self.window = window
        self.min_samples = min_samples
        self.max_rtt_ns = round(max_rtt_s * NS_PER_S)
        self.jump_threshold_ns = jump_threshold_s * NS_PER_S
        self.jump_confirm = jump_confirm
        self._samples: deque[TimesyncSample] = deque(maxlen=window)
        self._suspect: list[TimesyncSample] = []  # fast exchanges far from the estimate, in a row
        self._pending: deque[int] = deque(maxlen=pending_max)  # ts1 of the requests not answered yet
        self._last_sent_ns: int | None = None
        self.sent = 0
        self.accepted = 0
        self.rejected: dict[TimesyncRejection, int] = {r: 0 for r in TimesyncRejection}
        self.jumps = 0
        self.jump_log: list[ClockJump] = []

    def request(self, companion_ns: int) -> tuple[int, int]:
        """The (tc1, ts1) of the next request, sent now (``companion_ns``: the companion's clock,
        ns); a ts1 is never reused (a clock read twice in the same nanosecond is nudged on)."""
        ts1 = int(companion_ns)
        if ts1 <= 0:
            raise TimesyncError(f"companion_ns = {companion_ns!r}: a request's ts1 must be > 0 (0 marks none)")
        if self._last_sent_ns is not None and ts1 <= self._last_sent_ns:
            ts1 = self._last_sent_ns + 1
        self._last_sent_ns = ts1
        self._pending.append(ts1)
        self.sent += 1
        return 0, ts1

    def on_timesync(self, tc1: int, ts1: int, companion_ns: int) -> TimesyncRejection | ClockJump | None:
        """An answer received at ``companion_ns``: None when taken, the :class:`ClockJump` when it
        confirmed one, else why it was rejected."""
        tc1, ts1, now = int(tc1), int(ts1), int(companion_ns)
        why = self._check(tc1, ts1, now)
        if why is not None:
            self.rejected[why] += 1
            return why
        self._pending.remove(ts1)
        sample = TimesyncSample(ts1, now, tc1)
        self.accepted += 1
        est = self.estimate
        if est is not None:
            jitter_ns = est.jitter_s * NS_PER_S
            far = abs(sample.offset_ns - est.offset_s * NS_PER_S) > self.jump_threshold_ns + 3.0 * jitter_ns
            # only an exchange as fast as the window's typical one can say the clock moved: a slow
            # one's midpoint error (up to RTT / 2) is not a jump
            fast = sample.rtt_ns <= max(2.0 * est.rtt_median_s * NS_PER_S, self.jump_threshold_ns)
            if far and fast:
                self._suspect.append(sample)
                if len(self._suspect) < self.jump_confirm:
                    return None
                return self._jump(est, now)
            if far:
                return None  # slow and far: not taken, not evidence either
        self._suspect.clear()
        self._samples.append(sample)
        return None

    def _check(self, tc1: int, ts1: int, now: int) -> TimesyncRejection | None:
        if tc1 == 0:
            return TimesyncRejection.NOT_AN_ANSWER
        if tc1 < 0 or tc1 > INT64_MAX or ts1 < 0 or ts1 > INT64_MAX:
            return TimesyncRejection.NEGATIVE_CLOCK
        if ts1 not in self._pending:
            return TimesyncRejection.UNKNOWN_REQUEST
        rtt = now - ts1
        if rtt <= 0:
            return TimesyncRejection.NEGATIVE_RTT
        if rtt > self.max_rtt_ns:
            return TimesyncRejection.SLOW
        return None

    def _jump(self, old: ClockOffset, now: int) -> ClockJump:
        self._samples.clear()
        self._samples.extend(self._suspect)
        self._suspect.clear()
        self.jumps += 1
        new = self.estimate
        new_offset_s = new.offset_s if new is not None else self._samples[-1].offset_ns / NS_PER_S
        jump = ClockJump(now / NS_PER_S, old.offset_s, new_offset_s)
        self.jump_log.append(jump)
        log.warning(
            "autopilot clock jump: offset %.6f s -> %.6f s (%+.3f s; a reboot or a clock step), the estimate "
            "starts again",
            old.offset_s,
            new_offset_s,
            new_offset_s - old.offset_s,
        )
        return jump

    @property
    def estimate(self) -> ClockOffset | None:
        """The offset now, None before ``min_samples`` exchanges were taken."""
        n = len(self._samples)
        if n < min(self.min_samples, self.window):
            return None
        rtt = np.fromiter((s.rtt_ns for s in self._samples), dtype=float, count=n)
        off = np.fromiter((s.offset_ns for s in self._samples), dtype=float, count=n)
        order = np.argsort(rtt, kind="stable")
        best = float(off[order[0]])  # the fastest exchange (PX4 timesync's min-RTT filter)
        fast = off[order[: max(1, (n + 1) // 2)]]  # the faster half
        jitter = MAD_TO_STD * float(np.median(np.abs(fast - best))) if fast.size > 1 else 0.0
        return ClockOffset(
            best / NS_PER_S,
            jitter / NS_PER_S,
            float(rtt[order[0]]) / NS_PER_S,
            float(np.median(rtt)) / NS_PER_S,
            n,
            self.jumps,
        )


def log_clock_offset(logger: logging.Logger, offset: ClockOffset) -> None:
    """The estimate, as both backends log it (at their first exchange and every 60th after)."""
    logger.info(
        "autopilot clock: offset %.6f s (autopilot boot - companion monotonic), jitter %.3f ms, RTT min %.3f "
        "ms, median %.3f ms, over %d exchanges, %d jumps",
        offset.offset_s,
        1e3 * offset.jitter_s,
        1e3 * offset.rtt_min_s,
        1e3 * offset.rtt_median_s,
        offset.samples,
        offset.jumps,
    )


def answer_timesync(tc1: int, ts1: int, boot_ns: int) -> tuple[int, int] | None:
    """What the firmware sends back for a received TIMESYNC (ArduPilot's handle_timesync, PX4's):
    ``(tc1 = boot_ns, ts1)`` for a request (``tc1 == 0``); None for an answer (never answered)."""
    if int(tc1) != 0:
        return None
    return int(boot_ns), int(ts1)
