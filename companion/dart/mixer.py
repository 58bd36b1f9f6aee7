"""The Dart signal mixer's hybrid mode (dart sec. 2.2, Fig. 3) in MAVLink terms.

The Dart mixer board decodes the pilot's PPM into time intervals (1 unit = 1 us), adds the
cyber-pilot's contribution "by also taking into account their sign" and re-encodes the sum.
Here the pilot's sticks come from MAVLink RC_CHANNELS (microseconds, index 0 = channel 1), the
contribution from dart.control.DartController (offsets from neutral in FRD sense: +roll right,
+pitch nose up, +thrust up, +yaw rate nose right), and the result is the 18 ``chanN_raw`` fields
of RC_CHANNELS_OVERRIDE.

Engagement: the autonomous (hybrid) mode is on while the pilot's switch channel reads above
``engage_above_us`` (e.g. > 1700 us). Reading it at or below the threshold, or an invalid switch
or stick reading, disengages in the same call: the output returns to the pilot and
``on_disengage`` (the controller's reset) runs before :meth:`RcMixer.mix` returns.

Output values (MAVLink RC_CHANNELS_OVERRIDE semantics):

- engaged, for the four mixed channels: clamp(pilot + sign * contribution, 1000, 2000) us, with
  sign = -1 for a reversed channel;
- disengaged, with ``RcMixer(release_when_disengaged=True)`` (default): the four channels are *released* back
  to the RC radio — 0 for channels 1-8, UINT16_MAX-1 (65534) for channels 9-18 — so the autopilot
  uses the pilot's sticks directly, without a companion round trip. Without it, the pilot's own
  values are echoed unchanged (exactly the pilot's sticks);
- every other channel, including the switch channel: UINT16_MAX (65535) = "ignore this field"
  (for channels 9-18, 0 also means ignore; 65535 is used throughout).

For PX4 :func:`attitude_setpoint` maps the same pilot sticks + contribution onto an attitude
setpoint (roll/pitch rad, yaw rate rad/s, thrust 0..1) for SET_ATTITUDE_TARGET.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Protocol

from companion.param_kinds import DART_RC_CHANNELS, AttitudeMapTable, RcMixerTable

logger = logging.getLogger(__name__)

UINT16_MAX = 65535
IGNORE = UINT16_MAX  # "ignore this field" for every channel
RELEASE_LOW = 0  # channels 1-8: "release back to the RC radio"
RELEASE_HIGH = UINT16_MAX - 1  # channels 9-18: "release back to the RC radio"
N_OVERRIDE_CHANNELS = DART_RC_CHANNELS  # MAVLink RC_CHANNELS_OVERRIDE carries 18

AXES = ("roll", "pitch", "throttle", "yaw")


class ContributionLike(Protocol):
    """The cyber-pilot's contribution (dart.control.DartCommand satisfies it), microseconds."""

    @property
    def roll_us(self) -> float: ...
    @property
    def pitch_us(self) -> float: ...
    @property
    def thrust_us(self) -> float: ...
    @property
    def yaw_rate_us(self) -> float: ...


#: the mixer's channels, switch, stick range and authority: declared once (unit, limits,
#: description of each key) in companion.param_kinds.RcMixerTable, the keys ``[runtime]`` of a
#: Dart file shares with it (companion.dart.params.DartRuntimeConfig *is* a mixer config)
RcMixerConfig = RcMixerTable


@dataclass(frozen=True, slots=True)
class MixerOutput:
    """``channels``: the 18 chanN_raw values for RC_CHANNELS_OVERRIDE.
    ``sticks_us``: what the four axes (roll, pitch, throttle, yaw) now carry — the mixed values
    when engaged, the pilot's when not (None for an invalid pilot reading)."""

    channels: tuple[int, ...]
    engaged: bool
    disengaged_now: bool
    sticks_us: tuple[int | None, int | None, int | None, int | None]


def _reading(channels_us: Sequence[float | int | None], channel: int) -> float | None:
    """The pilot's value on a 1-based channel, or None when absent / not a number."""
    if channel > len(channels_us):
        return None
    v = channels_us[channel - 1]
    if v is None:
        return None
    try:
        f = float(v)
    except (TypeError, ValueError):
        return None
    return f if math.isfinite(f) else None


