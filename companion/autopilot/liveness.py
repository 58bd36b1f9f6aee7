"""The control loop's liveness: what lets the companion's heartbeats and setpoints leave.

The backends send some of their traffic from threads of their own: ArduPilot's reader thread
sends the heartbeat ArduCopter's GCS failsafe watches, MAVSDK sends the component's heartbeat and
(offboard plugin) re-sends the last setpoint. Those threads keep running when the event loop that
flies the mission hangs, so the autopilot sees a live companion and never fails safe while the
vehicle flies a setpoint nobody computes any more. Presence is not liveness.

So the shell renews a token every guidance tick (:meth:`LoopLiveness.renew`), and the backends
send a heartbeat or a setpoint only while :attr:`LoopLiveness.alive`. A watchdog thread (never
on the loop it watches: that one sees nothing while it hangs) shuts the gate the moment the token
is older than ``stall_s`` and says so in the log from its own thread; the autopilot then fails
safe within its own timeout, as if the companion had died (ArduCopter FS_GCS_TIMEOUT and
GUID_TIMEOUT, PX4 COM_OF_LOSS_T). When the ticks come back the watchdog opens the gate again and
the heartbeats resume; the mission then finds the autopilot's failsafe mode and decides.

Outside a supervised stretch (:meth:`LoopLiveness.watching`, the guidance loop's lifetime) the
gate is open: before the mission and between flights nothing is flown, and the heartbeat goes on.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable, Iterator

log = logging.getLogger(__name__)

WATCHDOG_THREAD_NAME = "loop-watchdog"
STALL_S_RANGE = (0.05, 30.0)  # what watching() accepts (the [runtime] key has its own, narrower)


class LoopLiveness:
    """The gate the backends consult before each heartbeat and setpoint, and its watchdog.

    ``clock`` is the watchdog's clock (monotonic seconds; injectable for tests). Thread-safe:
    :meth:`renew` runs on the loop, :attr:`alive` on any sender's thread, :meth:`poll` on the
    watchdog's. ``supervised=False`` is an inert gate, always open (backends that send nothing
    from threads of their own: the embedded simulator).
    """

    def __init__(self, clock: Callable[[], float] = time.monotonic, *, supervised: bool = True) -> None:
        self._clock = clock
        self._supervised = supervised
        self._lock = threading.Lock()
        self._stall_s: float | None = None  # None: not watching, the gate is open
        self._renewed_s = -math.inf
        self._shut = False
        self._shut_since_s = -math.inf
        self.stalls = 0  # times the gate was shut
        self.longest_stall_s = 0.0  # the longest stall seen, renewal to renewal
        self.withheld = 0  # heartbeats and setpoints the backends did not send while shut

    @property
    def watched(self) -> bool:
        return self._stall_s is not None

    @property
    def shut(self) -> bool:
        return self._shut

    def renew(self) -> None:
        """The control loop proves itself alive (each guidance tick, on the loop)."""
        if self._stall_s is not None:
            self._renewed_s = self._clock()

    @property
    def alive(self) -> bool:
        """Whether a heartbeat or a setpoint may leave now: not watching, or the token fresh and
        the watchdog not holding the gate shut."""
        stall = self._stall_s
        if stall is None:
            return True
        return not self._shut and self._clock() - self._renewed_s <= stall

    def may_send(self) -> bool:
        """For a sender: True (send it) while alive; otherwise False, counted in :attr:`withheld`."""
        if self.alive:
            return True
        self.withheld += 1
        return False

    def poll(self) -> bool:
        """The watchdog's step: shut the gate on a stall, open it when the loop renews again;
        each change said once in the log, from the calling thread. Returns :attr:`alive`."""
        with self._lock:
            stall = self._stall_s
            if stall is None:
                return True
            now = self._clock()
            age = now - self._renewed_s
            if not self._shut and age > stall:
                self._shut = True
                self._shut_since_s = self._renewed_s
                self.stalls += 1
                log.error(
                    "control loop stalled: no guidance tick for %.2f s (limit %.2f s); heartbeats and "
                    "setpoints stopped so the autopilot's own failsafe acts",
                    age,
                    stall,
                )
            elif self._shut and age <= stall:
                self._shut = False
                length = self._renewed_s - self._shut_since_s
                self.longest_stall_s = max(self.longest_stall_s, length)
                log.warning(
                    "control loop back after a %.2f s stall: heartbeats and setpoints resume; the mission "
                    "finds the autopilot's failsafe mode",
                    length,
                )
            return not self._shut

    @contextlib.contextmanager
    def watching(self, stall_s: float, poll_s: float | None = None) -> Iterator[LoopLiveness]:
        """Supervise the loop for the duration of the ``with``: the token starts fresh, the
        watchdog thread polls every ``poll_s`` (default: a fifth of ``stall_s``, at most 0.1 s),
        and at the end the gate is open again."""
        lo, hi = STALL_S_RANGE
        if not (math.isfinite(stall_s) and lo <= stall_s <= hi):
            raise ValueError(f"stall_s = {stall_s!r}: expected {lo} to {hi} s")
        if not self._supervised:
            yield self
            return
        if self._stall_s is not None:
            raise RuntimeError("LoopLiveness.watching: already watching (one control loop at a time)")
        period = min(stall_s / 5.0, 0.1) if poll_s is None else poll_s
        if not (math.isfinite(period) and period > 0.0):
            raise ValueError(f"poll_s = {poll_s!r}: expected a period > 0 s")
        with self._lock:
            self._renewed_s = self._clock()
            self._shut = False
            self._stall_s = stall_s
        stop = threading.Event()

        def watchdog() -> None:
            while not stop.wait(period):
                self.poll()

        thread = threading.Thread(target=watchdog, name=WATCHDOG_THREAD_NAME, daemon=True)
        thread.start()
        try:
            yield self
        finally:
            stop.set()
            thread.join(2.0)
            with self._lock:
                self._stall_s = None
                self._shut = False


#: the gate of an autopilot that sends nothing from threads of its own: always open
INERT_LIVENESS = LoopLiveness(supervised=False)
