"""The GPS-error probe's frequency response (lab/gps_step_probe.py): the fit on synthetic rows, and
the arducopter-sitl profile against what the real SITL answered."""

from __future__ import annotations

import math

import pytest

from companion_lab.gps_step_probe import SINE_SETTLE_CYCLES, hover_figures, profile_sine_response, sine_response

# ArduCopter 4.7 SITL hovering in GUIDED, a 0.1 m SIM_GPS1_GLTCH_X sine north (gps_step_probe
# --sine-hz, 2026-11-28): the truth's move against the GPS error's opposite, gain and phase lag
FIRMWARE_RESPONSE = {  # Hz: (gain, lag deg)
    0.05: (1.051, 28.3),
    0.1: (1.176, 79.5),
    0.16: (0.884, 139.1),
    0.2: (0.556, 171.3),
    0.3: (0.250, 235.5),
}
# the same, the wind from the north 3 m/s plus a 1 m/s sine at 6 m (--wind-mean-m-s 3): the truth's
# move north per m/s of air moving north (m per m/s, lag deg), with the SITL's own 0.2 s low-pass
# on the wind it was sent (SIM_WIND_TC) taken off, which the profile's vehicle does not have
FIRMWARE_WIND_RESPONSE = {
    0.05: (0.0275, -53.7),
    0.1: (0.0439, -1.8),
    0.2: (0.0385, 57.3),
    0.35: (0.0223, 106.6),
    0.5: (0.0101, 118.2),
}
# a 0.05 m/s sine of the velocity setpoint north at 3 m (--velocity --alt-m 3): the truth's
# velocity against it (gain, lag deg; the lag includes the probe's link, up to ~0.1 s)
FIRMWARE_VELOCITY_RESPONSE = {
    0.1: (1.11, 18.4),
    0.2: (0.90, 46.0),
    0.35: (0.76, 62.1),
    0.5: (0.66, 83.9),
    0.8: (0.41, 119.8),
    1.2: (0.24, 152.9),
}


def test_sine_response_recovers_a_known_gain_and_lag_under_a_drift():
    f, lag = 0.2, math.radians(100.0)
    rows = []
    for k in range(int((SINE_SETTLE_CYCLES + 8) / f / 0.05)):
        t = 3.0 + 0.05 * k
        err = 0.1 * math.sin(2 * math.pi * f * t)
        truth = -0.7 * 0.1 * math.sin(2 * math.pi * f * t - lag) + 0.02 + 0.003 * t  # and a slow drift
        est = 0.3 * 0.1 * math.sin(2 * math.pi * f * t)  # in phase with the error: lag 180 deg
        rows.append((t, f, err, truth, est))
    rows += [(0.05 * k, 0.0, 0.0, 0.0, 0.0) for k in range(60)]  # the hover before: not fitted
    (r,) = sine_response(rows)
    assert r["freq_hz"] == f
    assert r["gain"] == pytest.approx(0.7, abs=1e-6)
    assert r["phase_lag_deg"] == pytest.approx(100.0, abs=1e-4)
    assert r["estimate_gain"] == pytest.approx(0.3, abs=1e-6)
    # the same rows as a wind probe's (the truth against the input itself): half a turn apart
    (w,) = sine_response(rows, input_sign=1.0)
    assert w["gain"] == pytest.approx(0.7, abs=1e-6)
    assert w["phase_lag_deg"] == pytest.approx(100.0 - 180.0, abs=1e-4)
    with pytest.raises(ValueError, match=r"0\.2 Hz: 0 samples after the transient"):
        sine_response([x for x in rows if x[0] < 3.0 + SINE_SETTLE_CYCLES / f])