class RcMixer:
    """Hybrid-mode mixer. Counters: ``invalid_inputs`` (pilot readings missing, NaN or out of
    [valid_min, valid_max] — they disengage), ``clamped_inputs`` (pilot readings outside
    [min, max], clamped), ``rejected_contributions`` (non-finite: mixed as zero),
    ``clamped_contributions``, ``clamped_outputs``."""

    def __init__(
        self,
        config: RcMixerConfig | None = None,
        on_disengage: Callable[[], None] | None = None,
        *,
        release_when_disengaged: bool = True,
    ) -> None:
        self.config = config or RcMixerConfig()
        #: disengaged: release the four channels to the radio (True, what flight does) or echo
        #: the pilot's values (the mixer board's own behaviour, tests)
        self.release_when_disengaged = release_when_disengaged
        self.on_disengage = on_disengage
        self._engaged = False
        self.invalid_inputs = 0
        self.clamped_inputs = 0
        self.rejected_contributions = 0
        self.clamped_contributions = 0
        self.clamped_outputs = 0
        self.engagements = 0
        self.disengagements = 0

    @property
    def engaged(self) -> bool:
        return self._engaged

    def _valid(self, v: float | None) -> bool:
        c = self.config
        return v is not None and c.valid_min_us <= v <= c.valid_max_us

    def engaged_from(self, pilot_channels_us: Sequence[float | int | None]) -> bool:
        """Would these pilot channels engage? (Switch above the threshold and all four sticks
        valid.) Pure: no counters, no state."""
        c = self.config
        sw = _reading(pilot_channels_us, c.switch_channel)
        if not self._valid(sw) or not sw > c.engage_above_us:  # type: ignore[operator]
            return False
        return all(self._valid(_reading(pilot_channels_us, ch)) for ch in c.channels)

    def _release_value(self, channel: int) -> int:
        return RELEASE_LOW if channel <= 8 else RELEASE_HIGH

    def _disengage(self) -> bool:
        was = self._engaged
        self._engaged = False
        if was:
            self.disengagements += 1
            logger.info("rc mixer: autonomous mode off, pilot in control")
            if self.on_disengage is not None:
                self.on_disengage()
        return was

    def mix(
        self,
        pilot_channels_us: Sequence[float | int | None],
        contribution: ContributionLike | None,
    ) -> MixerOutput:
        """Pilot sticks + contribution -> RC_CHANNELS_OVERRIDE values (see the module doc)."""
        c = self.config
        raw = [_reading(pilot_channels_us, ch) for ch in c.channels]
        valid = [self._valid(v) for v in raw]
        self.invalid_inputs += valid.count(False)
        sw = _reading(pilot_channels_us, c.switch_channel)
        if not self._valid(sw):
            self.invalid_inputs += 1
        want = self.engaged_from(pilot_channels_us)

        out = [IGNORE] * N_OVERRIDE_CHANNELS
        if not want:
            just_off = self._disengage()
            sticks: list[int | None] = []
            for ch, v, ok in zip(c.channels, raw, valid, strict=True):
                pilot = round(v) if ok and v is not None else None
                sticks.append(pilot)
                if self.release_when_disengaged or pilot is None:
                    out[ch - 1] = self._release_value(ch)
                else:
                    out[ch - 1] = pilot  # exactly the pilot's stick
            return MixerOutput(tuple(out), False, just_off, tuple(sticks))  # type: ignore[arg-type]

        if not self._engaged:
            self._engaged = True
            self.engagements += 1
            logger.info("rc mixer: autonomous (hybrid) mode on")
        contrib = self._contribution(contribution)
        sticks = []
        for ch, v, sign, u in zip(c.channels, raw, c.signs, contrib, strict=True):
            stick = c.neutral_us if v is None else v  # never None: engaged_from checked
            if not c.min_us <= stick <= c.max_us:
                self.clamped_inputs += 1
                stick = min(c.max_us, max(c.min_us, stick))
            mixed = stick + sign * u  # dart Fig. 3: sum of the intervals, with their sign
            if not c.min_us <= mixed <= c.max_us:
                self.clamped_outputs += 1
                mixed = min(c.max_us, max(c.min_us, mixed))
            value = round(mixed)
            out[ch - 1] = value
            sticks.append(value)
        return MixerOutput(tuple(out), True, False, tuple(sticks))  # type: ignore[arg-type]

    def _contribution(self, contribution: ContributionLike | None) -> list[float]:
        if contribution is None:
            return [0.0, 0.0, 0.0, 0.0]
        try:
            u = [
                float(contribution.roll_us),
                float(contribution.pitch_us),
                float(contribution.thrust_us),
                float(contribution.yaw_rate_us),
            ]
        except (TypeError, ValueError):
            u = [math.nan]
        if not all(math.isfinite(v) for v in u):
            self.rejected_contributions += 1
            return [0.0, 0.0, 0.0, 0.0]
        lim = self.config.max_contribution_us
        clamped = [min(m, max(-m, v)) for v, m in zip(u, lim, strict=True)]
        if clamped != u:
            self.clamped_contributions += 1
        return clamped


