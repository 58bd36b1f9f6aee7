"""Delayed (out-of-sequence) measurements for the EKF: apply a measurement at the time it was
*captured* (camera exposure, UWB sample), then re-predict to now with the stored inputs.

:class:`DelayedMeasurementBuffer` owns the filter's time. It keeps a short history of events
(inputs and measurements), each with the filter snapshot (state, covariance, xi, counters, time,
held input) taken just before it was applied. A measurement stamped in the past is inserted at
its time: the filter is restored to the snapshot before the first later event, the measurement
is applied there and every later event (inputs *and* measurements) is replayed. The result is
identical, to rounding, to having applied the measurement on time.

Input convention (zero-order hold, causal): ``predict(t, u)`` first propagates from the current
time to ``t`` with the input held so far, then holds ``u`` from ``t`` on. A measurement at ``t_m``
between two inputs is therefore applied after propagating to ``t_m`` with the input held at
``t_m`` -- the same whether it arrives on time or late.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field
from enum import Enum
from typing import Any, assert_never

import numpy as np
from numpy.typing import ArrayLike

from companion.estimation.ekf import DeliveryEkf, EkfSnapshot, PositionFix, UpdateOutcome
from companion.estimation.types import StateEstimate
from companion.geometry import Transform


class BufferEventKind(Enum):
    """What an event of the buffer is: a process input or a measurement of one of the EKF's
    sensors (the values are :class:`~companion.estimation.ekf.EkfSensor`'s, and name the event in
    :attr:`BufferCounters.extra`: ``"aruco.rejected_too_old"``)."""

    INPUT = "input"
    SDK = "sdk"
    ARUCO = "aruco"
    UWB = "uwb"


@dataclass
class _Event:
    time_s: float
    kind: BufferEventKind
    payload: tuple[Any, ...]
    before: tuple[EkfSnapshot, float, np.ndarray] | None = None
    outcome: UpdateOutcome | None = None


@dataclass
class BufferCounters:
    delayed_applied: int = 0
    too_old: int = 0
    input_nonfinite: int = 0
    input_out_of_order: int = 0
    replayed_events: int = 0
    extra: dict[str, int] = field(default_factory=dict)


class DelayedMeasurementBuffer:
    """Time-aware wrapper of :class:`DeliveryEkf` that accepts late measurements.

    ``history_s`` bounds how late a measurement may be (older ones are counted and refused).
    """

    def __init__(self, ekf: DeliveryEkf, start_time_s: float, history_s: float = 1.0) -> None:
        if not (math.isfinite(start_time_s) and math.isfinite(history_s) and history_s > 0):
            raise ValueError("start_time_s and history_s must be finite, history_s > 0")
        self.ekf = ekf
        self.history_s = float(history_s)
        self.counters = BufferCounters()
        self._now = float(start_time_s)
        self._held_u = np.zeros(6)
        self._events: list[_Event] = []
        self._times: list[float] = []

    @property
    def now_s(self) -> float:
        return self._now

    def estimate(self) -> StateEstimate:
        return self.ekf.estimate(self._now)

    # ---- public event entry points -------------------------------------------------------

    def predict(self, time_s: float, u: ArrayLike) -> None:
        """Propagate to ``time_s`` with the held input, then hold ``u`` (input at ``time_s``)."""
        uu = np.asarray(u, dtype=float).reshape(6)
        if not np.all(np.isfinite(uu)):
            self.counters.input_nonfinite += 1
            uu = self._held_u.copy()  # keep holding the last finite input
        if not math.isfinite(time_s) or time_s < self._now:
            self.counters.input_out_of_order += 1
            return
        self._add(_Event(float(time_s), BufferEventKind.INPUT, (uu,)))

    def update_sdk(self, time_s: float, position_ned_m: ArrayLike, euler_rad: ArrayLike | None = None) -> UpdateOutcome:
        pos = np.asarray(position_ned_m, dtype=float).copy()
        eul = None if euler_rad is None else np.asarray(euler_rad, dtype=float).copy()
        return self._add(_Event(float(time_s), BufferEventKind.SDK, (pos, eul)))

    def update_aruco(self, time_s: float, T_camera_marker: Transform, T_world_marker: Transform) -> UpdateOutcome:
        return self._add(_Event(float(time_s), BufferEventKind.ARUCO, (T_camera_marker, T_world_marker)))

    def update_uwb(self, fix: PositionFix, T_world_anchor: Transform) -> UpdateOutcome:
        return self._add(_Event(float(fix.time_s), BufferEventKind.UWB, (fix, T_world_anchor)))

    # ---- machinery -----------------------------------------------------------------------

    def _state(self) -> tuple[EkfSnapshot, float, np.ndarray]:
        return self.ekf.snapshot(), self._now, self._held_u.copy()

    def _restore(self, st: tuple[EkfSnapshot, float, np.ndarray]) -> None:
        snap, now, held = st
        self.ekf.restore(snap)
        self._now = now
        self._held_u = held.copy()

    def _apply(self, ev: _Event) -> UpdateOutcome:
        ev.before = self._state()
        dt = ev.time_s - self._now
        if dt > 0.0:
            self.ekf.predict(self._held_u, dt)
            self._now = ev.time_s
        kind = ev.kind
        if kind is BufferEventKind.INPUT:
            self._held_u = ev.payload[0]
            ev.outcome = UpdateOutcome.ACCEPTED
        elif kind is BufferEventKind.SDK:
            ev.outcome = self.ekf.update_sdk(ev.payload[0], ev.payload[1])
        elif kind is BufferEventKind.ARUCO:
            ev.outcome = self.ekf.update_aruco(ev.payload[0], ev.payload[1])
        elif kind is BufferEventKind.UWB:
            ev.outcome = self.ekf.update_uwb(ev.payload[0], ev.payload[1])
        else:
            assert_never(kind)
        return ev.outcome

    def _add(self, ev: _Event) -> UpdateOutcome:
        if not math.isfinite(ev.time_s):
            return self._refuse(ev)
        if ev.time_s >= self._now:
            outcome = self._apply(ev)
            self._events.append(ev)
            self._times.append(ev.time_s)
            self._prune()
            return outcome
        # late: insert after every event with time <= its time, replay what follows
        i = bisect.bisect_right(self._times, ev.time_s)
        if i >= len(self._events) or ev.time_s < self._now - self.history_s:
            return self._refuse(ev)
        start = self._events[i].before
        if start is None or start[1] > ev.time_s:
            return self._refuse(ev)
        self._restore(start)
        later = self._events[i:]
        outcome = self._apply(ev)
        for e in later:
            self._apply(e)
        self.counters.replayed_events += len(later)
        self.counters.delayed_applied += 1
        self._events.insert(i, ev)
        self._times.insert(i, ev.time_s)
        self._prune()
        return outcome

    def _refuse(self, ev: _Event) -> UpdateOutcome:
        # counted here, not in the EKF's counters (those are rewound with its snapshots)
        self.counters.too_old += 1
        key = f"{ev.kind.value}.{UpdateOutcome.REJECTED_TOO_OLD.value}"
        self.counters.extra[key] = self.counters.extra.get(key, 0) + 1
        return UpdateOutcome.REJECTED_TOO_OLD

    def _prune(self) -> None:
        horizon = self._now - self.history_s
        # keep the first event at/after the horizon together with its "before" snapshot
        k = bisect.bisect_left(self._times, horizon)
        if k > 0:
            del self._events[:k]
            del self._times[:k]
