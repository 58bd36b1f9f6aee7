"""The truth feed's degE7 dequantiser (companion_firmware.truth_feed): the firmware's truth messages
carry latitude and longitude as degE7 integers truncated toward zero (1.1 cm steps)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.geometry.earth import GeoPoint, LocalTangentPlane
from companion_firmware.truth_feed import DegE7Dequantiser, MavlinkTruth, _mid_cm_s

CMAC = GeoPoint(-35.363261, 149.165230, 584.0)  # ArduPilot SITL's home: negative latitude


def test_the_step_each_integer_allows_follows_truncation_toward_zero():
    # C's (int32_t)(x): 12.7 -> 12, -12.7 -> -12, 0.4 and -0.4 -> 0
    assert DegE7Dequantiser.bounds(12) == (12.0, 13.0)
    assert DegE7Dequantiser.bounds(-12) == (-13.0, -12.0)
    assert DegE7Dequantiser.bounds(0) == (-1.0, 1.0)
    for x in (12.7, -12.7, 0.4, -0.4, 5.0, -5.0):
        lo, hi = DegE7Dequantiser.bounds(int(x))
        assert lo <= x <= hi


def test_first_value_is_the_middle_of_the_step_and_a_resting_vehicle_stays_inside_it():
    d = DegE7Dequantiser()
    assert d.update(-353632610, math.nan) == -353632610.5
    for _ in range(100):
        assert -353632611.0 <= d.update(-353632610, 0.01) <= -353632610.0
    assert d.update(-353632610, 0.0) == -353632610.0  # drifted to the edge, held there


def _track(seed: int, n: int = 3000, dt: float = 0.02) -> tuple[np.ndarray, np.ndarray]:
    """A slow wandering position (degE7 units, ~0.2 step / sample at most) and its velocity."""
    rng = np.random.default_rng(seed)
    v = np.cumsum(rng.normal(0.0, 0.02, n))  # steps per second, wandering through zero
    v = 8.0 * np.tanh(v / 8.0)
    x = -353632610.0 + np.cumsum(v * dt)
    return x, v


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_dequantised_value_is_far_closer_to_the_truth_than_the_integer(seed):
    x, v = _track(seed)
    dt = 0.02
    d = DegE7Dequantiser()
    out = []
    for k in range(len(x)):
        step = math.nan if k == 0 else 0.5 * (v[k - 1] + v[k]) * dt
        out.append(d.update(int(x[k]), step))
    q_err = np.array([int(a) for a in x]) - x  # the integer read as it is: 0.58 step RMS
    d_err = np.array(out) - x
    assert np.all(np.abs(d_err) <= 1.0)  # never outside the step the integer allows
    q_rms, d_rms = math.sqrt(np.mean(q_err**2)), math.sqrt(np.mean(d_err[200:] ** 2))
    assert q_rms > 0.5
    assert d_rms < 0.2 * q_rms


def test_feed_recovers_positions_inside_the_degE7_step():
    """A vehicle moving at a few cm/s seen through SIM_STATE's truncated integers: the feed's
    north / east follow the true ones to a few millimetres (the integers alone: ~0.6 cm RMS)."""
    ltp = LocalTangentPlane(CMAC)
    feed = MavlinkTruth("udpout:127.0.0.1:9", origin=CMAC)
    rng = np.random.default_rng(7)
    dt, n = 0.02, 2000
    vn = 0.05 * np.sin(np.arange(n) * dt * 0.9) + rng.normal(0.0, 0.002, n)
    ve = 0.04 * np.cos(np.arange(n) * dt * 0.6)
    pn, pe = 0.3 + np.cumsum(vn * dt), -0.2 + np.cumsum(ve * dt)
    err_feed, err_int = [], []
    q = [1.0, 0.0, 0.0, 0.0]
    for k in range(n):
        g = ltp.to_geo(float(pn[k]), float(pe[k]), -1.0)
        lat_i, lon_i = int(g.lat_deg * 1e7), int(g.lon_deg * 1e7)
        feed.store_sample(q, (lat_i, lon_i, g.alt_amsl_m), (float(vn[k]), float(ve[k]), 0.0), 100.0 + k * dt)
        if k >= 250:
            err_feed.append(math.hypot(feed.pn - pn[k], feed.pe - pe[k]))
            qn, qe, _ = ltp.to_ned(GeoPoint(lat_i * 1e-7, lon_i * 1e-7, g.alt_amsl_m))
            err_int.append(math.hypot(qn - pn[k], qe - pe[k]))
    assert feed.pd == pytest.approx(-1.0, abs=1e-6)
    rms_feed = math.sqrt(np.mean(np.square(err_feed)))
    rms_int = math.sqrt(np.mean(np.square(err_int)))
    assert rms_int > 0.005
    assert rms_feed < 0.25 * rms_int
    assert max(err_feed) < 0.015  # within the step, in both axes


def test_a_gap_in_the_samples_starts_afresh_in_the_middle_of_the_step():
    feed = MavlinkTruth("udpout:127.0.0.1:9", origin=CMAC)
    q = [1.0, 0.0, 0.0, 0.0]
    lat_i, lon_i = int(CMAC.lat_deg * 1e7), int(CMAC.lon_deg * 1e7)
    feed.store_sample(q, (lat_i, lon_i, 584.0), (0.0, 0.0, 0.0), 10.0)
    feed.store_sample(q, (lat_i, lon_i, 584.0), (5.0, 0.0, 0.0), 10.02)  # 5 m/s: clamped to the step's edge
    edge = feed.pn
    feed.store_sample(q, (lat_i, lon_i, 584.0), (5.0, 0.0, 0.0), 11.0)  # 0.98 s later: not integrated
    mid = LocalTangentPlane(CMAC).to_ned(GeoPoint((lat_i - 0.5) * 1e-7, (lon_i + 0.5) * 1e-7, 584.0))
    assert feed.pn == pytest.approx(mid[0], abs=1e-6) and feed.pe == pytest.approx(mid[1], abs=1e-6)
    assert edge == pytest.approx(
        LocalTangentPlane(CMAC).to_ned(GeoPoint(lat_i * 1e-7, CMAC.lon_deg, 584.0))[0], abs=1e-6
    )


def test_hil_velocity_integers_read_as_the_middle_of_their_step():
    # PX4 sends int16(lpos.vx * 1e2f): 3.7 cm/s -> 3, -3.7 -> -3; the middle of [3, 4) is 3.5
    assert _mid_cm_s(3) == pytest.approx(0.035)
    assert _mid_cm_s(-3) == pytest.approx(-0.035)
    assert _mid_cm_s(0) == 0.0
