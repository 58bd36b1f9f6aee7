"""A parcel on a real autopilot's winch line, for the camera rendered from the SITL's truth
(docs/winch.md, "The camera judges the parcel down"): ArduCopter SITL's winch only moves a servo
output, nothing hangs from it. Here the simulator's pendulum (companion_sitl.winch.ParcelOnLine)
hangs under the true vehicle on the length the firmware's own winch reports (WINCH_STATUS on the
truth link), and is let go when the firmware's gripper output reaches its release PWM
(SERVO_OUTPUT_RAW). The truth frame's ground is down = 0 (the origin is the take-off point).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable

from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.winch import STOWED_M, ParcelOnLine

STEP_S = 0.001  # the pendulum's integration step (sitl.payload.PARCEL_STEP_HZ)
RELEASE_PWM_TOLERANCE_US = 50


class ParcelOnTruth:
    """The parcel under ``truth`` (which must watch WINCH_STATUS and SERVO_OUTPUT_RAW);
    ``release_output`` / ``release_pwm``: the gripper's servo output and its GRIP_RELEASE.
    :meth:`bottom_ned` (called at each exposure) steps the pendulum to now and says where it is."""

    def __init__(
        self,
        truth: MavlinkTruth,
        release_output: int,
        release_pwm: int,
        drag_1_s: float = 0.3,
        snag_height_m: float = 0.0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not {"WINCH_STATUS", "SERVO_OUTPUT_RAW"} <= truth.watch:
            raise ValueError("the truth link must watch WINCH_STATUS and SERVO_OUTPUT_RAW")
        self.truth = truth
        self.release_output = release_output
        self.release_pwm = release_pwm
        self.parcel = ParcelOnLine(drag_1_s, snag_height_m)
        self.clock = clock  # the truth link's arrival clock (monotonic s)
        self.length_m = 0.0
        self._t: float | None = None
        self._a: tuple[float, float, float] | None = None
        self._length0 = 0.0  # the line's length at the last step
        self._seen_s = -math.inf  # the newest watched message read

    def _read_firmware(self) -> None:
        """The newest line length, and the release once the gripper's output reached it."""
        for t, m in self.truth.watched_messages("WINCH_STATUS", since=self._seen_s):
            self.length_m = float(m.line_length)
            self._seen_s = max(self._seen_s, t)
        if not self.parcel.released:
            for t, m in self.truth.watched_messages("SERVO_OUTPUT_RAW", since=self._seen_s):
                pwm = getattr(m, f"servo{self.release_output}_raw", 0)
                if abs(pwm - self.release_pwm) <= RELEASE_PWM_TOLERANCE_US:
                    self.parcel.release()
                self._seen_s = max(self._seen_s, t)

    def bottom_ned(self) -> tuple[float, float, float] | None:
        """The parcel's bottom (truth NED) once it is out of its bay, else None."""
        tr = self.truth
        now = self.clock()
        self._read_firmware()
        a = (tr.pn, tr.pe, tr.pd)
        va = (tr.vn, tr.ve, tr.vd)
        if self._t is None or self._a is None:
            self.parcel.stow(a, va)
        else:
            n = max(1, min(2000, math.ceil((now - self._t) / STEP_S)))
            dt = (now - self._t) / n
            a0, l0 = self._a, self._length0
            for k in range(1, n + 1):  # the suspension point and the line moved linearly meanwhile
                u = k / n
                ak = (a0[0] + u * (a[0] - a0[0]), a0[1] + u * (a[1] - a0[1]), a0[2] + u * (a[2] - a0[2]))
                self.parcel.step(self._t + k * dt, dt, ak, va, l0 + u * (self.length_m - l0))
        self._t, self._a, self._length0 = now, a, self.length_m
        p = self.parcel
        if self.length_m >= STOWED_M or p.on_ground or p.caught:
            return (p.p[0], p.p[1], p.p[2])
        return None
