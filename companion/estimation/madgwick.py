"""Madgwick attitude filter, gyroscope + accelerometer (dart eqs 8-13, Madgwick 2010 section 3).

Written with plain Python floats, about ten times faster than numpy on arrays this small, as
the filter runs at the IMU rate (200 Hz, dart sec. 4).

Conventions (docs/architecture.md): the quaternion q = (w, x, y, z) is Hamilton and is R_world_body: it
maps body (FRD) vectors into the world frame, local NED. Euler angles are roll-pitch-yaw ZYX.
The gyroscope gives body rates in rad/s; the accelerometer gives the specific force in m/s^2,
so at rest and level it reads (0, 0, -g) in FRD.

One update, with T the time since the previous sample (dt from the timestamps):

- dart eq 8, gyroscope:  q_g = q_prev + T * q_dot,  q_dot = 0.5 * q_prev (x) (0, w_x, w_y, w_z)
  (dart eq 7 gives the rate quaternion).
- dart eqs 9-12, accelerometer: one gradient-descent step on the cost f of Madgwick [59],
  q_a = q_prev - mu * grad f / |grad f|. The reference is gravity along NED z (dart eq 10,
  g_NED = (0, 0, 0, 1)); f = (world z axis seen in the body) - (measured gravity direction),
  and the measured gravity direction is -a/|a| because an accelerometer measures specific force.
- dart eq 13, fusion: q = gamma * q_a + (1 - gamma) * q_g, then normalised (unit quaternion).

Written out, eq 13 is q = q_prev + (1 - gamma) T q_dot - gamma mu grad f/|grad f|: Madgwick's
familiar beta form with beta = gamma * mu / T, and the gyro term scaled by (1 - gamma). The paper
keeps gamma "quite small" so the scale is close to one; this code implements eq 13 as written.

Step size: dart eq 12 allows a time-dependent mu[kT]. Here mu[kT] = mu * T / T_nominal, which is
the paper's constant mu when samples arrive at the nominal rate and keeps the accelerometer
correction per second the same when the IMU rate differs or jitters.

Yaw is not observable from the accelerometer: it is integrated from the gyroscope only and
drifts (dart Fig. 7 and the paragraph before it).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence
from dataclasses import dataclass

from companion.geometry import euler_to_quat
from companion.param_kinds import MadgwickTable

logger = logging.getLogger(__name__)


#: Madgwick filter parameters (dart eqs 12-13): ``[estimator.madgwick]`` of a Dart file, every
#: key declared once (unit, limits, description) in companion.param_kinds.MadgwickTable
MadgwickConfig = MadgwickTable


@dataclass(frozen=True, slots=True)
class AttitudeEstimate:
    """Attitude from the Madgwick filter: R_world_body (world NED, body FRD), ZYX Euler."""

    time_s: float
    qw: float
    qx: float
    qy: float
    qz: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float


def quat_to_euler_floats(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    """(roll, pitch, yaw) ZYX of a unit quaternion, plain floats (the same formulas as
    geometry.rotmat_to_euler(quat_to_rotmat(q)), inlined for the 200 Hz loop)."""
    roll = math.atan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    s = 2.0 * (w * y - x * z)
    pitch = math.asin(1.0 if s > 1.0 else (-1.0 if s < -1.0 else s))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return roll, pitch, yaw


class MadgwickFilter:
    """Madgwick gyro + accelerometer filter (dart eqs 8-13). Pure and synchronous.

    Counters: ``rejected`` (whole samples dropped: non-finite time or gyro, time not
    increasing), ``accel_rejected`` (samples propagated with the gyro only because the
    accelerometer was non-finite or its norm out of range), ``gaps`` (dt clamped to max_dt_s).
    """

    __slots__ = (
        "_dt_nom",
        "_gamma",
        "_mu",
        "_q0",
        "_q1",
        "_q2",
        "_q3",
        "_t",
        "accel_rejected",
        "accepted",
        "config",
        "gaps",
        "rejected",
    )

    def __init__(
        self,
        config: MadgwickConfig | None = None,
        q_init: Sequence[float] = (1.0, 0.0, 0.0, 0.0),
    ) -> None:
        self.config = config or MadgwickConfig()
        self._mu = self.config.mu
        self._gamma = self.config.gamma
        self._dt_nom = 1.0 / self.config.nominal_rate_hz
        self._q0 = self._q1 = self._q2 = self._q3 = 0.0
        self._t: float | None = None
        self.accepted = 0
        self.rejected = 0
        self.accel_rejected = 0
        self.gaps = 0
        self.reset(q_init)

    # ------------------------------------------------------------------ state
    def reset(self, q: Sequence[float] = (1.0, 0.0, 0.0, 0.0), time_s: float | None = None) -> None:
        """Set the attitude (w, x, y, z), normalised; the next sample starts a new dt."""
        w, x, y, z = (float(v) for v in q)
        n = math.sqrt(w * w + x * x + y * y + z * z)
        if not math.isfinite(n) or n == 0.0:
            raise ValueError(f"cannot reset to quaternion {tuple(q)!r}")
        self._q0, self._q1, self._q2, self._q3 = w / n, x / n, y / n, z / n
        self._t = time_s

    def reset_euler(self, roll_rad: float, pitch_rad: float, yaw_rad: float = 0.0) -> None:
        self.reset(tuple(euler_to_quat(roll_rad, pitch_rad, yaw_rad)))

    def reset_from_accel(self, accel_m_s2: Sequence[float], yaw_rad: float = 0.0) -> bool:
        """Roll and pitch from one accelerometer sample at rest (specific force, FRD)."""
        ax, ay, az = (float(v) for v in accel_m_s2)
        n = math.sqrt(ax * ax + ay * ay + az * az)
        if not (math.isfinite(n) and self.config.accel_min_m_s2 <= n <= self.config.accel_max_m_s2):
            return False
        roll = math.atan2(-ay, -az)
        pitch = math.atan2(ax, math.sqrt(ay * ay + az * az))
        self.reset_euler(roll, pitch, yaw_rad)
        return True

    @property
    def time_s(self) -> float | None:
        return self._t

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        return (self._q0, self._q1, self._q2, self._q3)

    def euler(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) in rad, ZYX, of R_world_body."""
        return quat_to_euler_floats(self._q0, self._q1, self._q2, self._q3)

    def estimate(self) -> AttitudeEstimate:
        r, p, y = self.euler()
        return AttitudeEstimate(
            time_s=self._t if self._t is not None else float("nan"),
            qw=self._q0,
            qx=self._q1,
            qy=self._q2,
            qz=self._q3,
            roll_rad=r,
            pitch_rad=p,
            yaw_rad=y,
        )

    # ----------------------------------------------------------------- update
    def update(
        self,
        time_s: float,
        gyro_rad_s: Sequence[float],
        accel_m_s2: Sequence[float],
    ) -> bool:
        """Fuse one IMU sample measured at ``time_s``. Returns False when it was rejected.

        The first accepted sample only starts the clock (dt unknown).
        """
        gx, gy, gz = gyro_rad_s
        t_prev = self._t
        # NaN-safe checks: every comparison with NaN is False
        if not (-1e300 < time_s < 1e300 and -1e3 < gx < 1e3 and -1e3 < gy < 1e3 and -1e3 < gz < 1e3):
            self.rejected += 1
            return False
        if t_prev is None:
            self._t = time_s
            self.accepted += 1
            return True
        dt = time_s - t_prev
        if not dt > 0.0:
            self.rejected += 1
            return False
        if dt > self.config.max_dt_s:
            dt = self.config.max_dt_s
            self.gaps += 1
        self._t = time_s
        self.accepted += 1

        q0, q1, q2, q3 = self._q0, self._q1, self._q2, self._q3
        # dart eqs 7-8: q_dot = 0.5 q (x) (0, w);  q_g = q + T q_dot
        h = 0.5 * dt
        d0 = h * (-q1 * gx - q2 * gy - q3 * gz)
        d1 = h * (q0 * gx + q2 * gz - q3 * gy)
        d2 = h * (q0 * gy - q1 * gz + q3 * gx)
        d3 = h * (q0 * gz + q1 * gy - q2 * gx)

        n0, n1, n2, n3 = self._fuse_accel((q0, q1, q2, q3), (d0, d1, d2, d3), accel_m_s2, dt)
        n = math.sqrt(n0 * n0 + n1 * n1 + n2 * n2 + n3 * n3)
        if not n > 1e-9 or n == math.inf:
            # cannot happen with finite, range-checked inputs; keep the previous attitude
            self.rejected += 1
            self.accepted -= 1
            logger.warning("madgwick: degenerate quaternion norm %r, sample dropped", n)
            return False
        inv_n = 1.0 / n
        self._q0, self._q1, self._q2, self._q3 = n0 * inv_n, n1 * inv_n, n2 * inv_n, n3 * inv_n
        return True

    def _fuse_accel(
        self,
        q: tuple[float, float, float, float],
        d: tuple[float, float, float, float],
        accel_m_s2: Sequence[float],
        dt: float,
    ) -> tuple[float, float, float, float]:
        """The un-normalised new quaternion from the attitude q, the gyro's increment d = T q_dot
        and the accelerometer (dart eqs 10-13); gyro only when the specific force is out of range."""
        q0, q1, q2, q3 = q
        d0, d1, d2, d3 = d
        ax, ay, az = accel_m_s2
        an2 = ax * ax + ay * ay + az * az
        amin = self.config.accel_min_m_s2
        amax = self.config.accel_max_m_s2
        if not (amin * amin <= an2 <= amax * amax):  # also False for NaN
            self.accel_rejected += 1
            return q0 + d0, q1 + d1, q2 + d2, q3 + d3  # gyro only (gamma = 0)
        # measured gravity direction in the body frame: -a/|a| (specific force is -g)
        inv = -1.0 / math.sqrt(an2)
        mx, my, mz = ax * inv, ay * inv, az * inv
        # dart eq 11: f = (NED z axis in body, the 3rd row of R_world_body) - measured
        f1 = 2.0 * (q1 * q3 - q0 * q2) - mx
        f2 = 2.0 * (q0 * q1 + q2 * q3) - my
        f3 = 1.0 - 2.0 * (q1 * q1 + q2 * q2) - mz
        # grad f = J^T f (Madgwick [59] eq 20 with the NED gravity reference, dart eq 10)
        s0 = -2.0 * q2 * f1 + 2.0 * q1 * f2
        s1 = 2.0 * q3 * f1 + 2.0 * q0 * f2 - 4.0 * q1 * f3
        s2 = -2.0 * q0 * f1 + 2.0 * q3 * f2 - 4.0 * q2 * f3
        s3 = 2.0 * q1 * f1 + 2.0 * q2 * f2
        sn = math.sqrt(s0 * s0 + s1 * s1 + s2 * s2 + s3 * s3)
        g = self._gamma
        og = 1.0 - g
        if sn > 1e-12:
            # dart eq 12: q_a = q - mu[kT] grad f / |grad f|, mu[kT] = mu T / T_nom
            k = self._mu * (dt / self._dt_nom) / sn
            # dart eq 13: q = gamma q_a + (1 - gamma) q_g
            gk = g * k
            return (q0 + og * d0 - gk * s0, q1 + og * d1 - gk * s1, q2 + og * d2 - gk * s2, q3 + og * d3 - gk * s3)
        # already at the minimum: q_a = q_prev
        return q0 + og * d0, q1 + og * d1, q2 + og * d2, q3 + og * d3
