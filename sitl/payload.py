"""The vehicle's payload: the release (a servo's ``release_delay_s`` after the command) and, where
``[sim.winch]`` fits one, the winch with the parcel swinging on its line (sitl/winch.py).

:class:`SimPayload` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds them; the
vehicle keeps ``payload_released`` (its status) and ``winch`` / ``parcel`` (read by the simulated
autopilots' WINCH_STATUS and the scoring).
"""

from __future__ import annotations

import math

from companion_sitl.params import SimWinchConfig
from companion_sitl.winch import ParcelOnLine, SimWinch

PARCEL_STEP_HZ = 1000.0  # the parcel pendulum's least integration rate (sitl/winch.py)

Vec3 = tuple[float, float, float]


class SimPayload:
    """``release_at``: when the commanded release happens (None: none pending); ``winch`` and
    ``parcel`` where one is fitted (None otherwise)."""

    def __init__(self, wc: SimWinchConfig, position: Vec3) -> None:
        self.release_at: float | None = None
        self.winch: SimWinch | None = None
        self.parcel: ParcelOnLine | None = None
        self.load_cell, self.parcel_mass_kg, self.hook_fails = wc.load_cell, wc.parcel_mass_kg, wc.hook_fails
        if wc.fitted:
            self.winch = SimWinch(wc.rate_max_m_s, wc.pos_p, stuck=wc.stuck, reel_in_jams=wc.reel_in_jams)
            self.parcel = ParcelOnLine(wc.parcel_drag_1_s, wc.snag_height_m)
            self.prev = position  # the vehicle's position at the last step (the line's top)

    def line_tension_kg(self) -> float:
        """What the winch's load cell reads (kg): the parcel's mass while the line holds it, else 0;
        NaN without a load cell (AP_Winch_PWM sends NaN)."""
        if not self.load_cell or self.parcel is None:
            return math.nan
        return self.parcel_mass_kg if self.parcel.taut else 0.0

    def command_release(self, t: float, delay_s: float, released: bool) -> None:
        """The release command at ``t``: it happens ``delay_s`` later (once)."""
        if self.release_at is None and not released:
            self.release_at = t + delay_s

    def release_due(self, t: float) -> bool:
        """The pending release happens now (``t``): True once."""
        if self.release_at is not None and t >= self.release_at:
            self.release_at = None
            return True
        return False

    def step_winch(self, t: float, dt: float, position: Vec3, velocity: Vec3, wind: Vec3, released: bool) -> None:
        """The drum, then the parcel on its line under the vehicle's path over the last ``dt``."""
        w, par = self.winch, self.parcel
        assert w is not None and par is not None
        l0 = w.length_m
        w.step(dt)
        l1 = w.length_m
        if released and not par.released and not self.hook_fails:
            par.release()
        # the pendulum at >= 1 kHz: its numerical damping is then below 1 % of the swing per period
        n = max(1, math.ceil(dt * PARCEL_STEP_HZ - 1e-9))
        h = dt / n
        a0 = self.prev
        a1 = position
        for k in range(1, n + 1):
            f = k / n
            a = (a0[0] + f * (a1[0] - a0[0]), a0[1] + f * (a1[1] - a0[1]), a0[2] + f * (a1[2] - a0[2]))
            par.step(t - dt + k * h, h, a, velocity, l0 + f * (l1 - l0), wind)
        self.prev = a1
