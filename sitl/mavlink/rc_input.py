"""RC input of the sim vehicle: the pilot's transmitter, the companion's RC_CHANNELS_OVERRIDE and
what the autopilot flies on (and reports in RC_CHANNELS).

An override replaces its channel until released (0 on channels 1-8, UINT16_MAX-1 on 9-18) or
until it lapses after ``rc_override_timeout_s`` (ArduPilot's RC_OVERRIDE_TIME). A vehicle with
``set_rc_input`` (companion_sitl.dart_link.StickSimVehicle) is handed the copter mode and
channels 1-4 every tick by the ArduPilot dialect, so STABILIZE / ALT_HOLD fly on the sticks.
"""

from __future__ import annotations

from typing import Any, ClassVar

from companion_sitl.mavlink.params import ParameterServer


class RcInput(ParameterServer):
    """The RC channels: ``_radio`` the pilot's, ``_ovr`` the overrides in force (per channel, with
    their time ``_ovr_at``) and ``_rc`` what the autopilot flies on."""

    #: RC_OVERRIDE_TIME when none is given (< 0: overrides never lapse)
    RC_OVERRIDE_TIMEOUT_S: ClassVar[float] = -1.0
    rc_override_timeout_s: float  # RC_OVERRIDE_TIME; < 0: never lapses
    _rc: list[int]
    _radio: list[int]
    _ovr: list[int | None]
    _ovr_at: list[float]
    _rc_override_at: float

    def _rc_switch(self, now: float) -> None:
        """The autopilot reads the pilot's RC (mode switch, sticks) after the RC input changed."""
        return None  # optional hook: this dialect ignores it

    @property
    def rc_channels(self) -> list[int]:
        return list(self._rc)

    @property
    def rc_overrides(self) -> list[int | None]:
        """The companion's overrides in force per channel (None: the radio's value is used)."""
        with self.lock:
            return list(self._ovr)

    def pilot_set_rc(self, channels: dict[int, int]) -> None:
        """The pilot's transmitter (ArduPilot dialect): 1-based channel -> microseconds, thread-safe.
        Overridden channels keep the override until it is released or lapses."""
        for ch, us in channels.items():
            if not 1 <= ch <= 18:
                raise ValueError(f"RC channel {ch}: must be 1..18")
            if not 0 <= us <= 65535:
                raise ValueError(f"RC channel {ch} = {us}: must be 0..65535 us")
        with self.lock:
            running = self.running  # before start(), vehicle time has not begun
            now = self.now if running else self.vehicle.time_s
            if running:
                self.vehicle.step_to(now)
            for ch, us in channels.items():
                self._radio[ch - 1] = int(us)
            self._rc_effective(now)
            self._rc_switch(now)

    def _rc_override(self, m: Any) -> None:
        """RC_CHANNELS_OVERRIDE: channels 1-8: 0 releases, UINT16_MAX ignores; channels 9-18: 0
        and UINT16_MAX ignore, UINT16_MAX-1 releases; any other value overrides the channel."""
        now = self.now
        for i in range(18):
            val = int(getattr(m, f"chan{i + 1}_raw", 0))
            if val == 65535 or (i >= 8 and val == 0):
                continue
            if (i < 8 and val == 0) or (i >= 8 and val == 65534):
                self._ovr[i] = None
                continue
            self._ovr[i] = val
            self._ovr_at[i] = now
        self._rc_override_at = now
        self._rc_effective(now)
        self._rc_switch(now)

    def _rc_effective(self, now: float) -> None:
        """What the autopilot flies on: each override in force, else the radio; stale overrides
        lapse after RC_OVERRIDE_TIME (ArduPilot: the radio takes the channel back)."""
        timeout = self.rc_override_timeout_s
        for i in range(18):
            o = self._ovr[i]
            if o is not None and 0.0 <= timeout < now - self._ovr_at[i]:
                self._ovr[i] = o = None
            self._rc[i] = self._radio[i] if o is None else o