# -------------------------------------------------------------------------------- PX4 path
#: full stick deflection in attitude units: companion.param_kinds.AttitudeMapTable (degrees in
#: the file, ``max_tilt_rad`` and ``max_yaw_rate_rad_s`` to the code); ``[runtime]`` and ``[sim]``
#: of a Dart file are attitude maps themselves
AttitudeMapConfig = AttitudeMapTable


@dataclass(frozen=True, slots=True)
class AttitudeSetpoint:
    """For SET_ATTITUDE_TARGET: roll/pitch (FRD, +pitch nose up), yaw rate, thrust 0..1."""

    roll_rad: float
    pitch_rad: float
    yaw_rate_rad_s: float
    thrust: float


def attitude_setpoint(
    pilot_channels_us: Sequence[float | int | None],
    contribution: ContributionLike | None,
    mixer: RcMixerConfig | None = None,
    mapping: AttitudeMapConfig | None = None,
) -> AttitudeSetpoint | None:
    """The hybrid mix of :meth:`RcMixer.mix` expressed as an attitude setpoint (PX4).

    Each axis: deflection = sign * (pilot - neutral) + contribution (FRD sense), clamped to the
    stick range and scaled: roll/pitch by max_tilt, yaw by max_yaw_rate over half the range;
    thrust = (throttle in FRD sense + contribution - min) / (max - min), clamped to [0, 1].
    Returns None when a pilot stick is missing or invalid (send nothing; let the pilot fly).
    A non-finite contribution is ignored (pilot only).
    """
    c = mixer or RcMixerConfig()
    m = mapping or AttitudeMapConfig()
    pilot: list[float] = []
    for ch in c.channels:
        v = _reading(pilot_channels_us, ch)
        if v is None or not c.valid_min_us <= v <= c.valid_max_us:
            return None
        pilot.append(min(c.max_us, max(c.min_us, v)))
    if contribution is None:
        u = [0.0, 0.0, 0.0, 0.0]
    else:
        u = [
            float(contribution.roll_us),
            float(contribution.pitch_us),
            float(contribution.thrust_us),
            float(contribution.yaw_rate_us),
        ]
        if not all(math.isfinite(v) for v in u):
            u = [0.0, 0.0, 0.0, 0.0]
        u = [min(lim, max(-lim, v)) for v, lim in zip(u, c.max_contribution_us, strict=True)]
    signs = c.signs
    half = 0.5 * (c.max_us - c.min_us)

    def deflection(i: int) -> float:
        d = signs[i] * (pilot[i] - c.neutral_us) + u[i]
        return min(1.0, max(-1.0, d / half))

    throttle = pilot[2] if signs[2] > 0 else c.max_us + c.min_us - pilot[2]
    thrust = (throttle + u[2] - c.min_us) / (c.max_us - c.min_us)
    return AttitudeSetpoint(
        roll_rad=deflection(0) * m.max_tilt_rad,
        pitch_rad=deflection(1) * m.max_tilt_rad,
        yaw_rate_rad_s=deflection(3) * m.max_yaw_rate_rad_s,
        thrust=min(1.0, max(0.0, thrust)),
    )
