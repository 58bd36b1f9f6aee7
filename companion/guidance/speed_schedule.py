"""The reference speed v_r of the vector field limited by what the autopilot can do.

Not in the papers. The field (delivery eq 19) asks for v_i in sector S_i and turns the velocity
through the arcs of radius r at once; an autopilot follows a velocity setpoint within its own
acceleration limits (ArduCopter GUIDED: WPNAV_ACCEL = 2.5 m/s^2 horizontally, WPNAV_ACCEL_Z =
1 m/s^2 vertically; PX4: MPC_ACC_HOR, MPC_ACC_UP_MAX / MPC_ACC_DOWN_MAX), so it overshoots: out
of the climb above the cruise height and past the turn into each descent (metres on ArduCopter
SITL with r = 2 m and a 5 m/s cruise). Two limits keep the speed feasible:

- on an arc the centripetal acceleration v^2 / r must stay within the smaller limit (the velocity
  turns between vertical and horizontal): v <= sqrt(a r);
- before the end of a sector the vehicle must be able to slow to the next sector's speed with the
  limit that applies (a_xy along the cruise, a_z along the climb and the descents, the smaller
  on an arc): v <= sqrt(v_next^2 + 2 a s), s the distance left in the sector along the path.

The result is a scale on v_r in (0, 1] (the field's ``speed_scale``), a function of position only,
like the field itself.
"""

from __future__ import annotations

import math

from companion.guidance.path import DeliveryPath


def sector_remaining_m(
    path: DeliveryPath, x: float, z: float, sector: int, s: int, z_end: tuple[float, float]
) -> float:
    """Distance left along the path in ``sector`` travelling in direction ``s`` (+1 out, -1 back)
    from (x, z) in F_I. ``z_end``: where the last sector hands over to the landing, (height of
    the pad-side end for s = +1, of the home-side end for s = -1)."""
    h, r, d = path.h, path.r, path.d
    if sector in (2, 4):
        cx = -d + r if sector == 2 else -r
        theta = math.atan2(z - (h - r), x - cx)  # s2: pi (start) .. pi/2; s4: pi/2 .. 0
        theta = min(max(theta, 0.0 if sector == 4 else math.pi / 2.0), math.pi / 2.0 if sector == 4 else math.pi)
        if sector == 2:
            left = theta - math.pi / 2.0 if s == 1 else math.pi - theta
        else:
            left = theta if s == 1 else math.pi / 2.0 - theta
        return r * left
    if sector == 3:
        return (-r - x) if s == 1 else (x - (-d + r))
    if sector == 1:
        return (h - r) - z if s == 1 else z - z_end[1]
    return z - z_end[0] if s == 1 else (h - r) - z  # sector 5


def speed_scale(
    path: DeliveryPath,
    x: float,
    z: float,
    sector: int,
    s: int,
    speeds_m_s: tuple[float, ...],
    accel_xy_m_s2: float,
    accel_z_m_s2: float,
    end_speed_m_s: float,
    z_end: tuple[float, float] = (0.0, 0.0),
) -> float:
    """Scale in (0, 1] on sector ``sector``'s speed so that the vehicle stays within the
    autopilot's acceleration limits (module doc). ``end_speed_m_s``: the speed the last sector
    hands over at (the landing). ``accel_*`` <= 0 turns that limit off."""
    if accel_xy_m_s2 <= 0.0 and accel_z_m_s2 <= 0.0:
        return 1.0
    inf = math.inf
    a_xy = accel_xy_m_s2 if accel_xy_m_s2 > 0.0 else inf
    a_z = accel_z_m_s2 if accel_z_m_s2 > 0.0 else inf
    a_arc = min(a_xy, a_z)

    def cap(k: int) -> float:  # the sector's own speed, capped on the arcs
        v = speeds_m_s[k - 1]
        return min(v, math.sqrt(a_arc * path.r)) if k in (2, 4) else v

    v_k = speeds_m_s[sector - 1]
    nxt = sector + s
    v_next = cap(nxt) if 1 <= nxt <= 5 else end_speed_m_s
    a = a_xy if sector == 3 else (a_arc if sector in (2, 4) else a_z)
    left = max(0.0, sector_remaining_m(path, x, z, sector, s, z_end))
    v = min(cap(sector), math.sqrt(v_next * v_next + 2.0 * a * left) if math.isfinite(a) else inf)
    return max(1e-3, min(1.0, v / v_k))
