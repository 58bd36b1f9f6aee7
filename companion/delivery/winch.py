"""The winch delivery's sequence (mission.delivery = "winch"; docs/winch.md).

Pure. The mission holds the vehicle over the locked pad at winch.hover_height_m and steps this
sequence each guidance tick with whether the hover is ready (locked, on the pad's centre, at the
height) and the winch's newest report; the sequence says which DO_WINCH or release to send and
when it has ended:

settle (ready for settle_s) -> payout (the line to the hover height plus slack: the parcel is down)
-> release (the existing parcel release, then release_time_s) -> reel in -> done: fly home.

A payout the winch refuses, or a line that does not reach its length within payout_timeout_s, or a
release the autopilot refuses: the line is reeled in and the vehicle flies home with the parcel,
the reason said once. A reel-in that is refused or does not finish within reel_timeout_s: home
anyway, said (hovering on with a line out would not bring it in).

With winch.tension_sensing (a winch whose WINCH_STATUS carries the line's tension) the line itself
is read: once it has carried the parcel, the parcel is down when the line goes slack; slack far
short of the hover height is a parcel caught on the way down, a line still taut at its full length
a parcel hanging short of the ground, and a line that never carried anything a missing parcel: no
release in each, reel in, home with it. After the release the first light_check_m reeled in must
stay slack; a line that takes the load again is a parcel still on the hook, flown home.

With winch.camera (a tag on the parcel's top, vision.parcel_tag) the parcel down by the line's
rule is looked at before the release: the camera must see the parcel's bottom within
down_tolerance_m of the pad for confirm_s within wait_s, else (caught, hanging short, not seen) no
release, reel in, home with it.

With winch.reel_check_s the reel-in is watched: a line that does not come in at half the asked
rate, or a winch reporting itself unhealthy, is a jam, said CRITICAL (``WinchTick.critical``); the
hover holds (no climb with the line out) while the reel-in is tried reel_retries more times, then
the sequence ends ``jammed``: the mission lands where the vehicle is, the line first.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from companion.autopilot.types import Wind
from companion.autopilot.winch import WinchAction, WinchCommand, WinchStatus
from companion.config import WinchConfig
from companion.vision.parcel_tag import ParcelSighting

LINE_MOVING_M_S = 0.05  # a winch reporting a faster payout is stopped before the reel-in
SLACK_CONFIRM_S = 0.5  # tension sensing: the line reads slack this long (a swing slackens it for an instant)


class WinchStep(enum.Enum):
    SETTLE = "settle"
    PAYOUT = "payout"
    LOOK = "look"  # winch.camera: the line says the parcel is down, the camera must see it on the pad
    RELEASE = "release"
    REEL = "reel"
    DONE = "done"


@dataclass(frozen=True, slots=True)
class WinchTick:
    """What the sequence wants this tick: a DO_WINCH to send, the parcel release to send, what to
    say (EventKind.WINCH details). ``done``: the sequence has ended (the line is in, or given up
    on): fly home; ``delivered`` then says whether the parcel was released on the pad."""

    command: WinchCommand | None = None
    release: bool = False
    say: tuple[str, ...] = ()
    done: bool = False
    critical: tuple[str, ...] = ()  # the line will not reel in (EventKind.WINCH_JAM), said before ``say``


class WindCorrection:
    """Where to hover so the parcel, blown downwind on its line, lands on the pad: upwind of the pad
    by wind_drift_s_m x hover_height_m x the wind (small angles: a linear drag k per unit mass
    holds the line at tan(theta) = k w / g from the vertical), on the autopilot's wind estimate
    low-passed over wind_filter_s (the gusts the parcel's swing does not follow)."""

    def __init__(self, cfg: WinchConfig):
        self.cfg = cfg
        self._wind: tuple[float, float] | None = None
        self._t: float | None = None

    def offset_ne_m(self, now_s: float, wind: Wind | None) -> tuple[float, float]:
        """(north, east) offset of the hover from the pad's centre (m)."""
        c = self.cfg
        if c.wind_drift_s_m <= 0.0 or wind is None:
            return (0.0, 0.0)
        w = (wind.north_m_s, wind.east_m_s)
        if self._wind is None or self._t is None:
            self._wind = w
        else:
            a = 1.0 - math.exp(-max(0.0, now_s - self._t) / c.wind_filter_s)
            self._wind = (self._wind[0] + a * (w[0] - self._wind[0]), self._wind[1] + a * (w[1] - self._wind[1]))
        self._t = now_s
        k = -c.wind_drift_s_m * c.hover_height_m  # upwind: against where the air moves
        return (k * self._wind[0], k * self._wind[1])


class WinchSequence:
    def __init__(self, cfg: WinchConfig, release_time_s: float):
        self.cfg = cfg
        self.release_time_s = release_time_s
        self.step_now = WinchStep.SETTLE
        self.delivered = False
        self.failure = ""  # why the parcel was not delivered (or a later problem), "" on success
        self.paid_out = False  # a payout was accepted: the line may be out, the hover must hold
        self._ready_since: float | None = None
        self._t0 = 0.0  # when the current step's command was accepted (or sent)
        self._sent = False  # the current step's request is out (or answered)
        self._accepted = False
        self._say: list[str] = []
        self._halt = 0  # reel-in: 1 the stop before it is out, 2 answered (at _halt_t)
        self._halt_t = 0.0
        self._loaded = False  # tension sensing: the line has carried the parcel in this payout
        self._tension_read = False  # tension sensing: the payout was judged on the tension
        self._light_from: float | None = None  # released at this length: the line must come up light
        self._no_tension_said = False
        self._slack_since: float | None = None
        self._slack_at_m = math.nan  # the line's length when it went slack
        self.jams = 0  # reel_check_s: reel-in tries seen jammed
        self.jammed = False  # ended with the line out and not coming in: land where the vehicle is
        self._critical: list[str] = []
        self._check: tuple[float, float] | None = None  # reel_check_s: (report time, length) of the window
        self._seen: ParcelSighting | None = None  # winch.camera: the newest fresh sighting while looking
        self._down_since: float | None = None  # winch.camera: the first of the run of sightings on the pad

    @property
    def target_m(self) -> float:
        """The line length at which the parcel stands on the pad with the line slack."""
        return self.cfg.hover_height_m + self.cfg.slack_m

    # ------------------------------------------------------------------ results
    def on_result(self, now_s: float, ok: bool, error: str = "") -> None:
        """The answer to the request this sequence asked for last (DO_WINCH or the release)."""
        st = self.step_now
        if st is WinchStep.REEL and self._halt == 1:  # the answer to the stop before the reel-in
            if not ok:
                self._end(f"the winch refused to stop the line ({error}): flying home with the line as it is")
                return
            self._halt, self._halt_t, self._sent = 2, now_s, False
            return
        if ok:
            self._accepted = True
            self._t0 = now_s
            self._check = None
            if st is WinchStep.PAYOUT:
                self.paid_out = True
                self._say.append(f"payout accepted: lowering the parcel {self.target_m:.2f} m")
            elif st is WinchStep.RELEASE:
                self._say.append(f"release commanded; waiting {self.release_time_s} s for the actuator")
            return
        if st is WinchStep.PAYOUT:
            self._fail(now_s, f"the winch refused the payout ({error})")
        elif st is WinchStep.RELEASE:
            self._fail(now_s, f"parcel not released: the autopilot refused the release ({error})")
        elif st is WinchStep.REEL:
            self._end(f"the winch refused the reel-in ({error}): flying home with the line as it is")

    # ------------------------------------------------------------------ the tick
    def step(
        self,
        now_s: float,
        ready: bool,
        status: WinchStatus | None,
        idle: bool,
        parcel: ParcelSighting | None = None,
    ) -> WinchTick:
        """``ready``: the hover is locked on the pad's centre at the height (judged by the mission);
        ``status``: the winch's newest report (None: none yet); ``idle``: no request in flight;
        ``parcel``: the camera's newest sighting of the parcel (winch.camera; None: none)."""
        st = self.step_now
        command: WinchCommand | None = None
        release = False
        length = status.line_length_m if status is not None else math.nan
        if st is WinchStep.SETTLE:
            if not ready:
                self._ready_since = None
            elif self._ready_since is None:
                self._ready_since = now_s
            if self._ready_since is not None and now_s - self._ready_since >= self.cfg.settle_s and idle:
                self.step_now = WinchStep.PAYOUT
                self._begin(now_s)
                out = self.target_m - (length if math.isfinite(length) else 0.0)
                command = WinchCommand(
                    self.cfg.instance, WinchAction.RELATIVE_LENGTH_CONTROL, out, self.cfg.payout_rate_m_s
                )
                self._say.append(f"over the pad: paying out {out:.2f} m at {self.cfg.payout_rate_m_s} m/s")
        elif st is WinchStep.PAYOUT and self._accepted:
            tension = self._tension(status)
            at_length = math.isfinite(length) and length >= self.target_m - self.cfg.length_tolerance_m
            if tension is not None and math.isfinite(length):
                self._payout_on_tension(now_s, length, tension, at_length)
            elif at_length:
                self._down(now_s, f"parcel down: line {length:.2f} m out after {now_s - self._t0:.1f} s")
            if self.step_now is WinchStep.PAYOUT and now_s - self._t0 > self.cfg.payout_timeout_s:
                seen = f"line {length:.2f} m" if math.isfinite(length) else "no WINCH_STATUS from the winch"
                self._fail(
                    now_s,
                    f"the line did not pay out: {seen} of {self.target_m:.2f} m after {self.cfg.payout_timeout_s} s",
                )
        elif st is WinchStep.LOOK:
            self._look(now_s, length, parcel)
        elif st is WinchStep.RELEASE:
            if not self._sent and idle:
                self._sent = True
                release = True
            elif self._accepted and now_s - self._t0 >= self.release_time_s:
                if self._tension_read and math.isfinite(length):
                    self._light_from = length
                    self._say.append("release done: checking that the line comes up light")
                else:
                    self.delivered = True
                    self._say.append("parcel released on the pad")
                self.step_now = WinchStep.REEL
                self._begin(now_s)
        if self.step_now is WinchStep.REEL and command is None and not release:
            command = self._reel(now_s, status, idle)
            self._check_light(status)
        tick = WinchTick(command, release, tuple(self._say), self.step_now is WinchStep.DONE, tuple(self._critical))
        self._say, self._critical = [], []
        return tick

    def _reel(self, now_s: float, status: WinchStatus | None, idle: bool) -> WinchCommand | None:
        length = status.line_length_m if status is not None else math.nan
        if not self._sent:
            if not idle:
                return None
            speed = status.speed_m_s if status is not None and math.isfinite(status.speed_m_s) else 0.0
            if self._halt == 0 and speed > LINE_MOVING_M_S:
                # still paying out (a payout given up): stop the line first, so the reel-in takes back
                # the length it stopped at, not the one reported before the command took effect
                self._halt, self._sent, self._t0 = 1, True, now_s
                self._say.append(f"stopping the line first (paying out at {speed:.2f} m/s)")
                return WinchCommand(self.cfg.instance, WinchAction.RATE_CONTROL, 0.0, 0.0)
            stale = status is None or status.time_s <= self._halt_t
            if self._halt == 2 and stale and now_s - self._halt_t < self.cfg.reel_timeout_s:
                return None  # waiting for a report from after the stop
            self._sent = True
            self._t0 = now_s
            # back to zero from what the winch reports (from the target when it reports nothing)
            out = length if math.isfinite(length) else self.target_m
            self._say.append(f"reeling in {max(out, 0.0):.2f} m at {self.cfg.reel_rate_m_s} m/s")
            return WinchCommand(
                self.cfg.instance, WinchAction.RELATIVE_LENGTH_CONTROL, -max(out, 0.0), self.cfg.reel_rate_m_s
            )
        if self.step_now is not WinchStep.REEL:
            return None
        if math.isfinite(length) and length <= self.cfg.reeled_in_m and self._accepted:
            self._end(f"line reeled in ({length:.2f} m)")
        elif self._accepted and self.cfg.reel_check_s > 0.0 and (why := self._jam(status)):
            self._on_jam(length, why)
        elif now_s - self._t0 > self.cfg.reel_timeout_s:
            seen = f"{length:.2f} m still out" if math.isfinite(length) else "no WINCH_STATUS from the winch"
            self._end(f"the line is not back in after {self.cfg.reel_timeout_s} s ({seen}): flying home as it is")
        return None

    # ------------------------------------------------------------------ the jammed line
    def _jam(self, status: WinchStatus | None) -> str:
        """Why the reel-in counts as jammed ("" while it comes in): judged on the winch's reports from
        after the command's acceptance, over windows of reel_check_s of their own time."""
        c = self.cfg
        if status is None or status.time_s < self._t0:
            return ""
        if not status.healthy:
            return "the winch reports itself unhealthy"
        if self._check is None:
            self._check = (status.time_s, status.line_length_m)
            return ""
        t, was = self._check
        if status.time_s - t < c.reel_check_s:
            return ""
        came = was - status.line_length_m
        need = min(0.5 * c.reel_rate_m_s * c.reel_check_s, was - c.reeled_in_m)
        if came < need:
            return f"{came:.2f} m in over {status.time_s - t:.1f} s, {need:.2f} m expected"
        self._check = (status.time_s, status.line_length_m)
        return ""

    @property
    def tries(self) -> str:
        """The reel-in tries seen jammed, said: "1 try", "2 tries"."""
        return f"{self.jams} {'try' if self.jams == 1 else 'tries'}"

    def _on_jam(self, length: float, why: str) -> None:
        c = self.cfg
        self.jams += 1
        if self.jams <= c.reel_retries:
            self._critical.append(
                f"the line will not reel in ({why}; {length:.2f} m out): holding, reel-in try "
                f"{self.jams + 1} of {c.reel_retries + 1}"
            )
            self._sent = self._accepted = False  # the next idle tick asks again, from the reported length
            self._halt, self._check = 0, None
            return
        self.jammed = True
        self._critical.append(
            f"the line will not reel in after {self.tries} ({why}; {length:.2f} m out): landing where the "
            "vehicle is, the line first"
        )
        self._end("the line will not reel in: landing where the vehicle is")

    def stop(self, now_s: float, reason: str) -> bool:
        """Give the delivery up (a ground command to return): reel in from wherever the line is,
        then done. False when the sequence ends by itself already (reeling in, or released)."""
        if self.step_now in (WinchStep.REEL, WinchStep.DONE) or (self.step_now is WinchStep.RELEASE and self._sent):
            return False  # coming in already, or the release is out: it reels in within release_time_s
        if self.step_now is WinchStep.SETTLE:
            self._say.append(f"{reason}: no line out")
            self.failure = reason
            self.step_now = WinchStep.DONE
            return True
        self._fail(now_s, reason)
        return True

    # ------------------------------------------------------------------ the camera's look
    def _down(self, now_s: float, said: str) -> None:
        """The line's rule says the parcel is down: release, or first look (winch.camera)."""
        if not self.cfg.camera.enabled:
            self._say.append(said)
            self.step_now = WinchStep.RELEASE
            self._begin(now_s)
            return
        self._say.append(f"{said}; looking for it on the pad with the camera")
        self.step_now = WinchStep.LOOK
        self._begin(now_s)
        self._seen, self._down_since = None, None

    def _look(self, now_s: float, length: float, parcel: ParcelSighting | None) -> None:
        c = self.cfg.camera
        fresh = parcel if parcel is not None and now_s - parcel.time_s <= c.stale_s else None
        if fresh is not None and fresh is not self._seen:
            self._seen = fresh
            if abs(fresh.bottom_above_pad_m) <= c.down_tolerance_m:
                if self._down_since is None:
                    self._down_since = fresh.time_s
            else:
                self._down_since = None  # every sighting of the run on the pad
        if self._down_since is not None and fresh is not None and fresh.time_s - self._down_since >= c.confirm_s:
            self._say.append(
                f"the camera sees the parcel on the pad (its bottom {fresh.bottom_above_pad_m:+.2f} m from it)"
            )
            self.step_now = WinchStep.RELEASE
            self._begin(now_s)
            return
        if now_s - self._t0 <= c.wait_s:
            return
        line = f"the line out {length:.2f} m" if math.isfinite(length) else "no line length reported"
        if fresh is not None and fresh.bottom_above_pad_m > c.down_tolerance_m:
            why = (
                f"the camera sees the parcel {fresh.bottom_above_pad_m:.2f} m above the pad with {line} "
                "(caught or hanging short)"
            )
        elif fresh is not None:
            why = f"the camera sees the parcel {-fresh.bottom_above_pad_m:.2f} m below the pad's plane with {line}"
        else:
            why = f"the camera did not see the parcel's tag within {c.wait_s} s with {line}"
        self._fail(now_s, why)

    # ------------------------------------------------------------------ the line's tension
    def _tension(self, status: WinchStatus | None) -> float | None:
        """The line's tension (kg) when the configuration reads it and the winch reports it."""
        if not self.cfg.tension_sensing or status is None:
            return None
        if math.isfinite(status.tension_kg):
            return status.tension_kg
        if not self._no_tension_said:
            self._no_tension_said = True
            self._say.append("the winch reports no tension (winch.tension_sensing): judged on the line length")
        return None

    def _payout_on_tension(self, now_s: float, length: float, tension: float, at_length: bool) -> None:
        c = self.cfg
        self._tension_read = True
        if tension >= c.slack_tension_kg:
            self._loaded = True
            self._slack_since = None
            if at_length:
                self._fail(
                    now_s,
                    f"the parcel hangs short of the ground: the line is out {length:.2f} m and still carries "
                    f"{tension:.2f} kg",
                )
        elif self._loaded and self._slack_for(now_s, length) < SLACK_CONFIRM_S:
            pass  # slack for an instant: wait for the next reports
        elif self._loaded and self._slack_at_m < c.hover_height_m - c.snag_margin_m:
            self._fail(
                now_s,
                f"the parcel caught on the way down: the line went slack at {self._slack_at_m:.2f} m, "
                f"{c.hover_height_m - self._slack_at_m:.2f} m above the pad",
            )
        elif self._loaded:
            self._down(
                now_s, f"parcel down: the line went slack at {self._slack_at_m:.2f} m after {now_s - self._t0:.1f} s"
            )
        elif at_length:
            self._fail(now_s, f"the line never carried the parcel (under {c.slack_tension_kg} kg to {length:.2f} m)")

    def _slack_for(self, now_s: float, length: float) -> float:
        """How long the line has read slack (its first slack report counts from now, at ``length``)."""
        if self._slack_since is None:
            self._slack_since, self._slack_at_m = now_s, length
        return now_s - self._slack_since

    def _check_light(self, status: WinchStatus | None) -> None:
        """After the release: the parcel left on the pad once light_check_m came in slack."""
        if self._light_from is None or status is None:
            return
        tension = status.tension_kg
        if math.isfinite(tension) and tension >= self.cfg.slack_tension_kg:
            self._light_from = None
            self.failure = "parcel not released: the line took its load again after the release (still on the hook)"
            self._say.append(f"{self.failure}, {tension:.2f} kg: reeling in, flying home with the parcel")
        elif math.isfinite(status.line_length_m) and status.line_length_m <= self._light_from - self.cfg.light_check_m:
            self._light_from = None
            self.delivered = True
            self._say.append(f"parcel released on the pad: the line came up light ({self.cfg.light_check_m} m in)")

    # ------------------------------------------------------------------ helpers
    def _begin(self, now_s: float) -> None:
        self._t0 = now_s
        self._halt = 0
        self._sent = self.step_now is WinchStep.PAYOUT  # the payout command goes out with this tick
        self._accepted = False
        self._check = None

    def _fail(self, now_s: float, reason: str) -> None:
        """The parcel stays aboard: reel the line in, then home with it."""
        self.failure = reason
        self._say.append(f"{reason}: reeling in, flying home with the parcel")
        self.step_now = WinchStep.REEL
        self._begin(now_s)

    def _end(self, detail: str) -> None:
        self._say.append(detail)
        if self._light_from is not None:  # released, the line not in far enough to read it light
            self._light_from = None
            self.delivered = True
            self._say.append("parcel released on the pad (the line did not come in far enough to check it)")
        if not self.delivered and not self.failure:
            self.failure = detail
        self.step_now = WinchStep.DONE
