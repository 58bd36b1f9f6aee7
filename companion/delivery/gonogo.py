"""Go / no-go on the battery and the wind (docs/go-no-go.md). Battery: is there the charge to get
home from here, at the speeds the mission flies, and land with the reserve left? Wind: is the wind
the autopilot estimates within the limit (:class:`WindMonitor`)?

Pure. The charge is the autopilot's own remaining % (BATTERY_STATUS / SYS_STATUS on ArduPilot,
MAVSDK telemetry.battery on PX4: ``VehicleStatus.battery_pct``). The use per second is the
configured one, or the one measured so far in flight (the drop of the remaining % over the time
flown, once ``measure_s`` have been flown: the % moves in 1 % steps). The way home: the horizontal
distance at the cruise speed v3, the descent from the height at v1 (the path's S1 speed, flown
downwards on the way home) down to the final-descent height, and the rest at the landing speed.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

from companion.autopilot.types import Wind
from companion.config import MissionConfig


class GoNoGoVerdict(enum.Enum):
    """A go/no-go check's verdict reached outside a guidance tick (the fence uploaded and read back,
    or refused); its value is what commands.csv records."""

    GO = "go"  # said, nothing changes
    REFUSE = "refuse"  # the delivery is refused before take-off


@dataclass(frozen=True, slots=True)
class WayHome:
    """How the mission flies home: speeds (m/s) and the final-descent height (m)."""

    cruise_m_s: float
    descent_m_s: float
    land_m_s: float
    final_descent_alt_m: float
    climb_m_s: float = 0.0  # to climb back to cruise height first (on the pad); 0: no climb
    cruise_height_m: float = 0.0
    arc_radius_m: float = 0.0  # farther than two arcs from home the path climbs to the cruise height


def way_home(cfg: MissionConfig) -> WayHome:
    """How the mission ``cfg`` flies home (its sector speeds, landing speed and heights)."""
    v = cfg.sector_speed_m_s
    return WayHome(v[2], v[0], cfg.land_speed_m_s, cfg.final_descent_alt_m, v[4], cfg.height_m, cfg.arc_radius_m)


def time_home_s(way: WayHome, distance_m: float, height_m: float) -> float:
    """Seconds to fly ``distance_m`` home horizontally and come down from ``height_m`` above home
    (below the cruise height farther than two arcs from home, the path climbs to it first)."""
    t = max(0.0, distance_m) / way.cruise_m_s
    h = max(0.0, height_m)
    if way.climb_m_s > 0.0 and h < way.cruise_height_m and distance_m > 2.0 * way.arc_radius_m:
        t += (way.cruise_height_m - h) / way.climb_m_s
        h = way.cruise_height_m
    fd = way.final_descent_alt_m
    t += max(0.0, h - fd) / way.descent_m_s + min(h, fd) / way.land_m_s
    return t


@dataclass(frozen=True, slots=True)
class BatteryVerdict:
    go_home: bool
    remaining_pct: float
    needed_pct: float  # for the way home, without the reserve
    reserve_pct: float
    use_pct_per_s: float
    time_home_s: float
    use_measured: bool
    what: str = "the way home"

    def reason(self) -> str:
        how = "measured in flight" if self.use_measured else "configured"
        return (
            f"battery {self.remaining_pct:.1f} % left; {self.what} takes {self.time_home_s:.0f} s x "
            f"{self.use_pct_per_s:.3f} %/s ({how}) = {self.needed_pct:.1f} %, plus the reserve of "
            f"{self.reserve_pct:g} % = {self.needed_pct + self.reserve_pct:.1f} %"
        )


class BatteryMonitor:
    """Measures the use per second while airborne and judges the charge left against the way home."""

    def __init__(self, reserve_pct: float, use_pct_per_s: float = 0.0, measure_s: float = 30.0):
        self.reserve_pct = reserve_pct
        self.configured_use = use_pct_per_s
        self.measure_s = measure_s
        self._t0: float | None = None  # first airborne sample
        self._pct0 = math.nan
        self._flown_s = 0.0
        self._last_t: float | None = None
        self._last_pct = math.nan

    def update(self, time_s: float, battery_pct: float, airborne: bool) -> None:
        """One status sample; only the time in the air counts (the battery barely drains on the pad)."""
        if not math.isfinite(battery_pct):
            return
        if airborne:
            if self._t0 is None:
                self._t0, self._pct0 = time_s, battery_pct
            elif self._last_t is not None:
                self._flown_s += max(0.0, time_s - self._last_t)
            self._last_t = time_s
        else:
            self._last_t = None  # a landing: the next airborne stretch counts from its start
        self._last_pct = battery_pct

    def use_pct_per_s(self) -> tuple[float, bool] | None:
        """The use per second and whether it was measured; None before there is one."""
        if self.configured_use > 0.0:
            return self.configured_use, False
        if self._t0 is None or self._flown_s < self.measure_s:
            return None
        used = self._pct0 - self._last_pct
        if used <= 0.0:
            return None  # no step of the remaining % seen yet
        return used / self._flown_s, True

    def verdict(self, remaining_pct: float, t_home_s: float, what: str = "the way home") -> BatteryVerdict | None:
        use = self.use_pct_per_s()
        if use is None or not math.isfinite(remaining_pct):
            return None
        rate, measured = use
        needed = rate * t_home_s
        return BatteryVerdict(
            remaining_pct <= needed + self.reserve_pct,
            remaining_pct,
            needed,
            self.reserve_pct,
            rate,
            t_home_s,
            measured,
            what,
        )


class WindMonitor:
    """The wind the autopilot estimates against ``limit_m_s``: none above it for a take-off, and in
    flight a return once it has stayed above it for ``exceed_s`` (a gust alone does not turn the
    delivery back)."""

    def __init__(self, limit_m_s: float, exceed_s: float = 3.0, max_age_s: float = 3.0):
        self.limit_m_s = limit_m_s
        self.exceed_s = exceed_s
        self.max_age_s = max_age_s
        self._above_since: float | None = None

    def fresh(self, time_s: float, wind: Wind | None) -> bool:
        return wind is not None and time_s - wind.time_s <= self.max_age_s

    def take_off_problem(self, time_s: float, wind: Wind | None) -> str | None:
        """Why the wind forbids a take-off now (None: it allows it). Call with a fresh estimate."""
        if wind is None or not self.fresh(time_s, wind):
            return "no fresh wind estimate from the autopilot"
        if wind.speed_m_s > self.limit_m_s:
            return (
                f"wind {wind.speed_m_s:.1f} m/s (the autopilot's estimate) above go_no_go.wind_limit_m_s = "
                f"{self.limit_m_s:g} m/s"
            )
        return None

    def update(self, time_s: float, wind: Wind | None) -> str | None:
        """In flight: the reason to return once the wind has stayed above the limit for ``exceed_s``."""
        if wind is None or not self.fresh(time_s, wind) or wind.speed_m_s <= self.limit_m_s:
            self._above_since = None
            return None
        if self._above_since is None:
            self._above_since = time_s
        if time_s - self._above_since < self.exceed_s:
            return None
        return (
            f"wind {wind.speed_m_s:.1f} m/s (the autopilot's estimate) above go_no_go.wind_limit_m_s = "
            f"{self.limit_m_s:g} m/s for {time_s - self._above_since:.1f} s"
        )


def round_trip_problem(battery: BatteryMonitor, way: WayHome, distance_m: float, battery_pct: float) -> str:
    """Before take-off: why the charge cannot cover out to a pad ``distance_m`` away and back
    ("" if it can, or while the use per second is only measured in flight: judged once airborne)."""
    if battery.use_pct_per_s() is None:
        return ""
    t_leg = time_home_s(way, distance_m, 0.0)
    v = battery.verdict(battery_pct, 2.0 * t_leg, "the round trip")
    if v is not None and v.go_home:
        return f"not enough charge for the round trip: {v.reason()}"
    return ""