def test_the_arducopter_profile_answers_a_gps_sine_as_the_firmware_did():
    """The profile's vehicle carries the GPS error's slow part as ArduCopter's GUIDED does,
    resonance at 0.1 Hz included; the ideal vehicle does not move."""
    freqs = sorted(FIRMWARE_RESPONSE)
    for r in profile_sine_response("arducopter-sitl", freqs):
        gain, lag = FIRMWARE_RESPONSE[r["freq_hz"]]
        assert r["gain"] == pytest.approx(gain, rel=0.2, abs=0.03), r
        assert (r["phase_lag_deg"] - lag + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=10.0), r
    assert max(r["gain"] for r in profile_sine_response("ideal", [0.1, 0.2])) < 0.02


def test_the_arducopter_profile_answers_a_gust_as_the_firmware_did():
    """A band-pass: GUIDED's position target takes a slow push back out (the vehicle leads the
    wind at 0.05 Hz), drag and the velocity loop roll the fast one off; the profile's vehicle
    without its position target (the ideal one) keeps a slow push."""
    freqs = sorted(FIRMWARE_WIND_RESPONSE)
    for r in profile_sine_response("arducopter-sitl", freqs, 1.0, wind_mean_m_s=3.0):
        gain, lag = FIRMWARE_WIND_RESPONSE[r["freq_hz"]]
        assert r["gain"] == pytest.approx(gain, rel=0.25), r
        assert (r["phase_lag_deg"] - lag + 180.0) % 360.0 - 180.0 == pytest.approx(0.0, abs=15.0), r
    (slow,) = profile_sine_response("ideal", [0.05], 1.0, wind_mean_m_s=3.0)
    assert slow["phase_lag_deg"] > 0.0  # lags the wind: nothing takes the push back


def test_the_arducopter_profile_follows_a_small_velocity_sine_as_the_firmware_did():
    """GUIDED's shaping (jerk / accel = 2 1/s) and velocity loop: the truth's velocity against a
    small setpoint sine, gain within 0.16 and lag within 25 deg (the real figures carry the probe's
    link delay, which the profile's lock-step flight does not have)."""
    freqs = sorted(FIRMWARE_VELOCITY_RESPONSE)
    for r in profile_sine_response("arducopter-sitl", freqs, 0.05, alt_m=3.0, velocity=True):
        gain, lag = FIRMWARE_VELOCITY_RESPONSE[r["freq_hz"]]
        assert r["gain"] == pytest.approx(gain, abs=0.16), r
        assert r["phase_lag_deg"] == pytest.approx(lag, abs=25.0), r


def test_hover_figures_on_synthetic_rows():
    """A truth circling at 2 cm radius once every 4 s (speed 2 pi 0.02 / 4 m/s) and an estimate
    error that is a constant plus a 1 cm east step every 2 s."""
    rows = []
    for k in range(400):
        t = 0.05 * k
        a = 2 * math.pi * t / 4.0
        n, e = 0.02 * math.cos(a), 0.02 * math.sin(a)
        step = 0.01 if int(t / 2.0) % 2 else -0.01
        rows.append((t, "noise", n, e, n + 0.5, e + 0.1 + step))
    rows += [(20.0 + 0.05 * k, "quiet", 0.0, 0.0, 0.0, 0.0) for k in range(200)]
    f = hover_figures(rows)
    assert f["noise"]["truth_rms_m"] == pytest.approx(0.02, rel=0.01)  # 3.75 turns after the first 5 s
    chord = 2 * 0.02 * math.sin(math.pi * 0.5 / 4.0)  # the 0.5 s difference on the circle
    assert f["noise"]["truth_speed_rms_m_s"] == pytest.approx(chord / 0.5, rel=0.01)
    assert f["noise"]["estimate_error_rms_m"] == pytest.approx(0.01, rel=0.02)
    assert f["noise"]["estimate_error_1s_rms_m"] == pytest.approx(math.sqrt(0.5) * 0.02, rel=0.05)
    assert f["quiet"] == {k: 0.0 for k in f["quiet"]}
    with pytest.raises(ValueError, match="phase 'quiet': 0 samples"):
        hover_figures(rows[:400] + rows[400:402])
