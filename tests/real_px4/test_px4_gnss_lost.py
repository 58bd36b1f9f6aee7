"""GNSS lost near the pad on a real PX4 v1.16 SIH (docs/external-nav.md, the PX4 section): the
sitl_short delivery, pad displaced 0.64 m from its configured position, EKF2_EV_CTRL = 1 from boot;
SIH's GPS is stopped (``sensor_gps_sim stop`` over the MAVLink shell) when the true vehicle comes
down through 3 m near the pad. The companion finds the fix gone and keeps streaming its fused pose
(ODOMETRY), which EKF2 navigates on; the vehicle lands on the pad and releases on the locked pad,
with no PX4 failsafe. ~40 s of flight after a ~3 s boot."""

from __future__ import annotations

import math

import pytest

from companion_lab.gnss_loss_px4 import fly_px4_gnss_loss

pytestmark = pytest.mark.firmware

# PX4 SIH's own estimate wanders +-0.3 m (its GPS LAND: 40 cm, docs): issue 57's 10 cm is ArduPilot's
GOAL_M = 0.30


async def test_px4_gnss_lost_at_3_m_lands_and_releases_on_the_pad(px4_root, tmp_path):
    f = await fly_px4_gnss_loss(px4_root, tmp_path, loss_height_m=3.0)
    r = f.result
    print(
        f"\nPX4 SIH GPS off at {f.loss_height_m:.2f} m; lost seen after {f.gnss_lost_seen_s:.2f} s; {f.poses_sent} "
        f"poses; pad error on truth {r.pad_landing_error_m * 100:.1f} cm; {f.flight_wall_s:.1f} s of flight; "
        f"PX4 modes after the loss {f.autopilot_modes}\n" + "\n".join(f.events)
    )
    assert 2.0 <= f.loss_height_m <= 3.0, f.loss_height_m  # the GPS went off in the descent
    assert math.isfinite(f.gnss_lost_seen_s) and f.gnss_lost_seen_s < 3.0, f.events  # GPS_RAW_INT: fix type 0
    assert any("EKF2 external vision" in e for e in f.events), f.events
    # no PX4 failsafe took the vehicle: OFFBOARD to the end, or PX4's LAND the companion asked for
    # when the descent outlasted its touchdown timeout (a loaded machine: CI, 2026-12-03); a mode
    # the companion did not ask for would have ended the delivery ("pilot took over")
    handed_over = any("handing the last metres to the autopilot's LAND" in e for e in f.events)
    others = [m for m in f.autopilot_modes if "OFFBOARD" not in m]
    assert all("AUTO.LAND" in m for m in others) and (handed_over or not others), (f.autopilot_modes, f.events)
    assert r.delivered and r.releases == 1, r.failure
    assert r.pad_landing_error_m <= GOAL_M, r.pad_landing_error_m
    assert r.markers_used > 0 and f.poses_sent > 0
