"""The gate between the autopilot's downward rangefinder (DISTANCE_SENSOR) and the final descent's
height above the ground (``[mission.rangefinder]``, docs/rangefinder.md).

Why: flying GPS only, PX4 v1.16 SIH's height estimate drifted 0.3-1.7 m within one 20 s flight,
so the descent's last metre (the sideways command's end, the ground contact) was judged on a
height a metre off. A rangefinder measures the height itself, but not always: beyond its range,
while the vehicle is tilted, when a leg or the hanging parcel comes into the beam, or when it
fails. A reading is used only when it passes every check below (the first after none only once
the next one agrees with it); each rejection is counted by its reason. A reading that passes
gives the offset between the rangefinder's height and the estimate's; the offset is kept
``hold_s`` after the last reading used, so the last centimetres, below the sensor's minimum
range, fly on the estimate corrected by it.

The readings are duck-typed (:class:`RangefinderSample`: ``companion.autopilot.types.RangefinderReading``
is one), so this layer does not import the autopilot's.
"""

from __future__ import annotations

import enum
import math
from collections import Counter
from typing import Protocol

from companion.config import RangefinderConfig

MAV_SENSOR_ROTATION_PITCH_270 = 25  # downward (MAV_SENSOR_ORIENTATION)


class RangefinderSample(Protocol):
    @property
    def time_s(self) -> float: ...
    @property
    def distance_m(self) -> float: ...
    @property
    def min_distance_m(self) -> float: ...
    @property
    def max_distance_m(self) -> float: ...
    @property
    def orientation(self) -> int: ...
    @property
    def signal_quality_pct(self) -> int | None: ...


class Rejection(enum.Enum):
    """Why a reading was not used (each counted once per reading)."""

    NOT_DOWNWARD = "not_downward"  # its orientation is not MAV_SENSOR_ROTATION_PITCH_270
    LOW_QUALITY = "low_quality"  # its signal quality below min_quality_pct
    STALE = "stale"  # older than max_age_s
    OUT_OF_RANGE = "out_of_range"  # outside [min_distance_m, max_distance_m) (at the ground: below the minimum)
    TILTED = "tilted"  # the vehicle tilted more than max_tilt_deg
    TOO_HIGH = "too_high"  # the estimate's height above below_height_m
    INCONSISTENT = "inconsistent"  # farther than max_disagreement_m from the estimate's height
    JUMP = "jump"  # moved more than max_jump_m (against the estimate) from the reading before or the last one used
    UNCONFIRMED = "unconfirmed"  # the first after none: used once the next agrees with it


class RangefinderGate:
    """One descent's gate: made anew for each landing phase (its reference offset starts empty)."""

    def __init__(self, cfg: RangefinderConfig):
        self.cfg = cfg
        self.rejected: Counter[Rejection] = Counter()
        self.accepted = 0
        self._offset_m: float | None = None  # rangefinder height - estimate's height, last reading used
        self._offset_t = -math.inf
        self._seen_t: float | None = None  # the last reading judged (by its time), and its verdict
        self._seen_verdict: Rejection | None = None
        self._seen_height: float | None = None
        # (offset, time) of the reading before, when it passed the other checks
        self._candidate: tuple[float, float] | None = None

    def judge(
        self, r: RangefinderSample, time_s: float, estimate_height_m: float, roll_rad: float, pitch_rad: float
    ) -> tuple[float | None, Rejection | None]:
        """The reading's tilt-corrected height above the ground and None, or None and why it is
        not used. A reading judged again (guidance ticks faster than the sensor) keeps its verdict
        and is counted once, unless it has gone stale since."""
        c = self.cfg
        if self._seen_t == r.time_s and (self._seen_verdict is not None or time_s - r.time_s <= c.max_age_s):
            return self._seen_height, self._seen_verdict
        height, why = self._check(r, time_s, estimate_height_m, roll_rad, pitch_rad)
        self._seen_t, self._seen_verdict, self._seen_height = r.time_s, why, height
        if why is not None:
            self.rejected[why] += 1
        else:
            assert height is not None
            self.accepted += 1
            self._offset_m, self._offset_t = height - estimate_height_m, time_s
        return height, why

    def height(
        self,
        r: RangefinderSample | None,
        time_s: float,
        estimate_height_m: float,
        roll_rad: float,
        pitch_rad: float,
    ) -> float:
        """The height above the ground the descent flies on: the reading's when it passes, else
        the estimate's corrected by the last reading used within hold_s, else the estimate's."""
        if r is not None:
            h, _ = self.judge(r, time_s, estimate_height_m, roll_rad, pitch_rad)
            if h is not None:
                return h
        if self._offset_m is not None and time_s - self._offset_t <= self.cfg.hold_s:
            return estimate_height_m + self._offset_m
        return estimate_height_m

    def _check(
        self, r: RangefinderSample, time_s: float, est_h: float, roll_rad: float, pitch_rad: float
    ) -> tuple[float | None, Rejection | None]:
        c = self.cfg
        cos_tilt = math.cos(roll_rad) * math.cos(pitch_rad)
        h = r.distance_m * cos_tilt  # the beam's length to the vertical (flat ground)
        why = self._unusable(r, time_s, est_h, cos_tilt, h)
        if why is not None:
            # a reading not used breaks the chain: the next one must be confirmed by its own
            # successor, not by one from before the gap (two spikes around a gap would agree)
            self._candidate = None
            return None, why
        # between samples: against the reading before (a spike is not confirmed by the next true
        # one) and against the last one used while it is held (a leg staying in the beam)
        off = h - est_h
        before, self._candidate = self._candidate, (off, r.time_s)
        if before is None or r.time_s - before[1] > c.max_age_s:
            return None, Rejection.UNCONFIRMED
        held = self._offset_m is not None and time_s - self._offset_t <= c.hold_s
        if abs(off - before[0]) > c.max_jump_m or (
            held and self._offset_m is not None and abs(off - self._offset_m) > c.max_jump_m
        ):
            return None, Rejection.JUMP
        return h, None

    def _unusable(
        self, r: RangefinderSample, time_s: float, est_h: float, cos_tilt: float, h: float
    ) -> Rejection | None:
        """Why one reading, on its own, is not a height above the ground (None: it may be)."""
        c = self.cfg
        if r.orientation != MAV_SENSOR_ROTATION_PITCH_270:
            return Rejection.NOT_DOWNWARD
        q = r.signal_quality_pct
        if q is not None and q < c.min_quality_pct:
            return Rejection.LOW_QUALITY
        if time_s - r.time_s > c.max_age_s:
            return Rejection.STALE
        if not (r.min_distance_m <= r.distance_m < r.max_distance_m):
            return Rejection.OUT_OF_RANGE
        if cos_tilt < math.cos(math.radians(c.max_tilt_deg)):
            return Rejection.TILTED
        if est_h > c.below_height_m:
            return Rejection.TOO_HIGH
        if abs(h - est_h) > c.max_disagreement_m:
            return Rejection.INCONSISTENT
        return None
