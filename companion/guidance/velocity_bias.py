"""The autopilot's velocity estimate checked against its own position estimate.

An autopilot's velocity loop drives *its velocity estimate* to our setpoint. When that estimate is
biased, the vehicle moves at setpoint + bias and the vector field (delivery eq 4-8, a proportional
law on the distance to the path) settles at distance = bias / convergence gain. PX4 v1.16 SIH
does this (docs/simulation.md): its reported velocity stays 0.3-0.5 m/s away from the rate of its
own position estimate for seconds, enough to put the descent at home well beside the path.

The position estimate follows GPS (it cannot drift away from it), so its rate is the vehicle's real
velocity, noisy but unbiased. The bias is estimated as the low-passed difference between that rate
and the reported velocity over the same interval (trapezoid mean of the two reported samples, so a
constant acceleration gives no bias), and subtracted from the setpoint: the velocity loop then
brings the estimate to setpoint - bias and the vehicle to the setpoint. Not in the papers.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import replace
from typing import Protocol

from companion.guidance.setpoint import VelocitySetpoint


class PositionNed(Protocol):
    """What the estimator reads of the autopilot's local position (autopilot.types.PositionNed:
    MAVLink LOCAL_POSITION_NED; guidance sits below the autopilot layer, so only its shape here)."""

    @property
    def time_s(self) -> float: ...
    @property
    def north_m(self) -> float: ...
    @property
    def east_m(self) -> float: ...
    @property
    def down_m(self) -> float: ...
    @property
    def north_m_s(self) -> float: ...
    @property
    def east_m_s(self) -> float: ...
    @property
    def down_m_s(self) -> float: ...


# the landing fusion's position while it has pad data: (time, NED position), None without
FusedPosition = Callable[[], "tuple[float, tuple[float, float, float]] | None"]

MAX_GAP_S = 1.0  # a longer gap between samples (link loss) restarts the estimate


class VelocityBiasEstimator:
    """First-order low-pass (time constant ``tau_s``) of rate(position) - mean(reported velocity)."""

    def __init__(self, tau_s: float, max_m_s: float):
        if not (tau_s > 0.0 and math.isfinite(tau_s)):
            raise ValueError(f"tau_s = {tau_s!r}: expected a positive number of seconds")
        if not (max_m_s >= 0.0 and math.isfinite(max_m_s)):
            raise ValueError(f"max_m_s = {max_m_s!r}: expected a non-negative speed in m/s")
        self.tau_s = tau_s
        self.max_m_s = max_m_s
        self.bias_ned_m_s = (0.0, 0.0, 0.0)
        self.samples = 0
        self._last: PositionNed | None = None
        self._elapsed_s = 0.0  # low-pass settling: corrections start once it has seen tau_s of data

    def update(self, s: PositionNed | None) -> tuple[float, float, float]:
        """Feed the latest position sample (the same sample again is ignored); the bias in NED."""
        if s is None or (self._last is not None and s.time_s == self._last.time_s):
            return self.bias_ned_m_s
        last, self._last = self._last, s
        if last is None:
            return self.bias_ned_m_s
        dt = s.time_s - last.time_s
        if not (0.0 < dt <= MAX_GAP_S):
            self._elapsed_s = 0.0
            self.bias_ned_m_s = (0.0, 0.0, 0.0)
            return self.bias_ned_m_s
        rate = ((s.north_m - last.north_m) / dt, (s.east_m - last.east_m) / dt, (s.down_m - last.down_m) / dt)
        reported = (
            0.5 * (s.north_m_s + last.north_m_s),
            0.5 * (s.east_m_s + last.east_m_s),
            0.5 * (s.down_m_s + last.down_m_s),
        )
        a = 1.0 - math.exp(-dt / self.tau_s)  # exact discretisation of the first-order lag
        self.bias_ned_m_s = tuple(
            b + a * ((r - v) - b) for b, r, v in zip(self.bias_ned_m_s, rate, reported, strict=True)
        )  # type: ignore[assignment]
        self._elapsed_s += dt
        self.samples += 1
        return self.bias_ned_m_s

    @property
    def settled(self) -> bool:
        return self._elapsed_s >= self.tau_s

    def applied_bias(self) -> tuple[float, float, float]:
        """The bias corrections use: zero until settled, its magnitude held to max_m_s."""
        if not self.settled:
            return (0.0, 0.0, 0.0)
        bn, be, bd = self.bias_ned_m_s
        mag = math.sqrt(bn * bn + be * be + bd * bd)
        k = 1.0 if mag <= self.max_m_s else self.max_m_s / mag
        return (k * bn, k * be, k * bd)

    def correct(self, sp: VelocitySetpoint) -> VelocitySetpoint:
        """The setpoint to send so that the vehicle (not the autopilot's estimate) flies ``sp``."""
        bn, be, bd = self.applied_bias()
        return replace(sp, north_m_s=sp.north_m_s - bn, east_m_s=sp.east_m_s - be, down_m_s=sp.down_m_s - bd)


class _Sample:
    """A PositionNed-shaped sample: the fused position with the autopilot's reported velocity."""

    __slots__ = ("down_m", "down_m_s", "east_m", "east_m_s", "north_m", "north_m_s", "time_s")

    def __init__(self, t: float, p: tuple[float, float, float], v: tuple[float, float, float]):
        self.time_s = t
        self.north_m, self.east_m, self.down_m = p
        self.north_m_s, self.east_m_s, self.down_m_s = v


class VelocityBiasCorrection:
    """The bias the setpoints and the landing EKF's velocity input are corrected by ([mission]
    velocity_bias_tau_s / velocity_bias_source, [landing] ekf_velocity_bias_tau_s).

    ``source = "autopilot"``: the bias against the autopilot's own position. ``"fusion"``: once the
    landing fusion has pad data, against the fused (camera / UWB) position instead, in a second
    estimator started then. The autopilot's position is held to GPS only loosely: PX4 v1.16 SIH's
    drifts with its biased velocity, up to 20 cm from the truth within 3 s near the ground, so
    its rate shows only part of the bias; the fused position is held by the pad itself.
    """

    def __init__(self, tau_s: float, max_m_s: float, source: str = "autopilot"):
        if source not in ("autopilot", "fusion"):
            raise ValueError(f"source = {source!r}: expected 'autopilot' or 'fusion'")
        self.autopilot = VelocityBiasEstimator(tau_s, max_m_s)
        self.fused = VelocityBiasEstimator(tau_s, max_m_s) if source == "fusion" else None
        self._fused_fresh = False  # the last update brought a fused position

    def update(self, s: PositionNed | None, fused_position: FusedPosition | None = None) -> tuple[float, float, float]:
        """Feed the autopilot's newest position sample; with source "fusion", ``fused_position``
        gives the fused estimate (its time, NED position; None: no pad data), asked for only
        then. The bias in use."""
        self.autopilot.update(s)
        est, fused = self.fused, None
        if est is not None and fused_position is not None and s is not None:
            fused = fused_position()
            if fused is not None:
                v = (s.north_m_s, s.east_m_s, s.down_m_s)
                est.update(_Sample(fused[0], fused[1], v))  # after a gap > MAX_GAP_S it starts again
        self._fused_fresh = fused is not None
        return self.active.applied_bias()

    @property
    def active(self) -> VelocityBiasEstimator:
        """The fused estimator while it is fed and settled, else the autopilot's."""
        if self.fused is not None and self._fused_fresh and self.fused.settled:
            return self.fused
        return self.autopilot

    def correct(self, sp: VelocitySetpoint) -> VelocitySetpoint:
        return self.active.correct(sp)
