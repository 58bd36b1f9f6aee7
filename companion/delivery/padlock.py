"""No release off the pad: what a pad lock is, and the search pattern flown when there is none.

Pure. The shell measures the lock each guidance tick (:func:`measure_pad_lock`, from the landing
fusion); the mission judges it (:func:`judge_pad_lock`) at the approach height, in the final
descent and at touchdown, and flies the policy's steps (docs/delivery-policy.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.config import PadLockPolicyConfig


@dataclass(frozen=True, slots=True)
class PadLock:
    """What the pad's lock is made of at ``time_s``: the age of the newest accepted camera or UWB
    observation of the pad (inf: none yet) and the EKF's horizontal position 1-sigma (largest
    axis of the north-east covariance, m). ``sensors``: a camera or UWB is fitted and fused (no
    lock is possible without one)."""

    time_s: float
    observation_age_s: float
    horizontal_sigma_m: float
    sensors: bool = True


NO_SENSORS = PadLock(0.0, math.inf, math.inf, sensors=False)

# pad data older than this no longer holds the fused position (the velocity-bias correction against
# it) nor counts as the pad being in sight (the final descent's hold to align)
PAD_DATA_FRESH_S = 0.5


def pad_in_sight(lock: PadLock | None) -> bool:
    """A camera or UWB observation of the pad within PAD_DATA_FRESH_S."""
    return lock is not None and lock.sensors and lock.observation_age_s <= PAD_DATA_FRESH_S


def horizontal_sigma_m(P: np.ndarray) -> float:
    """Largest 1-sigma of the north-east position block of a covariance (square root of its largest
    eigenvalue, in closed form for the symmetric 2 x 2 block)."""
    a, b, d = float(P[0, 0]), float(P[0, 1]), float(P[1, 1])
    if not (math.isfinite(a) and math.isfinite(b) and math.isfinite(d)):
        return math.inf
    half_tr = 0.5 * (a + d)
    lam = half_tr + math.sqrt(max(0.0, 0.25 * (a - d) ** 2 + b * b))
    return math.sqrt(max(0.0, lam))


def measure_pad_lock(fusion: object | None, now_s: float) -> PadLock:
    """The lock of a :class:`companion.delivery.fusion.LandingFusion` (None: no pad sensors)."""
    if fusion is None:
        return NO_SENSORS
    age = float(fusion.pad_data_age_s(now_s))  # type: ignore[attr-defined]
    ekf = fusion.ekf  # type: ignore[attr-defined]
    sigma = horizontal_sigma_m(ekf.P) if ekf.initialized else math.inf
    return PadLock(now_s, age, sigma)


def judge_pad_lock(lock: PadLock | None, cfg: PadLockPolicyConfig) -> tuple[bool, str]:
    """(locked, why): why names what is missing, or what the lock is made of."""
    if lock is None or not lock.sensors:
        return False, "no pad sensor (landing.fusion = false, or neither camera nor UWB fitted)"
    age, sigma = lock.observation_age_s, lock.horizontal_sigma_m
    seen = "no camera or UWB observation of the pad yet" if math.isinf(age) else f"last pad observation {age:.2f} s old"
    if not age < cfg.max_observation_age_s:
        return False, f"{seen} (limit {cfg.max_observation_age_s} s)"
    if not sigma < cfg.max_horizontal_sigma_m:
        return False, f"EKF horizontal 1-sigma {sigma:.2f} m (limit {cfg.max_horizontal_sigma_m} m)"
    return True, f"{seen}, EKF horizontal 1-sigma {sigma:.3f} m"


def expanding_square(radius_m: float, spacing_m: float) -> list[tuple[float, float]]:
    """Corners of an expanding square around the origin (north, east offsets, m): legs of 1, 1, 2,
    2, 3, 3, ... times ``spacing_m``, turning clockwise, until the next corner would lie farther
    than ``radius_m`` from the origin; that last leg is cut at the radius. Starts at the origin."""
    if radius_m <= 0.0:
        return [(0.0, 0.0)]
    if spacing_m <= 0.0:
        raise ValueError(f"spacing_m = {spacing_m}: must be > 0")
    dirs = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))  # north, east, south, west
    pts = [(0.0, 0.0)]
    n = e = 0.0
    k = 0
    while True:
        leg = spacing_m * (k // 2 + 1)
        dn, de = dirs[k % 4]
        nn, ne = n + dn * leg, e + de * leg
        if math.hypot(nn, ne) > radius_m:
            # the leg leaves the circle: cut it where it does (it runs along one axis from inside)
            across = e if dn else n
            if abs(across) < radius_m:
                x = math.copysign(math.sqrt(radius_m**2 - across**2), dn or de)
                pts.append((x, e) if dn else (n, x))
            return pts
        n, e = nn, ne
        pts.append((n, e))
        k += 1
